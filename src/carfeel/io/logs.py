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
`MAX_MAP_BYTES`, `MAX_CAN_FRAMES` in `log_limits`): a file beyond them is refused with the limit
named.

This module is the entry (`load_map`, `check_size`, `list_signals`, `read_channels`, `describe`);
the parts are its siblings: `log_units` (carfeel's channels, unit names to SI), `log_channels`
(the channel map), `log_limits`, `log_signals` (`Signal`, the time column), one reader per format
(`log_csv`, `log_parquet`, `log_mdf`, `log_can`) and `log_timebase` (one time base).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.errors import InputError
from carfeel.io.log_can import read_can
from carfeel.io.log_channels import ChannelMap, MapEntry, Term, load_map
from carfeel.io.log_csv import read_csv, scan_csv
from carfeel.io.log_limits import close, shown
from carfeel.io.log_mdf import read_mdf
from carfeel.io.log_parquet import read_parquet
from carfeel.io.log_signals import TIME_NAMES, FloatArray, Signal, kind_of, to_seconds
from carfeel.io.log_timebase import common_time
from carfeel.io.log_units import CHANNELS, OWN_NAMES, UNITS, si_factor, si_unit
from carfeel.simulation.result import Result

__all__ = [
    "CHANNELS",
    "OWN_NAMES",
    "TIME_NAMES",
    "UNITS",
    "ChannelMap",
    "MapEntry",
    "Signal",
    "Term",
    "check_size",
    "describe",
    "kind_of",
    "list_signals",
    "load_map",
    "read_channels",
    "shown",
]


def check_size(path: Path) -> None:
    """Refuse a log too large to read before any of it is allocated: a CSV by a streaming scan
    of its lines (their length and count), the other formats by what their headers say."""
    kind = kind_of(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    if kind == "csv":
        scan_csv(path)


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
        return read_csv(path, time_entry, wanted)
    if kind == "parquet":
        return read_parquet(path, time_entry, wanted)
    if kind == "mdf":
        return read_mdf(path, wanted)
    if dbc is None:
        raise InputError(f"{path}: a CAN log needs its DBC to be decoded: add --dbc FILE.dbc")
    return read_can(path, dbc, wanted)


def read_channels(
    path: Path, channel_map: ChannelMap | None = None, dbc: Path | None = None
) -> Result:
    """A log as a Result of carfeel's channels in SI units, on one time base (and, where its
    time column held date-times, the first one as `time_origin` in the metadata)."""
    kind = kind_of(path)
    if channel_map is None:
        signals, channel_map = _own_names(path, kind, dbc)
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
    converted, origin = _converted(path, channel_map, time_entry, by_name)
    result = common_time(path, converted, channel_map.rate_hz)
    if origin is not None:
        result = Result(result.time_s, result.signals, {**result.metadata, "time_origin": origin})
    return result


def _own_names(path: Path, kind: str, dbc: Path | None) -> tuple[list[Signal], ChannelMap]:
    """A file without a map: its signals, and the map of those named as carfeel's channels
    (a units row may not contradict a name's unit)."""
    if kind == "csv":
        check_size(path)
        signals = read_csv(path, own_names=True)
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
        if s.unit and (si_unit(s.unit) != OWN_NAMES[s.name] or si_factor(s.unit) != 1.0):
            raise InputError(
                f"{path}: column {s.name} is in {OWN_NAMES[s.name]} by its name but in "
                f"{shown(s.unit)} by the units row: convert the column, or rename it and map "
                "it with --channels MAP.toml (unit = ...)"
            )
    channel_map = ChannelMap({n: MapEntry((Term(n),), OWN_NAMES[n], 1.0, 0.0) for n in own})
    return signals, channel_map


def _converted(
    path: Path, channel_map: ChannelMap, time_entry: MapEntry | None,
    by_name: Mapping[str, list[Signal]],
) -> tuple[dict[str, tuple[FloatArray, FloatArray]], str | None]:  # fmt: skip
    """Each mapped channel as (time in s, value in SI) on its own time stamps (`time_entry`:
    the signal of times an MDF or CAN map names), and the first date-time the file gives."""
    converted: dict[str, tuple[FloatArray, FloatArray]] = {}
    origin = None
    for name, entry in channel_map.channels.items():
        if name == "time_s":
            continue
        time, raw, file_unit, first = _summed(path, name, entry, by_name)
        origin = origin or first.time_origin
        unit = entry.unit if entry.unit is not None else file_unit
        if (si_unit(unit) if unit else None) != OWN_NAMES[name]:
            raise InputError(
                f"{path}: {shown(entry.signal)} for {name} has unit {shown(unit or 'none')}: set "
                f"unit (and scale for raw counts) in the channel map, a unit of "
                f"{OWN_NAMES[name]}"
            )
        if time_entry is not None:  # MDF, CAN: time_s names a signal holding the times
            base = _one(path, "time_s", time_entry.terms[0], by_name)
            if len(base.values) != len(raw):
                raise InputError(f"{path}: no time signal {shown(time_entry.signal)} beside {name}")
            time = to_seconds(path, base.name, base.values, base.unit, time_entry)
        values = (raw * entry.scale + entry.offset) * si_factor(unit)
        converted[name] = (np.asarray(time, dtype=float), np.asarray(values, dtype=float))
    return converted, origin


def _one(path: Path, name: str, term: Term, by_name: Mapping[str, list[Signal]]) -> Signal:
    found = by_name.get(term.signal, [])
    if term.group is not None:
        found = [s for s in found if s.group == term.group]
        if not found:
            held = sorted({s.group for s in by_name.get(term.signal, []) if s.group is not None})
            where = f"; it is in group(s) {', '.join(map(str, held))}" if held else ""
            raise InputError(
                f"{path}: no signal {shown(term.signal)} in channel group {term.group} (for "
                f"{name}){where or close(term.signal, by_name)}; list them with: carfeel "
                f"channels {path}"
            )
    if not found:
        raise InputError(
            f"{path}: no signal {shown(term.signal)} (for {name}){close(term.signal, by_name)}; "
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
