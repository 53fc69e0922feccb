"""Assetto Corsa and ACC shared memory (physics, graphics, static pages).

No real dump of these pages was found: the images here are BUILT FROM THE SDK HEADER
(`SharedFileOut.h`, #pragma pack(4)): the field list below is the header's, in its order, and
the offsets are computed from it in this file, not taken from carfeel's struct strings.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import pytest

from carfeel import cli
from carfeel.errors import InputError
from carfeel.telemetry import pages, shm
from carfeel.telemetry.receiver import open_receiver, parse_source
from carfeel.telemetry.state import plausible
from tests.pagefuzz import fuzz_pages

# SPageFilePhysics, in the header's order: (name, count); every field 4 bytes.
PHYSICS_FIELDS = [
    ("packetId", 1), ("gas", 1), ("brake", 1), ("fuel", 1), ("gear", 1), ("rpms", 1),
    ("steerAngle", 1), ("speedKmh", 1), ("velocity", 3), ("accG", 3), ("wheelSlip", 4),
    ("wheelLoad", 4), ("wheelsPressure", 4), ("wheelAngularSpeed", 4), ("tyreWear", 4),
    ("tyreDirtyLevel", 4), ("tyreCoreTemperature", 4), ("camberRAD", 4),
    ("suspensionTravel", 4), ("drs", 1), ("tc", 1), ("heading", 1), ("pitch", 1), ("roll", 1),
    ("cgHeight", 1), ("carDamage", 5), ("numberOfTyresOut", 1), ("pitLimiterOn", 1),
    ("abs", 1), ("kersCharge", 1), ("kersInput", 1), ("autoShifterOn", 1), ("rideHeight", 2),
    ("turboBoost", 1), ("ballast", 1), ("airDensity", 1), ("airTemp", 1), ("roadTemp", 1),
    ("localAngularVel", 3), ("finalFF", 1), ("performanceMeter", 1), ("engineBrake", 1),
    ("ersRecoveryLevel", 1), ("ersPowerLevel", 1), ("ersHeatCharging", 1),
    ("ersIsCharging", 1), ("kersCurrentKJ", 1), ("drsAvailable", 1), ("drsEnabled", 1),
    ("brakeTemp", 4), ("clutch", 1),
]  # fmt: skip
INTS = {"packetId", "gear", "rpms"}


def _offsets() -> dict[str, int]:
    at, out = 0, {}
    for name, count in PHYSICS_FIELDS:
        out[name] = at
        at += 4 * count
    return out


OFFSET = _offsets()


def physics(size: int, **values: Any) -> bytes:
    page = bytearray(size)
    for name, value in values.items():
        for i, v in enumerate(value if isinstance(value, tuple) else (value,)):
            struct.pack_into("<i" if name in INTS else "<f", page, OFFSET[name] + 4 * i, v)
    return bytes(page)


def graphics(status: int, packet: int = 1) -> bytes:
    return struct.pack("<iii", packet, status, 2)  # packetId, status, session (race)


def wide(text: str, chars: int) -> bytes:
    return text.encode("utf-16-le").ljust(2 * chars, b"\0")


def static(version: str = "1.9", car: str = "porsche_991ii_gt3_r", max_rpm: int = 9250) -> bytes:
    # smVersion, acVersion (15 each), numberOfSessions, numCars, carModel, track, playerName,
    # playerSurname, playerNick (33 each), then sectorCount at 400 (4-aligned), maxTorque,
    # maxPower, maxRpm at 412.
    head = wide(version, 15) + wide("1.8.18", 15) + struct.pack("<ii", 1, 30)
    names = wide(car, 33) + wide("monza", 33) + wide("A", 33) + wide("B", 33) + wide("C", 33)
    page = head + names
    page += bytes(400 - len(page)) + struct.pack("<iffi", 3, 500.0, 400.0, max_rpm)
    assert len(page) == 416
    return page


def frame(layout: pages.PageLayout, status: int = pages.AC_LIVE, **values: Any) -> bytes:
    return (physics(layout.page_bytes[0], **values) + graphics(status)
            + static(car="ks_ferrari_488_gt3" if layout is pages.ASSETTO else
                     "porsche_991ii_gt3_r"))  # fmt: skip


DRIVING: dict[str, Any] = dict(packetId=7, gas=0.8, brake=0.0, gear=4, rpms=7200, steerAngle=-0.2,
               speedKmh=180.0, accG=(-1.5, 0.0, 0.3), localAngularVel=(0.0, -0.4, 0.0),
               clutch=0.0)  # fmt: skip
"""A left turn at 50 m/s: accG x -1.5 g (x right), yaw rate about y -0.4 rad/s (left-handed,
y up: negative is anticlockwise from above)."""


@pytest.mark.parametrize("layout", [pages.ACC, pages.ASSETTO], ids=lambda x: x.name)
def test_a_frame_built_from_the_header_decodes(tmp_path: Path, layout: pages.PageLayout) -> None:
    image = tmp_path / f"{layout.name}.bin"
    image.write_bytes(frame(layout, **DRIVING) + frame(layout, status=pages.AC_REPLAY, **DRIVING))
    with open_receiver(f"{layout.name}:file:{image}") as r:
        got: list[Any] = []
        for i in range(10):
            r.poll(got.append, now_s=i / 60.0)
        assert r.finished and r.bad == 0
    assert len(got) == 2
    s = got[0]
    assert s.speed_m_s == pytest.approx(50.0, rel=1e-6)  # 180 km/h, float32
    assert s.lateral_accel_m_s2 == pytest.approx(1.5 * 9.80665, rel=1e-6)  # left positive
    assert s.yaw_rate_rad_s == pytest.approx(0.4, rel=1e-6)
    assert (s.gear, s.engine_speed_rpm, s.engine_max_rpm) == (3, 7200.0, 9250.0)  # 4 is 3rd
    assert s.throttle == pytest.approx(0.8) and s.clutch_pedal == 0.0
    assert s.car in ("porsche_991ii_gt3_r", "ks_ferrari_488_gt3")
    assert not s.replay and got[1].replay


def test_the_game_in_its_menus_gives_no_state(tmp_path: Path) -> None:
    image = tmp_path / "acc.bin"
    image.write_bytes(frame(pages.ACC, status=pages.AC_OFF, **DRIVING))
    with open_receiver(f"acc:file:{image}") as r:
        assert r.poll(now_s=0.0) == 0 and r.ignored == 1


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (lambda: frame(pages.ACC)[:-1], "not a whole number of acc frames"),
        (lambda: frame(pages.ACC)[:812] + static(version="2.0"), "version '2.0'"),
        (lambda: frame(pages.ACC)[:812] + b"\xff" * 416, "not a string"),
    ],
)
def test_a_layout_it_does_not_know_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], data: Any, reason: str
) -> None:
    image = tmp_path / "bad.bin"
    image.write_bytes(data())
    with pytest.raises(InputError, match=reason):
        open_receiver(f"acc:file:{image}")
    assert cli.main(["telemetry", "listen", f"acc:file:{image}", "--duration", "0.1"]) == 2
    assert reason in capsys.readouterr().err


def test_assetto_is_udp_unless_live_or_a_file(tmp_path: Path) -> None:
    assert type(parse_source("assetto:127.0.0.1:9996")).__name__ == "Source"
    assert type(parse_source("assetto")).__name__ == "Source"
    assert isinstance(parse_source("assetto:live"), shm.MapSource)
    assert isinstance(parse_source(f"assetto:file:{tmp_path}/x.bin"), shm.MapSource)
    assert isinstance(parse_source("acc"), shm.MapSource)


def test_a_torn_page_is_read_again_then_counted_bad() -> None:
    class Moving(bytearray):
        """A physics page whose packetId moves on each time it is copied."""

        def __getitem__(self, key: Any) -> Any:
            got = super().__getitem__(key)
            if isinstance(key, slice) and (key.stop or 0) > 100:
                struct.pack_into("<i", self, 0, struct.unpack_from("<i", self, 0)[0] + 1)
            return got

    page = Moving(physics(pages.ACC_PHYSICS_BYTES, **DRIVING))
    reader = pages.PagesReader(pages.ACC, (page, graphics(2), static()), False)
    states = reader.read(0.0)
    assert len(states) == 1 and states[0] is not None and not plausible(states[0])
    steady = pages.PagesReader(
        pages.ACC, (physics(pages.ACC_PHYSICS_BYTES, **DRIVING), graphics(2), static()), False
    )
    assert len(steady.read(0.0)) == 1 and steady.read(0.001) == []  # same packetId: nothing new


@pytest.mark.parametrize("layout", [pages.ACC, pages.ASSETTO], ids=lambda x: x.name)
def test_the_reader_survives_fuzzed_pages(layout: pages.PageLayout) -> None:
    def check(s: Any) -> None:
        assert math.isfinite(s.speed_m_s) and -1 <= s.gear <= 10

    base = frame(layout, **DRIVING)
    kept, refused = fuzz_pages(layout, base, len(base), layout.name, 400, check)
    assert kept > 100 and refused > 10
