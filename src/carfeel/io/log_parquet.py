"""Parquet logs through pyarrow (the extra carfeel[logs]): the numeric columns, sized from the
file's metadata before any is read, units from each field's `unit` metadata; the time column
numbers, timestamps, durations, dates or ISO 8601 text."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from carfeel.errors import InputError
from carfeel.io import log_limits as limits
from carfeel.io.log_channels import MapEntry
from carfeel.io.log_limits import shown, too_many
from carfeel.io.log_signals import (
    FloatArray,
    Signal,
    iso_seconds,
    lazy_extra,
    time_column,
    to_seconds,
)
from carfeel.io.log_units import OWN_NAMES


def read_parquet(
    path: Path, time_entry: MapEntry | None = None, wanted: set[str] | None = None
) -> list[Signal]:
    """A Parquet file's numeric columns as signals, sized from its metadata before any is read;
    units from each field's `unit` metadata."""
    lazy_extra("parquet", path)
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        handle = pq.ParquetFile(path)
        schema = handle.schema_arrow
        rows = int(handle.metadata.num_rows)
    except Exception as exc:  # pyarrow raises its own errors for a broken file
        raise InputError(f"{path}: not a readable Parquet file ({str(exc)[:200]})") from None
    time_name = time_column(path, list(schema.names), time_entry)
    numeric = (pa.types.is_integer, pa.types.is_floating, pa.types.is_boolean,
               pa.types.is_decimal)  # fmt: skip
    columns = [
        f.name for f in schema
        if f.name != time_name and (wanted is None or f.name in wanted)
        and any(test(f.type) for test in numeric)
    ]  # fmt: skip
    if rows > limits.MAX_SAMPLES:
        raise too_many(path, "has", f"{rows:,} rows", limits.MAX_SAMPLES)
    if rows * (len(columns) + 1) > limits.MAX_VALUES:
        raise too_many(path, "holds", f"{rows:,} rows x {len(columns) + 1} columns",
                       limits.MAX_VALUES)  # fmt: skip
    time_field = schema.field(time_name)
    if pa.types.is_string(time_field.type) or pa.types.is_large_string(time_field.type):
        _check_text_time(path, handle, list(schema.names).index(time_name), time_name, rows)
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


def _check_text_time(path: Path, handle: Any, index: int, time_name: str, rows: int) -> None:
    """A text time column, sized from the metadata before it is read (a 50 MB cell came back
    whole in the message): at most 64 bytes a sample."""
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


def _arrow_time(
    path: Path, column: Any, name: str, file_unit: str, time_entry: MapEntry | None
) -> tuple[FloatArray, str | None]:
    """A Parquet time column as seconds, and the date-time of its first sample where it holds
    date-times: numbers through `to_seconds`; timestamps and durations (what pandas and Spark
    write) and dates from their integer counts; ISO 8601 text parsed."""
    import pyarrow as pa

    kind = column.type
    if any(test(kind) for test in (pa.types.is_integer, pa.types.is_floating,
                                   pa.types.is_decimal)):  # fmt: skip
        raw = np.asarray(column.to_numpy(zero_copy_only=False), dtype=float)
        return to_seconds(path, name, raw, file_unit, time_entry), None
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
        return iso_seconds(column.to_pylist(), str(path), name)
    raise InputError(
        f"{path}: the time column {shown(name)} is of type {str(kind)[:60]}: give seconds "
        "(numbers) or timestamps"
    )
