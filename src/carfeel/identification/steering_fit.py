"""Fit the steering torque law (K1..K9 of eqs. 4-7, and the friction's memory K10, K11) to
measured logs by robust least squares.

A log has `time_s, speed_m_s, steering_angle_rad, steering_torque_Nm` and optionally
`lateral_accel_m_s2` and `steering_rate_rad_s`. Where data enters (`read_log`) the regressors are
conditioned against errors in variables (noise on a regressor biases a least-squares fit, at many
standard deviations on long logs; noise on the torque does not):
  speed   zero-phase low-pass at 1 Hz (a car's speed changes slowly; at standstill the noise of
          |V| would otherwise sit inside 1/(K4 + K5|V|) with a positive mean),
  Ay      zero-phase low-pass at 4 Hz when measured (a car's lateral response rolls off well
          below that); when not measured, the transient single-track car driven by the logged
          angle and speed (`transient_ay`), not its steady state, whose phase error would land
          in K7..K9,
  rate    as logged when its noise is under 0.1 deg/s (a filter rounds off the edges of quick
          steers), else smoothed; without a rate column, the angle's derivative. Both by the
          adaptive local fits of `signals.adaptive_derivative`, whose noise model is the
          sensor's: its noise and its resolution (a 0.1 deg encoder's stairs; the fixed 81 ms
          derivative it replaces took the friction's K8 16 % high on them).
The filters run per gap-free stretch (forward and back: no phase lag).

The fit is `scipy.optimize.least_squares` with an analytic Jacobian, bounds that keep each term
physically signed (every K >= 0 and the scales > 0), and the robust 'soft_l1' loss. Beside the
law it fits nuisances that are reported, never written to a preset: a torque offset per log
(constant, or with `drift_s` a piecewise-linear one with knots that far apart: road crown, bank
and sensor drift wander along a drive), and one delay of the torque behind the other channels
(CAN messages arrive with their own latencies). The delay is fitted with the law: the regressors
are shifted through cubic splines (smooth in the delay; linear interpolation put a kink into the
cost at every sample and a joint fit stalled on them), its Jacobian column a central difference;
a grid scan with the law held places it first (the cost has a minimum every period of a weave)
and a rescan after the fit restarts it from a better minimum further away.
Starting values come from the data: K1 from the slope of torque on Ay while the wheel barely
turns, K9 from the slope on the rate while it turns fast, the friction level from the rest, the
tyre-spin scale from parking (V < 2 m/s) if there is any.

What the base preset's value may stand for is decided by a test, not a rule (`keep`): every
parameter the logs hardly excite (the tyre spin K4..K6 without parking, the saturation K2, K3
with Ay under 3 m/s^2, the friction's memory without reversals) or that the free fit leaves at a
bound, within a sigma of one, unconstrained or poorly pinned, is held at the base's value with
the rest refitted, and kept only if that fit is statistically as good (a likelihood ratio scaled
for the residuals' correlation); the others are written as fitted, with their intervals (at a
bound if the data put them there). The sigmas are then conditional on the kept values.

Uncertainties are a sandwich (M-estimator) covariance: the bread is the loss-weighted Gauss-Newton
matrix sum(rho'' J J^T), the meat sums the weighted scores sum(rho' r J) over blocks of BLOCK_S
seconds, so residuals correlated within a block (model error, a slow offset) count as the fewer
independent samples they are. The parameter correlations come from the same covariance.
Before the fit, logs whose units or signs would fit well but wrongly are refused or warned about
(`steering_checks`); after it, r2 under 0.5 is warned about.
Without a measured Ay the understeer gradient is fitted too (`fit_vehicle`, by default whenever
no log has Ay: the speed steps of a steady-state test separate it from K1, and the test keeps the
base's when a log has no such steps), and the preset's rear cornering stiffness is set to give
it. The steering ratio is not fitted: in the linear range K1 * Ay ~ K1 / SR, so the two trade
exactly; take SR from the car's data.

The law is one `LawModel` (names, bounds, torque, Jacobian): another steering model can be served
by another instance without touching the fit's machinery.

This module runs the fit and decides what is kept; its parts live beside it: `steering_log`
(reading and conditioning a log), `steering_checks` (units and signs), `steering_law` (the law
and its regressors), `steering_problem` (the concatenated logs and the parameter vector),
`steering_solver` (the robust least squares and the delay's scan), and, shared with
`physical_fit`, `steering_types` (the log and the result), `uncertainty` (the robust scale and
cost, the sandwich covariance) and `delay` (the delay's search).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification import keep, rms_r2, uncertainty
from carfeel.identification.common import one_blas_thread
from carfeel.identification.delay import MAX_DELAY_S
from carfeel.identification.steering_checks import check_units
from carfeel.identification.steering_law import K_NAMES, MEMORY, LawModel
from carfeel.identification.steering_law import LOWER as LOWER
from carfeel.identification.steering_law import MEANINGS as MEANINGS
from carfeel.identification.steering_law import PAPER_LAW as PAPER_LAW
from carfeel.identification.steering_law import UPPER as UPPER
from carfeel.identification.steering_law import Regressors as Regressors
from carfeel.identification.steering_log import read_log as read_log
from carfeel.identification.steering_log import transient_ay as transient_ay
from carfeel.identification.steering_problem import SATURATION_AY_M_S2, _Data, block_length
from carfeel.identification.steering_problem import _data as _data
from carfeel.identification.steering_problem import _Problem as _Problem
from carfeel.identification.steering_problem import law_inputs as law_inputs
from carfeel.identification.steering_problem import offset_basis as offset_basis
from carfeel.identification.steering_solver import TEST_NFEV, _Fit, _fit, _free_fit
from carfeel.identification.steering_types import Estimate, log_figures, poorly_pinned
from carfeel.identification.steering_types import SteeringFit as SteeringFit
from carfeel.identification.steering_types import SteeringLog as SteeringLog
from carfeel.identification.uncertainty import soft_l1_cost
from carfeel.models.vehicle.single_track import VehicleParams
from carfeel.simulation.steering import SteeringCar

FloatArray = npt.NDArray[np.float64]
MIN_MODEL_AY_M_S2 = 0.1
"""Without a measured Ay, logs whose base-car Ay stays under this (parked, straight) cannot
place K1, and only then may the base's stand for it."""
MAX_AY_BIAS_M_S2 = 3.0
"""Largest bias of a measured Ay the fit may find (an IMU tilted by 17 degrees)."""
PARKING_SPEED_M_S = 2.0
MIN_REVERSALS = 4
"""Reversals of the steering the friction's memory needs to be seen (after each it builds)."""


def fit_steering(
    logs: Sequence[SteeringLog],
    base: SteeringCar,
    *,
    fit_vehicle: bool | None = None,
    drift_s: float | None = None,
    estimate_delay: bool = True,
    law: LawModel = PAPER_LAW,
    progress: Callable[[int, float], None] | None = None,
    alpha: float = keep.ALPHA,
) -> SteeringFit:
    """Fit the law (and the nuisances: offsets, a torque delay; the understeer gradient where no
    log has a measured Ay, or with `fit_vehicle`) to the logs; keep the base's values the data
    accept (`keep`, at level `alpha`)."""
    with one_blas_thread():
        return _fit_steering(logs, base, fit_vehicle, drift_s, estimate_delay, law, progress,
                             alpha)  # fmt: skip


def _fit_steering(
    logs: Sequence[SteeringLog], base: SteeringCar, fit_vehicle: bool | None,
    drift_s: float | None, estimate_delay: bool, law: LawModel,
    progress: Callable[[int, float], None] | None, alpha: float,
) -> SteeringFit:  # fmt: skip
    if not logs:
        raise InputError("no logs given")
    vehicle = base.vehicle
    measured_ay = all(log.lateral_accel_m_s2 is not None for log in logs)
    if fit_vehicle and measured_ay:
        raise InputError(
            "--fit-vehicle fits the understeer gradient where Ay is not measured, but every log "
            "has lateral_accel_m_s2 (the car's understeer is in it already): run the fit "
            "without --fit-vehicle"
        )
    if fit_vehicle is None:  # the car too, where no log measured its Ay
        fit_vehicle = not any(log.lateral_accel_m_s2 is not None for log in logs)
    if drift_s is not None and not drift_s > 0:
        raise InputError(f"--drift {drift_s:g}: the knot spacing must be a positive time in s")
    unit_warnings = check_units(logs, vehicle)
    k_us0 = vehicle.understeer_gradient_rad_s2_m
    k_us = k_us0
    # The most understeer the rear axle can give with this front axle (`vehicle_with`).
    max_k_us = (
        0.95
        * vehicle.cg_to_rear_axle_m
        * vehicle.mass_kg
        / (vehicle.front_cornering_stiffness_N_rad * vehicle.wheelbase_m)
    )
    evaluations = [0]
    n_law = len(law.names)
    base_law = np.array([getattr(base.torque, nm) for nm in law.names])
    warm: FloatArray | None = None
    passes = 2 if fit_vehicle else 1
    for pass_ in range(passes):  # with fit_vehicle: Ay simulated again at the fitted K_us
        ays = [
            log.lateral_accel_m_s2
            if log.lateral_accel_m_s2 is not None
            else transient_ay(
                log.time_s,
                log.speed_m_s,
                log.angle_rad,
                vehicle_with(vehicle, vehicle.steering_ratio, k_us),
            )
            for log in logs
        ]
        offsets = sum(offset_basis(log.time_s, drift_s).shape[1] for log in logs)
        block_s = block_length(logs, n_law + 3 + offsets)  # K_us or the bias, the delay
        data = _data(logs, ays, drift_s, block_s)
        n_off, n_bias = data.offsets.shape[1], data.ay_bias.shape[1]
        head = [*base_law, *([k_us0] if fit_vehicle else []), 0.0]
        lower = np.array([*law.lower, *([0.0] if fit_vehicle else []), -MAX_DELAY_S,
                          *[-5.0] * n_off, *[-MAX_AY_BIAS_M_S2] * n_bias])  # fmt: skip
        upper = np.array([*law.upper, *([max_k_us] if fit_vehicle else []), MAX_DELAY_S,
                          *[5.0] * n_off, *[MAX_AY_BIAS_M_S2] * n_bias])  # fmt: skip
        base_x = np.array([*head, *[0.0] * (n_off + n_bias)])
        pb = _Problem(data, law, k_us if fit_vehicle else None, vehicle.wheelbase_m, base_x,
                      lower, upper, evaluations, progress)  # fmt: skip
        free = np.ones(len(pb.base_x), dtype=bool)
        free[pb.delay_index] = estimate_delay
        x0 = pb.base_x.copy()
        if warm is None:
            start = _start(data.speed, data.rate, data.torque, data.ay)
            x0[:n_law] = start[:n_law]
        else:
            x0[: len(warm)] = warm
        full = _free_fit(pb, x0, free)
        warm = full.x.copy()
        if fit_vehicle and pass_ == 0:
            k_us = float(np.clip(full.x[n_law], 1e-6, max_k_us))
    groups, reasons = _kept_for_excitation(data, law.names)
    names = [*law.names, *(["understeer_gradient_rad_s2_m"] if fit_vehicle else [])]
    names_all = [*names, "torque_delay_s", *[f"offset{i}" for i in range(n_off)],
                 *[f"ay_bias{i}" for i in range(n_bias)]]  # fmt: skip

    def refit(held: frozenset[int], start: keep.Fitted) -> keep.Fitted:
        trial = free.copy()
        x = start.x.copy()
        for i in held:
            trial[i] = False
            x[i] = pb.base_x[i]
        return _fit(pb, x, trial, full.scale, max_nfev=TEST_NFEV)

    # Rounds: what a kept value leaves weak (a memory level near 0 once its angle is held)
    # becomes a candidate of the next round, tested with the kept ones against the free fit.
    current: keep.Fitted = full
    held: frozenset[int] = frozenset()
    tests: list[keep.KeepTest] = []
    tried: set[tuple[int, ...]] = set()
    for _ in range(len(names)):
        assert isinstance(current, _Fit)
        fresh = [c for c in _candidates(pb, current, groups) if c not in tried]
        if not fresh:
            break
        tried.update(fresh)
        current, held, more = keep.keep_from_base(
            full, fresh, pb.base_x, refit, names_all, alpha, current, held
        )
        tests += more
    assert isinstance(current, _Fit)
    if held:  # the tests' refits stop early (that only errs toward refusing): converge it
        current = _fit(pb, current.x, current.free, full.scale)
    return _result(pb, logs, base, full, current, held, tests, names, reasons, unit_warnings,
                   alpha)  # fmt: skip


def _kept_for_excitation(data: _Data, names: Sequence[str]) -> tuple[list[tuple[int, ...]],
                                                                      dict[int, str]]:  # fmt: skip
    """Groups of parameters the logs hardly excite (candidates to keep), with the reasons."""
    speed, rate, ay = data.speed, data.rate, data.ay
    groups: list[tuple[int, ...]] = []
    reasons: dict[int, str] = {}
    if tuple(names) != K_NAMES:
        return groups, reasons
    parked = (speed < PARKING_SPEED_M_S) & (np.abs(rate) > 0.5)
    if parked.mean() < 0.01:
        groups.append((3, 4, 5))
        for i in (3, 4, 5):
            reasons[i] = (
                "the logs have almost no parking manoeuvres (V < 2 m/s with the wheel turning); "
                "add a steer cycle at standstill"
            )
    if np.percentile(np.abs(ay), 99) < SATURATION_AY_M_S2:
        groups.append((1, 2))
        for i in (1, 2):
            reasons[i] = "Ay stays under 3 m/s^2; add a steady-state circle or a lane change"
    moving = np.abs(rate) > 0.05
    flips = int(np.sum(np.abs(np.diff(np.sign(rate[moving]))) > 0)) if moving.any() else 0
    if flips < MIN_REVERSALS:
        groups.append(MEMORY)
        for i in MEMORY:
            reasons[i] = f"the steering reverses {flips} times (the memory needs {MIN_REVERSALS})"
    return groups, reasons


def _candidates(pb: _Problem, full: _Fit, groups: list[tuple[int, ...]]) -> list[tuple[int, ...]]:
    """What may be kept from the base: the groups the logs hardly excite, and each law (or
    K_us) parameter the free fit leaves at a bound, within a sigma of one, in an unconstrained
    direction or pinned to no better than half its value."""
    memory_off = tuple(pb.law.names) == K_NAMES and pb.base_x[MEMORY[0]] == 0.0
    grouped = {i for g in groups for i in g}
    out = list(groups)
    positions = np.cumsum(full.free) - 1
    for i in range(pb.delay_index):
        if i in grouped or not full.free[i]:
            continue
        if memory_off and i in MEMORY:  # the base has none: its level and angle go together
            weak = [_weak(pb, full, k, int(positions[k])) for k in MEMORY if full.free[k]]
            if any(weak) and MEMORY not in out:
                out.append(MEMORY)
            continue
        if i == 0 and pb.k_us is not None and _ay_excited(pb):
            # Without a measured Ay, K1 multiplies the base car's Ay: the base's K1 belongs to
            # that car, not to this one, so it is no default to keep where the logs steer the
            # car at all (a highway drive put K1 near 0 at a sigma of 850, and the 2.4 the test
            # let stand predicted 1.2 Nm of aligning torque where the driver held 0.1).
            continue
        if _weak(pb, full, i, int(positions[i])):
            out.append((i,))
    return out


def _ay_excited(pb: _Problem) -> bool:
    """The logs' (model) Ay reaches MIN_MODEL_AY_M_S2 (99th percentile): they steer the car."""
    return bool(np.percentile(np.abs(pb.data.ay), 99) >= MIN_MODEL_AY_M_S2)


def _weak(pb: _Problem, fit: _Fit, i: int, j: int) -> bool:
    """Entry i (free position j) at a bound, within a sigma of one, unconstrained or pinned to
    no better than half its value."""
    sigma = math.sqrt(max(float(fit.covariance[j, j]), 0.0))
    value = float(fit.x[i])
    near = min(value - pb.lower[i], pb.upper[i] - value)
    return bool(fit.active[j] != 0 or fit.unconstrained[j] or not math.isfinite(sigma)
                or near < sigma or sigma > 0.5 * abs(value))  # fmt: skip


def _result(
    pb: _Problem, logs: Sequence[SteeringLog], base: SteeringCar, full: _Fit, final: _Fit,
    held: frozenset[int], tests: list[keep.KeepTest], names: Sequence[str],
    reasons: dict[int, str], unit_warnings: list[str], alpha: float = keep.ALPHA,
) -> SteeringFit:  # fmt: skip
    """The SteeringFit of `final`, with the free fit's figures and the tests beside it."""
    data, n_law, di = pb.data, pb.n_law, pb.delay_index
    x, r = final.x, final.raw
    positions = np.cumsum(final.free) - 1
    decided: dict[str, keep.KeepTest] = {}  # a kept one's last joint test, else its refusal
    for step in tests:
        for name in step.held:
            if name not in decided or step.kept:
                decided[name] = step
    estimates = []
    for i, name in enumerate(names):
        why = reasons.get(i, "")
        test = decided.get(name)
        if i in held and test is not None:
            note = (f"kept from the base preset: {why + '; ' if why else ''}held at the base's "
                    f"value the fit is as good (likelihood ratio p = {test.p_value:.2g} against "
                    f"the free fit, {full_value(full, i, name)})")  # fmt: skip
            estimates.append(Estimate(name, float(x[i]), math.nan, "kept", note))
            continue
        j = int(positions[i])
        sigma = math.sqrt(max(float(final.covariance[j, j]), 0.0))
        note = ""
        at = [b for b in (pb.lower[i], pb.upper[i]) if abs(float(x[i]) - b) <= 1e-6 * (
            pb.upper[i] - pb.lower[i])]  # fmt: skip
        if test is not None:
            note = (f"the base's {pb.base_x[i]:.4g} fits significantly worse (p = "
                    f"{test.p_value:.2g}): written as fitted")  # fmt: skip
        if at:
            note = (f"at its bound {at[0]:g}: the data put it there; " + note).rstrip("; ")
        estimates.append(Estimate(name, float(x[i]), sigma, "fitted", note))
    correlation = uncertainty.correlation(final.covariance, final.free, di, names)
    warnings = unit_warnings + _identifiability(estimates, reasons)
    fitted_anyway: dict[str, list[str]] = {}  # the logs hardly excite them, yet reject the base
    for i, e in enumerate(estimates):
        if e.status == "fitted" and i in reasons:
            fitted_anyway.setdefault(reasons[i], []).append(e.name)
    for reason, which in fitted_anyway.items():
        warnings.append(
            f"{', '.join(which)} fitted though {reason}: the base preset's values fit these logs "
            "significantly worse, so the values written are the logs' own; beyond what the logs "
            "cover they are extrapolated"
        )
    per_log: dict[str, dict[str, float]] = {}
    offset_values = data.offsets @ x[pb.offset_slice]
    bias = x[pb.bias_slice]
    biases = {log.name: float(bias[0]) for log in logs
              if bias.size and log.lateral_accel_m_s2 is not None}  # fmt: skip
    for log, part in zip(logs, data.parts, strict=True):
        per_log[log.name] = {
            **log_figures(data.torque[part], r[part], offset_values[part], len(log.time_s)),
            **({"ay_offset_m_s2": biases[log.name]} if log.name in biases else {}),
        }
    rms, r2 = rms_r2(data.torque, data.torque + r)
    free_rms, free_r2 = rms_r2(data.torque, data.torque + full.raw)
    if held and rms > 1.01 * free_rms:
        kept_names = ", ".join(names[i] for i in sorted(held))
        last_kept = next((t.p_value for t in reversed(tests) if t.kept), math.nan)
        warnings.append(
            f"with {kept_names} at the base's values the law predicts these logs with rms "
            f"{rms:.4g} Nm against {free_rms:.4g} Nm of the free fit: not significantly worse "
            f"by the test (p = {last_kept:.2g} for them together), the difference is within "
            "what the data can tell"
        )
    if not r2 > 0.5:
        warnings.append(
            f"r2 {r2:.3g}: the law explains little of the torque; check the logs' units, signs "
            "and columns before using this preset"
        )
    law_test, explains = against_no_law(pb, final, alpha)
    if law_test.kept:
        warnings.append(
            f"the law is not significantly better than none (a torque offset per log alone): "
            f"it removes {explains:.1%} of the torque's variance about the offsets, at "
            f"likelihood ratio p = {law_test.p_value:.2g} (residuals correlated over seconds "
            "leave few independent samples); what is written is the logs' best guess, not a "
            "measurement of this car's feel"
        )
    car = dataclasses.replace(base, torque=pb.law.params(x[:n_law]))
    if pb.k_us is not None:
        car = dataclasses.replace(
            car, vehicle=vehicle_with(base.vehicle, base.vehicle.steering_ratio, float(x[n_law]))
        )
    return SteeringFit(
        car, tuple(estimates), float(np.mean(offset_values)), rms, r2, per_log, tuple(warnings),
        pb.evaluations[0], float(x[di]), correlation,
        free_fit={"rms_error_Nm": free_rms, "r2": free_r2}, keep_tests=tuple(tests),
        law_test=law_test, law_explains=explains,
    )  # fmt: skip


NO_LAW = "every law term (a torque offset per log only)"
"""How `against_no_law`'s test names what it holds."""
MIN_EXPLAINED = 0.01
"""A law that removes less of the torque's variance about the offsets than this explains
nothing, significant or not: the delay's scan over +-MAX_DELAY_S finds some alignment with
noise (a straight drive's base law at 237 ms 'explained' 0.15 % at p = 3e-4)."""


def against_no_law(
    pb: _Problem, final: _Fit, alpha: float = keep.ALPHA
) -> tuple[keep.KeepTest, float]:
    """The written fit against no law at all, each log's torque offset alone (robustly, at the
    fit's scale and weights): the scaled likelihood ratio (`keep.scaled_lr_of_cost`, the fit's
    free law, K_us and delay entries its degrees of freedom) and the fraction of the torque's
    variance about the offsets that the law removes. Each parameter's own keep test cannot see
    a law that explains nothing (a straight drive: K1 0.29 +- 0.28 from the angle sensor's
    noise, r2 0.0007), since a base value it rejects can still be no law at all."""
    basis, torque = pb.data.offsets, pb.data.torque
    w = np.ones_like(torque) if pb.weights is None else pb.weights
    c = np.zeros(basis.shape[1])
    for _ in range(20):  # IRLS of soft_l1 (its weights 1 / sqrt(1 + (r/s)^2)): a few suffice
        r = (basis @ c - torque) * w
        irls = w / np.sqrt(np.sqrt(1.0 + (r / final.scale) ** 2))
        c = np.asarray(np.linalg.lstsq(basis * irls[:, None], torque * irls, rcond=None)[0])
    cost = soft_l1_cost((basis @ c - torque) * w, final.scale)
    null = float(np.sum((basis @ c - torque) ** 2))
    explains = 1.0 - float(np.sum(final.raw**2)) / null if null > 0.0 else 0.0
    tested = [i for i in range(pb.delay_index + 1) if final.free[i]]
    if not tested:  # nothing fitted: the law is the base's, and no test of it is made here
        return keep.KeepTest((NO_LAW,), math.nan, 0, math.nan, False), explains
    statistic, p = keep.scaled_lr_of_cost(final, cost, tested)
    return keep.KeepTest((NO_LAW,), statistic, len(tested), p, p > alpha), explains


def full_value(full: keep.Fitted, i: int, name: str) -> str:
    """The free fit's value of entry i with its sigma, as a note quotes it."""
    if not full.free[i]:
        return f"{name} not free there"
    j = int(np.sum(full.free[:i]))
    sigma = math.sqrt(max(float(full.covariance[j, j]), 0.0))
    return f"where it came out {float(full.x[i]):.3g} +- {sigma:.2g}"


def vehicle_with(vehicle: VehicleParams, ratio: float, k_us: float) -> VehicleParams:
    """The car with this steering ratio, and the rear cornering stiffness that gives K_us."""
    a, b = vehicle.cg_to_front_axle_m, vehicle.cg_to_rear_axle_m
    denominator = b / vehicle.front_cornering_stiffness_N_rad - k_us * vehicle.wheelbase_m / (
        vehicle.mass_kg
    )
    if denominator <= 0.0:
        raise InputError(
            f"the fitted understeer gradient {math.degrees(k_us) * 9.80665:.2f} deg/g cannot be "
            "reached by the rear axle with this car's front cornering stiffness"
        )
    return dataclasses.replace(
        vehicle, steering_ratio=ratio, rear_cornering_stiffness_N_rad=a / denominator
    )


def _start(speed: FloatArray, rate: FloatArray, torque: FloatArray, ay: FloatArray) -> FloatArray:
    """Starting values of K1..K11 from the data (see the module docstring)."""
    slow = (np.abs(rate) < 0.1) & (np.abs(ay) < 3.0) & (speed > PARKING_SPEED_M_S)
    k1 = 2.0
    if slow.sum() > 20 and np.ptp(ay[slow]) > 0.5:
        k1 = float(max(np.polyfit(ay[slow], torque[slow], 1)[0], 0.05))
    rest = torque - k1 * ay
    fast = np.abs(rate) > 1.0
    k9 = (
        float(max(np.polyfit(rate[fast], rest[fast], 1)[0], 0.0)) * 0.3 if fast.sum() > 20 else 0.05
    )
    moving = np.abs(rate) > 0.05
    k7 = float(np.median(np.abs(rest[moving]))) / 2.0 if moving.sum() > 20 else 0.5
    parked = (speed < PARKING_SPEED_M_S) & (np.abs(rate) > 0.5)
    k4 = 0.5
    if parked.sum() > 20:
        spin = float(np.percentile(np.abs(rest[parked]), 90)) - k7 * math.pi / 2
        k4 = math.pi / 2 / max(spin, 0.5)
    k7 = max(k7, 0.05)
    # The friction's two parts share the level at the start; the fit moves it between them.
    return np.array([k1, 0.1, 1.2, k4, 0.1, 0.5, 0.7 * k7, 0.05, max(k9, 0.01), 0.5 * k7, 0.02])


def _identifiability(estimates: Sequence[Estimate], reasons: dict[int, str]) -> list[str]:
    """What was kept from the base and why, and what the data pin down poorly."""
    warnings = []
    by_reason: dict[str, list[str]] = {}
    for i, e in enumerate(estimates):
        if e.status == "kept":
            by_reason.setdefault(reasons.get(i, ""), []).append(e.name)
    level = next((e for e in estimates if e.name == "k10_Nm"), None)
    memory_off = level is not None and level.status == "kept" and level.value == 0.0
    for reason, kept in by_reason.items():
        if memory_off and set(kept) <= {"k10_Nm", "k11_rad"}:
            continue  # the friction's memory stays off, as the base has it: nothing to warn of
        why = reason or "the free fit could not place them"
        warnings.append(
            f"{', '.join(kept)} not identifiable ({why}): kept from the base preset, whose "
            "values fit as well by the test; the other sigmas are conditional on them"
        )
    return warnings + poorly_pinned(estimates)
