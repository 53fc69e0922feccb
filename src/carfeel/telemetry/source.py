"""Telemetry as the loop sees it: the latest vehicle state and a weight that fades it out.

Stale or bad telemetry (no good packet for `stale_after_s`, or a needed field NaN) fades the
weight linearly to 0 over `fade_s`; good packets bring it back at the same rate. The renderers
blend the telemetry-driven values with their passive fallbacks by this weight, so from the last
good packet the telemetry-driven forces are gone within stale_after_s + fade_s (0.3 s by default).
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections.abc import Callable

from carfeel.telemetry.receiver import Receiver
from carfeel.telemetry.state import VehicleState

AGE_BIN_S = 0.0005
AGE_BINS = 2000
"""Packet ages are counted in 0.5 ms bins to 1 s (then one bin for older): a bounded memory for
any session length, percentiles to half a millisecond."""
LATENCY_BIN_S = 0.00005
LATENCY_BINS = 2000
"""Packet-to-force latencies in 50 us bins to 100 ms (then one bin for longer)."""
STALE_AFTER_S = 0.1
"""Six missed packets of a 60 Hz game; 100 of a 1 kHz simulator."""
FADE_S = 0.2


class Histogram:
    """Counts of durations in `bins` bins of `width_s`, one more for all longer ones: bounded
    memory whatever the session's length; percentiles to a bin's upper edge."""

    def __init__(self, width_s: float, bins: int) -> None:
        self.width_s, self.bins = width_s, bins
        self.counts = [0] * (bins + 1)
        self.total = 0

    def add(self, duration_s: float) -> None:
        index = int(duration_s / self.width_s) if duration_s >= 0.0 else 0
        self.counts[min(self.bins, index)] += 1
        self.total += 1

    def percentiles(self) -> dict[str, float]:
        """p50, p99 and max, s (a bin's upper edge; inf past the last bin); {} when empty."""
        if not self.total:
            return {}
        cumulative = list(itertools.accumulate(self.counts))
        out = {name: self._edge(bisect.bisect_left(cumulative, q * self.total))
               for name, q in (("p50", 0.5), ("p99", 0.99))}  # fmt: skip
        out["max"] = self._edge(bisect.bisect_left(cumulative, self.total))
        return out

    def _edge(self, index: int) -> float:
        return (index + 1) * self.width_s if index < self.bins else math.inf


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
        self.ages = Histogram(AGE_BIN_S, AGE_BINS)
        self.latencies = Histogram(LATENCY_BIN_S, LATENCY_BINS)
        """Packet-to-force latency: from a good packet's arrival (the kernel's receive time
        where the socket gives it, else when it was read) to the first command sent to the
        device that was computed from it (`commanded`); wall-clock runs only."""
        self.latency_s = math.nan
        """The newest packet's latency, s."""
        self._unsent_ns = 0
        """Arrival (time.perf_counter_ns()) of a good packet no command has used yet; 0: none."""

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
                self._unsent_ns = receiver.arrival_ns
        age = self.age_s = t_s - self._last_good_s
        if age < math.inf:
            self.ages.add(age)
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
        return self.ages.percentiles()

    def commanded(self, now_ns: int) -> None:
        """The loop sent the device this tick's commands at `now_ns` (time.perf_counter_ns(),
        the wall clock's): the newest good packet's latency, if this is its first command."""
        if self._unsent_ns:
            latency = self.latency_s = (now_ns - self._unsent_ns) / 1e9
            self.latencies.add(latency)
            self._unsent_ns = 0

    def status(self) -> dict[str, float | int | bool | str]:
        """What a panel shows of the source now: health, weight, packet age, counters."""
        r = self.receiver
        latency = self.latencies.percentiles()
        return {"healthy": self.healthy, "weight": self.weight, "age_s": self.age_s,
                "latency_s": self.latency_s, "latency_p99_s": latency.get("p99", math.nan),
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
        latency = self.latencies.percentiles()
        if latency:
            self.events.append(
                f"telemetry packet-to-force latency (arrival to the first command sent from "
                f"it, {self.latencies.total} packets): p50 {latency['p50'] * 1e3:.2f} ms, p99 "
                f"{latency['p99'] * 1e3:.2f} ms, max {latency['max'] * 1e3:.2f} ms"
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
