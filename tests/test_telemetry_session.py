"""A running `carfeel run --telemetry` session against hostile packets, in simulated time over
real loopback sockets: garbage interleaved with the real Forza capture for 30 s changes nothing
that is rendered and ends with exit 0, the bad counted; spoofed packets from an address the
source does not accept change nothing and are counted (issues 26 and 24)."""

from __future__ import annotations

import json
import math
import random
import socket
import struct
from pathlib import Path
from typing import Any, ClassVar

import pytest

from carfeel import cli
from carfeel.telemetry import replay, source
from carfeel.telemetry.formats import encode_carfeel
from carfeel.telemetry.source import VehicleSource
from carfeel.telemetry.state import VehicleState
from tests.datafiles import data_file

PACKET_S = 1.0 / 60.0
GARBAGE_EVERY_S = 0.004
"""Garbage at 250 Hz between the game's 60 Hz: four bad datagrams for each good one."""


def _garbage(rng: random.Random) -> bytes:
    """Something that is not a good Forza packet: random bytes of each Forza size and of
    others, NaN and infinite floats of the right size, a truncated real packet (not to 232 or
    311 bytes: those are a whole Sled and FM7 Dash packet), a real packet with IsRaceOn 7,
    another game's packet, an empty datagram."""
    real = FeedingSource.packets[rng.randrange(len(FeedingSource.packets))]
    choices = [
        lambda: rng.randbytes(rng.choice([232, 311, 324, 331])),
        lambda: rng.randbytes(rng.randint(1, 1400)),
        lambda: b"\x00\x00\xc0\x7f" * 82 + b"\x00\x00\x80\x7f"[:3],
        lambda: real[: rng.choice([n for n in range(1, 331) if n not in (232, 311, 324)])],
        lambda: struct.pack("<i", 7) + real[4:],
        lambda: encode_carfeel(VehicleState(speed_m_s=40.0)),
        lambda: b"",
    ]
    return rng.choice(choices)()


class FeedingSource(VehicleSource):
    """Sends, as the session's ticks go by, the Forza capture at 60 Hz of simulated time from
    127.0.0.1 and, if asked, garbage from the same address or the capture's later packets from
    127.0.0.2 (a spoofer: real-looking packets of another moment of the lap)."""

    packets: ClassVar[list[bytes]] = []
    garbage = False
    spoof = False
    sent: ClassVar[dict[str, int]] = {}

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.game = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.game.bind(("127.0.0.1", 0))
        self.other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.other.bind(("127.0.0.2" if self.spoof else "127.0.0.1", 0))
        self.rng = random.Random(26)
        self.next_packet_s = self.next_garbage_s = math.inf  # from the tick after the first
        self.index = 0
        FeedingSource.sent = {"good": 0, "garbage": 0, "spoofed": 0}

    def update(self, t_s: float) -> Any:
        to = self.receiver.address
        if self.next_packet_s == math.inf:  # the first tick flushes what queued before it
            self.next_packet_s = self.next_garbage_s = t_s + 0.001
        elif t_s >= self.next_packet_s:
            self.next_packet_s += PACKET_S
            self.game.sendto(self.packets[self.index % len(self.packets)], to)
            self.index += 1
            FeedingSource.sent["good"] += 1
            if self.spoof:
                late = self.packets[(self.index + 900) % len(self.packets)]
                self.other.sendto(late, to)
                FeedingSource.sent["spoofed"] += 1
        if self.garbage and self.next_garbage_s <= t_s:
            self.next_garbage_s += GARBAGE_EVERY_S
            self.other.sendto(_garbage(self.rng), to)
            FeedingSource.sent["garbage"] += 1
        return super().update(t_s)

    def close(self) -> None:
        self.game.close()
        self.other.close()
        super().close()


def _run(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    name: str,
    duration_s: float,
    **feed: bool,
) -> tuple[dict[str, Any], str]:
    FeedingSource.packets = replay.datagrams(
        data_file("telemetry", "forza-motorsport-2023-dash.raw"), 331
    )
    for key, value in feed.items():
        monkeypatch.setattr(FeedingSource, key, value)
    monkeypatch.setattr(source, "VehicleSource", FeedingSource)
    # Each run identifies its device afresh: with the profile the one before saved, a run
    # starts from a check instead, and its first ticks differ from the other's.
    monkeypatch.setenv("CARFEEL_CONFIG_DIR", str(tmp_path / f"{name}-config"))
    record = tmp_path / f"{name}.csv"
    code = cli.main(["run", "--model", "steering", "--device", "virtual:wheel", "--clock",
                     "simulated", "--telemetry", "forza:127.0.0.1:0", "--duration",
                     f"{duration_s:g}", "--record", str(record), "--json"])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "Traceback" not in err
    summary: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return summary, record.read_text()


def _counts(summary: dict[str, Any]) -> str:
    return str(next(n for n in summary["notes"] if "good packets" in n))


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_thirty_seconds_of_garbage_between_a_real_capture_changes_nothing_rendered(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The same 30 s session with and without four bad datagrams per good one: exit 0 both
    times, no fault, every bad one counted, and the recordings (every command, the game's
    values as the model took them) identical to the last digit."""
    clean, clean_rows = _run(tmp_path, monkeypatch, capsys, "clean", 30.0)
    sent_clean = dict(FeedingSource.sent)
    dirty, dirty_rows = _run(tmp_path, monkeypatch, capsys, "dirty", 30.0, garbage=True)
    sent = dict(FeedingSource.sent)
    assert not clean["faults"] and not dirty["faults"]
    assert clean["stopped"] == dirty["stopped"] == "duration"
    assert sent["good"] == sent_clean["good"] > 1700  # the capture's 1,793 at 60 Hz, 30 s
    assert sent["garbage"] > 4 * 1700
    # Every datagram counted once: the good as good, the garbage as bad or ignored.
    assert f"{sent['good']} good packets, {sent['garbage']} bad, 0 ignored" in _counts(dirty)
    assert f"{sent['good']} good packets, 0 bad, 0 ignored" in _counts(clean)
    assert dirty_rows == clean_rows  # the garbage changed nothing the session rendered
    # And what was rendered is the game's: speed and Ay of the capture drove the torque.
    header, *rows = clean_rows.splitlines()
    names = header.split(",")
    weight = names.index("telemetry_weight")
    speed = names.index("game_speed_m_s")
    fresh = [r.split(",") for r in rows if float(r.split(",")[weight]) == 1.0]
    assert len(fresh) > 25_000  # of the 30,000 ticks: fresh once the ramp is done
    assert max(float(r[speed]) for r in fresh) > 50.0  # the capture reaches 60 m/s
    assert any("bad packets" in n for n in dirty["notes"])


def test_spoofed_packets_from_another_address_change_nothing_and_are_counted(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two real senders: the game on 127.0.0.1 and a spoofer on 127.0.0.2 sending real Forza
    packets of another moment of the lap (good-looking, 15 s apart). The session, listening on
    127.0.0.1 and accepting the game's host by default, renders exactly what it renders without
    the spoofer, and the summary counts and names the spoofer's packets."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.2", 0))
    except OSError as exc:  # pragma: no cover - loopback is 127/8 on Linux
        pytest.skip(f"this system has no second loopback address 127.0.0.2 ({exc})")
    alone, alone_rows = _run(tmp_path, monkeypatch, capsys, "alone", 5.0)
    spoofed, spoofed_rows = _run(tmp_path, monkeypatch, capsys, "spoofed", 5.0, spoof=True)
    sent = FeedingSource.sent
    assert sent["spoofed"] == sent["good"] > 250
    assert spoofed_rows == alone_rows  # nothing the spoofer sent reached the model
    assert f"{sent['good']} good packets, 0 bad" in _counts(spoofed)
    note = next(n for n in spoofed["notes"] if "not accepted" in n)
    assert f"{sent['spoofed']} packets from addresses not accepted" in note
    assert "127.0.0.2" in note and "accepted: 127.0.0.1" in note
    assert not any("not accepted" in n for n in alone["notes"])


def test_the_spoofer_would_have_moved_the_wheel(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The check that the test above can fail: the same spoofer accepted (--accept-from of a
    network holding both) changes the rendering."""
    monkeypatch.setattr(FeedingSource, "spoof", True)
    FeedingSource.packets = replay.datagrams(
        data_file("telemetry", "forza-motorsport-2023-dash.raw"), 331
    )
    monkeypatch.setattr(source, "VehicleSource", FeedingSource)
    records = []
    for accept in ("127.0.0.1", "127.0.0.0/8"):
        record = tmp_path / f"{accept.replace('/', '_')}.csv"
        code = cli.main(["run", "--model", "steering", "--device", "virtual:wheel", "--clock",
                         "simulated", "--telemetry", "forza:127.0.0.1:0", "--accept-from",
                         accept, "--duration", "5", "--record", str(record), "--json"])  # fmt: skip
        assert code == 0
        records.append(record.read_text())
        capsys.readouterr()
    assert records[0] != records[1]


def test_a_truncated_or_nan_datagram_alone_counts_bad_not_stale_forever() -> None:
    """Bad packets do not refresh the weight: NaN and truncated packets alone leave the
    telemetry stale (the weight 0), and a good one brings it back."""
    from carfeel.telemetry.receiver import Receiver, Source

    packets = replay.datagrams(data_file("telemetry", "forza-motorsport-2023-dash.raw"), 331)
    vs = VehicleSource(Receiver(Source.parse("forza:127.0.0.1:0")))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        vs.update(0.0)  # the first tick's flush
        for k in range(1, 400):
            # Truncated to 1..200 bytes (232 would be a whole Sled packet), or NaN floats.
            s.sendto(packets[0][: k % 200 + 1] if k % 2 else b"\x00\x00\xc0\x7f" * 83,
                     vs.receiver.address)  # fmt: skip
            _, weight = vs.update(k * 0.001)
            assert weight == 0.0
        weights = []
        for k in range(1, 250):
            if k % 10 == 1:  # good packets at 100 Hz from 0.4 s
                s.sendto(packets[k], vs.receiver.address)
            weights.append(vs.update(0.4 + k * 0.001)[1])
    vs.close()
    assert vs.receiver.bad == 399 and vs.receiver.packets == 25
    assert weights[-1] == 1.0 and not math.isnan(vs.state.speed_m_s)
