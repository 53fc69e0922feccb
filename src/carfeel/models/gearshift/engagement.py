"""One gear engagement along the engagement slot (1 DOF), after section 3 of the paper.

Axis: x along the slot, 0 = neutral, positive toward the gear. Forces are positive toward the gear.

    neutral      synchro ring    teeth          in gear (stop)
    |------------------|-----------|====|-------------|->  x
    0          x_sync        x_teeth   x_teeth_end   x_gear

Stages, in the order a push from neutral meets them (`Stage`):
  neutral          free motion; the neutral spring-ball centres the lever (x0 = 0)
  synchronization  the blocker ring holds the lever still at x_sync and carries the driver's
                   force while the cones cancel the speed difference; after
                   `synchronization_duration_s` of pushing the synchro gate opens (a time-dependent
                   transition)
  gate_open        free motion from the ring to the teeth
  engagement       tooth contact: the sleeve pushes through the chamfers of the gear's dog teeth,
                   turning the gear into mesh; the resistance (static and sliding friction of the
                   stage plus a tooth force drawn per engagement, as it depends on the relative
                   position of the teeth) decelerates lever and hand into a short, random peak
  free_travel      free motion to the end stop
  stop             spring-ball elastic stop around x_gear: overshoot, then recovery
  in_gear          settled; the detent holds the lever at x_gear
  returning        free motion back toward neutral: after the driver pulls the lever out of gear, or
                   after a force reversal during synchronization or engagement (never into gear)

The active stage selects the mechanics (mass, stiffness, damping, friction) of equation (8) and its
rest position x0 (0 for neutral and the free stages, x_sync while blocked, x_gear for stop and
in gear).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

from carfeel.models.mechanics import StageMechanics, stick_slip_step
from carfeel.models.rng import next_uniform, seed_state


class Stage(Enum):
    """Stage of an engagement; the value is the name used in CSV files and plots."""

    NEUTRAL = "neutral"
    SYNCHRONIZATION = "synchronization"
    GATE_OPEN = "gate_open"
    ENGAGEMENT = "engagement"
    FREE_TRAVEL = "free_travel"
    STOP = "stop"
    IN_GEAR = "in_gear"
    RETURNING = "returning"


@dataclass(frozen=True, slots=True)
class EngagementParams:
    """Parameters of one engagement. Positions in m along the slot, forces in N, times in s."""

    synchronization_position_m: float
    teeth_position_m: float
    teeth_end_position_m: float
    in_gear_position_m: float
    detent_release_m: float
    """How far the lever must be pulled back from x_gear before the in-gear detent lets it go."""
    synchronization_duration_s: float
    """Time the blocker ring holds the lever while the driver pushes (the paper's ~0.3 s)."""
    tooth_force_spread_N: float
    """Each engagement adds U(0, 1) times this to both frictions of the engagement stage."""
    stick_velocity_m_s: float
    """Below this speed the static friction applies (Karnopp's velocity band)."""
    settle_velocity_m_s: float
    settle_distance_m: float
    """The stop stage hands over to in_gear once speed and distance to x_gear are below these."""
    neutral: StageMechanics
    gate_open: StageMechanics
    engagement: StageMechanics
    free_travel: StageMechanics
    stop: StageMechanics
    in_gear: StageMechanics
    returning: StageMechanics


class EngagementState(NamedTuple):
    """State of the lever and of the stage machine."""

    stage: Stage
    position_m: float
    velocity_m_s: float
    stage_time_s: float
    synchronization_progress: float
    """Fraction of the speed difference cancelled, 0..1; the gate opens at 1."""
    tooth_force_N: float
    """Resistance of the teeth drawn for the current (or last) engagement, N."""
    rng_state: int


class EngagementInputs(NamedTuple):
    driver_force_N: float
    """Force the driver applies to the knob, positive toward the gear."""
    wall_stiffness_N_m: float = 0.0
    """An outside spring on the lever (a gate wall of the H-pattern), 0 when there is none."""
    wall_damping_N_s_m: float = 0.0
    wall_position_m: float = 0.0
    """Where the outside spring is relaxed."""
    gate_open: bool | None = None
    """None: the synchro gate opens after `synchronization_duration_s` of pushing (the paper).
    True / False: an outside synchronizer model says whether the speeds are matched."""
    extra_friction_N: float = 0.0
    """Friction added to the stage's own, static and sliding (a latch of the H-pattern)."""


class EngagementOutputs(NamedTuple):
    position_m: float
    velocity_m_s: float
    force_N: float
    """Driver force on the knob, as measured at the knob in the paper's Fig. 5."""
    reaction_N: float
    """Force of the gearbox on the knob against the driver: the driver's force less what
    accelerates the lever (F - m*a). It is what a force-feedback device renders."""
    stage: str


# Progress counts as complete within rounding: 300 steps of 1/300 must open the gate on the 300th.
_DONE = 1.0 - 1e-9


def initial_state(seed: int = 0, position_m: float = 0.0) -> EngagementState:
    """The lever at rest in neutral; `seed` fixes the draws of the tooth-indexing force."""
    return EngagementState(Stage.NEUTRAL, position_m, 0.0, 0.0, 0.0, 0.0, seed_state(seed))


def mechanics(params: EngagementParams, stage: Stage) -> tuple[StageMechanics, float]:
    """The mechanics of a free (integrated) stage and its rest position x0, m."""
    if stage is Stage.NEUTRAL:
        return params.neutral, 0.0
    if stage is Stage.GATE_OPEN:
        return params.gate_open, 0.0
    if stage is Stage.ENGAGEMENT:
        return params.engagement, 0.0
    if stage is Stage.FREE_TRAVEL:
        return params.free_travel, 0.0
    if stage is Stage.STOP:
        return params.stop, params.in_gear_position_m
    if stage is Stage.IN_GEAR:
        return params.in_gear, params.in_gear_position_m
    if stage is Stage.RETURNING:
        return params.returning, 0.0
    raise ValueError(f"stage {stage.value} has no free mechanics (the lever is blocked)")


def step(
    state: EngagementState, inputs: EngagementInputs, params: EngagementParams, dt_s: float
) -> tuple[EngagementState, EngagementOutputs]:
    """Advance one engagement by `dt_s` seconds."""
    force = inputs.driver_force_N
    stage = state.stage
    x = state.position_m
    v = state.velocity_m_s

    # Guards on force and time, before the motion of this step.
    if stage is Stage.SYNCHRONIZATION:
        if force < 0.0:
            stage = Stage.RETURNING  # force reversal: free motion, never into gear
        else:
            progress = state.synchronization_progress
            if inputs.gate_open is None:
                if force > 0.0:
                    progress += dt_s / params.synchronization_duration_s
                synchronized = progress >= _DONE
            else:
                synchronized = inputs.gate_open
            if not synchronized:
                held = EngagementState(
                    stage,
                    x,
                    0.0,
                    state.stage_time_s + dt_s,
                    progress,
                    state.tooth_force_N,
                    state.rng_state,
                )
                return held, EngagementOutputs(x, 0.0, force, force, stage.value)
            stage = Stage.GATE_OPEN  # synchro gate opens
    elif stage is Stage.ENGAGEMENT and force < 0.0 and v <= 0.0:
        # Force reversal on the teeth (a braking hand on a lever still moving in is not one).
        stage = Stage.RETURNING
    if stage is not state.stage:
        v = _hand_over(v, x, state.stage, stage, params)

    mech, rest = mechanics(params, stage)
    stiffness = mech.stiffness_N_m
    damping = mech.damping_N_s_m
    k_wall = inputs.wall_stiffness_N_m
    if k_wall > 0.0:  # the outside spring joins the stage's own, in the implicit step
        rest = (stiffness * rest + k_wall * inputs.wall_position_m) / (stiffness + k_wall)
        stiffness += k_wall
        damping += inputs.wall_damping_N_s_m
    extra = inputs.extra_friction_N
    if stage is Stage.ENGAGEMENT:
        extra += state.tooth_force_N
    x1, v1, _ = stick_slip_step(
        x,
        v,
        force,
        mech.mass_kg,
        damping,
        stiffness,
        rest,
        mech.static_friction_N + extra,
        mech.sliding_friction_N + extra,
        params.stick_velocity_m_s,
        dt_s,
    )
    reaction = force - mech.mass_kg * (v1 - v) / dt_s

    # Guards on position, at the end of the motion of this step.
    new_stage = stage
    rng_state = state.rng_state
    tooth = state.tooth_force_N
    progress = state.synchronization_progress
    x_sync = params.synchronization_position_m
    if stage is Stage.NEUTRAL:
        if x1 >= x_sync and v1 > 0.0:
            x1, v1, new_stage, progress = x_sync, 0.0, Stage.SYNCHRONIZATION, 0.0
    elif stage is Stage.GATE_OPEN:
        x_teeth = params.teeth_position_m
        if x1 < x_sync:
            new_stage = Stage.RETURNING
        elif x1 >= x_teeth:
            new_stage = Stage.ENGAGEMENT
            rng_state, u = next_uniform(rng_state)
            tooth = u * params.tooth_force_spread_N
    elif stage is Stage.ENGAGEMENT:
        if x1 >= params.teeth_end_position_m:
            new_stage = Stage.FREE_TRAVEL
        elif x1 < params.teeth_position_m:
            new_stage = Stage.RETURNING
    elif stage is Stage.FREE_TRAVEL:
        if x1 >= params.in_gear_position_m:
            # The stop's spring starts at x_gear: enter it there, so no spring energy appears
            # from the part of the step that overshot the boundary.
            x1 = params.in_gear_position_m
            new_stage = Stage.STOP
        elif x1 < params.teeth_end_position_m:
            new_stage = Stage.RETURNING  # pulled back into the teeth: on the way out
    elif stage is Stage.STOP or stage is Stage.IN_GEAR:
        x_gear = params.in_gear_position_m
        if x1 < x_gear - params.detent_release_m:
            new_stage = Stage.RETURNING
        elif (
            stage is Stage.STOP
            and -params.settle_velocity_m_s < v1 < params.settle_velocity_m_s
            and -params.settle_distance_m < x1 - x_gear < params.settle_distance_m
        ):
            new_stage = Stage.IN_GEAR  # recovered to the equilibrium: the detent holds
    elif stage is Stage.RETURNING:
        if x1 <= x_sync:
            new_stage = Stage.NEUTRAL
        elif v1 > 0.0 and force > 0.0:
            # Pushed forward again. Where the step started decides, so the outcome does not
            # depend on how far one step travels.
            if x <= params.teeth_end_position_m:
                # The sleeve is not in mesh: the blocker ring holds it where it is, a new
                # synchronization.
                x1, v1, new_stage, progress = x, 0.0, Stage.SYNCHRONIZATION, 0.0
            else:
                new_stage = Stage.FREE_TRAVEL  # still in mesh with the gear's teeth

    if new_stage is not stage:
        v1 = _hand_over(v1, x1, stage, new_stage, params)
    stage_time = state.stage_time_s + dt_s if new_stage is state.stage else 0.0
    new_state = EngagementState(new_stage, x1, v1, stage_time, progress, tooth, rng_state)
    return new_state, EngagementOutputs(x1, v1, force, reaction, new_stage.value)


def _mass_and_spring(params: EngagementParams, stage: Stage, x: float) -> tuple[float, float]:
    """(mass, spring energy at x) of a stage; the blocked synchronization stage stores none."""
    if stage is Stage.SYNCHRONIZATION:
        return params.neutral.mass_kg, 0.0
    mech, rest = mechanics(params, stage)
    return mech.mass_kg, 0.5 * mech.stiffness_N_m * (x - rest) ** 2


def _hand_over(
    velocity_m_s: float, position_m: float, old: Stage, new: Stage, params: EngagementParams
) -> float:
    """Velocity after a stage transition at `position_m`, such that energy does not grow.

    The mass may change (see `hand_over_velocity`), and so may the spring and its rest position:
    if the new stage's spring holds more energy here than the old one's, the lever pays for it
    from its kinetic energy (it climbs into the detent). Only if the kinetic energy cannot pay
    does the lever stop there, with the rest of the step in the new stage's energy: a gain of at
    most that spring energy, at rest, which the stage then dissipates.
    """
    old_mass, old_spring = _mass_and_spring(params, old, position_m)
    new_mass, new_spring = _mass_and_spring(params, new, position_m)
    v = hand_over_velocity(velocity_m_s, old_mass, new_mass)
    climb = new_spring - old_spring
    if climb > 0.0:
        kinetic = 0.5 * new_mass * v * v - climb
        speed = math.sqrt(2.0 * kinetic / new_mass) if kinetic > 0.0 else 0.0
        v = speed if v > 0.0 else -speed
    return v


def hand_over_velocity(velocity_m_s: float, old_mass_kg: float, new_mass_kg: float) -> float:
    """Velocity after the moving mass changes at a stage transition, m/s.

    Momentum is kept when the mass grows (a plastic pick-up), velocity when it shrinks, so the
    kinetic energy never grows at a transition.
    """
    if new_mass_kg > old_mass_kg:
        return velocity_m_s * (old_mass_kg / new_mass_kg)
    return velocity_m_s
