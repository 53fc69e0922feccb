"""Cost of one PRND selector step in CPython, per 1 ms step (median and p99), beside the
sequential lever's step measured in the same run (the reference: ratios hold on this shared
machine, absolute times do not). Prints only.

The selector is driven through R,N,D,N,R,P with the brake and button on, then the same moves
with the brake off (against P's locked wall), by the offline driver's hand.
    python benchmarks/bench_prnd_step.py
"""

from __future__ import annotations

import gc
import math
import platform
import statistics
import time

from carfeel.models.gearshift import prnd as pr
from carfeel.models.gearshift import sequential as sq


def report(label: str, samples: list[float]) -> float:
    ordered = sorted(samples)
    p99 = ordered[int(0.99 * (len(ordered) - 1))]
    median = statistics.median(ordered)
    print(f"{label:40s} median {median:6.2f} us   p99 {p99:6.2f} us   (n={len(ordered)})")
    return median


def main() -> None:
    print(f"CPython {platform.python_version()} on {platform.machine()}")
    gc.collect()
    gc.freeze()
    clock = time.perf_counter_ns
    params = pr.PrndParams()
    state = pr.PrndState()
    prnd_us, depth_m = [], 0.0
    for brake in (True, False):
        for target in (1, 2, 3, 2, 1, 0):
            for tick in range(1000):
                push = tick < 600 and state.position != target
                force = math.copysign(25.0, params.centre_m(target) - state.x_m) if push else 0.0
                inputs = pr.PrndInputs(force, brake, True, 0.0)
                t0 = clock()
                state, out = pr.step(params, state, inputs, 1e-3)
                prnd_us.append((clock() - t0) / 1e3)
                depth_m = max(depth_m, out.wall_depth_m)
    lever = sq.SequentialParams()
    seq_state = sq.SequentialState()
    seq_us = []
    for k in range(len(prnd_us)):
        hand = (-45.0 if (k // 600) % 2 == 0 else 45.0) if k % 600 < 300 else 0.0
        t0 = clock()
        seq_state, _ = sq.step(lever, seq_state, sq.SequentialInputs(hand, lift=True), 1e-3)
        seq_us.append((clock() - t0) / 1e3)
    a = report("prnd step", prnd_us)
    b = report("sequential step (reference)", seq_us)
    print(f"prnd / sequential: {a / b:.2f}; deepest into P's locked wall {1000 * depth_m:.2f} mm")


if __name__ == "__main__":
    main()
