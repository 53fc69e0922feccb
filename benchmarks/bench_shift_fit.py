"""Fit time of `fit_shift` for N measured-style engagement traces. Prints only.

Each trace is one push into first gear of the shipped preset's shift loop (a different seed,
so a different tooth draw), stepped at 0.1 ms, sampled at 500 Hz with 0.05 mm and 0.5 N of
noise, as in tests/test_shift_fit.py; with --quantized, issue 25's sensors instead: the position
in 0.05 mm steps and 1 N of force noise (the fit's r2 and its stage positions' errors printed).
    python benchmarks/bench_shift_fit.py [--traces 6] [--quantized]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from carfeel.identification.shift_fit import fit_shift
from carfeel.io.presets import load_shift
from carfeel.simulation import shift
from carfeel.simulation.result import Result
from carfeel.simulation.runner import run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--traces", type=int, default=6)
    parser.add_argument("--quantized", action="store_true")
    args = parser.parse_args()
    params = load_shift().params
    traces = []
    for seed in range(args.traces):
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


if __name__ == "__main__":
    main()
