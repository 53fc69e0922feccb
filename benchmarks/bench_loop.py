"""The real-time loop on the wall clock: overruns and period errors, beside a reference loop.

Runs, in one process, one after the other:
1. a reference loop: the same sleep-then-spin against absolute deadlines, doing no work;
2. carfeel's loop rendering the H-pattern on the virtual joystick (impedance, 1 kHz), the
   simulated hand driving the gear sequence over and over.
Both for `--seconds` (default 20). Prints overruns (periods > 1.5 x nominal) and the period
error distribution of each, and their ratio. Asserts nothing; numbers go in notes, not tests.
    python benchmarks/bench_loop.py [--seconds 20]
"""

from __future__ import annotations

import argparse
import gc
import platform
import statistics
import time

from carfeel.realtime.clock import WallClock
from carfeel.realtime.session import RealtimeRun, run_realtime


def reference(seconds: float, rate_hz: float = 1000.0) -> tuple[int, list[float]]:
    clock = WallClock()
    period = round(1e9 / rate_hz)
    gc.collect()
    gc.freeze()
    start = last = clock.now_ns()
    errors, overruns = [], 0
    for k in range(1, round(seconds * rate_hz) + 1):
        clock.sleep_until(start + k * period)
        now = clock.now_ns()
        errors.append((now - last - period) / 1e3)
        overruns += now - last > 1.5 * period
        last = now
    gc.unfreeze()
    return overruns, errors


def describe(label: str, overruns: int, p50: float, p99: float, worst: float) -> None:
    print(
        f"{label:34s} overruns {overruns:4d}   period error p50 {p50:7.2f} us   "
        f"p99 {p99:8.2f} us   max {worst:9.1f} us"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    print(f"CPython {platform.python_version()} on {platform.machine()}, {args.seconds:g} s each")

    overruns, errors = reference(args.seconds)
    ordered = sorted(errors)
    ref = (
        overruns,
        statistics.median(ordered),
        ordered[int(0.99 * (len(ordered) - 1))],
        ordered[-1],
    )
    describe("reference loop (no work)", *ref)

    sequence = ("N", "1", "2", "3", "4", "5", "4", "3", "2", "1", "N") * 3
    t0 = time.process_time()
    result = run_realtime(
        RealtimeRun(
            model="hpattern", mode="impedance", duration_s=args.seconds, sequence=sequence,
            calibrate=False,
        )
    )  # fmt: skip
    cpu = time.process_time() - t0
    s = result.summary
    ours = (s.overruns, s.period_error_p50_us, s.period_error_p99_us, s.period_error_max_us)
    describe("carfeel loop (H-pattern, virtual)", *ours)
    print(f"gears engaged: {len(s.gears)}; faults: {len(s.faults)}")
    print(
        f"CPU busy {cpu / args.seconds * 100:.0f} % of the wall time (spinning included); "
        f"ratios carfeel / reference: p99 {ours[2] / max(ref[2], 1e-3):.1f}x, "
        f"max {ours[3] / max(ref[3], 1e-3):.1f}x"
    )


if __name__ == "__main__":
    main()
