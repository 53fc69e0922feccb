"""Shared-memory games whose state is a few fixed pages (Assetto Corsa and ACC: physics,
graphics, static), one decoder per layout, from the games' published headers.

A live game has one named map per page; a file image is the pages concatenated in their order
(one frame), or several such frames one after the other, replayed at `FRAME_HZ`. Each layout's
pages are read at the sizes of the fields carfeel uses (a prefix of the game's page: the live
map is mapped at that size), and checked once at open (the static page's version string) and
each frame (the graphics page's status, the physics page's own ranges). A torn frame (the
physics page's packetId moved while it was copied) is copied again once, then counted bad.
rFactor 2's buffers are large (128 cars each): its layout's `select` copies only the player's
parts of them, between two reads of each buffer's own guard.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from carfeel.telemetry.formats import KMH, VELOCITY_BOUND_M_S, G, _within
from carfeel.telemetry.state import BAD, NAN, REVERSE, VehicleState

FRAME_HZ = 60.0
"""A file image's frames are replayed at 60 Hz (the games' graphics rate; a dump tool writes
one frame per graphics update)."""

# --- Assetto Corsa / ACC (SharedFileOut.h, #pragma pack(4)) ----------------------------------
AC_PHYSICS = struct.Struct("<i4x4x4xiiff12x3f240x3f56xf")
"""packetId 0, gear 16, rpms 20, steerAngle 24, speedKmh 28, accG 44..55, localAngularVel
296..307, clutch 364 (the other fields skipped)."""
AC_INPUTS = struct.Struct("<4xff")  # gas 4, brake 8
ACC_PHYSICS_BYTES = 800
"""ACC's SPageFilePhysics (to absVibrations)."""
AC_PHYSICS_BYTES = 580
"""Assetto Corsa's SPageFilePhysics to localVelocity (AC 1.7's header; later versions add
fields after it, not read)."""
GRAPHICS_BYTES = 12
"""SPageFileGraphic's packetId, status (0 off, 1 replay, 2 live, 3 pause), session."""
STATIC_BYTES = 416
"""SPageFileStatic to maxRpm: smVersion and acVersion (wchar_t[15] each), numberOfSessions,
numCars, carModel, track, playerName, playerSurname, playerNick (wchar_t[33] each),
sectorCount, maxTorque, maxPower, maxRpm."""
_STATUS = struct.Struct("<4xi")
_MAX_RPM = struct.Struct("<i")  # at 412
AC_OFF, AC_REPLAY, AC_LIVE, AC_PAUSE = 0, 1, 2, 3


def _wide(raw: bytes) -> str | None:
    """A wchar_t (UTF-16LE) C string, or None where it is not one (no NUL, unprintable)."""
    text = raw.decode("utf-16-le", "replace")
    head, nul, _ = text.partition("\x00")
    if not nul or "\ufffd" in head or not head.isprintable():
        return None
    return head


@dataclass(frozen=True, slots=True)
class PageLayout:
    name: str
    page_bytes: tuple[int, ...]
    """Each page's size as read (physics, graphics, static)."""
    check: Callable[[Sequence[bytes]], str | None]
    """Why the static pages are not this layout's (None: they are), checked at open."""
    decode: Callable[[Sequence[Any], str, float], VehicleState | None]
    """(pages, car, max rpm) -> a state, None (no car driven) or BAD; the pages as `select`
    gives them where the layout has one."""
    identify: Callable[[Sequence[bytes]], tuple[str, float]] = lambda pages: ("", NAN)
    """(car, max rpm) from the pages at open (the static page where the game has one)."""
    sequence_offset: int = 0
    """Where in the first page its update counter is (torn-read check)."""
    file_page_bytes: tuple[int, ...] = ()
    """Each page's size in a file image where it is more than what is read (a whole map)."""
    odd_is_writing: bool = False
    """The update counter is odd while the game writes (AMS2's mSequenceNumber): torn."""
    exact_bytes: bool = False
    """A live map of another size than `page_bytes` is another layout: refused (rF2's)."""
    select: Callable[[Sequence[Any]], Sequence[Any] | None] | None = None
    """Where `decode` reads a small part of large pages (rF2's player, one of 128 cars): (the
    pages: the live maps, or a file frame's) -> those parts only (copied, or unpacked in
    place), read between two reads of the pages' own guards; None: torn. A live read copies
    no more than it; without one, a live read copies `page_bytes` of each map."""

    @property
    def stride(self) -> tuple[int, ...]:
        return self.file_page_bytes or self.page_bytes

    @property
    def frame_bytes(self) -> int:
        return sum(self.stride)


def _check_ac(version_prefix: str) -> Callable[[Sequence[bytes]], str | None]:
    def check(pages: Sequence[bytes]) -> str | None:
        static = pages[2]
        version = _wide(static[0:30])
        if version is None:
            return "its static page's smVersion is not a string (not this game's pages)"
        if not version.startswith(version_prefix):
            return (
                f"its shared-memory version {version!r} is not {version_prefix}x, the layout "
                "carfeel reads"
            )
        return None

    return check


def _decode_ac(pages: Sequence[Any], car: str, max_rpm: float) -> VehicleState | None:
    physics, graphics = pages[0], pages[1]
    status = _STATUS.unpack_from(graphics)[0]
    if not AC_OFF <= status <= AC_PAUSE:
        return BAD
    if status == AC_OFF:
        return None  # the game is in its menus
    _id, raw_gear, rpm, steer, kmh, ax, ay, az, wx, wy, wz, clutch = AC_PHYSICS.unpack_from(physics)
    gas, brake = AC_INPUTS.unpack_from(physics)
    # gear 0 R, 1 N, 2 first; rpm whole; steer the normalized input -1..1; the accelerations in g.
    if not (
        0 <= raw_gear <= 11
        and 0 <= rpm <= 30_000
        and -1.01 <= steer <= 1.01
        and 0.0 <= kmh <= VELOCITY_BOUND_M_S * 3.6
        and _within(50.0, ax, ay, az)
        and _within(50.0, wx, wy, wz)
    ):
        return BAD
    # Car axes x right, y up, z forward (DirectX, left-handed): Ay left = -accG x * g; the yaw
    # rate about y is positive turning right, so left positive is its negative. As Assetto
    # Corsa's UDP accG_horizontal, whose sign the real capture fixed (tests/test_telemetry.py);
    # no real dump of the pages was found to check the yaw rate's.
    gear = raw_gear - 1 if raw_gear >= 1 else REVERSE
    return VehicleState(
        speed_m_s=kmh * KMH,
        lateral_accel_m_s2=-ax * G,
        yaw_rate_rad_s=-wy,
        engine_speed_rpm=float(rpm),
        gear=gear,
        clutch_pedal=clutch,
        throttle=gas,
        brake=brake,
        engine_max_rpm=max_rpm,
        car=car,
        replay=status == AC_REPLAY,
        paused=status == AC_PAUSE,
    )


def ac_static(pages: Sequence[bytes]) -> tuple[str, float]:
    """The car (carModel, wchar_t[33] at 68) and its max rpm (at 412)."""
    static = pages[2]
    car = _wide(static[68:134]) or ""
    rpm = _MAX_RPM.unpack_from(static, 412)[0]
    return car, float(rpm) if 0 < rpm <= 30_000 else NAN


ACC = PageLayout("acc", (ACC_PHYSICS_BYTES, GRAPHICS_BYTES, STATIC_BYTES), _check_ac("1."),
                 _decode_ac, ac_static)  # fmt: skip
ASSETTO = PageLayout("assetto", (AC_PHYSICS_BYTES, GRAPHICS_BYTES, STATIC_BYTES),
                     _check_ac("1."), _decode_ac, ac_static)  # fmt: skip
AC_MAP_NAMES = ("Local\\acpmf_physics", "Local\\acpmf_graphics", "Local\\acpmf_static")


# --- Euro Truck Simulator 2 / American Truck Simulator: scs-sdk-plugin revision 12 -----------
SCS_MAP_NAME = "Local\\SCSTelemetry"
SCS_MAP_BYTES = 32 * 1024
SCS_READ_BYTES = 3212
"""scsTelemetryMap_t through config_s.shifterType (zone 9), of the plugin's 32 KiB map."""
SCS_REVISION = 12
_SCS_HEAD = struct.Struct("<?3x?3xQ16x8xIIIIII4xIIIII16xI")
"""sdkActive 0, paused 4, time 8 (a stamp that moves each update), then at 40 the plugin
revision, the game's version major and minor, the game (1 ETS2, 2 ATS), its telemetry
version major and minor; at 68 gears, gears_reverse, retarderStepCount, truckWheelCount,
selectorCount; at 104 shifterSlot."""
_SCS_TABLE = struct.Struct("<32I32I")  # at 184: hshifterPosition[32], hshifterBitmask[32]
_SCS_RESULTING = struct.Struct("<ii32i")  # at 504: gear, gearDashboard, hshifterResulting[32]
_F32 = struct.Struct("<f")
_SCS_DRIVE = struct.Struct("<ff16xffff")
"""At 948: speed (m/s, negative reversing), engineRpm, gameSteer 972, gameThrottle,
gameBrake, gameClutch (what the game applies, 0..1)."""
_SCS_TOGGLES = struct.Struct("<??")  # at 1606: shifterToggle[2] (range, splitter)
_SCS_MOTION = struct.Struct("<3f3f3f")
"""At 1868: linear velocity, angular velocity, linear acceleration (truck frame)."""
SHIFTER_TYPES = {"hshifter": "h", "manual": "sequential", "automatic": "", "arcade": ""}


def _c_text(raw: bytes) -> str | None:
    text, nul, _ = raw.partition(b"\x00")
    if not nul or not text.isascii() or not text.decode("ascii").isprintable():
        return None
    return text.decode("ascii")


def _check_scs(pages: Sequence[bytes]) -> str | None:
    head = _SCS_HEAD.unpack_from(pages[0])
    revision, game = head[3], head[6]
    if revision != SCS_REVISION:
        return (
            f"scs-sdk-plugin revision {revision}: carfeel reads revision {SCS_REVISION} (its "
            "layout moved between revisions); update the plugin"
        )
    if game not in (1, 2):
        return f"game id {game}: not Euro Truck Simulator 2 (1) or American Truck Simulator (2)"
    return None


def scs_identify(pages: Sequence[bytes]) -> tuple[str, float]:
    """The truck (truckId, e.g. vehicle.scania.s_2016) and the engine's max rpm."""
    page = pages[0]
    truck = _c_text(page[2428:2492]) or ""
    rpm = _F32.unpack_from(page, 740)[0]
    return truck, float(rpm) if 0.0 < rpm <= 30_000.0 else NAN


_slot_cache: dict[bytes, tuple[tuple[int, int, int], ...]] = {}


def scs_slots(page: bytes) -> tuple[tuple[int, int, int], ...]:
    """The H-shifter's slot table (handle position, selector bitmask, gear), as the game gives
    it (32 slots; cached by its bytes: it changes with the truck only)."""
    raw = page[184:440] + page[512:640]
    cached = _slot_cache.get(raw)
    if cached is None:
        table = _SCS_TABLE.unpack_from(page, 184)
        gears = _SCS_RESULTING.unpack_from(page, 504)[2:]
        cached = tuple((table[i], table[32 + i], gears[i]) for i in range(32))
        if len(_slot_cache) > 16:
            _slot_cache.clear()
        _slot_cache[raw] = cached
    return cached


def _decode_scs(pages: Sequence[Any], car: str, max_rpm: float) -> VehicleState | None:
    page = pages[0]
    active, paused, _stamp, *_rest = _SCS_HEAD.unpack_from(page)
    if not active:
        return None  # the game is not running the SDK
    gears, reverse, _steps, _wheels, selectors, slot = _SCS_HEAD.unpack_from(page)[9:15]
    gear = _SCS_RESULTING.unpack_from(page, 504)[0]
    speed, rpm, steer, throttle, brake, clutch = _SCS_DRIVE.unpack_from(page, 948)
    range_high, splitter_high = _SCS_TOGGLES.unpack_from(page, 1606)
    m = _SCS_MOTION.unpack_from(page, 1868)
    kind = _c_text(page[3196:3212])
    # The game's own ranges: gear counts and the slot within the table; the gear within them;
    # the controls 0..1 (steer -1..1); the shifter type one of the SDK's four.
    if (
        not (0 <= gears <= 24 and 0 <= reverse <= 8 and 0 <= selectors <= 4 and slot <= 32)
        or not -reverse <= gear <= gears
        or kind not in SHIFTER_TYPES
        or not _within(1.01, steer, throttle, brake, clutch)
        or not _within(VELOCITY_BOUND_M_S, speed, *m[0:3])
        or not _within(50.0, *m[3:6])
        or not _within(500.0, *m[6:9])
        or not 0.0 <= rpm <= 30_000.0
    ):
        return BAD
    # Truck axes: x right, y up, z backward (the SDK's, right-handed): Ay left is minus the x
    # acceleration; the angular velocity about y (up) is positive anticlockwise: left already.
    gearbox = SHIFTER_TYPES[kind]
    if gearbox == "h" and selectors:
        gearbox = "truck"
    return VehicleState(
        speed_m_s=abs(speed),
        lateral_accel_m_s2=-m[6],
        yaw_rate_rad_s=m[4],
        engine_speed_rpm=rpm,
        gear=REVERSE if gear < 0 else gear,
        clutch_pedal=clutch,
        throttle=throttle,
        brake=brake,
        engine_max_rpm=max_rpm,
        car=car,
        forward_gears=gears,
        gearbox=gearbox,
        truck_slot=slot,
        range_high=range_high,
        splitter_high=splitter_high,
        slots=scs_slots(page) if selectors or gearbox == "h" else (),
        paused=paused,
    )


SCS = PageLayout("scs", (SCS_READ_BYTES,), _check_scs, _decode_scs, scs_identify,
                 sequence_offset=8, file_page_bytes=(SCS_MAP_BYTES,))  # fmt: skip


# --- Automobilista 2 / Project CARS 2 shared memory (SharedMemory.h, natural alignment) ------
AMS2_MAP_NAME = "$pcars2$"
AMS2_MAP_BYTES = 8192
AMS2_READ_BYTES = 7324
"""SharedMemory through mSequenceNumber (at 7320): every field carfeel reads."""
AMS2_VERSIONS = range(8, 15)
"""mVersion 8 (Project CARS 2's header) to 14: later headers append after mSequenceNumber."""
_AMS2_HEAD = struct.Struct("<IIIIIii")
"""mVersion, mBuildVersionNumber, mGameState, mSessionState, mRaceState,
mViewedParticipantIndex, mNumParticipants."""
_AMS2_DRIVE = struct.Struct("<7f2i")
"""At 6848: mSpeed, mRpm, mMaxRPM, mBrake, mThrottle, mClutch, mSteering, mGear, mNumGears."""
_AMS2_MOTION = struct.Struct("<3f3f3f3f3f")
"""At 6908: mOrientation, mLocalVelocity, mWorldVelocity, mAngularVelocity,
mLocalAcceleration."""
AMS2_PLAYING, AMS2_PAUSED, AMS2_MENU, AMS2_RESTARTING, AMS2_REPLAY, AMS2_FE_REPLAY = range(2, 8)


def _check_ams2(pages: Sequence[bytes]) -> str | None:
    version = _AMS2_HEAD.unpack_from(pages[0])[0]
    if version not in AMS2_VERSIONS:
        return (
            f"shared memory version {version}: carfeel reads versions "
            f"{AMS2_VERSIONS[0]}-{AMS2_VERSIONS[-1]} (Project CARS 2 and Automobilista 2); "
            "Project CARS 1's shared memory is another layout"
        )
    return None


def ams2_identify(pages: Sequence[bytes]) -> tuple[str, float]:
    car = _c_text(pages[0][6444:6508]) or ""
    rpm = _F32.unpack_from(pages[0], 6856)[0]
    return car, float(rpm) if 0.0 < rpm <= 30_000.0 else NAN


def _decode_ams2(pages: Sequence[Any], car: str, max_rpm: float) -> VehicleState | None:
    page = pages[0]
    _v, _b, game, _session, _race, viewed, count = _AMS2_HEAD.unpack_from(page)
    if not (game <= AMS2_FE_REPLAY and -1 <= viewed < 64 and -1 <= count <= 64):
        return BAD
    if game < AMS2_PLAYING:
        return None  # exited or in the front end
    speed, rpm, top, brake, throttle, clutch, steer, gear, gears = _AMS2_DRIVE.unpack_from(
        page, 6848
    )
    m = _AMS2_MOTION.unpack_from(page, 6908)
    if not (
        -1 <= gear <= 24
        and -1 <= gears <= 24
        and _within(1.01, brake, throttle, clutch, steer)
        and 0.0 <= speed <= VELOCITY_BOUND_M_S
        and 0.0 <= rpm <= 30_000.0
        and _within(VELOCITY_BOUND_M_S, *m[3:9])
        and _within(50.0, *m[9:12])
        and _within(500.0, *m[12:15])
    ):
        return BAD
    # Axes as Project CARS' UDP (the same engine; tests/test_telemetry_pcars.py fixed the
    # signs on a real capture): x left, y up, z back, so Ay and the yaw rate are ISO already.
    current = _c_text(page[6444:6508])
    return VehicleState(
        speed_m_s=speed,
        lateral_accel_m_s2=m[12],
        yaw_rate_rad_s=m[10],
        engine_speed_rpm=rpm,
        gear=gear,
        clutch_pedal=clutch,
        throttle=throttle,
        brake=brake,
        engine_max_rpm=float(top) if 0.0 < top <= 30_000.0 else max_rpm,
        car=current if current else car,
        forward_gears=max(0, gears),
        replay=game in (AMS2_REPLAY, AMS2_FE_REPLAY),
        paused=game in (AMS2_PAUSED, AMS2_MENU, AMS2_RESTARTING),
    )


AMS2 = PageLayout("ams2", (AMS2_READ_BYTES,), _check_ams2, _decode_ams2, ams2_identify,
                  sequence_offset=7320, file_page_bytes=(AMS2_MAP_BYTES,),
                  odd_is_writing=True)  # fmt: skip


# --- rFactor 2 / Le Mans Ultimate: rF2SharedMemoryMapPlugin (rF2State.h, #pragma pack(4)) -----
RF2_MAP_NAMES = ("$rFactor2SMMP_Telemetry$", "$rFactor2SMMP_Scoring$")
RF2_VEHICLES = 128
"""MAX_MAPPED_VEHICLES: each buffer's vehicle array has this many slots."""
RF2_TELEMETRY_VEHICLE_BYTES = 1888
"""rF2VehicleTelemetry: 848 bytes to mWheels, then 4 rF2Wheel of 260."""
RF2_SCORING_VEHICLE_BYTES = 584
RF2_TELEMETRY_BYTES = 16 + RF2_VEHICLES * RF2_TELEMETRY_VEHICLE_BYTES
"""rF2Telemetry: mVersionUpdateBegin, mVersionUpdateEnd, mBytesUpdatedHint, mNumVehicles, then
the vehicles (241,680 bytes)."""
RF2_SCORING_VEHICLES_AT = 12 + 548
"""rF2Scoring: the version pair, mBytesUpdatedHint, rF2ScoringInfo (548 bytes), the vehicles."""
RF2_SCORING_BYTES = RF2_SCORING_VEHICLES_AT + RF2_VEHICLES * RF2_SCORING_VEHICLE_BYTES
_RF2_GUARD = struct.Struct("<II")  # mVersionUpdateBegin, mVersionUpdateEnd
RF2_PLAYER_BYTES = 100
"""Of the player's scoring record, what is read: mID, mDriverName, mVehicleName."""
_I32 = struct.Struct("<i")
_RF2_PHASE = struct.Struct("<iB6xB")
"""At 116 of rF2Scoring: mNumVehicles, mGamePhase (127: mInRealtime)."""
_RF2_DRIVE = struct.Struct("<3d3d72x3d24xid24x4d32xd")
"""From 184 of rF2VehicleTelemetry: mLocalVel, mLocalAccel, (mOri) mLocalRot 304, mGear 352,
mEngineRPM 356, mUnfilteredThrottle 388, mUnfilteredBrake, mUnfilteredSteering,
mUnfilteredClutch, mSteeringShaftTorque 452."""
_RF2_MAX_RPM = struct.Struct("<d")  # at 532: mEngineMaxRPM
_RF2_RANGE = struct.Struct("<f")  # at 692: mPhysicalSteeringWheelRange (degrees, lock to lock)
RF2_PHASES = range(0, 9)
"""mGamePhase 0 (before the session) .. 8 (session over)."""
RF2_STOPPED = 7


def _check_rf2(pages: Sequence[bytes]) -> str | None:
    telemetry, scoring = pages
    for name, page in (("telemetry", telemetry), ("scoring", scoring)):
        count = _I32.unpack_from(page, 12 if name == "telemetry" else 116)[0]
        if not 0 <= count <= RF2_VEHICLES:
            return (
                f"its {name} buffer says {count} vehicles, outside 0-{RF2_VEHICLES}: not "
                "rF2SharedMemoryMapPlugin's buffers (or another version of its layout)"
            )
    return None


def _rf2_player_slot(scoring: Any, count: int) -> int | None:
    """The slot of scoring's player: the first of its `count` used slots whose mIsPlayer is set,
    read in place (the flags in one strided slice, no record copied); None: no player."""
    at = RF2_SCORING_VEHICLES_AT + 196
    flags = scoring[at : at + count * RF2_SCORING_VEHICLE_BYTES : RF2_SCORING_VEHICLE_BYTES]
    slot = len(flags) - len(flags.lstrip(b"\x00"))
    return slot if slot < len(flags) else None


@functools.cache
def _rf2_ids(cars: int) -> struct.Struct:
    """The mIDs of telemetry's first `cars` records (from 16) in one unpack, the rest skipped
    (at most 129 of them cached: `cars` is checked within 0-128 first)."""
    return struct.Struct("<" + f"i{RF2_TELEMETRY_VEHICLE_BYTES - 4}x" * cars)


_names: dict[bytes, str] = {}


def _rf2_name(raw: bytes) -> str:
    """mVehicleName (char[64]) as text ("" where it is not), cached by its bytes: it changes
    with the car only."""
    name = _names.get(raw)
    if name is None:
        name = _c_text(raw) or ""
        if len(_names) > 16:
            _names.clear()
        _names[raw] = name
    return name


def rf2_identify(pages: Sequence[bytes]) -> tuple[str, float]:
    scoring = pages[1]
    slot = _rf2_player_slot(scoring, _I32.unpack_from(scoring, 116)[0])
    if slot is None:
        return "", NAN
    at = RF2_SCORING_VEHICLES_AT + slot * RF2_SCORING_VEHICLE_BYTES
    return _c_text(scoring[at + 36 : at + 100]) or "", NAN


def _select_rf2(pages: Sequence[Any]) -> tuple[tuple[int, ...], bytes, bytes] | None:
    """What `_decode_rf2` reads of the two buffers (the live maps, or a file frame's), read
    between two reads of their guards (mVersionUpdateBegin, mVersionUpdateEnd): telemetry's
    mNumVehicles with scoring's mNumVehicles, mGamePhase and mInRealtime (unpacked); a copy of
    the player's scoring record to its mVehicleName (b"": no player) and of its telemetry
    record, the one with its mID (b"": not there yet). The flags and the mIDs are scanned in
    place, not copied. None: torn (a guard's begin differs from its end: being written; or a
    guard moved while these were read)."""
    telemetry, scoring = pages
    guards = _RF2_GUARD.unpack_from(telemetry), _RF2_GUARD.unpack_from(scoring)
    if guards[0][0] != guards[0][1] or guards[1][0] != guards[1][1]:
        return None
    head = _I32.unpack_from(telemetry, 12) + _RF2_PHASE.unpack_from(scoring, 116)
    count, scored = head[0], head[1]
    player = record = b""
    if 0 <= count <= RF2_VEHICLES and 0 <= scored <= RF2_VEHICLES:
        slot = _rf2_player_slot(scoring, scored)
        if slot is not None:
            at = RF2_SCORING_VEHICLES_AT + slot * RF2_SCORING_VEHICLE_BYTES
            player = bytes(scoring[at : at + RF2_PLAYER_BYTES])
            ids = _rf2_ids(count).unpack_from(telemetry, 16)
            try:
                at = 16 + ids.index(_I32.unpack_from(player)[0]) * RF2_TELEMETRY_VEHICLE_BYTES
                record = bytes(telemetry[at : at + RF2_TELEMETRY_VEHICLE_BYTES])
            except ValueError:
                pass  # not in telemetry yet
    if (_RF2_GUARD.unpack_from(telemetry), _RF2_GUARD.unpack_from(scoring)) != guards:
        return None
    return head, record, player


def _decode_rf2(parts: Sequence[Any], car: str, max_rpm: float) -> VehicleState | None:
    (count, scored, phase, realtime), record, player = parts  # as _select_rf2 read them
    if not (0 <= scored <= RF2_VEHICLES and 0 <= count <= RF2_VEHICLES and phase in RF2_PHASES):
        return BAD
    if not player:
        return None  # no player's car (the menus, or watching others)
    if not record:
        return None  # scoring has the player, telemetry not yet
    name = _rf2_name(player[36:100])
    v = _RF2_DRIVE.unpack_from(record, 184)
    vel, acc, rot = v[0:3], v[3:6], v[6:9]
    gear, rpm, throttle, brake, steer, clutch, torque = v[9:16]
    top = _RF2_MAX_RPM.unpack_from(record, 532)[0]
    lock_deg = _RF2_RANGE.unpack_from(record, 692)[0]
    if not (
        -1 <= gear <= 24
        and 0.0 <= rpm <= 30_000.0
        and _within(1.01, throttle, brake, steer, clutch)
        and _within(VELOCITY_BOUND_M_S, *vel)
        and _within(500.0, *acc)
        and _within(50.0, *rot)
        and _within(1e4, torque)
        and (lock_deg == 0.0 or 0.0 < lock_deg <= 3600.0)
    ):
        return BAD
    # Vehicle axes +x left, +y up, +z backward (rF2's; left-handed): Ay left is +x already; a
    # positive rotation about y turns x (left) towards -z (forward): the car turning right, so
    # the yaw rate left is its negative. mUnfilteredSteering is -1 left .. +1 right, over the
    # wheel's physical range (lock to lock). No real dump was found to check the signs.
    angle = -steer * math.radians(lock_deg) / 2.0 if lock_deg > 0.0 else NAN
    speed = math.sqrt(vel[0] ** 2 + vel[1] ** 2 + vel[2] ** 2)
    top = top if 0.0 < top <= 30_000.0 else max_rpm
    return _new(  # positional, in the fields' order: half the keyword constructor's cost
        (speed, acc[0], -rot[1], rpm, REVERSE if gear < 0 else gear, clutch, throttle, brake,
         angle, top, name or car, *_TO_TORQUE, torque, *_TO_REPLAY, not realtime,
         phase == RF2_STOPPED)
    )  # fmt: skip


_new = VehicleState._make
_FIELDS, _DEFAULTS = VehicleState._fields, VehicleState._field_defaults
_TO_TORQUE = tuple(
    _DEFAULTS[f] for f in _FIELDS[_FIELDS.index("car") + 1 : _FIELDS.index("wheel_torque_Nm")]
)
"""The defaults between car and wheel_torque_Nm (cylinders .. time_s)."""
_TO_REPLAY = tuple(
    _DEFAULTS[f] for f in _FIELDS[_FIELDS.index("wheel_torque_Nm") + 1 : _FIELDS.index("replay")]
)
"""The defaults between wheel_torque_Nm and replay (then paused, the last field)."""


RF2 = PageLayout("rf2", (RF2_TELEMETRY_BYTES, RF2_SCORING_BYTES), _check_rf2, _decode_rf2,
                 rf2_identify, exact_bytes=True, select=_select_rf2)  # fmt: skip


# --- RaceRoom: $R3E (Sector3's r3e-api r3e.h, version 3.4, #pragma pack(1)) --------------------
R3E_MAP_NAME = "$R3E"
R3E_VERSION = (3, 4)
R3E_MAP_BYTES = 44000
"""r3e_share whole: 2,016 bytes to the 128 r3e_driver_data of 328."""
R3E_READ_BYTES = 1540
"""r3e_share through steer_wheel_range_degrees: every field carfeel reads."""
R3E_NAME_AT = 1200  # vehicle_info.name, uint8_t[64]
R3E_ALL_DRIVERS_AT = 2012  # num_cars: what the header's all_drivers_offset must say
R3E_DRIVER_DATA_BYTES = 328
R3E_DRIVE_AT = 1392
_R3E_HEAD = struct.Struct("<10i")
"""version_major, version_minor, all_drivers_offset, driver_data_size, game_mode, game_paused,
game_in_menus, game_in_replay, game_using_vr, game_unused1."""
_R3E_DRIVE = struct.Struct("<iffffii24x3f48x7fii")
"""At 1392: control_type, car_speed, engine_rps, max_engine_rps, upshift_rps, gear, num_gears,
(car_cg_location, car_orientation) local_acceleration 1444, (mass .. turbo_pressure) throttle
1504, throttle_raw, brake, brake_raw, clutch, clutch_raw, steer_input_raw, steer_lock_degrees,
steer_wheel_range_degrees."""
_R3E_ROT = struct.Struct("<3d")  # at 272: player.local_angular_velocity, rad/s
RPS_TO_RPM = 60.0 / (2.0 * math.pi)


def _check_r3e(pages: Sequence[bytes]) -> str | None:
    major, minor, drivers_at, driver_bytes = _R3E_HEAD.unpack_from(pages[0])[0:4]
    if (major, minor) != R3E_VERSION:
        return (
            f"shared memory version {major}.{minor}: carfeel reads r3e.h version "
            f"{R3E_VERSION[0]}.{R3E_VERSION[1]} (its fields move between versions)"
        )
    if (drivers_at, driver_bytes) != (R3E_ALL_DRIVERS_AT, R3E_DRIVER_DATA_BYTES):
        return (
            f"all_drivers_offset {drivers_at} and driver_data_size {driver_bytes}: version "
            f"3.4's are {R3E_ALL_DRIVERS_AT} and {R3E_DRIVER_DATA_BYTES} (another layout)"
        )
    return None


def r3e_identify(pages: Sequence[bytes]) -> tuple[str, float]:
    car = _c_text(pages[0][R3E_NAME_AT : R3E_NAME_AT + 64]) or ""
    return car, NAN


def _decode_r3e(pages: Sequence[Any], car: str, max_rpm: float) -> VehicleState | None:
    page = pages[0]
    head = _R3E_HEAD.unpack_from(page)
    paused, menus, replay = head[5:8]
    if not all(flag in (-1, 0, 1) for flag in (paused, menus, replay)):
        return BAD
    if menus == 1:
        return None  # in the menus: nobody drives
    v = _R3E_DRIVE.unpack_from(page, R3E_DRIVE_AT)
    speed, rps, top_rps, gear, gears = v[1], v[2], v[3], v[5], v[6]
    acc, (throttle, _tr, brake, _br, clutch, _cr, steer), wheel_deg = v[7:10], v[10:17], v[18]
    rot = _R3E_ROT.unpack_from(page, 272)
    if not (
        -2 <= gear <= 24
        and -1 <= gears <= 24
        and 0.0 <= speed <= VELOCITY_BOUND_M_S
        and 0.0 <= rps <= 3200.0  # 30,000 rpm
        and _within(1.01, throttle, brake, clutch, steer)
        and _within(500.0, *acc)
        and _within(50.0, *rot)
        and 0 <= wheel_deg <= 3600
    ):
        return BAD
    # Car axes +X left, +Y up, +Z back (the header's, left-handed, as rF2): Ay is +X; the yaw
    # rate left is minus the rotation about Y. steer_input_raw -1 left (as rF2's; no real dump
    # was found to check it) over the wheel's range lock to lock: half of it each side.
    name = _c_text(page[R3E_NAME_AT : R3E_NAME_AT + 64])
    return VehicleState(
        speed_m_s=speed,
        lateral_accel_m_s2=acc[0],
        yaw_rate_rad_s=-rot[1],
        engine_speed_rpm=rps * RPS_TO_RPM,
        gear=max(REVERSE, gear) if gear != -2 else 0,  # -2: not available
        clutch_pedal=clutch if clutch >= 0.0 else NAN,
        throttle=throttle if throttle >= 0.0 else NAN,
        brake=brake if brake >= 0.0 else NAN,
        steering_angle_rad=-steer * math.radians(wheel_deg) / 2.0 if wheel_deg else NAN,
        engine_max_rpm=top_rps * RPS_TO_RPM if 0.0 < top_rps <= 3200.0 else max_rpm,
        car=name or car,
        forward_gears=max(0, gears),
        replay=replay == 1,
        paused=paused == 1,
    )


R3E = PageLayout("r3e", (R3E_READ_BYTES,), _check_r3e, _decode_r3e, r3e_identify,
                 sequence_offset=44, file_page_bytes=(R3E_MAP_BYTES,))  # fmt: skip
"""The update counter: player.game_simulation_ticks (1/400 s)."""


class PagesReader:
    """The frames of a page layout: a live map's pages (one image each) or a file of frames."""

    def __init__(self, layout: PageLayout, images: Sequence[Any], is_file: bool) -> None:
        self.layout, self.images, self.is_file = layout, images, is_file
        self.finished = False
        self.next = 0
        self.skipped = 0
        sizes = layout.page_bytes
        if is_file:
            (image,) = images
            if len(image) == 0 or len(image) % layout.frame_bytes:
                raise ValueError(
                    f"{len(image)} bytes is not a whole number of {layout.name} frames of "
                    f"{layout.frame_bytes} bytes (pages of {', '.join(map(str, sizes))})"
                )
            self.frames = len(image) // layout.frame_bytes
        else:
            for image, size in zip(images, sizes, strict=True):
                if len(image) < size or (layout.exact_bytes and len(image) != size):
                    raise ValueError(
                        f"a {layout.name} map of {len(image)} bytes: the layout carfeel reads "
                        f"is {size} bytes (another version of the game's plugin?)"
                    )
            self.frames = 0
        first = self._pages(0)
        why = layout.check(first)
        if why is not None:
            raise ValueError(why)
        self.car, self.max_rpm = layout.identify(first)
        self._sequence = -1
        self._seq = struct.Struct("<i")

    def _pages(self, frame: int) -> list[bytes]:
        sizes = self.layout.page_bytes
        if self.is_file:
            at = frame * self.layout.frame_bytes
            out = []
            for size, stride in zip(sizes, self.layout.stride, strict=True):
                out.append(bytes(self.images[0][at : at + size]))
                at += stride
            return out
        return [bytes(image[0:size]) for image, size in zip(self.images, sizes, strict=True)]

    def _decode_file(self, frame: int) -> VehicleState | None:
        pages: Sequence[Any] = self._pages(frame)
        if self.layout.select is not None:
            parts = self.layout.select(pages)
            if parts is None:
                return BAD  # torn when it was dumped
            pages = parts
        return self.layout.decode(pages, self.car, self.max_rpm)

    def read(self, now_s: float) -> list[VehicleState | None]:
        decode, car, max_rpm = self.layout.decode, self.car, self.max_rpm
        if self.is_file:
            due = min(self.frames, int(now_s * FRAME_HZ + 1e-9) + 1)
            if due <= self.next:
                self.finished = self.next >= self.frames
                return []
            start = max(self.next, due - 64)
            self.skipped += start - self.next
            self.next = due
            return [self._decode_file(i) for i in range(start, due)]
        at = self.layout.sequence_offset
        physics = self.images[0]
        odd, select = self.layout.odd_is_writing, self.layout.select
        for _ in range(2):  # the game may write the page while we copy it: once more
            before = self._seq.unpack_from(physics, at)[0]
            if before == self._sequence:
                return []  # nothing new
            if odd and before & 1:
                continue  # being written now
            pages = self._pages(0) if select is None else select(self.images)
            if pages is not None and self._seq.unpack_from(physics, at)[0] == before:
                self._sequence = before
                return [decode(pages, car, max_rpm)]
        return [BAD]
