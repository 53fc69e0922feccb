"""Steering wheel torque, equations (1) and (4)-(7) of the paper, and a friction with memory.

    tau  = tau0 + tau1 + tau2 + tau3                          (1)
    tau0 = K1 * Ay / (1 + K2 * |Ay|^K3)       aligning         (4)
    tau1 = atan(rate / K6) / (K4 + K5 * Vx)   tire spin (scrub) (5)
    tau2 = K7 * atan(rate / K8) + K10 * z     friction          (6), and its memory
    tau3 = K9 * rate                          damping           (7)

The paper's friction depends on the rate alone: it has no memory, so a wheel held off centre
feels no friction and every reversal flips it over the same rate band. Real columns, racks and
EPS gearboxes carry their history: after a reversal the friction builds over an angle, not a
rate (hysteresis). `z` is that memory, a Dahl element (Dahl 1968; the LuGre model's bristle
state without its Stribeck part) in -1..1 driven by the wheel's angle:

    dz/dt = (rate - |rate| z) / K11                          (Dahl, exponent 1)

so z follows sign(rate) over K11 radians of steering after each reversal, and holds while the
wheel is held. Stepped exactly for a rate held over the step (`friction_memory_step`). K10 = 0,
the default, switches the element off: the paper's law as it was, bit for bit.

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
from collections.abc import Callable, Sequence
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
    k10_Nm: float = 0.0
    """Friction with memory: its level, Nm (tau2 gains K10 * z, z in -1..1); 0 switches it off."""
    k11_rad: float = 0.02
    """Friction with memory: the steering angle over which it builds after a reversal (63 % of
    its level in K11 rad, Dahl's rest stiffness K10 / K11 Nm/rad)."""


class TorqueInputs(NamedTuple):
    speed_m_s: float
    steering_rate_rad_s: float
    lateral_accel_m_s2: float


class TorqueState(NamedTuple):
    friction_memory: float = 0.0
    """z of the friction with memory, -1..1 (module docstring)."""


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
    """(tau, tau0, tau1, tau2, tau3) in Nm, for floats or (with `atan=numpy.arctan`) arrays:
    the memoryless terms (`torque` adds the friction's memory, K10 z, to tau2 and tau)."""
    p = params
    ay = lateral_accel_m_s2
    rate = steering_rate_rad_s
    aligning = p.k1_Nm_s2_m * ay / (1.0 + p.k2 * abs(ay) ** p.k3)
    tire_spin = atan(rate / p.k6_rad_s) / (p.k4_1_Nm + p.k5_s_m_Nm * abs(speed_m_s))
    friction = p.k7_Nm * atan(rate / p.k8_rad_s)
    damping = p.k9_Nm_s_rad * rate
    return aligning + tire_spin + friction + damping, aligning, tire_spin, friction, damping


def friction_memory_step(
    z: float, steering_rate_rad_s: float, dt_s: float, params: SteeringTorqueParams
) -> float:
    """The friction memory z after dt_s with the rate held (exact for the Dahl element):
    z -> sign(rate) + (z - sign(rate)) exp(-|rate| dt / K11)."""
    turned = abs(steering_rate_rad_s) * dt_s
    if turned == 0.0:
        return z
    target = 1.0 if steering_rate_rad_s > 0.0 else -1.0
    return target + (z - target) * math.exp(-turned / params.k11_rad)


def friction_memory_series(
    steering_rate_rad_s: Sequence[float], dt_s: Sequence[float], params: SteeringTorqueParams,
    z: float = 0.0,
) -> list[float]:  # fmt: skip
    """z after each step of a run (rate and step length per step, from z): the model's own
    steps in sequence, for a run recorded without them (the law's torque does not act on the
    car, so its memory can follow the run)."""
    out = []
    for rate, dt in zip(steering_rate_rad_s, dt_s, strict=True):
        z = friction_memory_step(z, rate, dt, params)
        out.append(z)
    return out


def torque(
    inputs: TorqueInputs, params: SteeringTorqueParams, friction_memory: float = 0.0
) -> TorqueOutputs:
    """The steering wheel torque and its four terms, Nm; the friction's memory z (-1..1) adds
    K10 z to the friction."""
    total, aligning, spin, friction, damping = torque_terms(
        inputs.speed_m_s, inputs.steering_rate_rad_s, inputs.lateral_accel_m_s2, params
    )
    if params.k10_Nm != 0.0:
        memory = params.k10_Nm * friction_memory
        total, friction = total + memory, friction + memory
    return TorqueOutputs(total, aligning, spin, friction, damping)


def step(
    state: TorqueState, inputs: TorqueInputs, params: SteeringTorqueParams, dt_s: float
) -> tuple[TorqueState, TorqueOutputs]:
    """The law as a model step: the friction's memory follows the rate over the step (the
    inputs at its end, as the runner gives them), then the torque."""
    z = friction_memory_step(state.friction_memory, inputs.steering_rate_rad_s, dt_s, params)
    return TorqueState(z), torque(inputs, params, z)
