"""Automobilista 2 / Project CARS 2 shared memory ($pcars2$).

No real dump of the map was found: the image here is BUILT FROM THE SDK HEADER
(`SharedMemory.h`, version 8, the prefix later versions keep): the field list below is the
header's, in its order, and the offsets are computed from it here with C's natural alignment,
not taken from carfeel's constants. The axes are those the Project CARS UDP capture fixed.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest

from carfeel.errors import InputError
from carfeel.telemetry import pages
from carfeel.telemetry.receiver import open_receiver
from carfeel.telemetry.state import plausible
from tests.pagefuzz import fuzz_pages

# (name, C type, count), SharedMemory's fields in the header's order up to mSequenceNumber;
# "participant" is ParticipantInfo (bool, char[64], float[3], float, 3 x uint, int: 100 bytes).
C = {"u32": ("I", 4), "i32": ("i", 4), "f32": ("f", 4), "bool": ("?", 1), "char": ("s", 1),
     "participant": ("100s", 4)}  # fmt: skip
FIELDS = [
    ("mVersion", "u32", 1), ("mBuildVersionNumber", "u32", 1), ("mGameState", "u32", 1),
    ("mSessionState", "u32", 1), ("mRaceState", "u32", 1), ("mViewedParticipantIndex", "i32", 1),
    ("mNumParticipants", "i32", 1), ("mParticipantInfo", "participant", 64),
    ("mUnfilteredThrottle", "f32", 1), ("mUnfilteredBrake", "f32", 1),
    ("mUnfilteredSteering", "f32", 1), ("mUnfilteredClutch", "f32", 1),
    ("mCarName", "char", 64), ("mCarClassName", "char", 64), ("mLapsInEvent", "u32", 1),
    ("mTrackLocation", "char", 64), ("mTrackVariation", "char", 64),
    ("mTrackLength", "f32", 1), ("mNumSectors", "i32", 1), ("mLapInvalidated", "bool", 1),
    ("timings", "f32", 21), ("mHighestFlagColour", "u32", 1), ("mHighestFlagReason", "u32", 1),
    ("mPitMode", "u32", 1), ("mPitSchedule", "u32", 1), ("mCarFlags", "u32", 1),
    ("engine", "f32", 7), ("mSpeed", "f32", 1), ("mRpm", "f32", 1), ("mMaxRPM", "f32", 1),
    ("mBrake", "f32", 1), ("mThrottle", "f32", 1), ("mClutch", "f32", 1),
    ("mSteering", "f32", 1), ("mGear", "i32", 1), ("mNumGears", "i32", 1),
    ("mOdometerKM", "f32", 1), ("mAntiLockActive", "bool", 1),
    ("mLastOpponentCollisionIndex", "i32", 1), ("mLastOpponentCollisionMagnitude", "f32", 1),
    ("mBoostActive", "bool", 1), ("mBoostAmount", "f32", 1), ("mOrientation", "f32", 3),
    ("mLocalVelocity", "f32", 3), ("mWorldVelocity", "f32", 3), ("mAngularVelocity", "f32", 3),
    ("mLocalAcceleration", "f32", 3), ("mWorldAcceleration", "f32", 3),
    ("mExtentsCentre", "f32", 3), ("tyres", "f32", 18 * 4), ("mCrashState", "u32", 1),
    ("weather", "f32", 9), ("mSequenceNumber", "u32", 1),
]  # fmt: skip


def _offsets() -> dict[str, int]:
    at, out = 0, {}
    for name, kind, count in FIELDS:
        size = 100 if kind == "participant" else C[kind][1]
        align = C[kind][1]
        at = (at + align - 1) // align * align
        out[name] = at
        at += size * count
    return out


OFFSET = _offsets()


def build(version: int = 13, game: int = 2, sequence: int = 42, **values: Any) -> bytes:
    m = bytearray(pages.AMS2_MAP_BYTES)
    base = {"mVersion": version, "mGameState": game, "mViewedParticipantIndex": 0,
            "mNumParticipants": 20, "mSpeed": 50.0, "mRpm": 7000.0, "mMaxRPM": 8500.0,
            "mThrottle": 0.9, "mGear": 4, "mNumGears": 6, "mSequenceNumber": sequence,
            "mLocalVelocity": (0.0, 0.0, -50.0), "mAngularVelocity": (0.0, 0.3, 0.0),
            "mLocalAcceleration": (15.0, 0.0, 0.0), "mCarName": b"Formula Vintage"}  # fmt: skip
    base.update(values)
    kinds = {name: kind for name, kind, _ in FIELDS}
    for name, value in base.items():
        code = C[kinds[name]][0]
        if isinstance(value, bytes):
            struct.pack_into("64s", m, OFFSET[name], value)
        elif isinstance(value, tuple):
            struct.pack_into(f"<{len(value)}{code}", m, OFFSET[name], *value)
        else:
            struct.pack_into(f"<{code}", m, OFFSET[name], value)
    return bytes(m)


def test_the_header_offsets_are_the_readers() -> None:
    # The layout computed here from the header lands where carfeel reads: a mistake either
    # side shows here before it shows as a wrong value.
    assert OFFSET["mCarName"] == 6444 and OFFSET["mSpeed"] == 6848
    assert OFFSET["mOrientation"] == 6908 and OFFSET["mSequenceNumber"] == 7320


def test_a_left_turn_built_from_the_header_decodes(tmp_path: Path) -> None:
    image = tmp_path / "ams2.bin"
    image.write_bytes(build() + build(game=6, sequence=44))
    with open_receiver(f"ams2:file:{image}") as r:
        got: list[Any] = []
        for i in range(5):
            r.poll(got.append, now_s=i / 60.0)
        assert r.bad == 0 and r.car == "Formula Vintage"
    assert len(got) == 2
    s = got[0]
    assert (s.speed_m_s, s.engine_speed_rpm, s.engine_max_rpm, s.gear) == (50.0, 7000.0, 8500.0, 4)
    assert s.lateral_accel_m_s2 == 15.0 and s.yaw_rate_rad_s == pytest.approx(0.3)  # left
    assert s.throttle == pytest.approx(0.9) and s.forward_gears == 6
    assert not s.replay and got[1].replay


@pytest.mark.parametrize("version", [5, 7, 15])
def test_an_unknown_version_is_refused(tmp_path: Path, version: int) -> None:
    image = tmp_path / "ams2.bin"
    image.write_bytes(build(version=version))
    with pytest.raises(InputError, match=f"version {version}"):
        open_receiver(f"ams2:file:{image}")


def test_the_front_end_is_no_state_and_a_write_in_progress_is_torn() -> None:
    front = pages.PagesReader(pages.AMS2, (build(game=1),), True)
    assert front.read(0.0) == [None]
    writing = pages.PagesReader(pages.AMS2, (bytearray(build(sequence=43)),), False)
    states = writing.read(0.0)  # odd: the game is writing, both looks
    assert len(states) == 1 and states[0] is not None and not plausible(states[0])
    done = pages.PagesReader(pages.AMS2, (bytearray(build(sequence=44)),), False)
    first = done.read(0.0)
    assert len(first) == 1 and first[0] is not None and plausible(first[0])
    assert done.read(0.001) == []  # the same sequence: nothing new


def test_the_reader_survives_a_fuzzed_map() -> None:
    kept, refused = fuzz_pages(pages.AMS2, build(), pages.AMS2_READ_BYTES, 2, 300)
    assert kept > 50 and refused > 10
