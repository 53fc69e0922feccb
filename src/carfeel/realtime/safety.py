"""Safety: never hurt a hand, never leave a force on.

- `ForceLimiter`: every command is clipped to the largest force and then to the largest change
  per step (slew); a NaN or infinite command counts as zero. It holds for any input sequence
  (a property test checks it).
- `Watchdog`: a fault (a stall of the loop, a NaN or out-of-range reading, a lost device) starts a
  fade: the force envelope goes linearly from 1 to 0 within `fade_s`, and the run stops. A stall
  cannot be answered while it lasts; the devices' own hold time (their effects end by themselves)
  covers it, and on the next tick the watchdog fades from there.
- Ramp-in: after the start-up calibration the largest force rises from `start_fraction` of the
  limit to all of it over `ramp_s`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class SafetyLimits:
    max_force: float
    """Largest force (N) or torque (Nm) per axis, device units."""
    max_slew_per_s: float
    """Largest change of the command per second."""
    fade_s: float = 0.05
    stall_s: float = 0.02
    """A tick later than this after the previous one is a stall."""
    range_margin: float = 0.1
    """A reading beyond (1 + margin) x the device's travel is out of range."""
    ramp_s: float = 1.0
    start_fraction: float = 0.2


class ForceLimiter:
    """Clip to the largest force, then to the largest slew, per axis."""

    __slots__ = ("_last", "limits")

    def __init__(self, limits: SafetyLimits, axes: int) -> None:
        self.limits = limits
        self._last = [0.0] * axes

    @property
    def last(self) -> tuple[float, ...]:
        return tuple(self._last)

    def limit(
        self, commands: tuple[float, ...], dt_s: float, scale: float = 1.0
    ) -> tuple[float, ...]:
        """The commands made safe; `scale` (0..1) lowers the largest force (ramp-in, fade)."""
        top = self.limits.max_force * min(1.0, max(0.0, scale))
        step = self.limits.max_slew_per_s * dt_s
        out = []
        for i, wanted in enumerate(commands):
            if not math.isfinite(wanted):
                wanted = 0.0
            wanted = min(top, max(-top, wanted))
            last = self._last[i]
            value = min(last + step, max(last - step, wanted))
            # A lowered ceiling (fade) wins over the slew: never above the ceiling.
            value = min(top, max(-top, value)) if abs(value) > top else value
            self._last[i] = value
            out.append(value)
        return tuple(out)


class Watchdog:
    """Watches each tick; after a fault, `envelope` fades from 1 to 0 over `fade_s`."""

    __slots__ = ("_fade_left", "faults", "limits", "travel")

    def __init__(self, limits: SafetyLimits, travel: float) -> None:
        self.limits = limits
        self.travel = travel
        self.faults: list[str] = []
        self._fade_left: float | None = None

    @property
    def faulted(self) -> bool:
        return self._fade_left is not None

    def fault(self, reason: str) -> None:
        """Start the fade; the first fault is the one reported (later ones follow from it)."""
        if self._fade_left is None:
            self.faults.append(reason)
            self._fade_left = self.limits.fade_s

    def check(self, positions: tuple[float, ...], period_s: float, time_s: float) -> None:
        """Record a fault for a stall or a bad reading at this tick."""
        if period_s > self.limits.stall_s:
            self.fault(f"stall: {period_s * 1e3:.1f} ms between ticks at t = {time_s:.3f} s")
        bound = self.travel * (1.0 + self.limits.range_margin)
        for axis, value in enumerate(positions):
            if not math.isfinite(value):
                self.fault(f"axis {axis} read {value} at t = {time_s:.3f} s")
            elif abs(value) > bound:
                self.fault(
                    f"axis {axis} read {value:.4g}, beyond the travel {self.travel:g} at "
                    f"t = {time_s:.3f} s"
                )

    def envelope(self, dt_s: float) -> float:
        """1 before any fault; then down to 0 linearly over fade_s, one tick at a time."""
        if self._fade_left is None:
            return 1.0
        self._fade_left = max(0.0, self._fade_left - dt_s)
        return self._fade_left / self.limits.fade_s

    @property
    def finished(self) -> bool:
        """The fade is over: the force is zero and the run should stop."""
        return self._fade_left is not None and self._fade_left <= 0.0
