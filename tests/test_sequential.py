"""The sequential lever (issue 30): every shift through the pattern, the locks as walls."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from carfeel.errors import PresetError
from carfeel.models.gearshift import sequential as sq
from carfeel.telemetry.gearout import sequential_for
from tests.preset_edits import assert_each_edit_is_named

DT_S = 0.001
PUSH_N = 45.0
"""A firm hand: above the click's peak plus the centring spring there (~ 25 + 26 N minus the
spring's share at the bump start), so every allowed shift goes through."""


class Hand:
    def __init__(self, params: sq.SequentialParams) -> None:
        self.params = params
        self.state = sq.SequentialState()
        self.shifts: list[int] = []
        self.max_depth_m = 0.0
        self.max_travel_m = 0.0

    def move(self, up: int, seconds: float = 0.3, **flags: bool) -> None:
        """Push (up=+1) or pull (-1) in the shift's sense, then let go."""
        hand = up * self.params.up_direction * PUSH_N
        for force, duration in ((hand, seconds), (0.0, seconds)):
            for _ in range(round(duration / DT_S)):
                inputs = sq.SequentialInputs(force, **flags)
                self.state, out = sq.step(self.params, self.state, inputs, DT_S)
                assert math.isfinite(self.state.x_m) and math.isfinite(out.lever_N)
                self.max_depth_m = max(self.max_depth_m, out.wall_depth_m)
                self.max_travel_m = max(self.max_travel_m, abs(self.state.x_m))
                if out.shift:
                    self.shifts.append(out.shift)


@pytest.mark.parametrize("up_direction", [1, -1])
def test_every_shift_up_and_down_through_the_pattern(up_direction: int) -> None:
    params = sq.SequentialParams(up_direction=up_direction)
    hand = Hand(params)
    gears = []
    for _ in range(params.forward_gears):
        hand.move(+1)
        gears.append(hand.state.gear)
    assert gears == [1, 2, 3, 4, 5, 6]
    hand.move(+1)  # past top: the wall
    assert hand.state.gear == 6
    # A 45 N hand gets into the lock's wall by its impact overshoot only: never to the
    # click's bump (6 mm past the wall), so no shift can register through it.
    assert 0.0 < hand.max_depth_m < params.click_m - params.click_width_m - params.lock_m
    for expected in (5, 4, 3, 2, 1):
        hand.move(-1)
        assert hand.state.gear == expected
    hand.move(-1)  # 1 -> N needs the lift button ("lift" preset)
    assert hand.state.gear == 1
    hand.move(-1, lift=True)
    assert hand.state.gear == 0
    hand.move(-1, lift=True)
    assert hand.state.gear == -1
    hand.move(-1, lift=True)  # below R: the wall
    assert hand.state.gear == -1
    hand.move(+1)
    hand.move(+1)
    assert hand.state.gear == 1
    # The lever returns to the centre after every move (spring-centred) and never passes
    # the end stop by more than its wall's compliance (45 N / 40 kN/m ~ 1.1 mm, plus impact).
    assert abs(hand.state.x_m) < params.rearm_m
    assert hand.max_travel_m < params.end_m + 0.005
    # Gear output: the pulses a sequential game expects, one per registered shift.
    pulses = [b for shift in hand.shifts for _, b in sequential_for(0, shift)]
    assert pulses == [0] * 6 + [1] * 7 + [0] * 2


def test_pull_neutral_and_game_lock() -> None:
    params = sq.SequentialParams(neutral="pull")
    hand = Hand(params)
    hand.move(+1)
    hand.move(-1)  # 1 -> N plainly
    assert hand.state.gear == 0
    hand.move(-1)  # N -> R still needs the lift
    assert hand.state.gear == 0
    hand.move(+1, locked_up=True)  # the game says locked: a wall, no shift
    assert hand.state.gear == 0 and hand.shifts == [1, -1]
    assert 0.0 < hand.max_depth_m < params.click_m - params.click_width_m - params.lock_m


def test_a_weak_hand_does_not_shift_and_a_held_lever_shifts_once() -> None:
    params = sq.SequentialParams()
    hand = Hand(params)
    # 20 N is below the spring and click at the shift point: the lever stops before the click.
    for _ in range(300):
        hand.state, _out = sq.step(params, hand.state, sq.SequentialInputs(-20.0), DT_S)
    assert hand.state.gear == 0 and abs(hand.state.x_m) < params.click_m
    hand.move(+1, seconds=2.0)  # held at the end stop for 2 s: one shift only
    assert hand.shifts == [1]


@pytest.mark.parametrize(
    "bad",
    [
        {"up_direction": 0},
        {"neutral": "button"},
        {"forward_gears": 0},
        {"click_m": 0.04},
        {"drum_N": float("nan")},
        {"wall_N_m": -1.0},
    ],
)
def test_bad_parameters_are_refused_with_what_is_wrong(bad: dict[str, object]) -> None:
    with pytest.raises(PresetError, match="sequential lever"):
        sq.SequentialParams(**bad)  # type: ignore[arg-type]


def test_offline_driver_walks_the_pattern_and_refuses_bad_moves() -> None:
    from carfeel.errors import InputError
    from carfeel.simulation.sequential import SequentialSetup, parse_moves, simulate_sequential

    moves = parse_moves("up, up, up, down, down, down, lift-down, lift-down, up")
    result = simulate_sequential(SequentialSetup(), moves)
    shifts = result["shift"][result["shift"] != 0]
    # The third plain "down" from 1 is refused (neutral needs the lift in this preset).
    assert list(shifts) == [1, 1, 1, -1, -1, -1, -1, 1]
    changes = [g for k, g in enumerate(result["gear"]) if k == 0 or g != result["gear"][k - 1]]
    assert changes == ["N", "1", "2", "3", "2", "1", "N", "R", "N"]
    for bad in ("", "up,sideways", "up," * 1001):
        with pytest.raises(InputError, match="--moves"):
            parse_moves(bad)


def test_the_shipped_preset_loads_and_a_bad_one_names_its_problem(tmp_path: Path) -> None:
    from carfeel.io import presets

    preset = presets.load_sequential("rally-6")
    assert preset.params.lever.up_direction == -1 and preset.params.lever.forward_gears == 6
    edits = (
        ("up_direction = -1", "up_direction = 0", "up_direction must be"),
        ("drum_N = 10.0", "drum_N = nan", "drum_N = nan"),
        ("click_N = 25.0", 'click_N = "x"', "lever.click_N = 'x'"),
        ("end_m = 0.035", "end_m = 35", "lever.end_m = 35 m is out of range"),
        ("hold_s = 0.3", "hold_s = 0.0", "hold_s = 0.0"),
        ("[driver]", "[drivr]", "drivr: unknown key"),
    )
    other = ("hpattern", "5r", "is an hpattern preset")
    assert_each_edit_is_named("sequential", "rally-6", edits, tmp_path, other)


def test_simulate_sequential_command_and_its_refusals(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from carfeel.cli import main

    out = tmp_path / "run.csv"
    moves = "up,up,up,up,up,up,up,down,down,down,down,down,down,lift-down,lift-down,lift-down"
    assert main(["simulate", "sequential", "--moves", moves, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "13 shifts, 3 refused" in text and "gears N 1 2 3 4 5 6 5 4 3 2 1 N R" in text
    assert out.with_suffix(".json").is_file()
    before = out.read_bytes()
    for bad in (["--moves", "up,sideways"], ["--moves", "up", "--preset", "nope"],
                ["--moves", "up", "--dt", "0.5"]):  # fmt: skip
        assert main(["simulate", "sequential", *bad, "--out", str(out)]) == 2
        assert "Traceback" not in capsys.readouterr().err
        assert out.read_bytes() == before  # a failed run leaves the earlier output untouched
    assert main(["simulate", "sequential", "--moves", "up", "--locked", "up", "--out",
                 str(tmp_path / "locked.csv")]) == 0  # fmt: skip
    assert "0 shifts, 1 refused" in capsys.readouterr().out


def test_a_released_lever_does_not_swing_into_the_other_wall() -> None:
    from carfeel.io import presets
    from carfeel.simulation.sequential import parse_moves, simulate_sequential

    # With 8 N s/m (0.17 of critical) the lever let go at the end stop swung 13 mm past the
    # centre into the wall of a locked down-shift (1 -> N without the lift): this fails there.
    setup = presets.load_sequential("rally-6").params
    result = simulate_sequential(setup, parse_moves("up,up,up,down,down,lift-down,lift-down"))
    assert result["wall_depth_m"].max() == 0.0
    assert list(result["shift"][result["shift"] != 0]) == [1, 1, 1, -1, -1, -1, -1]
