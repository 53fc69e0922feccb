"""An automatic's selector (issue 30): every position both ways, the shift lock as a wall."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from carfeel.errors import InputError, PresetError
from carfeel.models.gearshift import prnd as pr
from carfeel.telemetry.gearout import prnd_buttons
from tests.preset_edits import assert_each_edit_is_named

DT_S = 0.001
HAND_N = 25.0
"""A firm hand: above the detents' 15 N peak, so every unlocked move goes through."""
P, R, N, D = 0, 1, 2, 3


class Hand:
    """Pushes toward a target until it registers (or `seconds` run out), then lets go."""

    def __init__(self, params: pr.PrndParams) -> None:
        self.params = params
        self.state = pr.PrndState()
        self.shifts: list[int] = []
        self.max_depth_m = 0.0

    def run(self, force_N: float, seconds: float, **flags: object) -> None:
        for _ in range(round(seconds / DT_S)):
            inputs = pr.PrndInputs(force_N, **flags)  # type: ignore[arg-type]
            self.state, out = pr.step(self.params, self.state, inputs, DT_S)
            assert math.isfinite(self.state.x_m) and math.isfinite(out.lever_N)
            self.max_depth_m = max(self.max_depth_m, out.wall_depth_m)
            if out.shift:
                self.shifts.append(out.shift)

    def move(self, target: int, hand_N: float = HAND_N, **flags: object) -> None:
        centre = self.params.centre_m(target)
        for _ in range(round(0.6 / DT_S)):
            if self.state.position == target:
                break
            self.run(math.copysign(hand_N, centre - self.state.x_m), DT_S, **flags)
        self.run(0.0, 0.5, **flags)


def test_every_position_both_ways_registered_at_its_centre() -> None:
    params = pr.PrndParams()
    hand = Hand(params)
    for target in (R, N, D, N, R, P):
        hand.move(target, brake=True, button=True)
        assert hand.state.position == target
        # Let go, the lever settles in the target's well: within 0.1 mm of its centre.
        assert abs(hand.state.x_m - params.centre_m(target)) < 1e-4
    assert hand.shifts == [1, 1, 1, -1, -1, -1] and hand.max_depth_m == 0.0
    assert [prnd_buttons(p, 4) for p in (P, R, N, D)] == [[("press", i)] for i in range(4)]
    with pytest.raises(ValueError, match=r"outside 0 \.\. 3"):
        prnd_buttons(4, 4)


@pytest.mark.parametrize("hand_N", [HAND_N, 100.0])
def test_p_is_locked_without_the_brake_as_a_wall(hand_N: float) -> None:
    params = pr.PrndParams()
    hand = Hand(params)
    hand.move(R, hand_N, brake=False)
    assert hand.state.position == P and hand.shifts == []
    # The wall stands lock_m (6 mm) from P's centre; a hand gets in by the wall's compliance
    # and its impact (25 N: 0.9 mm measured; 100 N: (100 - 14) / 40 kN/m ~ 2.2 mm static
    # plus impact), never to the crest (15 mm) from which the lever would fall into R.
    assert 0.0 < hand.max_depth_m < 0.5 * params.pitch_m - params.lock_m - params.register_m
    assert abs(hand.state.x_m) < 1e-4  # let go, back in P's centre: a wall, not a buzz
    hand.move(R, hand_N, brake=True)
    # With the brake, out of P; a 100 N shove (the hand lets go as R registers) carries the
    # 0.8 kg lever over R's 15 N detent into N, as a real selector shoved that hard would.
    assert hand.state.position == (R if hand_N == HAND_N else N)


def test_r_from_n_needs_the_button_and_a_slow_car() -> None:
    params = pr.PrndParams()
    hand = Hand(params)
    hand.move(N, brake=True)
    assert hand.state.position == N
    hand.move(R, button=False)
    assert hand.state.position == N and 0.0 < hand.max_depth_m < 0.002
    hand.move(R, button=True, speed_m_s=5.0)  # rolling forward at 18 km/h: locked
    assert hand.state.position == N
    hand.move(R, button=True, speed_m_s=float("nan"))  # a speed not known: locked, not open
    assert hand.state.position == N
    hand.move(R, button=True, speed_m_s=1.0)
    assert hand.state.position == R
    # A preset without the button rule: N -> R plainly (below the speed).
    plain = Hand(pr.PrndParams(r_needs_button=False))
    plain.state = pr.PrndState(params.centre_m(N), 0.0, N)
    plain.move(R)
    assert plain.state.position == R
    # A preset with the button on P too: the brake alone does not let it out.
    strict = Hand(pr.PrndParams(p_needs_button=True))
    strict.move(R, brake=True)
    assert strict.state.position == P
    strict.move(R, brake=True, button=True)
    assert strict.state.position == R


def _barrier_J(params: pr.PrndParams, x_m: float, crest_m: float) -> float:
    """The work the detents take from a lever moving from x to the crest, J (the potential
    of F = -detent_N sin(2 pi x / pitch): U = detent_N pitch / (2 pi) (1 - cos(...)))."""
    scale = params.detent_N * params.pitch_m / (2.0 * math.pi)
    u = lambda x: scale * (1.0 - math.cos(2.0 * math.pi * x / params.pitch_m))  # noqa: E731
    return u(crest_m) - u(x_m)


@pytest.mark.parametrize(
    ("x_m", "v_m_s", "settles"),
    [
        (0.0149, 0.0, P),  # at rest 0.1 mm on P's side of the crest: falls back into P
        (0.0151, 0.0, R),  # 0.1 mm past it: falls into R, which registers
        (0.012, 0.10, P),  # moving toward R, but with less energy than the crest takes
        (0.005, 0.60, P),  # 0.14 J, above the 0.11 J barrier: the damping takes the rest
        (0.005, 1.00, R),  # 0.4 J: carries over the crest into R
    ],
)
def test_a_lever_let_go_between_detents_settles_into_one(
    x_m: float, v_m_s: float, settles: int
) -> None:
    params = pr.PrndParams(p_needs_button=False)
    hand = Hand(params)
    # Registered P (the brake pressed, so P's lock is open and only the detents act).
    hand.state = pr.PrndState(x_m, v_m_s, P)
    kinetic_J = 0.5 * params.mass_kg * v_m_s**2
    crest = 0.5 * params.pitch_m
    if x_m < crest and kinetic_J < _barrier_J(params, x_m, crest):
        assert settles == P  # damping only takes energy: a lever short of it cannot cross
    hand.run(0.0, 1.0, brake=True)
    assert hand.state.position == settles
    assert abs(hand.state.x_m - params.centre_m(settles)) < 1e-4
    assert abs(hand.state.v_m_s) < 1e-3


def test_an_extra_m_position_and_its_buttons() -> None:
    params = pr.PrndParams(positions=("P", "R", "N", "D", "M"))
    hand = Hand(params)
    hand.move(4, brake=True)
    assert hand.state.position == 4 and hand.shifts == [1, 1, 1, 1]
    hand.move(4, hand_N=100.0)  # into the end stop past M: held by it
    assert hand.state.x_m < params.centre_m(4) + params.end_m
    assert prnd_buttons(4, 5) == [("press", 4)]


@pytest.mark.parametrize(
    ("bad", "named"),
    [
        ({"positions": ("P", "N", "R", "D")}, "positions ="),
        ({"positions": ("P", "R", "N", "D", "D")}, "each once"),
        ({"lock_m": 0.02}, "lock_m < pitch_m / 2"),
        ({"register_m": 0.0}, "register_m"),
        ({"detent_N": float("nan")}, "detent_N = nan"),
        ({"wall_N_m": -1.0}, "wall_N_m = -1.0"),
        ({"mass_kg": 0.0}, "mass_kg must be positive"),
    ],
)
def test_bad_parameters_are_refused_with_what_is_wrong(bad: dict[str, object], named: str) -> None:
    with pytest.raises(PresetError, match="prnd selector") as info:
        pr.PrndParams(**bad)  # type: ignore[arg-type]
    assert named in str(info.value)


def test_the_shipped_preset_loads_and_a_bad_one_names_its_problem(tmp_path: Path) -> None:
    from carfeel.io import presets

    preset = presets.load_prnd("automatic")
    assert preset.params.selector.positions == ("P", "R", "N", "D")
    assert "automatic" in presets.available("prnd")
    edits = (
        ("lock_m = 0.006", "lock_m = 0.02", "lock_m < pitch_m / 2"),
        ('positions = ["P", "R", "N", "D"]', 'positions = ["D"]', "positions = ['D']"),
        ("detent_N = 15.0", 'detent_N = "x"', "selector.detent_N = 'x'"),
        ("detent_N = 15.0", "detent_N = 1e6", "selector.detent_N = 1e+06 N is out of range"),
        ("hold_s = 0.6", "hold_s = 0.0", "hold_s = 0.0"),
        ("[driver]", "[drivr]", "drivr: unknown key"),
    )
    other = ("sequential", "rally-6", "is a sequential preset")
    assert_each_edit_is_named("prnd", "automatic", edits, tmp_path, other)


def test_offline_driver_and_its_input_checks() -> None:
    from carfeel.simulation.prnd import (
        PrndSetup,
        parse_flags,
        parse_moves,
        parse_speeds,
        simulate_prnd,
    )

    positions = pr.BASE_POSITIONS
    moves = parse_moves("R, N, D, N, R, P", positions)
    brake = parse_flags("off,on,on,on,on,on", 6, "--brake")
    result = simulate_prnd(PrndSetup(), moves, brake, (True,) * 6, (0.0,) * 6)
    seen = result["position"]
    changes = [g for k, g in enumerate(seen) if k == 0 or g != seen[k - 1]]
    # The first move (P -> R without the brake) is refused; the second walks P, R, N.
    assert changes == ["P", "R", "N", "D", "N", "R", "P"]
    assert 0.0 < result["wall_depth_m"].max() < 0.002
    for bad in ("", "R,Q", "R," * 1001):
        with pytest.raises(InputError, match="--moves"):
            parse_moves(bad, positions)
    for text in ("yes", "on,off"):
        with pytest.raises(InputError, match="--brake"):
            parse_flags(text, 3, "--brake")
    for text in ("fast", "nan", "-1", "1,2"):
        with pytest.raises(InputError, match="--speed"):
            parse_speeds(text, 3)


def test_simulate_prnd_command_and_its_refusals(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from carfeel.cli import main

    out = tmp_path / "run.csv"
    assert main(["simulate", "prnd", "--moves", "R,N,D,N,R,P", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "6 reached, 0 refused" in text and "positions P R N D N R P" in text
    assert out.with_suffix(".json").is_file()
    before = out.read_bytes()
    for bad in (["--moves", "R,X"], ["--moves", "R", "--preset", "nope"],
                ["--moves", "R", "--dt", "0.5"], ["--moves", "R", "--brake", "maybe"],
                ["--moves", "R,N", "--speed", "1,2,3"]):  # fmt: skip
        assert main(["simulate", "prnd", *bad, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and "error:" in err
        assert out.read_bytes() == before  # a failed run leaves the earlier output untouched
    locked = tmp_path / "locked.csv"
    assert main(["simulate", "prnd", "--moves", "R,N", "--brake", "off", "--out",
                 str(locked)]) == 0  # fmt: skip
    assert "0 reached, 2 refused" in capsys.readouterr().out


@pytest.mark.parametrize("gap_m", [0.0001, 0.0005, 0.002])
def test_the_lock_wall_only_pushes(gap_m: float) -> None:
    """A step from short of P's locked wall that would end past it: the wall may slow the
    lever, never speed it into itself (an implicit spring reached mid-step would pull)."""
    params = pr.PrndParams()
    state = pr.PrndState(params.lock_m - gap_m, 3.0, P)
    free, _ = pr.step(params, state, pr.PrndInputs(HAND_N, brake=True), DT_S)
    walled, _out = pr.step(params, state, pr.PrndInputs(HAND_N, brake=False), DT_S)
    assert free.x_m > params.lock_m  # the step does reach the wall's position
    assert walled.v_m_s <= free.v_m_s and walled.x_m <= free.x_m
    # Leaving the wall, it lets go: a lever moving out of it is not held back by its damper.
    inside = pr.PrndState(params.lock_m + 0.0005, -0.5, P)
    out_free, _ = pr.step(params, inside, pr.PrndInputs(0.0, brake=True), DT_S)
    out_walled, _ = pr.step(params, inside, pr.PrndInputs(0.0, brake=False), DT_S)
    assert out_walled.v_m_s <= out_free.v_m_s  # pushed out at least as fast, never pulled back


def test_a_brutal_hand_bends_the_lock_wall_but_never_shifts() -> None:
    """300 N (a yank, twelve times the driver's) compresses the 40 kN/m wall 11 mm, past the
    crest; the lock holds because it follows the registered position (P), which needs the
    lever within 4 mm of R's centre: the lever springs back into P when let go."""
    params = pr.PrndParams()
    hand = Hand(params)
    hand.move(R, 300.0, brake=False)
    assert hand.state.position == P and hand.shifts == []
    # (300 - 15) / 40 kN/m ~ 7 mm static plus the impact: measured 11.0 mm; the bound is the
    # distance from the wall to where R would register (30 - 4 - 6 = 20 mm).
    assert hand.max_depth_m < params.pitch_m - params.register_m - params.lock_m
    assert abs(hand.state.x_m) < 1e-4
