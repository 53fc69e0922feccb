"""The physical steering model's fit (issue 13): wall time beside the paper law's fit on the
same logs in the same run, and (with --seeds) its errors against the sigmas it reports over
repeated noisy fits. Prints only.

The logs: the acceptance set of `tests/physical_logs.py` (parking at 0 and 6 km/h, the ISO
13674-1 weave, a fast sine at 80 km/h, ISO 3888 and ISO 4138 to the limit: 86 s at 200 Hz),
noise on every channel, an angle offset and a torque bias; --repeat N takes each manoeuvre N
times with fresh noise (a longer drive of the same car).
    python benchmarks/bench_physical_fit.py [--repeat 1] [--seeds 0]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' log builder

from carfeel.identification.physical_fit import NAMES, fit_physical
from carfeel.identification.steering_fit import SteeringLog, fit_steering
from tests.physical_logs import TRUE, base_car, clean_runs, measured


def logs_for(seed: int, repeat: int) -> list[SteeringLog]:
    runs = clean_runs()
    logs = []
    for k in range(repeat):
        for log in measured(runs, seed=1000 * seed + k):
            logs.append(log)
    return logs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=1, help="each manoeuvre this many times")
    parser.add_argument("--seeds", type=int, default=0, help="repeated noisy fits to run")
    args = parser.parse_args()
    base = base_car()
    t0 = time.perf_counter()
    runs = clean_runs()
    logs = logs_for(0, args.repeat)
    seconds = sum(float(log.time_s[-1] - log.time_s[0]) for log in logs)
    samples = sum(len(log.time_s) for log in logs)
    print(f"logs: {len(logs)} ({seconds:.0f} s, {samples} samples at 200 Hz); truth simulated "
          f"in {time.perf_counter() - t0:.1f} s")  # fmt: skip
    law_logs = _law_logs(args.repeat)
    t0 = time.perf_counter()
    own = fit_steering(law_logs, base)
    t1 = time.perf_counter()
    law = fit_steering(logs, base)
    t2 = time.perf_counter()
    fit = fit_physical(logs, base)
    t3 = time.perf_counter()
    print(
        f"paper law fit, its own car's logs: {t1 - t0:7.2f} s, {own.iterations} evaluations, "
        f"rms {own.rms_error_Nm:.4f} Nm (the same manoeuvres and noise, the law's car)"
    )
    print(f"paper law fit (K1..K9):      {t2 - t1:7.2f} s, {law.iterations} evaluations, rms "
          f"{law.rms_error_Nm:.4f} Nm (the law cannot follow the EPS car)")  # fmt: skip
    print(f"physical model fit:          {t3 - t2:7.2f} s, {fit.iterations} simulations of the "
          f"logs, {fit.sweeps} batches, {fit.simulated_s:.0f} s of model time simulated, rms "
          f"{fit.rms_error_Nm:.4f} Nm")  # fmt: skip
    print(
        f"ratio physical / law:        {(t3 - t2) / (t2 - t1):7.2f} (same logs), "
        f"{(t3 - t2) / (t1 - t0):.2f} (against the law on its own car's logs)"
    )
    print(f"batch against the pure model at the solution: {fit.batch_check_Nm:.2g} Nm")
    rate = fit.simulated_s / (t3 - t2)
    print(f"model time simulated per wall second: {rate:.0f} (the pure step: about "
          f"{_pure_rate(runs[0][1]):.0f})")  # fmt: skip
    for e in fit.estimates:
        print(f"  {e.name:34s} {e.value:9.5g} +- {e.sigma:.2g}  truth {TRUE[e.name]:g}  "
              f"({100 * (e.value / TRUE[e.name] - 1):+.2f} %)")  # fmt: skip
    if args.seeds:
        _seeds(args.seeds, args.repeat)


def _law_logs(repeat: int) -> list[SteeringLog]:
    """The same manoeuvres driven by the base car with the paper's law (its linear car), logged
    with the same noise: what the law's fit is made for."""
    from carfeel.simulation.result import Result
    from carfeel.simulation.steering import simulate_steering
    from tests.physical_logs import manoeuvre_set

    car = base_car()
    runs = []
    for name, manoeuvre, cut in manoeuvre_set(car):
        full = simulate_steering(car, manoeuvre)
        keep = full.time_s >= cut
        runs.append((name, Result(full.time_s[keep], {k: v[keep] for k, v in full.signals.items()
                                                      if k != "segment"})))  # fmt: skip
    logs = []
    for k in range(repeat):
        logs.extend(measured(runs, seed=500 + k))
    return logs


def _pure_rate(result: object) -> float:
    """Model seconds per wall second of the pure step (hands on), measured here."""
    from carfeel.identification.physical_fit import reference, runs_of

    log = measured([("probe", result)], seed=99)[0]  # type: ignore[list-item]
    runs = runs_of([log])
    t0 = time.perf_counter()
    reference(base_car().physical(), runs)
    return float(runs[0].steps * 1e-3 / (time.perf_counter() - t0))


def _seeds(n: int, repeat: int) -> None:
    base = base_car()
    values, sigmas = [], []
    for seed in range(1, n + 1):
        t0 = time.perf_counter()
        fit = fit_physical(logs_for(seed, repeat), base)
        values.append([e.value for e in fit.estimates])
        sigmas.append([e.sigma for e in fit.estimates])
        print(f"seed {seed}: {time.perf_counter() - t0:.1f} s, rms {fit.rms_error_Nm:.4f} Nm")
    v, s = np.array(values), np.array(sigmas)
    truth = np.array([TRUE[name] for name in NAMES])
    print(f"{'parameter':34s} {'mean err %':>10s} {'max |err| %':>11s} {'scatter %':>9s} "
          f"{'sigma %':>8s} {'scatter/sigma':>13s} {'within 2 sigma':>14s}")  # fmt: skip
    for j, name in enumerate(NAMES):
        err = (v[:, j] - truth[j]) / truth[j] * 100
        spread = np.std(v[:, j], ddof=1) / truth[j] * 100 if n > 1 else float("nan")
        sigma = float(np.median(s[:, j])) / truth[j] * 100
        within = float(np.mean(np.abs(v[:, j] - truth[j]) <= 2 * s[:, j]))
        print(f"{name:34s} {err.mean():+10.3f} {np.abs(err).max():11.3f} {spread:9.3f} "
              f"{sigma:8.3f} {spread / sigma:13.2f} {within:14.0%}")  # fmt: skip
    within_all = np.mean(np.abs(v - truth) <= 2 * s)
    print(f"all errors within 2 reported sigmas: {within_all:.0%} of {v.size}")


if __name__ == "__main__":
    main()
