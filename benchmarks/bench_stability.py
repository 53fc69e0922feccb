"""What stability costs per tick, and the stability matrix.

1. Per-tick cost (median and p99 over many ticks, CPython) of the elements issue 9 added to the
   1 kHz path: the passivity controller, the oscillation guard, the new steering renderer (front
   axle, friction element, scheduled damping, stop) and the sized H-pattern renderer, each beside
   a reference measured in the same run: the force limiter every tick already paid, and the
   paper's torque law alone. Then the one-off cost of sizing a device at start-up.
2. The stability matrix (`carfeel.realtime.matrix`): per cell, the command's peak-to-peak over
   the last second as a share of the force limit, or the reason the loop refused the cell.
Asserts nothing; the numbers go in notes, not tests.
    python benchmarks/bench_stability.py [--ticks 20000] [--no-matrix]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from collections.abc import Callable

from carfeel.io.presets import load_hpattern, load_steering
from carfeel.models.steering.torque import torque_terms
from carfeel.realtime import matrix
from carfeel.realtime.devices.base import DeviceSample
from carfeel.realtime.devices.virtual import virtual_device
from carfeel.realtime.rendering import (
    Gains,
    HPatternRenderer,
    Scaling,
    SteeringRenderer,
    default_scaling,
    velocity_sections,
)
from carfeel.realtime.safety import (
    ForceLimiter,
    OscillationGuard,
    PassivityController,
    SafetyLimits,
)
from carfeel.realtime.stability import size


def per_call(body: Callable[[int], object], ticks: int) -> tuple[float, float]:
    """(median, p99) of one call, us, timed in batches of 10 calls."""
    times = []
    for k in range(0, ticks, 10):
        start = time.perf_counter_ns()
        for j in range(k, k + 10):
            body(j)
        times.append((time.perf_counter_ns() - start) / 10e3)
    times.sort()
    return statistics.median(times), times[int(0.99 * (len(times) - 1))]


def row(label: str, numbers: tuple[float, float], reference: tuple[float, float]) -> None:
    print(
        f"  {label:44s} median {numbers[0]:6.2f} us  p99 {numbers[1]:6.2f} us  "
        f"({numbers[0] / reference[0]:5.1f} x the reference)"
    )


def costs(ticks: int) -> None:
    limits = SafetyLimits(10.0, 2000.0)
    limiter = ForceLimiter(limits, 2)
    ref = per_call(lambda k: limiter.limit((0.001 * (k % 7), -0.5), 1e-3), ticks)
    print(f"per tick, {ticks} ticks each (reference: the force limiter, 2 axes)")
    print(f"  {'reference: ForceLimiter.limit':44s} median {ref[0]:6.2f} us  p99 {ref[1]:6.2f} us")
    pc = PassivityController(2, 1.5, 4e-4, 0.02, round_trip_ticks=4)

    def passivity(k: int) -> None:
        x = 1e-4 * (k % 13)
        pc.apply((0.3, -0.2), (x, -x), 1e-3)
        pc.applied((0.3, -0.2))

    row("PassivityController (apply + applied)", per_call(passivity, ticks), ref)
    guard = OscillationGuard(2, 10.0, 0.04, 1000.0)

    def watch(k: int) -> None:
        guard.check((0.01 * (k % 5), 0.0), (1e-4 * (k % 3), 0.0), 1e-3)

    row("OscillationGuard.check", per_call(watch, ticks), ref)

    wheel = virtual_device("wheel")
    car = load_steering("b-segment").params
    sizing = size(wheel.info, 1000.0, velocity_sections(1000.0))
    steering = SteeringRenderer(car, 100 / 3.6, Scaling(0.36, 1.0), 1000.0, sizing, wheel.info)

    def steer(k: int) -> None:
        steering.tick(DeviceSample(k * 1e-3, (0.2 * ((k % 200) / 200.0 - 0.5),), None), 1e-3)

    law = per_call(lambda k: torque_terms(27.8, 0.1 * (k % 5), 2.0, car.torque), ticks)
    row("reference 2: the paper's torque law alone", law, ref)
    row("SteeringRenderer.tick (car + new terms)", per_call(steer, ticks), ref)

    stick = virtual_device("joystick")
    preset = load_hpattern("5r")
    scaling = default_scaling(100.0, 0.058, stick.info)
    gains = Gains.sized(size(stick.info, 1000.0, velocity_sections(1000.0)), scaling)
    pattern = HPatternRenderer(preset.pattern(), "impedance", scaling, 1000.0, gains,
                               vehicle_speed_m_s=8.3)  # fmt: skip

    def shift(k: int) -> None:
        pattern.tick(DeviceSample(k * 1e-3, (0.001 * (k % 20), 0.0), None), 1e-3)

    row("HPatternRenderer.tick (sized coupling)", per_call(shift, ticks), ref)

    print("start-up: sizing a device (discrete-time loop analysis, not cached)")
    for kind in ("joystick", "wheel", "dd-wheel", "shifter"):
        info = virtual_device(kind, delay_s=0.004).info
        size.cache_clear()
        start = time.perf_counter()
        s = size(info, 1000.0, velocity_sections(1000.0))
        took = time.perf_counter() - start
        print(f"  {kind:9s} 4 ms each way: {took * 1e3:6.1f} ms -> stiffness {s.stiffness:8.4g}, "
              f"damping {s.damping:6.3g}, cap {s.damping_cap:6.3g}, zeta {s.zeta:.2f}")  # fmt: skip


def table() -> None:
    print("stability matrix (peak-to-peak of the command over the last second, % of the limit)")
    start = time.perf_counter()
    for cell in matrix.matrix():
        label = (
            f"{cell.model:8s} {cell.mode:10s} {cell.plant:9s} {cell.delay_ms:3.0f} ms "
            f"{cell.hand:8s}"
        )
        if cell.refused is not None:
            print(f"  {label} refused: {cell.refused.split(': ', 1)[-1][:90]}...")
            continue
        verdict = "ok" if cell.passed else "FAILS"
        print(
            f"  {label} {100 * cell.ripple_fraction:5.2f} %  at limit {cell.at_limit!s:5s}  "
            f"model peak {cell.model_peak:6.1f}  gears {' '.join(cell.gears) or '-':7s} {verdict}"
        )
    print(f"  ({time.perf_counter() - start:.0f} s of simulated runs)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=20_000)
    parser.add_argument("--no-matrix", action="store_true")
    args = parser.parse_args()
    print(f"CPython {platform.python_version()} on {platform.machine()}")
    costs(args.ticks)
    if not args.no_matrix:
        table()


if __name__ == "__main__":
    main()
