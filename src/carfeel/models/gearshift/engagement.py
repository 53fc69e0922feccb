"""One gear engagement along the engagement slot (1 DOF), after section 3 of the paper.

Axis: x along the slot, 0 = neutral, positive toward the gear. Forces are positive toward the gear.

    neutral      synchro ring    teeth          in gear (stop)
    |------------------|-----------|====|-------------|->  x
    0          x_sync        x_teeth   x_teeth_end   x_gear

Stages, in the order a push from neutral meets them (`Stage`):
  neutral          free motion; the neutral spring and spring-ball detent centre the lever;
                   a rear stop (plastic) at -x_gear ends the slot behind neutral
  synchronization  the blocker ring holds the lever at x_sync (rigidly, or through the linkage's
                   compliance) while the driver's push (more than
                   the strut and detent force that pushes the sleeve back there) loads it and the
                   cones cancel the speed difference; after `synchronization_duration_s` of
                   pushing (scaled by the axial load where `synchronization_force_N` is set)
                   the synchro gate opens (or when an outside synchronizer says so). When
                   the push drops, the ring lets go: back to neutral, the progress kept; it decays
                   there over `desynchronization_time_s` (the speeds drift apart again)
  gate_open        free motion from the ring to the teeth
  engagement       the sleeve's chamfers meet the gear's dog teeth at a random relative angle: no
                   contact (a chance), or the chamfer faces meet at a position set by that angle
                   (`contact_m`, Lovas et al. 2006) and from there the sleeve must turn the gear
                   (its inertia reflected through the chamfer angle and the linkage, picked up in
                   a plastic impact, against its drag) to the end of the chamfers; then sliding
                   friction to the end of the teeth
  free_travel      free motion to the end stop
  stop             elastic end stop around x_gear: overshoot, then recovery; the gate's end
                   (rigid, plastic) `stop_travel_m` past x_gear bounds the overshoot
  in_gear          settled; the stop's spring and the gear detent hold the lever at x_gear;
                   only a held pull of the driver takes it out (past `detent_release_m`, beyond
                   `reversal_force_N` for `reversal_time_s`), never a rebound off the stop
  returning        free motion back from past the ring: after the driver pulls the lever out of
                   gear or back from the teeth. Pushed forward again it goes on where it is (gate
                   open, teeth, free travel): the ring can block again only once the sleeve is back
                   behind it, in neutral

The active stage selects the mechanics (mass, stiffness, damping, friction) of equation (8) and its
rest position x0 (0 for neutral and the free stages, x_sync while blocked, x_gear for stop and
in gear). Two spring-ball detents act in every free stage as forces of position only (conservative):
the neutral one (seat 0) and the gear one (seat x_gear, the "suck-in" past its crest).
The stop and in-gear stages are integrated to second order (the midpoint rule), so the stop rings
with its continuous-time damping at 1 kHz; the other stages by backward Euler.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

from carfeel.models.mechanics import (
    StageMechanics,
    stick_slip_midpoint_step,
    stick_slip_step,
)
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
class DetentParams:
    """A spring-ball detent: a conservative force profile, symmetric about its seat.

        force toward the seat                 past the crest: away from it
        seat ~~~ parabola, peak seat_force_N ~~~ crest ~~~ parabola, peak far_force_N ~~~ |
                                              (far_width_m long)

    The seat is 0 for the neutral detent (its crest toward the gear) and x_gear for the gear's
    (its crest toward neutral). Force 0 at the seat, the crest and beyond.
    """

    width_m: float
    """From the seat to the crest."""
    seat_force_N: float
    """Peak force of the flank between the seat and the crest, toward the seat."""
    far_force_N: float
    """Peak force of the flank past the crest, away from the seat."""
    far_width_m: float
    """Length of the flank past the crest (0: no such flank); beyond it the force is 0."""


@dataclass(frozen=True, slots=True)
class ChamferParams:
    """The sleeve's chamfers indexing the gear's dog teeth (Lovas et al. 2006), at the knob.

    The gear (with all it drives, inertia J at the synchronizer) must turn by the relative angle
    of the teeth: the sleeve moving dx turns it by dx * tan(angle) / radius, so it adds an
    equivalent mass J * tan^2 / (radius^2 * ratio^2 * efficiency) at the knob, picked up by a
    plastic impact, and its drag torque a resistance T * tan / (radius * ratio * efficiency).
    The relative angle u is U(0, 1): below `no_contact_fraction` the teeth meet gap to gap (no
    contact); above, the chamfer faces meet q = (u - f) / (1 - f) of `travel_m` past the teeth
    (the sleeve's tip travels freely over the part of the face the angle leaves open) and turn
    the gear from there to the chamfers' end, `travel_m` past the teeth.
    """

    gear_inertia_kg_m2: float
    """Inertia the chamfers turn, at the synchronizer (the gear and what it drives); 0: none."""
    drag_torque_Nm: float
    """Drag on that inertia at the synchronizer (bearings, oil)."""
    angle_rad: float
    """Angle of the chamfer faces to the shaft axis."""
    radius_m: float
    """Pitch radius of the dog teeth."""
    lever_ratio: float
    """Knob travel per unit of sleeve travel."""
    linkage_efficiency: float
    """Share of the knob's work the linkage passes to the sleeve; the gear's mass and drag at the
    knob are divided by it."""
    travel_m: float
    """Knob travel over a whole chamfer (the largest relative angle)."""
    no_contact_fraction: float
    """Chance f (0..1) that the teeth meet gap to gap (no contact)."""


@dataclass(frozen=True, slots=True)
class EngagementParams:
    """Parameters of one engagement. Positions in m along the slot, forces in N, times in s."""

    synchronization_position_m: float
    """x_sync: where the sleeve meets the synchro (blocker) ring."""
    teeth_position_m: float
    """x_teeth: where the sleeve's chamfers meet the gear's dog teeth."""
    teeth_end_position_m: float
    """x_teeth_end: where the teeth are passed; free travel to the stop from here."""
    in_gear_position_m: float
    """x_gear: the in-gear position, the stop's rest; the rear stop is at -x_gear."""
    detent_release_m: float
    """How far the lever must be pulled back from x_gear before the in-gear detent lets it go."""
    synchronization_duration_s: float
    """Time the blocker ring holds the lever while the driver pushes (the paper's ~0.3 s)."""
    tooth_force_spread_N: float
    """Each engagement adds u times this to both frictions of the engagement stage, u the
    relative tooth angle U(0, 1) that also sets the chamfer contact."""
    stick_velocity_m_s: float
    """Below this speed the static friction applies (Karnopp's velocity band)."""
    settle_velocity_m_s: float
    """Speed below which the stop may hand over to in_gear (within settle_distance_m of x_gear)."""
    settle_distance_m: float
    """Distance to x_gear within which the stop may hand over to in_gear (below
    settle_velocity_m_s)."""
    neutral: StageMechanics
    """Mechanics in neutral, rest position 0 (its spring centres the lever)."""
    gate_open: StageMechanics
    """Mechanics from the ring to the teeth once the gate has opened (rest position 0)."""
    engagement: StageMechanics
    """Mechanics through the teeth (rest position 0); each engagement adds its tooth force to both
    frictions."""
    free_travel: StageMechanics
    """Mechanics from the end of the teeth to the stop (rest position 0)."""
    stop: StageMechanics
    """Mechanics of the elastic end stop: its spring and damping around x_gear."""
    in_gear: StageMechanics
    """Mechanics once settled in gear: the spring holding the lever at x_gear."""
    returning: StageMechanics
    """Mechanics on the way back from past the ring to neutral (rest position 0)."""
    ring_release_force_N: float
    """The ring lets go when the push drops below the force that pushes the sleeve back at
    x_sync (neutral spring and detent, `hold_force_N`) plus this."""
    desynchronization_time_s: float
    """Fixed synchronizer: after the ring lets go the progress falls by dt / this."""
    reversal_force_N: float
    """A pull on the knob beyond this, held reversal_time_s, reverses in the teeth or takes the
    lever out of gear."""
    reversal_time_s: float
    """How long a pull beyond reversal_force_N must be held to count: a reversal in the teeth,
    a pull out of gear in gear."""
    neutral_detent: DetentParams
    """The spring-ball detent centring the lever in neutral (seat 0, crest toward the gear)."""
    gear_detent: DetentParams
    """The detent holding the gear (seat x_gear, crest toward neutral); past its crest, the
    suck-in."""
    chamfer: ChamferParams
    """The sleeve's chamfers indexing the gear's dog teeth in the engagement stage."""
    linkage_stiffness_N_m: float
    """Compliance of the linkage against the blocked ring (0: rigid, the knob held at x_sync);
    a cable linkage lets the knob in by F / k while the ring blocks."""
    linkage_damping_N_s_m: float
    """Damping of the linkage against the blocked ring (acts with linkage_stiffness_N_m > 0)."""
    stop_travel_m: float = 0.0
    """How far the knob can press into the elastic stop before the lever meets the gate's end
    (rigid and plastic: the lever stops there); 0: no end (the stop's spring alone)."""
    synchronization_force_N: float = 0.0
    """Fixed synchronizer: the push at which it takes `synchronization_duration_s`; the cone's
    torque grows with the axial load (the push less `hold_force_N`), so the time scales as
    (this - hold) / (push - hold). 0: the paper's timer, whatever the push."""

    @property
    def hold_force_N(self) -> float:
        """Push (N) below which the blocked ring lets go: what pushes the sleeve back there."""
        x = self.synchronization_position_m
        back = self.neutral.stiffness_N_m * x - detent_force_N(x, self, 0.0)
        return back + self.ring_release_force_N


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
    index_end_m: float = 0.0
    """Where the chamfers of the current engagement have turned the gear into line, m."""
    reversal_s: float = 0.0
    """How long the driver has pulled beyond the reversal force in the teeth, s."""
    contact_m: float = 0.0
    """Where the chamfers of the current engagement meet, m (they turn the gear from there to
    `index_end_m`); 0: at the teeth."""


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
    gear_inertia_kg_m2: float | None = None
    gear_drag_Nm: float | None = None
    """The selected gear's inertia and drag at its synchronizer (None: the chamfer params')."""


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


def detent_force_N(x: float, params: EngagementParams, seat_m: float | None = None) -> float:
    """Force (N, + toward the gear) of both detents at x; with `seat_m`, of that one only."""
    force = 0.0
    if seat_m is None or seat_m == 0.0:
        force += _detent(x, 0.0, params.neutral_detent.width_m, params.neutral_detent)[0]
    if seat_m is None or seat_m != 0.0:
        gear = params.gear_detent
        force += _detent(x, params.in_gear_position_m, -gear.width_m, gear)[0]
    return force


def detent_energy_J(x: float, params: EngagementParams) -> float:
    """Potential energy (J) of both detents at x, 0 at their seats."""
    return _detents(x, params)[1]


def _detents(x: float, params: EngagementParams) -> tuple[float, float, float]:
    """(force N, potential J, stiffness -dF/dx N/m) of both detents at x."""
    neutral, gear = params.neutral_detent, params.gear_detent
    f1, e1, k1 = _detent(x, 0.0, neutral.width_m, neutral)
    f2, e2, k2 = _detent(x, params.in_gear_position_m, -gear.width_m, gear)
    return f1 + f2, e1 + e2, k1 + k2


def _flat_J(width: float, d: DetentParams) -> float:
    """Potential (J) of a detent beyond its reach (`width` from seat to crest, > 0)."""
    return (d.seat_force_N * width - d.far_force_N * d.far_width_m) * (2.0 / 3.0)


def _detent(x: float, seat: float, width: float, d: DetentParams) -> tuple[float, float, float]:
    """(force N, potential J, stiffness -dF/dx N/m) of one detent at x (see DetentParams);
    `width` is the signed distance from the seat to the crest."""
    span = width if width > 0.0 else -width
    u = (x - seat) / width  # 1 at the crest; negative on the other side of the seat (mirror)
    sign = 1.0 if width > 0.0 else -1.0
    if u < 0.0:
        u, sign = -u, -sign
    peak = d.seat_force_N
    if u < 1.0:  # the flank toward the seat: F = 4 * peak * u * (1 - u)
        return (
            -sign * 4.0 * peak * u * (1.0 - u),
            peak * span * u * u * (2.0 - u * (4.0 / 3.0)),
            4.0 * peak * (1.0 - 2.0 * u) / span,
        )
    far = d.far_width_m
    w = (u - 1.0) * span / far if far > 0.0 else 1.0
    top = peak * span * (2.0 / 3.0)
    if w < 1.0:  # past the crest, away from the seat
        help_ = d.far_force_N
        return (
            sign * 4.0 * help_ * w * (1.0 - w),
            top - help_ * far * w * w * (2.0 - w * (4.0 / 3.0)),
            -4.0 * help_ * (1.0 - 2.0 * w) / far,
        )
    return 0.0, top - d.far_force_N * far * (2.0 / 3.0), 0.0


def chamfer_load(
    params: EngagementParams, inertia_kg_m2: float | None, drag_Nm: float | None
) -> tuple[float, float]:
    """(equivalent mass kg, drag N) of the gear at the knob while the chamfers turn it."""
    c = params.chamfer
    j = c.gear_inertia_kg_m2 if inertia_kg_m2 is None else inertia_kg_m2
    drag = c.drag_torque_Nm if drag_Nm is None else drag_Nm
    tan = math.tan(c.angle_rad)
    per = tan / (c.radius_m * c.lever_ratio)  # gear angle per knob travel, rad/m
    return j * per * per / c.linkage_efficiency, drag * per / c.linkage_efficiency


def step(
    state: EngagementState, inputs: EngagementInputs, params: EngagementParams, dt_s: float
) -> tuple[EngagementState, EngagementOutputs]:
    """Advance one engagement by `dt_s` seconds."""
    force = inputs.driver_force_N
    stage = state.stage
    x = state.position_m
    v = state.velocity_m_s
    progress = state.synchronization_progress
    reversal = 0.0

    # Guards on force and time, before the motion of this step.
    if stage is Stage.SYNCHRONIZATION:
        neutral = params.neutral
        # (A cheap bound first: the detent pushes back with at most its seat force.)
        bound = neutral.stiffness_N_m * params.synchronization_position_m + (
            params.neutral_detent.seat_force_N + params.ring_release_force_N
        )
        if force < bound and force < params.hold_force_N:
            # The push dropped: the struts and the detent push the sleeve off the ring.
            stage = Stage.NEUTRAL
        else:
            if inputs.gate_open is None:
                rate = dt_s / params.synchronization_duration_s
                f_ref = params.synchronization_force_N
                if f_ref > 0.0:
                    # The cone's torque, so its rate, is proportional to the axial load.
                    hold = params.hold_force_N
                    rate *= (force - hold) / (f_ref - hold)
                progress += rate
                synchronized = progress >= _DONE
            else:
                synchronized = inputs.gate_open
            if not synchronized:
                x1, v1, reaction = x, 0.0, force
                k_link = params.linkage_stiffness_N_m
                if k_link > 0.0:
                    # The linkage gives against the blocked ring: a spring from x_sync on.
                    x_sync = params.synchronization_position_m
                    mass = params.neutral.mass_kg
                    x1, v1, _ = stick_slip_step(
                        x, v, force, mass, params.linkage_damping_N_s_m, k_link, x_sync,
                        0.0, 0.0, 0.0, dt_s,
                    )  # fmt: skip
                    if x1 < x_sync:  # the sleeve rests on the ring: no further back
                        x1, v1 = x_sync, 0.0
                    reaction = force - mass * (v1 - v) / dt_s
                held = EngagementState(
                    stage,
                    x1,
                    v1,
                    state.stage_time_s + dt_s,
                    progress,
                    state.tooth_force_N,
                    state.rng_state,
                    state.index_end_m,
                    contact_m=state.contact_m,
                )
                return held, EngagementOutputs(x1, v1, force, reaction, stage.value)
            stage = Stage.GATE_OPEN  # synchro gate opens
    elif stage is Stage.ENGAGEMENT and force < -params.reversal_force_N:
        # A pull on the teeth, held: a reversal (a grip's rebound or a noisy sample is not one).
        reversal = state.reversal_s + dt_s
        if reversal >= params.reversal_time_s and v <= 0.0:
            stage = Stage.RETURNING
    elif (stage is Stage.STOP or stage is Stage.IN_GEAR) and force < -params.reversal_force_N:
        # A pull out of gear counts as in the teeth: beyond the reversal force, held (a hand
        # dragged back by the lever's rebound pulls for a few ms only).
        reversal = state.reversal_s + dt_s
    elif stage is Stage.NEUTRAL and progress > 0.0:
        # The ring let go before the gate opened: the speeds drift apart again.
        progress = max(0.0, progress - dt_s / params.desynchronization_time_s)
    if stage is not state.stage:
        v = _hand_over(v, x, state.stage, stage, params)

    mech, rest = mechanics(params, stage)
    mass = mech.mass_kg
    stiffness = mech.stiffness_N_m
    damping = mech.damping_N_s_m
    k_wall = inputs.wall_stiffness_N_m
    if k_wall > 0.0:  # the outside spring joins the stage's own, in the implicit step
        rest = (stiffness * rest + k_wall * inputs.wall_position_m) / (stiffness + k_wall)
        stiffness += k_wall
        damping += inputs.wall_damping_N_s_m
    extra = inputs.extra_friction_N
    contact = state.contact_m
    heavy = stage is Stage.ENGAGEMENT and contact <= x < state.index_end_m
    if stage is Stage.ENGAGEMENT:
        extra += state.tooth_force_N
        if heavy:  # turning the gear through the chamfers
            index_mass, index_drag = chamfer_load(
                params, inputs.gear_inertia_kg_m2, inputs.gear_drag_Nm
            )
            mass += index_mass
            extra += index_drag
    # The detents: their force at x, linearized where they stiffen (the stiffness joins the
    # implicit step, so the stop and its detent ring as one spring at any step). Each is
    # evaluated only within its reach (beyond, it is flat).
    nd, gd = params.neutral_detent, params.gear_detent
    n_width, g_width = nd.width_m, gd.width_m
    n_reach, g_reach = n_width + nd.far_width_m, g_width + gd.far_width_m
    x_gear = params.in_gear_position_m
    near_n = -n_reach < x < n_reach
    near_g = -g_reach < x - x_gear < g_reach
    detent = k_detent = u_n = u_g = 0.0
    if near_n:
        detent, u_n, k_detent = _detent(x, 0.0, n_width, nd)
    if near_g:
        f, u_g, k = _detent(x, x_gear, -g_width, gd)
        detent += f
        k_detent += k
    if k_detent > 0.0:  # f(x') = f(x) - k_detent * (x' - x): a spring relaxed at x, plus f(x)
        rest = (stiffness * rest + k_detent * x) / (stiffness + k_detent)
        stiffness += k_detent
    else:
        k_detent = 0.0
    integrate = (
        stick_slip_midpoint_step
        if stage is Stage.STOP or stage is Stage.IN_GEAR
        else stick_slip_step
    )
    x1, v1, _ = integrate(
        x,
        v,
        force + detent,
        mass,
        damping,
        stiffness,
        rest,
        mech.static_friction_N + extra,
        mech.sliding_friction_N + extra,
        params.stick_velocity_m_s,
        dt_s,
    )
    if x1 != x:
        near_n1 = -n_reach < x1 < n_reach
        near_g1 = -g_reach < x1 - x_gear < g_reach
        if near_n or near_g or near_n1 or near_g1:
            # The detents' linearized force did work over the step; any of it beyond the fall
            # of their potential is taken back from the kinetic energy: they stay conservative.
            dx = x1 - x
            excess = (detent - 0.5 * k_detent * dx) * dx
            if near_n or near_n1:
                before = u_n if near_n else _flat_J(n_width, nd)
                after = _detent(x1, 0.0, n_width, nd)[1] if near_n1 else _flat_J(n_width, nd)
                excess += after - before
            if near_g or near_g1:
                before = u_g if near_g else _flat_J(g_width, gd)
                after = _detent(x1, x_gear, -g_width, gd)[1] if near_g1 else _flat_J(g_width, gd)
                excess += after - before
            if excess > 0.0:
                kinetic = 0.5 * mass * v1 * v1
                if kinetic > excess:
                    v1 *= math.sqrt(1.0 - excess / kinetic)
                else:
                    x1, v1 = x, 0.0
    reaction = force - mech.mass_kg * (v1 - v) / dt_s

    # Guards on position, at the end of the motion of this step.
    new_stage = stage
    rng_state = state.rng_state
    tooth = state.tooth_force_N
    index_end = state.index_end_m
    meets = False
    x_sync = params.synchronization_position_m
    if stage is Stage.NEUTRAL:
        if x1 >= x_sync and v1 > 0.0:
            x1, v1, new_stage = x_sync, 0.0, Stage.SYNCHRONIZATION
        elif x1 < -params.in_gear_position_m:
            # The rear stop: the slot ends as far behind neutral as the gear is in front (the
            # opposite gear's end stop); unilateral and plastic, so it only takes energy.
            x1, v1 = -params.in_gear_position_m, 0.0
    elif stage is Stage.GATE_OPEN:
        x_teeth = params.teeth_position_m
        if x1 < x_sync:
            new_stage = Stage.RETURNING
        elif x1 >= x_teeth:
            new_stage = Stage.ENGAGEMENT
            rng_state, u = next_uniform(rng_state)
            tooth = u * params.tooth_force_spread_N
            miss = params.chamfer.no_contact_fraction
            index_end = contact = 0.0
            if u >= miss:
                # Where the chamfer faces meet (the angle sets how much of the face the sleeve's
                # tip passes freely); they turn the gear from there to the chamfers' end.
                travel = params.chamfer.travel_m
                contact = x_teeth + (u - miss) / (1.0 - miss) * travel
                index_end = x_teeth + travel
    elif stage is Stage.ENGAGEMENT:
        if x1 >= index_end:
            meets = index_end > 0.0 and not heavy and x < contact  # met and passed in one step
            index_end = 0.0  # the teeth are in line: the chamfers are done with this gear
        if x1 >= params.teeth_end_position_m:
            new_stage = Stage.FREE_TRAVEL
        elif x1 < params.teeth_position_m:
            new_stage = Stage.RETURNING
    elif stage is Stage.FREE_TRAVEL:
        if x1 >= params.in_gear_position_m:
            # The stop's spring starts at x_gear: enter it there, so no spring energy appears
            # from the part of the step that overshot the boundary.
            x_gear = params.in_gear_position_m
            # ... and no kinetic energy either: v1 holds the whole step's acceleration, but the
            # driver did work only up to x_gear. Cap the kinetic energy at what it was plus that
            # work less the detents' potential climb (friction and damping only take away).
            gained = force * (x_gear - x) - (
                detent_energy_J(x_gear, params) - detent_energy_J(x, params)
            )
            cap = 0.5 * mech.mass_kg * v * v + gained
            kinetic = 0.5 * mech.mass_kg * v1 * v1
            if kinetic > cap:
                v1 = math.sqrt(2.0 * cap / mech.mass_kg) if cap > 0.0 else 0.0
            x1 = x_gear
            new_stage = Stage.STOP
        elif x1 < params.teeth_end_position_m:
            new_stage = Stage.RETURNING  # pulled back into the teeth: on the way out
    elif stage is Stage.STOP or stage is Stage.IN_GEAR:
        x_gear = params.in_gear_position_m
        end = params.stop_travel_m
        if end > 0.0 and x1 > x_gear + end:
            # The gate's end: the lever cannot press further into the stop (plastic).
            x1, v1 = x_gear + end, 0.0
        pulled = reversal > 0.0 and reversal >= params.reversal_time_s
        if x1 < x_gear - params.detent_release_m and pulled:
            # Only the driver's pull, held, takes the gear out: a rebound off the stop after a
            # release (the hand let go, or dragged back with the knob) stays in the in-gear well
            # (the sleeve's detent groove and the teeth's back taper), whose spring brings it
            # back to x_gear.
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
            progress = 0.0  # back behind the ring after passing it: the next push starts anew
        elif v1 > 0.0 and force > 0.0:
            # Pushed forward again: the sleeve goes on where the step started (past the ring,
            # it cannot block it again).
            if x < params.teeth_position_m:
                new_stage = Stage.GATE_OPEN
            elif x < params.teeth_end_position_m:
                new_stage = Stage.ENGAGEMENT
            else:
                new_stage = Stage.FREE_TRAVEL

    if new_stage is not stage:
        v1 = _hand_over(v1, x1, stage, new_stage, params)
    if new_stage is Stage.ENGAGEMENT and (meets or (contact <= x1 < index_end and not heavy)):
        # The chamfers meet: the lever picks up the gear's inertia (a plastic impact), also when
        # the step passed the whole face (the gear takes the sleeve's speed whatever the angle).
        index_mass = chamfer_load(params, inputs.gear_inertia_kg_m2, inputs.gear_drag_Nm)[0]
        v1 = hand_over_velocity(v1, mech.mass_kg, mech.mass_kg + index_mass)
    stage_time = state.stage_time_s + dt_s if new_stage is state.stage else 0.0
    new_state = EngagementState(
        new_stage, x1, v1, stage_time, progress, tooth, rng_state, index_end, reversal, contact
    )
    return new_state, EngagementOutputs(x1, v1, force, reaction, new_stage.value)


def energy_J(state: EngagementState, params: EngagementParams) -> float:
    """Mechanical energy (J) of the lever in a free stage: kinetic (the gear's, while the chamfers
    turn it, included), the stage's spring and the detents."""
    mech, rest = mechanics(params, state.stage)
    mass = mech.mass_kg
    if state.stage is Stage.ENGAGEMENT and state.contact_m <= state.position_m < state.index_end_m:
        mass += chamfer_load(params, None, None)[0]
    stretch = state.position_m - rest
    return (
        0.5 * mass * state.velocity_m_s**2
        + 0.5 * mech.stiffness_N_m * stretch**2
        + detent_energy_J(state.position_m, params)
    )


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
