"""The law's robust least squares (`_fit`: scipy's soft_l1 with the analytic Jacobian and the
sandwich covariance), the delay's scan with the law held, the rate's errors-in-variables
weights, and the free fit that places law and delay together (`_free_fit`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.identification import keep
from carfeel.identification.delay import RESCAN_S, minimize_delay
from carfeel.identification.steering_problem import _Problem
from carfeel.identification.uncertainty import robust_scale, sandwich, soft_l1_cost

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class _Fit(keep.Fitted):
    """One robust least-squares fit of the free entries, at the soft_l1 scale `scale`."""

    scale: float = 1.0
    residual: FloatArray = dataclasses.field(default_factory=lambda: np.zeros(0))
    """Weighted (what the fit minimizes); `raw` is model - measured."""
    raw: FloatArray = dataclasses.field(default_factory=lambda: np.zeros(0))
    unconstrained: BoolArray = dataclasses.field(default_factory=lambda: np.zeros(0, bool))
    active: npt.NDArray[np.int_] = dataclasses.field(default_factory=lambda: np.zeros(0, int))


def _fit(
    pb: _Problem, x0: FloatArray, free: BoolArray, scale: float | None = None,
    max_nfev: int = 200,
) -> _Fit:  # fmt: skip
    """Robust least squares of the free entries of x from x0 (clipped inside the bounds), at
    `scale` (default: the start's robust spread of the residuals); its covariance."""
    from scipy.optimize import least_squares

    idx = np.flatnonzero(free)
    lo, hi = pb.lower[idx], pb.upper[idx]
    base = x0.copy()

    def residual(z: FloatArray) -> FloatArray:
        pb.evaluations[0] += 1
        x = base.copy()
        x[idx] = z
        r = pb.residual(x)
        if pb.progress is not None:
            pb.progress(pb.evaluations[0], float(np.sqrt(np.mean(r * r))))
        return r

    def jacobian(z: FloatArray) -> FloatArray:
        x = base.copy()
        x[idx] = z
        return pb.weighted_jacobian(x, free)

    z0 = np.clip(x0[idx], lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo))
    if scale is None:
        scale = robust_scale(residual(z0)) or 0.1
    solution = least_squares(
        residual, z0, jac=jacobian, bounds=(lo, hi), loss="soft_l1", f_scale=scale,
        x_scale="jac", max_nfev=max_nfev,
    )  # fmt: skip
    x = base.copy()
    x[idx] = solution.x
    r = np.asarray(solution.fun)
    # scipy's solution.jac is scaled by the loss's weights: the sandwich weighs by itself.
    covariance, bread, unconstrained = sandwich(jacobian(solution.x), r, scale, pb.data.blocks)
    raw = r if pb.weights is None else np.asarray(pb.model(x) - pb.data.torque)
    return _Fit(x, free.copy(), soft_l1_cost(r, scale), covariance, bread, scale, r, raw,
                unconstrained, np.asarray(solution.active_mask))  # fmt: skip


def _scan_delay(pb: _Problem, x: FloatArray) -> float:
    """The torque's delay (s) that fits best with the rest of x held: a grid over
    +-MAX_DELAY_S, then a bounded search around its best point; the soft_l1 cost."""
    scale = robust_scale(pb.residual(x)) or 0.1
    offsets = pb.data.offsets @ x[pb.offset_slice]
    weights = 1.0 if pb.weights is None else pb.weights

    def cost(delay: float) -> float:
        r = (pb.law_torque(x, delay) + offsets - pb.data.torque) * weights
        return soft_l1_cost(r, scale)

    return minimize_delay(cost)


def _free_fit(pb: _Problem, x0: FloatArray, free: BoolArray) -> _Fit:
    """The fit with every candidate free: the law roughly at the start's delay (its robust scale
    is the one every later fit uses, so their costs compare), the delay placed by a scan, then
    both together, and again from a better minimum a rescan finds elsewhere."""
    di = pb.delay_index
    held_delay = free.copy()
    held_delay[di] = False
    held_delay[pb.bias_slice] = False  # the Ay biases move only the law's curvature: later
    fitted = _fit(pb, x0, held_delay, max_nfev=FIRST_NFEV if free[di] else 200)
    scale = robust_scale(fitted.residual) or fitted.scale
    pb.weights = eiv_weights(pb, fitted.x, scale)
    if pb.weights is not None:  # the first fit's cost is not the weighted fits': refit
        fitted = _fit(pb, fitted.x, held_delay, scale, max_nfev=FIRST_NFEV)
    if not free[di]:
        return fitted if np.array_equal(held_delay, free) else _fit(pb, fitted.x, free, scale)
    x = fitted.x.copy()
    x[di] = _scan_delay(pb, x)
    fitted = _fit(pb, x, free, scale)
    found = _scan_delay(pb, fitted.x)
    if abs(found - float(fitted.x[di])) > RESCAN_S:
        x = fitted.x.copy()
        x[di] = found
        other = _fit(pb, x, free, scale)
        if other.cost < fitted.cost:
            fitted = other
    return fitted


def eiv_weights(pb: _Problem, x: FloatArray, scale: float) -> FloatArray | None:
    """Weights of the residuals for the rate's errors in variables: a sample whose rate is
    uncertain by sigma_r (the adaptive derivative's error: large where a steer cycle's rate
    jumps within a sample, at a quantized angle's reversal) carries a torque error of about
    dtau/drate * sigma_r besides the torque's own, `scale`: its residual counts by
    1 / sqrt(1 + (dtau/drate * sigma_r / scale)^2) (weighted least squares, the slope from x).
    None when no rate error is known."""
    error = pb.data.rate_error
    if not np.any(error > 0.0):
        return None
    step = 1e-4
    r = pb.regressors(x)
    up = pb.law.torque(x[: pb.n_law], dataclasses.replace(r, rate=r.rate + step,
                                                          turned=np.abs(r.rate + step)
                                                          * pb.data.steps))  # fmt: skip
    down = pb.law.torque(x[: pb.n_law], dataclasses.replace(r, rate=r.rate - step,
                                                            turned=np.abs(r.rate - step)
                                                            * pb.data.steps))  # fmt: skip
    slope = (up - down) / (2.0 * step)
    return np.asarray(1.0 / np.sqrt(1.0 + (slope * error / scale) ** 2))


TEST_NFEV = 40
"""Evaluations of a held fit within the keep rule: a fit stopped early costs at least its
minimum, so the test it feeds errs toward refusing to keep, never toward keeping."""
FIRST_NFEV = 20
"""Evaluations of the first fit, before the delay is placed: it only has to find the law's
shape for the delay's scan."""
