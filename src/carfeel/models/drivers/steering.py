"""A driver who steers a car along a path: pure pursuit with the car's steady-state gain.

The driver aims at the point of the path one preview distance ahead (max(min_preview, V * T_p)),
computes the curvature of the arc through it, kappa = 2*sin(alpha)/L_d (alpha: bearing of the point
from the car's course, the direction its centre of gravity moves in), and the steering wheel angle
that holds that curvature in steady state, SR * kappa * (L + K_us * V^2) (the driver knows the
car's understeer). The hand follows that target
through a first-order lag (neuromuscular, `lag_s`) and a rate limit, so the wheel angle and its rate
are smooth, as the torque law needs them.

Signs as in `carfeel.models.vehicle.single_track`: angles and lateral offsets positive to the left.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from carfeel.models.vehicle.single_track import VehicleParams, VehicleState


@dataclass(frozen=True, slots=True)
class PathDriverParams:
    preview_time_s: float
    """T_p: the driver aims at the path point V * T_p ahead (at least min_preview_m)."""
    min_preview_m: float
    """Shortest preview distance: the aim point is never nearer than this."""
    lag_s: float
    """Time constant of the steering wheel angle following its target."""
    max_rate_rad_s: float
    """Fastest the driver turns the wheel."""


@dataclass(frozen=True, slots=True)
class Path:
    """A polyline of points `spacing_m` apart along its length (x forward, y left, m)."""

    x_m: tuple[float, ...]
    y_m: tuple[float, ...]
    spacing_m: float


@dataclass(frozen=True, slots=True)
class PathFollowing:
    """What a path-following driver knows: its own habits, the car, the path."""

    driver: PathDriverParams
    vehicle: VehicleParams
    path: Path


class PathDriverState(NamedTuple):
    path_index: int
    """Index of the path point nearest to the car at the last step (the search starts here)."""
    steering_angle_rad: float
    steering_rate_rad_s: float


class PathDriverOutputs(NamedTuple):
    steering_angle_rad: float
    steering_rate_rad_s: float
    cross_track_m: float
    """Distance of the car's centre of gravity to the left of the nearest path point's tangent."""


def initial_state(steering_angle_rad: float = 0.0) -> PathDriverState:
    return PathDriverState(0, steering_angle_rad, 0.0)


def nearest_index(path: Path, x: float, y: float, start: int, window: int) -> int:
    """Index of the path point nearest (x, y) among `start` .. `start + window` (progress only)."""
    xs, ys = path.x_m, path.y_m
    best, best_d2 = start, math.inf
    for i in range(start, min(start + window + 1, len(xs))):
        d2 = (xs[i] - x) ** 2 + (ys[i] - y) ** 2
        if d2 < best_d2:
            best, best_d2 = i, d2
    return best


def projection(path: Path, index: int, x: float, y: float) -> float:
    """Where (x, y) projects onto the path near point `index`, in (fractional) point indices.

    Continuous as the car moves, so the aimed-at point does not jump by a spacing when the
    nearest point changes.
    """
    xs, ys = path.x_m, path.y_m
    last = len(xs) - 1
    i = index if index < last else last - 1
    if i > 0:
        # The nearest point may lie on the segment before `index`.
        to_car = (x - xs[i]) * (xs[i + 1] - xs[i]) + (y - ys[i]) * (ys[i + 1] - ys[i])
        if to_car < 0.0:
            i -= 1
    dx, dy = xs[i + 1] - xs[i], ys[i + 1] - ys[i]
    length2 = dx * dx + dy * dy
    t = ((x - xs[i]) * dx + (y - ys[i]) * dy) / length2 if length2 > 0.0 else 0.0
    return i + min(1.0, max(0.0, t))


def point_ahead(path: Path, position: float, distance_m: float) -> tuple[float, float]:
    """The path point `distance_m` beyond `position` (in point indices), extended past the end."""
    xs, ys = path.x_m, path.y_m
    target = position + distance_m / path.spacing_m
    last = len(xs) - 1
    if target <= last:
        i = int(target)
        f = target - i
        j = min(i + 1, last)
        return xs[i] + f * (xs[j] - xs[i]), ys[i] + f * (ys[j] - ys[i])
    dx, dy = xs[last] - xs[last - 1], ys[last] - ys[last - 1]
    extra = target - last
    return xs[last] + extra * dx, ys[last] + extra * dy


def step(
    state: PathDriverState,
    inputs: tuple[VehicleState, float],
    params: PathFollowing,
    dt_s: float,
) -> tuple[PathDriverState, PathDriverOutputs]:
    """Steer for one step, given the car's state and its speed (m/s)."""
    car, speed = inputs
    path, vehicle, habits = params.path, params.vehicle, params.driver
    window = int(speed * dt_s / path.spacing_m) + 4
    index = nearest_index(path, car.x_m, car.y_m, state.path_index, window)
    preview = max(habits.min_preview_m, speed * habits.preview_time_s)
    tx, ty = point_ahead(path, projection(path, index, car.x_m, car.y_m), preview)
    dx, dy = tx - car.x_m, ty - car.y_m
    # The centre of gravity moves along the course (yaw + sideslip): the arc starts along it.
    course = car.yaw_rad + car.sideslip_rad
    lateral = -math.sin(course) * dx + math.cos(course) * dy  # target left of the course
    distance = math.hypot(dx, dy)
    curvature = 2.0 * lateral / (distance * distance) if distance > 1e-9 else 0.0
    front = curvature * (vehicle.wheelbase_m + vehicle.understeer_gradient_rad_s2_m * speed**2)
    lock = vehicle.steering_lock_rad
    target = max(-lock, min(lock, front * vehicle.steering_ratio))
    rate = (target - state.steering_angle_rad) / habits.lag_s
    rate = max(-habits.max_rate_rad_s, min(habits.max_rate_rad_s, rate))
    angle = state.steering_angle_rad + rate * dt_s
    # Signed offset of the car from the path, for checks and plots.
    j = min(index + 1, len(path.x_m) - 1)
    i = j - 1 if j > 0 else 0
    tangent_x, tangent_y = path.x_m[j] - path.x_m[i], path.y_m[j] - path.y_m[i]
    norm = math.hypot(tangent_x, tangent_y) or 1.0
    cross = (tangent_x * (car.y_m - path.y_m[i]) - tangent_y * (car.x_m - path.x_m[i])) / norm
    return PathDriverState(index, angle, rate), PathDriverOutputs(angle, rate, cross)
