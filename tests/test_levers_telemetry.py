"""A game driving the sequential lever and the PRND selector (`telemetry.lever_driving`), in
simulated time over a real loopback socket: the game's gear locks the lever, the game's speed
locks R, the gear output tells the game what the lever registered; the game's state gone stale
leaves the lever its own rules."""

from __future__ import annotations

import socket
from pathlib import Path
from typing import Any

import pytest

from carfeel.realtime.session import RealtimeRun, run_realtime
from carfeel.telemetry import gearout, source
from carfeel.telemetry.formats import encode_carfeel
from carfeel.telemetry.gearout import RecordingGearOutput, gears_from_buttons
from carfeel.telemetry.lever_driving import LeverDriven, PositionFollower, gear_number
from carfeel.telemetry.source import VehicleSource
from carfeel.telemetry.state import VehicleState

PACKET_S = 1.0 / 60.0


def feeding(state: VehicleState, until_s: float = 1e9) -> type[VehicleSource]:
    """A source that sends `state` over a real socket at 60 Hz of simulated time (until
    `until_s`), then updates as the session's source does."""

    class Feeding(VehicleSource):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.next_s = 0.0

        def update(self, t_s: float) -> Any:
            if t_s >= self.next_s and t_s < until_s:
                self.next_s += PACKET_S
                self.sock.sendto(encode_carfeel(state), self.receiver.address)
            return super().update(t_s)

        def close(self) -> None:
            self.sock.close()
            super().close()

    return Feeding


def run_lever(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, model: str, sequence: tuple[str, ...],
    game: VehicleState | None, **kwargs: Any,
) -> Any:  # fmt: skip
    telemetry = None
    if game is not None:
        monkeypatch.setattr(source, "VehicleSource", feeding(game))
        telemetry = "carfeel:127.0.0.1:0"
    run = RealtimeRun(model=model, device="virtual:shifter", clock="simulated",
                      sequence=sequence, telemetry=telemetry, record=tmp_path / "r.csv",
                      **kwargs)  # fmt: skip
    return run_realtime(run)


@pytest.mark.slow  # sessions in simulated time, over 2 s
def test_the_game_in_reverse_locks_the_sequential_lever_s_downshift(monkeypatch, tmp_path):
    """From N a lift-down shifts to R; with the game already in R (its gear -1) the same pull
    meets the lock's wall and shifts nothing: the lever cannot tell the game a gear below R."""
    alone = run_lever(monkeypatch, tmp_path, "sequential", ("lift-down",), None)
    assert alone.summary.gears == ["R"]
    driven = run_lever(monkeypatch, tmp_path, "sequential", ("lift-down",),
                       VehicleState(speed_m_s=0.0, gear=-1))  # fmt: skip
    assert driven.summary.faults == []
    assert driven.summary.gears == []


@pytest.mark.slow  # sessions in simulated time, over 2 s
def test_the_game_s_speed_locks_reverse_on_the_selector(monkeypatch, tmp_path):
    """R, N, D, N, R: standing still every move registers; at 20 m/s (the game's) the last
    move, N into R, meets the lock (R only below 2 m/s) and the selector stays in N."""
    script = ("R", "N", "D", "N", "R")
    still = run_lever(monkeypatch, tmp_path, "prnd", script, VehicleState(speed_m_s=0.0))
    assert still.summary.gears == ["R", "N", "D", "N", "R"]
    moving = run_lever(monkeypatch, tmp_path, "prnd", script, VehicleState(speed_m_s=20.0))
    assert moving.summary.faults == []
    assert moving.summary.gears == ["R", "N", "D", "N"]


@pytest.mark.slow  # sessions in simulated time, over 2 s
@pytest.mark.parametrize("mapping", ["buttons", "sequential"])
def test_the_gear_output_tells_the_game_the_sequential_lever_s_gears(
    monkeypatch, tmp_path, mapping
):
    """What a game bound to the mapping reads from the buttons is the lever's gears, in order
    (a sequential binding sees every step: up, up, down, then N and R on the lift)."""
    fake = RecordingGearOutput()
    monkeypatch.setattr(gearout, "open_gear_output", lambda name, buttons: fake)
    script = ("up", "up", "down", "lift-down", "lift-down")
    result = run_lever(monkeypatch, tmp_path, "sequential", script, VehicleState(speed_m_s=5.0),
                       gear_output="uinput", gear_mapping=mapping)  # fmt: skip
    assert result.summary.gears == ["1", "2", "1", "N", "R"]
    assert fake.calls[-2:] == [("release_all", None), ("close", None)]  # released at the end
    told = gears_from_buttons(fake.calls[:-2], mapping, 6)
    distinct = [g for i, g in enumerate(told) if i == 0 or g != told[i - 1]]
    assert distinct == [gear_number(g) for g in result.summary.gears]


@pytest.mark.slow  # sessions in simulated time, over 2 s
def test_the_gear_output_holds_the_selector_s_position(monkeypatch, tmp_path):
    """A button per position, P included: the buttons pressed are the positions registered."""
    fake = RecordingGearOutput()
    monkeypatch.setattr(gearout, "open_gear_output", lambda name, buttons: fake)
    result = run_lever(monkeypatch, tmp_path, "prnd", ("R", "N", "D"),
                       VehicleState(speed_m_s=0.0), gear_output="vjoy")  # fmt: skip
    positions = ("P", "R", "N", "D")
    pressed = [positions[b] for name, b in fake.calls if name == "press" and b is not None]
    assert pressed == ["P", *result.summary.gears]  # P held from the start
    assert result.summary.gears == ["R", "N", "D"]
    assert fake.calls[-2:] == [("release_all", None), ("close", None)]


def test_a_stale_game_unlocks_the_lever():
    """The game's gear locks only while its state is fresh: stale, the lever's own rules."""

    class Inner:
        axes = 2
        columns = ("x",)
        substeps = 1
        effect = 0.0
        gear = "N"

        def __init__(self) -> None:
            from carfeel.realtime.levers import Controls

            self.controls = Controls()
            self.gears: list[str] = []

        def tick(self, sample: Any, dt_s: float) -> tuple[tuple[float, ...], tuple[object, ...]]:
            return (0.0, 0.0), (0.0,)

    class Source:
        def __init__(self, weight: float) -> None:
            self.weight = weight

        def update(self, t_s: float) -> tuple[VehicleState, float]:
            return VehicleState(speed_m_s=30.0, gear=-1), self.weight

    sample = type("S", (), {"time_s": 0.0, "positions": (0.0, 0.0)})()
    for weight, locked in ((1.0, True), (0.0, False)):
        inner = Inner()
        LeverDriven(inner, Source(weight), "sequential").tick(sample, 1e-3)  # type: ignore[arg-type]
        assert inner.controls.locked_down is locked
        inner = Inner()
        LeverDriven(inner, Source(weight), "prnd").tick(sample, 1e-3)  # type: ignore[arg-type]
        speed = inner.controls.speed_m_s
        assert (speed == 30.0) if locked else (speed != speed)  # stale: unknown (NaN): R locked


def test_a_position_follower_presses_each_position_once():
    fake = RecordingGearOutput()
    follower = PositionFollower(fake, ("P", "R", "N", "D"))
    for position in ("P", "P", "R", "", "R", "N"):
        follower.update(position)
    assert fake.calls == [("press", 0), ("press", 1), ("press", 2)]
    follower.release()
    assert fake.calls[-1] == ("release_all", None)
