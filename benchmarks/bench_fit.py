"""Fit time for 10 minutes of 1 kHz steering data (600,000 samples). Prints only.

The data: the default car's weave, steer cycle, ISO 4138 and ISO 3888 runs, repeated to fill
10 minutes, with sensor noise; the rate derived from the angle as for a real log.
    python benchmarks/bench_fit.py [--minutes 10]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from carfeel.identification.steering_fit import fit_steering, read_log
from carfeel.io.presets import load_steering
from carfeel.simulation import manoeuvres
from carfeel.simulation.result import Result
from carfeel.simulation.steering import simulate_steering


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    args = parser.parse_args()
    car = load_steering().params
    pieces = []
    for name in ("weave", "steer-cycle", "iso4138", "iso3888"):
        run = simulate_steering(car, manoeuvres.build(name, car.vehicle))
        keep = run["segment"] == run["segment"][0]
        pieces.append({k: v[keep] for k, v in run.signals.items()})
    columns = {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0] if k != "segment"}
    samples = int(args.minutes * 60 * 1000)
    repeat = samples // len(columns["torque_Nm"]) + 1
    rng = np.random.default_rng(1)
    signals = {
        "speed_m_s": np.tile(columns["speed_m_s"], repeat)[:samples],
        "steering_angle_rad": np.tile(columns["steering_angle_rad"], repeat)[:samples],
        "steering_torque_Nm": np.tile(columns["torque_Nm"], repeat)[:samples]
        + rng.normal(0, 0.05, samples),
        "lateral_accel_m_s2": np.tile(columns["lateral_accel_m_s2"], repeat)[:samples]
        + rng.normal(0, 0.05, samples),
    }
    signals["steering_angle_rad"] = signals["steering_angle_rad"] + rng.normal(
        0, np.radians(0.02), samples
    )
    log = Result(np.arange(samples, dtype=np.float64) * 1e-3, signals)
    t0 = time.perf_counter()
    data = read_log(log, "bench")
    t1 = time.perf_counter()
    fit = fit_steering([data], car)
    t2 = time.perf_counter()
    print(f"{samples} samples ({args.minutes:g} min at 1 kHz)")
    print(f"checks and rate derivation {t1 - t0:6.2f} s")
    print(f"fit (K1..K9 + offset)      {t2 - t1:6.2f} s, {fit.iterations} evaluations")
    print(f"total                      {t2 - t0:6.2f} s   (target under 5 s)")
    print(f"rms error {fit.rms_error_Nm:.3f} Nm, r2 {fit.r2:.4f}, torque delay found "
          f"{fit.torque_delay_s * 1e3:.2g} ms")  # fmt: skip


if __name__ == "__main__":
    main()
