"""Measured logs in the formats car engineers have, read into carfeel's channels.

Every format goes through `read_channels`: the file's signals (each with its own time stamps and,
where the format carries it, its unit), a channel map saying which signal is which of carfeel's
channels with its unit and scale, then one common time base and SI units. The unit and sign checks
of the fits (`steering_fit.read_log`, `shift_traces.checked_columns`) run on what comes out,
whatever the format.

    CSV               carfeel's own reader (no extra needed)
    Parquet           pyarrow                   .parquet .pq
    MDF4 / MDF3       asammdf                   .mf4 .mdf .dat
    CAN + DBC         python-can + cantools     .log (candump -l) .asc (Vector) .blf (Vector)

The readers are the optional extra `carfeel[logs]`, imported only when such a file is read.

A channel map is a small TOML file, written once per car or logger:

    [resample]
    rate_hz = 100.0          # optional; default: the torque's (or the fastest mapped) rate

    [channels]
    speed_m_s = { signal = "SPEED.SPEED", unit = "km/h" }
    # a list is a sum: the RAV4's angle moves in 1.5 deg steps, its fraction in 0.1 deg
    steering_angle_rad = { signal = ["STEER_ANGLE_SENSOR.STEER_ANGLE",
                                     "STEER_ANGLE_SENSOR.STEER_FRACTION"], unit = "deg" }
    lateral_accel_m_s2 = { signal = "AccY", group = 3 }   # MDF4: the one in channel group 3
    [channels.steering_torque_Nm]
    signal = "STEER_TORQUE_SENSOR.STEER_TORQUE_DRIVER"
    unit = "Nm"
    scale = 0.01             # raw counts -> Nm

value in SI = (raw * scale + offset) * (the unit's factor to SI), raw being the signal (or the sum
of the list's signals, each term optionally `{ signal = "B", scale = -1.0 }`); `unit` defaults to
the unit the file gives the signal. A negative scale flips a sign convention. CAN signals are named
MESSAGE.SIGNAL. A file whose columns already carry carfeel's names needs no map.

Time: a CSV's or Parquet file's time column is numbers (seconds, or the unit its units row or the
map gives) or date-times (ISO 8601 text, Parquet timestamps): date-times become seconds from the
first sample, their origin kept in the metadata. A CSV may carry a row of units under its header.

Sizes are checked before anything is allocated (`MAX_SAMPLES`, `MAX_VALUES`, `MAX_LINE_BYTES`,
`MAX_MAP_BYTES`, `MAX_CAN_FRAMES`): a file beyond them is refused with the limit named.
"""

from __future__ import annotations

import codecs
import csv
import datetime
import difflib
import math
import tomllib
from array import array
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.simulation.result import Result

FloatArray = npt.NDArray[np.float64]

CHANNELS = {
    "time_s": "s",
    "speed_m_s": "m/s",
    "steering_angle_rad": "rad",
    "steering_rate_rad_s": "rad/s",
    "lateral_accel_m_s2": "m/s^2",
    "steering_torque_Nm": "N m",
    "position_m": "m",
    "force_N": "N",
}
"""carfeel's channels a map can fill, with their SI units."""
OWN_NAMES = {**CHANNELS, "torque_Nm": "N m"}
"""The columns a file named in carfeel's own way is read for (`carfeel simulate` writes the
torque as torque_Nm)."""

_G = 9.80665
UNITS: dict[str, tuple[str, float]] = {
    "s": ("s", 1.0), "ms": ("s", 1e-3), "us": ("s", 1e-6),
    "m/s": ("m/s", 1.0), "km/h": ("m/s", 1 / 3.6), "kph": ("m/s", 1 / 3.6),
    "kmh": ("m/s", 1 / 3.6), "mph": ("m/s", 0.44704),
    "rad": ("rad", 1.0), "deg": ("rad", math.pi / 180), "°": ("rad", math.pi / 180),
    "rad/s": ("rad/s", 1.0), "deg/s": ("rad/s", math.pi / 180), "°/s": ("rad/s", math.pi / 180),
    "m/s^2": ("m/s^2", 1.0), "m/s2": ("m/s^2", 1.0), "m/s²": ("m/s^2", 1.0), "g": ("m/s^2", _G),
    "nm": ("N m", 1.0), "n m": ("N m", 1.0), "n*m": ("N m", 1.0), "n.m": ("N m", 1.0),
    "ncm": ("N m", 0.01), "nmm": ("N m", 1e-3),
    "m": ("m", 1.0), "mm": ("m", 1e-3), "cm": ("m", 1e-2),
    "n": ("N", 1.0), "kn": ("N", 1e3), "kgf": ("N", _G), "kp": ("N", _G),
    "lbf": ("N", 4.4482216152605),
}  # fmt: skip
"""Unit names (case-insensitive) -> (SI unit, factor)."""

SUFFIXES = {
    ".csv": "csv",
    ".parquet": "parquet",
    ".pq": "parquet",
    ".mf4": "mdf",
    ".mdf": "mdf",
    ".dat": "mdf",
    ".log": "can",
    ".asc": "can",
    ".blf": "can",
}
_EXTRA = {
    "parquet": ("pyarrow", "Parquet"),
    "mdf": ("asammdf", "MDF"),
    "can": ("can", "CAN log"),
}

MAX_SAMPLES = 4_000_000
"""Most samples of one signal (67 min at 1 kHz, 5.5 h at 200 Hz): a fit holds a few arrays of
this length per parameter; a longer log is cut or resampled first."""
MAX_VALUES = 24_000_000
"""Most numbers read from one file at once (192 MB as float64): rows x the columns read."""
MAX_LINE_BYTES = 1 << 20
"""Longest CSV line (1 MiB: a header of 30,000 channel names)."""
MAX_MAP_BYTES = 1 << 20
"""Largest channel map (1 MiB; one is a few hundred bytes)."""
MAX_DBC_BYTES = 64 << 20
"""Largest DBC file (a car's whole bus is a few MB)."""
MAX_CAN_FRAMES = 40_000_000
"""Most frames read from a CAN log (3.5 h of a busy 500 kbit/s bus)."""
MAX_RAW_VALUE = 1e15
"""A decoded or converted value beyond this is not a measurement (a DBC scale of 1e308 made
every sample infinite); refused with the signal named."""
MAX_NAME_SHOWN = 80
"""Names and cells quoted in messages are cut to this many characters (a file's text is data:
a 50 MB cell must not come back in an error)."""
TIME_NAMES = ("time_s", "time", "timestamp", "t", "Time")


@dataclass(frozen=True)
class Signal:
    """One signal of a file, in the file's own units."""

    name: str
    time_s: FloatArray
    values: FloatArray
    unit: str
    group: int | None = None
    """The MDF channel group it comes from (None in other formats)."""
    time_origin: str | None = None
    """The date-time of the first sample, where the file's time column held date-times."""


@dataclass(frozen=True)
class Term:
    """One signal of a map entry's sum."""

    signal: str
    scale: float = 1.0
    group: int | None = None


@dataclass(frozen=True)
class MapEntry:
    terms: tuple[Term, ...]
    """Summed (one term: the signal itself)."""
    unit: str | None
    scale: float
    offset: float

    @property
    def signal(self) -> str:
        return " + ".join(t.signal for t in self.terms)


@dataclass(frozen=True)
class ChannelMap:
    channels: Mapping[str, MapEntry]
    rate_hz: float | None = None


def shown(text: object) -> str:
    """`text` as a message may quote it: cut to MAX_NAME_SHOWN characters, quoted."""
    value = str(text)
    if len(value) > MAX_NAME_SHOWN:
        value = value[:MAX_NAME_SHOWN] + f"... ({len(value)} characters)"
    return repr(value)


def _lazy(kind: str, path: Path) -> Any:
    module, what = _EXTRA[kind]
    try:
        return __import__(module)
    except ImportError:
        raise InputError(
            f"{path}: reading a {what} file needs the optional extra: pip install 'carfeel[logs]'"
        ) from None


# --- channel maps ------------------------------------------------------------------------------


def load_map(path: Path) -> ChannelMap:
    """Read and check a channel map (module docstring)."""
    where = f"--channels {path}"
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InputError(f"{where}: no such file") from None
    except OSError as exc:
        raise InputError(f"{where}: cannot read it ({exc.strerror})") from None
    if size > MAX_MAP_BYTES:
        raise InputError(
            f"{where}: {size:,} bytes, beyond the {_bytes(MAX_MAP_BYTES)} a channel map may have "
            "(one is a few hundred bytes): is it the right file?"
        )
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except IsADirectoryError:
        raise InputError(f"{where}: a folder, not a channel map") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{where}: not valid TOML ({str(exc)[:200]})") from None
    except RecursionError:  # tables or arrays nested thousands deep
        raise InputError(
            f"{where}: not a channel map: its tables or arrays nest thousands deep (a map has "
            "[channels] with one entry per channel)"
        ) from None
    unknown = sorted(set(data) - {"channels", "resample"})
    if unknown:
        raise InputError(
            f"{where}: unknown table(s) {', '.join(shown(u) for u in unknown[:5])}"
            .replace("'", "") + "; a channel map has [channels] and optionally [resample]"
        )  # fmt: skip
    table = data.get("channels")
    if not isinstance(table, dict) or not table:
        raise InputError(
            f"{where}: no [channels] table (see README, 'Log formats and channel maps')"
        )
    entries = {}
    for name, entry in table.items():
        if name not in CHANNELS:
            raise InputError(
                f"{where}: unknown channel {shown(name)}{_close(name, CHANNELS)}; carfeel's "
                f"channels are {', '.join(CHANNELS)}"
            )
        entries[name] = _entry(where, name, entry)
    resample = data.get("resample", {})
    if not isinstance(resample, dict):
        raise InputError(f"{where}: [resample] must be a table (rate_hz = 50.0)")
    if set(resample) - {"rate_hz"}:
        raise InputError(
            f"{where}: [resample] {', '.join(sorted(set(resample) - {'rate_hz'}))[:200]}: "
            "unknown key(s); it takes rate_hz"
        )
    rate = resample.get("rate_hz")
    if rate is not None and (
        isinstance(rate, bool)
        or not isinstance(rate, int | float)
        or not MIN_RESAMPLE_HZ <= rate <= MAX_RESAMPLE_HZ
    ):
        number = isinstance(rate, int | float) and not isinstance(rate, bool)
        raise InputError(
            f"{where}: [resample] rate_hz = {f'{rate:g}' if number else shown(rate)}: "
            f"expected a number of Hz, {MIN_RESAMPLE_HZ:g} <= rate_hz <= {MAX_RESAMPLE_HZ:g}"
        )
    return ChannelMap(entries, None if rate is None else float(rate))


MAX_TERMS = 16
"""Most signals one map entry sums."""


def _entry(where: str, name: str, entry: object) -> MapEntry:
    """One [channels] entry: a signal name, or a table with signal (a name, or a list of names
    or {signal, scale, group} tables: their sum), unit, scale, offset and group."""
    usage = (
        f'{where}: {name} needs signal = "NAME" (or a list of names to sum), and optionally '
        "unit, scale, offset, group"
    )
    if isinstance(entry, str):
        entry = {"signal": entry}
    if not isinstance(entry, dict) or "signal" not in entry:
        raise InputError(usage)
    extra = sorted(set(entry) - {"signal", "unit", "scale", "offset", "group"})
    if extra:
        raise InputError(
            f"{where}: {name}: unknown key(s) {', '.join(extra)[:200]}; allowed: signal, unit, "
            "scale, offset, group"
        )
    group = _group(where, name, entry.get("group"))
    raw = entry["signal"]
    items = raw if isinstance(raw, list) else [raw]
    if not items or len(items) > MAX_TERMS:
        raise InputError(f"{where}: {name}: signal lists 1 to {MAX_TERMS} signals to sum")
    terms = []
    for item in items:
        if isinstance(item, str):
            item = {"signal": item}
        if not isinstance(item, dict) or not isinstance(item.get("signal"), str):
            raise InputError(usage)
        if set(item) - {"signal", "scale", "group"}:
            raise InputError(
                f"{where}: {name}: a term of the sum takes signal, scale and group only"
            )
        scale = _number(where, name, "scale", item.get("scale", 1.0))
        terms.append(Term(item["signal"], scale, _group(where, name, item.get("group", group))))
    unit = entry.get("unit")
    if unit is not None:
        if not isinstance(unit, str):
            raise InputError(f'{where}: {name}: unit must be text, e.g. unit = "deg"')
        if _si(unit) != CHANNELS[name]:
            raise InputError(
                f"{where}: {name}: unit {shown(unit)} is not a unit of {CHANNELS[name]}; known: "
                f"{', '.join(u for u, (si, _) in UNITS.items() if si == CHANNELS[name])}"
            )
    scale = _number(where, name, "scale", entry.get("scale", 1.0))
    offset = _number(where, name, "offset", entry.get("offset", 0.0), zero=True)
    return MapEntry(tuple(terms), unit, scale, offset)


def _number(where: str, name: str, key: str, value: object, zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{where}: {name}: {key} must be a number")
    number = float(value)
    if not math.isfinite(number) or abs(number) > MAX_RAW_VALUE:
        raise InputError(f"{where}: {name}: {key} = {number:g}: give a finite number under 1e15")
    if number == 0.0 and not zero:
        raise InputError(f"{where}: {name}: {key} must not be 0")
    return number


def _group(where: str, name: str, value: object) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1_000_000:
        raise InputError(
            f"{where}: {name}: group must be an MDF channel group's index, 0 or more (carfeel "
            "channels FILE lists them)"
        )
    return int(value)


MIN_RESAMPLE_HZ = 1.0
MAX_RESAMPLE_HZ = 20_000.0
"""A log is resampled to 1 Hz .. 20 kHz (the 1 kHz loop's logs and a car's buses lie within)."""
MAX_GAP_S = 0.5
MAX_GAP_PERIODS = 20
"""A channel silent for longer than both (its own period's multiple and the seconds) is a gap in
the log, not jitter: interpolating across it would invent the data."""


def _si(unit: str) -> str | None:
    found = UNITS.get(unit.strip().lower()) or UNITS.get(unit.strip())
    return found[0] if found else None


def _factor(unit: str) -> float:
    return UNITS.get(unit.strip().lower(), UNITS.get(unit.strip(), ("", 1.0)))[1]


def _close(name: str, known: Iterable[str]) -> str:
    match = difflib.get_close_matches(name[:200], [k[:200] for k in known], n=1)
    return f" (did you mean {shown(match[0])}?)" if match else ""


def kind_of(path: Path) -> str:
    kind = SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise InputError(
            f"{path}: unknown log format {shown(path.suffix)}; carfeel reads "
            f"{', '.join(sorted(SUFFIXES))}"
        )
    return kind


# --- sizes -------------------------------------------------------------------------------------


def check_size(path: Path) -> None:
    """Refuse a log too large to read before any of it is allocated: a CSV by a streaming scan
    of its lines (their length and count), the other formats by what their headers say."""
    kind = kind_of(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    if kind == "csv":
        _scan_csv(path)


def _bytes(size: int) -> str:
    """A size as a message gives it: MiB, KiB or bytes."""
    for shift, unit in ((20, "MiB"), (10, "KiB")):
        if size >= 1 << shift and size % (1 << shift) == 0:
            return f"{size >> shift} {unit}"
    return f"{size:,} bytes"


def _too_many(path: Path, what: str, found: str, limit: int) -> InputError:
    return InputError(
        f"{path}: {what} {found}, beyond the {limit:,} carfeel reads from one log: cut the log "
        "into parts (or resample it) and give them one by one"
    )


def _scan_csv(path: Path) -> int:
    """Lines of a CSV file, read in 1 MiB blocks without keeping them: UTF-8 (a byte that is not
    is named with its line), no NUL bytes, no line over MAX_LINE_BYTES, at most MAX_SAMPLES + 2
    lines (a header, a units row). Returns the number of lines."""
    decoder = codecs.getincrementaldecoder("utf-8-sig")()
    lines, since = 0, 0  # lines ended so far; bytes since the last line's end
    with path.open("rb") as handle:
        while block := handle.read(1 << 20):
            try:
                decoder.decode(block)
            except UnicodeDecodeError as exc:
                line = lines + block[: exc.start].count(b"\n") + 1
                raise InputError(
                    f"{path}, line {line}: byte 0x{block[exc.start]:02x} is not UTF-8 text; save "
                    "the file as CSV UTF-8 (a spreadsheet's export, or iconv -f latin1 -t utf-8)"
                ) from None
            if b"\x00" in block:
                raise InputError(f"{path}: not a text CSV file (it holds NUL bytes)")
            ends = np.flatnonzero(np.frombuffer(block, dtype=np.uint8) == 10)
            lengths = np.diff(ends, prepend=-1 - since) - 1 if ends.size else np.zeros(0)
            longest = int(lengths.max()) if ends.size else since + len(block)
            if longest > MAX_LINE_BYTES:
                at = lines + 1 + (int(np.argmax(lengths)) if ends.size else 0)
                raise InputError(
                    f"{path}, line {at}: a line longer than {_bytes(MAX_LINE_BYTES)}, the most "
                    "carfeel reads: not a log's CSV (its lines are a few hundred bytes); is it "
                    "the right file?"
                )
            since = len(block) - int(ends[-1]) - 1 if ends.size else since + len(block)
            lines += int(ends.size)
            if lines > MAX_SAMPLES + 2:
                raise _too_many(path, "has", f"over {MAX_SAMPLES + 2:,} lines", MAX_SAMPLES)
        try:
            decoder.decode(b"", final=True)
        except UnicodeDecodeError:
            raise InputError(
                f"{path}, line {lines + 1}: the file ends inside a character: not UTF-8 text (cut "
                "short?); save the file as CSV UTF-8"
            ) from None
    return lines + (1 if since > 0 else 0)


# --- reading signals ---------------------------------------------------------------------------


def list_signals(
    path: Path, dbc: Path | None = None, wanted: set[str] | None = None,
    time_entry: MapEntry | None = None,
) -> list[Signal]:  # fmt: skip
    """The signals a file holds, each with its own time stamps (s) and unit. A CSV's or Parquet
    file's time column is `time_entry`'s signal (a channel map's time_s, with its unit, scale
    and offset), else the first of TIME_NAMES. With `wanted`, only those signals are read (the
    others are not allocated)."""
    kind = kind_of(path)
    check_size(path)
    if kind == "csv":
        return _csv(path, time_entry, wanted)
    if kind == "parquet":
        return _parquet(path, time_entry, wanted)
    if kind == "mdf":
        return _mdf(path, wanted)
    if dbc is None:
        raise InputError(f"{path}: a CAN log needs its DBC to be decoded: add --dbc FILE.dbc")
    return _can(path, dbc, wanted)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _unit_of(cell: str) -> str | None:
    """A units row's cell as a unit name (brackets and blanks dropped; "" for none), or None if
    it is not a unit carfeel knows."""
    text = cell.strip().strip("[]()").strip()
    if text in ("", "-"):
        return ""
    return text if _si(text) is not None else None


def _units_row(row: Sequence[str]) -> list[str] | None:
    """The row under a header as units, if it is one: no cell a number, and most of its
    non-empty cells units carfeel knows (a logger's '[km/h]' or '(deg)' too)."""
    if not row or any(_is_number(c) for c in row if c.strip()):
        return None
    units = [_unit_of(c) for c in row]
    named = [u for u, c in zip(units, row, strict=True) if c.strip() not in ("", "-")]
    known = [u for u in named if u]
    if not known or len(known) < 0.5 * len(named):
        return None
    return [u or "" for u in units]


def _time_name(
    path: Path, names: Sequence[str], time_entry: MapEntry | None,
    units: Sequence[str] | None = None,
) -> str:  # fmt: skip
    """The time column: the map's, else the first of TIME_NAMES, else the one column a units
    row gives a unit of time."""
    if time_entry is not None:
        wanted = time_entry.terms[0].signal
        if wanted not in names:
            raise InputError(
                f"{path}: no column {shown(wanted)} (the map's time_s){_close(wanted, names)}"
            )
        return wanted
    found = next((n for n in TIME_NAMES if n in names), None)
    timed = [n for n, u in zip(names, units or [], strict=False) if u and _si(u) == "s"]
    if found is None and len(timed) == 1:
        found = timed[0]
    if found is None:
        separator = next((s for s in (";", "\t") if len(names) == 1 and s in names[0]), None)
        if separator is not None:
            raise InputError(
                f"{path}: the header is one field holding {separator!r}: carfeel reads "
                "comma-separated CSV; save the file with ',' between fields and '.' as the "
                "decimal point"
            )
        listed = ", ".join(shown(h).strip("'") for h in names[:20])
        raise InputError(
            f"{path}: no time column ({', '.join(TIME_NAMES)}) among {listed}: name yours in "
            'the channel map (time_s = { signal = "Zeit", unit = "ms" })'
        )
    return found


def _to_seconds(
    path: Path, name: str, time: FloatArray, file_unit: str, time_entry: MapEntry | None
) -> FloatArray:
    """A numeric time column in seconds: (raw * scale + offset) * unit, with the map's time_s
    entry (its unit defaulting to the file's) or the file's unit (default s)."""
    unit = (time_entry.unit if time_entry is not None else None) or file_unit or "s"
    if _si(unit) != "s":
        raise InputError(
            f"{path}: the time column {shown(name)} has unit {shown(unit)}, not a unit of time "
            "(s, ms, us)"
        )
    scale, offset = (time_entry.scale, time_entry.offset) if time_entry else (1.0, 0.0)
    return np.asarray((time * scale + offset) * _factor(unit), dtype=float)


def _seconds(cells: Sequence[str], where: str, name: str) -> tuple[FloatArray, str]:
    """Date-times (ISO 8601: '2024-05-01T12:00:00.125', a space for the T, Z or +02:00 for a
    zone) as seconds from the first, and that first one as text."""
    try:
        first = datetime.datetime.fromisoformat(cells[0])
    except ValueError:
        raise InputError(
            f"{where}: the time column {shown(name)} holds {shown(cells[0])}: neither a number "
            "nor an ISO 8601 date-time (2024-05-01T12:00:00.125); give seconds, or name the time "
            'column and its unit in a channel map (time_s = { signal = "t", unit = "ms" })'
        ) from None
    seconds = np.empty(len(cells))
    for i, cell in enumerate(cells):
        try:
            seconds[i] = (datetime.datetime.fromisoformat(cell) - first).total_seconds()
        except (ValueError, TypeError):
            raise InputError(
                f"{where}, sample {i + 1}: the time column {shown(name)} holds {shown(cell)}, "
                f"not a date-time like the first ({cells[0][:40]}; one zone for all, or none)"
            ) from None
    return seconds, first.isoformat()


def _csv(
    path: Path, time_entry: MapEntry | None = None, wanted: set[str] | None = None,
    own_names: bool = False,
) -> list[Signal]:  # fmt: skip
    """A CSV's numeric columns as signals (the time column numbers or ISO date-times; a units
    row under the header gives the units), read row by row into arrays sized by `_scan_csv`.
    With `wanted` only those columns, with `own_names` carfeel's (OWN_NAMES); a cell of a
    column read that is not a number is named with its line (an empty one is NaN)."""
    lines = _scan_csv(path)
    with path.open(encoding="utf-8-sig", newline="") as handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if not header:
            raise InputError(f"{path}: no samples (a header row, then one row per sample)")
        doubled = sorted({name for name in header if header.count(name) > 1})
        if doubled:
            raise InputError(
                f"{path}: column(s) {', '.join(d[:MAX_NAME_SHOWN] for d in doubled[:5])} appear "
                "more than once"
            )
        row = next(reader, None)
        units = _units_row(row) if row is not None and len(row) == len(header) else None
        line = 2
        if units is not None:
            row, line = next(reader, None), 3
        time_name = _time_name(path, header, time_entry, units)
        while row is not None and not row:  # blank lines before the first sample
            row, line = next(reader, None), line + 1
        if row is None:
            raise InputError(f"{path}: no samples (a header row, then one row per sample)")
        if len(row) != len(header):
            raise InputError(
                f"{path}, line {line}: {len(row)} field(s), the header has {len(header)}"
            )
        t_index = header.index(time_name)
        chosen = [
            i for i, name in enumerate(header)
            if i != t_index and (wanted is None or name in wanted)
            and (not own_names or name in OWN_NAMES)
        ]  # fmt: skip
        numeric = [i for i in chosen if row[i].strip() == "" or _is_number(row[i])]
        if wanted is not None or own_names:  # a column asked for must hold numbers
            for i in sorted(set(chosen) - set(numeric)):
                raise InputError(
                    f"{path}, line {line}: column {header[i][:MAX_NAME_SHOWN]} must hold numbers; "
                    f"it holds {shown(row[i])}"
                )
        rows = max(lines - line + 1, 1)
        if rows * (len(numeric) + 1) > MAX_VALUES:
            raise _too_many(path, "holds", f"{rows:,} rows x {len(numeric) + 1} columns",
                            MAX_VALUES)  # fmt: skip
        data = np.empty((rows, len(numeric)))
        numeric_time = _is_number(row[t_index])
        time_values = np.empty(rows if numeric_time else 0)
        time_cells: list[str] = []
        n = 0
        while row is not None:
            if row:  # a blank line is no sample
                if len(row) != len(header):
                    raise InputError(
                        f"{path}, line {line}: {len(row)} field(s), the header has {len(header)}"
                    )
                if n >= rows:
                    raise InputError(f"{path}: the file changed while it was read")
                for j, i in enumerate(numeric):
                    cell = row[i]
                    try:
                        data[n, j] = float(cell) if cell.strip() else math.nan
                    except ValueError:
                        raise InputError(
                            f"{path}, line {line}: column {header[i][:MAX_NAME_SHOWN]} must "
                            f"hold numbers; it holds {shown(cell)}"
                        ) from None
                if numeric_time:
                    try:
                        time_values[n] = float(row[t_index])
                    except ValueError:
                        raise InputError(
                            f"{path}, line {line}: the time column {shown(time_name)} holds "
                            f"{shown(row[t_index])}, not a number like the rows before"
                        ) from None
                else:
                    time_cells.append(row[t_index])
                n += 1
            row = next(reader, None)
            line += 1
    origin = None
    if numeric_time:
        file_unit = units[t_index] if units else ""
        time = _to_seconds(path, time_name, time_values[:n], file_unit, time_entry)
    else:
        time, origin = _seconds(time_cells, str(path), time_name)
    return [
        Signal(header[i], time, data[:n, j], units[i] if units else OWN_NAMES.get(header[i], ""),
               None, origin)
        for j, i in enumerate(numeric)
    ]  # fmt: skip


def _parquet(
    path: Path, time_entry: MapEntry | None = None, wanted: set[str] | None = None
) -> list[Signal]:
    """A Parquet file's numeric columns as signals, sized from its metadata before any is read;
    units from each field's `unit` metadata."""
    _lazy("parquet", path)
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        handle = pq.ParquetFile(path)
        schema = handle.schema_arrow
        rows = int(handle.metadata.num_rows)
    except Exception as exc:  # pyarrow raises its own errors for a broken file
        raise InputError(f"{path}: not a readable Parquet file ({str(exc)[:200]})") from None
    time_name = _time_name(path, list(schema.names), time_entry)
    numeric = (pa.types.is_integer, pa.types.is_floating, pa.types.is_boolean,
               pa.types.is_decimal)  # fmt: skip
    columns = [
        f.name for f in schema
        if f.name != time_name and (wanted is None or f.name in wanted)
        and any(test(f.type) for test in numeric)
    ]  # fmt: skip
    if rows > MAX_SAMPLES:
        raise _too_many(path, "has", f"{rows:,} rows", MAX_SAMPLES)
    if rows * (len(columns) + 1) > MAX_VALUES:
        raise _too_many(path, "holds", f"{rows:,} rows x {len(columns) + 1} columns", MAX_VALUES)
    time_field = schema.field(time_name)
    if pa.types.is_string(time_field.type) or pa.types.is_large_string(time_field.type):
        # Text time: sized before it is read (a 50 MB cell came back whole in the message).
        index = list(schema.names).index(time_name)
        size = sum(
            handle.metadata.row_group(g).column(index).total_uncompressed_size
            for g in range(handle.metadata.num_row_groups)
        )
        if size > 64 * rows + (1 << 16):
            raise InputError(
                f"{path}: the time column {shown(time_name)} holds text of {size // max(rows, 1):,}"
                " bytes a sample: neither numbers nor ISO 8601 date-times; give seconds or "
                "timestamps"
            )
    try:
        table = handle.read(columns=[time_name, *columns])
    except Exception as exc:
        raise InputError(f"{path}: not a readable Parquet file ({str(exc)[:200]})") from None
    meta = time_field.metadata or {}
    file_unit = meta.get(b"unit", b"").decode("utf-8", "replace")[:40]
    time, origin = _arrow_time(path, table.column(time_name), time_name, file_unit, time_entry)
    signals = []
    for field in table.schema:
        if field.name == time_name:
            continue
        meta = field.metadata or {}
        unit = meta.get(b"unit", b"").decode("utf-8", "replace")[:40]
        values = np.asarray(table.column(field.name).to_numpy(zero_copy_only=False), dtype=float)
        signals.append(
            Signal(field.name, time, values, unit or OWN_NAMES.get(field.name, ""), None, origin)
        )
    return signals


def _arrow_time(
    path: Path, column: Any, name: str, file_unit: str, time_entry: MapEntry | None
) -> tuple[FloatArray, str | None]:
    """A Parquet time column as seconds, and the date-time of its first sample where it holds
    date-times: numbers through `_to_seconds`; timestamps and durations (what pandas and Spark
    write) and dates from their integer counts; ISO 8601 text parsed."""
    import pyarrow as pa

    kind = column.type
    if any(test(kind) for test in (pa.types.is_integer, pa.types.is_floating,
                                   pa.types.is_decimal)):  # fmt: skip
        raw = np.asarray(column.to_numpy(zero_copy_only=False), dtype=float)
        return _to_seconds(path, name, raw, file_unit, time_entry), None
    if column.null_count:
        raise InputError(f"{path}: the time column {shown(name)} has {column.null_count} empty "
                         "value(s); every sample needs its time")  # fmt: skip
    if len(column) == 0:
        return np.zeros(0), None
    if pa.types.is_timestamp(kind) or pa.types.is_duration(kind) or pa.types.is_time(kind):
        per_second = {"s": 1.0, "ms": 1e3, "us": 1e6, "ns": 1e9}[kind.unit]
        counts = np.asarray(column.cast(pa.int64()).to_numpy(), dtype=np.int64)
        seconds = (counts - counts[0]).astype(float) / per_second
        origin = None
        if pa.types.is_timestamp(kind):
            origin = str(np.datetime64(int(counts[0]), kind.unit)) + (f" {kind.tz}" if kind.tz
                                                                      else "")  # fmt: skip
        return seconds, origin
    if pa.types.is_date(kind):
        days = np.asarray(column.cast(pa.date32()).cast(pa.int32()).to_numpy(), dtype=float)
        return (days - days[0]) * 86400.0, None
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        return _seconds(column.to_pylist(), str(path), name)
    raise InputError(
        f"{path}: the time column {shown(name)} is of type {str(kind)[:60]}: give seconds "
        "(numbers) or timestamps"
    )


def _mdf(path: Path, wanted: set[str] | None = None) -> list[Signal]:
    _lazy("mdf", path)
    from asammdf import MDF

    try:
        mdf = MDF(str(path))
    except Exception as exc:  # asammdf raises many kinds for a broken file
        raise InputError(f"{path}: not a readable MDF file ({str(exc)[:200]})") from None
    signals = []
    try:
        masters = {(g, i) for g, i in mdf.masters_db.items()}
        chosen = [
            (name, g, i) for name, places in mdf.channels_db.items()
            for g, i in places if (g, i) not in masters and (wanted is None or name in wanted)
        ]  # fmt: skip
        total = 0
        for _, g, _ in chosen:
            cycles = int(mdf.groups[g].channel_group.cycles_nr)
            if cycles > MAX_SAMPLES:
                raise _too_many(path, "has", f"{cycles:,} samples in channel group {g}",
                                MAX_SAMPLES)  # fmt: skip
            total += 2 * cycles
        if total > MAX_VALUES:
            raise _too_many(path, "holds", f"{total:,} values in the channels read", MAX_VALUES)
        for name, g, i in chosen:
            try:
                signal = mdf.get(name, group=g, index=i)
            except Exception:  # a channel asammdf cannot give as numbers: not a signal
                continue
            samples = np.asarray(signal.samples)
            if samples.dtype.kind not in "fiub" or samples.ndim != 1:
                continue
            signals.append(
                Signal(name, np.asarray(signal.timestamps, dtype=float),
                       samples.astype(float), str(signal.unit or "")[:40], g)
            )  # fmt: skip
    finally:
        mdf.close()
    return signals


def _can(path: Path, dbc: Path, wanted: set[str] | None) -> list[Signal]:
    can = _lazy("can", path)
    try:
        import cantools
    except ImportError:
        raise InputError(
            f"{path}: decoding a CAN log needs the optional extra: pip install 'carfeel[logs]'"
        ) from None
    try:
        size = dbc.stat().st_size
    except FileNotFoundError:
        raise InputError(f"--dbc {dbc}: no such file") from None
    if size > MAX_DBC_BYTES:
        raise InputError(f"--dbc {dbc}: {size:,} bytes, beyond the {_bytes(MAX_DBC_BYTES)} a "
                         "DBC may have: is it the right file?")  # fmt: skip
    try:
        db = cantools.database.load_file(str(dbc), strict=False)
    except FileNotFoundError:
        raise InputError(f"--dbc {dbc}: no such file") from None
    except RecursionError:
        raise InputError(f"--dbc {dbc}: not a readable DBC file (nested too deep)") from None
    except Exception as exc:  # cantools raises its own parse errors
        raise InputError(f"--dbc {dbc}: not a readable DBC file ({str(exc)[:200]})") from None
    messages = {m.frame_id: m for m in getattr(db, "messages", [])}
    if wanted is not None:
        names = {w.split(".", 1)[0] for w in wanted}
        messages = {i: m for i, m in messages.items() if m.name in names}
    for message in messages.values():  # checked before a frame is decoded
        for s in message.signals:
            scale, offset = float(s.scale), float(s.offset)
            if wanted is not None and f"{message.name}.{s.name}" not in wanted:
                continue
            if not all(math.isfinite(v) and abs(v) <= MAX_RAW_VALUE for v in (scale, offset)):
                raise InputError(
                    f"--dbc {dbc}: {message.name}.{s.name} has scale {scale:g} and offset "
                    f"{offset:g}: its values would reach beyond anything a sensor gives (1e15) "
                    "or overflow; fix the DBC's factor and offset"
                )
    times: dict[str, array[float]] = {}
    values: dict[str, array[float]] = {}
    frames = matched = 0
    try:
        for frame in can.LogReader(str(path)):
            frames += 1
            if frames > MAX_CAN_FRAMES:
                raise _too_many(path, "has", f"over {MAX_CAN_FRAMES:,} frames", MAX_CAN_FRAMES)
            message = messages.get(frame.arbitration_id)
            if message is None:
                continue
            try:
                decoded = message.decode(bytes(frame.data), decode_choices=False)
            except Exception:  # a frame the DBC cannot decode (short, wrong multiplex): skip
                continue
            matched += 1
            for name, value in dict(decoded).items():
                key = f"{message.name}.{name}"
                if key not in times:
                    times[key], values[key] = array("d"), array("d")
                times[key].append(float(frame.timestamp))
                values[key].append(float(value))
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"{path}: not a readable CAN log ({str(exc)[:200]})") from None
    if frames == 0:
        raise InputError(f"{path}: no CAN frames found (candump -l .log, Vector .asc or .blf)")
    if matched == 0:
        raise InputError(
            f"{path}: none of its {frames} frames decodes with {dbc}: is it the DBC of this car "
            "and bus?"
        )
    units = {f"{m.name}.{s.name}": s.unit or "" for m in messages.values() for s in m.signals}
    return [
        Signal(k, np.frombuffer(times[k], dtype=float), np.frombuffer(values[k], dtype=float),
               units.get(k, ""))
        for k in times
    ]  # fmt: skip


# --- into carfeel's channels -------------------------------------------------------------------


def read_channels(
    path: Path, channel_map: ChannelMap | None = None, dbc: Path | None = None
) -> Result:
    """A log as a Result of carfeel's channels in SI units, on one time base (and, where its
    time column held date-times, the first one as `time_origin` in the metadata)."""
    kind = kind_of(path)
    if channel_map is None:
        if kind == "csv":
            check_size(path)
            signals = _csv(path, own_names=True)
        else:
            signals = list_signals(path, dbc, set(OWN_NAMES) if kind != "can" else None)
        own = {s.name: s for s in signals if s.name in OWN_NAMES and s.name != "time_s"}
        if not own:
            raise InputError(
                f"{path}: no channel carries carfeel's names ({', '.join(CHANNELS)}): give a "
                "channel map with --channels MAP.toml (list the file's signals with "
                f"carfeel channels {path})"
            )
        for s in own.values():  # a units row may not contradict a name's unit
            if s.unit and (_si(s.unit) != OWN_NAMES[s.name] or _factor(s.unit) != 1.0):
                raise InputError(
                    f"{path}: column {s.name} is in {OWN_NAMES[s.name]} by its name but in "
                    f"{shown(s.unit)} by the units row: convert the column, or rename it and map "
                    "it with --channels MAP.toml (unit = ...)"
                )
        channel_map = ChannelMap({n: MapEntry((Term(n),), OWN_NAMES[n], 1.0, 0.0) for n in own})
        time_entry = None
    else:
        wanted = {t.signal for e in channel_map.channels.values() for t in e.terms}
        time_entry = channel_map.channels.get("time_s")
        in_file = kind in ("csv", "parquet")  # the time column itself; else a signal of times
        signals = list_signals(path, dbc, wanted, time_entry if in_file else None)
        if in_file:
            time_entry = None
    by_name: dict[str, list[Signal]] = {}
    for s in signals:
        by_name.setdefault(s.name, []).append(s)
    converted: dict[str, tuple[FloatArray, FloatArray]] = {}
    origin = None
    for name, entry in channel_map.channels.items():
        if name == "time_s":
            continue
        time, raw, file_unit, first = _summed(path, name, entry, by_name)
        origin = origin or first.time_origin
        unit = entry.unit if entry.unit is not None else file_unit
        if (_si(unit) if unit else None) != OWN_NAMES[name]:
            raise InputError(
                f"{path}: {shown(entry.signal)} for {name} has unit {shown(unit or 'none')}: set "
                f"unit (and scale for raw counts) in the channel map, a unit of "
                f"{OWN_NAMES[name]}"
            )
        if time_entry is not None:  # MDF, CAN: time_s names a signal holding the times
            base = _one(path, "time_s", time_entry.terms[0], by_name)
            if len(base.values) != len(raw):
                raise InputError(f"{path}: no time signal {shown(time_entry.signal)} beside {name}")
            time = _to_seconds(path, base.name, base.values, base.unit, time_entry)
        values = (raw * entry.scale + entry.offset) * _factor(unit)
        converted[name] = (np.asarray(time, dtype=float), np.asarray(values, dtype=float))
    result = _common_time(path, converted, channel_map.rate_hz)
    if origin is not None:
        result = Result(result.time_s, result.signals, {**result.metadata, "time_origin": origin})
    return result


def _one(path: Path, name: str, term: Term, by_name: Mapping[str, list[Signal]]) -> Signal:
    found = by_name.get(term.signal, [])
    if term.group is not None:
        found = [s for s in found if s.group == term.group]
        if not found:
            held = sorted({s.group for s in by_name.get(term.signal, []) if s.group is not None})
            where = f"; it is in group(s) {', '.join(map(str, held))}" if held else ""
            raise InputError(
                f"{path}: no signal {shown(term.signal)} in channel group {term.group} (for "
                f"{name}){where or _close(term.signal, by_name)}; list them with: carfeel "
                f"channels {path}"
            )
    if not found:
        raise InputError(
            f"{path}: no signal {shown(term.signal)} (for {name}){_close(term.signal, by_name)}; "
            f"list them with: carfeel channels {path}"
        )
    if len(found) > 1:
        listed = ", ".join(str(s.group) for s in found)
        raise InputError(
            f"{path}: {len(found)} signals are named {shown(term.signal)} (channel groups "
            f"{listed}): say which one {name} is with group = N in the channel map"
        )
    return found[0]


def _summed(
    path: Path, name: str, entry: MapEntry, by_name: Mapping[str, list[Signal]]
) -> tuple[FloatArray, FloatArray, str, Signal]:
    """(time, raw value, unit) of an entry: its signal, or the sum of its terms on the first
    term's time stamps (interpolated where a term has its own); the terms share one unit."""
    first = _one(path, name, entry.terms[0], by_name)
    time, total = first.time_s, entry.terms[0].scale * first.values
    for term in entry.terms[1:]:
        other = _one(path, name, term, by_name)
        if other.unit != first.unit and entry.unit is None:
            raise InputError(
                f"{path}: {name} sums {shown(first.name)} ({first.unit or 'no unit'}) and "
                f"{shown(other.name)} ({other.unit or 'no unit'}): give the terms one unit "
                "(scale a term to it) and unit = ... in the map"
            )
        if len(other.time_s) == len(time) and np.array_equal(other.time_s, time):
            total = total + term.scale * other.values
        else:
            if len(other.time_s) < 2 or np.any(np.diff(other.time_s) <= 0):
                raise InputError(f"{path}: {other.name}: time stamps do not increase")
            total = total + term.scale * np.interp(time, other.time_s, other.values)
    return time, total, first.unit, first


def _common_time(
    path: Path, converted: Mapping[str, tuple[FloatArray, FloatArray]], rate_hz: float | None
) -> Result:
    """All channels on one uniform time base over the span they share, by linear interpolation
    (channels that share their time stamps are kept as they are)."""
    stamps = [t for t, _ in converted.values()]
    if all(len(t) == len(stamps[0]) and np.array_equal(t, stamps[0]) for t in stamps):
        # One time base already (a CSV, a Parquet table): its checks are the fits' (with lines).
        time = stamps[0]
        return Result(time - time[0] if len(time) and time[0] > 1e6 else time,
                      {n: v for n, (_, v) in converted.items()})  # fmt: skip
    for name, (t, _) in converted.items():
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            raise InputError(f"{path}: {name}: time stamps do not increase")
    start = max(float(t[0]) for t in stamps)
    end = min(float(t[-1]) for t in stamps)
    if not end > start:
        raise InputError(f"{path}: the mapped channels do not overlap in time")
    for name, (t, _) in converted.items():
        inside = t[(t >= start) & (t <= end)]
        steps = np.diff(inside)
        if len(steps) == 0:
            continue
        allowed = max(MAX_GAP_S, MAX_GAP_PERIODS * float(np.median(steps)))
        if steps.max() > allowed:
            k = int(np.argmax(steps))
            raise InputError(
                f"{path}: {name} has no sample for {steps[k]:.3g} s from t = "
                f"{inside[k] - start:.3f} s (its period is {np.median(steps):.3g} s): bridging "
                "that would invent data; cut the log at the gap (one file each side)"
            )
    if rate_hz is None:
        lead = next((converted[n] for n in ("steering_torque_Nm", "torque_Nm", "force_N")
                     if n in converted), None)  # fmt: skip
        periods = [float(np.median(np.diff(t))) for t in ([lead[0]] if lead else stamps)]
        rate_hz = 1.0 / min(periods)
    samples = (end - start) * rate_hz
    if samples > MAX_SAMPLES:
        raise _too_many(path, "would have", f"{samples:,.0f} samples at {rate_hz:g} Hz",
                        MAX_SAMPLES)  # fmt: skip
    time = np.arange(start, end, 1.0 / rate_hz)
    signals = {n: np.interp(time, t, v) for n, (t, v) in converted.items()}
    return Result(time - start, signals, {"time_origin_s": f"{start:.6f}"})


def describe(path: Path, dbc: Path | None = None) -> list[dict[str, Any]]:
    """What `carfeel channels` prints: per signal its unit, samples, rate and range (and its
    MDF channel group, where two signals share a name)."""
    rows = []
    signals = list_signals(path, dbc)
    named: dict[str, int] = {}
    for s in signals:
        named[s.name] = named.get(s.name, 0) + 1
    for s in signals:
        steps = np.diff(s.time_s)
        rate = 1.0 / float(np.median(steps)) if len(steps) and np.median(steps) > 0 else math.nan
        finite = s.values[np.isfinite(s.values)]
        row = {
            "signal": s.name, "unit": s.unit, "samples": len(s.values), "rate_hz": rate,
            "min": float(finite.min()) if finite.size else math.nan,
            "max": float(finite.max()) if finite.size else math.nan,
        }  # fmt: skip
        if s.group is not None:
            row["group"] = s.group
        rows.append(row)
    return rows
