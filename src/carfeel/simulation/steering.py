"""Steering wheel torque on the single-track car, the wheel imposed or steered by a driver."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from carfeel.models.drivers import steering as path_driver
from carfeel.models.drivers.steering import PathDriverParams, PathFollowing
from carfeel.models.steering import physical
from carfeel.models.steering.physical import (
    PhysicalInputs,
    PhysicalParams,
    PhysicalState,
    SystemParams,
    TyreParams,
)
from carfeel.models.steering.torque import (
    SteeringTorqueParams,
    friction_memory_series,
    torque_terms,
)
from carfeel.models.vehicle import single_track
from carfeel.models.vehicle.single_track import VehicleInputs, VehicleParams, VehicleState
from carfeel.simulation.manoeuvres import Manoeuvre
from carfeel.simulation.result import Result
from carfeel.simulation.runner import stream
from carfeel.simulation.stream import Collector, Sink

MAX_STEP_S = 5e-3
"""Longest model step: the path driver's lag (at least 20 ms, see the presets' ranges) is
integrated explicitly and stays accurate to a tenth of it or better at 5 ms."""

LINEAR_TYRE_LIMIT_G = 0.6
"""Beyond about this lateral acceleration real tyres saturate; the linear model does not."""

STEERING_MODELS = ("paper", "physical")
"""paper: the linear car and the paper's algebraic law; physical: brush tyres on a nonlinear car
and an EPS steering system (`carfeel.models.steering.physical`)."""

ROAD_FRICTION = {"dry": 1.0, "wet": 0.7, "snow": 0.3}
"""Friction coefficient of each road surface for the physical model's tyres (typical peak values
of passenger-car tyres: dry asphalt 0.9-1.1, wet 0.5-0.8, packed snow 0.2-0.4)."""


@dataclass(frozen=True, slots=True)
class SteeringCar:
    """A car for steering runs: the vehicle, its torque law and the driver who steers paths.

    `tyres` and `steering_system` (optional preset tables) give the physical model; a car
    without them runs the paper's law only.
    """

    vehicle: VehicleParams
    """The car: the single-track model's mass, geometry, cornering stiffnesses and steering."""
    torque: SteeringTorqueParams
    """The paper's steering torque law, K1..K9 (equations 4-7)."""
    driver: PathDriverParams
    """The path-following driver: preview, lag and rate limit."""
    tyres: TyreParams | None = None
    """Brush tyres and load transfer of the physical model (absent: the paper's law only)."""
    steering_system: SystemParams | None = None
    """The EPS steering system of the physical model (absent: the paper's law only)."""

    @property
    def has_physical(self) -> bool:
        return self.tyres is not None and self.steering_system is not None

    def physical(self, road: str | None = None) -> PhysicalParams:
        """The physical model's parameters, on `road` (a ROAD_FRICTION key) if given."""
        if self.tyres is None or self.steering_system is None:
            raise ValueError("this car has no [tyres] and [steering_system] tables")
        tyres = self.tyres
        if road is not None:
            tyres = dataclasses.replace(tyres, friction_coefficient=ROAD_FRICTION[road])
        return PhysicalParams(self.vehicle, tyres, self.steering_system)


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


class PhysicalRunOutputs(NamedTuple):
    speed_m_s: float
    steering_angle_rad: float
    steering_rate_rad_s: float
    lateral_accel_m_s2: float
    torque_Nm: float
    torque_aligning_Nm: float
    torque_jacking_Nm: float
    torque_park_Nm: float
    torque_friction_Nm: float
    torque_damping_Nm: float
    torque_inertia_Nm: float
    torque_stop_Nm: float
    torque_assist_Nm: float
    torsion_bar_torque_Nm: float
    front_wheel_angle_rad: float
    front_grip_used: float
    rear_grip_used: float
    yaw_rate_rad_s: float
    sideslip_rad: float
    x_m: float
    y_m: float
    yaw_rad: float
    cross_track_m: float


PHYSICAL_TERMS = (
    "torque_aligning_Nm",
    "torque_jacking_Nm",
    "torque_park_Nm",
    "torque_friction_Nm",
    "torque_damping_Nm",
    "torque_inertia_Nm",
    "torque_stop_Nm",
    "torque_assist_Nm",
)
"""The physical model's contributions to `torque_Nm` (they sum to it exactly)."""


def _physical_outputs(
    speed: float, out: physical.PhysicalOutputs, cross_track: float
) -> PhysicalRunOutputs:
    return PhysicalRunOutputs(speed, *out[:3], *out[3:], cross_track)


class PhysicalPathState(NamedTuple):
    model: PhysicalState
    driver: path_driver.PathDriverState


@dataclass(frozen=True, slots=True)
class PhysicalPathRun:
    params: PhysicalParams
    following: PathFollowing


def physical_imposed_step(
    state: PhysicalState, inputs: ImposedInputs, params: PhysicalParams, dt_s: float
) -> tuple[PhysicalState, PhysicalRunOutputs]:
    """The physical model with the rim's angle and rate imposed."""
    new, out = physical.step(
        state,
        PhysicalInputs(inputs.speed_m_s, inputs.steering_angle_rad, inputs.steering_rate_rad_s,
                       0.0, 1.0),
        params,
        dt_s,
    )  # fmt: skip
    return new, _physical_outputs(inputs.speed_m_s, out, 0.0)


def as_vehicle_state(state: PhysicalState, steering_ratio: float) -> VehicleState:
    """The physical model's car as the linear car's state (what the path driver reads)."""
    return VehicleState(
        state.sideslip_rad, state.yaw_rate_rad_s, state.x_m, state.y_m, state.yaw_rad,
        state.lateral_accel_m_s2, state.pinion_angle_rad / steering_ratio,
    )  # fmt: skip


def physical_path_step(
    state: PhysicalPathState, speed_m_s: float, params: PhysicalPathRun, dt_s: float
) -> tuple[PhysicalPathState, PhysicalRunOutputs]:
    """A driver steers the physical model's rim along a path at the imposed speed."""
    car = as_vehicle_state(state.model, params.params.vehicle.steering_ratio)
    driver, steer = path_driver.step(state.driver, (car, speed_m_s), params.following, dt_s)
    model, out = physical.step(
        state.model,
        PhysicalInputs(speed_m_s, steer.steering_angle_rad, steer.steering_rate_rad_s, 0.0, 1.0),
        params.params,
        dt_s,
    )
    return PhysicalPathState(model, driver), _physical_outputs(speed_m_s, out, steer.cross_track_m)


def physical_start(
    params: PhysicalParams,
    speed_m_s: float,
    steering_angle_rad: float,
    pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> PhysicalState:
    """Steady cornering of the linear car at this speed and angle (the low-Ay start of a path)."""
    x0, y0, yaw0 = pose
    start = physical.initial_state(params, x0, y0, yaw0, steering_angle_rad)
    if speed_m_s < params.vehicle.kinematic_speed_m_s:
        return start
    linear = single_track.steady_state(speed_m_s, steering_angle_rad, params.vehicle, x0, y0, yaw0)
    a, b = params.vehicle.cg_to_front_axle_m, params.vehicle.cg_to_rear_axle_m
    beta, r = linear.sideslip_rad, linear.yaw_rate_rad_s
    return start._replace(
        front_slip_rad=linear.front_wheel_angle_rad - beta - a * r / speed_m_s,
        rear_slip_rad=b * r / speed_m_s - beta,
        sideslip_rad=beta,
        yaw_rate_rad_s=r,
        yaw_rad=linear.yaw_rad,
        lateral_accel_m_s2=linear.lateral_accel_m_s2,
    )


def stream_steering(
    car: SteeringCar,
    manoeuvre: Manoeuvre,
    sink: Sink,
    *,
    dt_s: float = 1e-3,
    substeps: int = 1,
    model: str = "paper",
    road: str | None = None,
) -> int:
    """Run every segment of a manoeuvre, time running on across segments, the samples to
    `sink` as the run goes; returns the number of samples.

    The column `segment` names the segment of each sample (e.g. left / right for ISO 4138).
    `model` is one of STEERING_MODELS; `road` (physical model only) a ROAD_FRICTION key.
    """
    if model not in STEERING_MODELS:
        raise ValueError(f"unknown steering model {model!r}; one of {STEERING_MODELS}")
    physical_params = car.physical(road) if model == "physical" else None
    memory = car.torque if physical_params is None and car.torque.k10_Nm != 0.0 else None
    labelled = _Segments(sink, memory, dt_s)
    for segment in manoeuvre.segments:
        labelled.label = segment.label
        labelled.z = 0.0  # the law's friction memory starts each segment from rest
        x0, y0, yaw0 = segment.start_pose
        speed = segment.speed
        if segment.steering is not None:
            steering = segment.steering

            def inputs(t: float) -> ImposedInputs:
                angle, rate = steering(t)  # noqa: B023 - used within this iteration only
                return ImposedInputs(speed(t), angle, rate)  # noqa: B023

            if physical_params is None:
                _, n = stream(
                    imposed_step, single_track.initial_state(x0, y0, yaw0), car, labelled,
                    duration_s=segment.duration_s, dt_s=dt_s, substeps=substeps, inputs=inputs,
                )  # fmt: skip
            else:
                start = physical_start(
                    physical_params, speed(0.0), steering(0.0)[0], segment.start_pose
                )
                _, n = stream(
                    physical_imposed_step, start, physical_params, labelled,
                    duration_s=segment.duration_s, dt_s=dt_s, substeps=substeps, inputs=inputs,
                )  # fmt: skip
        elif segment.path is not None:
            following = PathFollowing(car.driver, car.vehicle, segment.path)
            driver = path_driver.initial_state(segment.start_steering_rad)
            if physical_params is None:
                # Start in steady state on the path's first heading at the starting steering.
                vehicle = single_track.steady_state(
                    speed(0.0), segment.start_steering_rad, car.vehicle, x0, y0, yaw0
                )
                _, n = stream(
                    path_step, PathState(vehicle, driver), PathRun(car, following), labelled,
                    duration_s=segment.duration_s, dt_s=dt_s, substeps=substeps, inputs=speed,
                )  # fmt: skip
            else:
                start = physical_start(
                    physical_params, speed(0.0), segment.start_steering_rad, segment.start_pose
                )
                _, n = stream(
                    physical_path_step, PhysicalPathState(start, driver),
                    PhysicalPathRun(physical_params, following), labelled,
                    duration_s=segment.duration_s, dt_s=dt_s, substeps=substeps, inputs=speed,
                )  # fmt: skip
        else:  # pragma: no cover - a Segment is built with one or the other
            raise ValueError(f"segment {segment.label} has neither steering nor path")
        labelled.offset += n * dt_s  # the segment's last time, as its samples were stamped
        labelled.samples += n
    return labelled.samples


class _Segments:
    """A sink that stamps each block with its segment's label and time since the run began,
    and adds the law's friction memory (K10 z, `torque.friction_memory_step`) to torque_Nm and
    torque_friction_Nm where the preset has one: the law's torque does not act on the car, so z
    follows the run's rate step by step (dt_s each), carried from block to block."""

    def __init__(self, sink: Sink, memory: SteeringTorqueParams | None, dt_s: float) -> None:
        self.sink = sink
        self.memory = memory
        self.dt_s = dt_s
        self.label = ""
        self.offset = 0.0
        self.samples = 0
        self.z = 0.0

    def write(self, block: Result) -> None:
        signals = dict(block.signals)
        signals["segment"] = np.full(len(block), self.label)
        if self.memory is not None:
            rates = block["steering_rate_rad_s"].tolist()
            zs = friction_memory_series(rates, [self.dt_s] * len(rates), self.memory, self.z)
            if zs:
                self.z = zs[-1]
            added = self.memory.k10_Nm * np.asarray(zs)
            signals["torque_Nm"] = block["torque_Nm"] + added
            signals["torque_friction_Nm"] = block["torque_friction_Nm"] + added
        self.sink.write(Result(block.time_s + self.offset, signals))


def simulate_steering(
    car: SteeringCar,
    manoeuvre: Manoeuvre,
    *,
    dt_s: float = 1e-3,
    substeps: int = 1,
    metadata: Mapping[str, str] | None = None,
    model: str = "paper",
    road: str | None = None,
) -> Result:
    """`stream_steering` into memory: the whole run as one Result."""
    kept = Collector()
    stream_steering(car, manoeuvre, kept, dt_s=dt_s, substeps=substeps, model=model, road=road)
    return kept.result(dict(metadata or {}))
