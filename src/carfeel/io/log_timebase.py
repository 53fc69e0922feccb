"""Channels onto one time base: all channels of a log, each with its own time stamps, resampled
by linear interpolation onto one uniform time base over the span they share; a gap in a channel
is refused, not bridged."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from carfeel.errors import InputError
from carfeel.io import log_limits as limits
from carfeel.io.log_limits import too_many
from carfeel.io.log_signals import FloatArray
from carfeel.simulation.result import Result

MAX_GAP_S = 0.5
MAX_GAP_PERIODS = 20
"""A channel silent for longer than both (its own period's multiple and the seconds) is a gap in
the log, not jitter: interpolating across it would invent the data."""


def common_time(
    path: Path, converted: Mapping[str, tuple[FloatArray, FloatArray]], rate_hz: float | None
) -> Result:
    """All channels (name -> (time in s, values)) on one uniform time base over the span they
    share, by linear interpolation, at `rate_hz` (default: the torque's or force's rate, else the
    fastest channel's); channels that share their time stamps are kept as they are."""
    stamps = [t for t, _ in converted.values()]
    if all(len(t) == len(stamps[0]) and np.array_equal(t, stamps[0]) for t in stamps):
        # One time base already (a CSV, a Parquet table): its checks are the fits' (with lines).
        time = stamps[0]
        return Result(time - time[0] if len(time) and time[0] > 1e6 else time,
                      {n: v for n, (_, v) in converted.items()})  # fmt: skip
    for name, (t, _) in converted.items():
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            raise InputError(f"{path}: {name}: time stamps do not increase")
    start = max(float(t[0]) for t in stamps)
    end = min(float(t[-1]) for t in stamps)
    if not end > start:
        raise InputError(f"{path}: the mapped channels do not overlap in time")
    _check_gaps(path, converted, start, end)
    if rate_hz is None:
        lead = next((converted[n] for n in ("steering_torque_Nm", "torque_Nm", "force_N")
                     if n in converted), None)  # fmt: skip
        periods = [float(np.median(np.diff(t))) for t in ([lead[0]] if lead else stamps)]
        rate_hz = 1.0 / min(periods)
    samples = (end - start) * rate_hz
    if samples > limits.MAX_SAMPLES:
        raise too_many(path, "would have", f"{samples:,.0f} samples at {rate_hz:g} Hz",
                       limits.MAX_SAMPLES)  # fmt: skip
    time = np.arange(start, end, 1.0 / rate_hz)
    signals = {n: np.interp(time, t, v) for n, (t, v) in converted.items()}
    return Result(time - start, signals, {"time_origin_s": f"{start:.6f}"})


def _check_gaps(
    path: Path, converted: Mapping[str, tuple[FloatArray, FloatArray]], start: float, end: float
) -> None:
    """Refuse a channel silent within [start, end] (s) for longer than MAX_GAP_S and
    MAX_GAP_PERIODS of its median period."""
    for name, (t, _) in converted.items():
        inside = t[(t >= start) & (t <= end)]
        steps = np.diff(inside)
        if len(steps) == 0:
            continue
        allowed = max(MAX_GAP_S, MAX_GAP_PERIODS * float(np.median(steps)))
        if steps.max() > allowed:
            k = int(np.argmax(steps))
            raise InputError(
                f"{path}: {name} has no sample for {steps[k]:.3g} s from t = "
                f"{inside[k] - start:.3f} s (its period is {np.median(steps):.3g} s): bridging "
                "that would invent data; cut the log at the gap (one file each side)"
            )
