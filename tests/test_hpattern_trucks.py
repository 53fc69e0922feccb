"""A truck's range/splitter box and a double-H on the H-pattern (issue 30, third part): the
gear is (slot, range, splitter) from the preset's table, the synchronizer matches its ratio,
a range waits for neutral and a split for the torque to go off; the double-H's range is the
half the knob is in, across a detent. Offline, on the virtual shifter, and the gear output's
buttons read through ETS2's own 14+2 slot table."""

from __future__ import annotations

import functools
import itertools
import json
import math

import numpy as np
import pytest

from carfeel.errors import InputError, PresetError
from carfeel.io.presets import HPatternPreset, load_hpattern
from carfeel.models.drivers.hpattern import Script
from carfeel.models.gearshift import hpattern, synchronizer
from carfeel.models.gearshift.engagement import Stage
from carfeel.models.gearshift.hpattern import HPatternInputs, HPatternParams, HPatternState
from carfeel.simulation import hpattern as loop
from carfeel.simulation.hpattern import HPatternRun, simulate_hpattern
from carfeel.telemetry.gearout import GearDriver, RecordingGearOutput, gears_from_buttons
from tests.datafiles import data_file

TRUCK_ALL = ("N", *(str(g) for g in range(1, 15)), "N", "R1", "N", "R2", "N")
DOUBLE_H_ALL = ("N", "1", "2", "3", "4", "5", "6", "7", "8", "7", "6", "5", "4", "N", "R", "N")
RPM_800 = 800 * 2 * math.pi / 60
POSITIONS = 8  # ETS2's Scania table: handle positions 0..7


@functools.cache
def preset(name: str) -> HPatternPreset:
    return load_hpattern(name)


def ets2_slots() -> tuple[tuple[int, int, int], ...]:
    """(handle position, selector, gear) of the Scania S 14+2 as ETS2's SDK gives them."""
    snapshot = json.loads(data_file("telemetry", "ets2-scs-sdk-plugin-snapshot-scania-s.json")
                          .read_text("utf-8"))  # fmt: skip
    return tuple((s["handlePosition"], s["selector"], s["gear"])
                 for s in snapshot["truck"]["transmission"]["slots"])  # fmt: skip


def engaged(events: list[str] | np.ndarray) -> list[str]:
    return [str(e).split()[1] for e in events if str(e).startswith("engage")]


def run_offline(name: str, sequence: tuple[str, ...], gear_mapping: str | None = None,
                physics: bool = False, speed_kmh: float = 0.0):  # fmt: skip
    """The driver through `sequence` offline at 1 kHz; with `gear_mapping`, a GearDriver fed
    with the knob's state every step, as the 1 kHz loop feeds it (engaged timing)."""
    p = preset(name)
    script = Script(sequence, p.setup.layout, p.shift.driver, p.setup.driver)
    run = HPatternRun(p.pattern(physics), script, speed_kmh / 3.6, RPM_800)
    fake = RecordingGearOutput()
    driver = None
    if gear_mapping is not None:
        driver = GearDriver(fake, p.setup.layout, "engaged", gear_mapping)
    state = loop.initial_state(run)
    rows = []
    for _ in range(60_000):
        state, out = loop.step(state, None, run, 1e-3)
        if driver is not None:
            driver.update(state.knob)
        rows.append((out, state.knob))
        if loop.finished(state) and state.driver.phase_time_s > 0.3:
            break
    return rows, fake


# ---------------------------------------------------------------- the truck, offline


def test_the_truck_shifts_through_all_fourteen_gears_and_both_reverses():
    """C, 1, 2, 3 in low range with the splitter low and high, 1, 2, 3 in high range, R1 and
    R2: every gear engages, in order, and each split (2, 4 ... 14) happens with the lever left
    in its slot (no disengage between the two gears of a slot)."""
    p = preset("truck-14r2")
    result = simulate_hpattern(
        HPatternRun(p.pattern(), Script(TRUCK_ALL, p.setup.layout, p.shift.driver,
                                        p.setup.driver), 0.0, RPM_800),
        max_duration_s=80.0,
    )  # fmt: skip
    assert engaged(result["event"]) == [g for g in TRUCK_ALL if g != "N"]
    assert result["gear"][-1] == "N"
    events = [str(e) for e in result["event"] if e]
    for split in ("2", "4", "6", "8", "10", "12", "14"):
        before = events[events.index(f"engage {split}") - 1]
        assert before == f"engage {int(split) - 1}"  # the split: no disengage in between


def _knob_at_ring(pattern: HPatternParams, slot: str, speed_kmh: float) -> HPatternState:
    """The knob in `slot`'s mouth, the input shaft turning with an 800 rpm engine."""
    layout = pattern.layout
    gear = layout.gear(slot)
    state = hpattern.initial_state(pattern, input_speed_rad_s=RPM_800)
    return state._replace(direction=gear.direction, y_m=layout.planes_y_m[gear.plane],
                          plane=gear.plane)  # fmt: skip


def _push_in(pattern, state, range_high, splitter_high, speed_kmh, seconds=8.0, sign=0):
    """A steady 78.5 N push along the slot, clutch pressed: (input-shaft speed as the ring let
    go, outputs, steps) when the gear goes in."""
    released = math.nan
    sign = sign or state.direction
    for n in range(int(seconds * 1000)):
        inputs = HPatternInputs(78.5 * sign, 0.0, 1.0, speed_kmh / 3.6, RPM_800,
                                range_high, splitter_high)  # fmt: skip
        was = state.lever.stage
        state, out = hpattern.step(state, inputs, pattern, 1e-3)
        if was is Stage.SYNCHRONIZATION and state.lever.stage is not Stage.SYNCHRONIZATION:
            released = state.sync.input_speed_rad_s
        if out.event.startswith("engage"):
            return (state, released), out, n + 1
    raise AssertionError("the gear did not go in")


def test_the_synchronizer_matches_the_ratio_of_the_selected_range_and_splitter():
    """Physics mode at 10 km/h, the same slot (1): in low range the cone must bring the input
    shaft to the table's 9.15 x the output speed, in high range to 2.444 x, with the splitter
    high to 7.331 x: the gear that engages is the table's, at the input speed of its ratio, and
    the time follows the speed step (from 800 rpm, 84 rad/s, up to 194 rad/s in 3 takes longer
    than down to 52 rad/s in 9)."""
    pattern = preset("truck-14r2").pattern(physics=True)
    w_out = synchronizer.output_speed_rad_s(10 / 3.6, pattern.synchronizer)
    steps = {}
    for range_high, splitter_high, gear, ratio in (
        (False, False, "3", 9.15), (True, False, "9", 2.444), (False, True, "4", 7.331),
    ):  # fmt: skip
        state = _knob_at_ring(pattern, "1", 10.0)
        (_, speed), out, steps[gear] = _push_in(pattern, state, range_high, splitter_high, 10.0)
        assert out.gear == gear
        # As the ring lets go: within the gate's speed tolerance (2 rad/s) of the table's
        # ratio; the slot's own (9.15) is 100-140 rad/s away for gears 9 and 4.
        assert abs(speed - w_out * ratio) <= 2.0
    assert steps["3"] > steps["4"] > steps["9"]


def test_a_range_pre_selected_in_gear_waits_for_neutral():
    """In 3 (slot 1, low range) the driver flips the range switch high: nothing changes while
    the gear is in; back in neutral the range goes high, and the next push into the same slot
    synchronizes to the high range's ratio and engages 9."""
    pattern = preset("truck-14r2").pattern(physics=True)
    w_out = synchronizer.output_speed_rad_s(10 / 3.6, pattern.synchronizer)
    state = _knob_at_ring(pattern, "1", 10.0)
    (state, _), out, _ = _push_in(pattern, state, False, False, 10.0)
    assert out.gear == "3"
    for _ in range(500):  # switch high, still pushing in gear: the range box waits
        state, out = hpattern.step(state, HPatternInputs(20.0, 0.0, 1.0, 10 / 3.6, RPM_800, True),
                                   pattern, 1e-3)  # fmt: skip
        assert out.gear == "3" and not out.range_high
    for _ in range(3000):  # pull back to neutral with the switch high
        pull = -40.0 if state.lever.position_m > 0.002 else 0.0
        inputs = HPatternInputs(pull, 0.0, 1.0, 10 / 3.6, RPM_800, True)
        state, out = hpattern.step(state, inputs, pattern, 1e-3)
        if state.lever.stage is Stage.NEUTRAL and abs(state.lever.position_m) < 0.002:
            break
    assert out.gear == "N" and out.range_high
    (state, speed), out, _ = _push_in(pattern, state, True, False, 10.0, sign=1)  # forward
    assert out.gear == "9"
    assert abs(speed - w_out * 2.444) <= 2.0  # the gate's tolerance


@pytest.mark.parametrize(("clutch", "throttle", "waits"), [
    (0.0, 0.5, True),  # under torque: the split waits
    (0.0, 0.0, False),  # throttle lifted (as in ETS2)
    (1.0, 0.5, False),  # clutch in
])  # fmt: skip
def test_a_split_pre_selected_under_torque_waits_for_the_torque_to_go_off(clutch, throttle, waits):
    pattern = preset("truck-14r2").pattern()
    state = _knob_at_ring(pattern, "2", 0.0)
    (state, _), out, _ = _push_in(pattern, state, False, False, 0.0)
    assert out.gear == "5"
    seen = []
    for _ in range(300):
        inputs = HPatternInputs(
            5.0 * state.direction, 0.0, clutch, 0.0, RPM_800, False, True, throttle
        )
        state, out = hpattern.step(state, inputs, pattern, 1e-3)
        seen.append(out.gear)
    assert set(seen) == ({"5"} if waits else {"6"})
    if waits:  # lifting the throttle executes it at that step
        inputs = HPatternInputs(5.0 * state.direction, 0.0, clutch, 0.0, RPM_800, False, True, 0.0)
        state, out = hpattern.step(state, inputs, pattern, 1e-3)
        assert out.gear == "6" and out.event == "engage 6" and state.lever.stage in hpattern.IN_MESH


def test_the_crawler_is_closed_in_high_range():
    """ETS2's table has no crawler in high range: its slot is a gate wall there, however hard
    the push (the hand holding the knob on the crawler's plane against the select spring); in
    low range the same push engages 1."""
    pattern = preset("truck-14r2").pattern()
    half = 0.5 * pattern.layout.corridor_width_m
    for range_high, expected in ((True, "N"), (False, "1")):
        state = _knob_at_ring(pattern, "C", 0.0)
        deepest = 0.0
        for _ in range(3000):
            inputs = HPatternInputs(-150.0, -15.0, 1.0, 0.0, RPM_800, range_high)
            state, out = hpattern.step(state, inputs, pattern, 1e-3)
            deepest = max(deepest, -out.x_m)
        assert out.gear == expected
        if range_high:  # the gate's compliance, no further
            assert deepest <= half + hpattern.WALL_DEPTH_M + 1e-12


def test_the_preset_table_is_ets2s_scania_table():
    """Every row of truck-14r2 (handle position, range and splitter bits, gear) is a row of
    the game's own table, and every gear the game's table gives is in ours."""
    layout = preset("truck-14r2").setup.layout
    game = {(pos, sel): gear for pos, sel, gear in ets2_slots()}
    ours = {(r.handle_position, r.range_high | r.splitter_high << 1): r.gear for r in layout.truck}
    assert all(game[key] == gear for key, gear in ours.items())
    assert {k for k, g in game.items() if g != 0} == set(ours)


def test_the_gear_output_gives_the_buttons_ets2_reads_as_each_gear():
    """range-splitter, offline through all gears: the buttons held, read through ETS2's own
    14+2 table (position button, range bit 8, splitter bit 9), are the gears engaged, in order,
    and neutral between slots."""
    rows, fake = run_offline("truck-14r2", TRUCK_ALL, "range-splitter")
    assert engaged([o.event for o, _ in rows]) == [g for g in TRUCK_ALL if g != "N"]
    read = gears_from_buttons(fake.calls, "range-splitter", 14, ets2_slots(), POSITIONS)
    # Between two slots the lever passes neutral (all released); a split changes the held
    # buttons without it: 1, 2 (the splitter), N, 3, 4, N ... 13, 14, N, R1, N, R2, N.
    pairs = [[2 * k + 1, 2 * k + 2, 0] for k in range(7)]
    assert read == [*(g for pair in pairs for g in pair), -1, 0, -2, 0]
    assert ("hold", 1 << 5 | 1 << 8) in fake.calls  # 9: the 1-slot's position, range high
    assert ("hold", 1 << 7 | 1 << 8 | 1 << 9) in fake.calls  # 14: 3's position, both high


def test_range_splitter_needs_a_truck_layout():
    with pytest.raises(InputError, match="truck"):
        GearDriver(RecordingGearOutput(), preset("double-h-8r").setup.layout,
                   mapping="range-splitter")  # fmt: skip


# ---------------------------------------------------------------- the double-H, offline


def test_the_double_h_shifts_through_both_halves_and_back():
    rows, fake = run_offline("double-h-8r", DOUBLE_H_ALL, "buttons")
    outs = [o for o, _ in rows]
    assert engaged([o.event for o in outs]) == [g for g in DOUBLE_H_ALL if g != "N"]
    layout = preset("double-h-8r").setup.layout
    boundary = layout.range_boundary_m()
    # The range is the half the knob is in; the gears 5-8 engage in the high half only.
    for o, knob in rows:
        assert knob.range_high == (o.y_m > boundary)
        if o.event.startswith("engage"):
            assert knob.range_high == (o.gear in {"5", "6", "7", "8"})
    # A button per gear, as an H-shifter binding: gear g holds button g - 1, R the ninth.
    pressed = [b for name, b in fake.calls if name == "press"]
    assert pressed == [0, 1, 2, 3, 4, 5, 6, 7, 6, 5, 4, 3, 8]


def _static_select_force(pattern: HPatternParams, y: float) -> float:
    """The select springs' force on a knob held still at y in the corridor, N (+: to higher y)."""
    state = hpattern.initial_state(pattern)
    state = state._replace(y_m=y, plane=hpattern.nearest_plane(pattern.layout, y))
    k, rest, _ = hpattern._select_springs(y, y, pattern.layout, pattern.select, pattern.walls)
    return -k * (y - rest)


def test_the_range_detent_stands_between_the_halves_and_is_passive():
    """The select force across the boundary: away from it on both sides, peaking at the detent
    plus the select spring (25 + 4 N) just before it, continuous elsewhere; with no hand, a knob
    thrown across it never gains energy (the force is a potential's)."""
    pattern = preset("double-h-8r").pattern()
    layout, sel = pattern.layout, pattern.select
    b = layout.range_boundary_m()
    left, right = _static_select_force(pattern, b - 1e-6), _static_select_force(pattern, b + 1e-6)
    spring = sel.centring_stiffness_N_m * (b - layout.planes_y_m[layout.centre_plane])
    assert left == pytest.approx(-(layout.range_detent_N + spring), rel=1e-3)
    assert right == pytest.approx(layout.range_detent_N + spring, rel=1e-3)
    # Energy: integrate the static force from the low neutral (a potential) and throw the knob.
    ys = np.linspace(layout.planes_y_m[1], layout.planes_y_m[-1], 4001)
    forces = np.array([_static_select_force(pattern, float(y)) for y in ys])
    potential = -np.concatenate(([0.0], np.cumsum(0.5 * (forces[1:] + forces[:-1]) * np.diff(ys))))

    def energy(state: HPatternState) -> float:
        return float(0.5 * sel.mass_kg * state.vy_m_s**2 + np.interp(state.y_m, ys, potential))

    for vy in (0.2, 0.5, 1.0, -0.5):
        y0 = b - 0.012 if vy > 0 else b + 0.012
        state = hpattern.initial_state(pattern)
        state = state._replace(y_m=y0, vy_m_s=vy, plane=hpattern.nearest_plane(layout, y0))
        start = energy(state)
        for _ in range(1500):
            state, _ = hpattern.step(state, HPatternInputs(0.0, 0.0, 1.0), pattern, 1e-3)
            if layout.planes_y_m[1] < state.y_m < layout.planes_y_m[-1]:
                # 1e-4 J: the trapezoid's error of the 4001-point potential at the wells' edges
                assert energy(state) <= start + 1e-4


@pytest.mark.parametrize(("old", "new", "message"), [
    ("high_centre_plane = 3", "high_centre_plane = 4", "equally far"),  # 10 mm and 30 mm
    ("range_plane = 3\n", "range_plane = 9\n", "range_plane = 9"),
    ("range_detent_N = 25.0", "range_detent_N = 60.0", "cannot cross the range detent"),
])  # fmt: skip
def test_a_double_h_it_cannot_render_or_drive_is_refused(tmp_path, old, new, message):
    from carfeel.io.presets import resolve

    text = resolve("hpattern", "double-h-8r")[1]
    assert old in text
    path = tmp_path / "dh.toml"
    path.write_text(text.replace(old, new), encoding="utf-8")
    with pytest.raises(PresetError, match=message):
        load_hpattern(str(path))


def test_a_truck_row_on_a_slot_the_layout_lacks_is_refused(tmp_path):
    from carfeel.io.presets import resolve

    text = resolve("hpattern", "truck-14r2")[1].replace('slot = "3"', 'slot = "4"', 1)
    path = tmp_path / "truck.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(PresetError, match=r"slot '4'.*no such slot"):
        load_hpattern(str(path))


def test_old_layouts_ignore_the_knob_switches():
    """A car's H-pattern has no range box: the switches change nothing, bit for bit."""
    car = load_hpattern("5r").pattern()
    assert not car.layout.truck and car.layout.range_plane == 0
    a = b = hpattern.initial_state(car)
    for i in range(2000):
        force = 78.5 if i < 1500 else -40.0
        a, oa = hpattern.step(a, HPatternInputs(force, 3.0, 1.0), car, 1e-3)
        b, ob = hpattern.step(b, HPatternInputs(force, 3.0, 1.0, 0.0, 0.0, True, True, 0.9),
                              car, 1e-3)  # fmt: skip
        assert oa[:-2] == ob[:-2]


# ---------------------------------------------------------------- on the virtual shifter


def _realtime(name: str, sequence: tuple[str, ...], mapping: str, monkeypatch):
    from carfeel.realtime.session import RealtimeRun, run_realtime
    from carfeel.telemetry import gearout

    fake = RecordingGearOutput()
    counts: list[int] = []

    def opened(name: str, buttons: int) -> RecordingGearOutput:
        counts.append(buttons)
        return fake

    monkeypatch.setattr(gearout, "open_gear_output", opened)
    run = RealtimeRun(model="hpattern", clock="simulated", device="virtual:shifter",
                      preset=name, sequence=sequence, speed_kmh=0.0,
                      telemetry="carfeel:127.0.0.1:0", gear_output="uinput",
                      gear_timing="engaged", gear_mapping=mapping)  # fmt: skip
    return run_realtime(run), fake, counts


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_truck_on_the_virtual_shifter(monkeypatch):
    """All 14 gears and both reverses on the virtual shifter at the default delay, simulated
    time: no fault, the gears in order, and the range-splitter buttons (10: 8 positions, range,
    splitter) read through ETS2's table as those gears."""
    result, fake, counts = _realtime("truck-14r2", TRUCK_ALL, "range-splitter", monkeypatch)
    assert result.summary.faults == []
    assert result.summary.gears == [g for g in TRUCK_ALL if g != "N"]
    assert counts == [POSITIONS + 2]
    read = gears_from_buttons(fake.calls, "range-splitter", 14, ets2_slots(), POSITIONS)
    assert [g for g in read if g != 0] == [*range(1, 15), -1, -2]


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_double_h_on_the_virtual_shifter(monkeypatch):
    sequence = ("N", "1", "2", "3", "4", "5", "6", "7", "8", "N", "R", "N")
    result, fake, _ = _realtime("double-h-8r", sequence, "buttons", monkeypatch)
    assert result.summary.faults == []
    assert result.summary.gears == [g for g in sequence if g != "N"]
    read = gears_from_buttons(fake.calls, "buttons", 8)
    assert [g for g in read if g != 0] == [1, 2, 3, 4, 5, 6, 7, 8, -1]


def test_the_sequence_names_the_trucks_gears():
    """A sequence names the table's gears (1..14, R1, R2), not the slots."""
    from carfeel.runs import HPatternRunConfig, plan_hpattern

    with pytest.raises(InputError, match="no gear C"):
        plan_hpattern(HPatternRunConfig(("N", "C", "N"), layout="truck-14r2"))
    names = preset("truck-14r2").setup.layout.gear_names()
    assert names == [*(str(g) for g in range(1, 15)), "R1", "R2"]


def test_simulate_hpattern_drives_the_truck_from_the_command_line(tmp_path, capsys):
    """`carfeel simulate hpattern --layout truck-14r2`: the gears in the CSV, the splits said
    as such; a slot's name (C) in --sequence is refused with the gears the truck has, exit 2,
    and the CSV already there is left as it was."""
    from carfeel.cli import main
    from carfeel.simulation.result import Result

    out = tmp_path / "truck.csv"
    args = ["simulate", "hpattern", "--layout", "truck-14r2", "--speed-kmh", "0"]
    assert main([*args, "--sequence", "N,1,2,3,N", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "into 2          a split" in printed and "gears engaged    1 2 3;" in printed
    assert engaged(Result.from_csv(out)["event"]) == ["1", "2", "3"]
    before = out.read_bytes()
    assert main([*args, "--sequence", "N,C,N", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "no gear C" in err and "14, R1, R2" in err
    assert out.read_bytes() == before


def test_the_games_cues_read_the_trucks_gear_not_its_slot():
    """With a truck's game (ETS2's 14+2 in 9): the lever in slot 1 with the range high is 9,
    the game's own gear, so its wall does not refuse it whatever the revs; with the range low
    the same slot is 3, refused with the clutch out and the revs apart. R1 is the game's -1."""
    from carfeel.telemetry import cues
    from carfeel.telemetry.cues import LeverCues
    from carfeel.telemetry.state import VehicleState

    pattern = preset("truck-14r2").pattern()
    game = VehicleState(speed_m_s=15.0, engine_speed_rpm=1200.0, gear=9, forward_gears=14,
                        clutch_pedal=0.0)  # fmt: skip
    layout = pattern.layout
    slot = layout.gear("1")
    walls = {}
    for range_high in (True, False):
        lever = LeverCues(pattern, 1000.0)
        lever.update(game, 1.0, "N", 1e-3)
        knob = hpattern.initial_state(pattern)._replace(
            lever=hpattern.initial_state(pattern).lever._replace(position_m=0.0145),
            direction=slot.direction, plane=slot.plane, range_high=range_high,
        )  # fmt: skip
        walls[range_high] = lever(knob)[0]
    assert walls[True] == 0.0 and walls[False] != 0.0
    assert not cues.mismatch("R1", game._replace(gear=-1)) and cues.mismatch(
        "R2", game._replace(gear=-1)
    )
    assert not cues.mismatch("9", game) and cues.mismatch("3", game)


@pytest.mark.parametrize(("old", "new", "message"), [
    ("handle_position = 5", "handle_position = 40", r"handle_position = 40 is out of range"),
    ("gear = 3\n", "gear = 0\n", r"gear 0, ratio 9.15: a reverse slot"),
    ("gear = -1\nratio = -11.93", "gear = -1\nratio = 11.93", r"ratio 11.93"),
    ("handle_position = 6", "handle_position = 4", r"one handle position per slot"),
    ("range_high = true\nsplitter_high = false\ngear = 9",
     "range_high = false\nsplitter_high = false\ngear = 9", r"appears twice"),
    ("range_high = true\nsplitter_high = false\ngear = 9", "range_high = 1\nsplitter_high = "
     "false\ngear = 9", r"expected true or false"),
    ("handle_position = 5\n", "handle_position = 5\nbogus = 1\n", r"bogus: unknown parameter"),
])  # fmt: skip
def test_a_truck_table_with_garbage_is_refused_with_what_is_wrong(tmp_path, old, new, message):
    from carfeel.io.presets import resolve

    text = resolve("hpattern", "truck-14r2")[1]
    assert old in text
    path = tmp_path / "truck.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    with pytest.raises(PresetError, match=message):
        load_hpattern(str(path))


def test_a_splitter_flicked_during_the_block_retargets_the_ring_and_stays_sound():
    """The splitter button toggled every 50 ms from the start of the push (physics, 10 km/h,
    clutch in): the cone chases the target of whichever split is in effect, so the block lasts
    between the two gears' own (604 ms for 4, 1,186 ms for 3; measured 729 ms); nothing goes
    non-finite; once in gear each flick is a split (clutch in: the torque is off), and the
    gear is the last split's."""
    pattern = preset("truck-14r2").pattern(physics=True)
    state = _knob_at_ring(pattern, "1", 10.0)
    gears = []
    for n in range(3000):
        high = (n // 50) % 2 == 1 if n < 1500 else True
        inputs = HPatternInputs(78.5, 0.0, 1.0, 10 / 3.6, RPM_800, False, high)
        state, out = hpattern.step(state, inputs, pattern, 1e-3)
        assert math.isfinite(out.x_m) and math.isfinite(out.speed_difference_rad_s)
        if out.event.startswith("engage"):
            gears.append((n, out.gear))
    first, gear = gears[0]
    assert 604 < first < 1186 and gear in ("3", "4")
    assert all(a[1] != b[1] for a, b in itertools.pairwise(gears))  # each flick a split
    assert gears[-1][1] == out.gear == "4"


def test_with_a_game_the_split_waits_for_its_throttle_on_the_device():
    """The 1 kHz renderer driven by the game's state (ETS2-like: clutch out): in 5 with the
    knob's splitter pressed high, the split waits while the game's throttle is on and executes
    at the tick the driver lifts it."""
    from types import SimpleNamespace

    from carfeel.contracts import DeviceSample
    from carfeel.realtime.rendering import Gains, HPatternRenderer, Scaling
    from carfeel.telemetry.driving import TelemetryDriven
    from carfeel.telemetry.state import VehicleState

    pattern = preset("truck-14r2").pattern()
    (state, _), out, _ = _push_in(pattern, _knob_at_ring(pattern, "2", 0.0), False, False, 0.0)
    assert out.gear == "5"
    hand = SimpleNamespace(clutch_pedal=0.0, range_high=False, splitter_high=True)
    renderer = HPatternRenderer(pattern, "impedance", Scaling(1.0, 1.0), 1000.0,
                                Gains(1e3, 10.0, 1e3, 10.0, 1e3, 10.0), clutch=hand)  # fmt: skip
    renderer.state = state
    game = SimpleNamespace(state=VehicleState(speed_m_s=0.0, engine_speed_rpm=1000.0, gear=5,
                                              clutch_pedal=0.0, throttle=0.8), w=1.0)  # fmt: skip
    source = SimpleNamespace(update=lambda t_s: (game.state, game.w))
    driven = TelemetryDriven(renderer, source, "hpattern")  # type: ignore[arg-type]
    x = state.direction * state.lever.position_m
    for n in range(400):
        if n == 200:
            game.state = game.state._replace(throttle=0.0)
        driven.tick(DeviceSample(n * 1e-3, (x, state.y_m), None), 1e-3)
        assert renderer.state.gear == ("5" if n < 200 else "6"), n
