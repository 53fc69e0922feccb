"""Standard steering manoeuvres: generators of the speed and steering input over time.

Where the standard's text was not at hand, the choice is said here and in `Manoeuvre.description`.
Every manoeuvre starts from straight driving unless said otherwise.

- iso4138: ISO 4138 steady-state circular driving, constant-radius method. A path-following driver
  holds a circle (default R = 40 m, the paper's Fig. 1) while the speed steps up so that the
  steady-state Ay rises by 0.5 m/s^2 per step (0.5 .. 5 m/s^2; each step a 2 s speed ramp and a 3 s
  hold); once to the left (counter-clockwise) and once to the right, as two segments.
- iso4138-limit: the same circle driven to the limit of a dry road: steps up to 11 m/s^2 (1.1 g,
  beyond what the physical model's tyres give, so Ay saturates and the car drifts out), each a
  1 s ramp and a 2 s hold, left then right. With the paper's linear car Ay keeps rising.
- iso3888: ISO 3888-1 double lane change (default 80 km/h, the standard's test speed). Sections of
  15/30/25/25/15 m (+15 m run-out); lane widths 1.1b+0.25, 1.2b+0.25, 1.3b+0.25 m for car width b.
  Lateral offset of lane 3: its near (right) boundary lies 3.5 m left of lane 1's centre line, and
  lanes 1 and 5 share their right boundary: our reading of the standard's figure, the same as
  Project Chrono's ISO 3888 helper. The driver follows a smooth centre path (half-cosine
  transitions from a lane's exit to 3 m past the next lane's entry; the driver's preview starts the
  turn earlier, as a real driver does), from a 30 m run-up.
- iso7401-step / -sine / -sweep: ISO 7401 lateral transient response, default 60 km/h (the paper's
  Fig. 4). The amplitude is the steering wheel angle that gives Ay = 4 m/s^2 in steady state. Step:
  a half-cosine ramp over 0.2 s (10-90 % in 0.12 s, within the standard's 0.15 s) after 1 s
  straight, then 4 s held. Sine: one period at 0.5 Hz after 1 s straight, then 3 s straight.
  Sweep: a continuous sine whose frequency rises linearly from 0.1 to 2 Hz over 25 s.
- steer-cycle: the complete steer cycle at Vx = 0 of the paper's Fig. 2: lock to lock and back
  as one sine period of 12 s (0.5 s still before and after).
- weave: ISO 13674-1 on-centre weave: 0.2 Hz sine at 100 km/h, amplitude for a steady-state Ay of
  2 m/s^2 (0.2 g), five periods.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from carfeel.errors import InputError
from carfeel.models.drivers.steering import Path
from carfeel.models.vehicle.single_track import VehicleParams, steady_state_steering_wheel_angle

MANOEUVRES = (
    "iso4138",
    "iso4138-limit",
    "iso3888",
    "iso7401-step",
    "iso7401-sine",
    "iso7401-sweep",
    "steer-cycle",
    "weave",
)

DEFAULT_SPEED_KMH = {
    "iso3888": 80.0,
    "iso7401-step": 60.0,
    "iso7401-sine": 60.0,
    "iso7401-sweep": 60.0,
    "steer-cycle": 0.0,
    "weave": 100.0,
}
MAX_SPEED_KMH = 250.0
STEER_CYCLE_MAX_KMH = 10.0
PATH_SPACING_M = 0.25

Steering = Callable[[float], tuple[float, float]]


@dataclass(frozen=True)
class Lane:
    """A section of the cone track (ISO 3888): where the car must stay."""

    x_start_m: float
    x_end_m: float
    y_centre_m: float
    width_m: float


@dataclass(frozen=True)
class Segment:
    """A stretch of a manoeuvre with one input: imposed steering, or a path for the driver."""

    label: str
    duration_s: float
    speed: Callable[[float], float]
    steering: Steering | None = None
    path: Path | None = None
    start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_steering_rad: float = 0.0


@dataclass(frozen=True)
class Manoeuvre:
    name: str
    description: str
    segments: tuple[Segment, ...]
    lanes: tuple[Lane, ...] = ()
    circle_radius_m: float | None = None


def _check_speed(name: str, speed_kmh: float | None) -> float:
    if speed_kmh is None:
        return DEFAULT_SPEED_KMH[name]
    if not (math.isfinite(speed_kmh) and 0.0 <= speed_kmh <= MAX_SPEED_KMH):
        raise InputError(f"--speed-kmh {speed_kmh:g}: allowed 0 <= value <= {MAX_SPEED_KMH:g} km/h")
    if name == "steer-cycle" and speed_kmh > STEER_CYCLE_MAX_KMH:
        raise InputError(
            f"--speed-kmh {speed_kmh:g}: the steer cycle goes lock to lock, a parking manoeuvre; "
            f"allowed 0 <= value <= {STEER_CYCLE_MAX_KMH:g} km/h"
        )
    if name != "steer-cycle" and speed_kmh < 10.0:
        raise InputError(
            f"--speed-kmh {speed_kmh:g}: {name} needs at least 10 km/h (its amplitude is set "
            "from the steady-state lateral acceleration); use steer-cycle for standstill"
        )
    return speed_kmh


def build(name: str, vehicle: VehicleParams, speed_kmh: float | None = None) -> Manoeuvre:
    """The manoeuvre `name` (one of MANOEUVRES) for a car, at `speed_kmh` or its default."""
    if name not in MANOEUVRES:
        raise InputError(f"unknown manoeuvre {name!r}; choose one of {', '.join(MANOEUVRES)}")
    if name in ("iso4138", "iso4138-limit"):
        if speed_kmh is not None:
            raise InputError(
                f"{name} steps its own speed on a 40 m circle (Ay from 0.5 m/s^2 up); drop "
                "--speed-kmh"
            )
        if name == "iso4138-limit":
            return iso4138(vehicle, max_lateral_accel_m_s2=11.0, ramp_s=1.0, hold_s=2.0)
        return iso4138(vehicle)
    v = _check_speed(name, speed_kmh) / 3.6
    if name == "iso3888":
        return iso3888(vehicle, v)
    if name == "steer-cycle":
        return steer_cycle(vehicle, v)
    if name == "weave":
        return weave(vehicle, v)
    return iso7401(name, vehicle, v)


def _constant(value: float) -> Callable[[float], float]:
    return lambda t: value


def _amplitude(vehicle: VehicleParams, speed: float, lateral_accel: float) -> float:
    """The steering wheel angle for a steady-state Ay; an error if it lies beyond the lock."""
    angle = steady_state_steering_wheel_angle(speed, lateral_accel, vehicle)
    if abs(angle) > vehicle.steering_lock_rad:
        raise InputError(
            f"at {speed * 3.6:.0f} km/h a steady-state Ay of {lateral_accel:g} m/s^2 needs "
            f"{math.degrees(angle):.0f} deg of steering wheel angle, beyond the car's lock of "
            f"{math.degrees(vehicle.steering_lock_rad):.0f} deg; use a higher --speed-kmh"
        )
    return angle


def iso7401(name: str, vehicle: VehicleParams, speed: float) -> Manoeuvre:
    amp = _amplitude(vehicle, speed, 4.0)
    if name == "iso7401-step":
        t0, ramp = 1.0, 0.2

        def steering(t: float) -> tuple[float, float]:
            if t < t0:
                return 0.0, 0.0
            if t < t0 + ramp:
                phase = math.pi * (t - t0) / ramp
                return amp * 0.5 * (1 - math.cos(phase)), amp * 0.5 * math.pi / ramp * math.sin(
                    phase
                )
            return amp, 0.0

        duration, text = 5.0, "ISO 7401 step steer"
    elif name == "iso7401-sine":
        t0, f = 1.0, 0.5

        def steering(t: float) -> tuple[float, float]:
            if t0 <= t < t0 + 1.0 / f:
                w = 2 * math.pi * f
                return amp * math.sin(w * (t - t0)), amp * w * math.cos(w * (t - t0))
            return 0.0, 0.0

        duration, text = 6.0, "ISO 7401 single-period sine, 0.5 Hz"
    else:
        f0, f1, sweep = 0.1, 2.0, 25.0

        def steering(t: float) -> tuple[float, float]:
            tt = min(t, sweep)
            phase = 2 * math.pi * (f0 * tt + 0.5 * (f1 - f0) / sweep * tt * tt)
            freq = f0 + (f1 - f0) * tt / sweep
            if t > sweep:
                return 0.0, 0.0
            return amp * math.sin(phase), amp * 2 * math.pi * freq * math.cos(phase)

        duration, text = sweep, "ISO 7401 continuous sine, 0.1-2 Hz linear sweep"
    segment = Segment(name, duration, _constant(speed), steering=steering)
    description = (
        f"{text} at {speed * 3.6:.0f} km/h; amplitude {math.degrees(amp):.1f} deg "
        "(steady-state Ay 4 m/s^2)"
    )
    return Manoeuvre(name, description, (segment,))


def steer_cycle(vehicle: VehicleParams, speed: float) -> Manoeuvre:
    lock, period, still = vehicle.steering_lock_rad, 12.0, 0.5
    w = 2 * math.pi / period

    def steering(t: float) -> tuple[float, float]:
        if still <= t < still + period:
            return lock * math.sin(w * (t - still)), lock * w * math.cos(w * (t - still))
        return 0.0, 0.0

    description = (
        f"complete steer cycle, lock to lock and back (+-{math.degrees(lock):.0f} deg) in "
        f"{period:g} s at {speed * 3.6:.0f} km/h"
    )
    segment = Segment("steer-cycle", period + 2 * still, _constant(speed), steering=steering)
    return Manoeuvre("steer-cycle", description, (segment,))


def weave(vehicle: VehicleParams, speed: float) -> Manoeuvre:
    f, periods = 0.2, 5
    amp = _amplitude(vehicle, speed, 2.0)
    w = 2 * math.pi * f

    def steering(t: float) -> tuple[float, float]:
        return amp * math.sin(w * t), amp * w * math.cos(w * t)

    description = (
        f"ISO 13674-1 weave: {f:g} Hz sine at {speed * 3.6:.0f} km/h, amplitude "
        f"{math.degrees(amp):.1f} deg (steady-state Ay 2 m/s^2, 0.2 g), {periods} periods"
    )
    segment = Segment("weave", periods / f, _constant(speed), steering=steering)
    return Manoeuvre("weave", description, (segment,))


def _resample(points: np.ndarray) -> Path:
    """A path through `points` (N x 2) resampled to equal spacing."""
    seg = np.hypot(*np.diff(points, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    s_new = np.arange(0.0, s[-1], PATH_SPACING_M)
    x = np.interp(s_new, s, points[:, 0])
    y = np.interp(s_new, s, points[:, 1])
    return Path(tuple(float(v) for v in x), tuple(float(v) for v in y), PATH_SPACING_M)


def lane_change_lanes(width_m: float) -> tuple[Lane, ...]:
    """The three cone lanes of ISO 3888-1 for a car of width `width_m` (see module docstring)."""
    w1, w3, w5 = 1.1 * width_m + 0.25, 1.2 * width_m + 0.25, 1.3 * width_m + 0.25
    return (
        Lane(0.0, 15.0, 0.0, w1),
        Lane(45.0, 70.0, w3 / 2 + 3.5, w3),
        Lane(95.0, 110.0, (w5 - w1) / 2, w5),
    )


def iso3888(vehicle: VehicleParams, speed: float) -> Manoeuvre:
    lanes = lane_change_lanes(vehicle.width_m)
    run_up, run_out, settle = 30.0, 15.0, 3.0
    x = np.arange(-run_up, lanes[-1].x_end_m + run_out + 30.0, 0.1)
    y = np.full_like(x, lanes[0].y_centre_m)
    for before, after in itertools.pairwise(lanes):
        x0, x1 = before.x_end_m, after.x_start_m + settle
        inside = (x >= x0) & (x <= x1)
        blend = 0.5 * (1 - np.cos(np.pi * (x[inside] - x0) / (x1 - x0)))
        y[inside] = before.y_centre_m + (after.y_centre_m - before.y_centre_m) * blend
        y[x > x1] = after.y_centre_m
    path = _resample(np.column_stack([x, y]))
    length = lanes[-1].x_end_m + run_out + run_up
    segment = Segment(
        "iso3888", length / speed, _constant(speed), path=path, start_pose=(-run_up, 0.0, 0.0)
    )
    description = (
        f"ISO 3888-1 double lane change at {speed * 3.6:.0f} km/h, car width "
        f"{vehicle.width_m:g} m (lanes {lanes[0].width_m:.2f}, {lanes[1].width_m:.2f}, "
        f"{lanes[2].width_m:.2f} m)"
    )
    return Manoeuvre("iso3888", description, (segment,), lanes=lanes)


def iso4138_speed_profile(
    radius_m: float, steps_m_s2: tuple[float, ...], ramp_s: float, hold_s: float
) -> tuple[Callable[[float], float], float]:
    """Speed against time for the constant-radius steps, and the total duration."""
    speeds = [math.sqrt(ay * radius_m) for ay in steps_m_s2]
    period = ramp_s + hold_s

    def speed(t: float) -> float:
        i = min(int(t // period), len(speeds) - 1)
        tau = t - i * period
        if i == 0 or tau >= ramp_s:
            return speeds[i]
        blend = 0.5 * (1 - math.cos(math.pi * tau / ramp_s))
        return speeds[i - 1] + (speeds[i] - speeds[i - 1]) * blend

    return speed, period * len(speeds)


def _circle(radius_m: float, direction: float, distance_m: float) -> Path:
    """A circle through the origin heading +x, counter-clockwise (direction +1) or clockwise."""
    laps = math.ceil(distance_m / (2 * math.pi * radius_m)) + 1
    s = np.arange(0.0, laps * 2 * math.pi * radius_m, PATH_SPACING_M)
    phi = s / radius_m
    x = radius_m * np.sin(phi)
    y = direction * radius_m * (1 - np.cos(phi))
    return Path(tuple(float(v) for v in x), tuple(float(v) for v in y), PATH_SPACING_M)


def iso4138(
    vehicle: VehicleParams,
    radius_m: float = 40.0,
    *,
    max_lateral_accel_m_s2: float = 5.0,
    ramp_s: float = 2.0,
    hold_s: float = 3.0,
    sides: tuple[str, ...] = ("left", "right"),
) -> Manoeuvre:
    """Steps of 0.5 m/s^2 up to `max_lateral_accel_m_s2` (10: to the limit of a dry road)."""
    steps = tuple(0.5 * i for i in range(1, round(max_lateral_accel_m_s2 / 0.5) + 1))
    speed, duration = iso4138_speed_profile(radius_m, steps, ramp_s=ramp_s, hold_s=hold_s)
    distance = sum(speed(t) * 0.01 for t in np.arange(0.0, duration, 0.01))
    segments = []
    for label, direction in (("left", 1.0), ("right", -1.0)):
        if label not in sides:
            continue
        start_angle = direction * steady_state_steering_wheel_angle(speed(0.0), steps[0], vehicle)
        segments.append(
            Segment(
                label,
                duration,
                speed,
                path=_circle(radius_m, direction, distance),
                start_steering_rad=start_angle,
            )
        )
    description = (
        f"ISO 4138 constant radius {radius_m:g} m, Ay steps of 0.5 up to {steps[-1]:g} m/s^2 "
        f"({ramp_s:g} s ramp + {hold_s:g} s hold each), {' then '.join(sides)}"
    )
    return Manoeuvre("iso4138", description, tuple(segments), circle_radius_m=radius_m)
