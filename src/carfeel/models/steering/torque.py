"""Steering wheel torque, equations (1) and (4)-(7) of the paper.

    tau  = tau0 + tau1 + tau2 + tau3                          (1)
    tau0 = K1 * Ay / (1 + K2 * |Ay|^K3)       aligning         (4)
    tau1 = atan(rate / K6) / (K4 + K5 * Vx)   tire spin (scrub) (5)
    tau2 = K7 * atan(rate / K8)               friction          (6)
    tau3 = K9 * rate                          damping           (7)

Signs: angle, rate and Ay are positive to the left (counter-clockwise wheel, leftward
acceleration). tau is the torque the driver applies to the wheel, positive counter-clockwise: each
term resists the driver, so it is positive with the angle (through Ay), with the rate and with Ay.
The law takes Ay as an input and does not care where it comes from (the built-in single-track model
or an outside simulator). At Vx = 0, Ay = 0 and the torque depends on the rate only.

The arithmetic works on floats and, with `atan=numpy.arctan`, elementwise on numpy arrays: one
implementation serves the 1 kHz loop and the batch evaluation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple


@dataclass(frozen=True, slots=True)
class SteeringTorqueParams:
    """K1..K9 of the paper, with their units (Ay in m/s^2, rate in rad/s, Vx in m/s, tau in Nm)."""

    k1_Nm_s2_m: float
    """Aligning gain: on-centre torque per m/s^2 of Ay (x 9.81 = the gradient in Nm/g)."""
    k2: float
    """Aligning saturation, (m/s^2)^-K3."""
    k3: float
    """Aligning saturation exponent, dimensionless."""
    k4_1_Nm: float
    """Tire spin at standstill: the term tends to pi/2 / K4 Nm at a fast rate."""
    k5_s_m_Nm: float
    """Tire spin falls with speed: 1/(K4 + K5*Vx)."""
    k6_rad_s: float
    """Rate scale of the tire spin: at rate = K6 the term is half of its asymptote."""
    k7_Nm: float
    """Friction torque amplitude: tau2 tends to +-K7 * pi/2."""
    k8_rad_s: float
    """Rate that smooths the friction's change of sign."""
    k9_Nm_s_rad: float
    """Viscous damping of the steering system."""


class TorqueInputs(NamedTuple):
    speed_m_s: float
    steering_rate_rad_s: float
    lateral_accel_m_s2: float


class TorqueOutputs(NamedTuple):
    torque_Nm: float
    torque_aligning_Nm: float
    torque_tire_spin_Nm: float
    torque_friction_Nm: float
    torque_damping_Nm: float


def torque_terms(
    speed_m_s: Any,
    steering_rate_rad_s: Any,
    lateral_accel_m_s2: Any,
    params: SteeringTorqueParams,
    atan: Callable[[Any], Any] = math.atan,
) -> tuple[Any, Any, Any, Any, Any]:
    """(tau, tau0, tau1, tau2, tau3) in Nm, for floats or (with `atan=numpy.arctan`) arrays."""
    p = params
    ay = lateral_accel_m_s2
    rate = steering_rate_rad_s
    aligning = p.k1_Nm_s2_m * ay / (1.0 + p.k2 * abs(ay) ** p.k3)
    tire_spin = atan(rate / p.k6_rad_s) / (p.k4_1_Nm + p.k5_s_m_Nm * abs(speed_m_s))
    friction = p.k7_Nm * atan(rate / p.k8_rad_s)
    damping = p.k9_Nm_s_rad * rate
    return aligning + tire_spin + friction + damping, aligning, tire_spin, friction, damping


def torque(inputs: TorqueInputs, params: SteeringTorqueParams) -> TorqueOutputs:
    """The steering wheel torque and its four terms, Nm."""
    return TorqueOutputs(
        *torque_terms(
            inputs.speed_m_s, inputs.steering_rate_rad_s, inputs.lateral_accel_m_s2, params
        )
    )


def step(
    state: None, inputs: TorqueInputs, params: SteeringTorqueParams, dt_s: float
) -> tuple[None, TorqueOutputs]:
    """The law as a (stateless) model step, for the runner and the contract tests."""
    return None, torque(inputs, params)
