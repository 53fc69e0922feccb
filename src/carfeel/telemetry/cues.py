"""The lever's cues from the game's state (issue 29): what AB9's Active Shifter and BonusFFB
users ask for, done from the state the game publishes.

Pure functions of (lever state, game state) -> force, model units: N on the knob, signed along
the lever's axes (x engage, forward positive; slot coordinates s = direction * x where said),
and `LeverCues`, which holds what they need from tick to tick (the grind's phase, the gears'
ratios learned from the game, the interlock's count) and is what the H-pattern renderer calls
each sub-step. Every cue is scaled by `cue_weight`: the telemetry's fade (stale: gone within
the source's 0.3 s), and zero while the game plays a replay or is paused (nobody drives).

  gear rejection  a wall at the gear's entry (just before the synchronizer's ring) while the
                  clutch is out and the engine's speed differs from the gearbox input's for
                  that gear by more than `match_rpm`: a spring and damper of the gate walls'
                  own stiffness (sized with the model), not a buzz; it opens when the clutch
                  goes in or the revs come within the match.
  grind           while the knob presses into that wall: a vibration at the dog teeth's
                  passing frequency, |speed difference| / 60 x teeth (kept below a quarter of
                  the loop rate, an octave down at a time), its amplitude growing with the push.
  clutch bite     the engine's vibration reaches the lever through the clutch: 1 released,
                  fading to 0 across the bite point as the pedal goes in.
  lockout         a slot past the car's top gear (the game's gear count) is walled, clutch or
                  not; `sequential_locked` says when a sequential lever's push up from the
                  top gear or pull down from R is (no sequential lever is rendered yet).
  interlock       the lever's gear against the game's: a mismatch is counted (and the gear
                  output, where given, tells the game the lever's gear); with `hold`, a
                  lever in a gear while the game stays in neutral (it refused the shift) is
                  pushed back out to the gear's entry, as a gearbox pops a gear that did not
                  mesh.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from carfeel.models.gearshift.hpattern import WALL_DEPTH_M, HPatternParams, HPatternState
from carfeel.models.gearshift.synchronizer import output_speed_rad_s
from carfeel.telemetry.state import VehicleState, gear_name

RAD_S_TO_RPM = 30.0 / math.pi


@dataclass(frozen=True, slots=True)
class CueParams:
    wall_stiffness_N_m: float
    wall_damping_N_s_m: float
    match_rpm: float = 200.0
    """Revs within this of the gearbox input's: the gear goes in without the clutch (a dog box
    takes it; a synchronizer's cone absorbs the rest)."""
    clutch_in: float = 0.8
    """Pedal travel (0 released .. 1 floored) past which the clutch is in: the gate opens."""
    bite_point: float = 0.5
    bite_width: float = 0.2
    grind_teeth: int = 30
    grind_amplitude_N: float = 3.0
    """At a push of `grind_push_N` into the wall."""
    grind_push_N: float = 30.0
    hold_grace_s: float = 0.15
    """The game's neutral for this long with the lever in a gear: it refused (a live game
    follows the lever within two 60 Hz frames; a shift passes neutral for one or two)."""
    hold_force_N: float = 60.0
    """The push out of the gear: the gate wall's force at its full depth (20000 N/m x 3 mm)."""

    @classmethod
    def of(cls, pattern: HPatternParams) -> CueParams:
        """The walls of the gearbox's own gate (their stiffness is what the model is sized to)."""
        return cls(pattern.walls.stiffness_N_m, pattern.walls.damping_N_s_m)


def cue_weight(weight: float, state: VehicleState) -> float:
    """The telemetry's weight, or 0 in a replay or while paused."""
    return 0.0 if state.replay or state.paused else weight


def input_speed_rpm(speed_m_s: float, ratio: float, pattern: HPatternParams) -> float:
    """The gearbox input shaft's speed in the gear of `ratio` at the car's speed, rpm (the
    preset's final drive and wheel radius)."""
    return abs(output_speed_rad_s(speed_m_s, pattern.synchronizer) * ratio) * RAD_S_TO_RPM


def speed_difference_rpm(
    state: VehicleState, ratio: float, pattern: HPatternParams, learned_rpm_per_m_s: float
) -> float:
    """The engine's speed less the gearbox input's for the gear, rpm: from the game's rpm and
    speed with that gear's ratio as the game showed it (rpm per m/s learned while in it), else
    the preset's ratios; where the game gives no rpm or speed, its ShiftGrindRPM; else NaN."""
    rpm, speed = state.engine_speed_rpm, state.speed_m_s
    if math.isfinite(rpm) and math.isfinite(speed):
        if learned_rpm_per_m_s > 0.0:
            return rpm - abs(speed) * learned_rpm_per_m_s
        return rpm - input_speed_rpm(speed, ratio, pattern)
    return state.shift_grind_rpm


def clutch_is_in(state: VehicleState, p: CueParams) -> bool:
    """The pedal past `clutch_in`; a game that gives no pedal counts as in (no wall)."""
    return not state.clutch_pedal < p.clutch_in


def rejects(difference_rpm: float, state: VehicleState, p: CueParams) -> bool:
    """The gear is refused: the clutch out and the revs apart (an unknown difference never
    refuses: no wall the state cannot justify)."""
    return not clutch_is_in(state, p) and abs(difference_rpm) > p.match_rpm


def wall_N(s_m: float, velocity_m_s: float, entry_m: float, p: CueParams) -> float:
    """A one-sided wall at `entry_m` in slot coordinates (s grows into the gear), N along s:
    a spring past the entry, damping only while the knob goes further in (passive)."""
    over = s_m - entry_m
    if over <= 0.0:
        return 0.0
    return -(p.wall_stiffness_N_m * over + p.wall_damping_N_s_m * max(0.0, velocity_m_s))


def octave_below(frequency_hz: float, ceiling_hz: float) -> float:
    """An octave down at a time until below `ceiling_hz` (a quarter of the loop rate: a
    vibration rendered there cannot alias)."""
    while frequency_hz >= ceiling_hz:
        frequency_hz *= 0.5
    return frequency_hz


def grind_frequency_hz(difference_rpm: float, teeth: int, ceiling_hz: float) -> float:
    """The dog teeth's passing frequency, an octave down at a time below `ceiling_hz`."""
    return octave_below(abs(difference_rpm) / 60.0 * teeth, ceiling_hz)


def bite_coupling(clutch_pedal: float, p: CueParams) -> float:
    """How much of the engine reaches the gearbox through the clutch: 1 released, 0 past the
    bite point (a smoothstep across `bite_width`); 1 where the game gives no pedal."""
    if not 0.0 <= clutch_pedal <= 1.0:
        return 1.0
    u = (clutch_pedal - (p.bite_point - 0.5 * p.bite_width)) / p.bite_width
    u = min(1.0, max(0.0, u))
    return 1.0 - u * u * (3.0 - 2.0 * u)


def sequential_locked(direction: int, state: VehicleState) -> bool:
    """Sequential: pushing up (+1) from the top gear, pulling down (-1) from R is locked."""
    top = state.forward_gears
    return (direction > 0 and top > 0 and state.gear >= top) or (direction < 0 and state.gear < 0)


def mismatch(lever_gear: str, state: VehicleState) -> bool:
    """The lever in a gear (not neutral) that is not the game's (a truck's reverses are R1,
    R2 ...: the game's -1, -2)."""
    truck_reverse = f"R{-state.gear}" if state.gear < 0 else ""
    return lever_gear not in ("N", gear_name(state.gear), truck_reverse)


class LeverCues:
    """The cues on the H-pattern's knob, called each sub-step with the model's state (after
    `update` set the tick's game state and weight); forces in model N along x and y."""

    def __init__(
        self,
        pattern: HPatternParams,
        rate_hz: float,
        params: CueParams | None = None,
        hold: bool = False,
    ) -> None:
        self.pattern = pattern
        self.p = params or CueParams.of(pattern)
        self.ceiling_hz = rate_hz / 4.0
        # The wall stands a gate wall's depth before the blocker ring, so that the refusal is
        # the wall's whatever the synchronizer (the paper's timer, a dog box's none).
        self.entry_m = pattern.engagement.synchronization_position_m - WALL_DEPTH_M
        self.state = VehicleState()
        self.weight = 0.0
        self.learned: dict[int, float] = {}
        """Game gear -> rpm per m/s, learned while in it with the clutch out and moving."""
        self.wall_N = 0.0
        """This tick's wall force on the knob (the last sub-step's), N along x."""
        self.refused = ""
        """The gear the wall refuses now ("" none)."""
        self.grind_hz = 0.0
        self._phase = 0.0
        self.mismatch_s = 0.0
        self.refusals = 0
        self.hold = hold
        self.game_neutral_s = 0.0
        self.holds = 0

    def update(self, state: VehicleState, weight: float, lever_gear: str, dt_s: float) -> None:
        """The tick's game state and telemetry weight; learns the game gear's ratio."""
        self.state, self.weight = state, cue_weight(weight, state)
        g, v, rpm = state.gear, state.speed_m_s, state.engine_speed_rpm
        if (
            self.weight > 0.0
            and g != 0
            and abs(v) > 3.0
            and rpm > 0.0
            and not (clutch_is_in(state, self.p) or math.isnan(state.clutch_pedal))
        ):
            ratio = rpm / abs(v)
            old = self.learned.get(g)
            self.learned[g] = ratio if old is None else old + 0.05 * (ratio - old)
        if self.weight > 0.0 and mismatch(lever_gear, state):
            self.mismatch_s += dt_s
        self.game_neutral_s = self.game_neutral_s + dt_s if state.gear == 0 else 0.0

    def __call__(self, lever: HPatternState) -> tuple[float, float]:
        """The wall's force on the knob (model N, x and y) for the model's state now."""
        self.wall_N, refused = 0.0, ""
        s, d = lever.lever.position_m, lever.direction
        layout = self.pattern.layout
        slot = layout.gear_at(lever.plane, d) if s > 0.0 else None
        if slot is not None and layout.truck:  # a truck's: the gear of its range and splitter
            row = layout.truck_gear(slot.name, getattr(lever, "range_high", False),
                                    getattr(lever, "splitter_high", False))  # fmt: skip
            slot = (
                None if row is None else dataclasses.replace(slot, name=row.name, ratio=row.ratio)
            )
        # A gear the lever is in stays in (the wall is at the entry, not in the gear).
        if self.weight > 0.0 and slot is not None and lever.gear == "N":
            number = -1 if slot.name == "R" else _number(slot.name)
            top = self.state.forward_gears
            if top > 0 and number > top:  # the car has no such gear: always walled
                refused, self.grind_hz = slot.name, 0.0
            elif mismatch(slot.name, self.state):  # the game's own gear always goes in
                learned = self.learned.get(number, 0.0)
                diff = speed_difference_rpm(self.state, slot.ratio, self.pattern, learned)
                if rejects(diff, self.state, self.p):
                    refused = slot.name
                    self.grind_hz = grind_frequency_hz(diff, self.p.grind_teeth, self.ceiling_hz)
            if refused:
                along = wall_N(s, lever.lever.velocity_m_s, self.entry_m, self.p)
                self.wall_N = self.weight * d * along
        if (
            self.hold
            and self.weight > 0.0
            and lever.gear != "N"
            and self.game_neutral_s > self.p.hold_grace_s
            and s > self.entry_m
        ):  # the game stayed in neutral: out of the gear, back to its entry
            self.wall_N, refused = -self.weight * d * self.p.hold_force_N, "hold"
        if refused == "hold" and self.refused != "hold":
            self.holds += 1
        elif refused and refused != self.refused:
            self.refusals += 1
        self.refused = refused
        return self.wall_N, 0.0

    def grind(self, dt_s: float) -> float:
        """The grind's vibration this tick, model N along x (0 unless the wall is pushed)."""
        if not self.wall_N or not self.grind_hz:
            return 0.0
        self._phase = (self._phase + 2.0 * math.pi * self.grind_hz * dt_s) % (2.0 * math.pi)
        push = min(1.0, abs(self.wall_N) / self.p.grind_push_N)
        return self.weight * self.p.grind_amplitude_N * push * math.sin(self._phase)


def _number(name: str) -> int:
    """A gear's number: "3" -> 3, a truck's reverse "R2" -> -2; 0 for another name."""
    if name[:1] == "R" and name[1:].isdigit():
        return -int(name[1:])
    return int(name) if name.isdigit() else 0
