"""When may a fit keep a parameter at the base preset's value? Only when the data say the base's
value fits as well (issue 25).

The rule it replaces kept whatever stopped at a bound, lay within one sigma of one or had a huge
sigma, and wrote the base's value without a test: a tyre-spin term that the data put at its bound
because it is not there (K4 17.4 +- 8e4 on a Golf-like car) came back as the base's large one,
and the preset predicted its own logs 20 times worse than the fit (1.62 Nm against 0.08). A large
sigma often means "correlated with another parameter" or "this term vanishes", not "the data say
nothing".

Now each candidate (a parameter the logs hardly excite, or one the free fit leaves at a bound,
within a sigma of one, in an unconstrained direction or poorly pinned) is held at the base's
value and everything else refitted; it is kept only if that fit is statistically as good as the
free fit. The test is a likelihood ratio of the robust (soft_l1) cost, scaled for the residuals'
correlation within blocks: under the null 2 (C_held - C_free) is a sum of lambda_j chi^2_1 with
lambda_j = V_jj / (A^-1)_jj (the block sandwich's variance over the loss's own, Rotnitzky and
Jewell 1990; Satorra and Bentler's mean correction for several at once), so T = 2 dC / mean(lambda)
is referred to chi^2_q. Candidates are tried in the order of their Wald statistic against the base
(the most compatible first), each time all the kept ones together against the free fit: what is
kept is jointly accepted. What the test refuses is written as fitted, with its interval, and at a
bound if the data put it there. The sigmas of the rest are conditional on the kept values.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

ALPHA = 0.01
"""A value is kept from the base when the test's p-value exceeds this."""


@dataclass(frozen=True)
class Fitted:
    """What the rule needs of one fit: the full parameter vector, which entries were free, the
    robust cost at a common scale, and the covariance (block sandwich) and the loss's own inverse
    curvature over the free entries (in their order)."""

    x: FloatArray
    free: npt.NDArray[np.bool_]
    cost: float
    covariance: FloatArray
    bread_inverse: FloatArray


@dataclass(frozen=True)
class KeepTest:
    """One step of the rule: `held` (names) at the base's values against the free fit."""

    held: tuple[str, ...]
    statistic: float
    dof: int
    p_value: float
    kept: bool

    def as_dict(self) -> dict[str, object]:
        return {"held": list(self.held), "statistic": self.statistic, "dof": self.dof,
                "p_value": self.p_value, "kept": self.kept}  # fmt: skip


def inflation(full: Fitted, index: int) -> float:
    """lambda of entry `index` of the free fit: its sandwich variance over the loss's own
    (NaN where either is not finite or positive)."""
    position = int(np.sum(full.free[:index]))
    if not full.free[index]:
        return math.nan
    v = float(full.covariance[position, position])
    a = float(full.bread_inverse[position, position])
    return v / a if math.isfinite(v) and math.isfinite(a) and a > 0.0 and v > 0.0 else math.nan


def scaled_lr(full: Fitted, held: Fitted, indices: Sequence[int]) -> tuple[float, float]:
    """(T, p) of holding `indices` (those of `held`'s that the free fit had free)."""
    return scaled_lr_of_cost(full, held.cost, indices)


def scaled_lr_of_cost(full: Fitted, cost: float, indices: Sequence[int]) -> tuple[float, float]:
    """(T, p) of a restricted fit of robust cost `cost` (at `full`'s scale) that removes
    `indices` of `full`'s free entries."""
    from scipy.stats import chi2

    lambdas = [inflation(full, i) for i in indices]
    finite = [v for v in lambdas if math.isfinite(v)]
    if not finite:  # none of them has a variance: the typical one of the fit's
        every = [inflation(full, i) for i in np.flatnonzero(full.free).tolist()]
        finite = [v for v in every if math.isfinite(v)] or [1.0]
        finite = [float(np.median(finite))]
    scale = float(np.mean(finite))
    statistic = max(2.0 * (cost - full.cost), 0.0) / scale
    return statistic, float(chi2.sf(statistic, len(indices)))


def wald(full: Fitted, indices: Sequence[int], base: FloatArray) -> float:
    """The Wald statistic of the base's values for `indices` (0 where a variance is infinite:
    the data cannot tell them apart from anything)."""
    total = 0.0
    for i in indices:
        if not full.free[i]:
            continue
        position = int(np.sum(full.free[:i]))
        v = float(full.covariance[position, position])
        if math.isfinite(v) and v > 0.0:
            total += (float(full.x[i]) - float(base[i])) ** 2 / v
    return total


def keep_from_base(
    full: Fitted,
    candidates: Sequence[tuple[int, ...]],
    base: FloatArray,
    refit: Callable[[frozenset[int], Fitted], Fitted],
    names: Sequence[str],
    alpha: float = ALPHA,
    current: Fitted | None = None,
    held: frozenset[int] = frozenset(),
) -> tuple[Fitted, frozenset[int], list[KeepTest]]:
    """The fit with every candidate (a group of indices) held at `base` that the data accept
    jointly, by `scaled_lr` against `full`; `refit(held, start)` fits with `held` at the base's
    values from `start`. From `current` with `held` already (a later round), else from `full`.
    Returns it, the held indices and the tests in the order made."""
    order = sorted(candidates, key=lambda group: wald(full, group, base) / max(len(group), 1))
    current = full if current is None else current
    tests: list[KeepTest] = []
    for group in order:
        group = tuple(i for i in group if full.free[i] and i not in held)
        if not group:
            continue
        trial = held | frozenset(group)
        fitted = refit(trial, current)
        tested = sorted(i for i in trial if full.free[i])
        statistic, p = scaled_lr(full, fitted, tested)
        accept = p > alpha
        tests.append(KeepTest(tuple(names[i] for i in tested), statistic, len(tested), p, accept))
        if accept:
            current, held = fitted, trial
    return current, held, tests
