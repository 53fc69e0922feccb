"""Fit time of `fit_shift` for N measured-style engagement traces. Prints only.

Each trace is one push into first gear of the shipped preset's shift loop (a different seed,
so a different tooth draw), stepped at 0.1 ms, sampled at 500 Hz with 0.05 mm and 0.5 N of
noise, as in tests/test_shift_fit.py; with --quantized, issue 25's sensors instead: the position
in 0.05 mm steps and 1 N of force noise (the fit's r2 and its stage positions' errors printed).
With --repeats N, N fits of fresh traces (other seeds: other tooth draws and noise) and, for each
fitted value, the scatter of its error over the fits against its median reported sigma.
    python benchmarks/bench_shift_fit.py [--traces 6] [--quantized] [--repeats 1]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from carfeel.identification.shift_fit import _fitted_values, fit_shift
from carfeel.io.presets import load_shift
from carfeel.simulation import shift
from carfeel.simulation.result import Result
from carfeel.simulation.runner import run
from carfeel.simulation.shift import ShiftParams


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--traces", type=int, default=6)
    parser.add_argument("--quantized", action="store_true")
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    params = load_shift().params
    if args.repeats > 1:
        _repeats(params, args)
        return
    traces = _traces(params, args, 0)
    samples = sum(len(trace.time_s) for trace in traces)
    t0 = time.perf_counter()
    fit = fit_shift(traces, params)
    elapsed = time.perf_counter() - t0
    g = fit.params.gearbox
    print(f"{args.traces} traces, {len(fit.engagements)} engagements, {samples} samples at 500 Hz")
    print(f"fit                         {elapsed:6.2f} s")
    print(f"position rms {fit.figures['rms_error_m'] * 1e3:.3f} mm, r2 {fit.figures['r2']:.4f}")
    truth = params.gearbox
    for name in ("synchronization", "teeth", "teeth_end", "in_gear"):
        key = f"{name}_position_m"
        error = getattr(g, key) - getattr(truth, key)
        sigma = fit.sigmas.get(f"gearbox.{key}", float("nan"))
        print(f"{key:28s} error {error * 1e3:+.3f} mm, sigma {sigma * 1e3:.3f} mm")
    print(f"push force sigma {fit.sigmas.get('driver.push_force_N', float('nan')):.3g} N")
    print(
        f"sync position {g.synchronization_position_m * 1e3:.2f} mm (preset "
        f"{params.gearbox.synchronization_position_m * 1e3:.2f}), stop stiffness "
        f"{g.stop.stiffness_N_m:.0f} N/m (preset {params.gearbox.stop.stiffness_N_m:.0f})"
    )


def _traces(params: ShiftParams, args: argparse.Namespace, first: int) -> list[Result]:
    """`args.traces` pushes into first gear, seeds from `first`, as the sensors log them."""
    traces = []
    for seed in range(first, first + args.traces):
        result, _ = run(
            shift.step, shift.initial_state(seed), params, duration_s=1.2, dt_s=1e-3, substeps=10
        )
        rng = np.random.default_rng(seed)
        t = np.arange(result.time_s[0] + 0.5e-3, result.time_s[-1], 1.0 / 500.0)
        x = np.interp(t, result.time_s, result["position_m"])
        x = np.round(x / 5e-5) * 5e-5 if args.quantized else x + rng.normal(0, 5e-5, t.size)
        f = np.interp(t, result.time_s, result["force_N"])
        f = f + rng.normal(0, 1.0 if args.quantized else 0.5, t.size)
        traces.append(Result(t, {"position_m": x, "force_N": f}))
    return traces


def _repeats(params: ShiftParams, args: argparse.Namespace) -> None:
    """The scatter of each fitted value's error over repeated fits against its sigma."""
    paths = ["gearbox.synchronization_position_m", "gearbox.teeth_position_m",
             "gearbox.teeth_end_position_m", "gearbox.in_gear_position_m",
             "gearbox.stop.stiffness_N_m", "gearbox.stop.damping_N_s_m",
             "driver.push_force_N"]  # fmt: skip
    truth = _fitted_values(params)
    errors, sigmas, r2 = [], [], []
    t0 = time.perf_counter()
    for r in range(args.repeats):
        fit = fit_shift(_traces(params, args, 100 * r), params)
        values = _fitted_values(fit.params)
        errors.append([values[k] - truth[k] for k in paths])
        sigmas.append([fit.sigmas.get(k, float("nan")) for k in paths])
        r2.append(fit.figures["r2"])
    e, s = np.array(errors), np.array(sigmas)
    each = (time.perf_counter() - t0) / args.repeats
    print(f"{args.repeats} fits of {args.traces} traces ({each:.1f} s each), r2 "
          f"{min(r2):.4f}..{max(r2):.4f}")  # fmt: skip
    print(f"{'value':36s} {'rms error':>10s} {'scatter':>10s} {'median sigma':>12s} {'ratio':>6s}")
    for i, key in enumerate(paths):
        rms, spread, sigma = (
            np.sqrt(np.mean(e[:, i] ** 2)),
            np.std(e[:, i], ddof=1),
            np.median(s[:, i]),
        )
        print(f"{key:36s} {rms:10.3g} {spread:10.3g} {sigma:12.3g} {spread / sigma:6.2f}")


if __name__ == "__main__":
    main()
