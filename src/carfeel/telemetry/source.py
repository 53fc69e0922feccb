"""Telemetry as the loop sees it: the latest vehicle state and a weight that fades it out.

Stale or bad telemetry (no good packet for `stale_after_s`, or a needed field NaN) fades the
weight linearly to 0 over `fade_s`; good packets bring it back at the same rate. The renderers
blend the telemetry-driven values with their passive fallbacks by this weight, so from the last
good packet the telemetry-driven forces are gone within stale_after_s + fade_s (0.3 s by default).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from carfeel.telemetry.receiver import Receiver
from carfeel.telemetry.state import VehicleState

AGE_BIN_S = 0.0005
AGE_BINS = 2000
"""Packet ages are counted in 0.5 ms bins to 1 s (then one bin for older): a bounded memory for
any session length, percentiles to half a millisecond."""
STALE_AFTER_S = 0.1
"""Six missed packets of a 60 Hz game; 100 of a 1 kHz simulator."""
FADE_S = 0.2


class VehicleSource:
    """Polled once a tick with the loop's time; `weight` is 1 with fresh good data, 0 without."""

    def __init__(
        self,
        receiver: Receiver,
        needs: Callable[[VehicleState], bool] = lambda s: not math.isnan(s.speed_m_s),
        stale_after_s: float = STALE_AFTER_S,
        fade_s: float = FADE_S,
    ) -> None:
        self.receiver = receiver
        self.needs = needs
        self.stale_after_s, self.fade_s = stale_after_s, fade_s
        self.state = VehicleState()
        self.weight = 0.0
        self.healthy = False
        self._last_good_s = -math.inf
        self._t = 0.0
        self.events: list[str] = []
        """What happened, with the loop's time: telemetry lost, back, bad packets."""
        self._bad_seen = 0
        self._started = False
        self.age_s = math.inf
        """The loop's time since the newest good packet came (0 on the tick it comes)."""
        self._ages = [0] * (AGE_BINS + 1)

    def update(self, t_s: float) -> tuple[VehicleState, float]:
        dt = max(0.0, t_s - self._t)
        self._t = t_s
        receiver = self.receiver
        if not self._started:  # what queued while the run was being set up is old news
            receiver.flush()
            self._started = True
        if receiver.poll(now_s=t_s):
            state = receiver.latest
            if self.needs(state):
                self.state = state
                self._last_good_s = t_s
        age = self.age_s = t_s - self._last_good_s
        if age < math.inf:
            self._ages[min(AGE_BINS, int(age / AGE_BIN_S))] += 1
        healthy = age <= self.stale_after_s
        if healthy != self.healthy:
            what = "back" if healthy else f"stale (no good packet for {self.stale_after_s:g} s)"
            self.events.append(f"telemetry {what} at t = {t_s:.3f} s")
            self.healthy = healthy
        if receiver.bad > self._bad_seen and (not self.events or "bad" not in self.events[-1]):
            self.events.append(f"bad packets from t = {t_s:.3f} s")
        self._bad_seen = receiver.bad
        step = dt / self.fade_s if self.fade_s > 0 else 1.0
        weight = self.weight + step if healthy else self.weight - step
        # Whole at the ends: sums of steps fall a rounding short of 1 (or 0) for a tick.
        self.weight = 1.0 if weight > 1.0 - 1e-9 else 0.0 if weight < 1e-9 else weight
        return self.state, self.weight

    def age_percentiles(self) -> dict[str, float]:
        """p50, p99 and max of the packet age over the ticks since the first good packet, s
        (to the 0.5 ms bin's upper edge; inf past 1 s); empty before any packet."""
        total = sum(self._ages)
        if not total:
            return {}
        out: dict[str, float] = {}
        seen = 0
        wanted = (("p50", 0.5), ("p99", 0.99))
        for i, count in enumerate(self._ages):
            seen += count
            for name, q in wanted:
                if name not in out and seen >= q * total:
                    out[name] = (i + 1) * AGE_BIN_S if i < AGE_BINS else math.inf
            if count:
                out["max"] = (i + 1) * AGE_BIN_S if i < AGE_BINS else math.inf
        return out

    def status(self) -> dict[str, float | int | bool | str]:
        """What a panel shows of the source now: health, weight, packet age, counters."""
        r = self.receiver
        return {"healthy": self.healthy, "weight": self.weight, "age_s": self.age_s,
                "packets": r.packets, "bad": r.bad, "car": r.latest.car}  # fmt: skip

    def close(self) -> None:
        """Close the socket; what the summary must say beyond the counts (packets from
        addresses not accepted, a decoder that raised) goes to `events`."""
        r = self.receiver
        r.close()
        ages = self.age_percentiles()
        if ages:
            self.events.append(
                f"telemetry packet age (loop time since the newest good packet, each tick): "
                f"p50 {ages['p50'] * 1e3:.1f} ms, p99 {ages['p99'] * 1e3:.1f} ms, max "
                f"{ages['max'] * 1e3:.1f} ms"
            )
        if r.foreign:
            shown = ", ".join(f"{a} ({k})" for a, k in r.foreign_from.items())
            self.events.append(
                f"telemetry: {r.foreign} packets from addresses not accepted dropped ({shown}); "
                f"accepted: {r.source.describe_accept()} (--accept-from)"
            )
        if r.errors:
            self.events.append(
                f"telemetry: the decoder raised on {r.errors} packets (counted bad; a bug to "
                f"report): {r.first_error}"
            )
