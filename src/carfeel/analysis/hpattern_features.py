"""Figures of an H-pattern run, from its labelled samples as they come: each engagement's
synchronization, tooth peak and stop peak, and the run's grinding (what `carfeel simulate
hpattern` reports and a sweep keeps)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from carfeel.simulation.result import Result


@dataclass(frozen=True, slots=True)
class EngagementFigures:
    """One push that reached a gear (its `engage` event), force magnitudes along the slot."""

    gear: str
    time_s: float
    """When the gear went in (the engage event's sample), s."""
    synchronization_s: float
    """Samples in synchronization since the previous engagement, times the sample period."""
    plateau_N: float
    """Median |force_x_N| over those samples (NaN without any)."""
    engagement_peak_N: float
    """Greatest |force_x_N| in the tooth engagement stage since the previous engagement."""
    stop_peak_N: float
    """Greatest |force_x_N| at the end stop from this engagement to the next (NaN if none)."""


@dataclass
class _Open:
    """The engagement being measured: its window's samples (synchronization forces kept for
    their median), and the stop peak of the last engagement until the next one."""

    sync_forces: list[np.ndarray] = field(default_factory=list)
    sync_count: int = 0
    teeth_peak: float = -math.inf
    last: tuple[str, float, float, float, float] | None = None
    """(gear, time, synchronization s, plateau, tooth peak) of the last engagement."""
    last_stop_peak: float = -math.inf


class EngagementStream:
    """A sink of `carfeel.simulation.stream`: the figures of every engagement of an H-pattern
    run (columns stage, event, force_x_N, gear, grind_N), the samples not kept (but for the
    synchronization forces of the push under way, for their median)."""

    def __init__(self) -> None:
        self.engagements: list[EngagementFigures] = []
        self.samples = 0
        self.final_gear = ""
        self.final_time_s = math.nan
        self.peak_grind_N = 0.0
        self._times: list[float] = []
        self._open = _Open()

    @property
    def dt_s(self) -> float:
        return self._times[1] - self._times[0] if len(self._times) > 1 else math.nan

    def write(self, block: Result) -> None:
        n = len(block)
        if not n:
            return
        if len(self._times) < 2:
            self._times.extend(block.time_s[: 2 - len(self._times)].tolist())
        stages, events = block["stage"], block["event"]
        force = np.abs(block["force_x_N"])
        window_start, stop_start = 0, 0
        for i in np.flatnonzero(np.char.startswith(events.astype(str), "engage")).tolist():
            self._stop_piece(stages[stop_start:i], force[stop_start:i])
            self._window_piece(stages[window_start : i + 1], force[window_start : i + 1])
            self._close(str(events[i]).split()[1], float(block.time_s[i]))
            window_start, stop_start = i + 1, i
        self._stop_piece(stages[stop_start:], force[stop_start:])
        self._window_piece(stages[window_start:], force[window_start:])
        self.peak_grind_N = max(self.peak_grind_N, float(np.abs(block["grind_N"]).max()))
        self.final_gear = str(block["gear"][-1])
        self.final_time_s = float(block.time_s[-1])
        self.samples += n

    def _window_piece(self, stages: np.ndarray, force: np.ndarray) -> None:
        sync = stages == "synchronization"
        if sync.any():
            self._open.sync_forces.append(force[sync])
            self._open.sync_count += int(sync.sum())
        teeth = stages == "engagement"
        if teeth.any():
            self._open.teeth_peak = max(self._open.teeth_peak, float(force[teeth].max()))

    def _stop_piece(self, stages: np.ndarray, force: np.ndarray) -> None:
        at_stop = stages == "stop"
        if self._open.last is not None and at_stop.any():
            self._open.last_stop_peak = max(self._open.last_stop_peak, float(force[at_stop].max()))

    def _close(self, gear: str, time_s: float) -> None:
        """An engage event: the last engagement's stop peak is complete, this one's window."""
        self._finish_last()
        o = self._open
        plateau = float(np.median(np.concatenate(o.sync_forces))) if o.sync_count else math.nan
        teeth = o.teeth_peak if math.isfinite(o.teeth_peak) else math.nan
        self._open = _Open(last=(gear, time_s, float(o.sync_count * self.dt_s), plateau, teeth))

    def _finish_last(self) -> None:
        o = self._open
        if o.last is not None:
            stop = o.last_stop_peak if math.isfinite(o.last_stop_peak) else math.nan
            self.engagements.append(EngagementFigures(*o.last, stop))
            o.last, o.last_stop_peak = None, -math.inf

    def figures(self) -> list[EngagementFigures]:
        """Every engagement, the last one's stop peak up to the run's end."""
        self._finish_last()
        return self.engagements
