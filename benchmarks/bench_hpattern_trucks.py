"""Cost of the trucks' H-pattern step (issue 30): the range/splitter box and the double-H beside
the 7r car layout measured in the same run, per 1 ms step (median and p99). Prints only.

Each layout is driven through its whole pattern by the scripted driver (fixed synchronizer,
at standstill); the model's step alone is timed with the inputs the driver gave last, the three
layouts interleaved step by step so the machine's load falls on each alike.
    python benchmarks/bench_hpattern_trucks.py
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

SEQUENCES = {
    "7r": ("N", "1", "2", "3", "4", "5", "6", "7", "6", "N", "R", "N"),
    "truck-14r2": ("N", *(str(g) for g in range(1, 15)), "N", "R1", "N", "R2", "N"),
    "double-h-8r": ("N", "1", "2", "3", "4", "5", "6", "7", "8", "N", "R", "N"),
}
STEPS = 20_000


def main() -> None:
    print(f"CPython {platform.python_version()} on {platform.machine()}")
    params: dict[str, loop.HPatternRun] = {}
    states: dict[str, loop.LoopState] = {}
    samples: dict[str, list[float]] = {}
    for name, sequence in SEQUENCES.items():
        preset = load_hpattern(name)
        script = Script(sequence, preset.setup.layout, preset.shift.driver, preset.setup.driver)
        params[name] = loop.HPatternRun(preset.pattern(False), script, 0.0, 800 * math.pi / 30)
        states[name] = loop.initial_state(params[name])
        samples[name] = []
    gc.collect()
    gc.freeze()
    clock = time.perf_counter_ns
    for _ in range(STEPS):
        for name, run in params.items():
            state = states[name]
            last = state.last
            inputs = HPatternInputs(
                last.force_x_N if last else 0.0, last.force_y_N if last else 0.0, 1.0, 0.0,
                run.engine_speed_rad_s, last.range_high if last else False,
                last.splitter_high if last else False,
            )  # fmt: skip
            t0 = clock()
            hpattern.step(state.knob, inputs, run.pattern, 1e-3)
            samples[name].append((clock() - t0) / 1e3)
            states[name], _ = loop.step(state, None, run, 1e-3)
    reference = statistics.median(samples["7r"])
    for name, taken in samples.items():
        ordered = sorted(taken)
        p99 = ordered[int(0.99 * (len(ordered) - 1))]
        median = statistics.median(ordered)
        print(
            f"{name:12s} model step median {median:6.2f} us  p99 {p99:6.2f} us  "
            f"x{median / reference:.2f} of 7r's (n={len(ordered)})"
        )


if __name__ == "__main__":
    main()
