"""Features of a simulated engagement, from its labelled samples: what a report quotes."""

from __future__ import annotations

import math
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


class ShiftFeatureStream:
    """`ShiftFeatures` of a run whose samples come a block at a time (a sink of
    `carfeel.simulation.stream`): the figures are kept as they come, not the samples, but for
    the plateau's forces (its median needs them: 8 bytes a sample of synchronization)."""

    def __init__(self, in_gear_position_m: float) -> None:
        self.in_gear_position_m = in_gear_position_m
        self.samples = 0
        self._times: list[float] = []  # the first two: the sample period
        self._first: dict[str, int] = {}
        self._sync_force: list[np.ndarray] = []
        self._sync_count = 0
        self._sync_position = math.nan
        self._engagement_position = math.nan
        self._engagement_peak = -math.inf
        self._engagement_peak_position = math.nan
        self._stop_peak = -math.inf
        self._stop_reach = -math.inf
        self._final = ("", math.nan)
        self.time_to_stop_s = math.nan
        """When the lever first reached the end stop (NaN if it never did), s."""

    def write(self, block: Result) -> None:
        if not len(block):
            return
        stages, x, force = block["stage"], block["position_m"], block["force_N"]
        if len(self._times) < 2:
            self._times.extend(block.time_s[: 2 - len(self._times)].tolist())
        for name, i in first_entries(stages):
            if name not in self._first:
                self._first[name] = self.samples + i
                if name == "stop":
                    self.time_to_stop_s = float(block.time_s[i])
        sync = np.asarray(stages == "synchronization")
        if sync.any():
            if not self._sync_count:
                self._sync_position = float(x[sync][0])
            self._sync_force.append(force[sync])
            self._sync_count += int(sync.sum())
        engagement = np.asarray(stages == "engagement")
        if engagement.any():
            if math.isnan(self._engagement_position):
                self._engagement_position = float(x[engagement][0])
            at = int(np.flatnonzero(engagement)[np.argmax(force[engagement])])
            if force[at] > self._engagement_peak:  # the first of equal peaks, as argmax
                self._engagement_peak, self._engagement_peak_position = (
                    float(force[at]),
                    float(x[at]),
                )
        stop = np.asarray(stages == "stop")
        if stop.any():
            self._stop_peak = max(self._stop_peak, float(force[stop].max()))
            self._stop_reach = max(self._stop_reach, float(x[stop].max()))
        self._final = (str(stages[-1]), float(x[-1]))
        self.samples += len(block)

    def features(self) -> ShiftFeatures:
        if not self.samples:
            raise ValueError("no samples: a run has at least one")
        nan = math.nan
        dt = self._times[1] - self._times[0] if len(self._times) > 1 else nan
        seen = self._first
        return ShiftFeatures(
            stages=tuple(sorted(seen, key=seen.__getitem__)),
            synchronization_position_m=self._sync_position,
            synchronization_force_N=(
                float(np.median(np.concatenate(self._sync_force))) if self._sync_count else nan
            ),
            synchronization_peak_N=(
                max(float(f.max()) for f in self._sync_force) if self._sync_count else nan
            ),
            synchronization_hold_s=float(self._sync_count * dt),
            engagement_position_m=self._engagement_position,
            engagement_peak_N=self._engagement_peak if "engagement" in seen else nan,
            engagement_peak_position_m=self._engagement_peak_position,
            stop_peak_N=self._stop_peak if "stop" in seen else nan,
            stop_overshoot_m=(
                self._stop_reach - self.in_gear_position_m if "stop" in seen else nan
            ),
            final_stage=self._final[0],
            final_position_m=self._final[1],
        )


def shift_features(result: Result, in_gear_position_m: float) -> ShiftFeatures:
    """The features of a whole run in memory (one block of `ShiftFeatureStream`)."""
    stream = ShiftFeatureStream(in_gear_position_m)
    stream.write(result)
    return stream.features()
