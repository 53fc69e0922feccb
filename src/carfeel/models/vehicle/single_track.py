"""Linear single-track (bicycle) model: steady state, transient, and a kinematic fallback.

    y (left)
    ^        b           a
    |   o---------+-----------o   front axle steered by delta = delta_w / SR
    |  rear       CG         front
    +---------------------------> x (forward)

Signs: steering angle, sideslip beta, yaw rate r, yaw and Ay are positive to the left (counter-
clockwise seen from above). Axle cornering stiffnesses C_f, C_r are per axle (both tires), N/rad.

Transient model (speed V given each step, linear tires):
    m*V*(beta' + r) = F_f + F_r         F_f = C_f*(delta - beta - a*r/V)
    I_z*r'          = a*F_f - b*F_r     F_r = C_r*(-beta + b*r/V)
    Ay = (F_f + F_r) / m
integrated by the trapezoidal rule (A-stable, second order, exact at steady state) over each step,
with the wheel angle averaged over the step's two ends.
Below `kinematic_speed_m_s` the tires' slip is ill-defined and the model follows the wheels:
beta = atan(b*tan(delta)/L), r = V*cos(beta)*tan(delta)/L (the kinematic bicycle), Ay = V*r.

Steady state: delta = L/R + K_us*Ay with K_us = m/L*(b/C_f - a/C_r), so
    Ay = V^2 * delta / (L * (1 + K*V^2)),   K = K_us / L,
and the characteristic speed sqrt(L / K_us) is where the yaw gain is half the neutral one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple


@dataclass(frozen=True, slots=True)
class VehicleParams:
    mass_kg: float
    """Vehicle mass m."""
    yaw_inertia_kg_m2: float
    """Yaw moment of inertia I_z about the centre of gravity."""
    wheelbase_m: float
    """Wheelbase L."""
    cg_to_front_axle_m: float
    """a: distance from the centre of gravity to the front axle."""
    front_cornering_stiffness_N_rad: float
    """Front axle cornering stiffness C_f (both tyres)."""
    rear_cornering_stiffness_N_rad: float
    """Rear axle cornering stiffness C_r (both tyres)."""
    steering_ratio: float
    """Steering wheel angle per front wheel angle, dimensionless."""
    width_m: float
    """Overall width of the car (ISO 3888's b, not the CG-to-rear-axle b): sets the lanes."""
    steering_lock_rad: float
    """Largest steering wheel angle either way."""
    kinematic_speed_m_s: float
    """Below this speed the kinematic bicycle replaces the tire model."""

    @property
    def cg_to_rear_axle_m(self) -> float:
        return self.wheelbase_m - self.cg_to_front_axle_m

    @property
    def understeer_gradient_rad_s2_m(self) -> float:
        """K_us = m/L * (b/C_f - a/C_r): front wheel angle per Ay beyond Ackermann, rad/(m/s^2)."""
        return (
            self.mass_kg
            / self.wheelbase_m
            * (
                self.cg_to_rear_axle_m / self.front_cornering_stiffness_N_rad
                - self.cg_to_front_axle_m / self.rear_cornering_stiffness_N_rad
            )
        )

    @property
    def understeer_gradient_deg_per_g(self) -> float:
        return math.degrees(self.understeer_gradient_rad_s2_m) * STANDARD_GRAVITY_M_S2

    @property
    def characteristic_speed_m_s(self) -> float:
        """sqrt(L / K_us) for an understeering car; inf when neutral or oversteering."""
        k_us = self.understeer_gradient_rad_s2_m
        return math.sqrt(self.wheelbase_m / k_us) if k_us > 0.0 else math.inf


STANDARD_GRAVITY_M_S2 = 9.80665


def steady_state_lateral_accel(
    speed_m_s: float, steering_wheel_angle_rad: float, params: VehicleParams
) -> float:
    """Ay = V^2 * delta / (L * (1 + K*V^2)) with delta = delta_w / SR, m/s^2."""
    delta = steering_wheel_angle_rad / params.steering_ratio
    stability = params.understeer_gradient_rad_s2_m / params.wheelbase_m
    v2 = speed_m_s * speed_m_s
    return v2 * delta / (params.wheelbase_m * (1.0 + stability * v2))


def steady_state_steering_wheel_angle(
    speed_m_s: float, lateral_accel_m_s2: float, params: VehicleParams
) -> float:
    """The steering wheel angle that holds Ay at speed V in steady state, rad."""
    if speed_m_s <= 0.0:
        raise ValueError("no steady-state lateral acceleration at standstill")
    v2 = speed_m_s * speed_m_s
    delta = lateral_accel_m_s2 * (params.wheelbase_m / v2 + params.understeer_gradient_rad_s2_m)
    return delta * params.steering_ratio


class VehicleState(NamedTuple):
    sideslip_rad: float
    yaw_rate_rad_s: float
    x_m: float
    y_m: float
    yaw_rad: float
    lateral_accel_m_s2: float
    front_wheel_angle_rad: float
    """At the last step: the trapezoidal rule averages it with the new one."""


class VehicleInputs(NamedTuple):
    speed_m_s: float
    steering_angle_rad: float
    """Steering wheel angle, positive to the left."""


class VehicleOutputs(NamedTuple):
    lateral_accel_m_s2: float
    yaw_rate_rad_s: float
    sideslip_rad: float
    x_m: float
    y_m: float
    yaw_rad: float


def initial_state(x_m: float = 0.0, y_m: float = 0.0, yaw_rad: float = 0.0) -> VehicleState:
    """Driving straight at the given pose."""
    return VehicleState(0.0, 0.0, x_m, y_m, yaw_rad, 0.0, 0.0)


def steady_state(
    speed_m_s: float,
    steering_wheel_angle_rad: float,
    params: VehicleParams,
    x_m: float = 0.0,
    y_m: float = 0.0,
    course_rad: float = 0.0,
) -> VehicleState:
    """Steady cornering at a speed and steering angle, moving along `course_rad` at (x, y).

    Ay from `steady_state_lateral_accel`, r = Ay / V, and the sideslip from the rear axle's slip
    angle (its force m*Ay*a/L, from the moment balance): beta = b*r/V - m*Ay*a/(L*C_r). The yaw is
    the course less the sideslip, so the car moves along `course_rad`.
    """
    delta = steering_wheel_angle_rad / params.steering_ratio
    if speed_m_s < params.kinematic_speed_m_s:
        return VehicleState(0.0, 0.0, x_m, y_m, course_rad, 0.0, delta)
    ay = steady_state_lateral_accel(speed_m_s, steering_wheel_angle_rad, params)
    r = ay / speed_m_s
    rear_force = params.mass_kg * ay * params.cg_to_front_axle_m / params.wheelbase_m
    beta = (
        params.cg_to_rear_axle_m * r / speed_m_s
        - rear_force / params.rear_cornering_stiffness_N_rad
    )
    return VehicleState(beta, r, x_m, y_m, course_rad - beta, ay, delta)


def front_axle_force_N(state: VehicleState, speed_m_s: float, params: VehicleParams) -> float:
    """Lateral force of the front axle (both tyres), N, positive to the left: C_f * alpha_f of
    the state (after a step). Below the kinematic speed, the force that gives the kinematic Ay:
    m * Ay * b / L."""
    p = params
    if speed_m_s < p.kinematic_speed_m_s:
        return p.mass_kg * state.lateral_accel_m_s2 * p.cg_to_rear_axle_m / p.wheelbase_m
    return p.front_cornering_stiffness_N_rad * (
        state.front_wheel_angle_rad
        - state.sideslip_rad
        - p.cg_to_front_axle_m * state.yaw_rate_rad_s / speed_m_s
    )


def aligning_lateral_accel(state: VehicleState, speed_m_s: float, params: VehicleParams) -> float:
    """The Ay the front axle's force stands for, F_f * L / (m * b), m/s^2.

    Equal to Ay in steady state (the front axle carries m * Ay * b / L there), so a torque law
    written for Ay keeps its gradient; in a transient it leads Ay, as the front tyres' force
    (and the aligning moment, trail times that force) does: the steering wheel feels the front
    axle before the car has turned.
    """
    p = params
    return (
        front_axle_force_N(state, speed_m_s, p) * p.wheelbase_m / (p.mass_kg * p.cg_to_rear_axle_m)
    )


def _derivatives(
    beta: float, r: float, delta: float, v: float, p: VehicleParams
) -> tuple[float, float, float]:
    """(beta', r', Ay) of the linear model at speed v > 0."""
    a = p.cg_to_front_axle_m
    b = p.cg_to_rear_axle_m
    front = p.front_cornering_stiffness_N_rad * (delta - beta - a * r / v)
    rear = p.rear_cornering_stiffness_N_rad * (-beta + b * r / v)
    ay = (front + rear) / p.mass_kg
    return ay / v - r, (a * front - b * rear) / p.yaw_inertia_kg_m2, ay


def step(
    state: VehicleState, inputs: VehicleInputs, params: VehicleParams, dt_s: float
) -> tuple[VehicleState, VehicleOutputs]:
    """Advance the vehicle by `dt_s` at the given speed and steering wheel angle."""
    p = params
    v = inputs.speed_m_s
    delta = inputs.steering_angle_rad / p.steering_ratio
    if v < p.kinematic_speed_m_s:
        tan_delta = math.tan(delta)
        beta = math.atan(p.cg_to_rear_axle_m * tan_delta / p.wheelbase_m)
        r = v * math.cos(beta) * tan_delta / p.wheelbase_m
        ay = v * r
    else:
        # Trapezoidal rule on x' = A x + B delta: (I - h/2 A) x1 = (I + h/2 A) x0 + h B delta.
        a = p.cg_to_front_axle_m
        b = p.cg_to_rear_axle_m
        cf = p.front_cornering_stiffness_N_rad
        cr = p.rear_cornering_stiffness_N_rad
        m_v = p.mass_kg * v
        a11 = -(cf + cr) / m_v
        a12 = -1.0 - (a * cf - b * cr) / (m_v * v)
        a21 = -(a * cf - b * cr) / p.yaw_inertia_kg_m2
        a22 = -(a * a * cf + b * b * cr) / (p.yaw_inertia_kg_m2 * v)
        b1 = cf / m_v
        b2 = a * cf / p.yaw_inertia_kg_m2
        h2 = 0.5 * dt_s
        beta0, r0 = state.sideslip_rad, state.yaw_rate_rad_s
        delta_mean = 0.5 * (state.front_wheel_angle_rad + delta)
        rhs1 = beta0 + h2 * (a11 * beta0 + a12 * r0) + dt_s * b1 * delta_mean
        rhs2 = r0 + h2 * (a21 * beta0 + a22 * r0) + dt_s * b2 * delta_mean
        m11, m12 = 1.0 - h2 * a11, -h2 * a12
        m21, m22 = -h2 * a21, 1.0 - h2 * a22
        det = m11 * m22 - m12 * m21
        beta = (rhs1 * m22 - m12 * rhs2) / det
        r = (m11 * rhs2 - m21 * rhs1) / det
        ay = _derivatives(beta, r, delta, v, p)[2]
    # Pose: the velocity points along yaw + sideslip; midpoint rule on the yaw.
    yaw = state.yaw_rad + 0.5 * dt_s * (state.yaw_rate_rad_s + r)
    course = 0.5 * (state.yaw_rad + yaw) + 0.5 * (state.sideslip_rad + beta)
    x = state.x_m + dt_s * v * math.cos(course)
    y = state.y_m + dt_s * v * math.sin(course)
    new = VehicleState(beta, r, x, y, yaw, ay, delta)
    return new, VehicleOutputs(ay, r, beta, x, y, yaw)
