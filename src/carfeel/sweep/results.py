"""A sweep's rows as Parquet (pyarrow) or CSV, with the spec and carfeel's version kept beside.

Parquet keeps them in the file's schema metadata (`carfeel_spec`, `carfeel_version`, ...); a CSV
gets them in a JSON sidecar (NAME.json), as `carfeel simulate` writes its runs.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.errors import InputError
from carfeel.sweep.spec import SweepSpec, base_params, field_type, metric_names

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


def write(
    rows: Sequence[Row], spec: SweepSpec, path: Path, fmt: str, sidecar: Path | None = None
) -> None:
    """Write the rows (sorted by case) to `path` as `fmt` (.parquet or .csv; a CSV's metadata
    goes to `sidecar`, default beside it with the suffix .json)."""
    rows = sorted(rows, key=lambda r: int(r["case_id"]))
    types = column_types(spec)
    names = list(types)
    meta = metadata(spec)
    if fmt == ".parquet":
        pa = pyarrow()
        arrow = {"int": pa.int64(), "float": pa.float64(), "bool": pa.bool_(), "str": pa.string()}
        schema = pa.schema([(n, arrow[types[n]]) for n in names], metadata=meta)
        columns = {n: [_typed(r.get(n), types[n]) for r in rows] for n in names}
        table = pa.Table.from_pydict(columns, schema=schema)
        pa.parquet.write_table(table, path)
        return
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for r in rows:
            writer.writerow([_cell(r.get(n), types[n]) for n in names])
    sidecar = sidecar if sidecar is not None else path.with_suffix(".json")
    sidecar.write_text(json.dumps({**meta, "columns": types}, indent=2) + "\n", encoding="utf-8")


def columns_of(rows: Sequence[Row], spec: SweepSpec) -> tuple[dict[str, list[Any]], dict[str, str]]:
    """(columns, metadata) of rows in memory, as `read` gives them from a file."""
    ordered = sorted(rows, key=lambda r: int(r["case_id"]))
    types = column_types(spec)
    return {n: [_typed(r.get(n), types[n]) for r in ordered] for n in types}, metadata(spec)


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


def read(path: Path) -> tuple[dict[str, list[Any]], dict[str, str]]:
    """(columns by name, metadata) of a sweep's results file, Parquet or CSV."""
    if not path.is_file():
        raise InputError(f"results file {path} not found; give the --out of a `carfeel sweep`")
    if path.suffix.lower() == ".parquet":
        pa = pyarrow()
        try:
            table = pa.parquet.read_table(path)
        except (OSError, ValueError, pa.ArrowException) as exc:
            raise InputError(f"{path} is not a readable Parquet file: {exc}") from None
        meta = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items()}
        columns = {name: table.column(name).to_pylist() for name in table.column_names}
    elif path.suffix.lower() == ".csv":
        sidecar = path.with_suffix(".json")
        try:
            info = json.loads(sidecar.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise InputError(
                f"{path}: its sidecar {sidecar} (written with it) cannot be read: {exc}"
            ) from None
        types = info.pop("columns", {})
        meta = {k: str(v) for k, v in info.items()}
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.reader(handle)
            header = next(reader, [])
            columns = {n: [] for n in header}
            for line in reader:
                for name, text in zip(header, line, strict=True):
                    columns[name].append(_parse(text, types.get(name, "str")))
    else:
        raise InputError(f"{path}: expected a .parquet or .csv file written by `carfeel sweep`")
    if "carfeel_spec" not in meta:
        raise InputError(f"{path} has no sweep metadata: was it written by `carfeel sweep`?")
    return columns, meta


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
