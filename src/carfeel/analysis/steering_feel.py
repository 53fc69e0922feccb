"""Steering feel metrics from any run or log (after ISO 13674-1's on-centre measures).

From the samples of speed V, steering wheel angle delta_w, lateral acceleration Ay and steering
torque T (signs: positive to the left), with Ay in g (9.80665 m/s^2):

- The loop T(Ay) is split into its two branches by the sign of dAy/dt (Ay rising, Ay falling),
  taken from Ay low-passed at 1.5 Hz without phase shift, so noise in a log does not mix them.
  On each branch a cubic is fitted on centre, |Ay| <= 0.12 g (a line if the branch spans less
  than 0.15 g there).
- torque_gradient_Nm_per_g: the mean of the two branches' slopes at 0 g.
- hysteresis_Nm ("torque at 0 g"): half the gap between the branches at Ay = 0.
- deadband_g ("Ay at 0 torque"): half the gap between the branches at T = 0.
- torque_at_0_1g_Nm: the branches' torque at +0.1 g and -0.1 g, averaged over both branches and
  both sides (sign taken out), where the branch reaches beyond 0.1 g both ways.
- sensitivity_g_per_100deg: the slope of Ay against delta_w on centre, fitted on each branch and
  averaged, per 100 deg (one fit through both branches would be biased low by the car's lag).
- understeer_gradient_deg_per_g: the slope K_us of delta_w/SR - L*Ay/V^2 against Ay (steady-state
  cornering, delta = L/R + K_us*Ay), over quasi-steady samples: V > 5 m/s, |Ay| <= 4 m/s^2,
  |dAy/dt| <= 0.5 m/s^3 and a steering rate within 0.1 rad/s (both low-passed as above), for at
  least 0.25 s on end; it needs the car's steering ratio SR and wheelbase L. It is a steady-state
  measure: ISO 4138 and slow weaves give it; a transient manoeuvre mostly does not.
A metric the data cannot give (no on-centre samples, a single branch, no speed) is NaN, with a note
saying why. The on-centre metrics (all but the understeer gradient) are what ISO 13674-1 measures
in a weave: a sinusoidal steer at a steady speed. A run that is not one (a lane change, a step, a
drive) gives numbers for them that mean something else (the lane change's loop is a transient's,
not the on-centre hysteresis), so they are NaN with a note unless `is_weave` holds: at least two
cycles of steering at one frequency between 0.05 and 1 Hz holding most (70 %) of the steering's
variance, at a speed steady within 10 %.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np
import numpy.typing as npt

from carfeel.models.vehicle.single_track import STANDARD_GRAVITY_M_S2
from carfeel.simulation.result import Result

G = STANDARD_GRAVITY_M_S2
ON_CENTRE_G = 0.1
FIT_G = 0.12
BRANCH_CUTOFF_HZ = 1.5
QUASI_STEADY_M_S3 = 0.5
QUASI_STEADY_RAD_S = 0.1
QUASI_STEADY_HOLD_S = 0.25
MIN_SAMPLES = 10
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SteeringFeel:
    torque_gradient_Nm_per_g: float
    torque_at_0_1g_Nm: float
    deadband_g: float
    hysteresis_Nm: float
    sensitivity_g_per_100deg: float
    understeer_gradient_deg_per_g: float
    notes: tuple[str, ...] = field(default=())

    def as_dict(self) -> dict[str, float]:
        """The six metrics by name (NaN as None is left to the JSON writer)."""
        values = asdict(self)
        values.pop("notes")
        return values


LABELS = {
    "torque_gradient_Nm_per_g": ("torque gradient at 0 g", "Nm/g"),
    "torque_at_0_1g_Nm": ("torque at 0.1 g", "Nm"),
    "deadband_g": ("torque deadband", "g"),
    "hysteresis_Nm": ("torque hysteresis (at 0 g)", "Nm"),
    "sensitivity_g_per_100deg": ("steering sensitivity", "g/100 deg"),
    "understeer_gradient_deg_per_g": ("understeer gradient", "deg/g"),
}
"""Each metric's name for people, and its unit."""


MIN_AY_SPREAD_M_S2 = 1.5
"""The least spread of quasi-steady Ay (5th to 95th percentile) the understeer gradient is taken
over: ISO 4138 fits it over a sweep of steady states, and below about 0.15 g a real Ay channel's
offset and noise, a lane-keeping system's corrections and the road's camber set the slope (a
RAV4's highway CAN log, Ay within 0.1 g, gave -4.5 deg/g for a car that understeers)."""


def _line(x: FloatArray, y: FloatArray) -> tuple[float, float]:
    """Least-squares (slope, intercept) of y against x."""
    slope, intercept = np.polyfit(x, y, 1)
    return float(slope), float(intercept)


def smoothed_rate(values: FloatArray, time_s: FloatArray) -> FloatArray:
    """d(values)/dt after a zero-phase 2nd-order Butterworth low-pass at BRANCH_CUTOFF_HZ."""
    from scipy.signal import butter, sosfiltfilt

    rate_hz = 1.0 / float(np.median(np.diff(time_s)))
    smooth = values
    if rate_hz > 4 * BRANCH_CUTOFF_HZ and len(values) > 30:
        sos = butter(2, BRANCH_CUTOFF_HZ, fs=rate_hz, output="sos")
        smooth = sosfiltfilt(sos, values)
    return np.asarray(np.gradient(smooth, time_s), dtype=float)


@dataclass(frozen=True)
class _Branch:
    coefficients: npt.NDArray[np.float64]
    """Polynomial in Ay_g, highest power first (numpy.polyval order)."""
    reaches_0_1g: bool

    def at(self, ay_g: float) -> float:
        return float(np.polyval(self.coefficients, ay_g))

    def slope_at_zero(self) -> float:
        return float(self.coefficients[-2])

    def zero_torque_g(self) -> float:
        """Ay (g) where this branch's torque is zero, by Newton from the linear guess."""
        derivative = np.polyder(self.coefficients)
        slope = float(np.polyval(derivative, 0.0))
        ay = -self.at(0.0) / slope if slope != 0.0 else math.nan
        for _ in range(20):
            d = float(np.polyval(derivative, ay))
            if not math.isfinite(ay) or d == 0.0:
                return math.nan
            ay -= self.at(ay) / d
        return ay


def _fit_branch(ay_g: FloatArray, torque: FloatArray, sel: npt.NDArray[np.bool_]) -> _Branch | None:
    window = sel & (np.abs(ay_g) <= FIT_G)
    if window.sum() < MIN_SAMPLES or np.ptp(ay_g[window]) < 0.05:
        return None
    degree = 3 if np.ptp(ay_g[window]) >= 0.15 else 1
    coefficients = np.polyfit(ay_g[window], torque[window], degree)
    reaches = bool(ay_g[sel].max() >= ON_CENTRE_G and ay_g[sel].min() <= -ON_CENTRE_G)
    return _Branch(coefficients, reaches)


def _lasting(
    flags: npt.NDArray[np.bool_], time_s: FloatArray, hold_s: float
) -> npt.NDArray[np.bool_]:
    """Flags kept only in runs of True that last at least `hold_s`."""
    out = np.zeros_like(flags)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flags.astype(np.int8), [0]])))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if time_s[stop - 1] - time_s[start] >= hold_s:
            out[start:stop] = True
    return out


WEAVE_PURITY = 0.7
WEAVE_BAND_HZ = (0.05, 1.0)
WEAVE_SPEED_SPREAD = 0.1


def is_weave(
    time_s: FloatArray, speed_m_s: FloatArray, steering_angle_rad: FloatArray
) -> tuple[bool, str]:
    """Whether a run is a weave (see the module docstring), and if not, why not."""
    angle = steering_angle_rad - float(np.mean(steering_angle_rad))
    duration = float(time_s[-1] - time_s[0]) if len(time_s) > 1 else 0.0
    if len(angle) < 4 * MIN_SAMPLES or duration <= 0.0 or not np.any(angle):
        return False, "too short or no steering"
    # Resample evenly (logs have jitter) and look at the spectrum of the steering angle.
    even = np.linspace(time_s[0], time_s[-1], min(len(time_s), 20_000))
    values = np.interp(even, time_s, angle)
    power = np.abs(np.fft.rfft(values * np.hanning(len(values)))) ** 2
    freqs = np.fft.rfftfreq(len(values), even[1] - even[0])
    peak = int(np.argmax(power[1:]) + 1)
    around = power[max(1, peak - 2) : peak + 3].sum()
    purity = float(around / power[1:].sum())
    # Cycles actually steered: alternations between beyond +30 % and beyond -30 % of the peak.
    edge = 0.3 * float(np.max(np.abs(angle)))
    sides = np.sign(angle[np.abs(angle) > edge])
    cycles = 0.5 * (1 + int(np.count_nonzero(np.diff(sides)))) if len(sides) else 0.0
    speed = speed_m_s[np.isfinite(speed_m_s)]
    spread = float(np.std(speed) / np.mean(speed)) if len(speed) and np.mean(speed) > 0 else 1.0
    low, high = WEAVE_BAND_HZ
    if not low <= freqs[peak] <= high:
        return False, f"its steering is dominated by {freqs[peak]:.3g} Hz, not a weave's 0.05-1 Hz"
    if cycles < 2.0:
        return False, f"{cycles:.1f} steering cycles, a weave has two at least"
    if purity < WEAVE_PURITY:
        return False, f"only {purity:.0%} of its steering is at one frequency (a weave: 70 %)"
    if spread > WEAVE_SPEED_SPREAD:
        return False, f"its speed varies by {spread:.0%} (a weave holds it within 10 %)"
    return True, ""


def steering_feel(
    time_s: FloatArray,
    speed_m_s: FloatArray,
    steering_angle_rad: FloatArray,
    lateral_accel_m_s2: FloatArray,
    torque_Nm: FloatArray,
    *,
    steering_ratio: float | None = None,
    wheelbase_m: float | None = None,
) -> SteeringFeel:
    """The six feel metrics of a run or log (see the module docstring for definitions)."""
    notes: list[str] = []
    nan = math.nan
    ay_g = lateral_accel_m_s2 / G
    moving = speed_m_s > 1.0
    ay_rate = smoothed_rate(lateral_accel_m_s2, time_s)
    branches = [moving & (ay_rate > 0.0), moving & (ay_rate < 0.0)]
    fits = [f for f in (_fit_branch(ay_g, torque_Nm, b) for b in branches) if f is not None]
    if len(fits) == 2:
        gradient = float(np.mean([f.slope_at_zero() for f in fits]))
        hysteresis = abs(fits[0].at(0.0) - fits[1].at(0.0)) / 2
        deadband = abs(fits[0].zero_torque_g() - fits[1].zero_torque_g()) / 2
    elif len(fits) == 1:
        gradient, hysteresis, deadband = fits[0].slope_at_zero(), nan, nan
        notes.append("Ay crosses the centre one way only: no hysteresis or deadband")
    else:
        gradient = hysteresis = deadband = nan
        notes.append(
            "too few on-centre samples (|Ay| <= 0.12 g, V > 1 m/s) for the torque gradient"
        )
    at_01 = [
        side * f.at(side * ON_CENTRE_G) for f in fits if f.reaches_0_1g for side in (1.0, -1.0)
    ]
    torque_01 = float(np.mean(at_01)) if at_01 else nan
    if not at_01:
        notes.append("Ay does not sweep through +-0.1 g on a branch: no torque at 0.1 g")

    gains = []
    for branch in branches:
        sel = branch & (np.abs(ay_g) <= ON_CENTRE_G)
        if sel.sum() >= MIN_SAMPLES and np.ptp(steering_angle_rad[sel]) > 0.0:
            gains.append(_line(np.degrees(steering_angle_rad[sel]), ay_g[sel])[0] * 100.0)
    sensitivity = float(np.mean(gains)) if gains else nan
    if not gains:
        notes.append("no on-centre steering to measure the sensitivity from")

    understeer = nan
    if steering_ratio is None or wheelbase_m is None:
        notes.append("understeer gradient needs the car's steering ratio and wheelbase")
    else:
        steering_rate = smoothed_rate(steering_angle_rad, time_s)
        steady = (np.abs(ay_rate) <= QUASI_STEADY_M_S3) & (
            np.abs(steering_rate) <= QUASI_STEADY_RAD_S
        )
        sel = (
            (speed_m_s > 5.0)
            & (np.abs(lateral_accel_m_s2) <= 4.0)
            & _lasting(steady, time_s, QUASI_STEADY_HOLD_S)
        )
        spread = (
            float(np.subtract(*np.percentile(lateral_accel_m_s2[sel], [95, 5])))
            if sel.any()
            else 0.0
        )
        if sel.sum() >= MIN_SAMPLES and spread >= MIN_AY_SPREAD_M_S2:
            ay = lateral_accel_m_s2[sel]
            beyond_ackermann = (
                steering_angle_rad[sel] / steering_ratio - wheelbase_m * ay / speed_m_s[sel] ** 2
            )
            k_us, _ = _line(ay, beyond_ackermann)
            understeer = math.degrees(k_us) * G
        else:
            notes.append(
                "too little quasi-steady cornering (V > 5 m/s, |dAy/dt| <= 0.5 m/s^3, steering "
                f"rate <= 0.1 rad/s) for the understeer gradient: its Ay spans {spread:.2g} "
                f"m/s^2 (5th to 95th percentile), under the {MIN_AY_SPREAD_M_S2:g} m/s^2 "
                "(0.15 g) it needs (ISO 4138 sweeps the steady states)"
            )
    weave, why = is_weave(time_s, speed_m_s, steering_angle_rad)
    if not weave and any(math.isfinite(v) for v in (gradient, torque_01, deadband, hysteresis,
                                                       sensitivity)):  # fmt: skip
        gradient = torque_01 = deadband = hysteresis = sensitivity = nan
        notes.append(
            f"on-centre metrics (torque gradient, torque at 0.1 g, deadband, hysteresis, "
            f"sensitivity) are ISO 13674-1's, measured in a weave; this run is not one ({why})"
        )
    return SteeringFeel(
        gradient, torque_01, deadband, hysteresis, sensitivity, understeer, tuple(notes)
    )


def feel_lines(feel: SteeringFeel) -> list[str]:
    """The metrics as a summary's lines (label, value and unit; n/a where NaN), then the notes."""
    lines = []
    for key, value in feel.as_dict().items():
        label, unit = LABELS[key]
        shown = "n/a" if math.isnan(value) else f"{value:.3g} {unit}"
        lines.append(f"  {label:28s} {shown}")
    lines.extend(f"  note: {note}" for note in feel.notes)
    return lines


def feel_of(
    result: Result, steering_ratio: float | None, wheelbase_m: float | None
) -> SteeringFeel:
    """`steering_feel` of a run or log read into a Result (its time_s, speed_m_s,
    steering_angle_rad, lateral_accel_m_s2 and torque_Nm)."""
    return steering_feel(
        result.time_s,
        result["speed_m_s"],
        result["steering_angle_rad"],
        result["lateral_accel_m_s2"],
        result["torque_Nm"],
        steering_ratio=steering_ratio,
        wheelbase_m=wheelbase_m,
    )
