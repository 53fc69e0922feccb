"""Logs of a known car for fitting the physical steering model: manoeuvres that excite each
fitted parameter, simulated at 1 kHz with the physical model, logged at 200 Hz with the sensor
errors of an instrumented car (`tests/test_steering_fit.py` uses the same levels for the law).

The imposed steering is smooth (its rate continuous), as a hand's or a steering robot's with
an acceleration limit is: a rate that jumps (the library's steer cycle and ISO 7401 sine start
and stop at full rate) cannot be placed within a 5 ms sample, and the rack's 7 Hz ring after it
then differs by up to 0.5 Nm for 0.2 s, which says nothing about the parameters.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence

import numpy as np

from carfeel.identification import physical_fit
from carfeel.identification.steering_fit import SteeringLog, read_log
from carfeel.io.presets import load_steering
from carfeel.models.vehicle.single_track import steady_state_steering_wheel_angle
from carfeel.simulation import manoeuvres
from carfeel.simulation.manoeuvres import Manoeuvre, Segment
from carfeel.simulation.result import Result
from carfeel.simulation.steering import SteeringCar, simulate_steering

TRUE = {
    "assist_gain_standstill_1_Nm": 1.4,
    "assist_gain_high_speed_1_Nm": 0.15,
    "column_friction_Nm": 0.35,
    "rack_friction_Nm": 0.6,
    "eps_damping_high_speed_Nm_s_rad": 1.6,
    "pneumatic_trail_m": 0.034,
    "friction_coefficient": 0.9,
}
"""The logged car: the B-segment preset with these (its own: 1.8, 0.1, 0.25, 0.8, 1.9, 0.04,
1.0), so a fit that stays at the base cannot pass."""
NOISE = {"speed": 0.05, "angle_deg": 0.02, "torque": 0.05, "ay": 0.05, "rate_deg_s": 0.05}
"""Sensor noise (1 sigma), as in the law's acceptance: a measurement steering wheel (torque
0.05 Nm, encoder angle 0.02 deg, its rate 0.05 deg/s), GPS/IMU speed (0.05 m/s) and Ay."""
ANGLE_OFFSET_DEG, TORQUE_BIAS_NM, DIVIDER = 0.3, 0.05, 5  # 1 kHz model -> 200 Hz logs


def base_car() -> SteeringCar:
    return load_steering().params


def true_car() -> SteeringCar:
    return physical_fit.with_values(base_car(), [TRUE[n] for n in physical_fit.NAMES])


def _envelope(t: float, start: float, end: float, edge: float = 1.0) -> float:
    """0 outside [start, end], raised-cosine edges of `edge` s, 1 between."""
    if t <= start or t >= end:
        return 0.0
    if t < start + edge:
        return 0.5 * (1.0 - math.cos(math.pi * (t - start) / edge))
    if t > end - edge:
        return 0.5 * (1.0 - math.cos(math.pi * (end - t) / edge))
    return 1.0


def _smooth(angle: Callable[[float], float]) -> Callable[[float], tuple[float, float]]:
    """(angle, rate) with the rate by a central difference of 1 us (exact to about 1e-9)."""
    h = 1e-6
    return lambda t: (angle(t), (angle(t + h) - angle(t - h)) / (2.0 * h))


def sine(
    label: str, speed_kmh: float, amplitude_rad: float, frequency_hz: float, duration_s: float
) -> Manoeuvre:
    """A sine steer with 1 s raised-cosine edges, 0.5 s still at each end."""
    w = 2.0 * math.pi * frequency_hz
    v = speed_kmh / 3.6

    def angle(t: float) -> float:
        return amplitude_rad * math.sin(w * (t - 0.5)) * _envelope(t, 0.5, duration_s - 0.5)

    segment = Segment(label, duration_s, lambda t: v, steering=_smooth(angle))
    return Manoeuvre(label, f"{label}: smooth sine steer", (segment,))


def manoeuvre_set(car: SteeringCar) -> list[tuple[str, Manoeuvre, float]]:
    """(name, manoeuvre, seconds cut from its start): parking at 0 and 6 km/h (the assist at
    standstill, the frictions), the ISO 13674-1 weave (the trail, the assist at speed), a fast
    sine at 80 km/h (the EPS damping), ISO 3888 (all of them at once) and ISO 4138 driven to the
    limit on the left (mu; its first 14 s, under 0.35 g, left out)."""
    v = car.vehicle
    lock = v.steering_lock_rad
    fast = steady_state_steering_wheel_angle(80 / 3.6, 4.0, v)
    return [
        ("park-0kmh", sine("park-0kmh", 0.0, 0.85 * lock, 0.125, 10.0), 0.0),
        ("park-6kmh", sine("park-6kmh", 6.0, 0.85 * lock, 0.125, 10.0), 0.0),
        ("weave", manoeuvres.build("weave", v), 0.0),
        ("fast-sine-80kmh", sine("fast-sine-80kmh", 80.0, fast, 1.0, 8.0), 0.0),
        ("iso3888", manoeuvres.build("iso3888", v), 0.0),
        ("limit", manoeuvres.iso4138(v, max_lateral_accel_m_s2=10.0, ramp_s=1.0, hold_s=1.0,
                                     sides=("left",)), 14.0),
    ]  # fmt: skip


@functools.cache
def clean_runs(names: tuple[str, ...] | None = None) -> tuple[tuple[str, Result], ...]:
    """The true car's runs at 1 kHz (physical model), cut as `manoeuvre_set` says."""
    car = true_car()
    runs = []
    for name, manoeuvre, cut in manoeuvre_set(car):
        if names is not None and name not in names:
            continue
        full = simulate_steering(car, manoeuvre, model="physical")
        keep = full.time_s >= cut
        signals = {k: v[keep] for k, v in full.signals.items() if k != "segment"}
        runs.append((name, Result(full.time_s[keep], signals)))
    return tuple(runs)


def measured(
    runs: Sequence[tuple[str, Result]],
    seed: int = 0,
    *,
    noise: bool = True,
    rate: bool = True,
    with_ay: bool = True,
) -> list[SteeringLog]:
    """The runs as a logger gives them: 200 Hz, noise on every channel, an angle offset and a
    torque bias (with `noise`), a logged rate (with `rate`) and Ay (with `with_ay`)."""
    rng = np.random.default_rng(seed)
    on = 1.0 if noise else 0.0
    logs = []
    for name, r in runs:
        idx = np.arange(0, len(r), DIVIDER)
        n = idx.size

        def draw(sigma: float, n: int = n) -> np.ndarray:
            return on * rng.normal(0.0, sigma, n)

        signals = {
            "speed_m_s": r["speed_m_s"][idx] + draw(NOISE["speed"]),
            "steering_angle_rad": r["steering_angle_rad"][idx]
            + np.radians(on * ANGLE_OFFSET_DEG + draw(NOISE["angle_deg"])),
            "steering_torque_Nm": r["torque_Nm"][idx] + on * TORQUE_BIAS_NM + draw(NOISE["torque"]),
        }
        if rate:
            signals["steering_rate_rad_s"] = r["steering_rate_rad_s"][idx] + np.radians(
                draw(NOISE["rate_deg_s"])
            )
        if with_ay:
            signals["lateral_accel_m_s2"] = r["lateral_accel_m_s2"][idx] + draw(NOISE["ay"])
        logs.append(read_log(Result(r.time_s[idx], signals), name))
    return logs
