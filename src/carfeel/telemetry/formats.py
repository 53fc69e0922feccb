"""One decoder per game format, from the published layouts (`struct`, little-endian).

Each decoder takes one datagram of one of its `Format.sizes` (any size where `other_sizes`) and
the last state (for formats that split the state over several packets), and returns a
`VehicleState` in SI units; None for a packet of the format that carries no vehicle state (a
menu, a paused game, another packet type); or `BAD` for bytes that are not a packet of the
format: a field outside the game's own range (a flag that is not 0 or 1, a car id, a gear, a
speed field that disagrees with the other). Decoders are total: whatever the bytes (NaN,
infinities, random), they return, never raise (`decode_datagram` checks the size first; the
fuzz tests hold them to it). The receiver then checks the state once (`plausible`).

Signs are turned into ISO 8855 here (left positive). Where a format has no lateral acceleration,
it is derived and `lateral_derived` is set: OutSim rotates its world acceleration by the heading;
BeamNG's MotionSim uses speed x yaw rate (exact in a steady turn; it misses the sideslip's rate).
`time_s` is the packet's own time stamp where the format has one.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from carfeel.telemetry.state import BAD, NAN, NEUTRAL, REVERSE, VehicleState

G = 9.80665
KMH = 1.0 / 3.6
DEG = math.pi / 180.0
_TAIL = tuple(VehicleState._field_defaults[f] for f in VehicleState._fields[14:])
"""The fields after time_s, which the UDP formats leave at their defaults."""
_new = VehicleState._make


def _make(values: tuple[Any, ...]) -> VehicleState:
    """Positional, as the fields' order up to time_s (a third of the keyword constructor's
    cost); the later fields at their defaults."""
    return _new(values + _TAIL)


Decoder = Callable[[Any, VehicleState], VehicleState | None]

ANGLE_BOUND_RAD = 2.0 * math.pi + 0.1
"""Headings, pitch and roll as the games send them (radians, within one turn either way)."""
ANGULAR_RATE_BOUND_RAD_S = 50.0
"""A car's rotation rate about any axis, even tumbling after a crash (8 turns a second)."""
ACCEL_BOUND_M_S2 = 500.0
"""A component of a car's acceleration, crashes included (50 g)."""
VELOCITY_BOUND_M_S = 150.0
"""As `plausible`'s speed: a component of the velocity."""


def _within(bound: float, *values: float) -> bool:
    """Every value finite and within +-bound (NaN and infinities fail). A plain loop: half the
    cost of all() over a generator, per packet."""
    for v in values:  # noqa: SIM110 - all() over a generator costs twice this, a packet
        if not -bound <= v <= bound:
            return False
    return True


@dataclass(frozen=True, slots=True)
class Format:
    name: str
    sizes: frozenset[int]
    """Datagram sizes the decoder accepts; any other is a bad packet (unless `other_sizes`)."""
    decode: Decoder
    default_port: int
    describe: str
    other_sizes: bool = False
    """True where the game sends other packet types, of other sizes, to the same port (F1): the
    decoder is given every datagram and tells its other packets (ignored) from garbage (bad)."""


def decode_datagram(fmt: Format, data: Any, last: VehicleState) -> VehicleState | None:
    """One datagram of any size and content: a state, None (a packet without a vehicle state)
    or a state that fails `plausible` (`BAD`: the wrong size, or not this format's)."""
    if not fmt.other_sizes and len(data) not in fmt.sizes:
        return BAD
    return fmt.decode(data, last)


# --- Codemasters "extradata" (DiRT Rally 1/2, DiRT 4, GRID ...), extradata=3: 66 floats ----------
_CM = struct.Struct("<f24xf84x6f8xf100xf4xf")
"""Only the floats used (the rest skipped): 0 time; 7 speed; 29 throttle, 30 steer, 31 brake,
32 clutch, 33 gear, 34 gforce_lat; 37 engine_rate; 63 max_rpm; 65 max_gears (index = byte / 4)."""
CM_MAX_GEAR = 10.0


def decode_codemasters(data: Any, last: VehicleState) -> VehicleState | None:
    time_s, speed, throttle, steer, brake, clutch, raw, lateral_g, rate, max_rate, gears = (
        _CM.unpack_from(data)
    )
    # The gear and the gear count are whole numbers the game keeps small; rpm / 10 and its
    # maximum at most 3000 (30000 rpm); the time is the session's, from 0. Checked before any
    # conversion: round() of NaN raised, and random floats are rarely whole.
    if not (
        -1.0 <= raw <= CM_MAX_GEAR
        and raw == int(raw)
        and 0.0 <= gears <= 12.0
        and gears == int(gears)
        and 0.0 <= rate <= 3000.0
        and 0.0 <= max_rate <= 3000.0
        and -1e9 < time_s < 1e9
        and -1.01 <= steer <= 1.01
    ):
        return BAD
    raw_gear = int(raw)
    # 0 neutral; reverse is -1 (DiRT Rally 2.0) or 10 (DiRT Rally 1, where no car has 10 gears).
    gear = REVERSE if raw_gear == 10 and gears < 10 else raw_gear  # -1 is REVERSE already
    # gforce_lat in g, positive to the right as published; engine_rate is rpm / 10.
    return _make((speed, -lateral_g * G, NAN, rate * 10.0, gear, clutch, throttle, brake, NAN,
                  max_rate * 10.0, "", 0, False, time_s))  # fmt: skip


# --- EA SPORTS F1 2023+: header, Motion (id 0) and Car Telemetry (id 6) -----------------------
_F1_HEADER = struct.Struct("<HBBBBBQfIIBB")  # 29 bytes
_F1_MOTION_CAR = struct.Struct("<6f6h6f")  # 60 bytes a car
_F1_TELEMETRY_CAR = struct.Struct("<HfffBbHBBH4H4B4BH4f4B")  # 60 bytes a car
F1_MOTION_SIZE = 29 + 22 * 60
F1_TELEMETRY_SIZE = 29 + 22 * 60 + 3
F1_FIRST_FORMAT, F1_LAST_FORMAT = 2023, 2030
"""The header's packetFormat this layout reads; earlier F1 games (from 2017) are ignored."""
F1_PACKET_IDS = 16
"""Packet ids 0..15 (F1 24); any other is not an F1 header."""
_UNIT_INT16 = 32767.0
"""The motion packet's direction vectors are unit vectors scaled to int16."""


def decode_f1(data: Any, last: VehicleState) -> VehicleState | None:
    if len(data) < _F1_HEADER.size:
        return BAD
    header = _F1_HEADER.unpack_from(data)
    packet_format, packet_id, session_time, player, second = (
        header[0], header[5], header[7], header[10], header[11],
    )  # fmt: skip
    if (
        not 2017 <= packet_format <= F1_LAST_FORMAT
        or packet_id >= F1_PACKET_IDS
        or player >= 22
        or not (second < 22 or second == 255)
        or not 0.0 <= session_time < 1e9
    ):
        return BAD  # not an F1 header
    if packet_format < F1_FIRST_FORMAT:
        return None  # an older game's layout
    offset = 29 + 60 * player
    if packet_id == 0 and len(data) == F1_MOTION_SIZE:
        m = _F1_MOTION_CAR.unpack_from(data, offset)
        forward = math.sqrt(m[6] * m[6] + m[7] * m[7] + m[8] * m[8]) / _UNIT_INT16
        right = math.sqrt(m[9] * m[9] + m[10] * m[10] + m[11] * m[11]) / _UNIT_INT16
        if not (
            0.9 <= forward <= 1.1
            and 0.9 <= right <= 1.1
            and _within(1e5, m[0], m[1], m[2])
            and _within(VELOCITY_BOUND_M_S, m[3], m[4], m[5])
            and _within(ANGLE_BOUND_RAD, m[15], m[16], m[17])
        ):
            return BAD
        speed = math.sqrt(m[3] * m[3] + m[4] * m[4] + m[5] * m[5])
        # gForceLateral, g, positive to the right as published (the car's right-direction vector).
        return last._replace(speed_m_s=speed, lateral_accel_m_s2=-m[12] * G, time_s=session_time)
    if packet_id == 6 and len(data) == F1_TELEMETRY_SIZE:
        c = _F1_TELEMETRY_CAR.unpack_from(data, offset)
        # clutch 0..100, gear -1..8, DRS 0/1, rev lights 0..100 %; steer -1..1.
        if not (c[4] <= 100 and -1 <= c[5] <= 8 and c[7] <= 1 and c[8] <= 100
                and -1.01 <= c[2] <= 1.01):  # fmt: skip
            return BAD
        speed = last.speed_m_s if not math.isnan(last.speed_m_s) else c[0] * KMH
        return last._replace(
            speed_m_s=speed,
            throttle=c[1],
            brake=c[3],
            clutch_pedal=c[4] / 100.0,
            gear=c[5],  # -1 R (REVERSE), 0 N, 1..8
            engine_speed_rpm=float(c[6]),
            time_s=session_time,
        )
    if len(data) in (F1_MOTION_SIZE, F1_TELEMETRY_SIZE) and packet_id in (0, 6):
        return BAD  # a motion or telemetry id at the other's size
    return None


# --- Assetto Corsa remote telemetry: RTCarInfo (328 bytes) ------------------------------------
_AC = struct.Struct("<c3xi3f6?2x3f4i5fif52f4f2f3f")
_AC_USED = struct.Struct("<c3xi8xf12xf20x5fi")
"""identifier, size, speed_Ms, accG_horizontal, gas, brake, clutch, engineRPM, steer, gear."""
_AC_CHECKED = struct.Struct("<8xff4x6B14x4i")
"""speed_Kmh, speed_Mph, the six flags (isAbsEnabled .. isEngineLimiterOn, one byte each),
lapTime, lastLap, bestLap, lapCount."""
AC_PORT = 9996
AC_HANDSHAKE, AC_SUBSCRIBE_UPDATE, AC_SUBSCRIBE_SPOT, AC_DISMISS = 0, 1, 2, 3
AC_RESPONSE_SIZE = 408
_AC_HANDSHAKER = struct.Struct("<iii")  # identifier, version, operationId
AC_NAME_CHARS = 50


def ac_request(operation: int) -> bytes:
    """The client's 12-byte handshaker (identifier 1 = eIPhoneDevice, version 1)."""
    return _AC_HANDSHAKER.pack(1, 1, operation)


def ac_car_name(response: Any) -> str:
    """The car's name from the 408-byte handshake response (wchar_t[50], UTF-16LE, then
    '%'-padded in practice); printable characters only (it is shown and looked up)."""
    raw = bytes(response[0 : 2 * AC_NAME_CHARS]).decode("utf-16-le", "replace")
    name = raw.split("\x00", 1)[0].split("%", 1)[0].strip()
    return "".join(c for c in name if c.isprintable())


def decode_assetto(data: Any, last: VehicleState) -> VehicleState | None:
    ident, size, speed, lateral_g, gas, brake, clutch, rpm, steer, raw_gear = _AC_USED.unpack_from(
        data
    )
    kmh, mph, *flags, lap_ms, last_ms, best_ms, laps = _AC_CHECKED.unpack_from(data)
    # The identifier and size fields; the flags are bools (0 or 1); the km/h field is the m/s
    # one x 3.6 and the mph one the km/h one / 1.609 (both float32: 1 % and 0.5 km/h of slack);
    # times in ms are not negative; gear 0 R, 1 N, 2 first .. (at most 10 forward).
    if (
        ident != b"a"
        or size != 328
        or max(flags) > 1
        or not abs(kmh - 3.6 * speed) <= 0.5 + 0.01 * abs(kmh)
        or not abs(mph * 1.609344 - kmh) <= 0.5 + 0.01 * abs(kmh)
        or min(lap_ms, last_ms, best_ms, laps) < 0
        or not 0 <= raw_gear <= 11
    ):
        return BAD
    # accG_horizontal, g: positive in right-hand turns (Monza, clockwise: its large values are
    # positive and follow the steer's sign). gear: 0 reverse, 1 neutral, 2 first. clutch: 1
    # engaged (pedal up). steer: degrees at the wheel, right positive.
    gear = raw_gear - 1  # 0 R -> -1 (REVERSE), 1 N -> 0, 2 first -> 1
    return _make((speed, -lateral_g * G, NAN, rpm, gear, 1.0 - clutch, gas, brake,
                  -steer * DEG, NAN, last.car, 0, False, NAN))  # fmt: skip


def assetto_speed_kmh(data: Any) -> float:
    """The second speed field (speed_Kmh) a test checks speed_Ms against."""
    return float(_AC.unpack_from(data)[2])


# --- Forza "Data Out": Sled (232), Dash FM7 (311), FH4/5 (324), FM 2023 (331) -----------------
_FORZA_SLED = struct.Struct("<iI3f3f3f3f3f")  # the first 68 bytes
_FORZA_USED = struct.Struct("<iIffff8x3f4xf")
"""IsRaceOn, TimestampMS, EngineMaxRpm, EngineIdleRpm, CurrentEngineRpm, AccelerationX,
Velocity XYZ, AngularVelocityY."""
_FORZA_RUMBLE = struct.Struct("<4i")  # at 116: WheelOnRumbleStrip, 0 or 1 each
_FORZA_CAR = struct.Struct("<5i")
"""At 212: CarOrdinal, CarClass, CarPerformanceIndex, DrivetrainType, NumCylinders."""
_FORZA_DASH = struct.Struct("<12xf28xf23xBBBxB")
"""After the sled (+12 bytes in FH4/5): Speed, Fuel, Accel, Brake, Clutch, Gear (u8 each)."""
FORZA_NEUTRAL = 11
"""Forza Motorsport 2023 reports gear 11 in neutral (and between gears); 0 is reverse."""
FORZA_MAX_ORDINAL = 1_000_000
"""Car ordinals run to a few thousand (FM 2023's capture: 2,000s); random bytes rarely fit."""


def decode_forza(data: Any, last: VehicleState) -> VehicleState | None:
    race_on, stamp_ms, max_rpm, idle_rpm, rpm, ax, vx, vy, vz, yaw = _FORZA_USED.unpack_from(data)
    if race_on == 0:  # menus, paused (the rest is zeros)
        return None
    ordinal, car_class, performance, drivetrain, cylinders = _FORZA_CAR.unpack_from(data, 212)
    # IsRaceOn and the rumble flags are 0 or 1; the car's ordinal, class (D..X and the
    # rest), performance index (to 999), drivetrain (FWD, RWD, AWD) and cylinders (none for an
    # electric car, 16 at most) are the game's small numbers; the engine's speeds are rpm.
    if (
        race_on != 1
        or not 0 <= min(rumble := _FORZA_RUMBLE.unpack_from(data, 116)) <= max(rumble) <= 1
        or not 0 < ordinal <= FORZA_MAX_ORDINAL
        or not 0 <= car_class <= 15
        or not 0 <= performance <= 1100
        or not 0 <= drivetrain <= 2
        or not 0 <= cylinders <= 16
        or not (0.0 <= max_rpm <= 30_000.0 and 0.0 <= idle_rpm <= 30_000.0)
        or not _within(VELOCITY_BOUND_M_S, vx, vy, vz)
    ):
        return BAD
    car = str(ordinal)
    time_s = stamp_ms / 1000.0
    # Car frame: x right, y up, z forward; the yaw rate about y is positive turning right.
    size = len(data)
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    if size == 232:
        return _make((speed, -ax, -yaw, rpm, NEUTRAL, NAN, NAN, NAN, NAN, max_rpm, car,
                      cylinders, False, time_s))  # fmt: skip
    dash_speed, fuel, accel, brake, clutch, raw_gear = _FORZA_DASH.unpack_from(
        data, 244 if size == 324 else 232
    )
    # The dash's Speed is the velocity's magnitude (to float32 on the capture); fuel 0..1.
    if (
        not abs(dash_speed - speed) <= 1.0 + 0.05 * speed
        or not 0.0 <= fuel <= 1.0
        or raw_gear > FORZA_NEUTRAL
    ):
        return BAD
    gear = REVERSE if raw_gear == 0 else NEUTRAL if raw_gear >= FORZA_NEUTRAL else raw_gear
    # Steer is a normalized input (-127..127), not an angle: steering_angle_rad stays NaN.
    return _make((dash_speed, -ax, -yaw, rpm, gear, clutch / 255.0, accel / 255.0, brake / 255.0,
                  NAN, max_rpm, car, cylinders, False, time_s))  # fmt: skip


def forza_velocity_speed(data: Any) -> float:
    """The second speed (the local velocity's magnitude) a test checks Speed against."""
    s = _FORZA_SLED.unpack_from(data)
    return math.sqrt(s[8] * s[8] + s[9] * s[9] + s[10] * s[10])


# --- Live for Speed / BeamNG OutGauge (92 bytes, 96 with the optional ID) ----------------------
_OUTGAUGE = struct.Struct("<I4s2xBxff8xf16x3f")
"""Time (ms), Car, Gear (0 R, 1 N, 2 first), Speed, RPM, Fuel, then Throttle, Brake, Clutch."""


def _car_name(raw: bytes) -> str | None:
    """A car's short name: printable ASCII, then NUL padding; None if it is not one."""
    name = raw.split(b"\x00", 1)[0]
    if raw[len(name) :].strip(b"\x00") or not name.isascii():
        return None
    text = name.decode("ascii")
    return text if text.isprintable() else None


def decode_outgauge(data: Any, last: VehicleState) -> VehicleState | None:
    stamp_ms, name, raw_gear, speed, rpm, fuel, throttle, brake, clutch = _OUTGAUGE.unpack_from(
        data
    )
    car = _car_name(name)
    # The car's name is text; gear 0 R, 1 N, 2.. forward; fuel 0..1.
    if car is None or raw_gear > 12 or not 0.0 <= fuel <= 1.0:
        return BAD
    gear = raw_gear - 1  # 0 R -> -1 (REVERSE), 1 N -> 0, 2 first -> 1
    return _make((speed, NAN, NAN, rpm, gear, clutch, throttle, brake, NAN, NAN, car, 0, False,
                  stamp_ms / 1000.0))  # fmt: skip


# --- Live for Speed OutSim (64 bytes, 68 with the optional ID) --------------------------------
_OUTSIM = struct.Struct("<I3f3f3f3f3i")


Floats = tuple[float, ...]


def _outsim_main(
    angular: Floats, angles: Floats, accel: Floats, velocity: Floats
) -> tuple[float, float, float] | None:
    """OSMain's (yaw rate, Ay, speed), or None where a value is beyond a car (checked before
    the heading's cosine: cos(inf) raised)."""
    if not (
        _within(ANGULAR_RATE_BOUND_RAD_S, *angular)
        and _within(ANGLE_BOUND_RAD, *angles)
        and _within(ACCEL_BOUND_M_S2, *accel)
        and _within(VELOCITY_BOUND_M_S, *velocity)
    ):
        return None
    heading = angles[0]
    # Heading 0 faces world +y, anticlockwise from above: the car's left is (-cos h, -sin h).
    lateral = -accel[0] * math.cos(heading) - accel[1] * math.sin(heading)
    vx, vy, vz = velocity
    # The angular velocity about world z (anticlockwise) is the yaw rate on flat ground.
    return angular[2], lateral, math.sqrt(vx * vx + vy * vy + vz * vz)


def decode_outsim(data: Any, last: VehicleState) -> VehicleState | None:
    f = _OUTSIM.unpack_from(data)
    main = _outsim_main(f[1:4], f[4:7], f[7:10], f[10:13])
    if main is None:
        return BAD
    yaw_rate, lateral, speed = main
    return _make((speed, lateral, yaw_rate, NAN, NEUTRAL, NAN, NAN, NAN, NAN, NAN, "", 0, True,
                  f[0] / 1000.0))  # fmt: skip


# --- Live for Speed OutSimPack2 (OutSim Opts != 0: the parts present depend on them) ----------
OSO_HEADER, OSO_ID, OSO_TIME, OSO_MAIN, OSO_INPUTS, OSO_DRIVE = 1, 2, 4, 8, 16, 32
OSO_DISTANCE, OSO_WHEELS, OSO_EXTRA_1 = 64, 128, 256
_OSO_SIZES = ((OSO_HEADER, 4), (OSO_ID, 4), (OSO_TIME, 4), (OSO_MAIN, 60), (OSO_INPUTS, 20),
              (OSO_DRIVE, 12), (OSO_DISTANCE, 8), (OSO_WHEELS, 160), (OSO_EXTRA_1, 8))  # fmt: skip
_OS2_MAIN = struct.Struct("<12f")
"""OSMain: AngVel xyz, Heading, Pitch, Roll, Accel xyz, Vel xyz (then Pos, not read)."""
_OS2_TIME = struct.Struct("<I")
_OS2_INPUTS = struct.Struct("<5f")  # Throttle, Brake, InputSteer, Clutch, Handbrake
_OS2_DRIVE = struct.Struct("<B3xf")  # Gear (0 R, 1 N, 2 first), EngineAngVel rad/s


def outsim_pack2(options: int) -> Format:
    """The OutSimPack2 format for LFS's "OutSim Opts" (hexadecimal in cfg.txt; OSMain needed)."""
    offsets: dict[int, int] = {}
    size = 0
    for flag, part in _OSO_SIZES:
        if options & flag:
            offsets[flag] = size
            size += part
    main = offsets.get(OSO_MAIN)
    if main is None or options >> 9:
        raise ValueError(f"OutSim Opts {options:x}: needs OSMain (8) and only the bits 1..100")
    inputs, drive, clock = offsets.get(OSO_INPUTS), offsets.get(OSO_DRIVE), offsets.get(OSO_TIME)
    header = OSO_HEADER in offsets

    def decode(data: Any, last: VehicleState) -> VehicleState | None:
        if header and bytes(data[0:4]) != b"LFST":
            return BAD
        m = _OS2_MAIN.unpack_from(data, main)
        checked = _outsim_main(m[0:3], m[3:6], m[6:9], m[9:12])
        if checked is None:
            return BAD
        yaw_rate, lateral, speed = checked
        throttle = brake = clutch = rpm = time_s = NAN
        gear = NEUTRAL
        if inputs is not None:
            throttle, brake, steer, clutch, handbrake = _OS2_INPUTS.unpack_from(data, inputs)
            if not (-1.01 <= steer <= 1.01 and -0.01 <= handbrake <= 1.01):
                return BAD
        if drive is not None:
            raw_gear, engine = _OS2_DRIVE.unpack_from(data, drive)
            if raw_gear > 12:
                return BAD
            gear = raw_gear - 1  # 0 R -> -1 (REVERSE), 1 N -> 0, 2 first -> 1
            rpm = engine * 30.0 / math.pi
        if clock is not None:
            time_s = _OS2_TIME.unpack_from(data, clock)[0] / 1000.0
        return _make((speed, lateral, yaw_rate, rpm, gear, clutch, throttle, brake, NAN, NAN, "",
                      0, True, time_s))  # fmt: skip

    return Format(f"outsim@{options:x}", frozenset({size}), decode, 4123,
                  f"Live for Speed OutSimPack2 (OutSim Opts {options:x})")  # fmt: skip


# --- BeamNG MotionSim "BNG1" (88 bytes) --------------------------------------------------------
_BNG1 = struct.Struct("<4s21f")


def decode_beamng(data: Any, last: VehicleState) -> VehicleState | None:
    f = _BNG1.unpack_from(data)
    if f[0] != b"BNG1":
        return BAD
    # posX..Z, velX..Z, accX..Z, upVec X..Z (a unit vector), roll/pitch/yaw, their rates and
    # accelerations.
    up = math.sqrt(f[10] * f[10] + f[11] * f[11] + f[12] * f[12]) if _within(2.0, *f[10:13]) else 0
    if not (
        0.95 <= up <= 1.05
        and _within(VELOCITY_BOUND_M_S, *f[4:7])
        and _within(ACCEL_BOUND_M_S2, *f[7:10])
        and _within(ANGLE_BOUND_RAD, *f[13:16])
        and _within(ANGULAR_RATE_BOUND_RAD_S, *f[16:19])
        and _within(1e7, *f[1:4], *f[19:22])
    ):
        return BAD
    speed = math.sqrt(f[4] * f[4] + f[5] * f[5] + f[6] * f[6])
    yaw_rate = f[18]
    return _make((speed, speed * yaw_rate, yaw_rate, NAN, NEUTRAL, NAN, NAN, NAN, NAN, NAN, "",
                  0, True, NAN))  # fmt: skip


# --- Project CARS 1 UDP (also sent by Project CARS 2 and Automobilista 2 in "PCARS1" mode) -----
PCARS_TELEMETRY, PCARS_STRINGS, PCARS_MORE_STRINGS = 0, 1, 2
PCARS_SIZES = {PCARS_TELEMETRY: 1367, PCARS_STRINGS: 1347, PCARS_MORE_STRINGS: 1028}
"""sTelemetryData (1,367 bytes as sent: its 2 pad bytes are not), sParticipantInfoStrings,
sParticipantInfoStringsAdditional; the type is the low 2 bits of byte 2 (the rest a count)."""
_PC_HEAD = struct.Struct("<HBBbb")
"""sBuildVersionNumber, sPacketType, sGameSessionState, sViewedParticipantIndex,
sNumParticipants."""
_PC_TIME = struct.Struct("<f")  # sCurrentTime at 20 (-1 when not timing)
_PC_CAR = struct.Struct("<BBBbffHHBBbB")
"""At 112: sBrake, sThrottle, sClutch (0..255), sSteering (-127..127), sFuelLevel, sSpeed (m/s),
sRpm, sMaxRpm, sGearNumGears (low nibble the gear, 15 reverse; high the gear count),
sBoostAmount, sEnforcedPitStopLap, sCrashState."""
_PC_MOTION = struct.Struct("<3f3f3f3f3f")
"""At 136: sOrientation, sLocalVelocity, sWorldVelocity, sAngularVelocity, sLocalAcceleration."""
PC_REVERSE_NIBBLE = 15
PC_PLAYING, PC_PAUSED, PC_MENU_TICKING, PC_REPLAY, PC_FRONT_END_REPLAY = 2, 3, 4, 6, 7


def _c_strings(data: Any, start: int, count: int) -> bool:
    """`count` 64-byte C strings from `start`: each NUL-terminated, printable ASCII before it."""
    for i in range(start, start + 64 * count, 64):
        text, nul, _ = bytes(data[i : i + 64]).partition(b"\x00")
        if not nul or not text.isascii() or not text.decode("ascii").isprintable():
            return False
    return True


def decode_pcars(data: Any, last: VehicleState) -> VehicleState | None:
    _build, kind, session, viewed, count = _PC_HEAD.unpack_from(data)
    packet = kind & 3
    if len(data) != PCARS_SIZES.get(packet):
        return BAD  # a size that is not its type's
    if packet != PCARS_TELEMETRY:
        # Pages of names: 64-char C strings (printable ASCII up to a NUL; the game leaves stale
        # bytes after it: "Audi A1 quattro\0a\0..." on the capture), random bytes never are.
        if packet == PCARS_MORE_STRINGS:  # sOffset (the first name's index, by 16), 16 names
            if session % 16 or not _c_strings(data, 4, 16):
                return BAD
            return None  # more drivers' names: nothing of the car
        if not _c_strings(data, 3, 20):  # car, class, track, variation, 16 names
            return BAD
        return last._replace(car=bytes(data[3:67]).split(b"\x00", 1)[0].decode("ascii"))
    brake, throttle, clutch, _steer, fuel, speed, rpm, max_rpm, gears, _b, _pit, crash = (
        _PC_CAR.unpack_from(data, 112)
    )
    m = _PC_MOTION.unpack_from(data, 136)
    game = session & 0x0F
    gear_nibble, gear_count = gears & 0x0F, gears >> 4
    # The game's own ranges: game states 0..7, the viewed participant -1..55 of at most 56, a
    # gear 0..12 or 15 (reverse), a crash state 0..4, the fuel 0..1. sSpeed is not checked
    # against the local velocity's length: it is the wheels' (3.4 m/s below the body's under
    # full braking on the capture), so a locked or spinning wheel may differ by any amount.
    if (
        game > PC_FRONT_END_REPLAY
        or not (-1 <= viewed < 56 and -1 <= count <= 56)
        or not (gear_nibble <= 12 or gear_nibble == PC_REVERSE_NIBBLE)
        or crash > 4
        or not 0.0 <= fuel <= 1.0  # sFuelLevel: a fraction of the tank
        or not _within(ANGLE_BOUND_RAD, *m[0:3])
        or not _within(VELOCITY_BOUND_M_S, *m[3:9])
        or not _within(ANGULAR_RATE_BOUND_RAD_S, *m[9:12])
        or not _within(ACCEL_BOUND_M_S2, *m[12:15])
        or not 0.0 <= speed <= VELOCITY_BOUND_M_S
    ):
        return BAD
    if game not in (PC_PLAYING, PC_PAUSED, PC_MENU_TICKING, PC_REPLAY, PC_FRONT_END_REPLAY):
        return None  # exited or in the front end: no car being driven
    time_s = _PC_TIME.unpack_from(data, 20)[0]
    gear = REVERSE if gear_nibble == PC_REVERSE_NIBBLE else gear_nibble
    # Car axes: x left, y up, z backward (the local velocity's z is minus the speed). Signs
    # from the capture (tests/test_telemetry_pcars.py): in a left turn, where the right wheels
    # turn faster, x acceleration and the angular velocity about y are positive: ISO already.
    # The steering is a normalized input (negative left), not an angle.
    state = _make((speed, m[12], m[10], float(rpm), gear, clutch / 255.0, throttle / 255.0,
                   brake / 255.0, NAN, float(max_rpm) if max_rpm else NAN, last.car, 0, False,
                   time_s if time_s >= 0.0 else NAN))  # fmt: skip
    return state._replace(
        forward_gears=gear_count if gear_count <= 12 else 0,
        replay=game in (PC_REPLAY, PC_FRONT_END_REPLAY),
        paused=game in (PC_PAUSED, PC_MENU_TICKING),
    )


# --- carfeel's own format, version 1 (56 bytes) ------------------------------------------------
CARFEEL_MAGIC = b"CRFL"
CARFEEL_VERSION = 1
CARFEEL = struct.Struct("<4sHHId4fb3x4f")
"""magic, version, flags (0), sequence, time_s, speed_m_s, lateral_accel_m_s2, yaw_rate_rad_s,
engine_speed_rpm, gear (-1 R, 0 N, 1..), 3 pad bytes, clutch_pedal, throttle, brake,
steering_angle_rad. NaN where the sender does not know a value."""


def encode_carfeel(state: VehicleState, sequence: int = 0, time_s: float = 0.0) -> bytes:
    s = state
    return CARFEEL.pack(
        CARFEEL_MAGIC, CARFEEL_VERSION, 0, sequence & 0xFFFFFFFF, time_s, s.speed_m_s,
        s.lateral_accel_m_s2, s.yaw_rate_rad_s, s.engine_speed_rpm, s.gear, s.clutch_pedal,
        s.throttle, s.brake, s.steering_angle_rad,
    )  # fmt: skip


_CARFEEL_USED = struct.Struct("<4sH6xd4fb3x4f")


def decode_carfeel(data: Any, last: VehicleState) -> VehicleState | None:
    magic, version, t, v, ay, r, rpm, gear, clutch, throttle, brake, steer = (
        _CARFEEL_USED.unpack_from(data)
    )
    if magic != CARFEEL_MAGIC:
        return BAD
    if version != CARFEEL_VERSION:
        return None  # a later version: refused, not misread
    return _make((v, ay, r, rpm, gear, clutch, throttle, brake, steer, NAN, "", 0, False, t))


FORMATS: dict[str, Format] = {
    f.name: f
    for f in (
        Format("codemasters", frozenset({264}), decode_codemasters, 20777,
               "Codemasters extradata=3 (DiRT Rally 1/2, DiRT 4, GRID)"),
        Format("f1", frozenset({F1_MOTION_SIZE, F1_TELEMETRY_SIZE}), decode_f1, 20777,
               "EA SPORTS F1 2023+ (Motion and Car Telemetry packets)", other_sizes=True),
        Format("assetto", frozenset({328}), decode_assetto, AC_PORT,
               "Assetto Corsa remote telemetry (RTCarInfo); HOST:PORT is the game's"),
        Format("forza", frozenset({232, 311, 324, 331}), decode_forza, 5300,
               "Forza Data Out: Sled 232, FM7 Dash 311, FH4/5 Dash 324, FM 2023 Dash 331"),
        Format("outgauge", frozenset({92, 96}), decode_outgauge, 4444,
               "Live for Speed / BeamNG OutGauge"),
        Format("outsim", frozenset({64, 68}), decode_outsim, 4123, "Live for Speed OutSim"),
        Format("beamng", frozenset({88}), decode_beamng, 4444, "BeamNG MotionSim (BNG1)"),
        Format("pcars", frozenset(PCARS_SIZES.values()), decode_pcars, 5606,
               "Project CARS 1 UDP (Project CARS 2 and Automobilista 2 in its PCARS1 mode)"),
        Format("carfeel", frozenset({CARFEEL.size}), decode_carfeel, 5606,
               "carfeel v1 (README)"),
    )
}  # fmt: skip
