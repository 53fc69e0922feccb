"""Shifts per second: the pure step against the vectorized batch, and whole sweeps serially,
batched and on a 2-worker Dask LocalCluster, all in one run. Prints numbers; asserts nothing.

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
    python benchmarks/bench_sweep.py [--lanes 4096] [--pure-shifts 48] [--rounds 3]
                                     [--sections 1,2,3,4]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from carfeel.analysis.shift_features import shift_features
from carfeel.io.presets import load_shift
from carfeel.simulation.shift import simulate_shift
from carfeel.sweep import runner, spec, tasks
from carfeel.sweep.batch import ShiftBatch

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


PEAK = (
    "import atexit, runpy, sys\n"
    "def peak():\n"
    "    hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')]\n"
    "    sys.stderr.write('peak ' + hwm[0].split()[1] + ' kB\\n')\n"
    "atexit.register(peak)\n"
    "args = sys.argv[1:]\n"
    "if args[0] == '-c':\n"
    "    sys.argv = ['-c', *args[2:]]\n"
    "    exec(compile(args[1], '<child>', 'exec'), {'__name__': '__main__'})\n"
    "else:\n"
    "    sys.argv = args\n"
    "    runpy.run_module(args[0], run_name='__main__', alter_sys=True)\n"
)
"""Runs `-m MODULE ARGS` or `-c CODE ARGS` and says its own peak memory (VmHWM) as it exits: a
child's ru_maxrss would count its parent's memory at the fork too."""


def child(command: list[str]) -> tuple[int, float, float]:
    """(exit code, wall seconds, peak RSS in MB) of `python -m MODULE ...` or `python -c CODE
    ...` (given without the interpreter) run as a child process."""
    t0 = time.perf_counter()
    arguments = command[1:] if command[0] == "-m" else command
    done = subprocess.run([sys.executable, "-c", PEAK, *arguments], capture_output=True,
                          text=True, check=False)  # fmt: skip
    wall = time.perf_counter() - t0
    said = done.stderr.rsplit("peak ", 1)
    peak = float(said[1].split()[0]) / 1024 if len(said) == 2 else float("nan")
    return done.returncode, wall, peak


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
    return [tasks._row(task.spec, c, {}, "ok", "") for c in task.cases]
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
    code, wall, rss = child(["-m", "carfeel.cli", "--version"])
    print(f"   reference: carfeel --version       exit {code}  {wall:5.2f} s  {rss:6.1f} MB")
    with tempfile.TemporaryDirectory() as folder:
        for label, text in OVERSIZED.items():
            path = Path(folder) / "big.toml"
            path.write_text(text)
            out = str(Path(folder) / "r.csv")
            code, wall, rss = child(["-m", "carfeel.cli", "sweep", str(path), "--out", out])
            print(f"   {label:32s} exit {code}  {wall:5.2f} s  {rss:6.1f} MB")


def streamed() -> None:
    print("4. a large sweep's memory (rows made without simulating: the runner and the writing)")
    for n, how in ((100_000, "held"), (100_000, "streamed"), (1_000_000, "streamed")):
        code, wall, rss = child(["-c", STREAMED, str(n), how])
        print(f"   {n:9,d} cases, rows {how:8s}  exit {code}  {wall:6.1f} s  peak {rss:7.1f} MB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=4096, help="shifts per batch (4096)")
    parser.add_argument("--pure-shifts", type=int, default=48, help="pure shifts a round (48)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (3)")
    parser.add_argument("--sections", default="1,2,3,4", help="which to run (1,2,3,4)")
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

        def finished(rows: list[dict[str, object]]) -> None:
            nonlocal n
            n += sum(r["status"] == "ok" for r in rows)

        runner._on_dask(client, runner.iter_tasks(sweep, done, 2), finished, tasks.run_task, 4)
        tls = n / (time.perf_counter() - t0)
    print(
        f"   2 workers with TLS (--workers 2), batch: {tls:8.1f} shifts/s ({n} cases); "
        f"/ plain 2 workers: {tls / rates[2]:.2f} (start {started:.1f} s, not counted)"
    )


if __name__ == "__main__":
    main()
