"""Fit time of the law for 10 minutes of 100 Hz steering data (60,000 samples), beside one
evaluation of the law and its Jacobian over the same log in the same run. Prints only.

The data: the default car's weave, steer cycle, ISO 4138 and ISO 3888 runs, repeated to fill
the minutes, with sensor noise; the rate derived from the angle as for a real log. The fit's time
is given in seconds and in those law evaluations (the ratio holds on a loaded machine where the
seconds do not).
    python benchmarks/bench_fit.py [--minutes 10] [--rate-hz 100]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from carfeel.identification.steering_fit import SteeringLog, fit_steering, read_log
from carfeel.io.presets import load_steering
from carfeel.simulation import manoeuvres
from carfeel.simulation.result import Result
from carfeel.simulation.steering import SteeringCar, simulate_steering


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    parser.add_argument(
        "--rav4",
        action="store_true",
        help="instead: the RAV4's real drive (no Ay) on three held-out splits",
    )
    args = parser.parse_args()
    if args.rav4:
        _rav4()
        return
    car = load_steering().params
    pieces = []
    for name in ("weave", "steer-cycle", "iso4138", "iso3888"):
        run = simulate_steering(car, manoeuvres.build(name, car.vehicle))
        keep = run["segment"] == run["segment"][0]
        pieces.append({k: v[keep] for k, v in run.signals.items()})
    columns = {k: np.concatenate([p[k] for p in pieces]) for k in pieces[0] if k != "segment"}
    step = max(1, round(1000.0 / args.rate_hz))  # the runs are at 1 kHz
    columns = {k: v[::step] for k, v in columns.items()}
    samples = int(args.minutes * 60 * 1000 / step)
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
    log = Result(np.arange(samples, dtype=np.float64) * step * 1e-3, signals)
    t0 = time.perf_counter()
    data = read_log(log, "bench")
    t1 = time.perf_counter()
    fit = fit_steering([data], car)
    t2 = time.perf_counter()
    reference = _law_evaluation(data, car)
    print(f"{samples} samples ({args.minutes:g} min at {1000 / step:g} Hz)")
    print(f"checks and rate derivation {t1 - t0:6.2f} s")
    print(
        f"fit (law, offset, delay)   {t2 - t1:6.2f} s, {fit.iterations} evaluations, "
        f"{len(fit.keep_tests)} keep tests"
    )
    print(f"total                      {t2 - t0:6.2f} s   (target under 5 s)")
    print(
        f"one law + Jacobian evaluation over the log: {reference * 1e3:.1f} ms; the fit took "
        f"{(t2 - t1) / reference:.0f} of them"
    )
    print(f"rms error {fit.rms_error_Nm:.3f} Nm, r2 {fit.r2:.4f}, torque delay found "
          f"{fit.torque_delay_s * 1e3:.2g} ms")  # fmt: skip


def _rav4() -> None:
    """The vendored RAV4 drive (tests/data/can, driver torque, no Ay) fitted on its first part
    and predicted on the rest, as `carfeel fit --holdout` does: the law's r2 (no offset fitted on
    the held-out part) beside the linear fit and the lagged ridge trained on the same part."""
    import contextlib
    import io
    import json
    import sys
    import tempfile
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' data and map
    from carfeel.cli import main as cli
    from tests.test_logs import RAV4_DBC, RAV4_LOG, RAV4_NO_AY_MAP

    with tempfile.TemporaryDirectory() as folder:
        channel_map = Path(folder) / "rav4-no-ay.toml"
        channel_map.write_text(RAV4_NO_AY_MAP)
        print(f"{'split':26s} {'law r2':>8s} {'ridge r2':>8s} {'linear r2':>9s}   fit s")
        for holdout in (0.3, 0.4, 0.5):
            out = io.StringIO()
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
                code = cli(["fit", "steering", str(RAV4_LOG), "--dbc", str(RAV4_DBC),
                            "--channels", str(channel_map), "--out",
                            str(Path(folder) / "rav4.toml"), "--holdout", str(holdout),
                            "--json"])  # fmt: skip
            elapsed = time.perf_counter() - t0
            if code != 0:
                print(f"holdout {holdout:g}: exit {code}")
                continue
            b = json.loads(out.getvalue())["baselines"]
            split = f"first {1 - holdout:.0%} -> last {holdout:.0%}"
            print(f"{split:26s} {b['model']['all']['r2']:8.3f} "
                  f"{b['lagged ridge']['all']['r2']:8.3f} {b['linear']['all']['r2']:9.3f}   "
                  f"{elapsed:5.1f}")  # fmt: skip


def _law_evaluation(log: SteeringLog, car: SteeringCar) -> float:
    """Seconds of one evaluation of the law's torque and Jacobian over the log (median of 5)."""
    from carfeel.identification.steering_fit import PAPER_LAW, Regressors

    steps = np.diff(log.time_s, prepend=log.time_s[0])
    starts = np.zeros(len(steps), dtype=bool)
    starts[0] = True
    ay = log.lateral_accel_m_s2 if log.lateral_accel_m_s2 is not None else log.speed_m_s * 0.0
    r = Regressors(log.speed_m_s, log.rate_rad_s, ay, np.abs(log.rate_rad_s) * steps, starts)
    x = np.array([getattr(car.torque, name) for name in PAPER_LAW.names])
    x[PAPER_LAW.names.index("k10_Nm")] = 0.1  # the memory's recurrences evaluated too
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        PAPER_LAW.torque(x, r)
        PAPER_LAW.jacobian(x, r)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


if __name__ == "__main__":
    main()
