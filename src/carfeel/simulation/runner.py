"""Fixed-step runner in simulated time.

A model is any pure `step(state, inputs, params, dt_s) -> (state, outputs)` whose outputs are a
NamedTuple of floats and str; each output field becomes a signal of the Result.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

from carfeel.simulation.result import Result

S = TypeVar("S")
P = TypeVar("P")


def run(
    step: Callable[[S, Any, P, float], tuple[S, Any]],
    state: S,
    params: P,
    *,
    duration_s: float,
    dt_s: float = 1e-3,
    substeps: int = 1,
    inputs: Callable[[float], Any] | None = None,
    metadata: Mapping[str, str] | None = None,
    stop_when: Callable[[S], bool] | None = None,
) -> tuple[Result, S]:
    """Run `step` for `duration_s` and record one sample every `dt_s` (default 1 kHz).

    Each output interval is split into `substeps` model steps of `dt_s / substeps`; the recorded
    sample is the output of the last sub-step, stamped with the time at the end of the interval.
    `inputs(t)` gives the exogenous inputs at the end of each sub-step (None when the model takes
    none): the instant its output is stamped with, and the input an implicit step integrates
    toward. If `stop_when(state)` holds after a sample, the run ends there (`duration_s` is then
    the longest it may last). Returns the Result and the final state.
    """
    if not dt_s > 0.0:
        raise ValueError(f"dt_s must be > 0 s, got {dt_s}")
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    n_samples = round(duration_s / dt_s)
    if n_samples < 1:
        raise ValueError(f"duration_s ({duration_s} s) must be at least one dt_s ({dt_s} s)")
    h = dt_s / substeps
    times: list[float] = []
    rows: list[Any] = []
    outputs: Any = None
    for k in range(n_samples):
        t0 = k * dt_s
        for j in range(substeps):
            u = inputs(t0 + (j + 1) * h) if inputs is not None else None
            state, outputs = step(state, u, params, h)
        times.append((k + 1) * dt_s)
        rows.append(outputs)
        if stop_when is not None and stop_when(state):
            break
    names = list(type(outputs)._fields)
    return Result.from_rows(times, names, rows, metadata), state
