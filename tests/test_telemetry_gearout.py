"""Gear output mappings (issue 29): the buttons a game binds to, from the gears a recorded
session went through (the real iRacing .ibt) and from ETS2's own slot table."""

from __future__ import annotations

import itertools
import json
from typing import Any

import pytest

from carfeel.errors import InputError
from carfeel.telemetry.gearout import (
    PULSE_S,
    GearFollower,
    RecordingGearOutput,
    gears_from_buttons,
    range_splitter_for,
)
from carfeel.telemetry.receiver import open_receiver
from tests.datafiles import data_file

FORWARD = 6  # the GT4's DriverCarGearNumForward
TICK_S = 0.001


def recorded_gears() -> list[tuple[float, int]]:
    """(time from the start, gear) of every record of the vendored .ibt."""
    states: list[Any] = []
    with open_receiver(
        f"iracing:file:{data_file('telemetry', 'iracing-mercedesamggt4-sebring.ibt')}"
    ) as r:
        for i in range(1500):
            r.poll(states.append, now_s=i / 60.0)
    return [(i / 60.0, s.gear) for i, s in enumerate(states)]


def changes(gears: list[int], start: int = 0) -> list[int]:
    out, last = [], start
    for g in gears:
        if g != last:
            out.append(g)
            last = g
    return out


def follow(follower: GearFollower, timeline: list[tuple[float, int]], tail_s: float) -> None:
    """The loop: 1 kHz ticks, the target the latest record's gear, then `tail_s` more."""
    k, target = 0, 0
    end = timeline[-1][0] + tail_s
    t = 0.0
    while t <= end:
        while k < len(timeline) and timeline[k][0] <= t + 1e-12:
            target = timeline[k][1]
            k += 1
        follower.update(target, t)
        t += TICK_S


def test_a_button_per_gear_replays_the_sessions_gears_exactly() -> None:
    timeline = recorded_gears()
    game = changes([g for _, g in timeline])
    assert game[:6] == [1, 0, 2, 0, 3, 0] and 4 in game and len(game) == 15  # the real file
    fake = RecordingGearOutput()
    follow(GearFollower(fake, "buttons", FORWARD), timeline, 0.1)
    assert gears_from_buttons(fake.calls, "buttons", FORWARD) == game
    assert next(c for c in fake.calls if c[0] == "press") == ("press", 0)  # 1st gear: button 0


def test_sequential_pulses_reach_every_gear_the_game_recorded() -> None:
    """Up/down pulses, each 50 ms held and 50 ms released: the gear a sequential binding reads
    passes through every recorded gear in order (a blip to neutral between two gears is a
    down and two ups) and ends on the last one."""
    timeline = recorded_gears()
    game = changes([g for _, g in timeline])
    fake = RecordingGearOutput()
    follower = GearFollower(fake, "sequential", FORWARD)
    follow(follower, timeline, 1.0)
    read = gears_from_buttons(fake.calls, "sequential", FORWARD)
    assert read[-1] == game[-1] == follower.gear
    it = iter(read)
    assert all(any(g == r for r in it) for g in game)  # game is a subsequence of what was read
    presses = [i for i, c in enumerate(fake.calls) if c[0] == "press"]
    assert all(fake.calls[i + 1][0] == "release_all" for i in presses)  # pulses, never held
    assert len(presses) == len(read)


def test_sequential_pulses_are_spaced_for_a_60_hz_game() -> None:
    fake = RecordingGearOutput()
    follower = GearFollower(fake, "sequential", FORWARD)
    times = []
    t = 0.0
    while t < 1.0:
        before = len(fake.calls)
        follower.update(3, t)
        if len(fake.calls) != before:
            times.append(t)
        t += TICK_S
    assert follower.gear == 3 and len(times) == 6  # three pulses: press and release each
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= PULSE_S - 1e-9  # three frames of a 60 Hz game each


def test_range_and_splitter_from_ets2s_slot_table() -> None:
    snapshot = json.loads(data_file("telemetry", "ets2-scs-sdk-plugin-snapshot-scania-s.json")
                          .read_text("utf-8"))  # fmt: skip
    slots = tuple((s["handlePosition"], s["selector"], s["gear"])
                  for s in snapshot["truck"]["transmission"]["slots"])  # fmt: skip
    positions = 8
    fake = RecordingGearOutput()
    follower = GearFollower(fake, "range-splitter", 14, slots, positions)
    sequence = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 0, -1, -2, 0]
    for i, gear in enumerate(sequence):
        follower.update(gear, i * 0.5)
    assert gears_from_buttons(fake.calls, "range-splitter", 14, slots, positions) == sequence
    # Gear 9 is position 5 with the range high (the table's selector 1): buttons 5 and 8 held.
    assert range_splitter_for(9, slots, positions) == [("hold", 1 << 5 | 1 << 8)]
    assert range_splitter_for(4, slots, positions) == [("hold", 1 << 5 | 1 << 9)]  # splitter
    follower.update(15, 10.0)  # no slot gives 15: nothing pressed, counted
    assert follower.unmapped == 1 and follower.gear == 0


def test_an_unknown_mapping_is_refused() -> None:
    with pytest.raises(InputError, match="buttons, sequential, range-splitter"):
        GearFollower(RecordingGearOutput(), "paddles", 6)


def test_the_lever_drives_sequential_pulses_in_a_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """--gear-mapping sequential on the H-pattern run: the lever through N, 1, 2, 3, N; the
    game bound to up/down reads each gear the lever engaged, in order (the neutral the lever
    crosses between two gears is not a step), and neutral once the lever rests there."""
    from carfeel.realtime.session import RealtimeRun, run_realtime
    from carfeel.telemetry import gearout

    fake = RecordingGearOutput()
    monkeypatch.setattr(gearout, "open_gear_output", lambda name, buttons: fake)
    run = RealtimeRun(model="hpattern", clock="simulated", telemetry="carfeel:127.0.0.1:0",
                      sequence=("N", "1", "2", "3", "N"), gear_output="uinput",
                      gear_timing="engaged", gear_mapping="sequential")  # fmt: skip
    result = run_realtime(run)
    assert result.summary.gears == ["1", "2", "3"]
    read = gears_from_buttons(fake.calls, "sequential", 5)
    assert changes(read) == [1, 2, 3, 2, 1, 0]  # up to third; down to neutral when it rests
    assert fake.calls[-1] == ("close", None)


def test_range_splitter_is_refused_for_the_lever() -> None:
    from carfeel.io.presets import load_hpattern
    from carfeel.telemetry.gearout import GearDriver

    layout = load_hpattern("5r").pattern().layout
    with pytest.raises(InputError, match="range-splitter"):
        GearDriver(RecordingGearOutput(), layout, mapping="range-splitter")
