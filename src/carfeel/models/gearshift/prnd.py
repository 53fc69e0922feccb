"""An automatic's selector (issue 30): a 1-DOF PRND lever along x with a shift lock.

    end stop    P         R         N         D   (M ...)   end stop
       |--------0---------1---------2---------3---------|
             x = 0     pitch_m  2 pitch_m ...              (+ x: toward D, the lever pulled back)

Each position is a detent well: a sinusoidal force `detent_N` at its peak, pulling the lever
to the nearest detent centre (the wells' crests stand halfway between the centres), so a
lever let go between two positions falls into the one whose half it is in. The gate's end
stops stand `end_m` past the first and last centres. A position registers when the lever
comes within `register_m` of its centre (the selector's display and the game's gear change
there, not at the crest).

The shift lock is a wall (a spring-damper that only pushes, integrated implicitly with the
lever, so passive at any step) `lock_m` from the registered position's centre toward the
locked neighbour, short of the crest: the lever gets `lock_m` plus the wall's compliance in
and springs back into its detent when let go. Locked: out of P unless the brake is pressed
(and the lock button, if `p_needs_button`); into R from N above `reverse_lock_speed_m_s`, or
without the lock button if `r_needs_button`.

Positions are indices into `positions` (0 = P). Forces in N on the knob along x, positions
in m, velocities in m/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from carfeel.errors import PresetError

BASE_POSITIONS = ("P", "R", "N", "D")
EXTRA_POSITIONS = ("M", "S", "L", "B", "2", "1")
"""Positions a preset may add after D (each a plain detent: no lock, no +/- gate)."""


@dataclass(frozen=True, slots=True)
class PrndParams:
    positions: tuple[str, ...] = BASE_POSITIONS
    """The detents from x = 0 along + x: P, R, N, D first, then any of EXTRA_POSITIONS."""
    pitch_m: float = 0.03
    """Distance between neighbouring detent centres, m."""
    mass_kg: float = 0.8
    """The lever's inertia at the knob, kg."""
    damping_N_s_m: float = 40.0
    """About 0.4 of critical in a detent well (k = 2 pi detent_N / pitch_m ~ 3.1 kN/m): a
    lever let go near a crest falls into its well without rolling over the next crest."""
    detent_N: float = 15.0
    """The detent's peak force (a quarter pitch from a centre), N."""
    end_m: float = 0.01
    """The end stops' distance past the first and last centres, m."""
    register_m: float = 0.004
    """A position registers within this distance of its centre, m."""
    lock_m: float = 0.006
    """A lock's wall from the registered centre toward the locked neighbour, m."""
    p_needs_button: bool = False
    """Out of P also needs the lock button (some cars), besides the brake."""
    r_needs_button: bool = True
    """Into R from N needs the lock button."""
    reverse_lock_speed_m_s: float = 2.0
    """Into R from N is locked above this road speed, m/s."""
    wall_N_m: float = 40000.0
    """Stiffness of the lock walls and the end stops, N/m."""
    wall_N_s_m: float = 60.0
    """Damping of the lock walls and the end stops, N*s/m."""

    def __post_init__(self) -> None:
        checks = [
            (
                self.positions[:4] == BASE_POSITIONS
                and all(name in EXTRA_POSITIONS for name in self.positions[4:])
                and len(set(self.positions)) == len(self.positions),
                f"positions = {list(self.positions)}: expected P, R, N, D then any of "
                f"{', '.join(EXTRA_POSITIONS)}, each once",
            ),
        ]
        for name in ("pitch_m", "mass_kg", "damping_N_s_m", "detent_N", "end_m", "register_m",
                     "lock_m", "reverse_lock_speed_m_s", "wall_N_m", "wall_N_s_m"):  # fmt: skip
            value = getattr(self, name)
            checks.append(
                (
                    math.isfinite(value) and value >= 0.0,
                    f"{name} = {value}: expected a finite number >= 0",
                )
            )
        checks += [
            (self.pitch_m > 0.0 and self.mass_kg > 0.0, "pitch_m and mass_kg must be positive"),
            (
                0.0 < self.register_m < self.lock_m < 0.5 * self.pitch_m,
                f"need 0 < register_m < lock_m < pitch_m / 2 (= {0.5 * self.pitch_m:g} m, "
                "the crest): a locked lever must stay in its detent's well",
            ),
            (self.end_m > self.register_m, "end_m must exceed register_m"),
        ]
        for ok, message in checks:
            if not ok:
                raise PresetError(f"prnd selector: {message}")

    def centre_m(self, position: int) -> float:
        """The detent centre of position index `position`, m."""
        return position * self.pitch_m


class PrndState(NamedTuple):
    x_m: float = 0.0
    v_m_s: float = 0.0
    position: int = 0
    """The registered position (index into `positions`; 0 = P)."""


class PrndInputs(NamedTuple):
    hand_N: float = 0.0
    """The driver's force on the knob, N, + toward D."""
    brake: bool = False
    """The brake pedal pressed."""
    button: bool = False
    """The lock button on the knob pressed."""
    speed_m_s: float = 0.0
    """The car's road speed (magnitude), m/s."""


class PrndOutputs(NamedTuple):
    lever_N: float
    """The mechanism's force on the knob (without the hand), N, + toward D."""
    position: int
    shift: int
    """+1 / -1: a position registered this step toward D / P; 0 none."""
    wall_depth_m: float
    """How far the lever is into a lock's wall (0 when not against one), m."""


def locked(params: PrndParams, position: int, direction: int, inputs: PrndInputs) -> bool:
    """Is the move from `position` toward `direction` (+1 toward D, -1 toward P) locked?"""
    if position == 0 and direction > 0:
        return not inputs.brake or (params.p_needs_button and not inputs.button)
    if position == 2 and direction < 0:  # N -> R
        # Written so that a speed not known (NaN from a log or a game) locks: not slow enough.
        too_fast = not abs(inputs.speed_m_s) <= params.reverse_lock_speed_m_s
        return too_fast or (params.r_needs_button and not inputs.button)
    return False


def detent_force_N(params: PrndParams, x_m: float) -> float:
    """The detent wells' force at x (toward the nearest centre), N."""
    return -params.detent_N * math.sin(2.0 * math.pi * x_m / params.pitch_m)


def step(
    params: PrndParams, state: PrndState, inputs: PrndInputs, dt_s: float
) -> tuple[PrndState, PrndOutputs]:
    """Advance the lever by dt_s (s): the hand's force against the detents and the walls."""
    p = params
    x, v = state.x_m, state.v_m_s
    centre = p.centre_m(state.position)
    last = p.centre_m(len(p.positions) - 1)
    low = -p.end_m
    high = last + p.end_m
    lock_low = locked(p, state.position, -1, inputs)
    lock_high = locked(p, state.position, +1, inputs)
    if lock_low:
        low = centre - p.lock_m
    if lock_high:
        high = centre + p.lock_m
    force = detent_force_N(p, x) + inputs.hand_N
    # Implicit Euler for the lever, with a wall's spring-damper when the step reaches it
    # (linear in the new speed, so passive at any step); a wall only pushes, never pulls.
    m, b = p.mass_kg, p.damping_N_s_m
    v_new = (m * v + dt_s * force) / (m + dt_s * b)
    for limit, side in ((high, 1.0), (low, -1.0)):
        if side * (x + dt_s * v_new - limit) > 0.0:
            k, c = p.wall_N_m, p.wall_N_s_m
            walled = (m * v + dt_s * force - dt_s * k * (x - limit)) / (
                m + dt_s * (b + c) + dt_s * dt_s * k
            )
            if side * (walled - v_new) < 0.0:  # the wall slows the move into it
                v_new = walled
    x_new = x + dt_s * v_new
    nearest = min(len(p.positions) - 1, max(0, round(x_new / p.pitch_m)))
    position, shift = state.position, 0
    if nearest != position and abs(x_new - p.centre_m(nearest)) < p.register_m:
        shift = 1 if nearest > position else -1
        position = nearest
    depth = 0.0
    if lock_high:
        depth = max(depth, x_new - high)
    if lock_low:
        depth = max(depth, low - x_new)
    lever_N = m * (v_new - v) / dt_s + b * v_new - inputs.hand_N
    return PrndState(x_new, v_new, position), PrndOutputs(lever_N, position, shift, depth)
