"""A sequential lever (issue 30): a rally/race gearbox's 1-DOF lever along x.

    end stop      click (down)     centre      click (up)      end stop
       |---------------x--------------0-------------x---------------|
                  -click_m                       +click_m        +end_m     (s = up_direction * x)

s = `up_direction` * x is the travel toward an upshift (+1: push forward for up, -1: pull).
The lever is spring-centred (a preloaded spring); each direction has an over-centre click at
`click_m`: a triangular bump `click_width_m` wide that resists the hand before the click point
and helps it after, so the lever snaps through. The shift registers at the click (the lever
must come back within `rearm_m` of the centre before the next one). Past the click the gearbox
turns its barrel drum: a Coulomb resistance `drum_N` until the end stop, with a dog-engagement
bump (a triangle `dog_N` high) halfway.

A locked move (up from the top gear, down from R, a neutral without the lift button, or a
lock the game reports: `SequentialInputs.locked_up`/`locked_down`, e.g. from
`telemetry.cues.sequential_locked`) meets a wall at `lock_m`, short of the click's bump:
the lever cannot reach the click, so no shift registers. Walls and end stops are
spring-dampers integrated implicitly with the lever (passive at any step).

Neutral, per `neutral` in the parameters: "lift" (down from 1 to N, and from N to R, only with
the lift button on the knob held), or "pull" (down from 1 to N is a plain pull; R below N still
needs the lift button). Up from R and N is always plain.

Gears are ints as the games count them: -1 R, 0 N, 1 .. `forward_gears`. Forces in N on the
knob along x (+ forward), positions in m, velocities in m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from carfeel.errors import PresetError

NEUTRAL_MODES = ("lift", "pull")


@dataclass(frozen=True, slots=True)
class SequentialParams:
    forward_gears: int = 6
    """Number of forward gears: gears run -1 (R), 0 (N), 1 .. this."""
    up_direction: int = -1
    """+1: push (x > 0) for up; -1: pull for up (most rally levers)."""
    neutral: str = "lift"
    """Neutral mode. "lift": 1 to N and N to R need the lift button; "pull": 1 to N is a plain
    pull (R still needs the button)."""
    mass_kg: float = 0.6
    """The lever's inertia at the knob, kg."""
    damping_N_s_m: float = 30.0
    """About 0.65 of critical with the centring spring: a released lever returns without
    swinging past the centre toward the other click."""
    centring_N_m: float = 900.0
    """Stiffness of the centring spring toward the centre, N/m."""
    centring_preload_N: float = 6.0
    """Preload of the centring spring: its force toward the centre just off it, N."""
    click_m: float = 0.022
    """Travel from centre to the click (the shift point), m."""
    click_width_m: float = 0.004
    """Reach of the click either side of click_m: it resists over this before the point, helps
    over this after."""
    click_N: float = 25.0
    """The click's peak: resisting before the point, helping after it."""
    end_m: float = 0.035
    """The end stop's travel from centre, m."""
    rearm_m: float = 0.006
    """After a shift, the next registers only once the lever has come back within this of the
    centre."""
    lock_m: float = 0.012
    """Where a locked move's wall stands (travel from centre, m): short of the click's bump,
    so the wall's compliance (a few mm at a firm hand's impact) never reaches the click."""
    drum_N: float = 10.0
    """The barrel drum's Coulomb resistance between the click and the end stop, N."""
    dog_N: float = 8.0
    """The dog-engagement bump's peak, halfway from the click to the end stop, N."""
    dog_width_m: float = 0.002
    """Half-width of the dog-engagement bump (a triangle about its peak), m."""
    wall_N_m: float = 40000.0
    """Stiffness of a locked move's wall and of the end stops, N/m."""
    wall_N_s_m: float = 60.0
    """Damping of a locked move's wall and of the end stops, N*s/m."""
    friction_velocity_m_s: float = 0.01
    """The speed over which Coulomb forces ramp to full (regularised friction), m/s."""

    def __post_init__(self) -> None:
        checks = [
            (self.forward_gears >= 1, "forward_gears must be at least 1"),
            (self.up_direction in (-1, 1), "up_direction must be +1 (push) or -1 (pull)"),
            (self.neutral in NEUTRAL_MODES, f"neutral must be one of {NEUTRAL_MODES}"),
            (
                0.0 < self.rearm_m < self.click_m - self.click_width_m,
                "need 0 < rearm_m < click_m - click_width_m",
            ),
            (
                self.click_m + self.click_width_m < self.end_m,
                "need click_m + click_width_m < end_m",
            ),
            (self.mass_kg > 0.0, "mass_kg must be positive"),
        ]
        for name in ("damping_N_s_m", "centring_N_m", "centring_preload_N", "click_N", "drum_N",
                     "dog_N", "dog_width_m", "wall_N_m", "wall_N_s_m", "click_width_m", "click_m",
                     "friction_velocity_m_s", "end_m", "rearm_m", "mass_kg"):  # fmt: skip
            value = getattr(self, name)
            checks.append(
                (
                    math.isfinite(value) and value >= 0.0,
                    f"{name} = {value}: expected a finite number >= 0",
                )
            )
        checks.append((self.click_width_m > 0.0 and self.friction_velocity_m_s > 0.0,
                       "click_width_m and friction_velocity_m_s must be positive"))  # fmt: skip
        for ok, message in checks:
            if not ok:
                raise PresetError(f"sequential lever: {message}")

    @property
    def wall_m(self) -> float:
        """Where a locked move's wall stands (travel from centre, m)."""
        return self.lock_m


class SequentialState(NamedTuple):
    x_m: float = 0.0
    v_m_s: float = 0.0
    gear: int = 0
    armed: bool = True
    """False after a shift until the lever is back near the centre."""


class SequentialInputs(NamedTuple):
    hand_N: float = 0.0
    """The driver's force on the knob, N, + forward."""
    lift: bool = False
    """The lift button on the knob (neutral / reverse)."""
    locked_up: bool = False
    locked_down: bool = False


class SequentialOutputs(NamedTuple):
    lever_N: float
    """The mechanism's force on the knob (without the hand), N, + forward."""
    gear: int
    shift: int
    """+1 an upshift, -1 a downshift registered this step, 0 none."""
    wall_depth_m: float
    """How far the lever is into a lock's wall (0 when not against one), m."""


def allowed(params: SequentialParams, gear: int, direction: int, inputs: SequentialInputs) -> bool:
    """May the lever shift from `gear` in `direction` (+1 up, -1 down)?"""
    if direction > 0:
        return not inputs.locked_up and gear < params.forward_gears
    if inputs.locked_down or gear <= -1:
        return False
    if gear == 0 or (gear == 1 and params.neutral == "lift"):
        return inputs.lift
    return True


def _triangle(s: float, centre: float, half_width: float) -> float:
    """1 at `centre`, falling to 0 at +- half_width."""
    return max(0.0, 1.0 - abs(s - centre) / half_width)


def mechanism_N(params: SequentialParams, s: float, ds: float) -> float:
    """The springs, click, drum and dog bump along s (toward up +), N, without walls."""
    p = params
    side = 1.0 if s > 0.0 else -1.0 if s < 0.0 else 0.0
    a = abs(s)
    force = -p.centring_N_m * s - p.centring_preload_N * side
    # Over-centre click: resists (against side) before the point, helps (with side) after.
    if p.click_m - p.click_width_m < a < p.click_m + p.click_width_m:
        shape = (a - (p.click_m - p.click_width_m)) / p.click_width_m
        force -= side * p.click_N * (shape if a <= p.click_m else shape - 2.0)
    if a > p.click_m:
        moving_out = ds * side
        drag = max(-1.0, min(1.0, moving_out / p.friction_velocity_m_s))
        force -= side * p.drum_N * drag
        dog = p.click_m + 0.5 * (p.end_m - p.click_m)
        force -= side * p.dog_N * _triangle(a, dog, p.dog_width_m) * (1.0 if a < dog else -1.0)
    return force


def step(
    params: SequentialParams, state: SequentialState, inputs: SequentialInputs, dt_s: float
) -> tuple[SequentialState, SequentialOutputs]:
    """Advance the lever by dt_s (s): the hand's force against the mechanism and the walls."""
    p = params
    u = p.up_direction
    s, ds = u * state.x_m, u * state.v_m_s
    hand = u * inputs.hand_N
    f_mech = mechanism_N(p, s, ds)
    # The wall or end stop on the side the lever is on: a locked move's wall, else the end stop.
    direction = 1 if s > 0.0 or (s == 0.0 and hand > 0.0) else -1
    locked = state.armed and not allowed(p, state.gear, direction, inputs)
    limit = p.wall_m if locked else p.end_m
    # Implicit Euler for the lever, with the wall's spring-damper when the step reaches it
    # (linear in the new speed, so passive at any step); a wall only pushes, never pulls.
    m, b = p.mass_kg, p.damping_N_s_m
    ds_new = (m * ds + dt_s * (f_mech + hand)) / (m + dt_s * b)
    if direction * (s + dt_s * ds_new) > limit:
        k, c = p.wall_N_m, p.wall_N_s_m
        walled = (
            m * ds + dt_s * (f_mech + hand) - dt_s * direction * k * (direction * s - limit)
        ) / (m + dt_s * (b + c) + dt_s * dt_s * k)
        if direction * (walled - ds_new) < 0.0:  # the wall slows the move into it
            ds_new = walled
    s_new = s + dt_s * ds_new
    gear, armed, shift = state.gear, state.armed, 0
    if armed and not locked and abs(s_new) >= p.click_m > abs(s):
        shift = 1 if s_new > 0.0 else -1
        gear, armed = gear + shift, False
    elif not armed and abs(s_new) < p.rearm_m:
        armed = True
    depth = max(0.0, direction * s_new - p.wall_m) if locked else 0.0
    # The mechanism's force on the knob this step (the wall's as integrated), along x.
    lever_s = m * (ds_new - ds) / dt_s + b * ds_new - hand
    new = SequentialState(u * s_new, u * ds_new, gear, armed)
    return new, SequentialOutputs(u * lever_s, gear, shift, depth)


def gear_name(gear: int) -> str:
    return "R" if gear < 0 else "N" if gear == 0 else str(gear)
