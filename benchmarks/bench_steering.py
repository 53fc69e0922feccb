"""Cost of the steering wheel torque law and of a full ISO 3888-1 run. Prints; asserts nothing.

- the law per sample in CPython (median and p99 per call),
- the same law vectorized over numpy arrays (samples per second),
- the car + torque step per 1 ms (imposed steering) and with the path driver,
- the physical model's step per 1 ms (brush tyres, nonlinear car, EPS steering system), imposed
  and hands off, beside the paper's law on the linear car,
- the wall time of a complete ISO 3888-1 double lane change simulation (7 s at 1 kHz), with
  either model.
    python benchmarks/bench_steering.py
"""

from __future__ import annotations

import gc
import math
import platform
import statistics
import time

import numpy as np

from carfeel.io.presets import load_steering
from carfeel.models.drivers import steering as path_driver
from carfeel.models.drivers.steering import PathFollowing
from carfeel.models.steering import physical
from carfeel.models.steering.torque import torque_terms
from carfeel.models.vehicle import single_track
from carfeel.simulation import manoeuvres
from carfeel.simulation.steering import (
    ImposedInputs,
    PathRun,
    PathState,
    imposed_step,
    path_step,
    simulate_steering,
)


def per_call(fn, n: int) -> list[float]:  # type: ignore[no-untyped-def]
    clock = time.perf_counter_ns
    samples = []
    for i in range(n):
        t0 = clock()
        fn(i)
        samples.append((clock() - t0) / 1e3)
    return samples


def report(label: str, samples: list[float]) -> None:
    ordered = sorted(samples)
    p99 = ordered[int(0.99 * (len(ordered) - 1))]
    print(f"{label:40s} median {statistics.median(ordered):6.2f} us   p99 {p99:6.2f} us")


def main() -> None:
    car = load_steering().params
    law = car.torque
    print(f"CPython {platform.python_version()} on {platform.machine()}")
    gc.collect()
    gc.freeze()

    rates = [math.sin(i * 1e-3) for i in range(200_000)]
    report(
        "torque law, one sample",
        per_call(lambda i: torque_terms(20.0, rates[i], 3.0 * rates[i], law), 200_000),
    )

    n = 1_000_000
    rng = np.random.default_rng(0)
    speed, rate, ay = rng.uniform(0, 40, n), rng.uniform(-5, 5, n), rng.uniform(-8, 8, n)
    best = math.inf
    for _ in range(5):
        t0 = time.perf_counter()
        torque_terms(speed, rate, ay, law, atan=np.arctan)
        best = min(best, time.perf_counter() - t0)
    print(f"{'torque law, numpy arrays':40s} {n / best / 1e6:6.1f} M samples/s ({n} per call)")

    state = single_track.initial_state()

    def imposed(i: int) -> None:
        nonlocal state
        state, _ = imposed_step(state, ImposedInputs(20.0, rates[i], rates[i]), car, 1e-3)

    report("car + torque, imposed steering, 1 ms", per_call(imposed, 100_000))

    segment = manoeuvres.build("iso3888", car.vehicle).segments[0]
    assert segment.path is not None
    run_params = PathRun(car, PathFollowing(car.driver, car.vehicle, segment.path))
    path_state = PathState(single_track.initial_state(-30.0), path_driver.initial_state())
    speed_m_s = 80 / 3.6

    def follow(i: int) -> None:
        nonlocal path_state
        path_state, _ = path_step(path_state, speed_m_s, run_params, 1e-3)

    report("car + torque + path driver, 1 ms", per_call(follow, 6000))

    params = car.physical()
    model = physical.initial_state(params)

    def physical_imposed(i: int) -> None:
        nonlocal model
        inputs = physical.PhysicalInputs(20.0, rates[i], rates[i], 0.0, 1.0)
        model, _ = physical.step(model, inputs, params, 1e-3)

    report("physical model, imposed steering, 1 ms", per_call(physical_imposed, 100_000))
    model = physical.initial_state(params)._replace(hand_angle_rad=1.0, column_anchor_rad=1.0)

    def physical_free(i: int) -> None:
        nonlocal model
        model, _ = physical.step(model, physical.PhysicalInputs(20.0, 0.0, 0.0, 0.0, 0.0),
                                 params, 1e-3)  # fmt: skip

    report("physical model, hands off, 1 ms", per_call(physical_free, 100_000))

    for name in ("paper", "physical"):
        walls = []
        for _ in range(5):
            t0 = time.perf_counter()
            simulate_steering(car, manoeuvres.build("iso3888", car.vehicle), model=name)
            walls.append(time.perf_counter() - t0)
        print(
            f"{'ISO 3888-1 run, 7 s at 1 kHz, ' + name:40s} median "
            f"{statistics.median(walls) * 1e3:6.1f} ms wall "
            f"({7.0 / statistics.median(walls):.0f}x real time)"
        )


if __name__ == "__main__":
    main()
