"""Run a sweep: its tasks serially, on a LocalCluster, or on an existing Dask cluster.

Rows stream as tasks finish into a part file beside the output (NAME.part.jsonl: a header with
the spec's hash, then one line of rows per finished task, flushed and synced), so an interrupted
sweep (Ctrl-C, a kill, a lost machine) resumes where it stopped: finished cases are read back,
not simulated again. The part file belongs to one spec: another spec (its hash differs) is
refused unless told to start again. The part file is the one output that `io.outputs.Outputs`
does not stage: it must outlive a failed run. The results file is written only once every case
is done, through `Outputs`, and then the part file is removed.

Dask: `dask[distributed]`, the extra `carfeel[batch]`, imported only here and only when asked
for. carfeel handles what Dask asks of its user: workers with one thread each (the models hold
the GIL) and BLAS/OpenMP threads at 1; and a LocalCluster's worker processes are spawned without
importing the caller's `__main__` again, so a script that calls `run_sweep` needs no
`if __name__ == "__main__":` guard (carfeel's own command line has one).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import time
import types
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from carfeel.errors import InputError
from carfeel.sweep import tasks
from carfeel.sweep.spec import Case, SpecError, SweepSpec, cases
from carfeel.sweep.tasks import Row, Task

PART_VERSION = 1
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
    """The finished rows of a sweep that has not finished yet (see the module)."""

    def __init__(self, path: Path, spec: SweepSpec) -> None:
        self.path = path
        self.spec = spec
        self._handle: TextIO | None = None

    def load(self, restart: bool = False) -> dict[int, Row]:
        """The rows finished by an earlier run of this spec; {} if there is none."""
        if not self.path.exists():
            return {}
        try:
            lines = self.path.read_text(encoding="utf-8").splitlines()
            header = json.loads(lines[0]) if lines else {}
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            if restart:
                return {}
            raise InputError(
                f"{self.path} (an interrupted sweep's rows) cannot be read: {exc}; "
                "delete it or pass --restart"
            ) from None
        if header.get("spec_hash") != self.spec.hash:
            if restart:
                return {}
            raise SpecError(
                f"{self.path} holds the finished cases of another sweep spec (or of another "
                f"carfeel version or preset): run the same spec again to resume it, or pass "
                "--restart to discard those rows and start anew"
            )
        rows: dict[int, Row] = {}
        for line in lines[1:]:
            try:
                chunk = json.loads(line)
            except ValueError:
                break  # a line cut short by a kill: the rows after it were never written
            for row in chunk["rows"]:
                rows[int(row["case_id"])] = row
        return rows

    def open(self, rows: dict[int, Row]) -> None:
        """Start the file anew with the rows kept (a clean copy: no cut line stays)."""
        staged = self.path.with_name(f".{self.path.name}.tmp")
        with staged.open("w", encoding="utf-8") as handle:
            header = {
                "carfeel_sweep_part": PART_VERSION,
                "spec_hash": self.spec.hash,
                "spec": self.spec.label,
                "cases": self.spec.n_cases,
            }
            handle.write(json.dumps(header) + "\n")
            if rows:
                handle.write(json.dumps({"rows": list(rows.values())}) + "\n")
        os.replace(staged, self.path)
        self._handle = self.path.open("a", encoding="utf-8")

    def append(self, rows: Sequence[Row]) -> None:
        assert self._handle is not None
        self._handle.write(json.dumps({"rows": list(rows)}) + "\n")
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


class Progress:
    """A one-line bar on a terminal (stderr); nothing at all when it is not one."""

    def __init__(self, total: int, done: int, stream: TextIO | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = self.stream.isatty()
        self.total, self.done, self.start_done = total, done, done
        self.started = time.monotonic()
        self._shown = 0.0

    def update(self, n: int) -> None:
        self.done += n
        now = time.monotonic()
        if self.enabled and (now - self._shown > 0.1 or self.done >= self.total):
            self._shown = now
            fraction = self.done / self.total if self.total else 1.0
            width = 30
            bar = "#" * int(fraction * width) + "." * (width - int(fraction * width))
            elapsed = now - self.started
            rate = (self.done - self.start_done) / elapsed if elapsed > 0 else 0.0
            left = (self.total - self.done) / rate if rate > 0 else math.nan
            eta = f"{left:.0f} s left" if math.isfinite(left) else ""
            self.stream.write(f"\r[{bar}] {self.done}/{self.total} cases, {rate:.1f}/s {eta}   ")
            self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()


def tasks_of(spec: SweepSpec, todo: Sequence[Case], workers: int = 1) -> list[Task]:
    """The cases left, in tasks of `cases_per_task` (fewer, so that every worker gets some)."""
    size = spec.cases_per_task
    if workers > 1 and todo:
        size = min(size, math.ceil(len(todo) / workers))
    return [Task(spec, tuple(todo[i : i + size])) for i in range(0, len(todo), size)]


@dataclass(frozen=True)
class SweepRun:
    """What a sweep did: its rows (every case, sorted) and how it got them."""

    spec: SweepSpec
    rows: list[Row]
    resumed: int
    """Cases read back from the part file of an interrupted run."""
    simulated: int
    where: str
    elapsed_s: float
    notes: tuple[str, ...] = ()

    def count(self, status: str) -> int:
        return sum(1 for r in self.rows if r["status"] == status)


def run_cases(
    spec: SweepSpec,
    part: PartFile | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    restart: bool = False,
    progress: TextIO | None = None,
    execute: Callable[[Task], list[Row]] | None = None,
) -> SweepRun:
    """Every case of `spec`, the finished ones from `part` (if given) and the rest simulated,
    serially or on Dask; the part file is kept up to date as tasks finish. `execute` runs one
    task (default `tasks.run_task`)."""
    execute = execute if execute is not None else tasks.run_task
    started = time.monotonic()
    done = part.load(restart) if part is not None else {}
    todo = [c for c in cases(spec) if c.case_id not in done]
    rows = dict(done)
    notes: list[str] = []
    with contextlib.ExitStack() as stack:
        client, n_workers, where = None, 1, "serial"
        if workers is not None or scheduler is not None:  # reached before the part file opens
            client, n_workers, where, note = stack.enter_context(dask_client(workers, scheduler))
            if note:
                notes.append(note)
        if part is not None:
            part.open(done)
            stack.callback(part.close)
        bar = Progress(spec.n_cases, len(done), progress)
        stack.callback(bar.close)

        def finished(chunk: list[Row]) -> None:
            for row in chunk:
                rows[int(row["case_id"])] = row
            if part is not None:
                part.append(chunk)
            bar.update(len(chunk))

        if client is None:
            for task in tasks_of(spec, todo):
                finished(execute(task))
        else:
            _on_dask(client, tasks_of(spec, todo, n_workers), finished, execute)
    ordered = [rows[i] for i in sorted(rows)]
    return SweepRun(
        spec, ordered, len(done), len(todo), where, time.monotonic() - started, tuple(notes)
    )


def _on_dask(
    client: Any,
    tasks: Sequence[Task],
    finished: Callable[[list[Row]], None],
    execute: Callable[[Task], list[Row]],
) -> None:
    as_completed: Any = dask_modules().as_completed

    futures = [
        client.submit(
            execute,
            task,
            key=f"carfeel-sweep-{task.spec.hash[:12]}-{task.cases[0].case_id}",
            pure=False,
        )
        for task in tasks
    ]
    try:
        for future in as_completed(futures):
            finished(future.result())
    finally:
        client.cancel(futures)


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
        with _main_not_reimported():
            cluster = distributed.LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                silence_logs=logging.ERROR,
                env=env,
            )
        try:
            client = distributed.Client(cluster)
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
        if any(t > 1 for t in threads):
            note = (
                f"the cluster's workers run {max(threads)} threads each: the simulations hold "
                "the GIL, so start workers with `dask worker ADDRESS --nthreads 1`"
            )
        if not threads:
            note = "the cluster has no worker yet: the tasks wait for one"
        yield client, max(len(threads), 1), f"the cluster at {scheduler}", note
    finally:
        client.close()
