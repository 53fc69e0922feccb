"""A log's signals as every format reader gives them (`Signal`: its own time stamps in s, its
values in the file's unit), which reader a file takes, and its time column in seconds."""

from __future__ import annotations

import datetime
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.io.log_channels import MapEntry
from carfeel.io.log_limits import close, shown
from carfeel.io.log_units import si_factor, si_unit

FloatArray = npt.NDArray[np.float64]

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


def kind_of(path: Path) -> str:
    """The reader a log takes by its suffix: 'csv', 'parquet', 'mdf' or 'can'."""
    kind = SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise InputError(
            f"{path}: unknown log format {shown(path.suffix)}; carfeel reads "
            f"{', '.join(sorted(SUFFIXES))}"
        )
    return kind


def lazy_extra(kind: str, path: Path) -> Any:
    """The module a `kind` of log is read with, or an error naming the extra carfeel[logs]."""
    module, what = _EXTRA[kind]
    try:
        return __import__(module)
    except ImportError:
        raise InputError(
            f"{path}: reading a {what} file needs the optional extra: pip install 'carfeel[logs]'"
        ) from None


def time_column(
    path: Path, names: Sequence[str], time_entry: MapEntry | None,
    units: Sequence[str] | None = None,
) -> str:  # fmt: skip
    """The time column: the map's, else the first of TIME_NAMES, else the one column a units
    row gives a unit of time."""
    if time_entry is not None:
        wanted = time_entry.terms[0].signal
        if wanted not in names:
            raise InputError(
                f"{path}: no column {shown(wanted)} (the map's time_s){close(wanted, names)}"
            )
        return wanted
    found = next((n for n in TIME_NAMES if n in names), None)
    timed = [n for n, u in zip(names, units or [], strict=False) if u and si_unit(u) == "s"]
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


def to_seconds(
    path: Path, name: str, time: FloatArray, file_unit: str, time_entry: MapEntry | None
) -> FloatArray:
    """A numeric time column in seconds: (raw * scale + offset) * unit, with the map's time_s
    entry (its unit defaulting to the file's) or the file's unit (default s)."""
    unit = (time_entry.unit if time_entry is not None else None) or file_unit or "s"
    if si_unit(unit) != "s":
        raise InputError(
            f"{path}: the time column {shown(name)} has unit {shown(unit)}, not a unit of time "
            "(s, ms, us)"
        )
    scale, offset = (time_entry.scale, time_entry.offset) if time_entry else (1.0, 0.0)
    return np.asarray((time * scale + offset) * si_factor(unit), dtype=float)


def iso_seconds(cells: Sequence[str], where: str, name: str) -> tuple[FloatArray, str]:
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
