"""Clocks for the loop: the wall clock for devices, a simulated one for tests and fast runs.

Both count integer nanoseconds. The wall clock sleeps until shortly before a deadline and spins
on the monotonic counter for the rest (`time.sleep` alone overshoots by 50-100 us or more).
"""

from __future__ import annotations

import time
from typing import Protocol

SPIN_NS = 200_000
"""Sleep until this long before a deadline, then spin (measured on these machines)."""


class Clock(Protocol):
    def now_ns(self) -> int: ...

    def sleep_until(self, deadline_ns: int) -> None: ...


class WallClock:
    """Monotonic time; sleep, then spin, to each deadline."""

    def now_ns(self) -> int:
        return time.perf_counter_ns()

    def sleep_until(self, deadline_ns: int) -> None:
        clock = time.perf_counter_ns
        remaining = deadline_ns - clock()
        if remaining > SPIN_NS:
            time.sleep((remaining - SPIN_NS) / 1e9)
        while clock() < deadline_ns:
            pass


class SimulatedClock:
    """Time that moves only when the loop waits: each wait ends exactly at its deadline.

    `stall(at_ns, for_ns)` makes the wait that passes `at_ns` end `for_ns` late, as a stalled
    process would (for tests of the watchdog).
    """

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns
        self._stalls: list[tuple[int, int]] = []

    def now_ns(self) -> int:
        return self._now

    def sleep_until(self, deadline_ns: int) -> None:
        late = 0
        for at, duration in list(self._stalls):
            if self._now <= at < deadline_ns:
                late += duration
                self._stalls.remove((at, duration))
        self._now = max(self._now, deadline_ns) + late

    def stall(self, at_ns: int, for_ns: int) -> None:
        self._stalls.append((at_ns, for_ns))
