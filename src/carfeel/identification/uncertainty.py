"""The robust loss and the uncertainties both steering fits (the law's, `steering_fit`, and the
physical model's, `physical_fit`) share: soft_l1's scale and cost, the block sandwich
covariance of an M-estimate, and the parameters' correlations from it."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
BLOCK_S = 2.0
"""Block length of the sandwich covariance: residuals of one manoeuvre phase hang together."""


def robust_scale(r: FloatArray) -> float:
    """The residuals' robust spread: 1.4826 times their median absolute deviation (the
    standard deviation for Gaussian ones)."""
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def soft_l1_cost(r: FloatArray, scale: float) -> float:
    """scipy's soft_l1 cost at `scale`: sum s^2 (sqrt(1 + (r/s)^2) - 1), about half the sum of
    squares for residuals within the scale."""
    return float(np.sum(scale * scale * (np.sqrt(1.0 + (r / scale) ** 2) - 1.0)))


def sandwich(
    jac: FloatArray, r: FloatArray, scale: float, blocks: npt.NDArray[np.intp]
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Covariance of a soft_l1 M-estimate: A^-1 B A^-1 with A = sum rho''(r) J J^T (the
    loss-weighted Gauss-Newton matrix) and B = sum over blocks of g g^T, g = sum rho'(r) r J in
    the block; times n_blocks / (n_blocks - p). Returns it, A^-1 (the loss's own inverse
    curvature: `keep` compares the two) and the parameters that lie in a direction the data do
    not constrain (infinite variance there)."""
    norms = np.linalg.norm(jac, axis=0)
    norms[norms == 0.0] = 1.0
    a, g = sandwich_terms(jac / norms, r, scale, blocks, int(blocks.max()) + 1)
    return sandwich_finish(a, g, norms)


def sandwich_terms(
    js: FloatArray, r: FloatArray, scale: float, blocks: npt.NDArray[np.intp], n_blocks: int
) -> tuple[FloatArray, FloatArray]:
    """`sandwich`'s sums over some rows of the column-scaled Jacobian `js`: (A, g per block),
    which add up over chunks of rows (`physical_fit` never holds its whole Jacobian)."""
    z = (r / scale) ** 2
    weight = 1.0 / np.sqrt(1.0 + z)  # rho'(z): the IRLS weight of soft_l1
    curvature = weight**3  # rho'(z) + 2 z rho''(z)
    a = js.T @ (js * curvature[:, None])
    scores = js * (weight * r)[:, None]
    g = np.zeros((n_blocks, js.shape[1]))
    np.add.at(g, blocks, scores)
    return a, g


def sandwich_finish(
    a: FloatArray, g: FloatArray, norms: FloatArray
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """`sandwich` from its sums (`sandwich_terms`) and the Jacobian's column norms."""
    n_blocks, p = g.shape
    b = g.T @ g * (n_blocks / max(n_blocks - p, 1))
    u, s, vt = np.linalg.svd(a)
    weak = s < 1e-10 * s[0]
    inverse = (vt[~weak].T / s[~weak]) @ u[:, ~weak].T
    scale_back = np.outer(norms, norms)
    covariance = inverse @ b @ inverse.T / scale_back
    bread = inverse / scale_back
    unconstrained = (
        np.any(np.abs(vt[weak]) > 0.1, axis=0) if weak.any() else np.zeros(p, dtype=bool)
    )
    for matrix in (covariance, bread):
        matrix[unconstrained, :] = math.inf
        matrix[:, unconstrained] = math.inf
    return covariance, bread, unconstrained


def _sandwich(
    jac: FloatArray, r: FloatArray, scale: float, blocks: npt.NDArray[np.intp]
) -> tuple[FloatArray, BoolArray]:
    """`sandwich` without the inverse curvature (its older form)."""
    covariance, _, unconstrained = sandwich(jac, r, scale, blocks)
    return covariance, unconstrained


def correlation(
    covariance: FloatArray, free: BoolArray, shown_below: int, names: Sequence[str]
) -> tuple[tuple[str, ...], tuple[tuple[float, ...], ...]]:
    """(names, matrix) of the correlations (to 4 decimals) of the free entries of x below
    `shown_below` (the model's parameters, not the nuisances), from the covariance of the free
    entries; `names` names x's entries. An unconstrained entry's are NaN (inf / inf)."""
    free_idx = np.flatnonzero(free)
    d = np.sqrt(np.clip(np.diag(covariance), 1e-300, None))
    with np.errstate(invalid="ignore"):  # unconstrained: inf / inf, no correlation to give
        corr = covariance / np.outer(d, d)
    shown = [j for j, i in enumerate(free_idx) if i < shown_below]
    return (
        tuple(names[free_idx[j]] for j in shown),
        tuple(tuple(round(float(corr[a, b]), 4) for b in shown) for a in shown),
    )
