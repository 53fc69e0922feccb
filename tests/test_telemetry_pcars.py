"""Project CARS UDP (the format Project CARS 2 and Automobilista 2 also send) on a real capture.

The expected values come from numpy structured arrays with the offsets of the published
sTelemetryData layout written here (independent of carfeel's struct strings). The fuzz tests of
every UDP format (tests/test_telemetry_fuzz.py) cover this one's three sizes.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from carfeel import cli
from carfeel.telemetry import replay
from carfeel.telemetry.formats import FORMATS, decode_datagram
from carfeel.telemetry.receiver import Receiver, Source
from carfeel.telemetry.state import REVERSE, VehicleState, plausible
from tests.datafiles import data_file

CAPTURE = "projectcars-udp.raw"
TELEMETRY = np.dtype(
    {
        "names": ["kind", "session", "clutch", "speed", "rpm", "max_rpm", "gears",
                  "local_velocity", "angular_velocity", "local_accel", "tyre_rps"],
        "formats": ["u1", "u1", "u1", "<f4", "<u2", "<u2", "u1", ("<f4", 3), ("<f4", 3),
                    ("<f4", 3), ("<f4", 4)],
        "offsets": [2, 3, 114, 120, 124, 126, 128, 148, 172, 184, 244],
        "itemsize": 1367,
    }
)  # fmt: skip


def _packets() -> list[bytes]:
    return replay.pcars_datagrams(data_file("telemetry", CAPTURE))


def _decode_all() -> tuple[list[bytes], list[VehicleState | None]]:
    packets = _packets()
    last = VehicleState()
    states: list[VehicleState | None] = []
    for p in packets:
        s = decode_datagram(FORMATS["pcars"], p, last)
        states.append(s)
        if s is not None and plausible(s):
            last = s
    return packets, states


def test_the_capture_splits_by_type_and_every_datagram_decodes() -> None:
    packets, states = _decode_all()
    kinds = [p[2] & 3 for p in packets]
    assert (kinds.count(0), kinds.count(1), kinds.count(2)) == (1094, 3, 3)
    assert all(s is None or plausible(s) for s in states)  # no datagram of it counted bad
    good = [s for s in states if s is not None]
    assert len(good) >= 900


def test_telemetry_matches_an_independent_decoding() -> None:
    packets, states = _decode_all()
    rows = [(p, s) for p, s in zip(packets, states, strict=True) if p[2] & 3 == 0]
    rows = [(p, s) for p, s in rows if s is not None]
    a = np.frombuffer(b"".join(p for p, _ in rows), TELEMETRY)
    got = [s for _, s in rows if s is not None]
    assert np.array_equal([s.speed_m_s for s in got], a["speed"].astype(float))
    assert np.array_equal([s.engine_speed_rpm for s in got], a["rpm"].astype(float))
    nibble = a["gears"] & 0x0F
    assert [s.gear for s in got] == [REVERSE if g == 15 else int(g) for g in nibble]
    assert np.array_equal([s.clutch_pedal for s in got], a["clutch"] / 255.0)
    assert np.array_equal([s.lateral_accel_m_s2 for s in got], a["local_accel"][:, 0])
    assert np.array_equal([s.yaw_rate_rad_s for s in got], a["angular_velocity"][:, 1])
    # The local velocity's z is minus the speed (z backward): the capture's own check. sSpeed
    # is the wheels' (a few % off the body's under wheelspin and braking): the median ratio.
    moving = a["speed"] > 5
    ratio = -a["local_velocity"][moving, 2] / a["speed"][moving]
    assert 0.98 < float(np.median(ratio)) < 1.02
    assert max(s.speed_m_s for s in got) > 45 and {1, 2, 3, 4} <= {s.gear for s in got}
    assert {s.engine_max_rpm for s in got if s.speed_m_s > 1} == {6800.0}


def test_the_signs_are_iso_by_the_wheels_of_the_capture() -> None:
    """In a left turn the right wheels run faster (the outer track): the wheel-speed difference,
    right minus left (the SDK's order FL, FR, RL, RR), rises with Ay and the yaw rate, both
    positive to the left. Slip on this quattro blurs the correlation: 0.3 is well clear of 0."""
    packets, states = _decode_all()
    pairs = [(p, s) for p, s in zip(packets, states, strict=True)
             if p[2] & 3 == 0 and s is not None and s.speed_m_s > 10]  # fmt: skip
    rps = np.abs(np.frombuffer(b"".join(p for p, _ in pairs), TELEMETRY)["tyre_rps"])
    right_minus_left = rps[:, 1] + rps[:, 3] - rps[:, 0] - rps[:, 2]
    ay = [s.lateral_accel_m_s2 for _, s in pairs]
    yaw = [s.yaw_rate_rad_s for _, s in pairs]
    assert np.corrcoef(right_minus_left, ay)[0, 1] > 0.3
    assert np.corrcoef(right_minus_left, yaw)[0, 1] > 0.3
    speed = np.array([s.speed_m_s for _, s in pairs])
    assert np.corrcoef(speed * np.array(yaw), ay)[0, 1] > 0.85  # Ay = v r in the turns


def test_the_car_comes_from_the_strings_packet_and_the_front_end_is_ignored() -> None:
    packets, states = _decode_all()
    first = next(i for i, p in enumerate(packets) if p[2] & 3 == 1)
    assert all(s is None or s.car == "" for s in states[:first])
    assert all(s is None or s.car == "Audi A1 quattro" for s in states[first:1000])
    # The last 100 datagrams: the game back in its front end, no car driven: ignored.
    assert all(s is None for s, p in zip(states[-100:], packets[-100:], strict=True)
               if p[2] & 3 == 0)  # fmt: skip


def test_a_datagram_of_the_wrong_size_for_its_type_is_bad() -> None:
    telemetry = next(p for p in _packets() if p[2] & 3 == 0)
    cut = decode_datagram(FORMATS["pcars"], telemetry[:1347], VehicleState())
    assert cut is not None and not plausible(cut)


def test_received_over_udp_as_the_game_sends(tmp_path: Path) -> None:
    packets = _packets()
    with Receiver(Source.parse("pcars:127.0.0.1:0"), 4 << 20) as receiver:
        sender = threading.Thread(
            target=replay.send, args=(packets, receiver.address, 2000.0), daemon=True
        )
        sender.start()
        got: list[VehicleState] = []
        deadline = time.monotonic() + 20.0
        while (sender.is_alive() or receiver.poll(got.append)) and time.monotonic() < deadline:
            receiver.poll(got.append)
            time.sleep(0.001)
        receiver.poll(got.append)
    assert receiver.bad == 0 and receiver.errors == 0
    # Every datagram arrived (loopback, a 4 MiB buffer): good, or ignored (the 3 pages of more
    # drivers' names and the 100 of the front end).
    assert len(got) == len(packets) - 103 and receiver.ignored == 103
    assert got[-1].car == "Audi A1 quattro"


def test_replay_splits_the_capture(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:
        sink.bind(("127.0.0.1", 0))
        port = sink.getsockname()[1]
        code = cli.main(["telemetry", "replay", str(data_file("telemetry", CAPTURE)),
                         "--format", "pcars", "--to", f"127.0.0.1:{port}",
                         "--rate-hz", "10000"])  # fmt: skip
    assert code == 0
    assert "sent 1100 of 1100 1028-1347-1367-byte datagrams" in capsys.readouterr().out
