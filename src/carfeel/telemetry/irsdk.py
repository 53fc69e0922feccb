"""iRacing's telemetry layout (irsdk, header version 2): the live memory map and `.ibt` files.

Both start with the same 112-byte header (version, status, tick rate, where the session info YAML
and the variable headers are, how many rotating buffers and their length, each buffer's tick
count and offset); a `.ibt` file adds a 32-byte disk header (start date and times, laps, record
count) and stores its records one after the other from the first buffer's offset. Each variable
header (144 bytes) names a channel, its type (char, bool, int, bitfield, float, double), its
offset in a record and its count (6 for the 360 Hz `_ST` channels, oldest sample first).

The layout is read once, checked against the bytes it is in (a version other than 2, offsets
beyond the image, a channel of an unexpected type are refused with the reason), and compiled to
one `struct` of the channels carfeel uses: a frame costs one unpack (bench_telemetry.py).

Why not pyirsdk (kutu/pyirsdk, kept up to date): its live `startup` asks the simulator's HTTP
port and waits up to 32 ms on a Windows event (a 1 kHz loop must not block), it looks every
value up by name per read (a dict and a struct a value), it has no version or bounds check (a
torn or foreign image raises `struct.error`), it steps no `.ibt` records at the file's rate, and
it needs PyYAML for the session info, where carfeel needs five keys of the player's car.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import Any

from carfeel.telemetry.state import NAN, VehicleState

IRSDK_VERSION = 2
HEADER = struct.Struct("<10i8x" + "2i8x" * 4)
"""ver, status, tickRate, sessionInfoUpdate, sessionInfoLen, sessionInfoOffset, numVars,
varHeaderOffset, numBuf, bufLen, then varBuf[4] of (tickCount, bufOffset)."""
DISK_HEADER = struct.Struct("<qddii")
"""startDate (time_t), startTime, endTime (session time, s), lapCount, recordCount; at 112."""
VAR_HEADER = struct.Struct("<iii?3x32s64s32s")
"""type, offset, count, countAsTime, name, desc, unit: 144 bytes."""
MAX_BUFFERS = 4
MAX_VARS = 8192
"""The SDK's files have 200-400 channels; a count beyond this is not a header."""
STATUS_CONNECTED = 1
TYPE_CODES = {0: "c", 1: "?", 2: "i", 3: "I", 4: "f", 5: "d"}
TYPE_SIZES = {0: 1, 1: 1, 2: 4, 3: 4, 4: 4, 5: 8}
LIVE_MAP_NAME = "Local\\IRSDKMemMapFileName"
"""The Windows named memory (the SDK's IRSDK_MEMMAPFILENAME)."""
LIVE_MAP_SIZE = 1164 * 1024
"""The SDK's IRSDK_MEMMAPFILESIZE: the live map is never larger."""
SESSION_INFO_MAX = 1 << 20


class LayoutError(ValueError):
    """The bytes are not an irsdk layout carfeel reads; the message says why."""


@dataclass(frozen=True, slots=True)
class Channel:
    type: int
    offset: int
    count: int
    count_as_time: bool
    unit: str


# (name, the types accepted, which element: -1 the latest of a time-sampled array).
_FLOAT = (4,)
_WANTED: tuple[tuple[str, tuple[int, ...]], ...] = (
    ("SessionTime", (5,)),
    ("Speed", _FLOAT),
    ("LatAccel", _FLOAT),
    ("YawRate", _FLOAT),
    ("RPM", _FLOAT),
    ("Gear", (2,)),
    ("Clutch", _FLOAT),
    ("Throttle", _FLOAT),
    ("Brake", _FLOAT),
    ("SteeringWheelAngle", _FLOAT),
    ("SteeringWheelTorque", _FLOAT),
    ("SteeringWheelMaxForceNm", _FLOAT),
    ("ShiftGrindRPM", _FLOAT),
    ("IsReplayPlaying", (1,)),
    ("IsOnTrack", (1,)),
)
TORQUE_SAMPLES = "SteeringWheelTorque_ST"


@dataclass(frozen=True, slots=True)
class SessionInfo:
    """What the session info YAML says of the player's car."""

    car: str = ""
    """CarPath: the car's stable name (e.g. mercedesamggt4), the car map's key."""
    car_screen_name: str = ""
    redline_rpm: float = NAN
    idle_rpm: float = NAN
    forward_gears: int = 0
    gearbox: str = ""


@dataclass(frozen=True, slots=True)
class Layout:
    """One irsdk image's header, checked, and its channels compiled to one struct."""

    version: int
    tick_rate_hz: int
    buffers: int
    buffer_bytes: int
    channels: dict[str, Channel]
    session_offset: int
    session_bytes: int
    frame: struct.Struct = field(repr=False)
    """The used channels of one record, in offset order (with pad bytes between)."""
    slots: tuple[int, ...] = field(repr=False)
    """For each name of `_WANTED` (then the torque samples' first), its index in `frame`'s
    tuple, or -1 where the file does not have it."""
    samples: int = 0


def _text(raw: bytes) -> str:
    return raw.split(b"\x00", 1)[0].decode("latin-1")


def read_layout(image: Any) -> Layout:
    """Check and compile the header of `image` (bytes, mmap or memoryview); `LayoutError` with
    the reason where it is not a version-2 irsdk layout that fits the image."""
    size = len(image)
    if size < HEADER.size:
        raise LayoutError(f"{size} bytes: shorter than the irsdk header ({HEADER.size} bytes)")
    h = HEADER.unpack_from(image, 0)
    version, _status, tick_rate, _update, info_len, info_offset, nvars, var_offset = h[:8]
    nbuf, buf_len = h[8], h[9]
    if version != IRSDK_VERSION:
        raise LayoutError(
            f"irsdk header version {version}: carfeel reads version {IRSDK_VERSION} (the SDK's "
            "since 2011); a file of another version is not read rather than misread"
        )
    if not 1 <= tick_rate <= 10_000:
        raise LayoutError(f"tick rate {tick_rate} Hz: not an irsdk header's (60 or 360)")
    if not 1 <= nbuf <= MAX_BUFFERS:
        raise LayoutError(f"{nbuf} buffers: an irsdk layout has 1 to {MAX_BUFFERS}")
    if not 1 <= nvars <= MAX_VARS or not 0 < var_offset <= size - nvars * VAR_HEADER.size:
        raise LayoutError(
            f"{nvars} channels at offset {var_offset}: beyond the image's {size} bytes"
        )
    if not 0 < buf_len <= size:
        raise LayoutError(f"record length {buf_len}: beyond the image's {size} bytes")
    if not (0 <= info_len <= SESSION_INFO_MAX and 0 <= info_offset <= size - info_len):
        raise LayoutError(f"session info of {info_len} bytes at {info_offset}: beyond the image")
    channels: dict[str, Channel] = {}
    for i in range(nvars):
        kind, offset, count, as_time, name, _desc, unit = VAR_HEADER.unpack_from(
            image, var_offset + i * VAR_HEADER.size
        )
        if kind not in TYPE_SIZES or not (
            count >= 1 and 0 <= offset <= buf_len - count * TYPE_SIZES[kind]
        ):
            raise LayoutError(
                f"channel {i} ({_text(name)!r}): type {kind}, {count} at offset {offset} does "
                f"not fit a record of {buf_len} bytes"
            )
        channels[_text(name)] = Channel(kind, offset, count, as_time, _text(unit))
    if "Speed" not in channels:
        raise LayoutError("no Speed channel: not a car's telemetry (carfeel needs the speed)")
    parts: list[tuple[int, str, int]] = []  # (offset, code, slot key)
    for key, (name, kinds) in enumerate(_WANTED):
        ch = channels.get(name)
        if ch is None:
            continue
        if ch.type not in kinds:
            raise LayoutError(
                f"channel {name} is of type {ch.type}, not {'/'.join(map(str, kinds))}: a "
                "layout carfeel does not know"
            )
        # A time-sampled array (the live map's LatAccel has 6): its latest, the last element.
        parts.append((ch.offset + (ch.count - 1) * TYPE_SIZES[ch.type], TYPE_CODES[ch.type], key))
    samples = 0
    st = channels.get(TORQUE_SAMPLES)
    if st is not None and st.type == 4:
        samples = st.count
        for j in range(st.count):
            parts.append((st.offset + 4 * j, "f", len(_WANTED) + j))
    parts.sort()
    code, at, slots = "<", 0, [-1] * (len(_WANTED) + samples)
    for index, (offset, c, key) in enumerate(parts):
        if offset < at:
            raise LayoutError(f"channels overlap at offset {offset}: not an irsdk record")
        code += f"{offset - at}x{c}" if offset > at else c
        at = offset + struct.calcsize("<" + c)
        slots[key] = index
    return Layout(version, tick_rate, nbuf, buf_len, channels, info_offset, info_len,
                  struct.Struct(code), tuple(slots), samples)  # fmt: skip


def read_session(image: Any, layout: Layout) -> SessionInfo:
    """The player's car from the session info YAML (a line scan of the few keys: total over
    any text, no YAML library)."""
    raw = bytes(image[layout.session_offset : layout.session_offset + layout.session_bytes])
    text = raw.split(b"\x00", 1)[0].decode("cp1252", "replace")
    top: dict[str, str] = {}
    drivers: list[dict[str, str]] = []
    entry: dict[str, str] | None = None  # the list entry being read (a driver's, or None)
    section = ""
    for line in text.splitlines():
        if line and not line[0].isspace():
            section = line.split(":", 1)[0]
            continue
        key, colon, value = line.strip().removeprefix("- ").partition(":")
        if section != "DriverInfo" or not colon:
            continue
        value = value.strip().strip('"')
        if line.startswith(" - "):  # a list's entry begins: a driver's if it starts CarIdx
            entry = {} if key == "CarIdx" else None
            if entry is not None:
                drivers.append(entry)
        if line.startswith((" - ", "   ")):
            if entry is not None:
                entry[key] = value
        elif not line.startswith("  "):
            top[key] = value
    me = next((d for d in drivers if d.get("CarIdx") == top.get("DriverCarIdx")), {})
    kind = top.get("DriverGearboxType", "").lower()
    gearbox = "sequential" if "seq" in kind else "h" if kind.startswith("h") else ""
    return SessionInfo(
        car=_printable(me.get("CarPath", "")),
        car_screen_name=_printable(me.get("CarScreenName", "")),
        redline_rpm=_number(top.get("DriverCarRedLine")),
        idle_rpm=_number(top.get("DriverCarIdleRPM")),
        forward_gears=int(g) if (g := _number(top.get("DriverCarGearNumForward"))) == g else 0,
        gearbox=gearbox,
    )


def _printable(text: str) -> str:
    return "".join(c for c in text if c.isprintable())[:64]


def _number(text: str | None) -> float:
    try:
        value = float(text) if text is not None else NAN
    except ValueError:
        return NAN
    return value if math.isfinite(value) and 0.0 <= value < 1e6 else NAN


_make = VehicleState._make


def decode_record(layout: Layout, image: Any, offset: int, session: SessionInfo) -> VehicleState:
    """One record (at `offset` of `image`) as a vehicle state. Signs: iRacing's car axes are x
    forward, y left, z up, as ISO 8855; its Clutch is 1 engaged (pedal up). Built positionally
    (`VehicleState._make`, the fields' order): a third of the keyword constructor's cost."""
    v = layout.frame.unpack_from(image, offset)
    s = layout.slots
    nan = NAN
    samples = tuple(v[s[len(_WANTED)] : s[len(_WANTED)] + layout.samples]) if layout.samples else ()
    return _make((
        v[s[1]] if s[1] >= 0 else nan,  # Speed
        v[s[2]] if s[2] >= 0 else nan,  # LatAccel
        v[s[3]] if s[3] >= 0 else nan,  # YawRate
        v[s[4]] if s[4] >= 0 else nan,  # RPM
        v[s[5]] if s[5] >= 0 else 0,  # Gear
        1.0 - v[s[6]] if s[6] >= 0 else nan,  # Clutch: 1 engaged
        v[s[7]] if s[7] >= 0 else nan,  # Throttle
        v[s[8]] if s[8] >= 0 else nan,  # Brake
        v[s[9]] if s[9] >= 0 else nan,  # SteeringWheelAngle
        session.redline_rpm, session.car, 0, False,
        v[s[0]] if s[0] >= 0 else nan,  # SessionTime
        v[s[10]] if s[10] >= 0 else nan,  # SteeringWheelTorque
        samples,
        v[s[11]] if s[11] >= 0 else nan,  # SteeringWheelMaxForceNm
        v[s[12]] if s[12] >= 0 else nan,  # ShiftGrindRPM
        session.idle_rpm, session.forward_gears, session.gearbox, -1, False, False, (),
        bool(v[s[13]]) if s[13] >= 0 else False,  # IsReplayPlaying
        not v[s[14]] if s[14] >= 0 else False,  # IsOnTrack off: paused
    ))  # fmt: skip


def header_ticks(image: Any) -> tuple[int, int, tuple[tuple[int, int], ...]]:
    """(status, session info update count, ((tick, offset) of each of the 4 buffer slots))."""
    h = HEADER.unpack_from(image, 0)
    return h[1], h[3], ((h[10], h[11]), (h[12], h[13]), (h[14], h[15]), (h[16], h[17]))


def disk_records(image: Any, layout: Layout) -> tuple[int, int, int]:
    """A `.ibt` file's (first record's offset, records that are whole in the image, the
    record count its disk header claims)."""
    first = HEADER.unpack_from(image, 0)[11]
    claimed = DISK_HEADER.unpack_from(image, HEADER.size)[4]
    whole = max(0, (len(image) - first) // layout.buffer_bytes) if 0 < first <= len(image) else 0
    return first, whole, claimed


def is_disk_file(image: Any, layout: Layout) -> bool:
    """A `.ibt` file (one buffer, a disk header whose records end where the file does or
    before) rather than a dump of the live map (rotating buffers; the header's slots)."""
    if layout.buffers != 1 or len(image) < HEADER.size + DISK_HEADER.size:
        return False
    first, whole, claimed = disk_records(image, layout)
    return first >= HEADER.size + DISK_HEADER.size and claimed >= 0 and whole >= 1
