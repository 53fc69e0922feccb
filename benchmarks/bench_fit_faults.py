"""Issue 25, point 2: the law fitted to logs with every fault of a real car's sensors, over seeds.
Prints only.

The hidden law of tests/steering_logs.py through its smooth manoeuvres, each log with the faults
of `steering_logs.FAULTS` (a 0.1 deg angle resolution after 0.02 deg of noise, a 0.5 deg offset,
speed/Ay/torque noise and offsets, the torque 20 ms late, no rate column), one noise draw per
seed. For each K: the mean and worst error in %, the scatter over the seeds against the median
reported sigma (the acceptance: 0.5..2), and the delay found.
    python benchmarks/bench_fit_faults.py [--seeds 6]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' log maker

from carfeel.identification.steering_fit import fit_steering
from tests import steering_logs as logs_of


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6)
    args = parser.parse_args()
    base, runs, names = logs_of.base_car(), logs_of.smooth_runs(), list(logs_of.TRUE)
    values, sigmas, delays = [], [], []
    t0 = time.perf_counter()
    for seed in range(args.seeds):
        fit = fit_steering(logs_of.as_logs(logs_of.faulty(runs, seed), runs), base)
        got = {e.name: e for e in fit.estimates}
        values.append([got[n].value for n in names])
        sigmas.append([got[n].sigma for n in names])
        delays.append(fit.torque_delay_s * 1e3)
    elapsed = (time.perf_counter() - t0) / args.seeds
    v, s = np.array(values), np.array(sigmas)
    truth = np.array([logs_of.TRUE[n] for n in names])
    error = (v / truth - 1.0) * 100.0
    spread = np.std(v, axis=0, ddof=1) if args.seeds > 1 else np.full(len(names), np.nan)
    print(f"{args.seeds} seeds, {elapsed:.1f} s per fit; delay found "
          f"{min(delays):.1f}..{max(delays):.1f} ms (logged 20 ms late)")  # fmt: skip
    print(f"{'K':14s} {'mean err %':>10s} {'max |err| %':>11s} {'scatter/sigma':>13s}")
    for i, name in enumerate(names):
        ratio = spread[i] / np.median(s[:, i])
        print(f"{name:14s} {error[:, i].mean():+10.2f} {np.abs(error[:, i]).max():11.2f} "
              f"{ratio:13.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
