"""CSV logs, carfeel's own reader (no extra): a header, optionally a row of units under it, then
one row per sample; the time column numbers or ISO 8601 date-times. The file is scanned first
(UTF-8, line lengths and count) so that arrays are sized before a row is parsed."""

from __future__ import annotations

import codecs
import csv
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carfeel.errors import InputError
from carfeel.io import log_limits as limits
from carfeel.io.log_channels import MapEntry
from carfeel.io.log_limits import byte_size, shown, too_many
from carfeel.io.log_signals import FloatArray, Signal, iso_seconds, time_column, to_seconds
from carfeel.io.log_units import OWN_NAMES, si_unit


def scan_csv(path: Path) -> int:
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
            if longest > limits.MAX_LINE_BYTES:
                at = lines + 1 + (int(np.argmax(lengths)) if ends.size else 0)
                raise InputError(
                    f"{path}, line {at}: a line longer than {byte_size(limits.MAX_LINE_BYTES)}, "
                    "the most carfeel reads: not a log's CSV (its lines are a few hundred bytes); "
                    "is it the right file?"
                )
            since = len(block) - int(ends[-1]) - 1 if ends.size else since + len(block)
            lines += int(ends.size)
            if lines > limits.MAX_SAMPLES + 2:
                raise too_many(
                    path, "has", f"over {limits.MAX_SAMPLES + 2:,} lines", limits.MAX_SAMPLES
                )
        try:
            decoder.decode(b"", final=True)
        except UnicodeDecodeError:
            raise InputError(
                f"{path}, line {lines + 1}: the file ends inside a character: not UTF-8 text (cut "
                "short?); save the file as CSV UTF-8"
            ) from None
    return lines + (1 if since > 0 else 0)


@dataclass(frozen=True)
class _Columns:
    """The columns a CSV is read for: the header, the numeric ones read, the time column."""

    header: list[str]
    numeric: list[int]
    t_index: int
    time_name: str
    numeric_time: bool
    """The time column holds numbers (else ISO date-times)."""


def read_csv(
    path: Path, time_entry: MapEntry | None = None, wanted: set[str] | None = None,
    own_names: bool = False,
) -> list[Signal]:  # fmt: skip
    """A CSV's numeric columns as signals (the time column numbers or ISO date-times; a units
    row under the header gives the units), read row by row into arrays sized by `scan_csv`.
    With `wanted` only those columns, with `own_names` carfeel's (OWN_NAMES); a cell of a
    column read that is not a number is named with its line (an empty one is NaN)."""
    lines = scan_csv(path)
    with path.open(encoding="utf-8-sig", newline="") as handle:
        reader = csv.reader(handle)
        header = _header(path, reader)
        row = next(reader, None)
        units = _units_row(row) if row is not None and len(row) == len(header) else None
        line = 2
        if units is not None:
            row, line = next(reader, None), 3
        time_name = time_column(path, header, time_entry, units)
        while row is not None and not row:  # blank lines before the first sample
            row, line = next(reader, None), line + 1
        if row is None:
            raise InputError(f"{path}: no samples (a header row, then one row per sample)")
        if len(row) != len(header):
            raise InputError(
                f"{path}, line {line}: {len(row)} field(s), the header has {len(header)}"
            )
        t_index = header.index(time_name)
        numeric = _numeric(path, header, row, line, t_index, wanted, own_names)
        rows = max(lines - line + 1, 1)
        if rows * (len(numeric) + 1) > limits.MAX_VALUES:
            raise too_many(path, "holds", f"{rows:,} rows x {len(numeric) + 1} columns",
                           limits.MAX_VALUES)  # fmt: skip
        columns = _Columns(header, numeric, t_index, time_name, _is_number(row[t_index]))
        data, time_values, time_cells = _read_rows(path, reader, columns, row, line, rows)
    origin = None
    if columns.numeric_time:
        file_unit = units[t_index] if units else ""
        time = to_seconds(path, time_name, time_values, file_unit, time_entry)
    else:
        time, origin = iso_seconds(time_cells, str(path), time_name)
    return [
        Signal(header[i], time, data[:, j], units[i] if units else OWN_NAMES.get(header[i], ""),
               None, origin)
        for j, i in enumerate(numeric)
    ]  # fmt: skip


def _header(path: Path, reader: Iterator[list[str]]) -> list[str]:
    """The header row: there, its names each once."""
    header = next(reader, None)
    if not header:
        raise InputError(f"{path}: no samples (a header row, then one row per sample)")
    doubled = sorted({name for name in header if header.count(name) > 1})
    if doubled:
        raise InputError(
            f"{path}: column(s) "
            f"{', '.join(d[: limits.MAX_NAME_SHOWN] for d in doubled[:5])} appear more than once"
        )
    return header


def _numeric(
    path: Path, header: Sequence[str], row: Sequence[str], line: int, t_index: int,
    wanted: set[str] | None, own_names: bool,
) -> list[int]:  # fmt: skip
    """The indices of the columns read, by the first sample's `row`: those holding numbers (or
    empty); a column asked for (`wanted`, `own_names`) that does not is refused."""
    chosen = [
        i for i, name in enumerate(header)
        if i != t_index and (wanted is None or name in wanted)
        and (not own_names or name in OWN_NAMES)
    ]  # fmt: skip
    numeric = [i for i in chosen if row[i].strip() == "" or _is_number(row[i])]
    if wanted is not None or own_names:  # a column asked for must hold numbers
        for i in sorted(set(chosen) - set(numeric)):
            raise InputError(
                f"{path}, line {line}: column {header[i][: limits.MAX_NAME_SHOWN]} must hold "
                f"numbers; it holds {shown(row[i])}"
            )
    return numeric


def _read_rows(
    path: Path, reader: Iterator[list[str]], columns: _Columns, row: list[str] | None,
    line: int, rows: int,
) -> tuple[FloatArray, FloatArray, list[str]]:  # fmt: skip
    """The samples from `row` (at `line`) on: the numeric columns' values (rows x columns), the
    time column as numbers or as its cells (`columns.numeric_time`)."""
    header, numeric, t_index = columns.header, columns.numeric, columns.t_index
    data = np.empty((rows, len(numeric)))
    time_values = np.empty(rows if columns.numeric_time else 0)
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
                        f"{path}, line {line}: column {header[i][: limits.MAX_NAME_SHOWN]} must "
                        f"hold numbers; it holds {shown(cell)}"
                    ) from None
            if columns.numeric_time:
                try:
                    time_values[n] = float(row[t_index])
                except ValueError:
                    raise InputError(
                        f"{path}, line {line}: the time column {shown(columns.time_name)} holds "
                        f"{shown(row[t_index])}, not a number like the rows before"
                    ) from None
            else:
                time_cells.append(row[t_index])
            n += 1
        row = next(reader, None)
        line += 1
    return data[:n], time_values[:n], time_cells


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
    return text if si_unit(text) is not None else None


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
