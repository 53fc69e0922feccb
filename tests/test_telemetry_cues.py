"""The lever's cues from the game's state (telemetry/cues.py, issue 29): each pure function,
`LeverCues` on the recorded Sebring .ibt, and the virtual shifter driven by it."""

from __future__ import annotations

import csv
import io
import json
import math
from contextlib import redirect_stdout
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from carfeel import cli
from carfeel.io.presets import load_hpattern
from carfeel.models.gearshift.hpattern import HPatternParams
from carfeel.telemetry import cues, source
from carfeel.telemetry.cues import CueParams, LeverCues
from carfeel.telemetry.receiver import open_receiver
from carfeel.telemetry.state import VehicleState
from tests.datafiles import data_file

IBT = "iracing-mercedesamggt4-sebring.ibt"
SHIFT_1_2 = 567
"""The .ibt's record between 1st and 2nd of its first upshift (9.45 s: in neutral at 25.6 m/s,
6719 rpm, no clutch; 2nd the next record)."""


@cache
def ibt_states() -> tuple[VehicleState, ...]:
    """Every record of the .ibt as carfeel decodes it (checked against numpy's decoding in
    test_telemetry_iracing)."""
    receiver = open_receiver(f"iracing:file:{data_file('telemetry', IBT)}")
    kept: list[VehicleState] = []
    try:
        for i in range(1600):
            receiver.poll(kept.append, now_s=i / 60.0)
    finally:
        receiver.close()
    return tuple(kept)


def pattern() -> HPatternParams:
    return load_hpattern("6r").pattern()


def test_a_shift_without_the_clutch_is_refused_with_it_accepted() -> None:
    states = ibt_states()
    shift = states[SHIFT_1_2]
    assert (states[SHIFT_1_2 - 1].gear, shift.gear, states[SHIFT_1_2 + 1].gear) == (1, 0, 2)
    assert round(shift.speed_m_s, 1) == 25.6 and shift.clutch_pedal == 0.0
    lever = LeverCues(pattern(), 1000.0)
    for s in states[: SHIFT_1_2 + 60]:  # what the game showed of 1st and 2nd: their ratios
        lever.update(s, 1.0, "N", 1e-3)
    in_second = [s.engine_speed_rpm / s.speed_m_s for s in states[SHIFT_1_2 + 5 : SHIFT_1_2 + 60]]
    # Learned while in 2nd with the clutch out: within 2% of the file's own rpm per m/s there
    # (the engine's speed varies within the gear by the tyres' slip and the driveline's lash).
    assert lever.learned[2] == pytest.approx(float(np.median(in_second)), rel=0.02)
    p, two = lever.p, pattern().layout.gear("2")
    diff = cues.speed_difference_rpm(shift, two.ratio, pattern(), lever.learned[2])
    # 6719 rpm against about 4900 in 2nd at 25.6 m/s: the file's own, within the 2% of the
    # learned ratio (2% of 4900 rpm: 100 rpm).
    expected = shift.engine_speed_rpm - float(np.median(in_second)) * shift.speed_m_s
    assert expected > 1500.0 and diff == pytest.approx(expected, abs=100.0)
    assert cues.rejects(diff, shift, p)
    assert not cues.rejects(diff, shift._replace(clutch_pedal=1.0), p)  # the clutch in
    matched = shift._replace(engine_speed_rpm=lever.learned[2] * shift.speed_m_s + 100.0)
    same = cues.speed_difference_rpm(matched, two.ratio, pattern(), lever.learned[2])
    assert not cues.rejects(same, matched, p)  # revs matched: it goes in without the clutch
    # Neither rpm nor speed: the game's own ShiftGrindRPM; nothing known never refuses.
    blind = VehicleState(clutch_pedal=0.0, shift_grind_rpm=800.0)
    assert cues.speed_difference_rpm(blind, two.ratio, pattern(), 0.0) == 800.0
    assert not cues.rejects(math.nan, blind, p)


def test_the_wall_is_a_passive_spring_past_the_entry() -> None:
    p = CueParams(20_000.0, 50.0)
    assert cues.wall_N(0.010, 0.5, 0.012, p) == 0.0
    assert cues.wall_N(0.013, 0.0, 0.012, p) == pytest.approx(-20.0)
    assert cues.wall_N(0.013, 0.1, 0.012, p) == pytest.approx(-25.0)  # damping going in
    assert cues.wall_N(0.013, -0.1, 0.012, p) == pytest.approx(-20.0)  # none coming out


def test_the_grind_frequency_and_the_bite_point() -> None:
    # 1200 rpm apart over 30 teeth: 600 Hz, an octave down twice below 250 Hz (1 kHz / 4).
    assert cues.grind_frequency_hz(1200.0, 30, 250.0) == pytest.approx(150.0)
    assert cues.grind_frequency_hz(-200.0, 30, 250.0) == pytest.approx(100.0)
    p = CueParams(1.0, 1.0)
    assert cues.bite_coupling(0.0, p) == 1.0 and cues.bite_coupling(1.0, p) == 0.0
    assert cues.bite_coupling(p.bite_point, p) == pytest.approx(0.5)
    assert cues.bite_coupling(math.nan, p) == 1.0  # no pedal said: the engine comes through


def test_replay_pause_lockout_and_mismatch() -> None:
    s = VehicleState(gear=6, forward_gears=6)
    assert cues.cue_weight(0.7, s) == 0.7
    assert cues.cue_weight(1.0, s._replace(replay=True)) == 0.0
    assert cues.cue_weight(1.0, s._replace(paused=True)) == 0.0
    assert cues.sequential_locked(+1, s) and not cues.sequential_locked(-1, s)
    assert cues.sequential_locked(-1, s._replace(gear=-1))
    assert not cues.sequential_locked(+1, s._replace(gear=5))
    assert cues.mismatch("3", s) and not cues.mismatch("6", s) and not cues.mismatch("N", s)
    assert not cues.mismatch("R", s._replace(gear=-1))


class _Lever:
    """The model's state as LeverCues reads it: the slot coordinate and where the knob is."""

    def __init__(self, s_m: float, plane: int, direction: int, gear: str = "N") -> None:
        from carfeel.models.gearshift.engagement import initial_state

        self.lever = initial_state(0)._replace(position_m=s_m, velocity_m_s=0.0)
        self.plane, self.direction, self.gear = plane, direction, gear


def test_the_wall_stands_fades_and_goes_in_a_replay() -> None:
    params = pattern()
    lever = LeverCues(params, 1000.0)
    two = params.layout.gear("2")
    knob: Any = _Lever(lever.entry_m + 0.001, two.plane, two.direction)
    game = ibt_states()[SHIFT_1_2]
    lever.update(game, 1.0, "N", 1e-3)
    fx, fy = lever(knob)
    # A millimetre into the wall of the gate's stiffness, against the gear's direction.
    assert fx == pytest.approx(-two.direction * lever.p.wall_stiffness_N_m * 0.001)
    assert fy == 0.0 and lever.refused == "2" and lever.refusals == 1
    assert lever.grind(1e-3) != 0.0
    lever.update(game, 0.5, "N", 1e-3)  # the telemetry half faded: half the wall
    assert lever(knob)[0] == pytest.approx(0.5 * fx)
    for state in (game._replace(replay=True), game._replace(clutch_pedal=1.0)):
        lever.update(state, 1.0, "N", 1e-3)
        assert lever(knob) == (0.0, 0.0) and lever.grind(1e-3) == 0.0
    engaged: Any = _Lever(lever.entry_m + 0.02, two.plane, two.direction, gear="2")
    lever.update(game, 1.0, "2", 1e-3)
    assert lever(engaged) == (0.0, 0.0)  # a gear that is in stays in
    one = params.layout.gear("1")
    lever.update(game._replace(gear=1), 1.0, "N", 1e-3)  # the game's own gear always goes in
    first: Any = _Lever(lever.entry_m + 0.001, one.plane, one.direction)
    assert lever(first) == (0.0, 0.0)
    six = params.layout.gear("6")
    lever.update(game._replace(forward_gears=5, clutch_pedal=1.0), 1.0, "N", 1e-3)
    sixth: Any = _Lever(lever.entry_m + 0.001, six.plane, six.direction)
    assert lever(sixth)[0] != 0.0  # the car has 5: walled, the clutch in or not


REAL_UPDATE = source.VehicleSource.update
"""Taken once: each run's change wraps the source's own update, not the run before's."""


def _run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, change: dict[str, Any]) -> Any:
    """The virtual shifter's script (1-5 and back) on the .ibt, the game's state changed."""

    def update(self: Any, t_s: float) -> tuple[VehicleState, float]:
        state, w = REAL_UPDATE(self, t_s)
        return state._replace(**change), w

    monkeypatch.setattr(source.VehicleSource, "update", update)
    record = tmp_path / "run.csv"
    out = io.StringIO()
    with redirect_stdout(out):
        code = cli.main(["run", "--model", "hpattern", "--device", "virtual", "--clock",
                         "simulated", "--telemetry", f"iracing:file:{data_file('telemetry', IBT)}",
                         "--duration", "25", "--synchronizer", "fixed", "--record", str(record),
                         "--json"])  # fmt: skip
    assert code == 0
    with record.open() as handle:
        rows = [r for r in csv.DictReader(handle) if r["x_m"] not in ("", "nan")]
    return json.loads(out.getvalue()), rows


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_recorded_session_on_the_virtual_shifter(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The .ibt's driver shifted without the clutch: on the H-pattern the wall refuses the
    script's shifts (revs apart), with a grind; with the clutch pressed every gear goes in;
    in a replay nothing is cued. Stable throughout (no fault, on the virtual joystick)."""
    (tmp_path / "out").mkdir()
    summary, rows = _run(tmp_path / "out", monkeypatch, {})
    assert not summary["faults"] and summary["gears"] == []
    assert any(float(r["engine_vibration"]) != 0.0 for r in rows)  # through the clutch
    walls = np.array([float(r["cue_wall_N"]) for r in rows])
    assert np.abs(walls).max() > 10.0  # the wall pushed back
    assert any(float(r["cue_grind_N"]) != 0.0 for r in rows)
    assert any("the gate refused a gear" in n for n in summary["notes"])
    (tmp_path / "clutch").mkdir()
    summary, rows = _run(tmp_path / "clutch", monkeypatch, {"clutch_pedal": 1.0})
    assert not summary["faults"]
    assert summary["gears"] == ["1", "2", "3", "4", "5", "4", "3", "2", "1"]
    assert all(float(r["cue_wall_N"]) == 0.0 for r in rows)
    (tmp_path / "replay").mkdir()
    summary, rows = _run(tmp_path / "replay", monkeypatch, {"replay": True})
    assert not summary["faults"] and summary["gears"] == []  # the synchronizer still balks
    assert all(float(r["cue_wall_N"]) == 0.0 and float(r["engine_vibration"]) == 0.0
               for r in rows)  # fmt: skip
    assert not any("the gate refused" in n for n in summary["notes"])


def test_garbage_states_give_finite_cues() -> None:
    """States a decoder could hand on (NaN anywhere, zeros, extremes, another game's gear
    counts): every force finite, a wall only where the state justifies one."""
    import random

    from carfeel.telemetry.driving import GameTorque

    rng = random.Random(29)
    params = pattern()
    lever = LeverCues(params, 1000.0)
    torque = GameTorque(1.0, 11.0, math.nan, exogenous=False)
    values = (math.nan, 0.0, -1.0, 1.0, 1e-9, 149.0, 29_999.0, -5.0)
    for _ in range(3000):
        state = VehicleState(
            speed_m_s=rng.choice(values), engine_speed_rpm=rng.choice(values),
            gear=rng.randint(-1, 24), clutch_pedal=rng.choice((math.nan, 0.0, 0.5, 1.0)),
            shift_grind_rpm=rng.choice(values), forward_gears=rng.randint(0, 24),
            wheel_torque_Nm=rng.choice(values), wheel_torque_max_Nm=rng.choice(values),
            wheel_torque_samples_Nm=rng.choice(((), (1.0, math.nan), (5.0,) * 6)),
            replay=rng.random() < 0.1,
        )  # fmt: skip
        lever.update(state, rng.random(), rng.choice(("N", "1", "R")), 1e-3)
        slot = rng.choice(params.layout.gears)
        knob: Any = _Lever(rng.uniform(-0.05, 0.05), slot.plane, slot.direction)
        fx, fy = lever(knob)
        assert math.isfinite(fx) and fy == 0.0 and math.isfinite(lever.grind(1e-3))
        if state.replay:
            assert fx == 0.0
        g = torque.value(state, rng.uniform(0.0, 0.05))
        assert math.isnan(g) or abs(g) <= 11.0
    assert all(math.isfinite(v) and v > 0.0 for v in lever.learned.values())


def test_hold_pushes_a_gear_the_game_did_not_take_back_out() -> None:
    params = pattern()
    three = params.layout.gear("3")
    in_gear = params.engagement.in_gear_position_m
    knob: Any = _Lever(in_gear, three.plane, three.direction, gear="3")
    for hold in (False, True):
        lever = LeverCues(params, 1000.0, hold=hold)
        neutral = VehicleState(speed_m_s=20.0, engine_speed_rpm=3000.0, gear=0)
        forces = []
        for _ in range(300):  # 0.3 s of the game in neutral, the lever in 3rd
            lever.update(neutral, 1.0, "3", 1e-3)
            forces.append(lever(knob)[0])
        if not hold:
            assert all(f == 0.0 for f in forces)  # counted only
            assert lever.mismatch_s == pytest.approx(0.3)
            continue
        # Nothing within the grace (a shift passes neutral, a live game follows in 2 frames),
        # then the gate wall's full force back out along the slot, once counted.
        grace = round(lever.p.hold_grace_s / 1e-3)
        assert all(f == 0.0 for f in forces[: grace - 1])
        assert forces[-1] == pytest.approx(-three.direction * lever.p.hold_force_N)
        assert lever.holds == 1
        lever.update(neutral._replace(gear=3), 1.0, "3", 1e-3)  # the game took it
        assert lever(knob) == (0.0, 0.0)
        for _ in range(300):
            lever.update(neutral._replace(replay=True), 1.0, "3", 1e-3)
        assert lever(knob) == (0.0, 0.0)  # a replay: nobody is driving


def test_interlock_hold_needs_the_lever_and_the_game(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["run", "--model", "hpattern", "--interlock", "hold"]) == 2
    assert "--interlock hold needs" in capsys.readouterr().err
