"""A driver who works through a gear sequence on the H-pattern, and can make mistakes on request.

For each gear of the sequence: pull the lever back into the corridor (the mirror of eq. 10), move
it across to the gear's plane (a hand that aims at the plane: a spring toward it limited to
`select_force_N`, less a damping that caps the crossing speed at select_force / damping, the
mirror of eq. 10 across the gate), push it in along the slot with the paper's law (eq. 10,
through the same hand as `drivers.shift`), let go once in gear, wait `hold_s`, go on. "N" pulls
back to neutral and leaves the knob on the centre plane. The clutch pedal is held at
`clutch_pedal` throughout.

Mistakes, for the tests and for demonstrations:
- `early_clutch_release_shift` = k > 0: the clutch is released (pedal 0) while pushing into the
  k-th gear of the sequence, so its synchronizer cannot finish (balk, grinding if forced);
- `wall_push_shift` = k > 0: while crossing between planes to the k-th gear the driver already
  pushes toward it, so the knob runs into the gate wall until it is aligned with the slot.

A truck's range/splitter box (`Layout.truck`): the sequence names the truck's gears ("1".."14",
"R1"); the driver sets the range switch for the next gear as it pulls out of the last (the box
waits for neutral to execute it) and the splitter once in neutral; a split in the same slot and
range (3 -> 4) is the splitter alone, the lever staying in gear.

Signs: x forward, y toward the higher planes, as in `carfeel.models.gearshift.hpattern`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import NamedTuple

from carfeel.models.drivers.shift import ShiftDriverParams, grip_step
from carfeel.models.gearshift.hpattern import NEUTRAL_GEAR, Layout, TruckGear


class Phase(Enum):
    PULL = "pull"
    SELECT = "select"
    PUSH = "push"
    RELEASE = "release"
    DONE = "done"


@dataclass(frozen=True, slots=True)
class HPatternDriverParams:
    """How this driver selects; the push and pull along x are the shift driver's (`hand`)."""

    select_force_N: float
    """Largest force of the hand across the gate (y): its aim spring is capped at this."""
    select_stiffness_N_m: float
    """Stiffness of the hand's aim toward the target plane along y, before the cap."""
    select_damping_N_s_m: float
    """Damping of the hand along y: it caps the crossing speed at select_force_N / this."""
    select_tolerance_m: float
    """Close enough to the plane to push in."""
    hold_s: float
    """Pause in each gear (and in neutral) before the next."""


@dataclass(frozen=True, slots=True)
class Script:
    """What this driver does in one run, and where the gears are."""

    sequence: tuple[str, ...]
    layout: Layout
    hand: ShiftDriverParams
    """Push and pull laws and the hand's impedance along x (the shift preset's driver)."""
    habits: HPatternDriverParams
    clutch_pedal: float = 1.0
    early_clutch_release_shift: int = 0
    wall_push_shift: int = 0
    outer_push_m: float = 0.0
    """For a gear on an outermost plane, aim this far beyond the plane: press the knob against
    the gate's end, as drivers do for reverse. Offline the knob is the hand's and needs none; on
    a device the model's knob lags the handle by the coupling's stretch, and pressing against
    the end is how a person makes up for it."""


class HPatternDriverState(NamedTuple):
    target_index: int
    """Position in the sequence of the gear being shifted to."""
    phase: Phase
    phase_time_s: float
    hand_position_m: float
    hand_velocity_m_s: float
    activation: float


class HPatternDriverInputs(NamedTuple):
    x_m: float
    y_m: float
    vx_m_s: float
    vy_m_s: float


class HPatternDriverOutputs(NamedTuple):
    force_x_N: float
    force_y_N: float
    clutch_pedal: float
    phase: str
    target: str
    range_high: bool = False
    """A truck's range switch, as the driver has set it."""
    splitter_high: bool = False


def initial_state() -> HPatternDriverState:
    return HPatternDriverState(0, Phase.PULL, 0.0, 0.0, 0.0, 0.0)


def _row(layout: Layout, name: str) -> TruckGear | None:
    """A truck's gear by name: its first row in the table (None: not a truck's gear)."""
    return next((row for row in layout.truck if row.name == name), None)


def _target(script: Script, index: int) -> tuple[str, float, int]:
    """(name, plane y, direction) of the index-th gear; neutral aims at the centre plane."""
    layout = script.layout
    name = script.sequence[index]
    if name == NEUTRAL_GEAR:
        return name, layout.planes_y_m[layout.centre_plane], 0
    row = _row(layout, name)
    gear = layout.gear(name if row is None else row.slot)
    return name, layout.planes_y_m[gear.plane], gear.direction


def _buttons(script: Script, index: int) -> tuple[bool, bool, str]:
    """(range high, splitter high, slot) for the index-th gear: the last truck gear's at or
    before it (neutral keeps them), low and low before any."""
    for i in range(min(index, len(script.sequence) - 1), -1, -1):
        row = _row(script.layout, script.sequence[i])
        if row is not None:
            return row.range_high, row.splitter_high, row.slot
    return False, False, ""


def _split_only(script: Script, index: int) -> bool:
    """The next gear is in the same slot and range as this one: the splitter alone."""
    if index + 1 >= len(script.sequence) or not script.layout.truck:
        return False
    if NEUTRAL_GEAR in (script.sequence[index], script.sequence[index + 1]):
        return False
    return _buttons(script, index)[::2] == _buttons(script, index + 1)[::2]


def _outward(script: Script, plane_y: float, direction: int) -> float:
    """+1 or -1 for a gear on the last or first plane (toward the gate's end), else 0."""
    planes = script.layout.planes_y_m
    if direction == 0 or len(planes) < 2 or not script.outer_push_m:
        return 0.0
    if plane_y == planes[-1]:
        return 1.0
    return -1.0 if plane_y == planes[0] else 0.0


def _next_phase(
    state: HPatternDriverState, knob: HPatternDriverInputs, script: Script
) -> tuple[int, Phase]:
    index, phase = state.target_index, state.phase
    if phase is Phase.DONE:
        return index, phase
    habits, hand = script.habits, script.hand
    _, plane_y, direction = _target(script, index)
    corridor = 0.5 * script.layout.corridor_width_m
    if phase is Phase.PULL and abs(knob.x_m) <= 0.5 * corridor:
        return index, Phase.SELECT
    if phase is Phase.SELECT:
        off = knob.y_m - plane_y
        outward = _outward(script, plane_y, direction)
        if outward and off * outward > 0.0:  # pressed against the gate's end counts as there
            off = max(0.0, abs(off) - script.outer_push_m)
        near = abs(off) <= habits.select_tolerance_m and abs(knob.vy_m_s) < 0.05
        if near:
            return index, (Phase.RELEASE if direction == 0 else Phase.PUSH)
    if phase is Phase.PUSH:
        s, v = direction * knob.x_m, direction * knob.vx_m_s
        if s >= hand.release_position_m and v <= 0.0:
            return index, Phase.RELEASE
    if phase is Phase.RELEASE and state.phase_time_s >= habits.hold_s:
        if index + 1 >= len(script.sequence):
            return index, Phase.DONE
        if _split_only(script, index):  # in gear: the splitter's button, no lever
            return index + 1, Phase.RELEASE
        return index + 1, Phase.PULL
    return index, phase


def step(
    state: HPatternDriverState,
    inputs: HPatternDriverInputs,
    params: Script,
    dt_s: float,
) -> tuple[HPatternDriverState, HPatternDriverOutputs]:
    """The driver's forces on the knob and the clutch pedal for one step."""
    script = params
    habits, hand = script.habits, script.hand
    index, phase = _next_phase(state, inputs, script)
    changed = phase is not state.phase or index != state.target_index
    phase_time = 0.0 if changed else state.phase_time_s + dt_s
    name, plane_y, direction = _target(script, index)
    shift_number = index + 1
    pedal = script.clutch_pedal
    x, vx = inputs.x_m, inputs.vx_m_s

    # Along x: the hand pulls, pushes, lets go, or is off the knob.
    activation = 0.0 if changed and phase is not Phase.RELEASE else state.activation
    hand_x, hand_v = state.hand_position_m, state.hand_velocity_m_s
    half_slot = 0.5 * script.layout.slot_width_m
    between_planes = all(abs(inputs.y_m - p) > half_slot for p in script.layout.planes_y_m)
    wall_push = phase is Phase.SELECT and script.wall_push_shift == shift_number and between_planes
    # While selecting, the driver keeps the knob in the middle of the corridor (it may have
    # slipped into a slot's mouth from the gate).
    corridor = 0.5 * script.layout.corridor_width_m
    recentre = phase is Phase.SELECT and not wall_push and abs(x) > 0.5 * corridor
    if phase is Phase.PULL or phase is Phase.PUSH or wall_push or recentre:
        if changed or state.phase is Phase.DONE or state.activation == 0.0:
            hand_x, hand_v = x, vx  # the hand takes hold of the knob where it is
        activation = 1.0 - (1.0 - activation) * math.exp(-dt_s / hand.activation_time_s)
        if phase is Phase.PULL or recentre:
            side = 1.0 if x > 0.0 else -1.0
            bias = -side * activation * hand.pull_force_N
            gain = activation * hand.pull_force_N / hand.pull_velocity_m_s
        else:
            side = float(direction) if direction != 0 else 1.0
            bias = side * activation * hand.push_force_N
            gain = activation * hand.push_force_N / hand.push_velocity_m_s
        if phase is Phase.PUSH and script.early_clutch_release_shift == shift_number:
            pedal = 0.0
        hand_x, hand_v, force_x = grip_step(hand_x, hand_v, bias, gain, x, vx, hand, dt_s)
    elif phase is Phase.RELEASE and direction != 0:
        activation *= math.exp(-dt_s / hand.release_time_s)
        side = float(direction)
        bias = side * activation * hand.push_force_N
        gain = activation * hand.push_force_N / hand.push_velocity_m_s
        hand_x, hand_v, force_x = grip_step(hand_x, hand_v, bias, gain, x, vx, hand, dt_s)
    else:
        hand_x, hand_v, force_x, activation = x, vx, 0.0, 0.0

    # Along y: aim at the target plane while selecting and pushing; hands off otherwise.
    if phase is Phase.SELECT or phase is Phase.PUSH or phase is Phase.PULL:
        aim = plane_y if phase is not Phase.PULL else inputs.y_m
        if phase is not Phase.PULL:
            aim += _outward(script, plane_y, direction) * script.outer_push_m
        # Eq. (10) across the gate: the aimed force (a spring toward the plane, at most
        # select_force_N) less the damping, so the knob crosses at select_force / damping.
        aimed = habits.select_stiffness_N_m * (aim - inputs.y_m)
        aimed = max(-habits.select_force_N, min(habits.select_force_N, aimed))
        force_y = aimed - habits.select_damping_N_s_m * inputs.vy_m_s
    else:
        force_y = 0.0

    # The knob's buttons: the range pre-selected from the pull on, the splitter once out of gear.
    range_high, splitter_high, _ = _buttons(script, index)
    if phase is Phase.PULL and index > 0:
        splitter_high = _buttons(script, index - 1)[1]
    new_state = HPatternDriverState(index, phase, phase_time, hand_x, hand_v, activation)
    return new_state, HPatternDriverOutputs(
        force_x, force_y, pedal, phase.value, name, range_high, splitter_high
    )
