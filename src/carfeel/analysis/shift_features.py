"""Features of a simulated engagement, from its labelled samples: what a report quotes."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from carfeel.simulation.result import Result


@dataclass(frozen=True, slots=True)
class ShiftFeatures:
    """Figures of one push into gear. NaN where a stage did not occur."""

    stages: tuple[str, ...]
    """Stages in the order they were first entered."""
    synchronization_position_m: float
    synchronization_force_N: float
    """Median knob force while the lever is blocked: the plateau."""
    synchronization_peak_N: float
    synchronization_hold_s: float
    """How long the knob stayed still at the synchro ring."""
    engagement_position_m: float
    """Where the lever met the teeth (the engagement stage's first sample)."""
    engagement_peak_N: float
    engagement_peak_position_m: float
    """Where the knob force peaked in the engagement stage."""
    stop_peak_N: float
    stop_overshoot_m: float
    """How far past the in-gear position the knob went."""
    final_stage: str
    final_position_m: float

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def first_entries(stages: np.ndarray) -> list[tuple[str, int]]:
    """(stage, index) of each stage's first sample, in order."""
    seen: dict[str, int] = {}
    for i, name in enumerate(stages.tolist()):
        seen.setdefault(name, i)
    return sorted(seen.items(), key=lambda item: item[1])


def shift_features(result: Result, in_gear_position_m: float) -> ShiftFeatures:
    stages = result["stage"]
    x = result["position_m"]
    force = result["force_N"]
    dt = float(result.time_s[1] - result.time_s[0]) if len(result) > 1 else float("nan")
    nan = float("nan")

    def mask(name: str) -> np.ndarray:
        return np.asarray(stages == name)

    sync = mask("synchronization")
    engagement = mask("engagement")
    stop = mask("stop")
    peak_at = (
        int(np.flatnonzero(engagement)[np.argmax(force[engagement])]) if engagement.any() else -1
    )
    return ShiftFeatures(
        stages=tuple(name for name, _ in first_entries(stages)),
        synchronization_position_m=float(x[sync][0]) if sync.any() else nan,
        synchronization_force_N=float(np.median(force[sync])) if sync.any() else nan,
        synchronization_peak_N=float(force[sync].max()) if sync.any() else nan,
        synchronization_hold_s=float(sync.sum() * dt),
        engagement_position_m=float(x[engagement][0]) if engagement.any() else nan,
        engagement_peak_N=float(force[engagement].max()) if engagement.any() else nan,
        engagement_peak_position_m=float(x[peak_at]) if engagement.any() else nan,
        stop_peak_N=float(force[stop].max()) if stop.any() else nan,
        stop_overshoot_m=float(x[stop].max() - in_gear_position_m) if stop.any() else nan,
        final_stage=str(stages[-1]),
        final_position_m=float(x[-1]),
    )
