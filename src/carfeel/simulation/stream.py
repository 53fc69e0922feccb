"""Where a run's samples go as it runs: sinks that take blocks of samples (each a `Result` of at
most a few thousand samples), so that a run of hours holds a block, not its whole length.

    with CsvWriter(path) as csv:                 # written as the run goes, renamed when done
        stream_shift(params, Tee(csv, FiniteCheck("shift"), features), duration_s=1000.0)

`Collector` gathers the blocks into one Result (the in-memory API); `Columns` keeps a few
columns only; `Envelope` keeps a bounded number of samples for a plot (each bucket's extremes).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import numpy as np

from carfeel.errors import CarfeelError, InputError
from carfeel.simulation.result import Result, csv_rows

BLOCK_SAMPLES = 4096
"""Samples a runner gathers before it hands them on: large enough that numpy's per-call cost
and the CSV writer's per-call cost vanish, small enough to be nothing beside the interpreter."""

PLOT_SAMPLES = 200_000
"""At most this many samples are drawn in a plot: a run of up to 200 s at 1 kHz in full; a
longer one as the extremes of buckets of consecutive samples (`Envelope`)."""


class Sink(Protocol):
    """Takes a run's samples a block at a time, in order."""

    def write(self, block: Result) -> None: ...


class Tee:
    """One block to several sinks, in order (a FiniteCheck first stops a bad run before the
    others see its samples)."""

    def __init__(self, *sinks: Sink) -> None:
        self.sinks = sinks

    def write(self, block: Result) -> None:
        for sink in self.sinks:
            sink.write(block)


class Collector:
    """Every block, kept: the whole run as one Result at the end (what `simulate_*` return)."""

    def __init__(self) -> None:
        self.blocks: list[Result] = []

    def write(self, block: Result) -> None:
        self.blocks.append(block)

    def result(self, metadata: Mapping[str, str] | None = None) -> Result:
        return Result.concatenate(self.blocks, metadata)


class Columns:
    """Only the named columns (and time), kept as float arrays: what a summary that needs a
    run's series (the steering feel's loops) holds, 8 bytes a sample and column."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        self._time: list[np.ndarray] = []
        self._parts: dict[str, list[np.ndarray]] = {n: [] for n in self.names}

    def write(self, block: Result) -> None:
        self._time.append(block.time_s)
        for name in self.names:
            self._parts[name].append(np.asarray(block[name], dtype=float))

    def result(self) -> Result:
        empty = np.empty(0)
        return Result(
            np.concatenate(self._time) if self._time else empty,
            {n: np.concatenate(p) if p else empty for n, p in self._parts.items()},
        )


class FiniteCheck:
    """Stops the run at the first non-finite number of a float column, naming it and its time:
    a run that went wrong ends at once, its staged outputs discarded."""

    def __init__(self, what: str, names: Sequence[str] | None = None) -> None:
        self.what = what
        self.names = names

    def write(self, block: Result) -> None:
        for name in self.names or block.names:
            values = block[name]
            if values.dtype.kind != "f":
                continue
            bad = ~np.isfinite(values)
            if bad.any():
                at = float(block.time_s[int(np.argmax(bad))])
                raise CarfeelError(
                    f"the {self.what} simulation produced non-finite {name} at {at:.6g} s; this "
                    "is a bug or a preset at the edge of its ranges: please report it with the "
                    "preset and options used"
                )


class CsvWriter:
    """The run's CSV written a block at a time (a header of names, one row per sample), under
    NAME.part.csv beside `path` (as `io.outputs.Outputs` stages a file written as it goes: a
    killed run leaves the samples so far readable, under a name that says they are not the
    run), renamed over `path` only when the `with` block succeeds: a reader of `path` never
    sees a half-written file and a file already there survives a failed run.

    `stage=False` writes `path` itself: a path `Outputs` has already staged (the CLI's --out),
    which `Outputs` commits or discards with the command's other files."""

    def __init__(self, path: str | os.PathLike[str], stage: bool = True) -> None:
        self.path = Path(path)
        directory = self.path.parent if str(self.path.parent) else Path(".")
        if not directory.is_dir():
            raise InputError(f"cannot write {self.path}: folder {directory} does not exist")
        self.staged = (
            self.path.with_name(f"{self.path.stem}.part{self.path.suffix}") if stage else self.path
        )
        self._stage = stage
        self._handle: Any = None
        self._writer: Any = None
        self._names: list[str] | None = None
        self.samples = 0

    def __enter__(self) -> CsvWriter:
        self._handle = self.staged.open("w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._handle)
        return self

    def write(self, block: Result) -> None:
        if self._writer is None:
            raise RuntimeError("CsvWriter.write outside its `with` block")
        if self._names is None:
            self._names = block.names
            self._writer.writerow(self._names)
        elif block.names != self._names:
            raise ValueError(f"a block's columns {block.names} differ from {self._names}")
        self._writer.writerows(csv_rows(block))
        self.samples += len(block)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        assert self._handle is not None
        done = False
        try:
            self._handle.close()
            if exc_type is None:
                if self._names is None:
                    raise ValueError(f"{self.path}: the run gave no sample to write")
                if self._stage:
                    os.replace(self.staged, self.path)
                done = True
        finally:
            self._writer = None
            if not done and self._stage:  # an unstaged path is its Outputs' to discard
                self.staged.unlink(missing_ok=True)


def every_for(samples: int, limit: int | None = None) -> int:
    """Bucket size that keeps at most `limit` (default PLOT_SAMPLES) samples of a run of
    `samples` (2 per bucket)."""
    limit = PLOT_SAMPLES if limit is None else limit
    return 1 if samples <= limit else math.ceil(samples / (limit // 2))


class Envelope:
    """A bounded view of a run for its plot: every sample when `every` is 1, else, of each
    bucket of `every` consecutive samples, the two where `key` (a column, or a function of a
    block) is least and greatest, in time order: the peaks a plot shows survive, in
    2 / `every` of the samples. `names`: the columns kept (all when None)."""

    def __init__(
        self,
        every: int,
        key: str | Callable[[Result], np.ndarray],
        names: Sequence[str] | None = None,
    ) -> None:
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.every = every
        self.key = key
        self.names = names
        self.samples = 0
        self._kept: list[Result] = []
        self._pending: Result | None = None

    def _trimmed(self, block: Result) -> Result:
        if self.names is None:
            return block
        return Result(block.time_s, {n: block[n] for n in self.names})

    def _key(self, block: Result) -> np.ndarray:
        values = block[self.key] if isinstance(self.key, str) else self.key(block)
        keyed: np.ndarray = np.nan_to_num(np.asarray(values, dtype=float), nan=0.0)
        return keyed

    def write(self, block: Result) -> None:
        self.samples += len(block)
        if self.every == 1:
            self._kept.append(self._trimmed(block))
            return
        keyed = self._key(block)
        if self._pending is not None:
            block = Result.concatenate([self._pending, block])
            keyed = np.concatenate([self._key(self._pending), keyed])
        whole = len(block) // self.every * self.every
        if whole:
            self._kept.append(self._extremes(block, keyed, whole))
        self._pending = block.take(np.arange(whole, len(block))) if whole < len(block) else None

    def _extremes(self, block: Result, keyed: np.ndarray, whole: int) -> Result:
        buckets = keyed[:whole].reshape(-1, self.every)
        base = np.arange(buckets.shape[0]) * self.every
        low = base + np.argmin(buckets, axis=1)
        high = base + np.argmax(buckets, axis=1)
        first, second = np.minimum(low, high), np.maximum(low, high)
        picked = np.column_stack([first, second]).ravel()
        keep = np.ones(picked.size, dtype=bool)
        keep[1::2] = second != first  # one sample where a bucket is flat
        return self._trimmed(block.take(picked[keep]))

    def result(self, metadata: Mapping[str, str] | None = None) -> Result:
        """The kept samples (a partial last bucket reduced like the others)."""
        if self._pending is not None:  # shorter than a bucket
            self._kept.append(self._last(self._pending))
            self._pending = None
        return Result.concatenate(self._kept, metadata)

    def _last(self, block: Result) -> Result:
        keyed = self._key(block)
        picked = sorted({int(np.argmin(keyed)), int(np.argmax(keyed))})
        return self._trimmed(block.take(np.asarray(picked)))

    def note(self) -> str:
        """What the plot shows, for its title: '' when every sample."""
        if self.every == 1:
            return ""
        return f"{self.samples} samples drawn as the extremes of every {self.every}"
