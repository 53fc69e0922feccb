"""Cost of one 2-DOF H-pattern step in CPython, per 1 ms step: median and p99. Prints only.

The knob is driven through N,1,2,3,4,5,4,3,2,1,N,R,N by the scripted driver (so every region
and stage is visited in proportion); the H-pattern model's step alone is timed, then the step
of the closed loop with the driver, in both synchronizer modes.
    python benchmarks/bench_hpattern_step.py
"""

from __future__ import annotations

import gc
import math
import platform
import statistics
import time

from carfeel.io.presets import load_hpattern
from carfeel.models.drivers.hpattern import Script
from carfeel.models.gearshift import hpattern
from carfeel.models.gearshift.hpattern import HPatternInputs
from carfeel.simulation import hpattern as loop

SEQUENCE = ("N", "1", "2", "3", "4", "5", "4", "3", "2", "1", "N", "R", "N")


def report(label: str, samples: list[float]) -> None:
    ordered = sorted(samples)
    p99 = ordered[int(0.99 * (len(ordered) - 1))]
    print(
        f"{label:46s} median {statistics.median(ordered):6.2f} us   p99 {p99:6.2f} us   "
        f"(n={len(ordered)})"
    )


def main() -> None:
    preset = load_hpattern("5r")
    print(f"CPython {platform.python_version()} on {platform.machine()}")
    gc.collect()
    gc.freeze()
    clock = time.perf_counter_ns
    for physics in (False, True):
        mode = "physics" if physics else "fixed"
        script = Script(SEQUENCE, preset.setup.layout, preset.shift.driver, preset.setup.driver)
        params = loop.HPatternRun(preset.pattern(physics), script, 30 / 3.6, 800 * math.pi / 30)
        state = loop.initial_state(params)
        model_samples, loop_samples = [], []
        for _ in range(14_000):
            knob = state.knob
            # The model alone, with the inputs the driver gave last (replayed).
            last = state.last
            inputs = HPatternInputs(
                last.force_x_N if last else 0.0,
                last.force_y_N if last else 0.0,
                1.0,
                params.vehicle_speed_m_s,
                params.engine_speed_rad_s,
            )
            t0 = clock()
            hpattern.step(knob, inputs, params.pattern, 1e-3)
            model_samples.append((clock() - t0) / 1e3)
            t0 = clock()
            state, _ = loop.step(state, None, params, 1e-3)
            loop_samples.append((clock() - t0) / 1e3)
        report(f"H-pattern model step ({mode} synchronizer)", model_samples)
        report(f"driver + H-pattern loop step ({mode})", loop_samples)


if __name__ == "__main__":
    main()
