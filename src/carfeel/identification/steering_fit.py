"""Fit the steering torque law (K1..K9 of eqs. 4-7) to measured logs by robust least squares.

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
  rate    as logged when its noise is under 0.1 deg/s (a low-pass rounds off the edges of quick
          steers and moves K5..K9 by 1-6 %, more than such noise does), at 20 Hz when noisier
          (`_logged_rate`); else a Savitzky-Golay derivative of the angle (quadratic, 81 ms) on
          each gap-free stretch. A coarse rate channel still biases the friction K7, K8 by a
          few %: ISO 4138's slow ramps keep the rate within a few K8 for minutes.
The filters run per gap-free stretch (forward and back: no phase lag).

The fit is `scipy.optimize.least_squares` with an analytic Jacobian, bounds that keep each term
physically signed (every K >= 0 and the scales > 0), and the robust 'soft_l1' loss. Beside
K1..K9 it fits nuisances that are reported, never written to a preset: a torque offset per log
(constant, or with `drift_s` a piecewise-linear one with knots that far apart: road crown, bank
and sensor drift wander along a drive), and one delay of the torque behind the other channels
(CAN messages arrive with their own latencies), applied by shifting the regressors, found by a
scan with the law held and the law refitted at it (`_scan_delay`).
Starting values come from the data: K1 from the slope of torque on Ay while the wheel barely
turns, K9 from the slope on the rate while it turns fast, the friction level from the rest, the
tyre-spin scale from parking (V < 2 m/s) if there is any.

What the logs cannot identify keeps the base preset's value and is marked so (status "kept"):
the tyre-spin terms K4..K6 without parking manoeuvres, the saturation K2, K3 without lateral
accelerations beyond 3 m/s^2, and, after a first pass, any parameter that stops at a bound, lies
within one sigma of one (the data cannot tell it from the bound) or in a direction the data do not
constrain. Nothing is written at a bound.

Uncertainties are a sandwich (M-estimator) covariance: the bread is the loss-weighted Gauss-Newton
matrix sum(rho'' J J^T), the meat sums the weighted scores sum(rho' r J) over blocks of BLOCK_S
seconds, so residuals correlated within a block (model error, a slow offset) count as the fewer
independent samples they are. The parameter correlations come from the same covariance.
Before the fit, logs whose units or signs would fit well but wrongly are refused or warned about
(`_check_units`); after it, r2 under 0.5 is warned about.
With `fit_vehicle` (and no measured Ay) the understeer gradient is fitted too (the speed steps of
a steady-state test separate it from K1), and the preset's rear cornering stiffness is set to give
it. The steering ratio is not fitted: in the linear range K1 * Ay ~ K1 / SR, so the two trade
exactly; take SR from the car's data.

The law is one `LawModel` (names, bounds, torque, Jacobian): another steering model can be served
by another instance without touching the fit's machinery.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification import rms_r2
from carfeel.identification.common import check_torque_logged
from carfeel.models.steering.torque import SteeringTorqueParams, torque_terms
from carfeel.models.vehicle.single_track import VehicleParams
from carfeel.simulation.result import Result
from carfeel.simulation.steering import SteeringCar
from carfeel.text import count

FloatArray = npt.NDArray[np.float64]
REQUIRED = ("time_s", "speed_m_s", "steering_angle_rad", "steering_torque_Nm")
K_NAMES = ("k1_Nm_s2_m", "k2", "k3", "k4_1_Nm", "k5_s_m_Nm", "k6_rad_s", "k7_Nm", "k8_rad_s",
           "k9_Nm_s_rad")  # fmt: skip
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
    "understeer_gradient_rad_s2_m": "the car's understeer gradient K_us (with --fit-vehicle), "
    "rad per m/s^2",
}
"""What each fitted parameter is (the paper's eqs. 4-7), for reports."""
LOWER = (1e-3, 0.0, 0.3, 1e-2, 0.0, 1e-2, 0.0, 1e-3, 0.0)
UPPER = (50.0, 10.0, 3.0, 100.0, 100.0, 10.0, 20.0, 5.0, 5.0)
SAVGOL_WINDOW_S = 0.081
CUTOFF_HZ = {"speed_m_s": 1.0, "lateral_accel_m_s2": 4.0}
"""Zero-phase low-pass corners of the regressors (see the module docstring)."""
RATE_NOISE_RAD_S = math.radians(0.1)
RATE_CUTOFF_HZ = 20.0
BLOCK_S = 2.0
"""Block length of the sandwich covariance: residuals of one manoeuvre phase hang together."""
MAX_DELAY_S = 0.25
MIN_DELAY_STEP_S = 0.0025
"""A scanned delay closer than this to the current one is not applied: below it the damping
K9 trades with the delay and the scan wanders (it found 1 ms on the benchmark's undelayed log)."""
PARKING_SPEED_M_S = 2.0
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
    """The rate is the log's own (as logged, or low-passed), not derived from the angle."""


@dataclass(frozen=True)
class Estimate:
    name: str
    value: float
    sigma: float
    """One standard deviation; NaN for a parameter kept from the base preset."""
    status: str = "fitted"
    """"fitted", or "kept": the base preset's value, which the logs cannot identify."""
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
    """Per log: rms_error_Nm, r2, mean residual (the bias left), samples, offset_Nm (mean) and
    offset_range_Nm (how far a drifting offset wandered)."""
    warnings: tuple[str, ...]
    iterations: int
    torque_delay_s: float = 0.0
    """How much later the torque was logged than the other channels (corrected in the fit)."""
    correlation: tuple[tuple[str, ...], tuple[tuple[float, ...], ...]] = ((), ())
    """(names, matrix) of the fitted parameters' correlations."""
    holdout: dict[str, dict[str, dict[str, float]]] = dataclasses.field(default_factory=dict)
    """With a held-out part: {"fit": figures per log, "held_out": figures per log}."""

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
            "correlation": {"parameters": list(names), "matrix": [list(r) for r in matrix]},
            "torque_offset_Nm": self.torque_offset_Nm,
            "torque_delay_s": self.torque_delay_s,
            "rms_error": self.rms_error_Nm,
            "rms_error_unit": "N m",
            "r2": self.r2,
            "per_log": self.per_log,
            "warnings": list(self.warnings),
            "iterations": self.iterations,
            **({"cross_validation": self.holdout} if self.holdout else {}),
        }


def savgol_rate(time_s: FloatArray, angle_rad: FloatArray) -> FloatArray:
    """d(angle)/dt by a quadratic Savitzky-Golay filter over about 81 ms, per gap-free stretch."""
    from scipy.signal import savgol_filter

    rate = np.zeros_like(angle_rad)
    dt = float(np.median(np.diff(time_s)))
    window = max(5, round(SAVGOL_WINDOW_S / dt) | 1)
    for a, b in _stretches(time_s):
        n = b - a
        if n >= window:
            rate[a:b] = savgol_filter(angle_rad[a:b], window, 2, deriv=1, delta=dt)
        elif n > 1:
            rate[a:b] = np.gradient(angle_rad[a:b], time_s[a:b])
    return rate


def _stretches(time_s: FloatArray) -> list[tuple[int, int]]:
    steps = np.diff(time_s)
    dt = float(np.median(steps))
    cuts = np.concatenate([[0], np.flatnonzero(steps > 1.5 * dt) + 1, [len(time_s)]])
    return [(int(a), int(b)) for a, b in itertools.pairwise(cuts)]


def lowpass(time_s: FloatArray, values: FloatArray, cutoff_hz: float) -> FloatArray:
    """Zero-phase 4th-order Butterworth low-pass (forward and back: 8th-order magnitude, 0.4 %
    down at half the corner), per gap-free stretch; the
    corner is kept under 40 % of the sample rate. Stretches too short to filter pass as they are."""
    from scipy.signal import butter, sosfiltfilt

    out = np.array(values, dtype=float, copy=True)
    dt = float(np.median(np.diff(time_s)))
    sos = butter(4, min(cutoff_hz, 0.4 / dt), fs=1.0 / dt, output="sos")
    for a, b in _stretches(time_s):
        if b - a > 30:
            out[a:b] = sosfiltfilt(sos, values[a:b])
    return out


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


def _logged_rate(time_s: FloatArray, rate_rad_s: FloatArray) -> FloatArray:
    """A logged rate, low-passed at RATE_CUTOFF_HZ only when its noise (from the MAD of its
    second differences: white noise gives 6 sigma^2 there) exceeds RATE_NOISE_RAD_S. Measured:
    with 0.3 deg/s of noise the filter takes K5's bias from +62 % to +2 % and K8's from +17 %
    to +4 % (at a cost of 3 % on K6 and K9, where quick steers lose their edges); with 0.05
    deg/s the noise biases less than that rounding would."""
    second = np.diff(rate_rad_s, 2)
    sigma = 1.4826 * float(np.median(np.abs(second - np.median(second)))) / math.sqrt(6.0)
    if sigma <= RATE_NOISE_RAD_S:
        return rate_rad_s
    return lowpass(time_s, rate_rad_s, RATE_CUTOFF_HZ)


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
    if np.max(np.abs(torque)) > 200.0:
        raise InputError(
            f"{name}: steering_torque_Nm reaches {np.max(np.abs(torque)):.4g}: check the units "
            "(Nm at the steering wheel)"
        )
    t = time[keep]
    rate = (
        _logged_rate(t, result["steering_rate_rad_s"][keep])
        if "steering_rate_rad_s" in result.names
        else savgol_rate(t, angle)
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
        name, t, speed, angle, rate, torque, ay, "steering_rate_rad_s" in result.names
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
class LawModel:
    """A torque law as the fit sees it: parameter names and bounds, the torque, its Jacobian in
    the parameters and its slope in Ay (for the understeer gradient), over arrays."""

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    torque: Callable[[FloatArray, FloatArray, FloatArray, FloatArray], FloatArray]
    jacobian: Callable[[FloatArray, FloatArray, FloatArray, FloatArray], FloatArray]
    d_torque_d_ay: Callable[[FloatArray, FloatArray], FloatArray]
    params: Callable[[FloatArray], SteeringTorqueParams]


def _law(x: FloatArray) -> SteeringTorqueParams:
    return SteeringTorqueParams(*(float(v) for v in x[:9]))


def _paper_torque(x: FloatArray, speed: FloatArray, rate: FloatArray, ay: FloatArray) -> FloatArray:
    return np.asarray(torque_terms(speed, rate, ay, _law(x), atan=np.arctan)[0])


def _paper_jacobian(
    x: FloatArray, speed: FloatArray, rate: FloatArray, ay: FloatArray
) -> FloatArray:
    """d torque / d (K1..K9), one column each."""
    k1, k2, k3, k4, k5, k6, k7, k8 = (float(v) for v in x[:8])
    abs_ay = np.abs(ay)
    power = np.where(abs_ay > 0.0, abs_ay**k3, 0.0)
    log_ay = np.where(abs_ay > 0.0, np.log(np.where(abs_ay > 0.0, abs_ay, 1.0)), 0.0)
    d = 1.0 + k2 * power
    spin_atan = np.arctan(rate / k6)
    e = k4 + k5 * np.abs(speed)
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
    ])  # fmt: skip


def _paper_d_ay(x: FloatArray, ay: FloatArray) -> FloatArray:
    k1, k2, k3 = (float(v) for v in x[:3])
    power = np.abs(ay) ** k3
    return np.asarray(k1 * (1.0 + k2 * (1.0 - k3) * power) / (1.0 + k2 * power) ** 2)


PAPER_LAW = LawModel(K_NAMES, LOWER, UPPER, _paper_torque, _paper_jacobian, _paper_d_ay, _law)
"""Eqs. (4)-(7) of the paper."""


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
    """The logs concatenated, on a time axis `tau` where logs lie far apart (so one np.interp
    delays all of them without mixing them)."""

    tau: FloatArray
    speed: FloatArray
    rate: FloatArray
    ay: FloatArray
    torque: FloatArray
    offsets: FloatArray
    parts: list[slice]
    blocks: npt.NDArray[np.intp]

    def delayed(self, delay_s: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        if delay_s == 0.0:
            return self.speed, self.rate, self.ay
        t = self.tau - delay_s
        return tuple(np.interp(t, self.tau, v) for v in (self.speed, self.rate, self.ay))  # type: ignore[return-value]


def _data(logs: Sequence[SteeringLog], ays: Sequence[FloatArray], drift_s: float | None) -> _Data:
    taus, parts, bases, blocks = [], [], [], []
    start, first, block0 = 0.0, 0, 0
    for log in logs:
        t = log.time_s - log.time_s[0]
        taus.append(t + start)
        start += float(t[-1]) + 1e3
        parts.append(slice(first, first + len(t)))
        first += len(t)
        bases.append(offset_basis(log.time_s, drift_s))
        block = (t // BLOCK_S).astype(np.intp)
        blocks.append(block + block0)
        block0 += int(block[-1]) + 1
    offsets = np.zeros((first, sum(b.shape[1] for b in bases)))
    column = 0
    for part, basis in zip(parts, bases, strict=True):
        offsets[part, column : column + basis.shape[1]] = basis
        column += basis.shape[1]
    return _Data(
        np.concatenate(taus),
        np.concatenate([log.speed_m_s for log in logs]),
        np.concatenate([log.rate_rad_s for log in logs]),
        np.concatenate(ays),
        np.concatenate([log.torque_Nm for log in logs]),
        offsets, parts, np.concatenate(blocks),
    )  # fmt: skip


def fit_steering(
    logs: Sequence[SteeringLog],
    base: SteeringCar,
    *,
    fit_vehicle: bool = False,
    drift_s: float | None = None,
    estimate_delay: bool = True,
    law: LawModel = PAPER_LAW,
    progress: Callable[[int, float], None] | None = None,
) -> SteeringFit:
    """Fit K1..K9 (and the nuisances: offsets, a torque delay; with `fit_vehicle`, K_us) to the
    logs; what they cannot identify keeps the base's value."""
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
    if drift_s is not None and not drift_s > 0:
        raise InputError(f"--drift {drift_s:g}: the knot spacing must be a positive time in s")
    unit_warnings = _check_units(logs, vehicle)
    k_us = vehicle.understeer_gradient_rad_s2_m
    evaluations = [0]
    delay = 0.0
    warm: FloatArray | None = None
    passes = 2 if fit_vehicle else 1
    for _ in range(passes):  # with fit_vehicle: Ay simulated again at the fitted K_us
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
        data = _data(logs, ays, drift_s)
        ku = k_us if fit_vehicle else None
        result = _solve(data, base, law, ku, delay, evaluations, progress, warm)
        # The delay by a scan with the law fixed, then the law again at it (a joint fit stalled
        # on the kinks that interpolating sharp steers puts into the cost at each sample).
        period = min(float(np.median(np.diff(log.time_s))) for log in logs)
        for _ in range(4 if estimate_delay else 0):
            found = _scan_delay(data, law, result.x, ku, base.vehicle.wheelbase_m)
            if abs(found - delay) < max(0.5 * period, MIN_DELAY_STEP_S):
                break
            delay = found
            result = _solve(data, base, law, ku, delay, evaluations, progress, result.x)
        warm = result.x
        if fit_vehicle:
            k_us = result.x[len(law.names)]
    x, free, notes, covariance, r = (
        result.x,
        result.free,
        result.notes,
        result.covariance,
        result.residual,
    )
    names = [
        *law.names,
        *(["understeer_gradient_rad_s2_m"] if fit_vehicle else []),
        "torque_delay_s",
    ]
    n_law = len(law.names)
    sigma_all = np.full(len(x), math.nan)
    sigma_all[free] = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    estimates = tuple(
        Estimate(nm, float(x[i]), float(sigma_all[i]),
                 "fitted" if free[i] else "kept", notes.get(i, ""))
        for i, nm in enumerate(names)
        if nm != "torque_delay_s"
    )  # fmt: skip
    delay_index = len(names) - 1
    free_idx = np.flatnonzero(free)
    d = np.sqrt(np.clip(np.diag(covariance), 1e-300, None))
    corr = covariance / np.outer(d, d)
    shown = [j for j, i in enumerate(free_idx) if i < delay_index]
    correlation = (
        tuple(names[free_idx[j]] for j in shown),
        tuple(tuple(round(float(corr[a, b]), 4) for b in shown) for a in shown),
    )
    warnings = unit_warnings + _identifiability(estimates, notes)
    per_log: dict[str, dict[str, float]] = {}
    offset_values = data.offsets @ x[len(names) :]
    for log, part in zip(logs, data.parts, strict=True):
        log_rms, log_r2 = rms_r2(data.torque[part], data.torque[part] + r[part])
        per_log[log.name] = {
            "rms_error_Nm": log_rms,
            "r2": log_r2,
            "mean_residual_Nm": float(np.mean(r[part])),
            "samples": float(len(log.time_s)),
            "offset_Nm": float(np.mean(offset_values[part])),
            "offset_range_Nm": float(np.ptp(offset_values[part])),
        }
    rms, r2 = rms_r2(data.torque, data.torque + r)
    if not r2 > 0.5:
        warnings.append(
            f"r2 {r2:.3g}: the law explains little of the torque; check the logs' units, signs "
            "and columns before using this preset"
        )
    car = dataclasses.replace(base, torque=law.params(x[:n_law]))
    if fit_vehicle:
        car = dataclasses.replace(
            car, vehicle=vehicle_with(vehicle, vehicle.steering_ratio, float(x[n_law]))
        )
    return SteeringFit(
        car, estimates, float(np.mean(offset_values)), rms, r2, per_log, tuple(warnings),
        evaluations[0], float(x[delay_index]), correlation,
    )  # fmt: skip


@dataclass
class _Solution:
    x: FloatArray
    free: npt.NDArray[np.bool_]
    notes: dict[int, str]
    covariance: FloatArray
    residual: FloatArray


def _solve(
    data: _Data,
    base: SteeringCar,
    law: LawModel,
    k_us: float | None,
    delay_s: float,
    evaluations: list[int],
    progress: Callable[[int, float], None] | None,
    warm: FloatArray | None = None,
) -> _Solution:
    """Two passes: fit what the excitation can identify; then keep at the base's value what
    stopped at a bound or in an unconstrained direction, and fit again."""
    from scipy.optimize import least_squares

    n_law = len(law.names)
    fit_vehicle = k_us is not None
    vehicle = base.vehicle
    n_offsets = data.offsets.shape[1]
    base_x = np.array([getattr(base.torque, nm) for nm in law.names])
    k_us0 = vehicle.understeer_gradient_rad_s2_m
    head = [*base_x, *([k_us] if fit_vehicle else []), delay_s]
    lower = [*law.lower, *([0.0] if fit_vehicle else []), -MAX_DELAY_S, *[-5.0] * n_offsets]
    upper = [*law.upper, *([0.05] if fit_vehicle else []), MAX_DELAY_S, *[5.0] * n_offsets]
    delay_index = len(head) - 1
    n_all = len(head) + n_offsets
    free = np.ones(n_all, dtype=bool)
    free[delay_index] = False  # the delay is scanned outside (fit_steering)
    notes: dict[int, str] = {}
    wheelbase = vehicle.wheelbase_m

    def lateral(x: FloatArray, ay: FloatArray, speed: FloatArray) -> FloatArray:
        return _lateral(x, ay, speed, k_us, n_law, wheelbase)

    def model(x: FloatArray) -> FloatArray:
        return _predict(data, law, x, k_us, wheelbase)

    def full_jacobian(x: FloatArray) -> FloatArray:
        speed, rate, ay = data.delayed(float(x[delay_index]))
        lat = lateral(x, ay, speed)
        columns = [law.jacobian(x[:n_law], speed, rate, lat)]
        if fit_vehicle:
            ku = float(x[n_law])
            columns.append((law.d_torque_d_ay(x[:n_law], lat) * (-lat * (speed**2 / wheelbase)
                            / (1.0 + ku / wheelbase * speed**2)))[:, None])  # fmt: skip
        columns.append(np.zeros((len(speed), 1)))  # the delay: held, scanned outside
        columns.append(data.offsets)
        return np.hstack(columns)

    excitation = _kept_for_excitation(data.speed, data.rate, data.ay, law.names)
    for i, why in excitation.items():
        free[i], notes[i] = False, why
    x_all = np.array([*head, *[0.0] * n_offsets])
    start = _start(data.speed, data.rate, data.torque, lateral(x_all, data.ay, data.speed))
    for i in range(n_law):
        if free[i]:
            x_all[i] = start[i]
    if warm is not None:  # from a previous pass: only the held parameters may differ
        x_all[:n_law] = warm[:n_law]
        x_all[delay_index + 1 :] = warm[delay_index + 1 :]
    x_all = np.clip(x_all, np.array(lower) + 1e-9, np.array(upper) - 1e-9)
    for kept in np.flatnonzero(~free[:n_law]):
        x_all[kept] = base_x[kept]
    lo, hi = np.array(lower), np.array(upper)
    for attempt in range(3):
        idx = np.flatnonzero(free)

        def residual(z: FloatArray, idx: npt.NDArray[np.intp] = idx) -> FloatArray:
            evaluations[0] += 1
            x = x_all.copy()
            x[idx] = z
            r = np.asarray(model(x) - data.torque)
            if progress is not None:
                progress(evaluations[0], float(np.sqrt(np.mean(r * r))))
            return r

        def jacobian(z: FloatArray, idx: npt.NDArray[np.intp] = idx) -> FloatArray:
            x = x_all.copy()
            x[idx] = z
            return full_jacobian(x)[:, idx]

        z0 = np.clip(x_all[idx], lo[idx] + 1e-9, hi[idx] - 1e-9)
        first = residual(z0)
        scale = float(1.4826 * np.median(np.abs(first - np.median(first)))) or 0.1
        solution = least_squares(
            residual, z0, jac=jacobian, bounds=(lo[idx], hi[idx]), loss="soft_l1",
            f_scale=scale, x_scale="jac", max_nfev=200,
        )  # fmt: skip
        x_all[idx] = solution.x
        r = residual(solution.x)
        # The final pass's scale: the residuals' own robust spread.
        scale = float(1.4826 * np.median(np.abs(r - np.median(r)))) or scale
        covariance, unconstrained = _sandwich(jacobian(solution.x), r, scale, data.blocks)
        stuck: dict[int, str] = {}
        for j, i in enumerate(idx.tolist()):
            if i >= n_law + (1 if fit_vehicle else 0):
                continue
            if solution.active_mask[j] != 0:
                bound = lo[i] if solution.active_mask[j] < 0 else hi[i]
                stuck[int(i)] = (f"kept from the base preset: the fit stopped at the bound "
                                 f"{bound:g}, the logs cannot place it")  # fmt: skip
            elif unconstrained[j]:
                stuck[int(i)] = "kept from the base preset: the logs do not constrain it"
            else:
                # Within one sigma of a bound the logs cannot tell the value from the bound.
                sigma = math.sqrt(max(float(covariance[j, j]), 0.0))
                value = float(solution.x[j])
                near = lo[i] if value - lo[i] <= hi[i] - value else hi[i]
                if math.isfinite(near) and abs(value - near) < sigma:
                    stuck[int(i)] = (
                        f"kept from the base preset: the fit ({value:.3g} +- {sigma:.2g}) lies "
                        f"within one sigma of its bound {near:g}, the logs cannot place it"
                    )
        if not stuck or attempt == 2:
            break
        for i, why in stuck.items():
            free[i], notes[i] = False, why
            x_all[i] = base_x[i] if i < n_law else k_us0
    return _Solution(x_all, free, notes, covariance, r)


def _lateral(
    x: FloatArray, ay: FloatArray, speed: FloatArray, k_us: float | None, n_law: int,
    wheelbase: float,
) -> FloatArray:  # fmt: skip
    """Ay for the parameters x: as given, or (fitting K_us) simulated at `k_us` and scaled by
    the steady-state gain for x's K_us."""
    if k_us is None:
        return ay
    gain = (1.0 + k_us / wheelbase * speed**2) / (1.0 + x[n_law] / wheelbase * speed**2)
    return np.asarray(ay * gain)


def _predict(
    data: _Data, law: LawModel, x: FloatArray, k_us: float | None, wheelbase: float
) -> FloatArray:
    """Model torque (offsets included) for the full parameter vector x."""
    n_law = len(law.names)
    delay_index = n_law + (1 if k_us is not None else 0)
    speed, rate, ay = data.delayed(float(x[delay_index]))
    lat = _lateral(x, ay, speed, k_us, n_law, wheelbase)
    return np.asarray(law.torque(x[:n_law], speed, rate, lat) + data.offsets @ x[delay_index + 1 :])


def _scan_delay(
    data: _Data, law: LawModel, x: FloatArray, k_us: float | None, wheelbase: float
) -> float:
    """The torque's delay (s) that fits best with the rest of x held: a grid over
    +-MAX_DELAY_S, then a bounded search around its best point; the soft_l1 cost."""
    from scipy.optimize import minimize_scalar

    delay_index = len(law.names) + (1 if k_us is not None else 0)
    r0 = _predict(data, law, x, k_us, wheelbase) - data.torque
    scale = float(1.4826 * np.median(np.abs(r0 - np.median(r0)))) or 0.1

    def cost(delay: float) -> float:
        trial = x.copy()
        trial[delay_index] = delay
        z = ((_predict(data, law, trial, k_us, wheelbase) - data.torque) / scale) ** 2
        return float(np.mean(np.sqrt(1.0 + z)))

    grid = np.linspace(-MAX_DELAY_S, MAX_DELAY_S, 21)
    best = float(grid[int(np.argmin([cost(float(d)) for d in grid]))])
    step = float(grid[1] - grid[0])
    found = minimize_scalar(
        cost, bounds=(max(best - step, -MAX_DELAY_S), min(best + step, MAX_DELAY_S)),
        method="bounded", options={"xatol": 1e-4},
    )  # fmt: skip
    return float(found.x) if found.fun <= cost(best) else best


def _sandwich(
    jac: FloatArray, r: FloatArray, scale: float, blocks: npt.NDArray[np.intp]
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Covariance of a soft_l1 M-estimate: A^-1 B A^-1 with A = sum rho''(r) J J^T (the
    loss-weighted Gauss-Newton matrix) and B = sum over blocks of g g^T, g = sum rho'(r) r J in
    the block; times n_blocks / (n_blocks - p). Returns it and the parameters that lie in a
    direction the data do not constrain (infinite variance there)."""
    z = (r / scale) ** 2
    weight = 1.0 / np.sqrt(1.0 + z)  # rho'(z): the IRLS weight of soft_l1
    curvature = weight**3  # rho'(z) + 2 z rho''(z)
    norms = np.linalg.norm(jac, axis=0)
    norms[norms == 0.0] = 1.0
    js = jac / norms
    a = js.T @ (js * curvature[:, None])
    scores = js * (weight * r)[:, None]
    n_blocks = int(blocks.max()) + 1
    g = np.zeros((n_blocks, js.shape[1]))
    np.add.at(g, blocks, scores)
    p = js.shape[1]
    b = g.T @ g * (n_blocks / max(n_blocks - p, 1))
    u, s, vt = np.linalg.svd(a)
    weak = s < 1e-10 * s[0]
    inverse = (vt[~weak].T / s[~weak]) @ u[:, ~weak].T
    covariance = inverse @ b @ inverse.T / np.outer(norms, norms)
    unconstrained = (
        np.any(np.abs(vt[weak]) > 0.1, axis=0) if weak.any() else np.zeros(p, dtype=bool)
    )
    covariance[unconstrained, :] = math.inf
    covariance[:, unconstrained] = math.inf
    return covariance, unconstrained


def _kept_for_excitation(
    speed: FloatArray, rate: FloatArray, ay: FloatArray, names: Sequence[str]
) -> dict[int, str]:
    """Parameters the excitation cannot identify, by index, with the reason."""
    kept = {}
    parked = (speed < PARKING_SPEED_M_S) & (np.abs(rate) > 0.5)
    if names == K_NAMES and parked.mean() < 0.01:
        for i in (3, 4, 5):
            kept[i] = (
                "kept from the base preset: the logs have almost no parking manoeuvres "
                "(V < 2 m/s with the wheel turning); add a steer cycle at standstill"
            )
    if names == K_NAMES and np.percentile(np.abs(ay), 99) < 3.0:
        for i in (1, 2):
            kept[i] = (
                "kept from the base preset: Ay stays under 3 m/s^2; add a steady-state "
                "circle or a lane change"
            )
    return kept


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
    """Starting values from the data (see the module docstring)."""
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
    return np.array([k1, 0.1, 1.2, k4, 0.1, 0.5, max(k7, 0.05), 0.05, max(k9, 0.01), 0.0])


def _identifiability(estimates: Sequence[Estimate], notes: dict[int, str]) -> list[str]:
    warnings = []
    for reason in dict.fromkeys(notes.values()):
        kept = [e.name for e in estimates if e.note == reason]
        warnings.append(f"{', '.join(kept)} not identifiable, {reason}")
    for e in estimates:
        if e.status == "fitted" and e.value > 0 and e.sigma > 0.5 * abs(e.value):
            warnings.append(
                f"{e.name} = {e.value:.3g} +- {e.sigma:.2g}: the data pin it down poorly"
            )
    return warnings
