"""Run a sweep: its tasks serially, on a LocalCluster, or on an existing Dask cluster.

Rows stream as tasks finish into a part file beside the output (NAME.part.jsonl: a header with
the spec's hash, then one line per finished task: its chunk of rows by column, flushed and
synced), so an interrupted sweep (Ctrl-C, a kill, a lost machine) resumes where it stopped:
finished cases are read back, not simulated again. The part file belongs to one spec: another
spec (its hash differs) is refused unless told to start again. The part file is the one output
that `io.outputs.Outputs` does not stage: it must outlive a failed run. The results file is
written only once every case is done, through `Outputs`, and then the part file is removed.

Dask: `dask[distributed]`, the extra `carfeel[batch]`, imported only here and only when asked
for. carfeel handles what Dask asks of its user: workers with one thread each (the models hold
the GIL) and BLAS/OpenMP threads at 1; a LocalCluster's worker processes are spawned without
importing the caller's `__main__` again, so a script that calls `run_sweep` needs no
`if __name__ == "__main__":` guard (carfeel's own command line has one); tasks are seconds of
work each (thousands of batched shifts), travel as the spec and two case numbers, and come back
as columns; at most two a worker are in flight, the next submitted as one finishes.
"""

from __future__ import annotations

import collections
import contextlib
import itertools
import json
import math
import os
import sys
import time
import types
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from carfeel import progress
from carfeel.errors import InputError
from carfeel.sweep import tasks
from carfeel.sweep.definition import SpecError, SweepSpec
from carfeel.sweep.tasks import Chunk, Row, Task, as_chunk

PART_VERSION = 2
"""1: a line of rows as dicts; 2: a line of a chunk's columns (issue 27)."""
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)
"""Set to 1 in every worker: one simulation per core, no thread pool beside it."""


def part_path(out: Path) -> Path:
    return out.with_name(f"{out.stem}.part.jsonl")


class PartFile:
    """The finished rows of a sweep that has not finished yet (see the module). Read a line at
    a time: a sweep of 10^7 cases never holds its rows (the results are written from here)."""

    def __init__(self, path: Path, spec: SweepSpec) -> None:
        self.path = path
        self.spec = spec
        self._handle: TextIO | None = None

    def _lines(self, restart: bool) -> Iterator[Chunk] | None:
        """The chunks of an earlier run of this spec (a line cut by a kill ends them); None
        when there is no part file of this spec to resume (or `restart`)."""
        if restart or not self.path.exists():  # --restart discards whatever is there
            return None
        try:
            handle = self.path.open(encoding="utf-8")
            header = json.loads(handle.readline() or "{}")
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise InputError(
                f"{self.path} (an interrupted sweep's rows) cannot be read: {exc}; "
                "delete it or pass --restart"
            ) from None
        if (
            not isinstance(header, dict)
            or header.get("spec_hash") != self.spec.hash
            or header.get("carfeel_sweep_part") != PART_VERSION
        ):
            handle.close()
            raise SpecError(
                f"{self.path} holds the finished cases of another sweep spec (or of another "
                f"carfeel version or preset): run the same spec again to resume it, or pass "
                "--restart to discard those rows and start anew"
            )

        def chunks() -> Iterator[Chunk]:
            with handle:
                for line in handle:
                    try:
                        chunk = _chunk_of(json.loads(line))
                    except (ValueError, KeyError, TypeError):
                        return  # a line cut short by a kill: the rows after it were never written
                    yield chunk

        return chunks()

    def load(self, restart: bool = False) -> dict[int, Row]:
        """The rows finished by an earlier run of this spec, in memory ({} if none): for small
        sweeps and tests; the runner uses `scan`."""
        lines = self._lines(restart)
        return {int(r["case_id"]): r for chunk in lines or () for r in chunk.rows()}

    def scan(self, restart: bool = False) -> tuple[np.ndarray, Tally]:
        """Which cases an earlier run of this spec finished (a bitmap, one byte per case) and
        their tally, read a line at a time."""
        done = np.zeros(self.spec.n_cases, dtype=bool)
        tally = Tally()
        for chunk in self._lines(restart) or ():
            if (
                not 0 <= chunk.start < chunk.stop <= self.spec.n_cases
                or done[chunk.start : chunk.stop].any()
            ):
                raise InputError(
                    f"{self.path} holds a case twice or one the spec does not have: delete it "
                    "or pass --restart"
                )
            done[chunk.start : chunk.stop] = True
            tally.add(chunk)
        return done, tally

    def open(self, keep: bool = True) -> None:
        """Start the file anew with the finished chunks kept (`keep`), copied a line at a time:
        no cut line stays."""
        staged = self.path.with_name(f".{self.path.name}.tmp")
        old = self._lines(restart=False) if keep else None
        with staged.open("w", encoding="utf-8") as handle:
            header = {
                "carfeel_sweep_part": PART_VERSION,
                "spec_hash": self.spec.hash,
                "spec": self.spec.label,
                "cases": self.spec.n_cases,
            }
            handle.write(json.dumps(header) + "\n")
            for chunk in old or ():
                handle.write(_line(chunk))
        os.replace(staged, self.path)
        self._handle = self.path.open("a", encoding="utf-8")

    def append(self, rows: Chunk | Sequence[Row]) -> None:
        """One task's rows (a chunk, or rows of consecutive cases), flushed and synced."""
        assert self._handle is not None
        self._handle.write(_line(as_chunk(rows)))
        self._handle.flush()
        os.fsync(self._handle.fileno())

    def close(self) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None

    def remove(self) -> None:
        self.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def chunks_in_order(self, every: int = 1) -> Iterator[Chunk]:
        """Every chunk, by case, read from the file (two passes: where each line starts, then
        the lines in order); `every`: only the rows whose case_id is divisible by it.
        InputError if a case is missing."""
        starts: list[tuple[int, int]] = []
        with self.path.open("rb") as handle:
            handle.readline()
            while True:
                offset = handle.tell()
                line = handle.readline()
                if not line:
                    break
                try:
                    first = _chunk_of(json.loads(line)).start
                except (ValueError, KeyError, TypeError):
                    break  # cut by a kill
                starts.append((first, offset))
            starts.sort()
            expected = 0
            for first, offset in starts:
                if first != expected:
                    raise InputError(
                        f"{self.path}: case {expected} is missing (found {first}): run the "
                        "sweep again to finish it"
                    )
                handle.seek(offset)
                chunk = _chunk_of(json.loads(handle.readline()))
                expected = chunk.stop
                picked = chunk if every == 1 else chunk.every(every)
                if picked is not None:
                    yield picked
        if expected != self.spec.n_cases:
            raise InputError(f"{self.path}: {expected} of {self.spec.n_cases} cases are done")

    def rows_in_order(self, every: int = 1) -> Iterator[Row]:
        """Every row, by case (`chunks_in_order` a row at a time)."""
        for chunk in self.chunks_in_order(every):
            yield from chunk.rows()


def _line(chunk: Chunk) -> str:
    return json.dumps({"start": chunk.start, "columns": chunk.columns}) + "\n"


def _chunk_of(line: Any) -> Chunk:
    """A part file's line as a chunk: its columns all as long, its case ids from `start`."""
    start, columns = int(line["start"]), line["columns"]
    ids = columns["case_id"]
    if not ids or any(len(v) != len(ids) for v in columns.values()):
        raise ValueError("columns of unequal lengths")
    if ids[0] != start or ids[-1] != start + len(ids) - 1:
        raise ValueError("case ids that are not the chunk's")
    return Chunk(start, columns)


@dataclass
class Tally:
    """Rows counted by status as they come (the summary's figures without the rows)."""

    counts: dict[str, int] = field(default_factory=dict)
    first_invalid: Row | None = None

    def add(self, rows: Chunk | Sequence[Row]) -> None:
        chunk = as_chunk(rows)
        for status, n in chunk.statuses().items():
            self.counts[status] = self.counts.get(status, 0) + n
        if "invalid" in chunk.columns["status"]:
            i = chunk.columns["status"].index("invalid")
            if self.first_invalid is None or chunk.start + i < self.first_invalid["case_id"]:
                self.first_invalid = {n: v[i] for n, v in chunk.columns.items()}


class Progress(progress.Progress):
    """A one-line bar on a terminal (stderr): cases done, cases per second over the last
    half minute (the rate now, not the start-up's), the time left; nothing when stderr is not
    a terminal."""

    WINDOW_S = 30.0

    def __init__(self, total: int, done: int, stream: TextIO | None = None) -> None:
        super().__init__(stream, every_s=0.1)
        self.total, self.done, self.start_done = total, done, done
        self._history: collections.deque[tuple[float, int]] = collections.deque()
        self._history.append((self.started, done))

    def rate(self, now: float) -> float:
        """Cases per second over the last WINDOW_S (since the start, before that)."""
        while len(self._history) > 1 and now - self._history[1][0] > self.WINDOW_S:
            self._history.popleft()
        then, done_then = self._history[0]
        return (self.done - done_then) / (now - then) if now > then else 0.0

    def update(self, n: int) -> None:
        """`n` more cases done."""
        self.done += n
        now = time.monotonic()
        self._history.append((now, self.done))
        self.show(lambda: self.text(now), now, last=self.done >= self.total)

    def text(self, now: float) -> str:
        """The bar, the cases done, the rate and the time left."""
        fraction = self.done / self.total if self.total else 1.0
        width = 30
        bar = "#" * int(fraction * width) + "." * (width - int(fraction * width))
        rate = self.rate(now)
        left = (self.total - self.done) / rate if rate > 0 else math.nan
        eta = f"{left:.0f} s left" if math.isfinite(left) else ""
        return f"[{bar}] {self.done}/{self.total} cases, {rate:.1f} cases/s {eta}   "

    def close(self, always: bool = True) -> None:
        """End the line: on a terminal, always (a sweep with nothing left to run too)."""
        super().close(always)


def iter_tasks(spec: SweepSpec, done: np.ndarray, workers: int = 1) -> Iterator[Task]:
    """The cases not `done`, in tasks made as they are asked for, each a run of consecutive
    cases (a task ends where a finished case lies between). A task is `cases_per_task` cases;
    with several workers at most half of the cases left a worker (but not below a quarter of
    `cases_per_task`: a batch's steps cost the same whatever its width, 0.3 s for a shift's
    1200): the last tasks shrink, and the workers finish together instead of one waiting for
    another's last big task (guided self-scheduling)."""
    size = spec.cases_per_task
    smallest = max(1, size // 4)
    left = int(spec.n_cases - done.sum())
    for first, stop in _runs(done):
        while first < stop:
            n = size if workers <= 1 else min(size, max(smallest, math.ceil(left / (2 * workers))))
            n = min(n, stop - first)
            yield Task(spec, first, first + n)
            first += n
            left -= n


def _runs(done: np.ndarray) -> Iterator[tuple[int, int]]:
    """(first, stop) of each run of cases not done, in order (from the bitmap, by numpy)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[True], done, [True]]).astype(np.int8)))
    for first, stop in zip(edges[::2], edges[1::2], strict=True):
        yield int(first), int(stop)


@dataclass(frozen=True)
class SweepRun:
    """What a sweep did: its rows (every case, sorted; empty when they were streamed to the
    part file instead), their tally, and how it got them."""

    spec: SweepSpec
    rows: list[Row]
    resumed: int
    """Cases read back from the part file of an interrupted run."""
    simulated: int
    where: str
    elapsed_s: float
    notes: tuple[str, ...] = ()
    tally: Tally = field(default_factory=Tally)

    def count(self, status: str) -> int:
        return self.tally.counts.get(status, 0)


def run_cases(
    spec: SweepSpec,
    part: PartFile | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    restart: bool = False,
    progress: TextIO | None = None,
    execute: Callable[[Task], Chunk | list[Row]] | None = None,
    keep_rows: bool = True,
) -> SweepRun:
    """Every case of `spec`, the finished ones from `part` (if given) and the rest simulated,
    serially or on Dask; the part file is kept up to date as tasks finish. `execute` runs one
    task (default `tasks.run_chunk`; rows of its cases in order will do). With `keep_rows`
    False (and a part file) no row is held: they are on disk, read back by
    `PartFile.chunks_in_order`; memory stays the same whatever the number of cases."""
    if not keep_rows and part is None:
        raise ValueError("rows not kept need a part file to go to")
    execute = execute if execute is not None else tasks.run_chunk
    started = time.monotonic()
    if part is not None:
        done, tally = part.scan(restart)
    else:
        done, tally = np.zeros(spec.n_cases, dtype=bool), Tally()
    resumed = int(done.sum())
    rows = part.load(restart) if part is not None and keep_rows else {}
    notes: list[str] = []
    with contextlib.ExitStack() as stack:
        client, n_workers, where = None, 1, "serial"
        if workers is not None or scheduler is not None:  # reached before the part file opens
            client, n_workers, where, note = stack.enter_context(dask_client(workers, scheduler))
            if note:
                notes.append(note)
        if part is not None:
            part.open(keep=resumed > 0)
            stack.callback(part.close)
        bar = Progress(spec.n_cases, resumed, progress)
        stack.callback(bar.close)

        def finished(result: Chunk | list[Row]) -> None:
            chunk = as_chunk(result)
            if keep_rows:
                for row in chunk.rows():
                    rows[int(row["case_id"])] = row
            tally.add(chunk)
            if part is not None:
                part.append(chunk)
            bar.update(len(chunk))

        todo = iter_tasks(spec, done, n_workers)
        if client is None:
            for task in todo:
                finished(execute(task))
        else:
            _on_dask(client, todo, finished, execute, in_flight=2 * max(n_workers, 2))
    ordered = [rows[i] for i in sorted(rows)]
    return SweepRun(
        spec, ordered, resumed, spec.n_cases - resumed, where, time.monotonic() - started,
        tuple(notes), tally,
    )  # fmt: skip


def _on_dask(
    client: Any,
    tasks: Iterator[Task],
    finished: Callable[[Any], None],
    execute: Callable[[Task], Any],
    in_flight: int,
) -> None:
    """The tasks on the cluster, at most `in_flight` submitted at a time (a new one as each
    finishes): the tasks of a large sweep are made as they go, never held all at once."""
    as_completed: Any = dask_modules().as_completed

    def submit(task: Task) -> Any:
        key = f"carfeel-sweep-{task.spec.hash[:12]}-{task.start}"
        return client.submit(execute, task, key=key, pure=False)

    running = {submit(task) for task in itertools.islice(tasks, in_flight)}
    queue = as_completed(list(running))
    try:
        for future in queue:
            running.discard(future)
            result = future.result()
            future.release()  # the scheduler forgets the task and its result at once
            finished(result)
            following = next(tasks, None)
            if following is not None:
                new = submit(following)
                running.add(new)
                queue.add(new)
    finally:
        client.cancel(list(running))


def dask_modules() -> Any:
    try:
        import dask.distributed
    except ImportError:
        raise InputError(
            "--workers and --scheduler run the sweep on Dask, which is not installed: "
            "pip install 'carfeel[batch]'"
        ) from None
    return dask.distributed


@contextlib.contextmanager
def _main_not_reimported() -> Iterator[None]:
    """Spawned processes import the parent's `__main__` again (multiprocessing's spawn), which
    runs a script's top level anew unless it has a `__main__` guard. While the cluster's
    workers are spawned, `__main__` is a bare module: there is nothing to import again."""
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if main is not None:
            sys.modules["__main__"] = main


def temporary_security() -> Any:
    """Dask's TLS credentials made for one run (a self-signed certificate in memory), which
    need the `cryptography` package (in the extra carfeel[batch])."""
    from distributed.security import Security

    try:
        return Security.temporary()  # type: ignore[no-untyped-call]
    except ImportError:
        raise InputError(
            "--workers starts its Dask cluster with TLS, whose temporary credentials need the "
            "cryptography package: pip install 'carfeel[batch]'"
        ) from None


@contextlib.contextmanager
def dask_client(workers: int | None, scheduler: str | None) -> Iterator[tuple[Any, int, str, str]]:
    """(client, number of workers, a description, a note) for a LocalCluster of `workers`
    single-threaded processes, or for the cluster at `scheduler`; closed at the end."""
    if workers is not None and scheduler is not None:
        raise InputError("--workers starts a cluster here, --scheduler uses one: give one")
    distributed = dask_modules()
    import logging

    if scheduler is None:
        assert workers is not None
        env = dict.fromkeys(THREAD_VARIABLES, "1")
        security = temporary_security()
        with _main_not_reimported():
            # TLS with credentials made for this run (held in memory, handed to the workers
            # through their pipes): no other process, another local user's included, can
            # connect to the scheduler or the workers and have them run its code.
            cluster = distributed.LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address=None,
                silence_logs=logging.ERROR,
                env=env,
                security=security,
            )
        try:
            client = distributed.Client(cluster, security=security)
            try:
                yield client, workers, f"LocalCluster of {workers} workers", ""
            finally:
                client.close()
        finally:
            cluster.close()
        return
    try:
        client = distributed.Client(scheduler, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(
            f"--scheduler {scheduler}: no Dask scheduler answered there ({exc}); start one "
            "with `dask scheduler` and workers with `dask worker ADDRESS --nthreads 1`"
        ) from None
    try:
        info = client.scheduler_info()
        threads = [w.get("nthreads", 1) for w in info.get("workers", {}).values()]
        note = ""
        if not scheduler.startswith("tls://"):
            note = (
                f"the cluster at {scheduler} is neither encrypted nor authenticated: whoever "
                "reaches it can run code on its workers and, through the results carfeel "
                "unpickles, in this process; use TLS (README, 'On Dask')"
            )
        if any(t > 1 for t in threads):
            note = (note + "; " if note else "") + (
                f"the cluster's workers run {max(threads)} threads each: the simulations hold "
                "the GIL, so start workers with `dask worker ADDRESS --nthreads 1`"
            )
        if not threads:
            note = (note + "; " if note else "") + "the cluster has no worker yet: the tasks wait"
        yield client, max(len(threads), 1), f"the cluster at {scheduler}", note
    finally:
        client.close()
