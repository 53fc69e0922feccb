"""The engagement peak's spread across seeds against the shift speed (issue 30), not a timing.

For each push force and driver speed V0 (eq. 10), 10 seeds (or --seeds N) of the 1-DOF preset
through the batch engagement: the peak's mean, min, max and coefficient of variation, and the
same for the seeds whose chamfers met (the gap-to-gap ones apart). Prints numbers; asserts
nothing.
    python benchmarks/bench_engagement_peak_spread.py [--seeds N]
"""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np

from carfeel.io.presets import load_shift
from carfeel.models.rng import next_uniform, seed_state
from carfeel.sweep.batch import ShiftBatch

SPEEDS_M_S = (0.25, 0.5, 1.0, 2.0)
PUSHES_N = (78.5, 120.0)


def peaks(push_N: float, speed_m_s: float, seeds: int) -> tuple[np.ndarray, np.ndarray]:
    """(engagement peaks N, whether the chamfers met) of `seeds` shifts."""
    base = load_shift().params
    driver = dataclasses.replace(base.driver, push_force_N=push_N, push_velocity_m_s=speed_m_s)
    params = dataclasses.replace(base, driver=driver)
    g = params.gearbox
    run = ShiftBatch([params] * seeds, list(range(seeds))).run(1.2)
    found = np.array([f.engagement_peak_N for f in run.features])
    # The tooth draw u (the first uniform of each seed's stream) sets the contact: u >= f meets.
    met = np.array(
        [next_uniform(seed_state(s))[1] >= g.chamfer.no_contact_fraction for s in range(seeds)]
    )
    return found, met


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    print(f"engagement peak across {args.seeds} seeds (paper-first-gear preset)")
    print("push N  V0 m/s   mean N   min N   max N    CV   | chamfers met: n  min N  max N   CV")
    for push in PUSHES_N:
        for speed in SPEEDS_M_S:
            p, met = peaks(push, speed, args.seeds)
            m = p[met]
            cv = p.std() / p.mean()
            cv_met = m.std() / m.mean() if len(m) > 1 else float("nan")
            print(
                f"{push:6.1f}  {speed:5.2f}  {p.mean():7.1f} {p.min():7.1f} {p.max():7.1f}  "
                f"{cv:5.3f} |            {len(m):2d} {m.min():6.1f} {m.max():6.1f}  {cv_met:5.3f}"
            )


if __name__ == "__main__":
    main()
