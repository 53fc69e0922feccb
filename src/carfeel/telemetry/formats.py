"""One decoder per game format, from the published layouts (`struct`, little-endian).

Each decoder takes one datagram (a bytes-like object whose size the receiver has checked against
`Format.sizes`) and the last state (for formats that split the state over several packets), and
returns a `VehicleState` in SI units, or None for a datagram that carries no vehicle state (a menu,
a paused game, another packet type). The receiver then checks the state once (`plausible`).

Signs are turned into ISO 8855 here (left positive). Where a format has no lateral acceleration,
it is derived and `lateral_derived` is set: OutSim rotates its world acceleration by the heading;
BeamNG's MotionSim uses speed x yaw rate (exact in a steady turn; it misses the sideslip's rate).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from carfeel.telemetry.state import NAN, NEUTRAL, REVERSE, VehicleState

G = 9.80665
KMH = 1.0 / 3.6
DEG = math.pi / 180.0
_make = VehicleState._make
"""Positional, as the fields' order: a third of the keyword constructor's cost."""

Decoder = Callable[[Any, VehicleState], VehicleState | None]


@dataclass(frozen=True, slots=True)
class Format:
    name: str
    sizes: frozenset[int]
    """Datagram sizes the decoder accepts; any other is a bad packet (unless `other_sizes`)."""
    decode: Decoder
    default_port: int
    describe: str
    other_sizes: bool = False
    """True where the game sends other packet types, of other sizes, to the same port (F1)."""


# --- Codemasters "extradata" (DiRT Rally 1/2, DiRT 4, GRID ...), extradata=3: 66 floats ----------
_CM = struct.Struct("<28xf84x6f8xf100xf4xf")
"""Only the floats used (the rest skipped): 7 speed; 29 throttle, 30 steer, 31 brake, 32 clutch,
33 gear, 34 gforce_lat; 37 engine_rate; 63 max_rpm; 65 max_gears (float index = byte / 4)."""


def decode_codemasters(data: Any, last: VehicleState) -> VehicleState | None:
    speed, throttle, _, brake, clutch, raw, lateral_g, rate, max_rate, gears = _CM.unpack_from(data)
    raw_gear = round(raw)
    # 0 neutral; reverse is -1 (DiRT Rally 2.0) or 10 (DiRT Rally 1, where no car has 10 gears).
    gear = REVERSE if raw_gear < 0 or (raw_gear == 10 and gears < 10) else raw_gear
    # gforce_lat in g, positive to the right as published; engine_rate is rpm / 10.
    return _make((speed, -lateral_g * G, NAN, rate * 10.0, gear, clutch, throttle, brake, NAN,
                  max_rate * 10.0, "", 0, False))  # fmt: skip


# --- EA SPORTS F1 2023+: header, Motion (id 0) and Car Telemetry (id 6) -----------------------
_F1_HEADER = struct.Struct("<HBBBBBQfIIBB")  # 29 bytes
_F1_MOTION_CAR = struct.Struct("<6f6h6f")  # 60 bytes a car
_F1_TELEMETRY_CAR = struct.Struct("<HfffBbHBBH4H4B4BH4f4B")  # 60 bytes a car
F1_MOTION_SIZE = 29 + 22 * 60
F1_TELEMETRY_SIZE = 29 + 22 * 60 + 3


def decode_f1(data: Any, last: VehicleState) -> VehicleState | None:
    header = _F1_HEADER.unpack_from(data)
    packet_format, packet_id, player = header[0], header[5], header[10]
    if packet_format < 2023 or player >= 22:
        return None
    offset = 29 + 60 * player
    if packet_id == 0 and len(data) == F1_MOTION_SIZE:
        m = _F1_MOTION_CAR.unpack_from(data, offset)
        speed = math.sqrt(m[3] * m[3] + m[4] * m[4] + m[5] * m[5])
        # gForceLateral, g, positive to the right as published (the car's right-direction vector).
        return last._replace(speed_m_s=speed, lateral_accel_m_s2=-m[12] * G)
    if packet_id == 6 and len(data) == F1_TELEMETRY_SIZE:
        c = _F1_TELEMETRY_CAR.unpack_from(data, offset)
        speed = last.speed_m_s if not math.isnan(last.speed_m_s) else c[0] * KMH
        return last._replace(
            speed_m_s=speed,
            throttle=c[1],
            brake=c[3],
            clutch_pedal=c[4] / 100.0,
            gear=REVERSE if c[5] < 0 else c[5],
            engine_speed_rpm=float(c[6]),
        )
    return None


# --- Assetto Corsa remote telemetry: RTCarInfo (328 bytes) ------------------------------------
_AC = struct.Struct("<c3xi3f6?2x3f4i5fif52f4f2f3f")
_AC_USED = struct.Struct("<c3xi8xf12xf20x5fi")
"""identifier, size, speed_Ms, accG_horizontal, gas, brake, clutch, engineRPM, steer, gear."""
AC_PORT = 9996
AC_HANDSHAKE, AC_SUBSCRIBE_UPDATE, AC_SUBSCRIBE_SPOT, AC_DISMISS = 0, 1, 2, 3
AC_RESPONSE_SIZE = 408
_AC_HANDSHAKER = struct.Struct("<iii")  # identifier, version, operationId


def ac_request(operation: int) -> bytes:
    """The client's 12-byte handshaker (identifier 1 = eIPhoneDevice, version 1)."""
    return _AC_HANDSHAKER.pack(1, 1, operation)


def ac_car_name(response: Any) -> str:
    """The car's name from the 408-byte handshake response (wchar_t[50], UTF-16LE, then
    '%'-padded in practice)."""
    raw = bytes(response[0:100]).decode("utf-16-le", "replace")
    return raw.split("\x00", 1)[0].split("%", 1)[0].strip()


def decode_assetto(data: Any, last: VehicleState) -> VehicleState | None:
    ident, size, speed, lateral_g, gas, brake, clutch, rpm, steer, raw_gear = _AC_USED.unpack_from(
        data
    )
    if ident != b"a" or size != 328:
        return None
    # accG_horizontal, g: positive in right-hand turns (Monza, clockwise: its large values are
    # positive and follow the steer's sign). gear: 0 reverse, 1 neutral, 2 first. clutch: 1
    # engaged (pedal up). steer: degrees at the wheel, right positive.
    gear = REVERSE if raw_gear <= 0 else raw_gear - 1
    return _make((speed, -lateral_g * G, NAN, rpm, gear, 1.0 - clutch, gas, brake,
                  -steer * DEG, NAN, last.car, 0, False))  # fmt: skip


def assetto_speed_kmh(data: Any) -> float:
    """The second speed field (speed_Kmh) a test checks speed_Ms against."""
    return float(_AC.unpack_from(data)[2])


# --- Forza "Data Out": Sled (232), Dash FM7 (311), FH4/5 (324), FM 2023 (331) -----------------
_FORZA_SLED = struct.Struct("<iI3f3f3f3f3f")  # the first 68 bytes
_FORZA_USED = struct.Struct("<i4xf4xff8x3f4xf")
"""IsRaceOn, EngineMaxRpm, CurrentEngineRpm, AccelerationX, Velocity XYZ, AngularVelocityY."""
_FORZA_CAR = struct.Struct("<i12xi")  # at 212: CarOrdinal .. NumCylinders
_FORZA_DASH = struct.Struct("<12xf55xBBBxB")
"""After the sled (+12 bytes in FH4/5): Speed, Accel, Brake, Clutch, Gear (u8 each)."""
FORZA_NEUTRAL = 11
"""Forza Motorsport 2023 reports gear 11 in neutral (and between gears); 0 is reverse."""


def decode_forza(data: Any, last: VehicleState) -> VehicleState | None:
    race_on, max_rpm, rpm, ax, vx, vy, vz, yaw = _FORZA_USED.unpack_from(data)
    if race_on == 0:  # menus, paused
        return None
    ordinal, cylinders = _FORZA_CAR.unpack_from(data, 212)
    car = str(ordinal)
    # Car frame: x right, y up, z forward; the yaw rate about y is positive turning right.
    size = len(data)
    if size == 232:
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        return _make((speed, -ax, -yaw, rpm, NEUTRAL, NAN, NAN, NAN, NAN, max_rpm, car,
                      cylinders, False))  # fmt: skip
    speed, accel, brake, clutch, raw_gear = _FORZA_DASH.unpack_from(
        data, 244 if size == 324 else 232
    )
    gear = REVERSE if raw_gear == 0 else NEUTRAL if raw_gear >= FORZA_NEUTRAL else raw_gear
    # Steer is a normalized input (-127..127), not an angle: steering_angle_rad stays NaN.
    return _make((speed, -ax, -yaw, rpm, gear, clutch / 255.0, accel / 255.0, brake / 255.0,
                  NAN, max_rpm, car, cylinders, False))  # fmt: skip


def forza_velocity_speed(data: Any) -> float:
    """The second speed (the local velocity's magnitude) a test checks Speed against."""
    s = _FORZA_SLED.unpack_from(data)
    return math.sqrt(s[8] * s[8] + s[9] * s[9] + s[10] * s[10])


# --- Live for Speed / BeamNG OutGauge (92 bytes, 96 with the optional ID) ----------------------
_OUTGAUGE = struct.Struct("<4x4s2xBxff28x3f")
"""Car, Gear (0 R, 1 N, 2 first), Speed, RPM, then Throttle, Brake, Clutch (the first 60)."""


def decode_outgauge(data: Any, last: VehicleState) -> VehicleState | None:
    name, raw_gear, speed, rpm, throttle, brake, clutch = _OUTGAUGE.unpack_from(data)
    car = _name(name)
    gear = REVERSE if raw_gear == 0 else raw_gear - 1
    return _make((speed, NAN, NAN, rpm, gear, clutch, throttle, brake, NAN, NAN, car, 0, False))


def _name(raw: bytes) -> str:
    return raw.split(b"\x00", 1)[0].decode("ascii", "replace")


# --- Live for Speed OutSim (64 bytes, 68 with the optional ID) --------------------------------
_OUTSIM = struct.Struct("<I3f3f3f3f3i")


def decode_outsim(data: Any, last: VehicleState) -> VehicleState | None:
    _, _, _, yaw_rate, heading, _, _, ax, ay, _, vx, vy, vz, *_ = _OUTSIM.unpack_from(data)
    # Heading 0 faces world +y, anticlockwise from above: the car's left is (-cos h, -sin h).
    lateral = -ax * math.cos(heading) - ay * math.sin(heading)
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    # The angular velocity about world z (anticlockwise) is the yaw rate on flat ground.
    return _make((speed, lateral, yaw_rate, NAN, NEUTRAL, NAN, NAN, NAN, NAN, NAN, "", 0, True))


# --- Live for Speed OutSimPack2 (OutSim Opts != 0: the parts present depend on them) ----------
OSO_HEADER, OSO_ID, OSO_TIME, OSO_MAIN, OSO_INPUTS, OSO_DRIVE = 1, 2, 4, 8, 16, 32
OSO_DISTANCE, OSO_WHEELS, OSO_EXTRA_1 = 64, 128, 256
_OSO_SIZES = ((OSO_HEADER, 4), (OSO_ID, 4), (OSO_TIME, 4), (OSO_MAIN, 60), (OSO_INPUTS, 20),
              (OSO_DRIVE, 12), (OSO_DISTANCE, 8), (OSO_WHEELS, 160), (OSO_EXTRA_1, 8))  # fmt: skip
_OS2_MAIN = struct.Struct("<8xff8xff4x3f")
"""From OSMain: AngVel z, Heading, Accel x y, Vel x y z."""
_OS2_INPUTS = struct.Struct("<ff4xf")  # Throttle, Brake, (InputSteer), Clutch
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
    inputs, drive = offsets.get(OSO_INPUTS), offsets.get(OSO_DRIVE)
    header = OSO_HEADER in offsets

    def decode(data: Any, last: VehicleState) -> VehicleState | None:
        if header and bytes(data[0:4]) != b"LFST":
            return None
        yaw_rate, heading, ax, ay, vx, vy, vz = _OS2_MAIN.unpack_from(data, main)
        lateral = -ax * math.cos(heading) - ay * math.sin(heading)  # as OutSim's
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        throttle = brake = clutch = rpm = NAN
        gear = NEUTRAL
        if inputs is not None:
            throttle, brake, clutch = _OS2_INPUTS.unpack_from(data, inputs)
        if drive is not None:
            raw_gear, engine = _OS2_DRIVE.unpack_from(data, drive)
            gear = REVERSE if raw_gear == 0 else raw_gear - 1
            rpm = engine * 30.0 / math.pi
        return _make((speed, lateral, yaw_rate, rpm, gear, clutch, throttle, brake, NAN, NAN, "",
                      0, True))  # fmt: skip

    return Format(f"outsim@{options:x}", frozenset({size}), decode, 4123,
                  f"Live for Speed OutSimPack2 (OutSim Opts {options:x})")  # fmt: skip


# --- BeamNG MotionSim "BNG1" (88 bytes) --------------------------------------------------------
_BNG1 = struct.Struct("<4s21f")


def decode_beamng(data: Any, last: VehicleState) -> VehicleState | None:
    f = _BNG1.unpack_from(data)
    if f[0] != b"BNG1":
        return None
    speed = math.sqrt(f[4] * f[4] + f[5] * f[5] + f[6] * f[6])
    yaw_rate = f[18]
    return _make((speed, speed * yaw_rate, yaw_rate, NAN, NEUTRAL, NAN, NAN, NAN, NAN, NAN, "",
                  0, True))  # fmt: skip


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


_CARFEEL_USED = struct.Struct("<4sH14x4fb3x4f")


def decode_carfeel(data: Any, last: VehicleState) -> VehicleState | None:
    magic, version, v, ay, r, rpm, gear, clutch, throttle, brake, steer = _CARFEEL_USED.unpack_from(
        data
    )
    if magic != CARFEEL_MAGIC or version != CARFEEL_VERSION:
        return None
    return _make((v, ay, r, rpm, gear, clutch, throttle, brake, steer, NAN, "", 0, False))


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
        Format("carfeel", frozenset({CARFEEL.size}), decode_carfeel, 5606,
               "carfeel v1 (README)"),
    )
}  # fmt: skip
