"""Cost of one 1 ms step of the gear engagement in CPython, per call: median and p99.

Runs the closed loop (driver + lever) through whole shifts, in and out, so every stage is
timed in proportion to how long a shift spends in it. Prints numbers; asserts nothing.
    python benchmarks/bench_engagement_step.py [--shifts N]
"""

from __future__ import annotations

import argparse
import gc
import platform
import statistics
import sys
import time
from dataclasses import replace

from carfeel.io.presets import load_shift
from carfeel.models.gearshift import engagement
from carfeel.simulation import shift


def time_steps(substeps: int, shifts: int) -> list[float]:
    """Wall time of each 1 ms output step (with `substeps` model steps inside), in us."""
    params = load_shift().params
    params = replace(params, driver=replace(params.driver, pull_out=True))
    h = 1e-3 / substeps
    samples: list[float] = []
    clock = time.perf_counter_ns
    step = shift.step
    for seed in range(shifts):
        state = shift.initial_state(seed)
        for _ in range(2000):  # 2 s: neutral -> first -> neutral
            t0 = clock()
            for _ in range(substeps):
                state, _out = step(state, None, params, h)
            samples.append((clock() - t0) / 1e3)
    return samples


def time_lever_only(substeps: int, shifts: int) -> list[float]:
    """The engagement model alone, fed a push-then-pull force, in us per 1 ms step."""
    gearbox = load_shift().params.gearbox
    forces = [60.0] * 900 + [-20.0] * 1100
    h = 1e-3 / substeps
    samples: list[float] = []
    clock = time.perf_counter_ns
    step = engagement.step
    for seed in range(shifts):
        state = engagement.initial_state(seed)
        for force in forces:
            inputs = engagement.EngagementInputs(force)
            t0 = clock()
            for _ in range(substeps):
                state, _out = step(state, inputs, gearbox, h)
            samples.append((clock() - t0) / 1e3)
    return samples


def clock_overhead_us() -> float:
    clock = time.perf_counter_ns
    values = []
    for _ in range(100_000):
        t0 = clock()
        values.append(clock() - t0)
    return statistics.median(values) / 1e3


def report(label: str, samples: list[float]) -> None:
    ordered = sorted(samples)
    p99 = ordered[int(0.99 * (len(ordered) - 1))]
    print(
        f"{label:44s} median {statistics.median(ordered):6.2f} us   p99 {p99:6.2f} us   "
        f"max {ordered[-1]:8.1f} us   (n={len(ordered)})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shifts", type=int, default=50, help="shifts per case (default 50)")
    args = parser.parse_args()
    print(f"CPython {platform.python_version()} on {platform.machine()}, {sys.platform}")
    print(f"timer overhead (included below): {clock_overhead_us():.3f} us per reading pair")
    gc.collect()
    gc.freeze()
    for _ in range(2):  # warm-up
        time_steps(1, 1)
    report("engagement, 1 step per 1 ms", time_lever_only(1, args.shifts))
    report("engagement, 10 sub-steps per 1 ms", time_lever_only(10, args.shifts // 5 or 1))
    report("driver + engagement, 1 step per 1 ms", time_steps(1, args.shifts))
    report("driver + engagement, 10 sub-steps per 1 ms", time_steps(10, args.shifts // 5 or 1))


if __name__ == "__main__":
    main()
