"""Reading a steering log for the fits (`read_log`): its columns, units and samples checked, its
regressors conditioned against errors in variables (the speed and a measured Ay low-passed, the
rate as logged, smoothed or derived; see `steering_fit`), and Ay simulated where not measured
(`transient_ay`)."""

from __future__ import annotations

import functools
import math

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification.common import check_torque_logged
from carfeel.identification.signals import (
    adaptive_derivative,
    adaptive_estimate,
    lowpass,
    measurement_sigma,
    stretches,
)
from carfeel.identification.steering_checks import ay_angle_correlation, opposite_sign_problem
from carfeel.identification.steering_types import SteeringLog
from carfeel.models.vehicle.single_track import VehicleParams
from carfeel.simulation.result import Result
from carfeel.text import count

FloatArray = npt.NDArray[np.float64]
REQUIRED = ("time_s", "speed_m_s", "steering_angle_rad", "steering_torque_Nm")
CUTOFF_HZ = {"speed_m_s": 1.0, "lateral_accel_m_s2": 4.0}
"""Zero-phase low-pass corners of the regressors (see `steering_fit`'s docstring)."""
RATE_NOISE_RAD_S = math.radians(0.1)
MAX_SAMPLE_PERIOD_S = 0.05
"""20 Hz: slower logs cannot show the friction and damping terms (and ms read as s land here)."""


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
    """Check a log's columns, units and samples; condition the regressors (`steering_fit`) and
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
