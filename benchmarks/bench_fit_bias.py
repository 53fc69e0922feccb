"""Bias of K1..K9 from noise on one channel at a time, then on all. Prints only.

The reproduction of issue 12's errors-in-variables bias, adapted to the fit as it is: a car
with the tests' K1..K9 runs the weave, the parking steer cycle, ISO 4138, the ISO 7401 step and
ISO 3888, logged at 200 Hz with a rate column; noise (1 sigma): speed 0.05 m/s, angle 0.02 deg,
Ay 0.05 m/s^2, torque 0.05 Nm, rate 0.3 deg/s. Each line: the error of each K in % of its true
value, and |error| / reported sigma.
    python benchmarks/bench_fit_bias.py [--seeds 1]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np

from carfeel.identification.steering_fit import SteeringLog, fit_steering, read_log
from carfeel.io.presets import load_steering
from carfeel.simulation import manoeuvres
from carfeel.simulation.result import Result
from carfeel.simulation.steering import simulate_steering

TRUE = {
    "k1_Nm_s2_m": 1.9, "k2": 0.25, "k3": 1.0, "k4_1_Nm": 0.5, "k5_s_m_Nm": 0.2, "k6_rad_s": 0.7,
    "k7_Nm": 0.6, "k8_rad_s": 0.08, "k9_Nm_s_rad": 0.12,
}  # fmt: skip
NOISE = {
    "speed_m_s": 0.05, "steering_angle_rad": math.radians(0.02), "lateral_accel_m_s2": 0.05,
    "steering_torque_Nm": 0.05, "steering_rate_rad_s": math.radians(0.3),
}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1)
    args = parser.parse_args()
    base = load_steering().params
    truth = dataclasses.replace(base, torque=dataclasses.replace(base.torque, **TRUE))
    runs = []
    for name in ("weave", "steer-cycle", "iso4138", "iso7401-step", "iso3888"):
        full = simulate_steering(truth, manoeuvres.build(name, truth.vehicle))
        for segment in dict.fromkeys(full["segment"].tolist()):
            keep = full["segment"] == segment
            runs.append((f"{name}-{segment}", Result(full.time_s[keep], {
                k: v[keep] for k, v in full.signals.items()})))  # fmt: skip

    def logs(noisy: list[str], seed: int) -> list[SteeringLog]:
        rng = np.random.default_rng(seed)
        out = []
        for name, r in runs:
            idx = np.arange(0, len(r), 5)
            signals = {k: r["torque_Nm" if k == "steering_torque_Nm" else k][idx] for k in NOISE}
            for k in noisy:
                signals[k] = signals[k] + rng.normal(0.0, NOISE[k], idx.size)
            out.append(read_log(Result(r.time_s[idx], signals), name))
        return out

    for noisy in [[k] for k in NOISE] + [list(NOISE)]:
        errors, zs = [], []
        t0 = time.perf_counter()
        for seed in range(args.seeds):
            fit = fit_steering(logs(noisy, seed), base)
            got = {e.name: e for e in fit.estimates}
            errors.append([(got[n].value / t - 1.0) * 100.0 for n, t in TRUE.items()])
            zs.append([abs(got[n].value - t) / got[n].sigma for n, t in TRUE.items()])
        label = "all" if len(noisy) > 1 else noisy[0]
        print(f"{label:20s} ({(time.perf_counter() - t0) / args.seeds:.1f} s per fit)")
        mean_error, median_z = np.mean(errors, axis=0), np.median(zs, axis=0)
        cells = [
            f"{n.split('_')[0]} {e:+6.2f}% z{z:4.1f}"
            for n, e, z in zip(TRUE, mean_error, median_z, strict=True)
        ]
        print("   " + " | ".join(cells))


if __name__ == "__main__":
    main()
