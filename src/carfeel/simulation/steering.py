"""Steering wheel torque on the single-track car, the wheel imposed or steered by a driver."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from carfeel.models.drivers import steering as path_driver
from carfeel.models.drivers.steering import PathDriverParams, PathFollowing
from carfeel.models.steering.torque import SteeringTorqueParams, torque_terms
from carfeel.models.vehicle import single_track
from carfeel.models.vehicle.single_track import VehicleInputs, VehicleParams, VehicleState
from carfeel.simulation.manoeuvres import Manoeuvre
from carfeel.simulation.result import Result
from carfeel.simulation.runner import run

MAX_STEP_S = 5e-3
"""Longest model step: the path driver's lag (at least 20 ms, see the presets' ranges) is
integrated explicitly and stays accurate to a tenth of it or better at 5 ms."""

LINEAR_TYRE_LIMIT_G = 0.6
"""Beyond about this lateral acceleration real tyres saturate; the linear model does not."""


@dataclass(frozen=True, slots=True)
class SteeringCar:
    """A car for steering runs: the vehicle, its torque law and the driver who steers paths."""

    vehicle: VehicleParams
    torque: SteeringTorqueParams
    driver: PathDriverParams


class SteeringOutputs(NamedTuple):
    speed_m_s: float
    steering_angle_rad: float
    steering_rate_rad_s: float
    lateral_accel_m_s2: float
    torque_Nm: float
    torque_aligning_Nm: float
    torque_tire_spin_Nm: float
    torque_friction_Nm: float
    torque_damping_Nm: float
    yaw_rate_rad_s: float
    sideslip_rad: float
    x_m: float
    y_m: float
    yaw_rad: float
    cross_track_m: float


class ImposedInputs(NamedTuple):
    speed_m_s: float
    steering_angle_rad: float
    steering_rate_rad_s: float


class PathState(NamedTuple):
    vehicle: VehicleState
    driver: path_driver.PathDriverState


@dataclass(frozen=True, slots=True)
class PathRun:
    car: SteeringCar
    following: PathFollowing


def _outputs(
    speed: float,
    angle: float,
    rate: float,
    vehicle: VehicleState,
    torque: SteeringTorqueParams,
    cross_track: float,
) -> SteeringOutputs:
    ay = vehicle.lateral_accel_m_s2
    total, aligning, spin, friction, damping = torque_terms(speed, rate, ay, torque)
    return SteeringOutputs(
        speed, angle, rate, ay, total, aligning, spin, friction, damping,
        vehicle.yaw_rate_rad_s, vehicle.sideslip_rad, vehicle.x_m, vehicle.y_m,
        vehicle.yaw_rad, cross_track,
    )  # fmt: skip


def imposed_step(
    state: VehicleState, inputs: ImposedInputs, params: SteeringCar, dt_s: float
) -> tuple[VehicleState, SteeringOutputs]:
    """Steering wheel angle and rate imposed (ISO 7401, steer cycle, weave)."""
    vehicle, _ = single_track.step(
        state, VehicleInputs(inputs.speed_m_s, inputs.steering_angle_rad), params.vehicle, dt_s
    )
    return vehicle, _outputs(
        inputs.speed_m_s, inputs.steering_angle_rad, inputs.steering_rate_rad_s, vehicle,
        params.torque, 0.0,
    )  # fmt: skip


def path_step(
    state: PathState, speed_m_s: float, params: PathRun, dt_s: float
) -> tuple[PathState, SteeringOutputs]:
    """A driver steers along a path at the imposed speed (ISO 4138, ISO 3888)."""
    driver, steer = path_driver.step(
        state.driver, (state.vehicle, speed_m_s), params.following, dt_s
    )
    vehicle, _ = single_track.step(
        state.vehicle, VehicleInputs(speed_m_s, steer.steering_angle_rad), params.car.vehicle, dt_s
    )
    return PathState(vehicle, driver), _outputs(
        speed_m_s, steer.steering_angle_rad, steer.steering_rate_rad_s, vehicle,
        params.car.torque, steer.cross_track_m,
    )  # fmt: skip


def simulate_steering(
    car: SteeringCar,
    manoeuvre: Manoeuvre,
    *,
    dt_s: float = 1e-3,
    substeps: int = 1,
    metadata: Mapping[str, str] | None = None,
) -> Result:
    """Run every segment of a manoeuvre; one Result, time running on across segments.

    The column `segment` names the segment of each sample (e.g. left / right for ISO 4138).
    """
    parts: list[Result] = []
    for segment in manoeuvre.segments:
        x0, y0, yaw0 = segment.start_pose
        vehicle = single_track.initial_state(x0, y0, yaw0)
        if segment.steering is not None:
            steering = segment.steering
            speed = segment.speed

            def inputs(t: float) -> ImposedInputs:
                angle, rate = steering(t)  # noqa: B023 - used within this iteration only
                return ImposedInputs(speed(t), angle, rate)  # noqa: B023

            result, _ = run(
                imposed_step, vehicle, car, duration_s=segment.duration_s, dt_s=dt_s,
                substeps=substeps, inputs=inputs,
            )  # fmt: skip
        elif segment.path is not None:
            # Start in steady state on the path's first heading at the starting steering.
            vehicle = single_track.steady_state(
                segment.speed(0.0), segment.start_steering_rad, car.vehicle, x0, y0, yaw0
            )
            following = PathFollowing(car.driver, car.vehicle, segment.path)
            state = PathState(vehicle, path_driver.initial_state(segment.start_steering_rad))
            result, _ = run(
                path_step, state, PathRun(car, following), duration_s=segment.duration_s,
                dt_s=dt_s, substeps=substeps, inputs=segment.speed,
            )  # fmt: skip
        else:  # pragma: no cover - a Segment is built with one or the other
            raise ValueError(f"segment {segment.label} has neither steering nor path")
        parts.append(result)
    return _concatenate(parts, [s.label for s in manoeuvre.segments], metadata)


def _concatenate(
    parts: list[Result], labels: list[str], metadata: Mapping[str, str] | None
) -> Result:
    times, offset = [], 0.0
    for part in parts:
        times.append(part.time_s + offset)
        offset += float(part.time_s[-1])
    signals = {name: np.concatenate([part[name] for part in parts]) for name in parts[0].signals}
    signals["segment"] = np.concatenate(
        [np.full(len(part), label) for part, label in zip(parts, labels, strict=True)]
    )
    return Result(np.concatenate(times), signals, dict(metadata or {}))
