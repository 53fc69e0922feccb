"""The complete H-pattern gearshift (2 DOF), after section 3.5 of the paper, and beyond it.

    y (select) ->          planes at planes_y_m; x (engage) forward +, back -
         1     3     5        a slot per gear: a channel slot_width_m wide along x
         |     |     |
    =====+=====+=====+=====   the neutral corridor: |x| <= corridor_width_m / 2
         |     |     |
         2     4     R

The workspace is divided into areas (`Region`): the corridor, the mouths (the corridor where it
meets a slot), the slots, and outside (beyond a wall). A manager identifies the area from (x, y)
and hands it to the two axis controllers:
- X: along the slot, s = direction * x runs the single-gear engagement model (its stages and
  its random tooth peaks) with the direction of the side the lever is on; in the corridor its
  neutral stage. If the lever is not aligned with a slot on that side, a gate wall at the
  corridor's edge stops it: a gear can be entered only from the corridor.
- Y: in the corridor, the select spring centres the knob on `centre_plane` with a detent well at
  every plane, a preloaded lockout spring before a reverse plane (if set), and walls at the
  corridor's ends; in a slot, the slot's impedance holds the knob on the slot's centre line.
Walls and the slot hold are spring-dampers toward the nearest legal path, integrated implicitly
with the lever (so they are passive at any step); their stiffness and damping also satisfy the
sampled-wall bound K*T/2 + B < b (Colgate & Schenkel) with the lever's own damping b at the
1 kHz rate, so a device rendering them explicitly stays passive too (checked when loading).

The synchronizer model (`synchronizer.py`) says when the synchro gate may open; the engaged gear
is an output with hysteresis (in mesh past the teeth, out of mesh back before them), with an
event at each change.

Trucks (issue 30), both optional in `Layout` and off in the car presets (their step unchanged):
- A range/splitter box (`Layout.truck`, the game's slot table: a row per slot, range and
  splitter, with its gear and ratio): the range switch and the splitter button on the knob are
  inputs; the gear is (slot, range, splitter), and the synchronizer matches the row's ratio. The
  range executes only with the lever in neutral (the range synchro needs the main box out of
  gear: a range pre-selected in gear waits for neutral); the splitter executes when the torque
  is off (clutch past `clutch_open_above`, or throttle at most THROTTLE_OFF) or in neutral: a
  split pre-selected under torque waits, as in ETS2. A slot with no row for the range (the
  crawler in high range) is closed: a gate wall, as an interlock.
- A double-H (`Layout.range_plane` > 0): the planes from `range_plane` on are the high half,
  the select spring centres on `high_centre_plane` there, and a detent (a triangular bump of
  `range_detent_N`) stands between the halves; the range is the half the knob is in.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

from carfeel.models.gearshift import engagement, synchronizer
from carfeel.models.gearshift.engagement import EngagementParams, EngagementState, Stage
from carfeel.models.gearshift.synchronizer import SynchronizerParams, SynchronizerState
from carfeel.models.mechanics import stick_slip_step

NEUTRAL_GEAR = "N"
THROTTLE_OFF = 0.05
"""A truck's splitter executes in gear with the throttle at most this (0..1), or the clutch in."""
WALL_DEPTH_M = 0.003
"""The deepest a knob sinks into a wall before the wall is rigid (the gate's compliance)."""
IN_MESH = frozenset({Stage.FREE_TRAVEL, Stage.STOP, Stage.IN_GEAR})


class Region(Enum):
    CORRIDOR = "corridor"
    MOUTH = "mouth"
    SLOT = "slot"
    OUTSIDE = "outside"


@dataclass(frozen=True, slots=True)
class GearSlot:
    name: str
    """"1".."6" or "R"."""
    plane: int
    """Index into `Layout.planes_y_m`."""
    direction: int
    """+1: the slot runs forward (x > 0), -1: back."""
    ratio: float
    """Gearbox ratio, input over output speed; negative for reverse."""
    synchronizer: str
    """Where its synchronizer sits: "output" or "input" shaft, or "none"."""
    cone_scale: float
    """Its cone torque relative to the synchronizer's cone (number of cones x radius ratio)."""


@dataclass(frozen=True, slots=True)
class TruckGear:
    """A row of a range/splitter box's gear table (the game's own: ETS2's hshifter slots)."""

    slot: str
    """The lever's slot (a `GearSlot.name`)."""
    range_high: bool
    """The range of this row: true high, false low."""
    splitter_high: bool
    """The splitter position of this row: true high, false low."""
    gear: int
    """The gear number as the game counts it: 1.. forward, -1.. reverse."""
    ratio: float
    """Gearbox ratio in this slot, range and splitter (negative for reverse)."""
    handle_position: int
    """The game's H-shifter handle position of the slot (ETS2's hshifterPosition), 0..31."""

    @property
    def name(self) -> str:
        """The gear's name: "1".."14", reverse "R1", "R2" ..."""
        return str(self.gear) if self.gear > 0 else f"R{-self.gear}"


@dataclass(frozen=True, slots=True)
class Layout:
    planes_y_m: tuple[float, ...]
    """The y of each select plane, increasing (`GearSlot.plane` indexes it)."""
    centre_plane: int
    """The plane the select spring centres the knob on (the 3-4 plane of a 5-speed)."""
    gears: tuple[GearSlot, ...]
    """The gear slots: each one's name, plane, direction, ratio and synchronizer."""
    slot_width_m: float
    """Width of each gear slot along y: its walls hold the knob beyond half of it from the plane."""
    corridor_width_m: float
    """Width of the neutral corridor along x (|x| <= half of it); the slots start at its edges."""
    reverse_lockout_N: float
    """Extra select force to pass into a plane that holds only reverse (0: no lockout)."""
    truck: tuple[TruckGear, ...] = ()
    """A range/splitter box's gear table (empty: the slots' own gears and ratios)."""
    range_plane: int = 0
    """A double-H: the first plane of the high half (0: a single H)."""
    high_centre_plane: int = 0
    """A double-H: the plane the select spring centres on in the high half."""
    range_detent_N: float = 0.0
    """A double-H: the detent's peak force between the halves, N."""

    def truck_gear(self, slot: str, range_high: bool, splitter_high: bool) -> TruckGear | None:
        """The truck table's row for a slot, range and splitter (None: no gear there)."""
        for row in self.truck:
            same = row.range_high == range_high and row.splitter_high == splitter_high
            if row.slot == slot and same:
                return row
        return None

    def range_boundary_m(self) -> float:
        """A double-H: the y of the detent between the halves (inf for a single H)."""
        if self.range_plane <= 0:
            return math.inf
        return 0.5 * (self.planes_y_m[self.range_plane - 1] + self.planes_y_m[self.range_plane])

    def gear_at(self, plane: int, direction: int) -> GearSlot | None:
        for gear in self.gears:
            if gear.plane == plane and gear.direction == direction:
                return gear
        return None

    def gear_names(self) -> list[str]:
        """The gears a driver's sequence may name: the truck table's (in its order), else the
        slots'."""
        if self.truck:
            gears = sorted({row.gear for row in self.truck}, key=lambda g: (g < 0, abs(g)))
            return [str(g) if g > 0 else f"R{-g}" for g in gears]
        return [gear.name for gear in self.gears]

    def gear(self, name: str) -> GearSlot:
        for gear in self.gears:
            if gear.name == name:
                return gear
        raise KeyError(name)

    @property
    def lockout_plane(self) -> int | None:
        """The plane that only reverse occupies, behind the lockout (None without lockout)."""
        if self.reverse_lockout_N <= 0.0:
            return None
        for gear in self.gears:
            if gear.name == "R":
                others = [g for g in self.gears if g.plane == gear.plane and g.name != "R"]
                return None if others else gear.plane
        return None


@dataclass(frozen=True, slots=True)
class SelectParams:
    """The y (select) axis: the lever's select mechanics and its springs."""

    mass_kg: float
    """Mass of the lever along y (select), reflected at the knob."""
    damping_N_s_m: float
    """Viscous damping of the lever along y (the walls' and the slot's add to it)."""
    static_friction_N: float
    """Static (break-away) friction along y."""
    sliding_friction_N: float
    """Sliding friction along y."""
    centring_stiffness_N_m: float
    """Select spring centring the knob on `centre_plane` in the corridor (`high_centre_plane` in a
    double-H's high half)."""
    detent_stiffness_N_m: float
    """Stiffness of the detent well toward each plane, within detent_width_m of it (in the
    corridor)."""
    detent_width_m: float
    """Half-width of the detent well around each plane."""
    slot_stiffness_N_m: float
    """Stiffness of a slot's walls, holding the knob within half slot_width_m of its plane."""
    slot_damping_N_s_m: float
    """Damping of a slot's walls while the knob presses them."""
    lockout_stiffness_N_m: float
    """Stiffness of the reverse lockout's spring, preloaded to reverse_lockout_N, from halfway to
    the reverse plane."""


@dataclass(frozen=True, slots=True)
class WallParams:
    stiffness_N_m: float
    """Stiffness of the gate walls: the corridor's edge where no slot faces the knob, and its ends
    along y."""
    damping_N_s_m: float
    """Damping of the gate walls while the knob presses them."""


@dataclass(frozen=True, slots=True)
class FeelParams:
    """What users of force-feedback shifters ask for, on top of the gearbox's own forces.

    Latch: a friction bump a little way into every slot, before the synchro ring (triangular,
    `latch_force_N` at `latch_position_m`, gone `latch_width_m` either side): you feel the lever
    leave neutral, and come back into it. Friction is passive, so the latch is too.
    Click: when the lever reaches the end stop faster than `click_speed_m_s`, a decaying
    vibration A * exp(-t / decay) * sin(2 pi f t) on the force rendered at the knob.
    """

    latch_position_m: float
    """Where the latch's friction peaks, measured into each slot from neutral."""
    latch_width_m: float
    """Half-width of the latch: its friction falls linearly to 0 this far either side."""
    latch_force_N: float
    """Peak friction of the latch, added to the static and sliding (0: no latch)."""
    click_amplitude_N: float
    """Amplitude A of the click's vibration on the rendered force (0: no click)."""
    click_frequency_hz: float
    """Frequency f of the click's vibration."""
    click_decay_s: float
    """Time constant of the click's decay (it is cut off after five of these)."""
    click_speed_m_s: float
    """The click plays when the lever enters the end stop faster than this."""


@dataclass(frozen=True, slots=True)
class HPatternParams:
    layout: Layout
    engagement: EngagementParams
    select: SelectParams
    walls: WallParams
    synchronizer: SynchronizerParams
    feel: FeelParams


class HPatternState(NamedTuple):
    lever: EngagementState
    """The x axis, in slot coordinates s = direction * x."""
    direction: int
    y_m: float
    vy_m_s: float
    plane: int
    """The plane the knob is in (frozen while in a slot, the nearest one in the corridor)."""
    in_slot: bool
    """The lever entered a slot from the corridor (aligned with it) and has not left it."""
    sync: SynchronizerState
    gear: str
    click_s: float
    """Time since the lever last hit the end stop (the click's clock); inf before any."""
    range_high: bool = False
    """The range in effect (a truck's range box; a double-H's half)."""
    splitter_high: bool = False
    """The splitter in effect (a truck's)."""


class HPatternInputs(NamedTuple):
    force_x_N: float
    force_y_N: float
    clutch_pedal: float = 1.0
    vehicle_speed_m_s: float = 0.0
    engine_speed_rad_s: float = 0.0
    range_high: bool = False
    """A truck's range switch on the knob (pre-selection: see the module's docstring)."""
    splitter_high: bool = False
    """A truck's splitter button on the knob."""
    throttle: float = 0.0
    """0..1: under torque (above THROTTLE_OFF, clutch engaged) a split waits."""


class HPatternOutputs(NamedTuple):
    x_m: float
    y_m: float
    vx_m_s: float
    vy_m_s: float
    force_x_N: float
    force_y_N: float
    reaction_x_N: float
    """Force of the gearbox on the knob along x (F - m*a), grinding included."""
    reaction_y_N: float
    region: str
    gear: str
    event: str
    """"engage 3", "disengage 3" at the step where the gear output changes, else ""."""
    stage: str
    speed_difference_rad_s: float
    grind_N: float
    click_N: float
    range_high: bool = False
    splitter_high: bool = False


def initial_state(
    params: HPatternParams, seed: int = 0, input_speed_rad_s: float = 0.0
) -> HPatternState:
    """At rest in neutral on the centre plane."""
    layout = params.layout
    centre = layout.centre_plane
    return HPatternState(
        engagement.initial_state(seed),
        1,
        layout.planes_y_m[centre],
        0.0,
        centre,
        False,
        synchronizer.initial_state(input_speed_rad_s),
        NEUTRAL_GEAR,
        math.inf,
    )


def nearest_plane(layout: Layout, y: float) -> int:
    planes = layout.planes_y_m
    best = 0
    for i in range(1, len(planes)):
        if abs(planes[i] - y) < abs(planes[best] - y):
            best = i
    return best


def _facing(layout: Layout, plane: int, y: float) -> bool:
    """The knob faces the plane's slots: within half a slot of its centre line, or, on an
    outermost plane, pressed into the gate's end beyond it (a driver finds reverse that way)."""
    planes = layout.planes_y_m
    off = y - planes[plane]
    half = 0.5 * layout.slot_width_m
    if abs(off) <= half:
        return True
    outward = (plane == len(planes) - 1 and off > 0.0) or (plane == 0 and off < 0.0)
    return outward and abs(off) <= half + WALL_DEPTH_M


def _select_springs(
    ahead: float, y: float, layout: Layout, select: SelectParams, walls: WallParams
) -> tuple[float, float, float]:
    """(stiffness, rest, extra damping) of the springs on y in the corridor, combined.

    `ahead` is where the knob would be at the end of the step at its speed: the corridor's end
    walls switch on one step ahead, so the knob meets them at the edge.
    """
    planes = layout.planes_y_m
    centre_y = planes[layout.centre_plane]
    boundary = layout.range_boundary_m()
    if y > boundary:  # a double-H's high half: its own neutral
        centre_y = planes[layout.high_centre_plane]
    k = select.centring_stiffness_N_m
    moment = k * centre_y
    damping = 0.0
    if layout.range_detent_N > 0.0 and boundary < math.inf:
        # The detent between the halves: a spring pushing away from the boundary, up to
        # range_detent_N at it (a triangular bump: a potential, so passive), over the gap
        # between the planes' detent wells.
        width = boundary - planes[layout.range_plane - 1] - select.detent_width_m
        if abs(y - boundary) < width:
            k_d = layout.range_detent_N / width
            k += k_d
            moment += k_d * (boundary + width if y > boundary else boundary - width)
    nearest = nearest_plane(layout, y)
    y_p = planes[nearest]
    if abs(y - y_p) < select.detent_width_m:
        k += select.detent_stiffness_N_m
        moment += select.detent_stiffness_N_m * y_p
    lock = layout.lockout_plane
    if lock is not None:
        # A preloaded spring pushes back toward the neighbouring plane from half-way on.
        neighbour = lock - 1 if lock > 0 else lock + 1
        start = 0.5 * (planes[lock] + planes[neighbour])
        toward = 1.0 if planes[lock] > planes[neighbour] else -1.0
        if (y - start) * toward > 0.0:
            k_l = select.lockout_stiffness_N_m
            rest = start - toward * layout.reverse_lockout_N / k_l
            k += k_l
            moment += k_l * rest
    half = 0.5 * layout.slot_width_m
    low, high = planes[0] - half, planes[-1] + half
    if ahead > high or ahead < low:
        k += walls.stiffness_N_m
        moment += walls.stiffness_N_m * (high if ahead > high else low)
        damping += walls.damping_N_s_m
    return k, moment / k, damping


def step(
    state: HPatternState, inputs: HPatternInputs, params: HPatternParams, dt_s: float
) -> tuple[HPatternState, HPatternOutputs]:
    """Advance the knob by `dt_s` under the driver's forces and the car's state."""
    layout = params.layout
    eng = params.engagement
    lever = state.lever
    direction = state.direction
    if lever.stage is Stage.NEUTRAL and lever.position_m < 0.0:
        # Through the centre of the corridor: the lever now faces the other side's slots.
        direction = -direction
        lever = lever._replace(position_m=-lever.position_m, velocity_m_s=-lever.velocity_m_s)
    s = lever.position_m
    y = state.y_m
    half_corridor = 0.5 * layout.corridor_width_m
    in_slot = state.in_slot and s > half_corridor
    plane = state.plane if in_slot else nearest_plane(layout, y)
    if lever.synchronization_progress > 0.0 and (
        direction != state.direction or plane != state.plane
    ):
        # Another slot: the fixed synchronizer's progress belonged to the last gear.
        lever = lever._replace(synchronization_progress=0.0)
    slot = layout.gear_at(plane, direction)
    range_high, splitter_high = state.range_high, state.splitter_high
    if layout.truck:
        # Pre-selection: the range waits for neutral, a split for the torque to go off.
        neutral = state.gear == NEUTRAL_GEAR
        if neutral and lever.stage is Stage.NEUTRAL:
            range_high = inputs.range_high
        torque_off = (
            inputs.clutch_pedal >= params.synchronizer.clutch_open_above
            or inputs.throttle <= THROTTLE_OFF
        )
        if neutral or torque_off:
            splitter_high = inputs.splitter_high
        if slot is not None:
            row = layout.truck_gear(slot.name, range_high, splitter_high)
            named = (
                None if row is None else dataclasses.replace(slot, name=row.name, ratio=row.ratio)
            )
            slot = named
    aligned = slot is not None and _facing(layout, plane, y)

    # Synchronizer: which gear is selected, is it in mesh, how hard is the ring pressed.
    ratio = slot.ratio if slot is not None and (aligned or in_slot) else None
    location = slot.synchronizer if slot is not None else synchronizer.NONE
    axial = direction * inputs.force_x_N if lever.stage is Stage.SYNCHRONIZATION else 0.0
    sync_state, sync_out = synchronizer.step(
        state.sync,
        synchronizer.SynchronizerInputs(
            inputs.vehicle_speed_m_s,
            inputs.engine_speed_rad_s,
            inputs.clutch_pedal,
            ratio,
            lever.stage in IN_MESH,
            axial,
            location,
            slot.cone_scale if slot is not None else 1.0,
        ),
        params.synchronizer,
        dt_s,
    )

    # X: the engagement along the slot; outside a slot and not aligned with one, the gate wall
    # at the corridor's edge (switched on one step ahead, so the lever meets it at the edge).
    walls = params.walls
    walled_x = not in_slot and not aligned and s + lever.velocity_m_s * dt_s > half_corridor
    feel = params.feel
    latch = 0.0
    if lever.stage is Stage.NEUTRAL or lever.stage is Stage.RETURNING:
        off = abs(s - feel.latch_position_m)
        if off < feel.latch_width_m and (in_slot or aligned):
            latch = feel.latch_force_N * (1.0 - off / feel.latch_width_m)
    # The gear the chamfers turn: the input side's inertia (and drag), seen at the synchronizer.
    sync_p = params.synchronizer
    reflect = abs(slot.ratio) if slot is not None and location != synchronizer.INPUT else 1.0
    x_inputs = engagement.EngagementInputs(
        direction * inputs.force_x_N,
        walls.stiffness_N_m if walled_x else 0.0,
        walls.damping_N_s_m if walled_x else 0.0,
        half_corridor,
        sync_out.gate_open,
        latch,
        sync_p.input_inertia_kg_m2 * reflect * reflect,
        sync_p.drag_torque_Nm * reflect,
    )
    impact_speed = lever.velocity_m_s
    was_stop = lever.stage is Stage.STOP
    lever, x_out = engagement.step(lever, x_inputs, eng, dt_s)
    s1 = lever.position_m
    entered = not in_slot and aligned and s1 > half_corridor
    if not in_slot and not entered and s1 > half_corridor + WALL_DEPTH_M:
        # However hard the push, the gate is metal: no deeper than its compliance allows
        # (a plastic contact: the lever stops there, which only takes energy away).
        s1 = half_corridor + WALL_DEPTH_M
        lever = lever._replace(position_m=s1, velocity_m_s=0.0)
    click_s = state.click_s + dt_s
    if lever.stage is Stage.STOP and not was_stop and impact_speed > feel.click_speed_m_s:
        click_s = 0.0
    click = 0.0
    if click_s < 5.0 * feel.click_decay_s:
        click = (
            feel.click_amplitude_N
            * math.exp(-click_s / feel.click_decay_s)
            * math.sin(2.0 * math.pi * feel.click_frequency_hz * click_s)
        )

    # Y: select springs in the corridor (and in the gate wall), the slot's hold in a slot.
    sel = params.select
    if not (in_slot or entered):
        k_y, rest_y, damping_y = _select_springs(y + state.vy_m_s * dt_s, y, layout, sel, walls)
    else:
        # The slot is a channel slot_width_m wide: its walls hold the knob only beyond it,
        # switched on one step ahead like the other walls (so entering never stretches them).
        y_p = layout.planes_y_m[plane]
        ahead = y + state.vy_m_s * dt_s - y_p
        half_slot = 0.5 * layout.slot_width_m
        if ahead > half_slot or ahead < -half_slot:
            edge = y_p + (half_slot if ahead > 0.0 else -half_slot)
            k_y, rest_y, damping_y = sel.slot_stiffness_N_m, edge, sel.slot_damping_N_s_m
        else:
            k_y, rest_y, damping_y = 0.0, y_p, 0.0
    y1, vy1, _ = stick_slip_step(
        y,
        state.vy_m_s,
        inputs.force_y_N,
        sel.mass_kg,
        sel.damping_N_s_m + damping_y,
        k_y,
        rest_y,
        sel.static_friction_N,
        sel.sliding_friction_N,
        eng.stick_velocity_m_s,
        dt_s,
    )
    reaction_y = inputs.force_y_N - sel.mass_kg * (vy1 - state.vy_m_s) / dt_s

    # The engaged gear, with hysteresis: in mesh past the teeth, out of mesh back before them.
    gear = state.gear
    event = ""
    if gear == NEUTRAL_GEAR:
        if lever.stage in IN_MESH and slot is not None:
            gear = slot.name
            event = f"engage {gear}"
    elif s1 < eng.teeth_position_m or lever.stage is Stage.NEUTRAL:
        event = f"disengage {gear}"
        gear = NEUTRAL_GEAR
    elif layout.truck and slot is not None and slot.name != gear:  # a split, executed in gear
        gear = slot.name
        event = f"engage {gear}"

    x1 = direction * s1
    in_slot = in_slot or entered
    if s1 > half_corridor:
        region = Region.SLOT if in_slot else Region.OUTSIDE
    else:
        half = 0.5 * layout.slot_width_m + WALL_DEPTH_M
        if y1 > layout.planes_y_m[-1] + half or y1 < layout.planes_y_m[0] - half:
            region = Region.OUTSIDE
        else:
            region = Region.MOUTH if aligned else Region.CORRIDOR
    if layout.range_plane > 0:
        range_high = y1 > layout.range_boundary_m()
    new_state = HPatternState(
        lever,
        direction,
        y1,
        vy1,
        plane,
        in_slot,
        sync_state,
        gear,
        click_s,
        range_high,
        splitter_high,
    )
    return new_state, HPatternOutputs(
        x1,
        y1,
        direction * lever.velocity_m_s,
        vy1,
        inputs.force_x_N,
        inputs.force_y_N,
        direction * (x_out.reaction_N + sync_out.grind_N + click),
        reaction_y,
        region.value,
        gear,
        event,
        x_out.stage,
        sync_out.speed_difference_rad_s,
        sync_out.grind_N,
        click,
        range_high,
        splitter_high,
    )
