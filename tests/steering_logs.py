"""Steering logs for the fit's acceptance tests (issue 25), made the way a real car's are: the
manoeuvres of `tests/test_steering_fit.py` driven by the true car, logged at 200 Hz with the
sensor faults a review found in real data. Shared by the tests and `benchmarks/bench_fit*.py`.

    golf_runs()      a law shape the preset does not have: torque = 3.0 Nm x (Ay / 1.375 +
                     0.202 tanh(rate / 0.05)), linear aligning and a friction step, no tyre spin
    hidden_runs()    the paper law with the tests' hidden K1..K9 (`TRUE`)
    faulty(...)      every fault of issue 25's point 2 at the stated level (FAULTS)
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from carfeel.identification.steering_fit import SteeringLog, read_log
from carfeel.io.presets import load_steering
from carfeel.simulation import manoeuvres
from carfeel.simulation.result import Result
from carfeel.simulation.steering import SteeringCar, simulate_steering

TRUE = dict(
    k1_Nm_s2_m=1.9, k2=0.25, k3=1.0, k4_1_Nm=0.5, k5_s_m_Nm=0.2, k6_rad_s=0.7, k7_Nm=0.6,
    k8_rad_s=0.08, k9_Nm_s_rad=0.12,
)  # fmt: skip
"""The hidden law (the same as tests/test_steering_fit.py's)."""
MANOEUVRES = ("weave", "steer-cycle", "iso4138", "iso7401-step", "iso3888")
"""The five ISO manoeuvres (ISO 4138 as its left and right circles)."""
EXTRA = (("steer-cycle", 6.0), ("iso7401-sweep", None))
"""What pins the tyre spin's speed term K5 and the damping K9 besides (a parking cycle at 6 km/h,
an ISO 7401 frequency sweep at 60 km/h), as in tests/test_steering_fit.excitation_runs."""
GOLF_GAIN_NM, GOLF_AY_M_S2, GOLF_FRICTION, GOLF_RATE_RAD_S = 3.0, 1.375, 0.202, 0.05
GOLF_K1 = GOLF_GAIN_NM / GOLF_AY_M_S2
"""2.18 Nm s^2/m: the Golf-like law's on-centre gradient, what K1 must find."""

FAULTS: dict[str, Any] = {
    "angle_resolution_deg": 0.1,  # the Lincoln MKZ's steering angle
    "angle_noise_deg": 0.02,
    "angle_offset_deg": 0.5,
    "speed_noise_m_s": 0.05,
    "speed_offset_m_s": 0.03,
    "ay_noise_m_s2": 0.05,
    "ay_offset_m_s2": 0.08,
    "torque_noise_Nm": 0.05,
    "torque_offset_Nm": 0.05,
    "torque_delay_s": 0.020,
}
"""Issue 25, point 2: a 0.1 deg angle resolution, 0.02 deg of noise before it, a 0.5 deg offset,
speed, Ay and torque noise and offsets, the torque logged 20 ms late, and no rate column."""
DIVIDER = 5
"""The 1 kHz simulation logged at 200 Hz."""


def golf_torque(rate_rad_s: Any, ay_m_s2: Any) -> Any:
    """The Golf-like law of issue 25 (Nm): linear aligning and a tanh friction step."""
    return GOLF_GAIN_NM * (
        ay_m_s2 / GOLF_AY_M_S2 + GOLF_FRICTION * np.tanh(rate_rad_s / GOLF_RATE_RAD_S)
    )


@functools.cache
def base_car() -> SteeringCar:
    return load_steering().params


@functools.cache
def hidden_car() -> SteeringCar:
    base = base_car()
    return dataclasses.replace(base, torque=dataclasses.replace(base.torque, **TRUE))


def _segments(car: SteeringCar, names: Sequence[str]) -> list[tuple[str, Result]]:
    runs = []
    for name in names:
        full = simulate_steering(car, manoeuvres.build(name, car.vehicle))
        for segment in dict.fromkeys(full["segment"].tolist()):  # ISO 4138: left, right
            keep = full["segment"] == segment
            runs.append((f"{name}-{segment}", Result(full.time_s[keep], {
                k: v[keep] for k, v in full.signals.items() if k != "segment"})))  # fmt: skip
    return runs


@functools.cache
def hidden_runs(names: tuple[str, ...] = MANOEUVRES) -> tuple[tuple[str, Result], ...]:
    """The manoeuvres driven by the hidden law's car (1 kHz, noise-free)."""
    return tuple(_segments(hidden_car(), names))


@functools.cache
def excitation_runs() -> tuple[tuple[str, Result], ...]:
    """hidden_runs and EXTRA: the acceptance set of the hidden-law case."""
    car = hidden_car()
    extra = []
    for name, kmh in EXTRA:
        full = simulate_steering(car, manoeuvres.build(name, car.vehicle, kmh))
        extra.append((f"{name}-{kmh or 60:g}kmh", Result(full.time_s, {
            k: v for k, v in full.signals.items() if k != "segment"})))  # fmt: skip
    return (*hidden_runs(), *extra)


@functools.cache
def smooth_runs() -> tuple[tuple[str, Result], ...]:
    """The hidden law's car through manoeuvres a hand or a steering robot with an acceleration
    limit steers (their rate continuous, as tests/physical_logs.py's): parking sines at 0 and
    6 km/h (the tyre spin K4..K6), the ISO 13674-1 weave, sines at 80 km/h (1 Hz: the damping
    K9) and 60 km/h (0.5 Hz), ISO 4138 both ways and ISO 3888 (the saturation K2, K3). The
    library's steer cycle and ISO 7401 step change the rate within one sample: no 200 Hz log
    can place that, and the misfit it leaves is the same on every drive, so it is bias the
    sandwich counts as noise (the friction's sigma came out 4 times its scatter over seeds)."""
    from tests.physical_logs import sine

    car = hidden_car()
    v = car.vehicle
    lock = v.steering_lock_rad
    built = [
        ("park-0kmh", sine("park-0kmh", 0.0, 0.85 * lock, 0.125, 10.0)),
        ("park-6kmh", sine("park-6kmh", 6.0, 0.85 * lock, 0.125, 10.0)),
        ("sine-80kmh", sine("sine-80kmh", 80.0, 0.6, 1.0, 8.0)),
        ("sine-60kmh", sine("sine-60kmh", 60.0, 1.2, 0.5, 10.0)),
    ]
    runs = [*_segments(car, ("weave", "iso4138", "iso3888"))]
    for name, manoeuvre in built:
        full = simulate_steering(car, manoeuvre)
        runs.append((name, Result(full.time_s, {
            k: values for k, values in full.signals.items() if k != "segment"})))  # fmt: skip
    return tuple(runs)


@functools.cache
def golf_runs(names: tuple[str, ...] = MANOEUVRES) -> tuple[tuple[str, Result], ...]:
    """The manoeuvres of the base car with the Golf-like law's torque (1 kHz, noise-free)."""
    runs = []
    for name, r in _segments(base_car(), names):
        torque = golf_torque(r["steering_rate_rad_s"], r["lateral_accel_m_s2"])
        runs.append((name, Result(r.time_s, {**r.signals, "torque_Nm": torque})))
    return tuple(runs)


def noisy(runs: Sequence[tuple[str, Result]], seed: int = 0) -> list[Result]:
    """The runs as a measurement rig logs them (tests/test_steering_fit.measured's noise):
    200 Hz, torque 0.05 Nm, angle 0.02 deg and a 0.3 deg offset, speed 0.05 m/s, Ay
    0.05 m/s^2, a 0.05 Nm torque bias; no rate column."""
    rng = np.random.default_rng(seed)
    out = []
    for _, r in runs:
        idx = np.arange(0, len(r), DIVIDER)
        n = idx.size
        out.append(Result(r.time_s[idx], {
            "speed_m_s": r["speed_m_s"][idx] + rng.normal(0, 0.05, n),
            "steering_angle_rad": r["steering_angle_rad"][idx]
            + np.radians(0.3 + rng.normal(0, 0.02, n)),
            "lateral_accel_m_s2": r["lateral_accel_m_s2"][idx] + rng.normal(0, 0.05, n),
            "steering_torque_Nm": r["torque_Nm"][idx] + 0.05 + rng.normal(0, 0.05, n),
        }))  # fmt: skip
    return out


def faulty(
    runs: Sequence[tuple[str, Result]], seed: int = 0, scale: float = 1.0,
    faults: dict[str, Any] | None = None,
) -> list[Result]:  # fmt: skip
    """The runs logged with every fault of FAULTS (noise levels times `scale`): the angle is
    the true one plus its offset and noise, then quantized to the resolution (an encoder counts
    what it sees); the torque is sampled `torque_delay_s` late; no rate column. Where the
    quantizer's steps fall against the true angle is a draw of the seed too (the offset's part
    within one step, uniform: no car's offset is a whole number of steps), so repeated seeds
    scatter as repeated drives would."""
    f = {**FAULTS, **(faults or {})}
    rng = np.random.default_rng(seed)
    out = []
    for _, r in runs:
        idx = np.arange(0, len(r), DIVIDER)
        n, t = idx.size, r.time_s[idx]
        step = math.radians(f["angle_resolution_deg"])
        phase = rng.uniform(-0.5, 0.5) * f["angle_resolution_deg"]
        angle = r["steering_angle_rad"][idx] + np.radians(
            f["angle_offset_deg"] + phase + rng.normal(0, scale * f["angle_noise_deg"], n)
        )
        if step > 0:
            angle = step * np.round(angle / step)
        late = np.interp(t - f["torque_delay_s"], r.time_s, r["torque_Nm"])
        out.append(Result(t, {
            "speed_m_s": r["speed_m_s"][idx] + f["speed_offset_m_s"]
            + rng.normal(0, scale * f["speed_noise_m_s"], n),
            "steering_angle_rad": angle,
            "lateral_accel_m_s2": r["lateral_accel_m_s2"][idx] + f["ay_offset_m_s2"]
            + rng.normal(0, scale * f["ay_noise_m_s2"], n),
            "steering_torque_Nm": late + f["torque_offset_Nm"]
            + rng.normal(0, scale * f["torque_noise_Nm"], n),
        }))  # fmt: skip
    return out


def as_logs(results: Sequence[Result], runs: Sequence[tuple[str, Result]]) -> list[SteeringLog]:
    """`read_log` of each result, named after its run."""
    return [read_log(r, name) for r, (name, _) in zip(results, runs, strict=True)]
