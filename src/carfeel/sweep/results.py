"""A sweep's rows as Parquet (pyarrow) or CSV, with the spec and carfeel's version kept beside.

Parquet keeps them in the file's schema metadata (`carfeel_spec`, `carfeel_version`, ...); a CSV
gets them in a JSON sidecar (NAME.json), as `carfeel simulate` writes its runs.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.errors import InputError
from carfeel.sweep.base import base_params
from carfeel.sweep.definition import SweepSpec
from carfeel.sweep.paths import field_type
from carfeel.sweep.settings import metric_names
from carfeel.sweep.tasks import Chunk

Row = dict[str, Any]
BOOL_METRICS = ("balked", "engaged", "ground")
FORMATS = (".parquet", ".csv")


def pyarrow() -> Any:
    try:
        import pyarrow as pa
        import pyarrow.parquet
    except ImportError:
        raise InputError(
            "Parquet needs pyarrow: pip install 'carfeel[batch]' (or write CSV: --out results.csv)"
        ) from None
    return pa


def is_bool_metric(name: str) -> bool:
    return name.split("_")[-1] in BOOL_METRICS or name in BOOL_METRICS


def column_types(spec: SweepSpec) -> dict[str, str]:
    """Each column's type: int, float, bool or str."""
    base = base_params(spec.model, spec.preset_text, spec.engagement_text)
    types = {"case_id": "int", "sample": "int", "seed": "int"}
    for path in spec.parameters:
        kind = field_type(spec.model, base, path)[0]
        types[path] = {bool: "bool", int: "int"}.get(kind, "float")
    for name in spec.metrics:
        types[name] = "bool" if is_bool_metric(name) else "float"
    types["status"] = types["problem"] = "str"
    return types


def metadata(spec: SweepSpec) -> dict[str, str]:
    described = metric_names(spec.model, spec.settings)
    return {
        "carfeel_version": __version__,
        "carfeel_spec": spec.text,
        "carfeel_spec_hash": spec.hash,
        "carfeel_model": spec.model,
        "carfeel_preset": spec.preset_label,
        "carfeel_parameters": json.dumps(list(spec.parameters)),
        "carfeel_metrics": json.dumps({m: described[m] for m in spec.metrics}),
        "carfeel_cases": str(spec.n_cases),
    }


WRITE_BATCH = 65_536
"""Rows per Parquet row group written: memory stays this many rows whatever the sweep's size."""


def write(
    rows: Sequence[Row], spec: SweepSpec, path: Path, fmt: str, sidecar: Path | None = None
) -> None:
    """Write the rows (sorted by case) to `path` as `fmt` (.parquet or .csv; a CSV's metadata
    goes to `sidecar`, default beside it with the suffix .json)."""
    write_rows(sorted(rows, key=lambda r: int(r["case_id"])), spec, path, fmt, sidecar)


def write_rows(
    rows: Iterable[Row], spec: SweepSpec, path: Path, fmt: str, sidecar: Path | None = None
) -> None:
    """`write` of rows that come in case order, as they come: a batch of WRITE_BATCH at most
    in memory (Parquet row groups), a row at a time for a CSV."""
    types = column_types(spec)
    names = list(types)
    meta = metadata(spec)
    if fmt == ".parquet":
        pa = pyarrow()
        arrow = {"int": pa.int64(), "float": pa.float64(), "bool": pa.bool_(), "str": pa.string()}
        schema = pa.schema([(n, arrow[types[n]]) for n in names], metadata=meta)
        with pa.parquet.ParquetWriter(path, schema) as writer:
            for batch in _batches(rows, WRITE_BATCH):
                columns = {n: [_typed(r.get(n), types[n]) for r in batch] for n in names}
                writer.write_table(pa.Table.from_pydict(columns, schema=schema))
        return
    with path.open("w", newline="", encoding="utf-8") as handle:
        out = csv.writer(handle)
        out.writerow(names)
        for r in rows:
            out.writerow([_cell(r.get(n), types[n]) for n in names])
    sidecar = sidecar if sidecar is not None else path.with_suffix(".json")
    sidecar.write_text(json.dumps({**meta, "columns": types}, indent=2) + "\n", encoding="utf-8")


def write_chunks(
    chunks: Iterable[Chunk], spec: SweepSpec, path: Path, fmt: str, sidecar: Path | None = None
) -> None:
    """`write_rows` of chunks that come in case order (a part file's): Parquet in row groups
    of about WRITE_BATCH rows (whole chunks), made from the columns as they are; CSV a chunk
    at a time."""
    types = column_types(spec)
    names = list(types)
    meta = metadata(spec)
    if fmt == ".parquet":
        pa = pyarrow()
        arrow = {"int": pa.int64(), "float": pa.float64(), "bool": pa.bool_(), "str": pa.string()}
        schema = pa.schema([(n, arrow[types[n]]) for n in names], metadata=meta)
        held: list[Chunk] = []
        with pa.parquet.ParquetWriter(path, schema) as writer:
            # chain, not (*chunks, None): a tuple would hold every chunk of the sweep
            for chunk in itertools.chain(chunks, [None]):
                if chunk is not None:
                    held.append(chunk)
                if held and (chunk is None or sum(map(len, held)) >= WRITE_BATCH):
                    columns = {
                        n: pa.array(_joined(held, n, types[n]), type=arrow[types[n]]) for n in names
                    }
                    writer.write_table(pa.Table.from_pydict(columns, schema=schema))
                    held = []
        return
    with path.open("w", newline="", encoding="utf-8") as handle:
        out = csv.writer(handle)
        out.writerow(names)
        for chunk in chunks:
            cells = [[_cell(v, types[n]) for v in _column(chunk, n)] for n in names]
            out.writerows(zip(*cells, strict=True))
    sidecar = sidecar if sidecar is not None else path.with_suffix(".json")
    sidecar.write_text(json.dumps({**meta, "columns": types}, indent=2) + "\n", encoding="utf-8")


def _column(chunk: Chunk, name: str) -> list[Any]:
    """A chunk's column (None for each row of a column it lacks)."""
    values = chunk.columns.get(name)
    return values if values is not None else [None] * len(chunk)


def _joined(chunks: Sequence[Chunk], name: str, kind: str) -> list[Any]:
    """A column of several chunks, typed (a JSON integer of a float column as a float)."""
    values = [v for chunk in chunks for v in _column(chunk, name)]
    if kind == "float":
        return [None if v is None else float(v) for v in values]
    return values


def _batches(rows: Iterable[Row], size: int) -> Iterator[list[Row]]:
    """Lists of `size` rows (the last shorter): itertools.batched, which Python 3.11 lacks."""
    iterator = iter(rows)
    while batch := list(itertools.islice(iterator, size)):
        yield batch


def columns_of(rows: Sequence[Row], spec: SweepSpec) -> tuple[dict[str, list[Any]], dict[str, str]]:
    """(columns, metadata) of rows in memory, as `read` gives them from a file."""
    return columns_from(sorted(rows, key=lambda r: int(r["case_id"])), spec)


def columns_from(
    rows: Iterable[Row], spec: SweepSpec
) -> tuple[dict[str, list[Any]], dict[str, str]]:
    """(columns, metadata) of rows that come in order (a part file's, or a sample of them)."""
    types = column_types(spec)
    columns: dict[str, list[Any]] = {n: [] for n in types}
    for r in rows:
        for n, kind in types.items():
            columns[n].append(_typed(r.get(n), kind))
    return columns, metadata(spec)


def columns_of_chunks(
    chunks: Iterable[Chunk], spec: SweepSpec
) -> tuple[dict[str, list[Any]], dict[str, str]]:
    """`columns_from` of chunks that come in order."""
    types = column_types(spec)
    columns: dict[str, list[Any]] = {n: [] for n in types}
    for chunk in chunks:
        for n, kind in types.items():
            columns[n].extend(_typed(v, kind) for v in _column(chunk, n))
    return columns, metadata(spec)


def _typed(value: Any, kind: str) -> Any:
    if value is None:
        return None
    if kind == "float":
        return float(value)
    if kind == "int":
        return int(value)
    if kind == "bool":
        return bool(value)
    return str(value)


def _cell(value: Any, kind: str) -> str:
    if value is None:
        return ""
    if kind == "bool":
        return "true" if value else "false"
    if kind == "float":
        return repr(float(value))
    return str(value)


MAX_SIDECAR_BYTES = 16 * 1024 * 1024
"""A CSV's sidecar holds the spec and the metrics' descriptions: kilobytes."""


def read(path: Path, max_rows: int | None = None) -> tuple[dict[str, list[Any]], dict[str, str]]:
    """(columns by name, metadata) of a sweep's results file, Parquet or CSV; with `max_rows`,
    every k-th row only (k the least that keeps at most that many; the metadata's
    `carfeel_plotted` says so), read a row group or a line at a time."""
    if not path.is_file():
        raise InputError(f"results file {path} not found; give the --out of a `carfeel sweep`")
    columns: dict[str, list[Any]]
    if path.suffix.lower() == ".parquet":
        pa = pyarrow()
        try:
            table = pa.parquet.ParquetFile(path)
            meta = {k.decode(): v.decode() for k, v in (table.schema_arrow.metadata or {}).items()}
            total = table.metadata.num_rows
            every = _every(total, max_rows)
            columns = {name: [] for name in table.schema_arrow.names}
            seen = 0
            for batch in table.iter_batches(batch_size=WRITE_BATCH):
                first = (-seen) % every  # the batch's first row whose index is a multiple
                picked = batch.slice(first).take(list(range(0, batch.num_rows - first, every)))
                for name in columns:
                    columns[name].extend(picked.column(name).to_pylist())
                seen += batch.num_rows
        except (OSError, ValueError, pa.ArrowException) as exc:
            raise InputError(f"{path} is not a readable Parquet file: {exc}") from None
    elif path.suffix.lower() == ".csv":
        sidecar = path.with_suffix(".json")
        try:
            if sidecar.stat().st_size > MAX_SIDECAR_BYTES:
                raise InputError(f"{sidecar}: over {MAX_SIDECAR_BYTES} bytes, not a sweep's")
            info = json.loads(sidecar.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise InputError(
                f"{path}: its sidecar {sidecar} (written with it) cannot be read: {exc}"
            ) from None
        if not isinstance(info, dict):
            raise InputError(f"{path}: its sidecar {sidecar} is not a sweep's metadata")
        types = info.pop("columns", {})
        meta = {k: str(v) for k, v in info.items()}
        try:
            total = int(meta.get("carfeel_cases", "0"))
        except ValueError:
            total = 0
        every = _every(total, max_rows)
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.reader(handle)
            header = next(reader, [])
            columns = {n: [] for n in header}
            for k, line in enumerate(reader):
                if k % every:
                    continue
                if len(line) != len(header):
                    raise InputError(
                        f"{path}: line {k + 2} has {len(line)} fields, the header {len(header)}"
                    )
                for name, text in zip(header, line, strict=True):
                    columns[name].append(_parse(text, types.get(name, "str")))
    else:
        raise InputError(f"{path}: expected a .parquet or .csv file written by `carfeel sweep`")
    if "carfeel_spec" not in meta:
        raise InputError(f"{path} has no sweep metadata: was it written by `carfeel sweep`?")
    if every > 1:
        meta["carfeel_plotted"] = (
            f"drawn from every {every}th of the {total} cases (at most {max_rows} are plotted)"
        )
    return columns, meta


def _every(total: int, max_rows: int | None) -> int:
    return 1 if max_rows is None or total <= max_rows else math.ceil(total / max_rows)


def _parse(text: str, kind: str) -> Any:
    if kind == "str":
        return text
    if text == "":
        return None
    if kind == "int":
        return int(text)
    if kind == "float":
        return float(text)
    if kind == "bool":
        return text == "true"
    return text


def as_float(values: Sequence[Any]) -> list[float]:
    """A column as floats: None as NaN, booleans as 0/1."""
    return [math.nan if v is None else float(v) for v in values]
