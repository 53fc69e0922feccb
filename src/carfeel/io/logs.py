"""Measured logs in the formats car engineers have, read into carfeel's channels.

Every format goes through `read_channels`: the file's signals (each with its own time stamps and,
where the format carries it, its unit), a channel map saying which signal is which of carfeel's
channels with its unit and scale, then one common time base and SI units. The unit and sign checks
of the fits (`steering_fit.read_log`, `shift_fit.checked_columns`) run on what comes out, whatever
the format.

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
    steering_angle_rad = { signal = "STEER_ANGLE_SENSOR.STEER_ANGLE", unit = "deg" }
    [channels.steering_torque_Nm]
    signal = "STEER_TORQUE_SENSOR.STEER_TORQUE_DRIVER"
    unit = "Nm"
    scale = 0.01             # raw counts -> Nm

value in SI = (raw * scale + offset) * (the unit's factor to SI); `unit` defaults to the unit the
file gives the signal. A negative scale flips a sign convention. CAN signals are named
MESSAGE.SIGNAL. A file whose columns already carry carfeel's names needs no map.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Iterable, Mapping
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


@dataclass(frozen=True)
class Signal:
    """One signal of a file, in the file's own units."""

    name: str
    time_s: FloatArray
    values: FloatArray
    unit: str


@dataclass(frozen=True)
class MapEntry:
    signal: str
    unit: str | None
    scale: float
    offset: float


@dataclass(frozen=True)
class ChannelMap:
    channels: Mapping[str, MapEntry]
    rate_hz: float | None = None


def _lazy(kind: str, path: Path) -> Any:
    module, what = _EXTRA[kind]
    try:
        return __import__(module)
    except ImportError:
        raise InputError(
            f"{path}: reading a {what} file needs the optional extra: pip install 'carfeel[logs]'"
        ) from None


def load_map(path: Path) -> ChannelMap:
    """Read and check a channel map (module docstring)."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"--channels {path}: no such file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"--channels {path}: not valid TOML ({exc})") from None
    unknown = sorted(set(data) - {"channels", "resample"})
    if unknown:
        raise InputError(
            f"--channels {path}: unknown table(s) {', '.join(unknown)}; a channel map has "
            "[channels] and optionally [resample]"
        )
    table = data.get("channels")
    if not isinstance(table, dict) or not table:
        raise InputError(f"--channels {path}: no [channels] table (see README, 'Channel maps')")
    entries = {}
    for name, entry in table.items():
        if name not in CHANNELS:
            raise InputError(
                f"--channels {path}: unknown channel {name!r}{_close(name, CHANNELS)}; carfeel's "
                f"channels are {', '.join(CHANNELS)}"
            )
        if isinstance(entry, str):
            entry = {"signal": entry}
        if not isinstance(entry, dict) or not isinstance(entry.get("signal"), str):
            raise InputError(
                f'--channels {path}: {name} needs signal = "NAME" (and optionally unit, scale, '
                "offset)"
            )
        extra = sorted(set(entry) - {"signal", "unit", "scale", "offset"})
        if extra:
            raise InputError(
                f"--channels {path}: {name}: unknown key(s) {', '.join(extra)}; allowed: signal, "
                "unit, scale, offset"
            )
        unit = entry.get("unit")
        if unit is not None and _si(str(unit)) != CHANNELS[name]:
            raise InputError(
                f"--channels {path}: {name}: unit {unit!r} is not a unit of {CHANNELS[name]}; "
                f"known: {', '.join(u for u, (si, _) in UNITS.items() if si == CHANNELS[name])}"
            )
        numbers = {}
        for key, default in (("scale", 1.0), ("offset", 0.0)):
            value = entry.get(key, default)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise InputError(f"--channels {path}: {name}: {key} must be a number")
            numbers[key] = float(value)
        if numbers["scale"] == 0.0:
            raise InputError(f"--channels {path}: {name}: scale must not be 0")
        entries[name] = MapEntry(entry["signal"], unit, numbers["scale"], numbers["offset"])
    resample = data.get("resample", {})
    if not isinstance(resample, dict):
        raise InputError(f"--channels {path}: [resample] must be a table (rate_hz = 50.0)")
    if set(resample) - {"rate_hz"}:
        raise InputError(
            f"--channels {path}: [resample] {', '.join(sorted(set(resample) - {'rate_hz'}))}: "
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
            f"--channels {path}: [resample] rate_hz = {f'{rate:g}' if number else repr(rate)}: "
            f"expected a number of Hz, {MIN_RESAMPLE_HZ:g} <= rate_hz <= {MAX_RESAMPLE_HZ:g}"
        )
    return ChannelMap(entries, None if rate is None else float(rate))


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


def _close(name: str, known: Iterable[str]) -> str:
    match = difflib.get_close_matches(name, list(known), n=1)
    return f" (did you mean {match[0]!r}?)" if match else ""


def kind_of(path: Path) -> str:
    kind = SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise InputError(
            f"{path}: unknown log format {path.suffix!r}; carfeel reads "
            f"{', '.join(sorted(SUFFIXES))}"
        )
    return kind


def list_signals(
    path: Path, dbc: Path | None = None, wanted: set[str] | None = None,
    time_column: str | None = None,
) -> list[Signal]:  # fmt: skip
    """The signals a file holds, each with its own time stamps and unit (a CSV's time column:
    `time_column`, as a channel map names it, else the first of TIME_NAMES)."""
    kind = kind_of(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if kind == "csv":
        return _csv(path, time_column)
    if kind == "parquet":
        return _parquet(path)
    if kind == "mdf":
        return _mdf(path)
    if dbc is None:
        raise InputError(f"{path}: a CAN log needs its DBC to be decoded: add --dbc FILE.dbc")
    return _can(path, dbc, wanted)


TIME_NAMES = ("time_s", "time", "timestamp", "t", "Time")


def _csv(path: Path, time_column: str | None = None) -> list[Signal]:
    import csv
    import io

    from carfeel.simulation.result import read_csv_text

    rows = list(csv.reader(io.StringIO(read_csv_text(path), newline="")))
    if len(rows) < 2:
        raise InputError(f"{path}: no samples (a header row, then one row per sample)")
    header, body = rows[0], rows[1:]
    if time_column is not None and time_column not in header:
        raise InputError(
            f"{path}: no column {time_column!r} (the map's time_s){_close(time_column, header)}"
        )
    time_name = time_column or next((n for n in TIME_NAMES if n in header), None)
    if time_name is None:
        raise InputError(
            f"{path}: no time column ({', '.join(TIME_NAMES)}) among {header}: name yours in "
            'the channel map (time_s = { signal = "Zeit", unit = "ms" })'
        )
    columns = {}
    for i, name in enumerate(header):
        try:
            columns[name] = np.array([float(r[i]) for r in body])
        except (ValueError, IndexError):
            continue  # text columns are not signals
    time = columns[time_name] if time_column else columns.pop(time_name)
    return [Signal(n, time, v, CHANNELS.get(n, "")) for n, v in columns.items()]


def _parquet(path: Path) -> list[Signal]:
    _lazy("parquet", path)
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises its own errors for a broken file
        raise InputError(f"{path}: not a readable Parquet file ({exc})") from None
    names = table.column_names
    time_name = next((n for n in TIME_NAMES if n in names), None)
    if time_name is None:
        raise InputError(f"{path}: no time column ({', '.join(TIME_NAMES)}) among {names}")
    time = np.asarray(table.column(time_name).to_numpy(), dtype=float)
    signals = []
    for field in table.schema:
        if field.name == time_name:
            continue
        meta = field.metadata or {}
        unit = meta.get(b"unit", b"").decode() or CHANNELS.get(field.name, "")
        try:
            values = np.asarray(
                table.column(field.name).to_numpy(zero_copy_only=False), dtype=float
            )
        except (TypeError, ValueError):
            continue  # text columns (a stage, a gear name) are not signals
        signals.append(Signal(field.name, time, values, unit))
    return signals


def _mdf(path: Path) -> list[Signal]:
    _lazy("mdf", path)
    from asammdf import MDF

    try:
        mdf = MDF(str(path))
    except Exception as exc:  # asammdf raises many kinds for a broken file
        raise InputError(f"{path}: not a readable MDF file ({exc})") from None
    signals = []
    try:
        for signal in mdf.iter_channels():
            if signal.samples.dtype.kind not in "fiub" or signal.samples.ndim != 1:
                continue
            signals.append(
                Signal(signal.name, np.asarray(signal.timestamps, dtype=float),
                       np.asarray(signal.samples, dtype=float), str(signal.unit or ""))
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
        db = cantools.database.load_file(str(dbc), strict=False)
    except FileNotFoundError:
        raise InputError(f"--dbc {dbc}: no such file") from None
    except Exception as exc:  # cantools raises its own parse errors
        raise InputError(f"--dbc {dbc}: not a readable DBC file ({exc})") from None
    messages = {m.frame_id: m for m in getattr(db, "messages", [])}
    if wanted is not None:
        names = {w.split(".", 1)[0] for w in wanted}
        messages = {i: m for i, m in messages.items() if m.name in names}
    times: dict[str, list[float]] = {}
    values: dict[str, list[float]] = {}
    frames = matched = 0
    try:
        for frame in can.LogReader(str(path)):
            frames += 1
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
                times.setdefault(key, []).append(float(frame.timestamp))
                values.setdefault(key, []).append(float(value))
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"{path}: not a readable CAN log ({exc})") from None
    if frames == 0:
        raise InputError(f"{path}: no CAN frames found (candump -l .log, Vector .asc or .blf)")
    if matched == 0:
        raise InputError(
            f"{path}: none of its {frames} frames decodes with {dbc}: is it the DBC of this car "
            "and bus?"
        )
    units = {f"{m.name}.{s.name}": s.unit or "" for m in messages.values() for s in m.signals}
    return [Signal(k, np.asarray(times[k]), np.asarray(values[k]), units.get(k, "")) for k in times]


def read_channels(
    path: Path, channel_map: ChannelMap | None = None, dbc: Path | None = None
) -> Result:
    """A log as a Result of carfeel's channels in SI units, on one time base."""
    kind = kind_of(path)
    if channel_map is None:
        if kind == "csv":
            return Result.from_csv(path)
        signals = list_signals(path, dbc)
        own = {s.name: s for s in signals if s.name in CHANNELS}
        if not own:
            raise InputError(
                f"{path}: no channel carries carfeel's names ({', '.join(CHANNELS)}): give a "
                "channel map with --channels MAP.toml (list the file's signals with "
                f"carfeel channels {path})"
            )
        entries = {n: MapEntry(n, CHANNELS[n], 1.0, 0.0) for n in own if n != "time_s"}
        channel_map = ChannelMap(entries)
    else:
        wanted = {e.signal for e in channel_map.channels.values()}
        named = channel_map.channels.get("time_s")
        signals = list_signals(
            path, dbc, wanted if kind == "can" else None, named.signal if named else None
        )
    by_name = {s.name: s for s in signals}
    converted: dict[str, tuple[FloatArray, FloatArray]] = {}
    time_entry = channel_map.channels.get("time_s")
    for name, entry in channel_map.channels.items():
        if name == "time_s":
            continue
        signal = by_name.get(entry.signal)
        if signal is None:
            raise InputError(
                f"{path}: no signal {entry.signal!r} (for {name}){_close(entry.signal, by_name)}; "
                f"list them with: carfeel channels {path}"
            )
        unit = entry.unit if entry.unit is not None else signal.unit
        si = _si(unit) if unit else None
        if si != CHANNELS[name]:
            raise InputError(
                f"{path}: {entry.signal} for {name} has unit {unit or 'none'!r}: set unit (and "
                f"scale for raw counts) in the channel map, a unit of {CHANNELS[name]}"
            )
        factor = UNITS.get(unit.strip().lower(), UNITS.get(unit.strip(), ("", 1.0)))[1]
        time = signal.time_s
        if time_entry is not None:
            base = by_name.get(time_entry.signal)
            if base is None or len(base.values) != len(signal.values):
                raise InputError(f"{path}: no time signal {time_entry.signal!r} beside {name}")
            t_unit = time_entry.unit or base.unit or "s"
            if _si(t_unit) != "s":
                raise InputError(f"{path}: time_s: unit {t_unit!r} is not a time unit")
            t_factor = UNITS[t_unit.strip().lower()][1]
            time = (base.values * time_entry.scale + time_entry.offset) * t_factor
        values = (signal.values * entry.scale + entry.offset) * factor
        converted[name] = (np.asarray(time, dtype=float), np.asarray(values, dtype=float))
    return _common_time(path, converted, channel_map.rate_hz)


def _common_time(
    path: Path, converted: Mapping[str, tuple[FloatArray, FloatArray]], rate_hz: float | None
) -> Result:
    """All channels on one uniform time base over the span they share, by linear interpolation
    (channels that share their time stamps are kept as they are)."""
    stamps = [t for t, _ in converted.values()]
    for name, (t, _) in converted.items():
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            raise InputError(f"{path}: {name}: time stamps do not increase")
    if all(len(t) == len(stamps[0]) and np.array_equal(t, stamps[0]) for t in stamps):
        time = stamps[0]
        return Result(time - time[0] if time[0] > 1e6 else time,
                      {n: v for n, (_, v) in converted.items()})  # fmt: skip
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
        lead = converted.get("steering_torque_Nm", converted.get("force_N"))
        periods = [float(np.median(np.diff(t))) for t in ([lead[0]] if lead else stamps)]
        rate_hz = 1.0 / min(periods)
    time = np.arange(start, end, 1.0 / rate_hz)
    signals = {n: np.interp(time, t, v) for n, (t, v) in converted.items()}
    return Result(time - start, signals, {"time_origin_s": f"{start:.6f}"})


def describe(path: Path, dbc: Path | None = None) -> list[dict[str, Any]]:
    """What `carfeel channels` prints: per signal its unit, samples, rate and range."""
    rows = []
    for s in list_signals(path, dbc):
        steps = np.diff(s.time_s)
        rate = 1.0 / float(np.median(steps)) if len(steps) and np.median(steps) > 0 else math.nan
        finite = s.values[np.isfinite(s.values)]
        rows.append({
            "signal": s.name, "unit": s.unit, "samples": len(s.values), "rate_hz": rate,
            "min": float(finite.min()) if finite.size else math.nan,
            "max": float(finite.max()) if finite.size else math.nan,
        })  # fmt: skip
    return rows
