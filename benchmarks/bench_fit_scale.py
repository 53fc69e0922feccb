"""How the steering fits grow with the log (issue 27): wall time, evaluations and peak memory of
the physical model's fit and the paper law's fit on one log of 1 to 60 minutes at 100 Hz, with
log-log slopes between sizes. Prints only.

The log: the acceptance manoeuvres of `tests/physical_logs.py` (parking, the ISO 13674-1 weave,
a fast sine, ISO 3888 and ISO 4138 to the limit: 86 s, simulated once with the true car at
1 kHz), driven again and again with fresh sensor noise and logged at 100 Hz into one file, a 2 s
pause between drives (a logger's gap: the model starts again there).

Each fit runs in a fresh process that loads the log from a file and measures its own peak
resident memory above what it held before the fit (`ru_maxrss`), beside the log's own arrays
(the reference for memory) and, for time, a pure-model run over the same log in the same
process (the reference for speed: the fits should cost a fixed number of such runs).
    python benchmarks/bench_fit_scale.py [--minutes 1 5 20 60] [--fits physical law]
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the tests' log builder

LOG_HZ = 100
GAP_S = 2.0


def build_log(minutes: float, path: Path) -> None:
    """The long log (module docstring) as an .npz of its columns."""
    from tests.physical_logs import ANGLE_OFFSET_DEG, NOISE, TORQUE_BIAS_NM, clean_runs

    rng = np.random.default_rng(27)
    columns: dict[str, list[np.ndarray]] = {k: [] for k in (
        "time_s", "speed_m_s", "steering_angle_rad", "steering_torque_Nm",
        "steering_rate_rad_s", "lateral_accel_m_s2")}  # fmt: skip
    t_end, total = 0.0, minutes * 60.0
    while t_end < total:
        for _, r in clean_runs():
            idx = np.arange(0, len(r), 1000 // LOG_HZ)
            n = idx.size
            t = r.time_s[idx] - r.time_s[0] + t_end
            keep = t <= total
            if not keep.any():
                break
            sel = idx[keep]
            n = sel.size

            def noise(sigma: float, n: int = n) -> np.ndarray:
                return rng.normal(0.0, sigma, n)

            columns["time_s"].append(t[keep])
            columns["speed_m_s"].append(r["speed_m_s"][sel] + noise(NOISE["speed"]))
            columns["steering_angle_rad"].append(
                r["steering_angle_rad"][sel]
                + np.radians(ANGLE_OFFSET_DEG + noise(NOISE["angle_deg"]))
            )
            columns["steering_torque_Nm"].append(
                r["torque_Nm"][sel] + TORQUE_BIAS_NM + noise(NOISE["torque"])
            )
            columns["steering_rate_rad_s"].append(
                r["steering_rate_rad_s"][sel] + np.radians(noise(NOISE["rate_deg_s"]))
            )
            columns["lateral_accel_m_s2"].append(r["lateral_accel_m_s2"][sel] + noise(NOISE["ay"]))
            t_end = float(t[keep][-1]) + GAP_S
    np.savez(path, **{k: np.concatenate(v) for k, v in columns.items()})  # type: ignore[arg-type]


def child(path: str, fit: str) -> None:
    """Fit the log at `path` in this process; print one JSON line of figures."""
    import gc
    import resource
    import time

    from carfeel.identification.physical_fit import reference, runs_of
    from carfeel.identification.steering_fit import SteeringFit, fit_steering, read_log
    from carfeel.simulation.result import Result
    from tests.physical_logs import base_car

    data = dict(np.load(path))
    time_s = data.pop("time_s")
    log = read_log(Result(time_s, data), "long")
    del data
    log_bytes = sum(
        a.nbytes for a in (log.time_s, log.speed_m_s, log.angle_rad, log.rate_rad_s,
                           log.torque_Nm, log.lateral_accel_m_s2) if a is not None
    )  # fmt: skip
    base = base_car()
    inside = _time_in_model(fit)
    # Imported before the baseline: their modules are not the fit's memory.
    import scipy.interpolate
    import scipy.optimize

    del scipy

    gc.collect()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    t0 = time.perf_counter()
    if fit == "physical":
        from carfeel.identification.physical_fit import fit_physical

        result: SteeringFit = fit_physical([log], base)
    else:
        result = fit_steering([log], base)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    t0 = time.perf_counter()
    reference(base.physical(), runs_of([log]))
    pure = time.perf_counter() - t0
    print(json.dumps({
        "samples": len(log.time_s), "log_bytes": log_bytes, "wall_s": wall,
        "evaluations": result.iterations, "peak_bytes": peak - before, "pure_run_s": pure,
        "rms_Nm": result.rms_error_Nm, "model_s": inside[0], "model_calls": inside[1],
        "one_evaluation_s": inside[0] / max(inside[1], 1),
    }))  # fmt: skip


def _time_in_model(fit: str) -> list[float]:
    """Wrap what computes the model's torque and Jacobian (the physical fit's batch evaluation;
    the law's residual and Jacobian) to add up the time spent in it: [seconds, evaluations]
    (for the law a torque-and-Jacobian pair counts as one)."""
    import functools
    import time

    from carfeel.identification import physical_solver, steering_fit

    total = [0.0, 0.0]

    def timed(function: Any, count: float) -> Any:
        @functools.wraps(function)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                total[0] += time.perf_counter() - t0
                total[1] += count

        return wrapper

    if fit == "physical":
        physical_solver._evaluate = timed(physical_solver._evaluate, 1.0)
    else:
        problem = steering_fit._Problem
        problem.residual = timed(problem.residual, 0.5)  # type: ignore[method-assign]
        problem.weighted_jacobian = timed(problem.weighted_jacobian, 0.5)  # type: ignore[method-assign]
    return total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, nargs="+", default=[1, 5, 20, 60])
    parser.add_argument("--fits", nargs="+", default=["physical", "law"],
                        choices=["physical", "law"])  # fmt: skip
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        rows: dict[str, list[dict[str, float]]] = {fit: [] for fit in args.fits}
        for minutes in args.minutes:
            path = Path(folder) / f"log-{minutes:g}.npz"
            build_log(minutes, path)
            for fit in args.fits:
                out = subprocess.run(
                    [sys.executable, __file__, "--child", str(path), fit],
                    capture_output=True, text=True, check=True, cwd=ROOT,
                )  # fmt: skip
                row = json.loads(out.stdout.strip().splitlines()[-1])
                row["minutes"] = minutes
                rows[fit].append(row)
                print(
                    f"{fit:8s} {minutes:5g} min ({row['samples']:8d} samples): "
                    f"{row['wall_s']:8.1f} s, {row['evaluations']:4d} evaluations, "
                    f"{row['wall_s'] / row['pure_run_s']:6.1f} pure-model runs of the log "
                    f"({row['pure_run_s']:.1f} s each); peak +{row['peak_bytes'] / 1e6:7.1f} MB "
                    f"= {row['peak_bytes'] / row['log_bytes']:5.2f} x the log's arrays "
                    f"({row['log_bytes'] / 1e6:.1f} MB); rms {row['rms_Nm']:.4f} Nm; "
                    f"{100 * row['model_s'] / row['wall_s']:.0f} % of the time in the model"
                    + (
                        f", {row['wall_s'] / (row['one_evaluation_s'] * row['evaluations']):.2f} x "
                        f"the counted evaluations' cost ({row['one_evaluation_s'] * 1e3:.0f} ms "
                        "each)"
                        if fit == "law"
                        else f" ({row['model_calls']:.0f} batch evaluations of every parameter set)"
                    ),
                    flush=True,
                )
        for fit, fit_rows in rows.items():
            for a, b in itertools.pairwise(fit_rows):
                ratio = math.log(b["samples"] / a["samples"])
                print(
                    f"{fit:8s} {a['minutes']:g} -> {b['minutes']:g} min: time slope "
                    f"{math.log(b['wall_s'] / a['wall_s']) / ratio:.2f}, memory slope "
                    f"{math.log(max(b['peak_bytes'], 1) / max(a['peak_bytes'], 1)) / ratio:.2f}"
                )


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "--child":
        child(sys.argv[2], sys.argv[3])
    else:
        main()
