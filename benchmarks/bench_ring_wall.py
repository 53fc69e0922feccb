"""The synchronizer's plateau on the device (issue 30): the ring wall beside the coupling alone.

`carfeel run --model shift` on the virtual joystick and shifter at the default delay (2 ms each
way), the device identified afresh, impedance and admittance, seeds 0-2: over the
synchronization stage, the handle's travel (device mm, whole stage and its middle half) and the
hand's force (the estimate the model is pushed with) over the middle half (p10 / p90, N) beside
the offline plateau (its median, N); each run with the ring wall (`rendering.ring_wall`), with
its springs alone (no feed-forward) and with the coupling alone (the rendering before the
wall), in the same process. Then the wall's table per
device (stretch at each push) and the start-up cost of sizing it beside the sizing it builds on.
Prints numbers; asserts nothing.
    python benchmarks/bench_ring_wall.py [--seeds N]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.errors import InputError
from carfeel.io.presets import load_shift
from carfeel.realtime import building, rendering, stability
from carfeel.realtime.rendering import velocity_sections
from carfeel.realtime.session import RealtimeRun, run_realtime
from carfeel.simulation.result import Result
from carfeel.simulation.shift import simulate_shift

DEVICES = ("virtual:joystick", "virtual:shifter")
MODES = ("impedance", "admittance")


def offline_plateau_N() -> float:
    """The median driver force over the offline run's synchronization stage."""
    result = simulate_shift(load_shift().params)
    sync = np.asarray(result["stage"]) == "synchronization"
    return float(np.median(np.asarray(result["force_N"], dtype=float)[sync]))


RENDERINGS = ("coupling", "springs", "ring wall")
"""The coupling alone (before the ring wall), the wall's springs without its feed-forward, and
the wall as built (springs with the feed-forward)."""


def plateau(device: str, mode: str, seed: int, wall: str, folder: Path) -> dict[str, float]:
    """One run's plateau figures (see the module's docstring) on a rendering of RENDERINGS."""
    record = folder / f"{device.replace(':', '_')}-{mode}-{seed}-{wall.replace(' ', '_')}.csv"
    original = rendering.ring_wall
    if wall == "coupling":  # the session as it was: the coupling alone holds the ring
        setattr(building, "ring_wall", lambda *args: None)  # noqa: B010
    elif wall == "springs":

        def springs(info: Any, rate_hz: float, scaling: Any, driver: Any) -> Any:
            return original(info, rate_hz, scaling, driver, feed_forward=False)

        setattr(building, "ring_wall", springs)  # noqa: B010
    try:
        result = run_realtime(
            RealtimeRun(model="shift", mode=mode, clock="simulated", record=record,
                        device=device, seed=seed)
        )  # fmt: skip
    finally:
        setattr(building, "ring_wall", original)  # noqa: B010
    rec = Result.from_csv(record)
    sync = np.flatnonzero(np.asarray(rec["stage"]) == "synchronization")
    x = np.asarray(rec["x_device"], dtype=float)[sync]
    f = np.asarray(rec["force_N"], dtype=float)[sync]
    n = len(sync)
    middle = slice(n // 4, 3 * n // 4)
    return {
        "travel": 1e3 * float(np.ptp(x)),
        "middle travel": 1e3 * float(np.ptp(x[middle])),
        "p10": float(np.percentile(f[middle], 10)),
        "p90": float(np.percentile(f[middle], 90)),
        "ms": float(n),
        "faults": float(len(result.summary.faults)),
        "gear": float(result.summary.gears == ["1"]),
    }


def identified(device: str, delay_ms: float) -> Any:
    """The device's info as the session's identification finds it at that delay each way."""
    info: list[Any] = []
    original = stability.size

    def spy(device_info: Any, *rest: Any) -> Any:
        info.append(device_info)
        return original(device_info, *rest)

    setattr(stability, "size", spy)  # noqa: B010
    try:
        run_realtime(RealtimeRun(model="shift", clock="simulated", device=device,
                                 device_delay_ms=delay_ms, duration_s=0.05))  # fmt: skip
    finally:
        setattr(stability, "size", original)  # noqa: B010
    return info[-1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    os.environ["CARFEEL_CONFIG_DIR"] = tempfile.mkdtemp(prefix="carfeel-bench-")
    folder = Path(tempfile.mkdtemp(prefix="carfeel-bench-ring-"))
    reference = offline_plateau_N()
    print(f"offline plateau (median over the stage): {reference:.1f} N; +-15 %: "
          f"{0.85 * reference:.1f}-{1.15 * reference:.1f} N")  # fmt: skip
    print("device            mode        rendering  travel mm (whole / middle)  force p10-p90 N"
          "  (middle half)  block ms  faults  gear 1")  # fmt: skip
    for device in DEVICES:
        for mode in MODES:
            rows: dict[str, list[dict[str, float]]] = {w: [] for w in RENDERINGS}
            for seed in range(args.seeds):
                for walled in RENDERINGS:
                    rows[walled].append(plateau(device, mode, seed, walled, folder))
            for walled in RENDERINGS:
                got = rows[walled]

                def span(key: str, got: list[dict[str, float]] = got) -> str:
                    values = [r[key] for r in got]
                    return f"{min(values):.1f}-{max(values):.1f}"

                print(f"{device:17s} {mode:11s} {walled:10s} "
                      f"{span('travel'):>9s} / {span('middle travel'):>9s}        "
                      f"{span('p10')} - {span('p90')}       {span('ms'):>9s}  "
                      f"{sum(r['faults'] for r in got):.0f}       "
                      f"{sum(r['gear'] for r in got):.0f}/{len(got)}")  # fmt: skip
            for walled in RENDERINGS[1:]:
                ratio = [
                    w["travel"] / c["travel"]
                    for w, c in zip(rows[walled], rows["coupling"], strict=True)
                ]
                print(f"{'':29s} travel, {walled} / coupling: {min(ratio):.2f}-{max(ratio):.2f}")
    shift = load_shift().params
    sections = velocity_sections(1000.0)
    print("What each delay allows (the device identified at it): the stretch that holds the")
    print("preset's 78.5 N push on the coupling alone (push / sized spring) and on the wall's")
    print("springs (before its feed-forward moves the push toward the blocked position)")
    for device in DEVICES:
        for delay_ms in (0.0, 1.0, 2.0, 3.0, 4.0):
            try:
                known = identified(device, delay_ms)
            except InputError as refused:
                print(f"  {device} {delay_ms:g} ms each way: refused ({str(refused)[:60]}...)")
                continue
            scaling = rendering.default_scaling(
                building.MODEL_FORCE_N, shift.gearbox.in_gear_position_m + 0.005, known
            )
            push = shift.driver.push_force_N * scaling.force_scale
            sized = stability.size(known, 1000.0, sections)
            wall = rendering.ring_wall(known, 1000.0, scaling, shift.driver)
            at = float(np.interp(push, wall.forces, wall.stretches))
            on_spring = push / sized.stiffness
            fed = sum(t > 0.0 for t in wall.integrals)
            print(f"  {device} {delay_ms:g} ms each way: spring {sized.stiffness:.0f} N/m, "
                  f"{push:.1f} N at {1e3 * on_spring:.1f} mm on it, "
                  f"{1e3 * at:.1f} mm on the wall (x{at / on_spring:.2f}), feed-forward on "
                  f"{fed} of {len(wall.integrals)} pieces")  # fmt: skip
    for device in DEVICES:
        known = identified(device, 2.0)
        scaling = rendering.default_scaling(
            building.MODEL_FORCE_N, shift.gearbox.in_gear_position_m + 0.005, known
        )
        stability.size.cache_clear()
        stability.size_ring_wall.cache_clear()
        started = time.process_time()
        sized = stability.size(known, 1000.0, sections)
        sizing_s = time.process_time() - started
        started = time.process_time()
        wall = rendering.ring_wall(known, 1000.0, scaling, shift.driver)
        wall_s = time.process_time() - started
        table = ", ".join(
            f"{f:.1f} N at {1e3 * x:.2f} mm"
            for x, f in zip(wall.stretches[1:], wall.forces[1:], strict=True)
        )
        print(f"{device}: sized spring {sized.stiffness:.0f} N/m, the wall's first piece "
              f"{wall.forces[1] / wall.stretches[1]:.0f} N/m; the wall: {table}; dampers "
              f"{', '.join(f'{b:.2f}' for b in wall.dampings)} N*s/m; feed-forward time "
              f"constants {', '.join(f'{t:g}' for t in wall.integrals)} s")  # fmt: skip
        print(f"  start-up CPU: the sizing {sizing_s:.2f} s, the wall beside it {wall_s:.2f} s")


if __name__ == "__main__":
    main()
