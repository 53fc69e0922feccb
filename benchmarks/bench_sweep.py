"""Shifts per second: the pure step against the vectorized batch, and whole sweeps serially,
batched, on Dask and on a plain multiprocessing pool, all in one run. Prints numbers; asserts
nothing.

1. shift-steps per second of the pure step (`simulate_shift` + its features, what the pure
   engine runs per case) and of the batch (`ShiftBatch.run` with its features), measured in
   alternating rounds so that both see the same load; the ratio is per round.
2. a Monte Carlo sweep (`run_cases`) of single shifts: the pure engine serially, the batch
   serially, the batch on a LocalCluster of 2 single-threaded workers (its start-up timed
   apart), and the pure engine on it; then the batch on the TLS cluster `--workers 2` starts
   (carfeel's own, with temporary credentials) beside the plain one.
3. refusals (issue 24): each oversized spec (seeds 1e8, 1e9, 1e18; samples 1e18; seeds x samples
   2e7; a 4000 x 4000 grid) in a child process: its wall time to exit 2 and its peak memory,
   beside `carfeel --version` in a child (what Python and the imports cost).
4. memory of a large sweep (issue 24): peak RSS of a child running `run_cases` + the results'
   writing over 10^5 and 10^6 cases streamed (rows to the part file, CSV from it), and 10^5
   held as before; each task's rows are made without a simulation (the runner's own cost).
5. scaling (issue 27): the README's tolerance sweep at --scaling-cases (10^5) through the same
   tasks serially, on a multiprocessing pool of 1 and 2 processes (the reference) and on
   carfeel's TLS LocalCluster of 1 and 2 workers, in rounds: cases/s, the speed-up over the
   serial run of the round, the workers' share of their wall time spent in the tasks, Dask's
   time over the pool's, and the CPU the machine's other users took meanwhile (/proc/stat).
6. the command (issue 27): `carfeel sweep` of that spec serially and with `--workers 2`, each
   in a child (wall time, the client's peak memory, the CPU others took), and of 10^6 cases
   with `--workers 2` (the client's peak memory).
    python benchmarks/bench_sweep.py [--lanes 4096] [--pure-shifts 48] [--rounds 3]
                                     [--sections 1,2,3,4,5,6] [--scaling-cases 100000]
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.analysis.shift_features import shift_features
from carfeel.io.presets import load_shift
from carfeel.simulation.shift import simulate_shift
from carfeel.sweep import runner, spec, tasks
from carfeel.sweep.batch import ShiftBatch
from measure import busy_s, child

STEPS = 1200  # a 1.2 s shift at 1 ms

SPEC = """\
model = "shift"
seeds = 8
samples = {samples}
sampling = "latin"
engine = "{engine}"
cases_per_task = {per_task}
[vary]
"gearbox.chamfer.gear_inertia_kg_m2" = {{ distribution = "uniform", low = 0.05, high = 0.3 }}
"driver.push_velocity_m_s" = {{ distribution = "uniform", low = 0.15, high = 0.4 }}
"driver.push_force_N" = {{ distribution = "truncnormal", mean = 80, sd = 10, low = 60, high = 100 }}
"""


def pure_rate(shifts: int) -> float:
    params = load_shift().params
    t0 = time.perf_counter()
    for seed in range(shifts):
        result = simulate_shift(params, seed=seed, duration_s=1.2)
        shift_features(result, params.gearbox.in_gear_position_m)
    return shifts * STEPS / (time.perf_counter() - t0)


def batch_rate(lanes: int) -> float:
    base = load_shift().params
    params = [
        dataclasses.replace(
            base, driver=dataclasses.replace(base.driver, push_force_N=60.0 + (i % 40))
        )
        for i in range(lanes)
    ]
    t0 = time.perf_counter()
    ShiftBatch(params, list(range(lanes))).run(1.2)
    return lanes * STEPS / (time.perf_counter() - t0)


def sweep_rate(text: str, **where: object) -> tuple[float, int]:
    sweep = spec.from_toml(text)
    t0 = time.perf_counter()
    run = runner.run_cases(sweep, **where)  # type: ignore[arg-type]
    elapsed = time.perf_counter() - t0
    assert run.count("ok") == sweep.n_cases
    return sweep.n_cases / elapsed, sweep.n_cases


UNIFORM = '"driver.push_force_N" = { distribution = "uniform", low = 60, high = 100 }'
GRID = (
    'model = "shift"\n[vary]\n"driver.push_force_N" = {{ values = [{}] }}\n'
    '"driver.push_velocity_m_s" = {{ values = [{}] }}\n'
).format(
    ", ".join(str(60 + k * 1e-3) for k in range(4000)),
    ", ".join(str(0.15 + k * 1e-5) for k in range(4000)),
)
OVERSIZED = {
    "seeds = 1e8": 'model = "shift"\nseeds = 100000000\n',
    "seeds = 1e9": 'model = "shift"\nseeds = 1000000000\n',
    "seeds = 1e18": 'model = "shift"\nseeds = 1000000000000000000\n',
    "samples = 1e18": f'model = "shift"\nsamples = 1000000000000000000\n[vary]\n{UNIFORM}\n',
    "1e7 seeds x 2 samples": f'model = "shift"\nseeds = 10000000\nsamples = 2\n[vary]\n{UNIFORM}\n',
    "grid 4000 x 4000": GRID,
}

STREAMED = """
import sys, tempfile
from pathlib import Path
from carfeel.sweep import results, runner, spec, tasks
n, keep = int(sys.argv[1]), sys.argv[2] == "held"
def fast(task):
    return tasks.Chunk.of([tasks._row(task.spec, c, {}, "ok", "") for c in task.cases])
sweep = spec.from_toml(f'model = "shift"\\nseeds = {n}\\ncases_per_task = 4096\\n')
with tempfile.TemporaryDirectory() as scratch:
    folder = Path(scratch)
    part = runner.PartFile(folder / "r.part.jsonl", sweep)
    run = runner.run_cases(sweep, part, execute=fast, keep_rows=keep)
    rows = run.rows if keep else part.rows_in_order()
    results.write_rows(rows, sweep, folder / "r.csv", ".csv")
    part.remove()
"""


def refusals() -> None:
    print("3. oversized sweeps refused (exit code, wall time, peak memory of the child)")
    run = child(["-m", "carfeel.cli", "--version"])
    print(f"   reference: carfeel --version       exit {run.code}  {run.wall_s:5.2f} s  "
          f"{run.peak_MB:6.1f} MB")  # fmt: skip
    with tempfile.TemporaryDirectory() as folder:
        for label, text in OVERSIZED.items():
            path = Path(folder) / "big.toml"
            path.write_text(text)
            out = str(Path(folder) / "r.csv")
            run = child(["-m", "carfeel.cli", "sweep", str(path), "--out", out])
            print(f"   {label:32s} exit {run.code}  {run.wall_s:5.2f} s  {run.peak_MB:6.1f} MB")


def streamed() -> None:
    print("4. a large sweep's memory (rows made without simulating: the runner and the writing)")
    for n, how in ((100_000, "held"), (100_000, "streamed"), (1_000_000, "streamed")):
        run = child(["-c", STREAMED, str(n), how])
        print(f"   {n:9,d} cases, rows {how:8s}  exit {run.code}  {run.wall_s:6.1f} s  peak "
              f"{run.peak_MB:7.1f} MB")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=4096, help="shifts per batch (4096)")
    parser.add_argument("--pure-shifts", type=int, default=48, help="pure shifts a round (48)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (3)")
    parser.add_argument("--sections", default="1,2,3,4,5,6", help="which to run (1,...,6)")
    parser.add_argument("--scaling-cases", type=int, default=100_000,
                        help="cases of sections 5 and 6 (100000)")  # fmt: skip
    args = parser.parse_args()
    sections = set(args.sections.split(","))
    print(
        f"CPython {platform.python_version()} on {platform.machine()}, {sys.platform}, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start"
    )
    if "1" in sections:
        shift_steps(args)
    if "2" in sections:
        sweeps(args)
    if "3" in sections:
        refusals()
    if "4" in sections:
        streamed()
    if "5" in sections:
        scaling(args)
    if "6" in sections:
        command(args)
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


def shift_steps(args: argparse.Namespace) -> None:
    print("1. shift-steps per second (1 ms steps of driver + lever, features included)")
    ratios = []
    for r in range(args.rounds):
        pure = pure_rate(args.pure_shifts)
        batch = batch_rate(args.lanes)
        ratios.append(batch / pure)
        print(
            f"   round {r + 1}: pure step {pure:10,.0f}/s   batch of {args.lanes} lanes "
            f"{batch:11,.0f}/s   ratio {batch / pure:5.1f}"
        )
    print(
        f"   batch / pure: median {statistics.median(ratios):.1f} (min {min(ratios):.1f}, "
        f"max {max(ratios):.1f})"
    )


def sweeps(args: argparse.Namespace) -> None:
    print("2. Monte Carlo sweeps of single shifts (run_cases, rows and features included)")
    lanes = args.lanes
    pure_text = SPEC.format(samples=args.pure_shifts // 8 * 2, engine="pure", per_task=48)
    batch_text = SPEC.format(samples=lanes * 2 // 8, engine="batch", per_task=lanes)
    rate, n = sweep_rate(pure_text)
    print(f"   serial, pure step:            {rate:8.1f} shifts/s ({n} cases)")
    serial_batch, n = sweep_rate(batch_text)
    print(
        f"   serial, batch:                {serial_batch:8.1f} shifts/s ({n} cases, "
        f"{n // lanes} tasks of {lanes})"
    )
    distributed = runner.dask_modules()
    import logging

    rates = {}
    for workers in (1, 2):
        t0 = time.perf_counter()
        cluster = distributed.LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
        started = time.perf_counter() - t0
        try:
            address = cluster.scheduler_address
            rates[workers], n = sweep_rate(batch_text, scheduler=address)
            print(
                f"   {workers} worker{'s' if workers > 1 else ' '}, batch:"
                f"             {rates[workers]:8.1f} shifts/s ({n} cases)"
            )
            if workers == 2:
                rate, n = sweep_rate(pure_text, scheduler=address)
                print(f"   2 workers, pure step:         {rate:8.1f} shifts/s ({n} cases)")
        finally:
            cluster.close()
        print(f"   (the {workers}-worker LocalCluster took {started:.1f} s to start, not counted)")
    print(
        f"   2 workers / 1 worker: {rates[2] / rates[1]:.2f}; 2 workers / serial batch: "
        f"{rates[2] / serial_batch:.2f}"
    )
    t0 = time.perf_counter()
    with runner.dask_client(2, None) as (client, _, _, _):  # what --workers 2 starts: TLS
        started = time.perf_counter() - t0
        sweep = spec.from_toml(batch_text)
        done = np.zeros(sweep.n_cases, dtype=bool)
        n = 0
        t0 = time.perf_counter()

        def finished(chunk: tasks.Chunk) -> None:
            nonlocal n
            n += chunk.statuses()["ok"]

        runner._on_dask(client, runner.iter_tasks(sweep, done, 2), finished, tasks.run_chunk, 4)
        tls = n / (time.perf_counter() - t0)
    print(
        f"   2 workers with TLS (--workers 2), batch: {tls:8.1f} shifts/s ({n} cases); "
        f"/ plain 2 workers: {tls / rates[2]:.2f} (start {started:.1f} s, not counted)"
    )


TOLERANCES = """\
model = "shift"
preset = "paper-first-gear"
seeds = 8
samples = {samples}
sampling = "latin"
sampling_seed = 1
metrics = ["synchronization_force_N", "engagement_peak_N", "stop_overshoot_m", "shift_time_s"]
[run]
duration_s = 1.2
[set]
"driver.pull_out" = false
[vary]
"gearbox.chamfer.gear_inertia_kg_m2" = {{ values = [0.1, 0.153, 0.2] }}
"gearbox.chamfer.linkage_efficiency" = {{ distribution = "uniform", low = 0.7, high = 0.9 }}
"gearbox.neutral_detent.seat_force_N" = {{ distribution = "normal", mean = 5.0, sd = 0.5 }}
"driver.push_force_N" = {{ distribution = "truncnormal", mean = 80, sd = 12, low = 50, high = 120 }}
"driver.push_velocity_m_s" = {{ distribution = "uniform", low = 0.15, high = 0.5 }}
"""
"""The README's sweep of production tolerances: 3 grid values x `samples` draws x 8 seeds."""


def tolerances(cases: int) -> str:
    return TOLERANCES.format(samples=max(1, round(cases / 24)))


Spent = tuple[float, float]
"""(wall seconds, CPU-seconds of its own thread) of a task, measured inside it."""


def timed_chunk(task: tasks.Task) -> tuple[tasks.Chunk, Spent]:
    """A task's chunk and what it spent (for the workers' share of their time in tasks)."""
    t0, c0 = time.perf_counter(), time.thread_time()
    chunk = tasks.run_chunk(task)
    return chunk, (time.perf_counter() - t0, time.thread_time() - c0)


def _warm(_: int) -> int:
    """A pool process made ready as a Dask worker is before its first task (the imports)."""
    from carfeel.sweep import batch  # noqa: F401

    return os.getpid()


def _single_threaded() -> None:
    for name in runner.THREAD_VARIABLES:
        os.environ[name] = "1"


class Round:
    """Runs of one round, each measured the same way."""

    def __init__(self, sweep: spec.SweepSpec) -> None:
        self.sweep = sweep
        self.serial_s = float("nan")

    def measure(
        self, label: str, workers: int, go: Callable[[Iterator[tasks.Task]], list[Spent]]
    ) -> float:
        """Runs the sweep's tasks through `go` and prints: cases/s, the speed-up over the
        round's serial run, the workers' share of their time spent inside tasks (1 - it is
        what scheduling, transfers and an idle end cost), the tasks' share of their time on a
        core (what the others and a worker's own threads left them), the others' CPU."""
        done = np.zeros(self.sweep.n_cases, dtype=bool)
        todo = runner.iter_tasks(self.sweep, done, workers)
        busy0, cpu0, t0 = busy_s(), time.process_time(), time.perf_counter()
        spent = go(todo)
        wall = time.perf_counter() - t0
        busy, own = busy_s() - busy0, time.process_time() - cpu0
        in_tasks, on_core = sum(s[0] for s in spent), sum(s[1] for s in spent)
        ours = own + (on_core if label != "serial" else 0.0)
        others = max(busy - ours, 0.0)
        if label == "serial":
            self.serial_s = wall
        print(
            f"   {label:30s} {self.sweep.n_cases / wall:6.0f} cases/s {wall:6.1f} s "
            f"x{self.serial_s / wall:4.2f}; {len(spent)} tasks: {in_tasks / (workers * wall):6.1%} "
            f"of the workers' time, on a core {on_core / in_tasks:6.1%} of theirs; the others "
            f"{others:5.1f} CPU-s ({(os.cpu_count() or 1) - others / wall:.2f} cores left), "
            f"load {os.getloadavg()[0]:.1f}"
        )
        return wall


def scaling(args: argparse.Namespace) -> None:
    sweep = spec.from_toml(tolerances(args.scaling_cases))
    print(
        f"5. scaling: the README's tolerance sweep, {sweep.n_cases} single shifts in tasks of "
        f"{sweep.cases_per_task} (the same tasks through each); x = speed-up over the round's "
        "serial run; the others = the machine's CPU not spent by this process or in the tasks "
        "(the other sessions, and the workers' own upkeep)"
    )
    _single_threaded()  # the pool's processes inherit it, as Dask's workers are given it
    context = multiprocessing.get_context("spawn")
    for r in range(args.rounds):
        print(f"   round {r + 1}")
        measured = Round(sweep)

        def serial(todo: Iterator[tasks.Task]) -> list[Spent]:
            return [timed_chunk(task)[1] for task in todo]

        measured.measure("serial", 1, serial)
        walls: dict[str, float] = {}
        for n in (1, 2):
            with context.Pool(n) as pool:
                pool.map(_warm, range(n))

                def on_pool(todo: Iterator[tasks.Task], pool: Any = pool) -> list[Spent]:
                    return [spent for _, spent in pool.imap_unordered(timed_chunk, todo)]

                walls[f"pool {n}"] = measured.measure(f"multiprocessing pool of {n}", n, on_pool)
            with runner.dask_client(n, None) as (client, _, _, _):
                client.run(_warm, 0)

                def on_dask(
                    todo: Iterator[tasks.Task], client: Any = client, n: int = n
                ) -> list[Spent]:
                    spent: list[Spent] = []

                    def finished(result: tuple[tasks.Chunk, Spent]) -> None:
                        spent.append(result[1])

                    runner._on_dask(client, todo, finished, timed_chunk, 2 * n)
                    return spent

                walls[f"dask {n}"] = measured.measure(f"Dask LocalCluster (TLS) of {n}", n, on_dask)
        ratios = [f"{n} {walls[f'dask {n}'] / walls[f'pool {n}']:.3f}" for n in (1, 2)]
        print(f"   Dask's time over the pool's, by workers: {', '.join(ratios)}")


def command(args: argparse.Namespace) -> None:
    print(
        "6. the command: carfeel sweep SPEC --out r.parquet, serial and --workers 2, each in a "
        "child (wall time, the client's own peak memory, the CPU of it and its workers, the CPU "
        "the machine's other users took meanwhile)"
    )
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "tolerances.toml"
        path.write_text(tolerances(args.scaling_cases))
        out = str(Path(folder) / "r.parquet")
        cases = spec.load(path).n_cases
        base = ["-m", "carfeel.cli", "sweep", str(path), "--out", out]
        for r in range(max(1, args.rounds - 1)):
            serial = child(base)
            print(f"   {cases} cases serially    {serial.line()}")
            two = child([*base, "--workers", "2"])
            print(f"   {cases} cases, --workers 2 {two.line()}")
            print(f"   round {r + 1}: --workers 2 / serial = {two.wall_s / serial.wall_s:.2f}")
        path.write_text(tolerances(10 * args.scaling_cases))
        big = child([*base, "--workers", "2"])
        print(f"   {spec.load(path).n_cases} cases, --workers 2 {big.line()}")


if __name__ == "__main__":
    main()
