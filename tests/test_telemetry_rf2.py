"""rFactor 2 / Le Mans Ultimate shared memory (rF2SharedMemoryMapPlugin by The Iron Wolf).

No real dump of the plugin's buffers was found: the images here are BUILT FROM THE PLUGIN'S
HEADER (`rF2State.h`): the field lists below are the header's, in its order, and the offsets
are computed from them here with `#pragma pack(4)` (a member aligns to min(its size, 4)), not
taken from carfeel's constants.
"""

from __future__ import annotations

import math
import mmap
import random
import struct
from pathlib import Path
from typing import Any

import pytest

from carfeel.errors import InputError
from carfeel.telemetry import pages
from carfeel.telemetry.receiver import open_receiver
from carfeel.telemetry.state import BAD, VehicleState, plausible
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


# --- The live read copies the player's parts only ----------------------------------------------


def whole_decode(frame: bytes, car: str = "") -> VehicleState | None:
    """The reference: the decode as it was before the live read copied only the player's parts
    (both whole buffers, the guards read from them, the player scanned in them), its offsets
    the header's as this file computes them; `car` is the reader's from the first frame."""
    telemetry, scoring = frame[:TELEMETRY_BYTES], frame[TELEMETRY_BYTES:]
    for page in (telemetry, scoring):
        begin, end = struct.unpack_from("<II", page)
        if begin != end:
            return BAD
    scored, phase, realtime = struct.unpack_from("<iB6xB", scoring, 116)
    cars = struct.unpack_from("<i", telemetry, 12)[0]
    if not (0 <= scored <= 128 and 0 <= cars <= 128 and 0 <= phase <= 8):
        return BAD
    for i in range(scored):
        at = SCORING_VEHICLES_AT + i * SV_BYTES
        if scoring[at + SV["mIsPlayer"]]:
            wanted = struct.unpack_from("<i", scoring, at)[0]
            raw = scoring[at + SV["mVehicleName"] : at + SV["mVehicleName"] + 64]
            text, nul, _ = raw.partition(b"\x00")
            ok = nul and text.isascii() and text.decode("ascii").isprintable()
            name = text.decode("ascii") if ok else ""
            break
    else:
        return None
    for i in range(cars):
        at = 16 + i * TV_BYTES
        if struct.unpack_from("<i", telemetry, at)[0] == wanted:
            break
    else:
        return None

    def get(field: str, count: int = 1) -> Any:
        values = struct.unpack_from(f"<{count}{CODES[field]}", telemetry, at + TV[field])
        return values if count > 1 else values[0]

    vel, acc, rot = get("mLocalVel", 3), get("mLocalAccel", 3), get("mLocalRot", 3)
    gear, rpm, torque = get("mGear"), get("mEngineRPM"), get("mSteeringShaftTorque")
    throttle, brake = get("mUnfilteredThrottle"), get("mUnfilteredBrake")
    steer, clutch = get("mUnfilteredSteering"), get("mUnfilteredClutch")
    top, lock_deg = get("mEngineMaxRPM"), get("mPhysicalSteeringWheelRange")
    if not (
        -1 <= gear <= 24
        and 0.0 <= rpm <= 30_000.0
        and all(-1.01 <= x <= 1.01 for x in (throttle, brake, steer, clutch))
        and all(-150.0 <= x <= 150.0 for x in vel)
        and all(-500.0 <= x <= 500.0 for x in acc)
        and all(-50.0 <= x <= 50.0 for x in rot)
        and -1e4 <= torque <= 1e4
        and (lock_deg == 0.0 or 0.0 < lock_deg <= 3600.0)
    ):
        return BAD
    return VehicleState(
        speed_m_s=math.sqrt(vel[0] ** 2 + vel[1] ** 2 + vel[2] ** 2),
        lateral_accel_m_s2=acc[0],
        yaw_rate_rad_s=-rot[1],
        engine_speed_rpm=rpm,
        gear=-1 if gear < 0 else gear,
        clutch_pedal=clutch,
        throttle=throttle,
        brake=brake,
        steering_angle_rad=-steer * math.radians(lock_deg) / 2.0 if lock_deg > 0.0 else math.nan,
        engine_max_rpm=top if 0.0 < top <= 30_000.0 else math.nan,
        car=name or car,
        wheel_torque_Nm=torque,
        replay=not realtime,
        paused=phase == 7,
    )


def live(frame: bytes, kind: type[bytearray] = bytearray) -> pages.PagesReader:
    """A live reader on the frame's two buffers as maps (`kind`: a bytearray or a fake)."""
    images = (kind(frame[:TELEMETRY_BYTES]), kind(frame[TELEMETRY_BYTES:]))
    return pages.PagesReader(pages.RF2, images, False)


def crowd(scoring_slot: int, telemetry_slot: int, cars: int = 20, **values: Any) -> bytes:
    """`cars` cars in both buffers (their mNumVehicles), the player (mID 17, `build`'s) in
    scoring's `scoring_slot` and telemetry's `telemetry_slot` (possibly past `cars`); every other
    slot of the 128 holds another car (mID 100 + its scoring slot, in telemetry in the reverse
    order) driving plausibly at 20 m/s in 2nd at 3000 rpm + its slot: a record taken by index,
    or past the used slots, shows."""
    frame = build(**values)
    tele, score = bytearray(frame[:TELEMETRY_BYTES]), bytearray(frame[TELEMETRY_BYTES:])
    player_t = tele[16 + TV_BYTES : 16 + 2 * TV_BYTES]  # build's: [3, 17, 40] in telemetry
    player_s = score[SCORING_VEHICLES_AT + 2 * SV_BYTES : SCORING_VEHICLES_AT + 3 * SV_BYTES]
    tele[16:], score[SCORING_VEHICLES_AT:] = bytes(128 * TV_BYTES), bytes(128 * SV_BYTES)
    struct.pack_into("<i", tele, 12, cars)
    struct.pack_into("<i", score, 12 + SI["mNumVehicles"], cars)
    others = [100 + slot for slot in range(128) if slot != scoring_slot]
    for slot, vid in zip([s for s in range(128) if s != scoring_slot], others, strict=True):
        at = SCORING_VEHICLES_AT + slot * SV_BYTES
        _put(score, at + SV["mID"], "i", vid)
        _put(score, at + SV["mVehicleName"], "s", b"AI car\x00")
    tele_slots = [s for s in range(128) if s != telemetry_slot]
    for slot, vid in zip(tele_slots, reversed(others), strict=True):
        at = 16 + slot * TV_BYTES
        decoy = {"mID": vid, "mLocalVel": (0.0, 0.0, -20.0), "mGear": 2,
                 "mEngineRPM": 3000.0 + slot, "mPhysicalSteeringWheelRange": 900.0}  # fmt: skip
        for name, value in decoy.items():
            _put(tele, at + TV[name], CODES[name], value)
    at = SCORING_VEHICLES_AT + scoring_slot * SV_BYTES
    score[at : at + SV_BYTES] = player_s
    tele[16 + telemetry_slot * TV_BYTES : 16 + (telemetry_slot + 1) * TV_BYTES] = player_t
    return bytes(tele) + bytes(score)


@pytest.mark.parametrize(
    ("cars", "scoring_slot", "telemetry_slot"),
    [(20, 13, 5), (20, 0, 19), (6, 5, 5), (128, 127, 0), (128, 0, 127), (128, 64, 1)],
)
def test_the_players_record_is_taken_by_its_mid_in_any_slot(
    cars: int, scoring_slot: int, telemetry_slot: int
) -> None:
    frame = crowd(scoring_slot, telemetry_slot, cars)
    for reader in (live(frame), pages.PagesReader(pages.RF2, (frame,), True)):
        (state,) = reader.read(0.0)
        assert state is not None and plausible(state)
        assert (state.speed_m_s, state.engine_speed_rpm, state.gear) == (40.0, 6500.0, 3)
        assert state.car == reader.car == "Oreca 07 #22"
        assert repr(state) == repr(whole_decode(frame))


def test_a_player_past_the_used_slots_is_no_state() -> None:
    # mIsPlayer in a scoring slot past its mNumVehicles, or the player's mID in a telemetry slot
    # past its own: stale slots the plugin did not write this frame, not the player.
    for frame in (crowd(20, 3), crowd(3, 20), crowd(127, 3, cars=127), crowd(3, 127, cars=127)):
        assert live(frame).read(0.0) == [None]
        assert pages.PagesReader(pages.RF2, (frame,), True).read(0.0) == [None]
        assert whole_decode(frame) is None


class Written(bytearray):
    """A live buffer the plugin writes while the reader copies from it: each copy of a car's
    record (a slice of 100 bytes or more; one a read) is followed by one of the plugin's
    writes while `writes` lasts: mVersionUpdateBegin + 1, then mVersionUpdateEnd + 1 unless
    `unfinished` (still writing). `copied` counts the bytes the reader copied (slices)."""

    writes = 0
    unfinished = False
    copied = 0

    def __getitem__(self, key: Any) -> Any:
        out = super().__getitem__(key)
        if isinstance(key, slice):
            self.copied += len(out)
            if self.writes and len(out) >= 100:
                self.writes -= 1
                begin, end = struct.unpack_from("<II", self)
                struct.pack_into("<II", self, 0, begin + 1, end + (not self.unfinished))
        return out


@pytest.mark.parametrize("buffer", [0, 1], ids=["telemetry", "scoring"])
@pytest.mark.parametrize("unfinished", [False, True], ids=["written", "writing"])
def test_a_buffer_written_while_it_is_copied_is_torn(buffer: int, unfinished: bool) -> None:
    # Its guard is whole before the copy and after it (begin == end), but not the same: the
    # parts copied may be of two frames. Torn, copied again once, then counted bad.
    frame = crowd(13, 5)
    reader = live(frame, Written)
    image = reader.images[buffer]
    assert isinstance(image, Written)
    image.writes, image.unfinished = 2, unfinished  # a write during each of the two tries
    assert reader.read(0.0) == [BAD]
    reader = live(frame, Written)
    image = reader.images[buffer]
    assert isinstance(image, Written)
    image.writes = 1  # during the first try only: the second reads the frame whole
    (state,) = reader.read(0.0)
    assert state is not None and plausible(state) and state.engine_speed_rpm == 6500.0


def test_the_live_read_copies_the_players_parts_only() -> None:
    # Of 317 KB of buffers, a read copies the player's telemetry record (1,888 bytes), its
    # scoring record to mVehicleName (100) and the 20 used slots' mIsPlayer flags (the counts,
    # the game phase and the guards are unpacked in place).
    reader = live(crowd(13, 5), Written)
    telemetry, scoring = reader.images
    assert isinstance(telemetry, Written) and isinstance(scoring, Written)
    telemetry.copied = scoring.copied = 0
    (state,) = reader.read(0.0)
    assert state is not None and plausible(state)
    assert telemetry.copied == TV_BYTES
    assert scoring.copied == 100 + 20


def _fuzz(rng: random.Random, base: bytes) -> bytes:
    """A few of the fields the read depends on changed: counts (within the slots and not), the
    phase, guards, mIsPlayer and mIDs of any slot, bytes of any car's fields and name."""
    data, s = bytearray(base), TELEMETRY_BYTES
    read = [TV[name] + k for name in ("mLocalVel", "mLocalAccel", "mLocalRot", "mGear",
            "mEngineRPM", "mUnfilteredThrottle", "mUnfilteredSteering", "mSteeringShaftTorque",
            "mEngineMaxRPM", "mPhysicalSteeringWheelRange") for k in range(8)]  # fmt: skip
    for _ in range(rng.choice((1, 2, 4, 8))):
        op = rng.randrange(7)
        slot = rng.choice((rng.randrange(128), rng.randrange(24)))
        if op == 0:
            at = rng.choice((12, s + 12 + SI["mNumVehicles"]))
            count = rng.choice((rng.randrange(-2, 131), rng.randrange(24), rng.getrandbits(32)))
            struct.pack_into("<I", data, at, count % 2**32)
        elif op == 1:
            data[s + 12 + rng.choice((SI["mGamePhase"], SI["mInRealtime"]))] = rng.randrange(12)
        elif op == 2:
            struct.pack_into("<I", data, rng.choice((0, 4, s, s + 4)), rng.randrange(2, 10))
        elif op == 3:
            at = s + SCORING_VEHICLES_AT + slot * SV_BYTES + SV["mIsPlayer"]
            data[at] = rng.choice((0, 1, 1, 255))
        elif op == 4:
            vid = rng.choice((17, 17, 100 + slot, rng.getrandbits(32) - 2**31))
            at = rng.choice((16 + slot * TV_BYTES, s + SCORING_VEHICLES_AT + slot * SV_BYTES))
            struct.pack_into("<i", data, at, vid)
        elif op == 5:
            data[16 + slot * TV_BYTES + rng.choice(read)] = rng.randrange(256)
        else:
            at = s + SCORING_VEHICLES_AT + slot * SV_BYTES + SV["mVehicleName"]
            data[at + rng.randrange(64)] = rng.choice((0, 7, 65, 200))
    return bytes(data)


def test_the_live_read_equals_the_whole_buffer_decode_on_fuzzed_images() -> None:
    rng = random.Random("rf2 live")
    outcomes = {"state": 0, "none": 0, "bad": 0, "refused": 0}
    for trial in range(300):
        frame = _fuzz(rng, build() if trial % 3 == 0 else crowd(13, 5))
        try:
            file = pages.PagesReader(pages.RF2, (frame,), True)
        except ValueError:
            outcomes["refused"] += 1
            with pytest.raises(ValueError, match="vehicles"):
                live(frame)
            continue
        reader = live(frame)
        assert reader.car == file.car
        want = whole_decode(frame, file.car)
        assert repr(reader.read(0.0)) == repr(file.read(0.0)) == repr([want])
        key = "none" if want is None else "state" if plausible(want) else "bad"
        outcomes[key] += 1
    assert min(outcomes.values()) >= 10, outcomes


def test_the_live_read_of_mapped_buffers(tmp_path: Path) -> None:
    # The buffers as the game's maps are opened (mmap, read only): slices of a map are bytes.
    frame = crowd(13, 5)
    maps = []
    for name, data in (("t", frame[:TELEMETRY_BYTES]), ("s", frame[TELEMETRY_BYTES:])):
        (tmp_path / name).write_bytes(data)
        with (tmp_path / name).open("rb") as handle:
            maps.append(mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ))
    try:
        (state,) = pages.PagesReader(pages.RF2, maps, False).read(0.0)
        assert repr(state) == repr(whole_decode(frame, "Oreca 07 #22"))
        assert state is not None and state.engine_speed_rpm == 6500.0
    finally:
        for image in maps:
            image.close()
