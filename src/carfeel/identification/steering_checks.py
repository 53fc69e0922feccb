"""Checks of a steering log's units and signs against a car's steady state: the mistakes that
would fit to a good r2 and a wrong preset (an angle in degrees, a flipped Ay or torque, km/h)
are refused with their fix, what only looks suspicious is warned about."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification.steering_types import SteeringLog
from carfeel.models.vehicle.single_track import VehicleParams

FloatArray = npt.NDArray[np.float64]


def steady_ay(
    speed: FloatArray, angle: FloatArray, ratio: float, k_us: float, wheelbase: float
) -> FloatArray:
    """Steady-state lateral acceleration (m/s^2) of a car at `speed` (m/s) with the steering
    wheel at `angle` (rad, + left): V^2 * (angle / SR) / (L * (1 + K_us / L * V^2))."""
    v2 = speed * speed
    return np.asarray(v2 * (angle / ratio) / (wheelbase * (1.0 + k_us / wheelbase * v2)))


def car_steady_ay(speed: FloatArray, angle: FloatArray, vehicle: VehicleParams) -> FloatArray:
    """`steady_ay` (m/s^2) of `vehicle`: its steering ratio, understeer gradient and wheelbase."""
    return steady_ay(
        speed, angle, vehicle.steering_ratio, vehicle.understeer_gradient_rad_s2_m,
        vehicle.wheelbase_m,
    )  # fmt: skip


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
    model = car_steady_ay(speed, angle, vehicle)
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
    model = car_steady_ay(speed, angle, vehicle)
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
    model = car_steady_ay(speed, angle, vehicle)
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


def check_units(logs: Sequence[SteeringLog], vehicle: VehicleParams) -> list[str]:
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
        ay_model = car_steady_ay(speed, angle, vehicle)
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
