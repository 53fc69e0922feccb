"""The real-time loop on the wall clock: overruns and period errors, beside a reference loop.

Runs, in one process, one after the other:
1. a reference loop: the same sleep-then-spin against absolute deadlines, doing no work;
2. carfeel's loop rendering the H-pattern on the virtual joystick (impedance, 1 kHz), the
   simulated hand driving the gear sequence over and over;
3. the steering on the virtual dd-wheel (100 km/h, the hands weaving), the paper's law and then
   the physical model behind its coupling (issue 13), one after the other;
4. with --levers, the sequential lever on the virtual shifter and the PRND selector on the
   virtual joystick, their virtual hands repeating their default scripts (issue 30).
Each for `--seconds` (default 20). Prints overruns (periods > 1.5 x nominal) and the period
error distribution of each, and their ratio. `--cpu N` pins the process to core N (the machine
is shared: say so beside the numbers). Asserts nothing; numbers go in notes, not tests.
    python benchmarks/bench_loop.py [--seconds 20] [--cpu N] [--steering-only] [--levers]
"""

from __future__ import annotations

import argparse
import gc
import os
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
    parser.add_argument("--cpu", type=int, default=None, help="pin the process to this core")
    parser.add_argument("--steering-only", action="store_true")
    parser.add_argument("--levers", action="store_true", help="then the two levers (issue 30)")
    args = parser.parse_args()
    pinned = ""
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
        pinned = f", pinned to core {args.cpu}"
    print(f"CPython {platform.python_version()} on {platform.machine()}, {args.seconds:g} s each"
          f"{pinned}; load average {os.getloadavg()[0]:.1f}")  # fmt: skip

    overruns, errors = reference(args.seconds)
    ordered = sorted(errors)
    ref = (
        overruns,
        statistics.median(ordered),
        ordered[int(0.99 * (len(ordered) - 1))],
        ordered[-1],
    )
    describe("reference loop (no work)", *ref)
    if not args.steering_only:
        hpattern(args.seconds, ref)
    for model in ("paper", "physical"):
        timed(f"steering {model} (dd-wheel, virtual)", ref, RealtimeRun(
            model="steering", steering_model=model, device="virtual:dd-wheel", speed_kmh=100.0,
            duration_s=args.seconds, calibrate=False))  # fmt: skip
    if args.levers:
        from carfeel.realtime.run_options import DEFAULT_SEQUENCES

        for model, device in (("sequential", "virtual:shifter"), ("prnd", "virtual:joystick")):
            timed(f"{model} ({device})", ref, RealtimeRun(
                model=model, device=device, duration_s=args.seconds, calibrate=False,
                sequence=DEFAULT_SEQUENCES[model] * 20))  # fmt: skip


def timed(label: str, ref: tuple[int, float, float, float], run: RealtimeRun) -> None:
    """One run on the wall clock: its period errors beside the reference's, its CPU share."""
    t0 = time.process_time()
    result = run_realtime(run)
    cpu = time.process_time() - t0
    s = result.summary
    ours = (s.overruns, s.period_error_p50_us, s.period_error_p99_us, s.period_error_max_us)
    describe(label, *ours)
    seconds = run.duration_s or 1.0
    print(f"  {s.periods} periods, {len(s.gears)} gears, stopped by {s.stopped} "
          f"{'; '.join(s.faults)}; CPU busy {cpu / seconds * 100:.0f} % of the wall time; "
          f"p99 / reference {ours[2] / max(ref[2], 1e-3):.1f}x")  # fmt: skip


def hpattern(seconds: float, ref: tuple[int, float, float, float]) -> None:
    sequence = ("N", "1", "2", "3", "4", "5", "4", "3", "2", "1", "N") * 3
    t0 = time.process_time()
    result = run_realtime(
        RealtimeRun(
            model="hpattern", mode="impedance", duration_s=seconds, sequence=sequence,
            calibrate=False,
        )
    )  # fmt: skip
    cpu = time.process_time() - t0
    s = result.summary
    ours = (s.overruns, s.period_error_p50_us, s.period_error_p99_us, s.period_error_max_us)
    describe("carfeel loop (H-pattern, virtual)", *ours)
    print(f"gears engaged: {len(s.gears)}; faults: {len(s.faults)}")
    print(
        f"CPU busy {cpu / seconds * 100:.0f} % of the wall time (spinning included); "
        f"ratios carfeel / reference: p99 {ours[2] / max(ref[2], 1e-3):.1f}x, "
        f"max {ours[3] / max(ref[3], 1e-3):.1f}x"
    )


if __name__ == "__main__":
    main()
