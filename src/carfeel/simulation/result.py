"""Result: time and named signals in SI units; written to and read from CSV.

Results do not plot themselves: `carfeel.io.plots` does.
"""

from __future__ import annotations

import csv
import io
import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.text import count


@dataclass(frozen=True)
class Result:
    """Samples of a run: `time_s` and one array per signal, all the same length.

    Numeric signals are float arrays; categorical ones (a stage, a gear) are arrays of str.
    """

    time_s: npt.NDArray[np.float64]
    signals: Mapping[str, np.ndarray]
    metadata: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.time_s)
        for name, values in self.signals.items():
            if len(values) != n:
                raise ValueError(f"signal {name!r} has {len(values)} samples, time has {n}")

    def __getitem__(self, name: str) -> np.ndarray:
        if name == "time_s":
            return self.time_s
        try:
            return self.signals[name]
        except KeyError:
            known = ", ".join(["time_s", *self.signals])
            raise KeyError(f"no signal {name!r}; the result has: {known}") from None

    def __len__(self) -> int:
        return len(self.time_s)

    @property
    def names(self) -> list[str]:
        """Column names, time first."""
        return ["time_s", *self.signals]

    def to_pandas(self) -> Any:
        """The samples as a pandas DataFrame indexed by time_s (s), a column per signal (the
        arrays are copied, not shared); the metadata in `frame.attrs`. Needs the `pandas`
        extra (`pip install 'carfeel[pandas]'`)."""
        try:
            import pandas as pd
        except ImportError:
            from carfeel.errors import InputError

            raise InputError(
                "Result.to_pandas needs pandas: pip install 'carfeel[pandas]' (or pip install "
                "pandas)"
            ) from None
        frame = pd.DataFrame({name: np.array(v) for name, v in self.signals.items()},
                             index=pd.Index(np.array(self.time_s), name="time_s"))  # fmt: skip
        frame.attrs.update(self.metadata)
        return frame

    @classmethod
    def from_rows(
        cls,
        time_s: Sequence[float] | npt.NDArray[np.float64],
        names: Sequence[str],
        rows: Sequence[Sequence[object]],
        metadata: Mapping[str, str] | None = None,
    ) -> Result:
        """Build a Result from per-sample rows of values in the order of `names`."""
        columns = list(zip(*rows, strict=True)) if rows else [() for _ in names]
        signals: dict[str, np.ndarray] = {}
        for name, column in zip(names, columns, strict=True):
            if column and isinstance(column[0], str):
                signals[name] = np.array(column, dtype=str)
            else:
                signals[name] = np.array(column, dtype=float)
        return cls(np.asarray(time_s, dtype=float), signals, dict(metadata or {}))

    @classmethod
    def concatenate(
        cls, parts: Sequence[Result], metadata: Mapping[str, str] | None = None
    ) -> Result:
        """The samples of `parts` (blocks of one run, with the same signals) one after another."""
        if not parts:
            raise ValueError("no samples to put together")
        if len(parts) == 1:
            only = parts[0]
            return cls(only.time_s, dict(only.signals), dict(metadata or only.metadata))
        names = list(parts[0].signals)
        signals = {n: np.concatenate([p.signals[n] for p in parts]) for n in names}
        time = np.concatenate([p.time_s for p in parts])
        return cls(time, signals, dict(metadata or parts[0].metadata))

    def take(self, indices: npt.NDArray[np.intp]) -> Result:
        """The samples at `indices` (in the order given)."""
        return Result(
            self.time_s[indices],
            {n: v[indices] for n, v in self.signals.items()},
            self.metadata,
        )

    def to_csv(self, path: str | os.PathLike[str]) -> Path:
        """Write all samples as CSV (header row of names, then one row per sample).

        The file is written beside its target and then renamed over it, so a reader never sees
        a half-written file and an existing file survives a failed write.
        """
        target = Path(path)
        directory = target.parent if str(target.parent) else Path(".")
        if not directory.is_dir():
            raise InputError(f"cannot write {target}: folder {directory} does not exist")
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{target.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "w", newline="", encoding="utf-8") as handle:
                writer = csv.writer(handle)
                writer.writerow(self.names)
                for start in range(0, len(self), 4096):  # a block's strings at a time
                    stop = min(start + 4096, len(self))
                    writer.writerows(csv_rows(self.take(np.arange(start, stop))))
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return target

    @classmethod
    def from_csv(
        cls, path: str | os.PathLike[str], *, drop_partial_last_line: bool = False
    ) -> Result:
        """Read a CSV written by `to_csv` (or any CSV with a `time_s` column).

        `drop_partial_last_line`: a recording cut short by a killed process may end in half a
        line; it is dropped instead of rejected.
        """
        source = Path(path)
        rows = list(csv.reader(io.StringIO(read_csv_text(source), newline="")))
        if not rows:
            raise InputError(f"{source}: empty file, expected a header row with time_s")
        header, body = rows[0], rows[1:]
        if drop_partial_last_line and body and len(body[-1]) != len(header):
            body = body[:-1]
        doubled = sorted({name for name in header if header.count(name) > 1})
        if doubled:
            raise InputError(f"{source}: column(s) {', '.join(doubled)} appear more than once")
        if "time_s" not in header:
            separator = next((s for s in (";", "\t") if len(header) == 1 and s in header[0]), None)
            if separator is not None:
                raise InputError(
                    f"{source}: the header is one field holding {separator!r}: carfeel reads "
                    "comma-separated CSV; save the file with ',' between fields and '.' as the "
                    "decimal point"
                )
            raise InputError(f"{source}: no time_s column (columns: {', '.join(header)})")
        for line_no, row in enumerate(body, start=2):
            if len(row) != len(header):
                raise InputError(
                    f"{source}, line {line_no}: {count(len(row), 'field')}, the header has "
                    f"{len(header)}"
                )
        signals: dict[str, np.ndarray] = {}
        for index, name in enumerate(header):
            column = [row[index] for row in body]
            signals[name] = _parse_column(column)
        time = signals.pop("time_s")
        if time.dtype.kind != "f":
            raise InputError(f"{source}: time_s must be numbers, in seconds")
        return cls(time, signals)


def read_csv_text(source: Path) -> str:
    """A CSV file's text: UTF-8, a byte-order mark dropped (a spreadsheet's "CSV UTF-8"); a byte
    that is not UTF-8 is named with its line and the fix (the one place CSV text is decoded)."""
    try:
        data = source.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{source}: no such file") from None
    except IsADirectoryError:
        raise InputError(f"{source}: a folder, not a CSV file") from None
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise InputError(
            f"{source}, line {line}: byte 0x{data[exc.start]:02x} is not UTF-8 text; save "
            "the file as CSV UTF-8 (a spreadsheet's export, or iconv -f latin1 -t utf-8)"
        ) from None
    if "\x00" in text:
        raise InputError(f"{source}: not a text CSV file (it holds NUL bytes)")
    return text


def csv_rows(block: Result) -> zip[tuple[str, ...]]:
    """A block's samples as CSV rows of text: numbers to 10 significant digits."""
    columns = [block.time_s, *block.signals.values()]
    return zip(*[_format_column(c) for c in columns], strict=True)


def _format_column(values: np.ndarray) -> list[str]:
    if values.dtype.kind in "fi":
        return [format(v, ".10g") for v in values.astype(float).tolist()]
    return [str(v) for v in values.tolist()]


def _parse_column(column: list[str]) -> np.ndarray:
    try:
        return np.array([float(v) for v in column], dtype=float)
    except ValueError:
        return np.array(column, dtype=str)
