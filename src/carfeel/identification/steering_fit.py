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
(`_check_units`); after it, r2 under 0.5 is warned about.
Without a measured Ay the understeer gradient is fitted too (`fit_vehicle`, by default whenever
no log has Ay: the speed steps of a steady-state test separate it from K1, and the test keeps the
base's when a log has no such steps), and the preset's rear cornering stiffness is set to give
it. The steering ratio is not fitted: in the linear range K1 * Ay ~ K1 / SR, so the two trade
exactly; take SR from the car's data.

The law is one `LawModel` (names, bounds, torque, Jacobian): another steering model can be served
by another instance without touching the fit's machinery.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification import keep, rms_r2
from carfeel.identification.common import check_torque_logged, one_blas_thread
from carfeel.identification.signals import (
    adaptive_derivative,
    adaptive_estimate,
    linear_recurrence,
    lowpass,
    measurement_sigma,
    stretches,
)
from carfeel.models.steering.torque import SteeringTorqueParams, torque_terms
from carfeel.models.vehicle.single_track import VehicleParams
from carfeel.simulation.result import Result
from carfeel.simulation.steering import SteeringCar
from carfeel.text import count

__all__ = ["lowpass"]  # re-exported for physical_fit

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
REQUIRED = ("time_s", "speed_m_s", "steering_angle_rad", "steering_torque_Nm")
K_NAMES = ("k1_Nm_s2_m", "k2", "k3", "k4_1_Nm", "k5_s_m_Nm", "k6_rad_s", "k7_Nm", "k8_rad_s",
           "k9_Nm_s_rad", "k10_Nm", "k11_rad")  # fmt: skip
MEANINGS = {
    "k1_Nm_s2_m": "K1, aligning: on-centre torque per m/s^2 of Ay, Nm s^2/m (x 9.81: Nm/g)",
    "k2": "K2, aligning saturation: tau0 = K1 Ay / (1 + K2 |Ay|^K3), (m/s^2)^-K3",
    "k3": "K3, aligning saturation exponent",
    "k4_1_Nm": "K4, tyre spin at standstill: tau1 = atan(rate / K6) / (K4 + K5 V), 1/Nm",
    "k5_s_m_Nm": "K5, tyre spin falling with speed V, s/(m Nm)",
    "k6_rad_s": "K6, steering rate at which the tyre spin builds, rad/s",
    "k7_Nm": "K7, friction level: tau2 = K7 atan(rate / K8), Nm",
    "k8_rad_s": "K8, steering rate within which the friction builds, rad/s",
    "k9_Nm_s_rad": "K9, damping: tau3 = K9 rate, Nm s/rad",
    "k10_Nm": "K10, friction with memory: its level, Nm (tau2 + K10 z, z a Dahl element)",
    "k11_rad": "K11, the steering angle over which that friction builds after a reversal, rad",
    "understeer_gradient_rad_s2_m": "the car's understeer gradient K_us (fitted without a "
    "measured Ay), rad per m/s^2",
}
"""What each fitted parameter is (the paper's eqs. 4-7 and the friction's memory), for reports."""
LOWER = (1e-3, 0.0, 0.3, 1e-2, 0.0, 1e-2, 0.0, 1e-3, 0.0, 0.0, 1e-3)
UPPER = (50.0, 10.0, 3.0, 100.0, 100.0, 10.0, 20.0, 5.0, 5.0, 20.0, 0.1)
CUTOFF_HZ = {"speed_m_s": 1.0, "lateral_accel_m_s2": 4.0}
"""Zero-phase low-pass corners of the regressors (see the module docstring)."""
RATE_NOISE_RAD_S = math.radians(0.1)
BLOCK_S = 2.0
"""Block length of the sandwich covariance: residuals of one manoeuvre phase hang together."""
MIN_BLOCK_S = 0.5
BLOCKS_PER_PARAMETER = 4
"""Short logs get shorter blocks (to MIN_BLOCK_S) so that they hold this many per parameter
(`block_length`)."""
MIN_MODEL_AY_M_S2 = 0.1
"""Without a measured Ay, logs whose base-car Ay stays under this (parked, straight) cannot
place K1, and only then may the base's stand for it."""
MAX_DELAY_S = 0.25
MAX_AY_BIAS_M_S2 = 3.0
"""Largest bias of a measured Ay the fit may find (an IMU tilted by 17 degrees)."""
DELAY_STEP_S = 2e-4
"""Half-step of the delay's central difference (the splines are smooth far below a sample)."""
RESCAN_S = 0.005
"""After the fit, a delay scan that finds a better minimum further than this starts it again."""
PARKING_SPEED_M_S = 2.0
SATURATION_AY_M_S2 = 3.0
"""The law's saturation K2, K3 (and the Ay sensor's bias with it) is seen only in logs whose Ay
goes beyond this (99th percentile)."""
MIN_REVERSALS = 4
"""Reversals of the steering the friction's memory needs to be seen (after each it builds)."""
MAX_SAMPLE_PERIOD_S = 0.05
"""20 Hz: slower logs cannot show the friction and damping terms (and ms read as s land here)."""


@dataclass(frozen=True)
class SteeringLog:
    """One log's signals in SI units, checked, with the rate and Ay it will be fitted with."""

    name: str
    time_s: FloatArray
    speed_m_s: FloatArray
    angle_rad: FloatArray
    rate_rad_s: FloatArray
    torque_Nm: FloatArray
    lateral_accel_m_s2: FloatArray | None
    rate_logged: bool = False
    """The rate is the log's own (as logged, or smoothed), not derived from the angle."""
    rate_error_rad_s: FloatArray | None = None
    """One sigma of the rate at each sample (`signals.adaptive_estimate`): its errors in
    variables, which weight the fit (`_Problem.weights`); None: not known."""


@dataclass(frozen=True)
class Estimate:
    name: str
    value: float
    sigma: float
    """One standard deviation; NaN for a parameter kept from the base preset."""
    status: str = "fitted"
    """"fitted", or "kept": the base preset's value, which the data accept (the test's note)."""
    note: str = ""


@dataclass(frozen=True)
class SteeringFit:
    car: SteeringCar
    estimates: tuple[Estimate, ...]
    torque_offset_Nm: float
    """The mean of the logs' offsets (model + offset = measured)."""
    rms_error_Nm: float
    r2: float
    per_log: dict[str, dict[str, float]]
    """Per log: rms_error_Nm, r2, mean residual (the bias left), samples, offset_Nm (mean),
    offset_range_Nm (how far a drifting offset wandered), offset_end_Nm (its last value: what
    a later part of the log is predicted with) and, with a measured Ay, ay_offset_m_s2."""
    warnings: tuple[str, ...]
    iterations: int
    torque_delay_s: float = 0.0
    """How much later the torque was logged than the other channels (corrected in the fit)."""
    correlation: tuple[tuple[str, ...], tuple[tuple[float, ...], ...]] = ((), ())
    """(names, matrix) of the fitted parameters' correlations."""
    holdout: dict[str, dict[str, dict[str, float]]] = dataclasses.field(default_factory=dict)
    """With a held-out part: {"fit": figures per log, "held_out": figures per log}."""
    free_fit: dict[str, float] = dataclasses.field(default_factory=dict)
    """rms_error_Nm and r2 of the fit with every candidate free (before any is kept)."""
    keep_tests: tuple[keep.KeepTest, ...] = ()
    """The tests that decided what is kept from the base (`keep.keep_from_base`)."""
    baselines: dict[str, dict[str, dict[str, float]]] = dataclasses.field(default_factory=dict)
    """The model and the black boxes (`baselines`) on the same split: {name: {log or "all":
    figures}}, with `baseline_split` saying which."""
    baseline_split: str = ""
    law_test: keep.KeepTest | None = None
    """The written law against none (a torque offset per log only, `against_no_law`): with
    p > alpha the logs show no steering feel at all, whatever the parameters say."""
    law_explains: float = math.nan
    """The fraction of the torque's variance about the offsets that the written law removes
    (`against_no_law`): under MIN_EXPLAINED it explains nothing an engineer could use."""

    @property
    def conditional(self) -> bool:
        """The sigmas are conditional on values kept from the base."""
        return any(t.kept for t in self.keep_tests)

    def as_dict(self) -> dict[str, object]:
        names, matrix = self.correlation
        return {
            "parameters": {
                e.name: {
                    "value": e.value,
                    "sigma": e.sigma,
                    "status": e.status,
                    **({"note": e.note} if e.note else {}),
                }
                for e in self.estimates
            },
            "sigmas_conditional_on_kept": self.conditional,
            "correlation": {"parameters": list(names), "matrix": [list(r) for r in matrix]},
            "torque_offset_Nm": self.torque_offset_Nm,
            "torque_delay_s": self.torque_delay_s,
            "rms_error": self.rms_error_Nm,
            "rms_error_unit": "N m",
            "r2": self.r2,
            "free_fit": self.free_fit,
            "keep_tests": [t.as_dict() for t in self.keep_tests],
            **(
                {"law_test": {**self.law_test.as_dict(), "explains": self.law_explains}}
                if self.law_test is not None
                else {}
            ),
            "per_log": self.per_log,
            "warnings": list(self.warnings),
            "iterations": self.iterations,
            **({"cross_validation": self.holdout} if self.holdout else {}),
            **(
                {"baselines": {"split": self.baseline_split, **self.baselines}}
                if self.baselines
                else {}
            ),
        }


def derived_rate(time_s: FloatArray, angle_rad: FloatArray) -> FloatArray:
    """d(angle)/dt where no rate is logged: `signals.adaptive_derivative` with the angle's own
    noise and resolution as its measurement model."""
    return adaptive_derivative(time_s, angle_rad, deriv=1)


def _stretches(time_s: FloatArray) -> list[tuple[int, int]]:
    return stretches(time_s)


def _check_rate(name: str, time: FloatArray, logged: FloatArray, angle: FloatArray) -> None:
    """A logged rate must be the angle's in its units and sign: over 1 s windows in which the
    angle moves by more than 0.1 rad (a quantized angle's steps, 1.5 deg on a RAV4, stay far
    below), the rate's integral against the angle's change, as a least-squares gain, within
    0.5..2 (deg/s make it 57, a flipped sign -1); not judged with fewer than 5 such windows."""
    window = 1.0
    starts = np.searchsorted(time, np.arange(time[0], time[-1] - window, window / 2))
    ends = np.searchsorted(time, time[starts] + window)
    ends = np.minimum(ends, len(time) - 1)
    integral = np.concatenate(([0.0], np.cumsum(0.5 * (logged[1:] + logged[:-1]) * np.diff(time))))
    moved = angle[ends] - angle[starts]
    turned = integral[ends] - integral[starts]
    use = np.abs(moved) > 0.1
    if use.sum() < 5:
        return
    gain = float(np.sum(turned[use] * moved[use]) / np.sum(moved[use] ** 2))
    if 0.5 < gain < 2.0:
        return
    hint = (
        "it looks like deg/s: give its unit (deg/s) in the channel map, or convert to rad/s"
        if 35.0 < gain < 90.0
        else "steering_angle_rad looks like degrees: convert it to radians"
        if 1 / 90 < gain < 1 / 35
        else "its sign is the opposite of the angle's: negate it (scale = -1.0 in the map)"
        if -2.0 < gain < -0.5
        else "check its unit and that it is this angle's rate (or leave it out: the rate is "
        "then the angle's derivative)"
    )
    raise InputError(
        f"{name}: steering_rate_rad_s turns the wheel {gain:.3g} times as far as "
        f"steering_angle_rad says (about 1 expected): {hint}"
    )


def _logged_rate(time_s: FloatArray, rate_rad_s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """A logged rate as it is when its measurement error (noise and resolution) is under
    RATE_NOISE_RAD_S, else smoothed by `signals.adaptive_derivative` with that error: a coarse
    rate channel (the RAV4's 1 deg/s steps) is its stairs' mean, quick steers keep their edges.
    Measured earlier with a fixed 20 Hz low-pass: with 0.3 deg/s of noise K5's bias went from
    +62 % to +2 % and K8's from +17 % to +4 %; with 0.05 deg/s the noise biases less than any
    smoothing would. Returns the rate and its error at each sample."""
    error = measurement_sigma(rate_rad_s)
    if error <= RATE_NOISE_RAD_S:
        return rate_rad_s, np.full(len(rate_rad_s), error)
    return adaptive_estimate(time_s, rate_rad_s, deriv=0)


def transient_ay(
    time_s: FloatArray, speed_m_s: FloatArray, angle_rad: FloatArray, vehicle: VehicleParams
) -> FloatArray:
    """Ay (m/s^2) of the transient single-track car driven by the logged speed and angle, from
    its steady state at the start of each gap-free stretch (the model's own `step`)."""
    from carfeel.models.vehicle import single_track as st

    ay = np.empty_like(speed_m_s)
    for a, b in _stretches(time_s):
        state = st.steady_state(float(speed_m_s[a]), float(angle_rad[a]), vehicle)
        ay[a] = state.lateral_accel_m_s2
        dts = np.diff(time_s[a:b]).tolist()
        speeds = speed_m_s[a + 1 : b].tolist()
        angles = angle_rad[a + 1 : b].tolist()
        step, inputs = st.step, st.VehicleInputs
        for i, (dt, v, delta) in enumerate(zip(dts, speeds, angles, strict=True)):
            state, out = step(state, inputs(v, delta), vehicle, dt)
            ay[a + 1 + i] = out.lateral_accel_m_s2
    return ay


def read_log(result: Result, name: str) -> SteeringLog:
    """Check a log's columns, units and samples; condition the regressors (module docstring) and
    derive the rate when missing. `torque_Nm` (what `carfeel simulate steering` writes) stands
    for steering_torque_Nm when that is absent."""
    if "steering_torque_Nm" not in result.names and "torque_Nm" in result.names:
        result = Result(
            result.time_s,
            {
                ("steering_torque_Nm" if k == "torque_Nm" else k): v
                for k, v in result.signals.items()
            },
            result.metadata,
        )
    missing = [c for c in REQUIRED if c not in result.names]
    if missing:
        raise InputError(
            f"{name}: missing column(s) {', '.join(missing)}; a steering log needs "
            f"{', '.join(REQUIRED)} (s, m/s, rad, Nm), and may have lateral_accel_m_s2 and "
            "steering_rate_rad_s"
        )
    columns = [*REQUIRED] + [
        c for c in ("lateral_accel_m_s2", "steering_rate_rad_s") if c in result.names
    ]
    for column in columns:
        values = result[column]
        if values.dtype.kind != "f":
            raise InputError(f"{name}: column {column} must hold numbers")
    time = result.time_s
    if len(time) < 50:
        raise InputError(
            f"{name}: {count(len(time), 'sample')}; a fit or a validation needs 50 at least"
        )
    if np.any(np.diff(time) <= 0):
        row = int(np.flatnonzero(np.diff(time) <= 0)[0]) + 3
        raise InputError(f"{name}, line {row}: time_s does not increase")
    period = float(np.median(np.diff(time)))
    if period > MAX_SAMPLE_PERIOD_S:
        raise InputError(
            f"{name}: a sample every {period:.3g} s; the fit needs at least "
            f"{1 / MAX_SAMPLE_PERIOD_S:.0f} Hz. If time_s is in milliseconds, divide it by 1000"
        )
    keep = np.ones(len(time), dtype=bool)
    for column in columns:
        keep &= np.isfinite(result[column])
    if keep.sum() < 0.5 * len(time):
        raise InputError(f"{name}: more than half of the rows hold NaN; check the logger")
    angle = result["steering_angle_rad"][keep]
    speed = result["speed_m_s"][keep]
    torque = result["steering_torque_Nm"][keep]
    if np.max(np.abs(angle)) > 20.0:
        raise InputError(
            f"{name}: steering_angle_rad reaches {np.max(np.abs(angle)):.4g}: that looks like "
            "degrees; convert to radians"
        )
    if np.max(np.abs(speed)) > 100.0:
        raise InputError(
            f"{name}: speed_m_s reaches {np.max(np.abs(speed)):.4g}: that looks like km/h; "
            "divide by 3.6"
        )
    check_torque_logged(name, "steering_torque_Nm", torque)
    if "lateral_accel_m_s2" in result.names:
        flat = result["lateral_accel_m_s2"][keep]
        if len(flat) > 1 and np.ptp(flat) == 0.0 and np.any(np.abs(speed) > 5.0):
            raise InputError(
                f"{name}: lateral_accel_m_s2 is {float(flat[0]):.4g} m/s^2 in every row while the "
                "car drives: the channel logged nothing (or it is the wrong signal); fix it, or "
                "leave the column out and the base car's model gives Ay"
            )
    if np.max(np.abs(torque)) > 200.0:
        raise InputError(
            f"{name}: steering_torque_Nm reaches {np.max(np.abs(torque)):.4g}: check the units "
            "(Nm at the steering wheel)"
        )
    t = time[keep]
    rate, rate_error = (
        _logged_rate(t, result["steering_rate_rad_s"][keep])
        if "steering_rate_rad_s" in result.names
        else adaptive_estimate(t, angle, deriv=1)
    )
    if "steering_rate_rad_s" in result.names:
        _check_rate(name, t, result["steering_rate_rad_s"][keep], angle)
    ay = (
        lowpass(t, result["lateral_accel_m_s2"][keep], CUTOFF_HZ["lateral_accel_m_s2"])
        if "lateral_accel_m_s2" in result.names
        else None
    )
    speed = lowpass(t, speed, CUTOFF_HZ["speed_m_s"])
    if ay is not None:  # a sign convention, judged on any car: the steering's sign is the test
        problem = opposite_sign_problem(
            name, ay_angle_correlation(t, speed, angle, ay, _nominal_vehicle())
        )
        if problem:
            raise InputError(problem)
    return SteeringLog(
        name,
        t,
        speed,
        angle,
        rate,
        torque,
        ay,
        "steering_rate_rad_s" in result.names,
        rate_error,
    )


@functools.cache
def _nominal_vehicle() -> VehicleParams:
    """The car the sign check's steady-state Ay comes from before any preset is chosen (the
    sign of a steady state does not depend on the car)."""
    from carfeel.io.presets import load_steering

    return load_steering("b-segment").params.vehicle


def steady_ay(
    speed: FloatArray, angle: FloatArray, ratio: float, k_us: float, wheelbase: float
) -> FloatArray:
    """Steady-state lateral acceleration (m/s^2) of a car at `speed` (m/s) with the steering
    wheel at `angle` (rad, + left): V^2 * (angle / SR) / (L * (1 + K_us / L * V^2))."""
    v2 = speed * speed
    return np.asarray(v2 * (angle / ratio) / (wheelbase * (1.0 + k_us / wheelbase * v2)))


@dataclass(frozen=True)
class Regressors:
    """What a law is evaluated on, sample by sample over the concatenated logs: speed (m/s),
    rate (rad/s), Ay (m/s^2), and for a law with memory the angle each sample's step turned
    (|rate| dt, rad) and where a gap-free stretch starts (memory from rest)."""

    speed: FloatArray
    rate: FloatArray
    ay: FloatArray
    turned: FloatArray
    starts: BoolArray


@dataclass(frozen=True)
class LawModel:
    """A torque law as the fit sees it: parameter names and bounds, the torque and its Jacobian
    in the parameters over `Regressors`, its slope in Ay (for the understeer gradient), and the
    parameters as a preset's."""

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    torque: Callable[[FloatArray, Regressors], FloatArray]
    jacobian: Callable[[FloatArray, Regressors], FloatArray]
    d_torque_d_ay: Callable[[FloatArray, FloatArray], FloatArray]
    params: Callable[[FloatArray], SteeringTorqueParams]


def _law(x: FloatArray) -> SteeringTorqueParams:
    return SteeringTorqueParams(*(float(v) for v in x[: len(K_NAMES)]))


def friction_memory(
    regressors: Regressors, k11_rad: float, sensitivity: bool = False
) -> tuple[FloatArray, FloatArray | None]:
    """The law's friction memory z at every sample (`torque.friction_memory_step` run over the
    samples, from 0 at each stretch's start), and with `sensitivity` dz/dK11 (its own
    recurrence), both by `signals.linear_recurrence`."""
    sign = np.sign(regressors.rate)
    log_decay = np.where(regressors.starts, -np.inf, -regressors.turned / k11_rad)
    decay = np.exp(log_decay)
    z = linear_recurrence(log_decay, np.where(regressors.starts, 0.0, (1.0 - decay) * sign))
    if not sensitivity:
        return z, None
    before = np.concatenate([[0.0], z[:-1]])
    drive = np.where(regressors.starts, 0.0,
                     (before - sign) * decay * regressors.turned / k11_rad**2)  # fmt: skip
    return z, linear_recurrence(log_decay, drive)


def _paper_torque(x: FloatArray, r: Regressors) -> FloatArray:
    law = _law(x)
    torque = np.asarray(torque_terms(r.speed, r.rate, r.ay, law, atan=np.arctan)[0])
    if law.k10_Nm != 0.0:
        torque = torque + law.k10_Nm * friction_memory(r, law.k11_rad)[0]
    return torque


def _paper_jacobian(x: FloatArray, r: Regressors) -> FloatArray:
    """d torque / d (K1..K11), one column each."""
    k1, k2, k3, k4, k5, k6, k7, k8, _, k10, k11 = (float(v) for v in x[: len(K_NAMES)])
    speed, rate, ay = r.speed, r.rate, r.ay
    abs_ay = np.abs(ay)
    power = np.where(abs_ay > 0.0, abs_ay**k3, 0.0)
    log_ay = np.where(abs_ay > 0.0, np.log(np.where(abs_ay > 0.0, abs_ay, 1.0)), 0.0)
    d = 1.0 + k2 * power
    spin_atan = np.arctan(rate / k6)
    e = k4 + k5 * np.abs(speed)
    z, dz = friction_memory(r, k11, sensitivity=k10 != 0.0)
    return np.column_stack([
        ay / d,
        -k1 * ay * power / d**2,
        -k1 * ay * k2 * power * log_ay / d**2,
        -spin_atan / e**2,
        -np.abs(speed) * spin_atan / e**2,
        (1.0 / e) / (1.0 + (rate / k6) ** 2) * (-rate / k6**2),
        np.arctan(rate / k8),
        k7 / (1.0 + (rate / k8) ** 2) * (-rate / k8**2),
        rate,
        z,
        k10 * dz if dz is not None else np.zeros_like(z),
    ])  # fmt: skip


def _paper_d_ay(x: FloatArray, ay: FloatArray) -> FloatArray:
    k1, k2, k3 = (float(v) for v in x[:3])
    power = np.abs(ay) ** k3
    return np.asarray(k1 * (1.0 + k2 * (1.0 - k3) * power) / (1.0 + k2 * power) ** 2)


PAPER_LAW = LawModel(K_NAMES, LOWER, UPPER, _paper_torque, _paper_jacobian, _paper_d_ay, _law)
"""Eqs. (4)-(7) of the paper, with the friction's memory (K10, K11; `torque`)."""
MEMORY = (K_NAMES.index("k10_Nm"), K_NAMES.index("k11_rad"))


def offset_basis(time_s: FloatArray, drift_s: float | None) -> FloatArray:
    """Columns of a log's torque offset: one constant, or with `drift_s` hat functions on knots
    about `drift_s` apart (a piecewise-linear offset through the log)."""
    span = float(time_s[-1] - time_s[0])
    if drift_s is None or span < 1.5 * drift_s:
        return np.ones((len(time_s), 1))
    knots = np.linspace(time_s[0], time_s[-1], math.ceil(span / drift_s) + 1)
    return np.column_stack(
        [np.interp(time_s, knots, np.eye(len(knots))[k]) for k in range(len(knots))]
    )


@dataclass
class _Data:
    """The logs concatenated (`parts` of them), with each log's regressors as cubic splines of
    its own time for shifting them by a delay."""

    tau: FloatArray
    speed: FloatArray
    rate: FloatArray
    ay: FloatArray
    torque: FloatArray
    offsets: FloatArray
    parts: list[slice]
    blocks: npt.NDArray[np.intp]
    local: list[FloatArray]
    """Each log's own time from its first sample, s."""
    steps: FloatArray
    """Each sample's step from the one before (0 where a stretch starts)."""
    starts: BoolArray
    rate_error: FloatArray
    """Each sample's rate error (one sigma, rad/s; 0 where not known)."""
    ay_bias: FloatArray
    """The measured Ay's bias, a nuisance: one column over the logs with a measured Ay (none
    when they do not reach the law's saturation, SATURATION_AY_M_S2)."""
    _splines_by: dict[tuple[int, int], Any] = dataclasses.field(default_factory=dict)
    _cache: dict[float, Regressors] = dataclasses.field(default_factory=dict)

    def regressors(self, delay_s: float = 0.0) -> Regressors:
        """The regressors at t - delay_s (held at each log's first sample before it): cubic
        convolution (Catmull-Rom: C1 in the delay) on uniformly sampled logs, cubic splines on
        the others."""
        found = self._cache.get(delay_s)
        if found is not None:
            return found
        if delay_s == 0.0:
            speed, rate, ay = self.speed, self.rate, self.ay
        else:
            speed, rate, ay = (np.empty_like(self.speed) for _ in range(3))
            for k, (t, part) in enumerate(zip(self.local, self.parts, strict=True)):
                for c, (out, values) in enumerate(zip((speed, rate, ay),
                                                      (self.speed, self.rate, self.ay),
                                                      strict=True)):  # fmt: skip
                    out[part] = self._shifted((k, c), t, values[part], delay_s)
        found = Regressors(speed, rate, ay, np.abs(rate) * self.steps, self.starts)
        if len(self._cache) > 4:
            self._cache.clear()
        self._cache[delay_s] = found
        return found

    def _shifted(
        self, key: tuple[int, int], t: FloatArray, values: FloatArray, delay_s: float
    ) -> FloatArray:
        """One log's (key: log, signal) values at t - delay_s."""
        dt = (t[-1] - t[0]) / max(len(t) - 1, 1)
        if len(t) > 3 and np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-9):
            return cubic_shift(values, delay_s / dt)
        from scipy.interpolate import CubicSpline

        # By log and signal, never by id(values): `values` is a fresh slice whose id a later
        # slice of another signal reuses (a gap's log was fitted with its speed's spline as Ay).
        spline = self._splines_by.get(key)
        if spline is None:
            spline = self._splines_by[key] = CubicSpline(t, values)
        return np.asarray(spline(np.clip(t - delay_s, 0.0, t[-1])))


def cubic_shift(values: FloatArray, samples: float) -> FloatArray:
    """values(k - samples) by Catmull-Rom cubic convolution (the samples held beyond the ends):
    exact for cubics' samples, continuous with a continuous derivative in `samples`."""
    n = len(values)
    whole = math.floor(samples)
    u = 1.0 - (samples - whole) if samples != whole else 0.0
    base = np.arange(n) - whole - (1 if u > 0.0 else 0)
    taps = [values[np.clip(base + j, 0, n - 1)] for j in (-1, 0, 1, 2)]
    u2, u3 = u * u, u * u * u
    weights = (0.5 * (-u + 2.0 * u2 - u3), 0.5 * (2.0 - 5.0 * u2 + 3.0 * u3),
               0.5 * (u + 4.0 * u2 - 3.0 * u3), 0.5 * (-u2 + u3))  # fmt: skip
    return np.asarray(sum(w * tap for w, tap in zip(weights, taps, strict=True)))


def law_inputs(log: SteeringLog, ay: FloatArray, delay_s: float = 0.0) -> Regressors:
    """One log's regressors as the fit evaluates the law on them, shifted by `delay_s`."""
    return _data([log], [ay], None).regressors(delay_s)


def block_length(logs: Sequence[SteeringLog], parameters: int) -> float:
    """The sandwich's block (s): BLOCK_S, shorter (to MIN_BLOCK_S) where the logs hold fewer than
    BLOCKS_PER_PARAMETER blocks for each parameter: with about as many blocks as parameters the
    meat is nearly singular and its small-sample factor n_b / (n_b - p) runs away (15 on half a
    minute of a highway drive), and the keep rule's test then keeps anything."""
    span = sum(float(log.time_s[-1] - log.time_s[0]) for log in logs)
    wanted = span / (BLOCKS_PER_PARAMETER * max(parameters, 1))
    return float(min(BLOCK_S, max(MIN_BLOCK_S, wanted)))


def _data(
    logs: Sequence[SteeringLog], ays: Sequence[FloatArray], drift_s: float | None,
    block_s: float = BLOCK_S,
) -> _Data:  # fmt: skip
    taus, parts, bases, blocks, local, steps, starts = [], [], [], [], [], [], []
    start, first, block0 = 0.0, 0, 0
    for log in logs:
        t = log.time_s - log.time_s[0]
        local.append(t)
        taus.append(t + start)
        start += float(t[-1]) + 1e3
        parts.append(slice(first, first + len(t)))
        first += len(t)
        bases.append(offset_basis(log.time_s, drift_s))
        block = (t // block_s).astype(np.intp)
        blocks.append(block + block0)
        block0 += int(block[-1]) + 1
        step = np.diff(t, prepend=t[0])
        begins = np.zeros(len(t), dtype=bool)
        for a, _ in stretches(log.time_s):
            begins[a] = True
        steps.append(np.where(begins, 0.0, step))
        starts.append(begins)
    offsets = np.zeros((first, sum(b.shape[1] for b in bases)))
    column = 0
    for part, basis in zip(parts, bases, strict=True):
        offsets[part, column : column + basis.shape[1]] = basis
        column += basis.shape[1]
    # One bias for the logs' Ay sensor (a test's IMU and its mounting): the law's saturation
    # is what tells it from the torque offsets, so only where the logs reach it; a bias per log
    # wandered with its offset on a parking log (no Ay: the two are one).
    measured = [i for i, log in enumerate(logs) if log.lateral_accel_m_s2 is not None]
    ay_all = np.concatenate(ays)
    reach = len(measured) > 0 and float(np.percentile(np.abs(ay_all), 99)) >= SATURATION_AY_M_S2
    ay_bias = np.zeros((first, 1 if reach else 0))
    for i in measured if reach else []:
        ay_bias[parts[i], 0] = 1.0
    return _Data(
        np.concatenate(taus),
        np.concatenate([log.speed_m_s for log in logs]),
        np.concatenate([log.rate_rad_s for log in logs]),
        np.concatenate(ays),
        np.concatenate([log.torque_Nm for log in logs]),
        offsets, parts, np.concatenate(blocks), local, np.concatenate(steps),
        np.concatenate(starts),
        np.concatenate([log.rate_error_rad_s if log.rate_error_rad_s is not None
                        else np.zeros(len(log.time_s)) for log in logs]),
        ay_bias,
    )  # fmt: skip


@dataclass
class _Problem:
    """The full parameter vector x = [law, (K_us), delay, torque offsets, Ay biases] and what
    it predicts."""

    data: _Data
    law: LawModel
    k_us: float | None
    """The understeer gradient Ay was simulated at (fitting K_us), else None."""
    wheelbase: float
    base_x: FloatArray
    lower: FloatArray
    upper: FloatArray
    evaluations: list[int]
    progress: Callable[[int, float], None] | None
    weights: FloatArray | None = None
    """Each residual's weight: 1 / sqrt(1 + (dtau/drate * rate error / scale)^2), the rate's
    errors in variables (`eiv_weights`); None: all 1."""

    @property
    def n_law(self) -> int:
        return len(self.law.names)

    @property
    def delay_index(self) -> int:
        return self.n_law + (1 if self.k_us is not None else 0)

    @property
    def offset_slice(self) -> slice:
        start = self.delay_index + 1
        return slice(start, start + self.data.offsets.shape[1])

    @property
    def bias_slice(self) -> slice:
        return slice(self.offset_slice.stop, None)

    def regressors(self, x: FloatArray, delay_s: float | None = None) -> Regressors:
        """The regressors at the delay (x's, or `delay_s`), the measured Ay less its bias."""
        r = self.data.regressors(float(x[self.delay_index]) if delay_s is None else delay_s)
        if self.data.ay_bias.shape[1]:
            r = dataclasses.replace(r, ay=r.ay - self.data.ay_bias @ x[self.bias_slice])
        if self.k_us is None:
            return r
        gain = (1.0 + self.k_us / self.wheelbase * r.speed**2) / (
            1.0 + x[self.n_law] / self.wheelbase * r.speed**2
        )
        return dataclasses.replace(r, ay=r.ay * gain)

    def law_torque(self, x: FloatArray, delay_s: float | None = None) -> FloatArray:
        return self.law.torque(x[: self.n_law], self.regressors(x, delay_s))

    def model(self, x: FloatArray) -> FloatArray:
        """Model torque, offsets included."""
        offsets = self.data.offsets @ x[self.offset_slice]
        return np.asarray(self.law_torque(x) + offsets)

    def residual(self, x: FloatArray) -> FloatArray:
        """(model - measured), weighted."""
        r = np.asarray(self.model(x) - self.data.torque)
        return r if self.weights is None else r * self.weights

    def weighted_jacobian(self, x: FloatArray, free: BoolArray) -> FloatArray:
        jac = self.jacobian(x, free)
        return jac if self.weights is None else jac * self.weights[:, None]

    def jacobian(self, x: FloatArray, free: BoolArray) -> FloatArray:
        """d model / d x over the free entries."""
        n_law, di = self.n_law, self.delay_index
        r = self.regressors(x)
        columns = [self.law.jacobian(x[:n_law], r)]
        if self.k_us is not None:
            speed = r.speed
            ku = float(x[n_law])
            slope = self.law.d_torque_d_ay(x[:n_law], r.ay)
            stability = speed**2 / self.wheelbase
            columns.append((slope * (-r.ay * stability / (1.0 + ku * stability)))[:, None])
        if free[di]:
            d = float(x[di])
            up = self.law_torque(x, d + DELAY_STEP_S)
            down = self.law_torque(x, d - DELAY_STEP_S)
            columns.append(((up - down) / (2.0 * DELAY_STEP_S))[:, None])
        else:
            columns.append(np.zeros((len(r.speed), 1)))
        columns.append(self.data.offsets)
        if self.data.ay_bias.shape[1]:  # Ay - bias: the aligning term's slope, negated
            slope = self.law.d_torque_d_ay(x[:n_law], r.ay)
            columns.append(-slope[:, None] * self.data.ay_bias)
        return np.hstack(columns)[:, free]


@dataclass(frozen=True)
class _Fit(keep.Fitted):
    """One robust least-squares fit of the free entries, at the soft_l1 scale `scale`."""

    scale: float = 1.0
    residual: FloatArray = dataclasses.field(default_factory=lambda: np.zeros(0))
    """Weighted (what the fit minimizes); `raw` is model - measured."""
    raw: FloatArray = dataclasses.field(default_factory=lambda: np.zeros(0))
    unconstrained: BoolArray = dataclasses.field(default_factory=lambda: np.zeros(0, bool))
    active: npt.NDArray[np.int_] = dataclasses.field(default_factory=lambda: np.zeros(0, int))


def _robust_scale(r: FloatArray) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def soft_l1_cost(r: FloatArray, scale: float) -> float:
    """scipy's soft_l1 cost at `scale`: sum s^2 (sqrt(1 + (r/s)^2) - 1), about half the sum of
    squares for residuals within the scale."""
    return float(np.sum(scale * scale * (np.sqrt(1.0 + (r / scale) ** 2) - 1.0)))


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
        scale = _robust_scale(residual(z0)) or 0.1
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


def minimize_delay(cost: Callable[[float], float]) -> float:
    """The delay (s) of least `cost`: a grid of 21 over +-MAX_DELAY_S, then a bounded search
    within a grid step of its best point (kept only where it does better)."""
    from scipy.optimize import minimize_scalar

    grid = np.linspace(-MAX_DELAY_S, MAX_DELAY_S, 21)
    best = float(grid[int(np.argmin([cost(float(d)) for d in grid]))])
    step = float(grid[1] - grid[0])
    found = minimize_scalar(
        cost, bounds=(max(best - step, -MAX_DELAY_S), min(best + step, MAX_DELAY_S)),
        method="bounded", options={"xatol": 1e-4},
    )  # fmt: skip
    return float(found.x) if found.fun <= cost(best) else best


def _scan_delay(pb: _Problem, x: FloatArray) -> float:
    """The torque's delay (s) that fits best with the rest of x held: a grid over
    +-MAX_DELAY_S, then a bounded search around its best point; the soft_l1 cost."""
    scale = _robust_scale(pb.residual(x)) or 0.1
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
    scale = _robust_scale(fitted.residual) or fitted.scale
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
    unit_warnings = _check_units(logs, vehicle)
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
    free_idx = np.flatnonzero(final.free)
    cov = final.covariance
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    with np.errstate(invalid="ignore"):  # unconstrained: inf / inf, no correlation to give
        corr = cov / np.outer(d, d)
    shown = [j for j, i in enumerate(free_idx) if i < di]
    correlation = (
        tuple(names[free_idx[j]] for j in shown),
        tuple(tuple(round(float(corr[a, b]), 4) for b in shown) for a in shown),
    )
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
        log_rms, log_r2 = rms_r2(data.torque[part], data.torque[part] + r[part])
        per_log[log.name] = {
            "rms_error_Nm": log_rms,
            "r2": log_r2,
            "mean_residual_Nm": float(np.mean(r[part])),
            "samples": float(len(log.time_s)),
            "offset_Nm": float(np.mean(offset_values[part])),
            "offset_range_Nm": float(np.ptp(offset_values[part])),
            "offset_end_Nm": float(offset_values[part][-1]),
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


QUASI_STEADY_AY_M_S2 = (1.0, 6.0)
"""|Ay| range of the quasi-steady samples the unit checks compare (V > 5 m/s, |rate| < 0.2
rad/s)."""
MAX_MODEL_AY_G = 2.5
"""The base car's Ay from a log's speed and angle beyond this (99th percentile, at speed) is not a
car's: no road tyre holds 2.5 g, and an angle in degrees makes any Ay over 0.045 g exceed it."""


def ay_ratio(
    speed: FloatArray, angle: FloatArray, rate: FloatArray, ay: FloatArray,
    vehicle: VehicleParams,
) -> float | None:  # fmt: skip
    """Median of a measured Ay over the car's steady-state Ay from speed and angle, on the
    quasi-steady samples (None with fewer than 50 of them): about 1 for a log in SI units and a
    car like `vehicle`, 1/57 for an angle in degrees."""
    model = steady_ay(
        speed, angle, vehicle.steering_ratio, vehicle.understeer_gradient_rad_s2_m,
        vehicle.wheelbase_m,
    )  # fmt: skip
    low, high = QUASI_STEADY_AY_M_S2
    usable = (speed > 5.0) & (np.abs(rate) < 0.2) & (np.abs(ay) > low) & (np.abs(ay) < high)
    usable &= np.abs(model) > 0.1
    if usable.sum() < 50:
        return None
    return float(np.median(ay[usable] / model[usable]))


def ay_gain(speed: FloatArray, angle: FloatArray, ay: FloatArray, vehicle: VehicleParams) -> float:
    """The least-squares gain of a measured Ay on the car's steady-state Ay from speed and angle,
    over the samples at speed with |Ay| > 0.5 m/s^2 (NaN without any): for any manoeuvre, not
    only quasi-steady ones (a weave's lag takes a few % off it), so a coarse check of units."""
    model = steady_ay(
        speed, angle, vehicle.steering_ratio, vehicle.understeer_gradient_rad_s2_m,
        vehicle.wheelbase_m,
    )  # fmt: skip
    use = (speed > 5.0) & (np.abs(ay) > 0.5)
    power = float(np.sum(model[use] ** 2))
    return float(np.sum(ay[use] * model[use]) / power) if power > 0.0 else math.nan


SIGN_SMOOTHING_S = 0.5
"""Ay and the angle are averaged over this long before their correlation is taken (a real Ay
channel's noise and the car's vibration swamp a highway's small steering)."""
OPPOSITE_SIGN_CORRELATION = -0.5
"""A measured Ay this anti-correlated with the steady-state Ay from the steering angle turns the
other way from the wheel: a sign convention, not a car (a real car's is +0.8 or more on a log
with steering in it; -0.82 on the RAV4's CAN log read with Ay + to the right)."""


def ay_angle_correlation(
    time: FloatArray, speed: FloatArray, angle: FloatArray, ay: FloatArray,
    vehicle: VehicleParams,
) -> float | None:  # fmt: skip
    """Correlation of a measured Ay with the steady-state Ay from speed and angle, both averaged
    over SIGN_SMOOTHING_S, on the samples at speed (V > 5 m/s); None with under 10 s of them or
    no steering to speak of (the averaged angle's spread under 0.05 deg)."""
    if len(time) < 3:
        return None
    dt = float(np.median(np.diff(time)))
    if not dt > 0.0:
        return None
    n = max(1, round(SIGN_SMOOTHING_S / dt))
    window = np.ones(n) / n
    model = steady_ay(
        speed, angle, vehicle.steering_ratio, vehicle.understeer_gradient_rad_s2_m,
        vehicle.wheelbase_m,
    )  # fmt: skip
    smooth_model = np.convolve(model, window, mode="same")
    smooth_ay = np.convolve(ay, window, mode="same")
    smooth_angle = np.convolve(angle, window, mode="same")
    use = speed > 5.0
    use[: n // 2 + 1] = False  # the averages' edges
    use[len(use) - n // 2 - 1 :] = False
    if use.sum() * dt < 10.0 or np.std(smooth_angle[use]) < math.radians(0.05):
        return None
    if np.std(smooth_ay[use]) == 0.0 or np.std(smooth_model[use]) == 0.0:
        return None
    return float(np.corrcoef(smooth_ay[use], smooth_model[use])[0, 1])


def opposite_sign_problem(name: str, correlation: float | None) -> str | None:
    """The refusal of a log whose Ay turns the other way from its steering angle, or None."""
    if correlation is None or correlation > OPPOSITE_SIGN_CORRELATION:
        return None
    return (
        f"{name}: lateral_accel_m_s2 turns the other way from steering_angle_rad (their "
        f"correlation at speed is {correlation:.2f}; a car's is about +0.8 or more): carfeel takes "
        "both + to the left; negate the one that is + to the right (scale = -1.0 in the channel "
        "map, or flip the column)"
    )


def looks_like_degrees(factor: float) -> bool:
    """A measured Ay this many times the steady state from the angle: the angle in degrees."""
    return 1 / 90 < factor < 1 / 35


def _check_units(logs: Sequence[SteeringLog], vehicle: VehicleParams) -> list[str]:
    """Catch a log in the wrong units or sign, which would fit to a good r2 and a wrong preset;
    return warnings for what only looks suspicious. Each log is judged alone (one bad log among
    good ones would otherwise pass) and named.

    The angle must stay within the base car's lock (a weave in degrees reaches 11.5 "rad").
    On quasi-steady samples (V > 5 m/s, |rate| < 0.2 rad/s, 1 < |Ay| < 6 m/s^2): a measured Ay
    must agree with the base car's steady state within a factor of 4 (a car's SR and K_us do not
    stray further; degrees make it 1/57), with a warning beyond a factor of 1.6; without a
    measured Ay, the steady state from speed and angle must stay under MAX_MODEL_AY_G (degrees
    make it 57 times a car's); and the torque must mostly share Ay's sign (the aligning torque
    the driver holds, + with + Ay: a sign test, which a log turning one way at constant Ay still
    passes). km/h read as m/s cannot be told from Ay at speed (understeer flattens Ay(V): at 100
    km/h it makes 0.53x), so speeds beyond 250 km/h get a warning too."""
    warnings = []
    for log in logs:
        name, speed, angle, torque = log.name, log.speed_m_s, log.angle_rad, log.torque_Nm
        top = float(np.max(speed))
        if top > 70.0:
            warnings.append(
                f"{name}: speed_m_s reaches {top:.4g} m/s ({top * 3.6:.4g} km/h): if it is in "
                "km/h, divide it by 3.6 and fit again"
            )
        widest = float(np.max(np.abs(angle)))
        lock = vehicle.steering_lock_rad
        if widest > 1.05 * lock:
            raise InputError(
                f"{name}: steering_angle_rad reaches {widest:.4g}, beyond the base car's lock of "
                f"{lock:.4g} rad ({math.degrees(lock):.0f} deg): that looks like degrees (convert "
                "to radians); for a car with a wider lock, give --base a preset of it"
            )
        ay_model = steady_ay(
            speed, angle, vehicle.steering_ratio, vehicle.understeer_gradient_rad_s2_m,
            vehicle.wheelbase_m,
        )  # fmt: skip
        measured = log.lateral_accel_m_s2
        if measured is None and np.any(speed > 5.0):
            peak_g = float(np.percentile(np.abs(ay_model[speed > 5.0]), 99)) / 9.80665
            if peak_g > MAX_MODEL_AY_G:
                hint = (
                    "steering_angle_rad looks like degrees (convert it to radians)"
                    if peak_g / math.degrees(1.0) < 1.5
                    else "check the units of steering_angle_rad (rad at the wheel) and speed_m_s "
                    "(m/s), or give --base a preset with this car's steering ratio"
                )
                raise InputError(
                    f"{name}: without a lateral_accel_m_s2 column Ay comes from the base car, and "
                    f"with this speed and steering angle it reaches {peak_g:.3g} g, beyond what "
                    f"any car holds: {hint}"
                )
        ay = measured if measured is not None else ay_model
        low, high = QUASI_STEADY_AY_M_S2
        steady = (speed > 5.0) & (np.abs(log.rate_rad_s) < 0.2) & (np.abs(ay) > low)
        steady &= np.abs(ay) < high
        if steady.sum() < 50:
            continue
        factor = (
            ay_ratio(speed, angle, log.rate_rad_s, measured, vehicle)
            if measured is not None
            else None
        )
        if factor is not None:
            if not 0.25 < factor < 4.0:
                hint = (
                    "steering_angle_rad looks like degrees (convert to radians)"
                    if looks_like_degrees(factor)
                    else "check the units of steering_angle_rad (rad at the wheel), speed_m_s "
                    "(m/s, not km/h) and lateral_accel_m_s2 (m/s^2, not g), and the sign of Ay; "
                    "for a car far from the base preset, give --base a preset with its "
                    "steering ratio, wheelbase and understeer"
                )
                raise InputError(
                    f"{name}: the measured lateral_accel_m_s2 is {factor:.3g} times the base "
                    f"car's steady-state Ay from speed and angle (expected about 1): {hint}"
                )
            if not 1 / 1.6 < factor < 1.6:
                warnings.append(
                    f"{name}: the measured Ay is {factor:.3g} times the base car's steady state "
                    "from speed and angle: check the units of speed_m_s and steering_angle_rad, "
                    "or start from a base preset with this car's steering ratio and understeer"
                )
        held = torque[steady] != 0.0
        if held.mean() < 0.5:
            raise InputError(
                f"{name}: steering_torque_Nm is exactly 0 in {1 - held.mean():.0%} of the steady "
                "cornering, where a driver holds the aligning torque: a channel that logged "
                "nothing (or the wrong signal); check the column"
            )
        agree = float(np.mean(np.sign(torque[steady][held]) == np.sign(ay[steady][held])))
        if agree < 0.2:
            raise InputError(
                f"{name}: steering_torque_Nm has the opposite sign of Ay in {1 - agree:.0%} of the "
                "steady cornering; carfeel's convention is + torque with + Ay (the driver holds "
                "the aligning torque): flip the sign of steering_torque_Nm (or of the angle and Ay)"
            )
    return warnings


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
    for e in estimates:
        if e.status == "fitted" and e.value > 0 and e.sigma > 0.5 * abs(e.value):
            warnings.append(
                f"{e.name} = {e.value:.3g} +- {e.sigma:.2g}: the data pin it down poorly"
            )
    return warnings
