"""What stability costs per tick, and the stability matrix.

1. Per-tick cost (median and p99 over many ticks, CPython) of the elements issue 9 added to the
   1 kHz path: the passivity controller, the oscillation guard, the new steering renderer (front
   axle, friction element, scheduled damping, stop) and the sized H-pattern renderer, each beside
   a reference measured in the same run: the force limiter every tick already paid, and the
   paper's torque law alone; the physical steering renderer (issue 13: the model behind its
   coupling) beside the paper's renderer on the dd-wheel. Then the one-off cost of sizing a
   device, and the physical steering on it, at start-up, and of the panel's check of a live
   tuning of the physical steering beside it.
2. The released physical wheel (4 ms each way, both wheels, 30 and 90 deg, 60-150 km/h): the
   log-decrement damping ratio of each pair of swings.
3. The stability matrix (`carfeel.realtime.matrix`): per cell, the command's peak-to-peak over
   the last second as a share of the force limit, or the reason the loop refused the cell.
4. Device identification (issue 23): per device class, on its catalogue plant and on true
   plants unlike it, the identification's (simulated) duration, its largest force and what it
   found beside the truth; the start-up check of a stored profile; the CPU time of the fit
   beside the time of the loop's own 1,000 ticks on the same device.
5. The passivity controller's share of a nominal run (each model on each plant, the device
   identified, hands off and shifting).
6. The mismatch matrix (issue 23): model x plant x true plant x hand, with the device
   identified (every cell stable or refused) and with identification off (sized for the
   declared set: no oscillation over a tenth of the limit lasts more than 0.2 s before the
   fade); and the review's cases with the sizing trusting the told plant, where only the guard
   stands between the user and the limit cycle: how long it oscillated before the fade.
Asserts nothing; the numbers go in notes, not tests.
    python benchmarks/bench_stability.py [--ticks 20000] [--no-matrix] [--no-release]
        [--no-identify] [--no-mismatch] [--workers 2]
"""

from __future__ import annotations

import argparse
import itertools
import math
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

from carfeel.errors import InputError
from carfeel.io.presets import load_hpattern, load_steering
from carfeel.models.steering.torque import torque_terms
from carfeel.panel import tuning
from carfeel.realtime import matrix
from carfeel.realtime.devices.base import DeviceSample
from carfeel.realtime.devices.virtual import virtual_device
from carfeel.realtime.physical_steering import (
    SPEEDS_M_S,
    PhysicalSizing,
    PhysicalSteeringRenderer,
    size_physical,
)
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

    dd = virtual_device("dd-wheel", delay_s=0.004)
    dd_sizing = size(dd.info, 1000.0, velocity_sections(1000.0))
    dd_scaling = Scaling(1.35, 1.0)
    params = car.physical()
    sized = size_physical(dd.info, 1000.0, velocity_sections(1000.0), params, dd_scaling,
                          dd_sizing, 1, (100 / 3.6,))  # fmt: skip
    assert isinstance(sized, PhysicalSizing)
    paper = SteeringRenderer(car, 100 / 3.6, dd_scaling, 1000.0, dd_sizing, dd.info)
    physical = PhysicalSteeringRenderer(params, 100 / 3.6, dd_scaling, 1000.0, sized, dd.info)

    def sample(k: int) -> DeviceSample:
        return DeviceSample(k * 1e-3, (0.2 * math.sin(2 * math.pi * 0.5 * k * 1e-3),), None)

    paper_tick = per_call(lambda k: paper.tick(sample(k), 1e-3), ticks)
    physical_tick = per_call(lambda k: physical.tick(sample(k), 1e-3), ticks)
    row("dd-wheel: SteeringRenderer.tick (paper)", paper_tick, ref)
    row("dd-wheel: PhysicalSteeringRenderer.tick", physical_tick, ref)
    print(f"  {'':44s} physical / paper: {physical_tick[0] / paper_tick[0]:.1f} x (median)")

    stick = virtual_device("joystick")
    preset = load_hpattern("5r")
    scaling = default_scaling(100.0, 0.058, stick.info)
    gains = Gains.sized(size(stick.info, 1000.0, velocity_sections(1000.0)), scaling)
    pattern = HPatternRenderer(preset.pattern(), "impedance", scaling, 1000.0, gains,
                               vehicle_speed_m_s=8.3)  # fmt: skip

    def shift(k: int) -> None:
        pattern.tick(DeviceSample(k * 1e-3, (0.001 * (k % 20), 0.0), None), 1e-3)

    row("HPatternRenderer.tick (sized coupling)", per_call(shift, ticks), ref)

    print("start-up: sizing the physical steering on a wheel, 4 ms each way (not cached)")
    for kind in ("wheel", "dd-wheel"):
        info = virtual_device(kind, delay_s=0.004).info
        device_sizing = size(info, 1000.0, velocity_sections(1000.0))
        scale = Scaling(0.9 * info.max_force / 10.0, 1.0)
        for label, speeds in (("100 km/h", (100 / 3.6,)), ("0-252 km/h", SPEEDS_M_S)):
            size_physical.cache_clear()
            start = time.perf_counter()
            found = size_physical(info, 1000.0, velocity_sections(1000.0), params, scale,
                                  device_sizing, 1, speeds)  # fmt: skip
            took = time.perf_counter() - start
            what = (
                found
                if isinstance(found, str)
                else f"coupling {found.coupling_stiffness:.3g} "
                f"Nm/rad, least zeta {min(found.zeta):.2f}, up to {found.top_speed_m_s * 3.6:.0f}"
                " km/h"
            )
            print(f"  {kind:9s} {label:10s}: {took * 1e3:7.1f} ms -> {what}")
            if isinstance(found, PhysicalSizing):  # the panel's check of a live tuning on it
                ready = {"info": info, "sizing": device_sizing, "scaling": scale,
                         "rate_hz": 1000.0, "speed_m_s": 100 / 3.6, "physical": found}  # fmt: skip
                live = tuning.Session("steering", car, None, ready, "physical", "dry")
                start = time.perf_counter()
                try:
                    note = tuning.propose(live, {"tyres.pneumatic_trail_m": 0.05}).note
                    verdict = f"accepted{f' ({note})' if note else ''}"
                except InputError as exc:
                    verdict = f"refused ({str(exc)[:60]}...)"
                tuned = time.perf_counter() - start
                print(
                    f"  {'':20s}  a live tuning (trail 0.04 -> 0.05 m) checked: "
                    f"{tuned * 1e3:7.1f} ms, {tuned / took:.2f}x the sizing, {verdict}"
                )
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


def releases() -> None:
    """The released physical wheel on both wheels, 4 ms each way: the log-decrement damping
    ratio of each pair of successive swings, and where the rim came to rest."""
    import numpy as np

    from carfeel.realtime import session
    from carfeel.realtime.session import RealtimeRun, run_realtime

    print(
        "released physical wheel, 4 ms each way (overshoot beside the offline model's; the "
        "log-decrement damping ratio of each pair of later swings; rest angle)"
    )
    original = session.open_device
    made: list[object] = []

    def keep(*args: object, **kwargs: object) -> object:
        device = original(*args, **kwargs)  # type: ignore[arg-type]
        device.keep_log = True  # type: ignore[attr-defined]  # a session's keeps none
        made.append(device)
        return device

    for plant, angle, speed in itertools.product(("wheel", "dd-wheel"), (30.0, 90.0),
                                                 (60.0, 100.0, 120.0, 150.0)):  # fmt: skip
        made.clear()
        session.open_device = keep  # type: ignore[assignment]
        try:
            run_realtime(RealtimeRun(model="steering", steering_model="physical",
                                     device=f"virtual:{plant}", clock="simulated",
                                     hand="release", speed_kmh=speed, device_delay_ms=4.0,
                                     duration_s=6.0, release_angle_deg=angle))  # fmt: skip
        finally:
            session.open_device = original
        device: Any = made[0]
        t = np.array([a for a, _, _ in device.log])
        x = np.degrees([p[0] for _, p, _ in device.log])[t >= device.hand.released_at_s]
        extremes = [x[0]] + [x[i] for i in range(1, len(x) - 1)
                             if (x[i] - x[i - 1]) * (x[i + 1] - x[i]) < 0]  # fmt: skip
        swings = [s for s in (abs(b - a) for a, b in itertools.pairwise(extremes)) if s > 0.5]
        zetas = []
        for a, b in itertools.pairwise(swings):
            delta = 2.0 * math.log(a / b)
            zetas.append(delta / math.sqrt(4 * math.pi**2 + delta**2))
        ratios = " ".join(f"{z:.2f}" for z in zetas) or "-"
        print(
            f"  {plant:9s} {angle:3.0f} deg {speed:4.0f} km/h: overshoot {overshoot(x):5.1f} % "
            f"(offline {overshoot(offline(speed, angle)):5.1f} %), swing zeta {ratios:10s} "
            f"rest {x[-1]:6.2f} deg"
        )


def overshoot(x: Any) -> float:
    """How far past the centre the first swing goes, % of the release angle (0: it stops on
    its side, held by the friction)."""
    import numpy as np

    past = -np.sign(x[0]) * x
    return float(max(0.0, np.max(past)) / abs(x[0]) * 100.0)


def offline(speed_kmh: float, angle_deg: float) -> Any:
    """The offline model released the same way (the tests' release: 0.5 s turn, 1 s hold)."""
    import numpy as np

    from carfeel.models.steering import physical
    from carfeel.models.steering.physical import PhysicalInputs
    from carfeel.simulation.steering import physical_start

    params = load_steering("b-segment").params.physical()
    v, a0 = speed_kmh / 3.6, math.radians(angle_deg)
    state = physical_start(params, v, 0.0)
    angles = []
    for k in range(7500):
        t = k * 1e-3
        if t < 0.5:
            turn = 0.5 * (1 - math.cos(math.pi * t / 0.5))
            rate = a0 * 0.5 * math.pi / 0.5 * math.sin(math.pi * t / 0.5)
            inputs = PhysicalInputs(v, a0 * turn, rate, 0.0, 1.0)
        elif t < 1.5:
            inputs = PhysicalInputs(v, a0, 0.0, 0.0, 1.0)
        else:
            inputs = PhysicalInputs(v, 0.0, 0.0, 0.0, 0.0)
        state, out = physical.step(state, inputs, params, 1e-3)
        if t >= 1.5:
            angles.append(out.steering_angle_rad)
    return np.degrees(angles)


def identification() -> None:
    """The identification per class, on its catalogue plant and on three plants unlike it."""
    from carfeel.realtime import identify, profiles
    from carfeel.realtime.clock import SimulatedClock
    from carfeel.realtime.loop import LoopConfig, run_loop

    print("device identification (simulated time; the fit's CPU time beside 1,000 ticks of "
          "the loop on the same device)")  # fmt: skip
    trues = {"catalogue": {}, "mass 0.5x, delay 6 ms": {"mass": (0.5, True),
             "delay_ms": (6.0, False)}, "damping 0.3x, friction 3x": {"damping": (0.3, True),
             "friction": (3.0, True)}, "reports 250 Hz": {"report_hz": (250.0, False)}}  # fmt: skip
    for kind in ("joystick", "shifter", "wheel", "dd-wheel"):
        for label, changes in trues.items():
            device = virtual_device(kind, true=changes)
            info = device.info
            limits = SafetyLimits(info.max_force, max(info.max_force / 0.05, 200 * info.max_force))
            start = time.perf_counter()
            with device:
                found = identify.identify(device, SimulatedClock(), 1000.0, 0, limits)
            cpu = time.perf_counter() - start
            reference = _loop_seconds(device, LoopConfig, run_loop)
            plant = device.plant
            a = found.axes[0]
            print(
                f"  {kind:9s} {label:26s} {found.duration_s:4.1f} s, peak "
                f"{found.peak_force / found.max_force:4.0%} of the limit; inertia "
                f"{a.mass / plant.mass - 1:+6.1%}, damping {a.damping / plant.damping - 1:+6.1%}, "
                f"friction {a.friction / plant.coulomb - 1:+6.1%}, round trip "
                f"{a.round_trip_s * 1e3:5.2f} ms (+-{a.round_trip_sigma_s * 1e3:.2f}), reports "
                f"{a.report_hz:5.0f}; CPU {cpu:5.2f} s (1,000 loop ticks {reference:5.2f} s)"
            )
        device = virtual_device(kind)
        info = device.info
        limits = SafetyLimits(info.max_force, max(info.max_force / 0.05, 200 * info.max_force))
        with device:
            found = identify.identify(device, SimulatedClock(), 1000.0, 0, limits)
        stored = profiles.new_profile(info, found)
        again = virtual_device(kind, seed=3)
        clock = SimulatedClock()
        with again:
            check = profiles.check(again, clock, 1000.0, 0, limits, stored)
        print(f"  {kind:9s} its profile's check at a later start: {clock.now_ns() / 1e9:.2f} s, "
              f"{check.reason or 'holds'} (shift {check.shift_s * 1e3:.2f} ms, gain "
              f"{check.gain:.3f})")  # fmt: skip


def _loop_seconds(device: Any, config: Any, run_loop: Any) -> float:
    """CPU time of 1,000 ticks of the loop rendering a spring on the device (the reference)."""
    from carfeel.realtime.clock import SimulatedClock

    class Spring:
        axes = device.info.axes
        columns: tuple[str, ...] = ()
        gears: tuple[str, ...] = ()
        substeps = 1
        effect = 0.0

        def tick(self, sample: Any, dt_s: float) -> Any:
            return tuple(-10.0 * x for x in sample.positions), ()

    fresh = virtual_device(device.info.name.split()[-1])
    info = fresh.info
    start = time.perf_counter()
    with fresh:
        run_loop(Spring(), fresh, SimulatedClock(), config(1000.0, 1.0, calibrate=False),
                 SafetyLimits(info.max_force, 200 * info.max_force))  # fmt: skip
    return time.perf_counter() - start


def passivity_share() -> None:
    from carfeel.realtime.session import RealtimeRun, run_realtime

    print("the passivity controller's share of a nominal run (6 s, the device identified)")
    for model, plant in (("shift", "joystick"), ("shift", "shifter"), ("hpattern", "joystick"),
                         ("hpattern", "shifter"), ("steering", "wheel"),
                         ("steering", "dd-wheel")):  # fmt: skip
        for hand in ("none", "script"):
            result = run_realtime(RealtimeRun(
                model=model, device=f"virtual:{plant}", hand=hand, clock="simulated",
                sequence=("N", "1", "2", "N"), duration_s=6.0,
                speed_kmh=100.0 if model == "steering" else 30.0))  # fmt: skip
            s = result.summary
            print(
                f"  {model:8s} {plant:9s} {hand:6s}: acted {s.passivity_acted_s:.3f} s of "
                f"{s.periods / 1000:.1f} s ({s.passivity_acted_s / (s.periods / 1000):.1%})"
            )


def mismatch(workers: int) -> None:
    """The mismatch matrix with identification on and off, and the review's cases trusted."""
    from unittest import mock

    from carfeel.realtime import knowledge

    for identify in ("auto", "off"):
        start = time.perf_counter()
        cells = matrix.mismatch_matrix(identify, workers=workers)
        took = time.perf_counter() - start

        def verdict(c: matrix.MismatchCell, identify: str = identify) -> bool:
            return c.stable if identify == "auto" else c.guarded

        print(f"mismatch matrix, identification {identify} ({len(cells)} cells, {took:.0f} s "
              f"on {workers} workers): {sum(verdict(c) for c in cells)} pass, "
              f"{sum(c.refused is not None for c in cells)} refused, "
              f"{sum(bool(c.faults) for c in cells)} faulted")  # fmt: skip
        for c in cells:
            label = f"  {c.model:8s} {c.plant:9s} {c.true:14s} {c.hand:8s}"
            if c.refused is not None:
                print(f"{label} refused: {c.refused[:100]}")
            elif c.faults:
                print(f"{label} faulted after oscillating {c.oscillating_s:.3f} s: "
                      f"{c.faults[0][:80]}")  # fmt: skip
            else:
                print(f"{label} {100 * c.ripple_fraction:6.2f} % over the last second"
                      f"{'  AT THE LIMIT' if c.at_limit else ''}"
                      f"{'' if verdict(c) else '  FAILS'}")  # fmt: skip
    print("the review's cases with the sizing trusting the told plant (the guard alone)")
    review = [("shift", "joystick", "delay 4x", "none"), ("shift", "joystick", "delay 3x", "none"),
              ("steering", "dd-wheel", "mass 0.6x", "release"),
              ("steering", "dd-wheel", "mass 0.4x", "release"),
              ("shift", "shifter", "delay 2x", "none"),
              ("steering", "dd-wheel", "delay 2x", "release"),
              ("steering", "dd-wheel", "delay 3x", "release"),
              ("hpattern", "shifter", "delay 3x", "script")]  # fmt: skip
    with mock.patch.object(knowledge, "declared_set", lambda info: info):
        cells = matrix.mismatch_matrix("off", workers=1, cells=review)
    for c in cells:
        label = f"  {c.model:8s} {c.plant:9s} {c.true:14s} {c.hand:8s}"
        if c.faults:
            print(f"{label} faded after oscillating {c.oscillating_s:.3f} s over a tenth of the "
                  f"limit: {c.faults[0][:70]}")  # fmt: skip
        else:
            print(f"{label} no fault; {100 * c.ripple_fraction:.2f} % over the last second")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=20_000)
    parser.add_argument("--no-matrix", action="store_true")
    parser.add_argument("--no-release", action="store_true")
    parser.add_argument("--no-identify", action="store_true")
    parser.add_argument("--no-mismatch", action="store_true")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    import os
    import tempfile

    # Device profiles of the benchmark's own (a user's stay untouched).
    os.environ["CARFEEL_CONFIG_DIR"] = tempfile.mkdtemp(prefix="carfeel-bench-")
    print(f"CPython {platform.python_version()} on {platform.machine()}")
    costs(args.ticks)
    if not args.no_identify:
        identification()
        passivity_share()
    if not args.no_release:
        releases()
    if not args.no_matrix:
        table()
    if not args.no_mismatch:
        mismatch(args.workers)


if __name__ == "__main__":
    main()
