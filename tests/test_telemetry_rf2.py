"""rFactor 2 / Le Mans Ultimate shared memory (rF2SharedMemoryMapPlugin by The Iron Wolf).

No real dump of the plugin's buffers was found: the images here are BUILT FROM THE PLUGIN'S
HEADER (`rF2State.h`): the field lists below are the header's, in its order, and the offsets
are computed from them here with `#pragma pack(4)` (a member aligns to min(its size, 4)), not
taken from carfeel's constants.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import pytest

from carfeel.errors import InputError
from carfeel.telemetry import pages
from carfeel.telemetry.receiver import open_receiver
from carfeel.telemetry.state import plausible
from tests.pagefuzz import fuzz_pages

# (name, struct code of one element, element size, count)
VEC3 = ("24s", 8, 1)  # rF2Vec3: three doubles (aligned to 4 under pack(4))
WHEEL = [("d", 8, 16), ("d", 8, 3), ("d", 8, 1), ("s", 1, 16), ("B", 1, 3), ("d", 8, 4),
         ("d", 8, 3), ("s", 1, 24)]  # fmt: skip
TELEMETRY_VEHICLE = [
    ("mID", "i", 4, 1), ("mDeltaTime", "d", 8, 1), ("mElapsedTime", "d", 8, 1),
    ("mLapNumber", "i", 4, 1), ("mLapStartET", "d", 8, 1), ("mVehicleName", "s", 1, 64),
    ("mTrackName", "s", 1, 64), ("mPos", "d", 8, 3), ("mLocalVel", "d", 8, 3),
    ("mLocalAccel", "d", 8, 3), ("mOri", "d", 8, 9), ("mLocalRot", "d", 8, 3),
    ("mLocalRotAccel", "d", 8, 3), ("mGear", "i", 4, 1), ("mEngineRPM", "d", 8, 1),
    ("mEngineWaterTemp", "d", 8, 1), ("mEngineOilTemp", "d", 8, 1), ("mClutchRPM", "d", 8, 1),
    ("mUnfilteredThrottle", "d", 8, 1), ("mUnfilteredBrake", "d", 8, 1),
    ("mUnfilteredSteering", "d", 8, 1), ("mUnfilteredClutch", "d", 8, 1),
    ("mFiltered", "d", 8, 4), ("mSteeringShaftTorque", "d", 8, 1), ("mThirdSprings", "d", 8, 2),
    ("mAero", "d", 8, 6), ("mFuel", "d", 8, 1), ("mEngineMaxRPM", "d", 8, 1),
    ("mFlags4", "B", 1, 4), ("mDentSeverity", "B", 1, 8), ("mLastImpactET", "d", 8, 1),
    ("mLastImpactMagnitude", "d", 8, 1), ("mLastImpactPos", "d", 8, 3),
    ("mEngineTorque", "d", 8, 1), ("mCurrentSector", "i", 4, 1), ("mBytes4", "B", 1, 4),
    ("mFuelCapacity", "d", 8, 1), ("mFlapsEtc", "B", 1, 4), ("mTireNames", "s", 1, 36),
    ("mSpeedLimiterAvailable", "B", 1, 1), ("mAntiStallActivated", "B", 1, 1),
    ("mUnused", "B", 1, 2), ("mVisualSteeringWheelRange", "f", 4, 1),
    ("mRearBrakeBias", "d", 8, 1), ("mTurboBoostPressure", "d", 8, 1),
    ("mPhysicsToGraphicsOffset", "f", 4, 3), ("mPhysicalSteeringWheelRange", "f", 4, 1),
    ("mExpansion", "s", 1, 152), ("mWheels", "wheel", 0, 4),
]  # fmt: skip
SCORING_INFO = [
    ("mTrackName", "s", 1, 64), ("mSession", "i", 4, 1), ("mCurrentET", "d", 8, 1),
    ("mEndET", "d", 8, 1), ("mMaxLaps", "i", 4, 1), ("mLapDist", "d", 8, 1),
    ("pointer1", "s", 1, 8), ("mNumVehicles", "i", 4, 1), ("mGamePhase", "B", 1, 1),
    ("mYellowFlagState", "b", 1, 1), ("mSectorFlag", "b", 1, 3), ("mStartLight", "B", 1, 1),
    ("mNumRedLights", "B", 1, 1), ("mInRealtime", "B", 1, 1), ("mPlayerName", "s", 1, 32),
    ("mPlrFileName", "s", 1, 64), ("mWeather", "d", 8, 4), ("mWind", "d", 8, 3),
    ("mPathWetness", "d", 8, 2), ("mExpansion", "s", 1, 256), ("pointer2", "s", 1, 8),
]  # fmt: skip
SCORING_VEHICLE = [
    ("mID", "i", 4, 1), ("mDriverName", "s", 1, 32), ("mVehicleName", "s", 1, 64),
    ("mTotalLaps", "h", 2, 1), ("mSector", "b", 1, 1), ("mFinishStatus", "b", 1, 1),
    ("mTimes", "d", 8, 11), ("mNumPitstops", "h", 2, 1), ("mNumPenalties", "h", 2, 1),
    ("mIsPlayer", "B", 1, 1), ("mControl", "b", 1, 1), ("mInPits", "B", 1, 1),
    ("mPlace", "B", 1, 1), ("mVehicleClass", "s", 1, 32), ("mTimeBehindNext", "d", 8, 1),
    ("mLapsBehindNext", "i", 4, 1), ("mTimeBehindLeader", "d", 8, 1),
    ("mLapsBehindLeader", "i", 4, 1), ("mLapStartET", "d", 8, 1), ("mMotion", "d", 8, 24),
    ("mBytes4", "B", 1, 4), ("mQualification", "i", 4, 1), ("mLapTimes", "d", 8, 2),
    ("mPitGroup", "s", 1, 24), ("mFlags4", "B", 1, 4), ("mUpgradePack", "s", 1, 16),
    ("mExpansion", "s", 1, 60),
]  # fmt: skip


def _layout(fields: list[tuple[str, str, int, int]]) -> tuple[dict[str, int], int]:
    """Offsets under #pragma pack(4): each member aligned to min(its element size, 4)."""
    at, out = 0, {}
    for name, code, size, count in fields:
        if code == "wheel":
            _, wheel_bytes = _layout([("w", c, s, n) for c, s, n in WHEEL])
            size = wheel_bytes
            align = 4
        else:
            align = min(size, 4)
        at = (at + align - 1) // align * align
        out[name] = at
        at += size * count
    return out, (at + 3) // 4 * 4


TV, TV_BYTES = _layout(TELEMETRY_VEHICLE)
SI, SI_BYTES = _layout(SCORING_INFO)
SV, SV_BYTES = _layout(SCORING_VEHICLE)
TELEMETRY_BYTES = 16 + 128 * TV_BYTES  # version begin/end, mBytesUpdatedHint, mNumVehicles
SCORING_VEHICLES_AT = 12 + SI_BYTES  # version begin/end, mBytesUpdatedHint, mScoringInfo
SCORING_BYTES = SCORING_VEHICLES_AT + 128 * SV_BYTES
CODES = {n: c for n, c, _s, _n in TELEMETRY_VEHICLE + SCORING_INFO + SCORING_VEHICLE}


def _put(buf: bytearray, at: int, code: str, value: Any) -> None:
    if isinstance(value, bytes):
        buf[at : at + len(value)] = value
    elif isinstance(value, tuple):
        struct.pack_into(f"<{len(value)}{code}", buf, at, *value)
    else:
        struct.pack_into(f"<{code}", buf, at, value)


def build(
    version: tuple[int, int] = (7, 7),
    scoring_version: tuple[int, int] = (3, 3),
    phase: int = 5,
    realtime: int = 1,
    player_slot: int = 2,
    player_id: int = 17,
    **values: Any,
) -> bytes:
    """A frame (telemetry buffer then scoring buffer): three cars, the player third in
    scoring and second in telemetry (matched by mID, not by index)."""
    tele, score = bytearray(TELEMETRY_BYTES), bytearray(SCORING_BYTES)
    struct.pack_into("<IIii", tele, 0, *version, 0, 3)
    struct.pack_into("<III", score, 0, *scoring_version, 0)
    info = {"mNumVehicles": 3, "mGamePhase": phase, "mInRealtime": realtime}
    for name, value in info.items():
        _put(score, 12 + SI[name], CODES[name], value)
    ids = [3, player_id, 40]
    for slot in range(3):
        at = SCORING_VEHICLES_AT + slot * SV_BYTES
        vid = player_id if slot == player_slot else [3, 40][slot % 2]
        _put(score, at + SV["mID"], "i", vid)
        _put(score, at + SV["mIsPlayer"], "B", int(slot == player_slot))
        _put(score, at + SV["mVehicleName"], "s", b"Oreca 07 #22\x00" if vid == player_id
             else b"AI car\x00")  # fmt: skip
    car: dict[str, Any] = {"mLocalVel": (0.0, 0.0, -40.0), "mLocalAccel": (12.0, 0.0, -1.0),
           "mLocalRot": (0.0, -0.3, 0.0), "mGear": 3, "mEngineRPM": 6500.0,
           "mEngineMaxRPM": 9000.0, "mUnfilteredThrottle": 0.8, "mUnfilteredClutch": 0.0,
           "mUnfilteredSteering": -0.25, "mPhysicalSteeringWheelRange": 540.0,
           "mSteeringShaftTorque": -4.5}  # fmt: skip
    car.update(values)
    for slot, vid in enumerate(ids):
        at = 16 + slot * TV_BYTES
        _put(tele, at + TV["mID"], "i", vid)
        if vid != player_id:
            _put(tele, at + TV["mGear"], "i", 1)
            continue
        for name, value in car.items():
            _put(tele, at + TV[name], CODES[name], value)
    return bytes(tele) + bytes(score)


def test_the_header_offsets_are_the_readers() -> None:
    # The layout computed here from the header lands where carfeel reads: a mistake either
    # side shows here before it shows as a wrong value.
    assert (TV["mLocalVel"], TV["mGear"], TV["mEngineRPM"]) == (184, 352, 356)
    assert (TV["mSteeringShaftTorque"], TV["mEngineMaxRPM"]) == (452, 532)
    assert (TV["mPhysicalSteeringWheelRange"], TV["mWheels"]) == (692, 848)
    assert (TV_BYTES, SV_BYTES, SI_BYTES) == (1888, 584, 548)
    assert (TELEMETRY_BYTES, SCORING_BYTES) == (pages.RF2_TELEMETRY_BYTES, pages.RF2_SCORING_BYTES)
    assert (SI["mNumVehicles"], SI["mGamePhase"], SI["mInRealtime"]) == (104, 108, 115)
    assert (SV["mVehicleName"], SV["mIsPlayer"]) == (36, 196)


def test_a_left_turn_built_from_the_header_decodes(tmp_path: Path) -> None:
    image = tmp_path / "rf2.bin"
    image.write_bytes(build() + build(realtime=0) + build(phase=7) + build(mGear=-1))
    with open_receiver(f"rf2:file:{image}") as r:
        got: list[Any] = []
        for i in range(6):
            r.poll(got.append, now_s=i / 60.0)
        assert r.bad == 0 and r.car == "Oreca 07 #22"
    assert len(got) == 4
    s = got[0]
    assert (s.speed_m_s, s.engine_speed_rpm, s.engine_max_rpm, s.gear) == (40.0, 6500.0, 9000.0, 3)
    assert s.lateral_accel_m_s2 == 12.0  # +x is left in rF2's axes
    assert s.yaw_rate_rad_s == pytest.approx(0.3)  # about +y, turning left: negative in rF2
    # -0.25 (left) of a 540 degree wheel: 67.5 degrees left.
    assert s.steering_angle_rad == pytest.approx(math.radians(67.5))
    assert s.wheel_torque_Nm == -4.5 and s.throttle == pytest.approx(0.8)
    assert s.car == "Oreca 07 #22" and not s.replay and not s.paused
    assert got[1].replay and got[2].paused and got[3].gear == -1


def test_torn_buffers_are_counted_bad_not_used(tmp_path: Path) -> None:
    image = tmp_path / "rf2.bin"
    image.write_bytes(build(version=(8, 7)) + build(scoring_version=(4, 3)) + build())
    with open_receiver(f"rf2:file:{image}") as r:
        got: list[Any] = []
        for i in range(4):
            r.poll(got.append, now_s=i / 60.0)
        assert r.bad == 2
    assert len(got) == 1 and got[0].speed_m_s == 40.0


def test_no_player_is_no_state() -> None:
    # The player's mID is absent from telemetry (scoring updated first): no state, not garbage.
    frame = bytearray(build())
    struct.pack_into("<i", frame, 16 + TV_BYTES + TV["mID"], 99)
    assert pages.PagesReader(pages.RF2, (bytes(frame),), True).read(0.0) == [None]
    nobody = bytearray(build())
    at = TELEMETRY_BYTES + SCORING_VEHICLES_AT + 2 * SV_BYTES + SV["mIsPlayer"]
    nobody[at] = 0
    assert pages.PagesReader(pages.RF2, (bytes(nobody),), True).read(0.0) == [None]


def test_a_buffer_of_another_size_is_refused_with_both_sizes(tmp_path: Path) -> None:
    image = tmp_path / "rf2.bin"
    image.write_bytes(build()[:-4])
    with pytest.raises(InputError, match=f"{pages.RF2.frame_bytes}"):
        open_receiver(f"rf2:file:{image}")
    frame = build()
    live = (frame[:TELEMETRY_BYTES] + b"\0" * 64, frame[TELEMETRY_BYTES:])
    with pytest.raises(ValueError, match=f"{TELEMETRY_BYTES + 64} bytes.*{TELEMETRY_BYTES} bytes"):
        pages.PagesReader(pages.RF2, live, False)


def test_another_games_image_is_refused(tmp_path: Path) -> None:
    from tests.test_telemetry_ams2 import build as ams2_build

    image = tmp_path / "rf2.bin"
    image.write_bytes(ams2_build())
    with pytest.raises(InputError, match="bytes"):
        open_receiver(f"rf2:file:{image}")


@pytest.mark.parametrize("field", ["mEngineRPM", "mUnfilteredSteering", "mLocalVel"])
def test_nan_is_counted_bad(tmp_path: Path, field: str) -> None:
    value: Any = (math.nan, 0.0, 0.0) if field == "mLocalVel" else math.nan
    image = tmp_path / "rf2.bin"
    image.write_bytes(build(**{field: value}))
    with open_receiver(f"rf2:file:{image}") as r:
        got: list[Any] = []
        r.poll(got.append, now_s=0.0)
        assert r.bad == 1 and got == []


def test_the_live_map_tears_and_reads() -> None:
    frame = build()
    live = (frame[:TELEMETRY_BYTES], frame[TELEMETRY_BYTES:])
    reader = pages.PagesReader(pages.RF2, live, False)
    first = reader.read(0.0)
    assert len(first) == 1 and first[0] is not None and plausible(first[0])
    assert reader.read(0.01) == []  # the same version: nothing new
    torn = build(version=(9, 8))
    reader = pages.PagesReader(pages.RF2, (torn[:TELEMETRY_BYTES], torn[TELEMETRY_BYTES:]), False)
    states = reader.read(0.0)
    assert len(states) == 1 and states[0] is not None and not plausible(states[0])


def test_the_reader_survives_a_fuzzed_map() -> None:
    # Flips in the player's telemetry record and the scoring header's first bytes.
    kept, refused = fuzz_pages(pages.RF2, build(), 16 + 2 * TV_BYTES, 3, 200)
    assert kept > 20
    _ = refused
