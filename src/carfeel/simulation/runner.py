"""Fixed-step runner in simulated time.

A model is any pure `step(state, inputs, params, dt_s) -> (state, outputs)` whose outputs are a
NamedTuple of floats and str; each output field becomes a signal. `stream` hands the samples to
a sink a block at a time as the run goes (memory flat in the run's length); `run` keeps them all
and returns one Result.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from carfeel.simulation.result import Result
from carfeel.simulation.stream import BLOCK_SAMPLES, Collector, Sink

S = TypeVar("S")
P = TypeVar("P")


def samples_of(duration_s: float, dt_s: float, substeps: int = 1) -> int:
    """How many samples a run of `duration_s` records every `dt_s` (ValueError if none)."""
    if not dt_s > 0.0:
        raise ValueError(f"dt_s must be > 0 s, got {dt_s}")
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    n_samples = round(duration_s / dt_s)
    if n_samples < 1:
        raise ValueError(f"duration_s ({duration_s} s) must be at least one dt_s ({dt_s} s)")
    return n_samples


def stream(
    step: Callable[[S, Any, P, float], tuple[S, Any]],
    state: S,
    params: P,
    sink: Sink,
    *,
    duration_s: float,
    dt_s: float = 1e-3,
    substeps: int = 1,
    inputs: Callable[[float], Any] | None = None,
    stop_when: Callable[[S], bool] | None = None,
    block_samples: int = BLOCK_SAMPLES,
) -> tuple[S, int]:
    """Run `step` for `duration_s`, one sample every `dt_s` (default 1 kHz), handed to `sink`
    in blocks of `block_samples` (each a Result; the last may be shorter).

    Each output interval is split into `substeps` model steps of `dt_s / substeps`; the recorded
    sample is the output of the last sub-step, stamped with the time at the end of the interval.
    `inputs(t)` gives the exogenous inputs at the end of each sub-step (None when the model takes
    none): the instant its output is stamped with, and the input an implicit step integrates
    toward. If `stop_when(state)` holds after a sample, the run ends there (`duration_s` is then
    the longest it may last). Returns the final state and the number of samples.
    """
    n_samples = samples_of(duration_s, dt_s, substeps)
    h = dt_s / substeps
    rows: list[Any] = []
    first = 0  # index of the block's first sample
    k = 0
    for k in range(n_samples):
        t0 = k * dt_s
        for j in range(substeps):
            u = inputs(t0 + (j + 1) * h) if inputs is not None else None
            state, outputs = step(state, u, params, h)
        rows.append(outputs)
        stop = stop_when is not None and stop_when(state)
        if len(rows) == block_samples or stop or k == n_samples - 1:
            sink.write(_block(rows, first, dt_s))
            first += len(rows)
            rows = []
        if stop:
            break
    return state, first


def _block(rows: list[Any], first: int, dt_s: float) -> Result:
    """Rows of outputs (NamedTuples) as a Result: floats as float arrays, str as str arrays."""
    # (k + 1) * dt_s as numpy computes it is the Python float product, bit for bit.
    time = (np.arange(first, first + len(rows), dtype=float) + 1.0) * dt_s
    names = list(type(rows[0])._fields)
    return Result.from_rows(time, names, rows)


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
    """`stream` into memory: the whole run as one Result (with `metadata`) and the final state."""
    kept = Collector()
    state, _ = stream(
        step, state, params, kept, duration_s=duration_s, dt_s=dt_s, substeps=substeps,
        inputs=inputs, stop_when=stop_when,
    )  # fmt: skip
    return kept.result(metadata), state
