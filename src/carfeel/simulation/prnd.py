"""A PRND selector driven through a list of target positions offline (issue 30): for each move
the hand pushes toward the target with a constant force until the target registers (or
`hold_s` runs out: a lock held it), then lets go for `rest_s`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from carfeel.errors import InputError
from carfeel.models.gearshift import prnd as pr
from carfeel.simulation.result import Result
from carfeel.simulation.sequential import check_driver
from carfeel.text import shown

MAX_MOVES = 1000


@dataclass(frozen=True, slots=True)
class PrndDriver:
    hand_N: float = 25.0
    """The hand's force during a move, N (above the detents' 15 N peak)."""
    hold_s: float = 0.6
    """Longest push per move: the hand pushes hand_N until the target registers or this runs out."""
    rest_s: float = 0.4
    """How long the hand lets go after each move."""

    def __post_init__(self) -> None:
        check_driver("prnd driver", self)


@dataclass(frozen=True, slots=True)
class PrndSetup:
    """A prnd preset's tables: the selector and the offline driver."""

    selector: pr.PrndParams = field(default_factory=pr.PrndParams)
    """The selector: its positions, detents, locks and walls."""
    driver: PrndDriver = field(default_factory=PrndDriver)
    """The offline driver's hand: its force and timing per move."""


def parse_moves(text: str, positions: tuple[str, ...]) -> tuple[int, ...]:
    """ "R,N,D" -> the target positions' indices; InputError naming a bad one."""
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise InputError("--moves is empty: give target positions like R,N,D")
    if len(names) > MAX_MOVES:
        raise InputError(f"--moves has {len(names)} moves; at most {MAX_MOVES}")
    for name in names:
        if name not in positions:
            raise InputError(
                f"--moves: '{shown(name)}' is not a position of this selector; use "
                f"{', '.join(positions)}"
            )
    return tuple(positions.index(name) for name in names)


def parse_flags(text: str, moves: int, option: str) -> tuple[bool, ...]:
    """ "on" / "off" for every move, or one per move ("on,off,on"); InputError otherwise."""
    items = [t.strip() for t in text.split(",")]
    if len(items) == 1:
        items = items * moves
    if len(items) != moves or any(t not in ("on", "off") for t in items):
        raise InputError(
            f"{option} {shown(text[:80])}: expected on or off, once or once per move "
            f"({moves} moves)"
        )
    return tuple(t == "on" for t in items)


def parse_speeds(text: str, moves: int) -> tuple[float, ...]:
    """Road speeds, m/s: one for every move or one per move; InputError otherwise."""
    items = [t.strip() for t in text.split(",")]
    if len(items) == 1:
        items = items * moves
    try:
        speeds = tuple(float(t) for t in items)
    except ValueError:
        speeds = ()
    if len(speeds) != moves or not all(math.isfinite(s) and 0.0 <= s <= 200.0 for s in speeds):
        raise InputError(
            f"--speed {shown(text[:80])}: expected speeds 0 to 200 m/s, once or once per move "
            f"({moves} moves)"
        )
    return speeds


def simulate_prnd(
    setup: PrndSetup,
    moves: tuple[int, ...],
    brake: tuple[bool, ...],
    button: tuple[bool, ...],
    speed_m_s: tuple[float, ...],
    dt_s: float = 0.001,
) -> Result:
    """Samples of the selector through `moves` (target indices): x_m, v_m_s, hand_N, lever_N
    (the mechanism's force on the knob, + toward D), wall_depth_m, shift (+1/-1 as a position
    registers), position (P, R, N, D ...)."""
    p, d = setup.selector, setup.driver
    state = pr.PrndState()
    hold, rest = round(d.hold_s / dt_s), round(d.rest_s / dt_s)
    n = len(moves) * (hold + rest)
    columns = {name: np.zeros(n) for name in ("x_m", "v_m_s", "hand_N", "lever_N",
                                               "wall_depth_m", "shift")}  # fmt: skip
    names = np.empty(n, dtype=object)
    i = 0
    for k, target in enumerate(moves):
        for tick in range(hold + rest):
            pushing = tick < hold and state.position != target
            force = math.copysign(d.hand_N, p.centre_m(target) - state.x_m) if pushing else 0.0
            inputs = pr.PrndInputs(force, brake[k], button[k], speed_m_s[k])
            state, out = pr.step(p, state, inputs, dt_s)
            for name, value in (("x_m", state.x_m), ("v_m_s", state.v_m_s), ("hand_N", force),
                                ("lever_N", out.lever_N), ("wall_depth_m", out.wall_depth_m),
                                ("shift", float(out.shift))):  # fmt: skip
                columns[name][i] = value
            names[i] = p.positions[state.position]
            i += 1
    time_s = np.arange(1, n + 1, dtype=np.float64) * np.float64(dt_s)
    return Result(time_s, {**columns, "position": names.astype(str)})
