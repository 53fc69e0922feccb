"""What the shift fit's simulation fits (`shift_passage`, `shift_stop`) share: x_gear's slack,
the bounded robust least squares over unknowns scaled to order 1 with grouped forward
differences (`_solve`), and the uncertainties of their solutions: Gauss-Newton and cluster
sandwich covariances (`_covariances`), the method's own error by a replica of the experiment
(`_method_error`), and the sigma that is the largest of them (`_sigma_of`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from carfeel.identification.shift_traces import FloatArray, PreparedTrace

GEAR_SLACK_M = 0.002
"""How far below the settled position x_gear may be fitted."""
DIFF_STEP = 0.05
"""Forward-difference step of the Jacobians, in the scaled unknowns (mm, ms, N, kN/m, N*s/m)."""
SOFT_L1_SCALE = 3.0
TOLERANCE = 1e-4
"""ftol and xtol of the fits: far below the noise, and a few times faster than the default."""


def _solve(
    residuals: Callable[[FloatArray], FloatArray],
    lower: FloatArray,
    upper: FloatArray,
    groups: Sequence[Sequence[int]],
    rows_of: Sequence[slice | None],
    tick: Callable[[FloatArray], None],
    start: FloatArray | None = None,
    max_nfev: int = 100,
) -> Any:
    """Bounded robust least squares from `start` (default 0) over unknowns scaled to order 1.

    The Jacobian is a forward difference of fixed step DIFF_STEP: scipy's relative steps vanish
    at 0, and the simulated positions move in quanta of a refined step that a step of 1e-8
    cannot see. The columns of a group touch disjoint rows (`rows_of`, None = all rows) and are
    differenced together, so per-engagement unknowns cost one simulation per kind, not per
    engagement.
    """
    from scipy.optimize import least_squares

    last: dict[bytes, FloatArray] = {}

    def fun(z: FloatArray) -> FloatArray:
        key = z.tobytes()
        if key not in last:
            last.clear()
            last[key] = residuals(z)
            tick(last[key])
        return last[key]

    def jac(z: FloatArray) -> FloatArray:
        f0 = fun(z)
        jacobian = np.zeros((len(f0), len(z)))
        for group in groups:
            cols = np.asarray(group)
            step = np.where(z[cols] + DIFF_STEP <= upper[cols], DIFF_STEP, -DIFF_STEP)
            moved = z.copy()
            moved[cols] += step
            change = residuals(moved) - f0
            for col, h in zip(cols, step, strict=True):
                rows = rows_of[col]
                if rows is None:
                    jacobian[:, col] = change / h
                else:
                    jacobian[rows, col] = change[rows] / h
        return jacobian

    return least_squares(
        fun, np.zeros(len(lower)) if start is None else start, jac=jac, bounds=(lower, upper),
        loss="soft_l1",
        f_scale=SOFT_L1_SCALE, xtol=TOLERANCE, ftol=TOLERANCE, max_nfev=max_nfev,
    )  # fmt: skip


def _covariance(solution: Any) -> FloatArray:
    """Gauss-Newton covariance of a fit's unknowns (in their scaled units): (J^T J)^-1 times
    the residuals' variance (they are in units of the noise, so about 1 for a model that fits).
    Residuals correlated in time (what a model misses hangs together along a run) make it a lower
    bound; an unknown the data cannot move gets an infinite variance."""
    jac = np.asarray(solution.jac, dtype=float)
    m, p = jac.shape
    variance = float(np.sum(np.asarray(solution.fun) ** 2)) / max(m - p, 1)
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    weak = s <= 1e-10 * (s[0] if len(s) else 1.0)
    cov = (vt[~weak].T / s[~weak] ** 2) @ vt[~weak] * variance
    if weak.any():
        loose = np.any(np.abs(vt[weak]) > 0.1, axis=0)
        cov[loose, :] = math.inf
        cov[:, loose] = math.inf
    return np.asarray(cov)


CORRELATION_BLOCK = 10
"""Samples per block of the residuals' correlation factor (`_covariances`): 20 ms at 500 Hz."""


def _covariances(solution: Any, cases: Sequence[slice], shared: int) -> list[FloatArray]:
    """Covariances of a simulation fit's unknowns whose rows come in cases (one engagement
    each; its own unknowns after the first `shared`): Gauss-Newton (`_covariance`) times the
    residuals' correlation factor within each case (the variance of their sums over blocks of
    CORRELATION_BLOCK samples over the sum of their squares: a knob's stairs, or what the model
    misses along a passage, hang together for many samples), and for the shared unknowns the
    cluster sandwich over the engagements (J^T J)^-1 (sum_c g_c g_c^T) (J^T J)^-1 with g_c =
    J_c^T r_c and the small-sample factor C / (C - p): what differs from one engagement to the
    next (its start, its draw) scatters the shared ones more than the noise would. The stop's
    stiffness came out 1.5 kN/m from the truth at a Gauss-Newton sigma of 13 N/m. A sigma is
    the largest of them (`_sigma_of`)."""
    r = np.asarray(solution.fun, dtype=float)
    jac = np.asarray(solution.jac, dtype=float)
    plain = _covariance(solution)
    total = float(np.sum(r * r))
    sums = 0.0
    for case in cases:
        part = r[case]
        ends = np.arange(CORRELATION_BLOCK, len(part), CORRELATION_BLOCK)
        sums += sum(float(np.sum(b)) ** 2 for b in np.split(part, ends))
    factor = max(sums / total, 1.0) if total > 0.0 else 1.0
    out = [plain, plain * factor]
    n = len(cases)
    if n > shared:
        scores = np.array([jac[case].T @ r[case] for case in cases])
        meat = scores.T @ scores * (n / (n - shared))
        _, sv, vt = np.linalg.svd(jac, full_matrices=False)
        keep = sv > 1e-10 * (sv[0] if len(sv) else 1.0)
        inverse = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
        robust = inverse @ meat @ inverse
        # Only the shared unknowns' block: an engagement's own unknowns zero its own score.
        robust[shared:, :] = 0.0
        robust[:, shared:] = 0.0
        out.append(robust)
    return out


def _sigma_of(
    covariances: Sequence[FloatArray], weights: Mapping[int, float],
    bias: FloatArray | None = None,
) -> float:  # fmt: skip
    """The largest standard deviation of sum(w_i x_i) over the covariances, and no less than
    the method's error in it (`_method_error`) where that is given."""
    idx, w = list(weights), np.array(list(weights.values()))
    variances = [float(w @ c[np.ix_(idx, idx)] @ w) for c in covariances]
    if not all(map(math.isfinite, variances)):
        return math.inf
    sigma = math.sqrt(max(max(variances), 0.0))
    return max(sigma, abs(float(w @ bias[idx]))) if bias is not None else sigma


def _replica(
    traces: Sequence[PreparedTrace], predicted: Sequence[FloatArray], seed: int = 0
) -> list[FloatArray]:
    """What each trace's sensor would have recorded of `predicted`: its noise added, and
    rounded to its resolution on the trace's own grid of values."""
    rng = np.random.default_rng(seed)
    out = []
    for tr, sim in zip(traces, predicted, strict=True):
        y = sim + rng.normal(0.0, tr.noise_m, len(sim)) if tr.noise_m > 0.0 else sim.copy()
        q = tr.resolution_m
        if q > 0.0:
            origin = float(tr.position_m[0])
            y = origin + np.round((y - origin) / q) * q
        out.append(np.asarray(y, dtype=float))
    return out


Forces = Mapping[int, FloatArray] | None
"""Each trace's force (by its index) to drive a fit's simulations with; None: as recorded."""


def _method_error(
    solution: Any, predicted: Callable[[FloatArray], list[FloatArray]],
    residuals: Callable[[FloatArray, Sequence[FloatArray], Forces], FloatArray],
    traces: Sequence[PreparedTrace], lower: FloatArray, upper: FloatArray,
    groups: Sequence[Sequence[int]], rows: Sequence[slice | None],
    tick: Callable[[FloatArray], None],
) -> FloatArray:  # fmt: skip
    """The fit's own error (scaled unknowns), by one replica of the experiment: the fitted
    model's traces recorded as the sensors would (`_replica`: the position's noise and
    resolution), fitted again as the traces were, from the same start, with the force driving
    the simulations carrying a fresh draw of its own noise (an error in the input the residuals
    cannot show: 1 N of it moved the stop's stiffness by 3 % from one draw to the next at a
    Gauss-Newton sigma of 0.4 %); the refit's departure from the fit. It holds what the sigmas
    of the position noise miss: a stop's ringing under a 0.05 mm resolution looks damped, the
    500 Hz samples of a 31 Hz ring (k +2 % without any noise), a solver that stops on the flat
    steps of a quantized cost. One draw: it also holds one draw of the noise, so `_sigma_of`
    takes the larger of it and the sigma, not their sum."""
    rng = np.random.default_rng(1)
    forces = {tr.index: tr.force_N + rng.normal(0.0, tr.noise_N, len(tr.force_N))
              for tr in traces}  # fmt: skip
    targets = _replica(traces, predicted(solution.x))
    again = _solve(lambda z: residuals(z, targets, forces), lower, upper, groups, rows, tick)
    return np.asarray(again.x - solution.x, dtype=float)
