"""Shifts per second: the pure step against the vectorized batch, and whole sweeps serially,
batched and on a 2-worker Dask LocalCluster, all in one run. Prints numbers; asserts nothing.

1. shift-steps per second of the pure step (`simulate_shift` + its features, what the pure
   engine runs per case) and of the batch (`ShiftBatch.run` with its features), measured in
   alternating rounds so that both see the same load; the ratio is per round.
2. a Monte Carlo sweep (`run_cases`) of single shifts: the pure engine serially, the batch
   serially, the batch on a LocalCluster of 2 single-threaded workers (its start-up timed
   apart), and the pure engine on it.
    python benchmarks/bench_sweep.py [--lanes 4096] [--pure-shifts 48] [--rounds 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import sys
import time

from carfeel.analysis.shift_features import shift_features
from carfeel.io.presets import load_shift
from carfeel.simulation.shift import simulate_shift
from carfeel.sweep import runner, spec
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=4096, help="shifts per batch (4096)")
    parser.add_argument("--pure-shifts", type=int, default=48, help="pure shifts a round (48)")
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (3)")
    args = parser.parse_args()
    print(
        f"CPython {platform.python_version()} on {platform.machine()}, {sys.platform}, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start"
    )
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
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
