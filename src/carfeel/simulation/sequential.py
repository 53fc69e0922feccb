"""A sequential lever driven through a pattern of moves offline (issue 30): the hand pushes
or pulls with a constant force for `hold_s`, lets go for `rest_s`, move after move."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from carfeel.errors import InputError, PresetError
from carfeel.models.gearshift import sequential as sq
from carfeel.simulation.result import Result
from carfeel.text import shown

MOVES = ("up", "down", "lift-down", "lift-up")
"""A move: up or down in the lever's shift sense; lift-: with the knob's lift button held."""
MAX_MOVES = 1000


@dataclass(frozen=True, slots=True)
class SequentialDriver:
    hand_N: float = 60.0
    """The hand's force during a move, N (over the click's peak with the spring there: 50.8 N
    in rally-6; a weaker hand gets over it only by its momentum, which a device's coupling
    takes)."""
    hold_s: float = 0.3
    """How long the hand pushes or pulls with hand_N in each move."""
    rest_s: float = 0.3
    """How long the hand lets go after each move."""

    def __post_init__(self) -> None:
        check_driver("sequential driver", self)


def check_driver(label: str, driver: object) -> None:
    """A scripted hand's hand_N (N), hold_s and rest_s (s) within their ranges, else a
    PresetError naming `label` and the field."""
    for name, low, high in (
        ("hand_N", 0.0, 1000.0),
        ("hold_s", 0.01, 60.0),
        ("rest_s", 0.01, 60.0),
    ):
        value = getattr(driver, name)
        if not (math.isfinite(value) and low <= value <= high):
            raise PresetError(f"{label}: {name} = {value}: expected {low:g} to {high:g}")


@dataclass(frozen=True, slots=True)
class SequentialSetup:
    """A sequential preset's tables: the lever and the offline driver."""

    lever: sq.SequentialParams = field(default_factory=sq.SequentialParams)
    """The lever: its springs, click, drum, walls and neutral mode."""
    driver: SequentialDriver = field(default_factory=SequentialDriver)
    """The offline driver's hand: its force and timing per move."""


def parse_moves(text: str) -> tuple[str, ...]:
    """ "up,up,down,lift-down" -> the moves; InputError naming a bad one."""
    moves = tuple(m.strip() for m in text.split(",") if m.strip())
    if not moves:
        raise InputError("--moves is empty: give moves like up,up,down,lift-down")
    if len(moves) > MAX_MOVES:
        raise InputError(f"--moves has {len(moves)} moves; at most {MAX_MOVES}")
    for move in moves:
        if move not in MOVES:
            raise InputError(f"--moves: '{shown(move)}' is not a move; use {', '.join(MOVES)}")
    return moves


def simulate_sequential(
    setup: SequentialSetup,
    moves: tuple[str, ...],
    dt_s: float = 0.001,
    locked_up: bool = False,
    locked_down: bool = False,
) -> Result:
    """Samples of the lever through `moves`: x_m, v_m_s, hand_N, lever_N (the mechanism's
    force on the knob, + forward), wall_depth_m, shift (+1/-1 at the click), gear (R, N, 1..)."""
    p, d = setup.lever, setup.driver
    state = sq.SequentialState()
    hold, rest = round(d.hold_s / dt_s), round(d.rest_s / dt_s)
    n = len(moves) * (hold + rest)
    columns = {name: np.zeros(n) for name in ("x_m", "v_m_s", "hand_N", "lever_N",
                                               "wall_depth_m", "shift")}  # fmt: skip
    gears = np.empty(n, dtype=object)
    i = 0
    for move in moves:
        sense = 1 if move.endswith("up") else -1
        lift = move.startswith("lift-")
        for force in [sense * p.up_direction * d.hand_N] * hold + [0.0] * rest:
            inputs = sq.SequentialInputs(force, lift, locked_up, locked_down)
            state, out = sq.step(p, state, inputs, dt_s)
            for name, value in (("x_m", state.x_m), ("v_m_s", state.v_m_s), ("hand_N", force),
                                ("lever_N", out.lever_N), ("wall_depth_m", out.wall_depth_m),
                                ("shift", float(out.shift))):  # fmt: skip
                columns[name][i] = value
            gears[i] = sq.gear_name(state.gear)
            i += 1
    time_s = np.arange(1, n + 1, dtype=np.float64) * np.float64(dt_s)
    return Result(time_s, {**columns, "gear": gears.astype(str)})
