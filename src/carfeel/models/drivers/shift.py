"""A driver's hand that pushes a gear lever in (equation 10 of the paper), lets go, may pull it out.

The muscle force follows eq. (10) on the hand's own velocity v_h:

    push:  F_m = F_max * (1 - v_h / V0)        V0: the highest knob speed of an engagement
    pull:  F_m = -F_pull * (1 + v_h / V_pull)   the mirror, for the way back to neutral

and acts on the hand's mass m_h, which holds the knob through the hand's stiffness k_h and damping
c_h. The force the knob (and a force sensor in it, as in the paper's measurements) feels is

    F_knob = k_h * (x_h - x) + c_h * (v_h - v)

So while the lever is blocked the hand comes to rest and pushes with F_max: the synchronization
plateau. When the lever stops abruptly (the teeth, the end stop) the moving hand runs into it and
the knob force peaks for a few milliseconds, the isolated impact peaks of Fig. 5.

The muscle is scaled by an activation a in 0..1 (F_m = a * law): it rises with `activation_time_s`
when the driver starts to push or pull, and fades with `release_time_s` when the driver lets go;
`hold_s` after letting go the hand leaves the knob (no force), or pulls it out if `pull_out`.

Signs: x and forces positive toward the gear, as in `carfeel.models.gearshift.engagement`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple


class DriverPhase(Enum):
    PUSH = "push"
    RELEASE = "release"
    PULL = "pull"
    IDLE = "idle"


@dataclass(frozen=True, slots=True)
class ShiftDriverParams:
    push_force_N: float
    """F_max of eq. (10): the force while the lever is blocked."""
    push_velocity_m_s: float
    """V0 of eq. (10): the hand speed at which the driver stops pushing."""
    hand_mass_kg: float
    """Mass m_h of the hand, which holds the knob through its grip."""
    hand_stiffness_N_m: float
    """Stiffness k_h of the hand's grip on the knob."""
    hand_damping_N_s_m: float
    """Damping c_h of the hand's grip on the knob."""
    activation_time_s: float
    """Time constant of the muscle force building up at the start of a push or pull."""
    release_position_m: float
    """The driver lets go once the knob has reached this position and stops moving forward."""
    release_time_s: float
    """Time constant of the muscle force fading when the driver lets go."""
    hold_s: float
    """Time from letting go until the hand leaves the knob, or pulls it out."""
    pull_out: bool
    """true: hold_s after letting go the hand pulls the lever back to neutral; false: it leaves the
    knob."""
    pull_force_N: float
    """F_pull: the pull's force at rest (the mirror of eq. (10)'s F_max)."""
    pull_velocity_m_s: float
    """V_pull: the hand speed back toward neutral at which the pull's force falls to 0."""
    neutral_position_m: float
    """The pull ends (the hand leaves the knob) once the knob is within this of neutral."""


class DriverState(NamedTuple):
    phase: DriverPhase
    phase_time_s: float
    hand_position_m: float
    hand_velocity_m_s: float
    activation: float
    """Muscle activation, 0 (relaxed) .. 1 (the full force of eq. 10)."""


class DriverInputs(NamedTuple):
    position_m: float
    velocity_m_s: float


class DriverOutputs(NamedTuple):
    force_N: float
    """Force of the hand on the knob, positive toward the gear."""
    phase: str


def initial_state(position_m: float = 0.0) -> DriverState:
    """A hand at rest on the knob, about to push."""
    return DriverState(DriverPhase.PUSH, 0.0, position_m, 0.0, 0.0)


def _next_phase(state: DriverState, x: float, v: float, params: ShiftDriverParams) -> DriverPhase:
    phase = state.phase
    if phase is DriverPhase.PUSH:
        if x >= params.release_position_m and v <= 0.0:
            return DriverPhase.RELEASE
    elif phase is DriverPhase.RELEASE:
        if state.phase_time_s >= params.hold_s:
            return DriverPhase.PULL if params.pull_out else DriverPhase.IDLE
    elif phase is DriverPhase.PULL and x <= params.neutral_position_m:
        return DriverPhase.IDLE
    return phase


def step(
    state: DriverState, inputs: DriverInputs, params: ShiftDriverParams, dt_s: float
) -> tuple[DriverState, DriverOutputs]:
    """Advance the hand by `dt_s` seconds given the knob's position and velocity.

    The hand is integrated by implicit Euler (its muscle velocity feedback and its grip are stiff
    next to a 1 ms step); the knob's motion enters as a given, one step old.
    """
    x = inputs.position_m
    v = inputs.velocity_m_s
    phase = _next_phase(state, x, v, params)
    phase_time = state.phase_time_s + dt_s if phase is state.phase else 0.0
    if phase is DriverPhase.IDLE:  # hand off the knob; it follows the knob to grip it again
        return DriverState(phase, phase_time, x, v, 0.0), DriverOutputs(0.0, phase.value)
    activation = state.activation if phase is state.phase or phase is DriverPhase.RELEASE else 0.0
    if phase is DriverPhase.RELEASE:  # the muscle fades, the hand stays on the knob
        activation *= math.exp(-dt_s / params.release_time_s)
    else:
        activation = 1.0 - (1.0 - activation) * math.exp(-dt_s / params.activation_time_s)
    if phase is DriverPhase.PULL:
        bias = -activation * params.pull_force_N
        gain = activation * params.pull_force_N / params.pull_velocity_m_s
    else:  # PUSH, and RELEASE fading from it
        bias = activation * params.push_force_N
        gain = activation * params.push_force_N / params.push_velocity_m_s
    x_h, v_h, knob_force = grip_step(
        state.hand_position_m, state.hand_velocity_m_s, bias, gain, x, v, params, dt_s
    )
    new_state = DriverState(phase, phase_time, x_h, v_h, activation)
    return new_state, DriverOutputs(knob_force, phase.value)


def grip_step(
    hand_position_m: float,
    hand_velocity_m_s: float,
    bias_N: float,
    gain_N_s_m: float,
    knob_position_m: float,
    knob_velocity_m_s: float,
    params: ShiftDriverParams,
    dt_s: float,
) -> tuple[float, float, float]:
    """One implicit step of the hand on the knob: (hand position, hand velocity, knob force).

    The muscle force is bias - gain * v_h (eq. 10 scaled by the activation); the hand's grip is
    its stiffness and damping to the knob, whose motion is given.
    """
    m_h = params.hand_mass_kg / dt_s
    k = params.hand_stiffness_N_m
    c = params.hand_damping_N_s_m
    x = knob_position_m
    v = knob_velocity_m_s
    impedance = m_h + gain_N_s_m + c + dt_s * k
    v_h = (m_h * hand_velocity_m_s + bias_N - k * (hand_position_m - x) + c * v) / impedance
    x_h = hand_position_m + dt_s * v_h
    return x_h, v_h, k * (x_h - x) + c * (v_h - v)
