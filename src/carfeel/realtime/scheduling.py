"""What the operating system offers a 1 kHz loop written in Python, taken and reported.

A wall-clock run (the identification and the loop alike) asks, in this order:
- a core of its own (`os.sched_setaffinity`, Linux): the run is pinned to `cpu` if given, else
  to the last core it may use (the first is where most other work lands);
- real-time scheduling (`SCHED_FIFO`, priority REALTIME_PRIORITY) where the user may (root, or
  a user with an rtprio limit: `/etc/security/limits.d/`), else a raised priority (nice
  NICE_RAISE) where permitted; on Windows the high priority class and a 1 ms system timer;
- (the loop itself freezes the garbage collector: `loop.py`).
Linux keeps 5 % of each second for other tasks even under SCHED_FIFO (`sched_rt_runtime_us`),
so a loop that never sleeps cannot lock the machine. Everything taken is given back when the
run ends (`Scheduling.restore`), and the summary says what the run got: on a busy machine
without it, stalls of 20-80 ms end runs (the watchdog's stall fault says what to do).
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

REALTIME_PRIORITY = 20
"""SCHED_FIFO priority (1..99): above ordinary work, below the kernel's own threads."""
NICE_RAISE = -10


_CLAIMED: list[tuple[set[int], int | None]] = []
"""While a claim holds on Linux: the cores the process had before it and the loop's (None: not
pinned)."""


def background() -> str:
    """Called first in a helper thread of the loop (a recorder's writer, a file's closing):
    give up what the loop took. A thread inherits its creator's core and SCHED_FIFO on Linux,
    and a helper at the loop's own FIFO priority on the loop's core is not preempted by the
    loop when its timer wakes it: the recorder's writer, formatting a block every 0.5 s, held
    the loop 1.4 ms late at each (13 ms when it yielded the GIL per row). So: ordinary
    scheduling and the cores but the loop's. Returns what it did (for tests), never raises."""
    if not _CLAIMED or not sys.platform.startswith("linux"):
        return ""
    cores, loop = _CLAIMED[-1]
    done = []
    if hasattr(os, "sched_setscheduler") and os.sched_getscheduler(0) != os.SCHED_OTHER:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
            done.append("ordinary scheduling")
    others = (cores - {loop} or cores) if loop is not None else cores
    with contextlib.suppress(OSError):
        os.sched_setaffinity(0, others)
        done.append(f"CPUs {','.join(map(str, sorted(others)))}")
    return ", ".join(done)


@dataclass
class Scheduling:
    """What a run was given; `restore` gives it back."""

    granted: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    _undo: list[Callable[[], None]] = field(default_factory=list)

    def text(self) -> str:
        got = ", ".join(self.granted) or "nothing beyond a normal process"
        missing = f" (not given: {', '.join(self.refused)})" if self.refused else ""
        return f"scheduling: {got}{missing}"

    def restore(self) -> None:
        for undo in reversed(self._undo):
            with contextlib.suppress(OSError, ValueError, AttributeError):
                undo()
        self._undo.clear()


def claim(cpu: int | None = None) -> Scheduling:
    """Take what the system allows for this process's real-time work (see the module)."""
    taken = Scheduling()
    if hasattr(os, "sched_setaffinity") and hasattr(os, "sched_getaffinity"):
        before = os.sched_getaffinity(0)
        target = cpu if cpu is not None else max(before)
        pinned: int | None = None
        try:
            os.sched_setaffinity(0, {target})
            taken.granted.append(f"pinned to CPU {target}")
            taken._undo.append(lambda: os.sched_setaffinity(0, before))
            pinned = target
        except OSError as exc:
            taken.refused.append(f"CPU {target} ({exc.strerror})")
        _CLAIMED.append((set(before), pinned))  # for the loop's helper threads: `background`
        taken._undo.append(lambda: _CLAIMED.clear())
    if sys.platform.startswith("linux") and hasattr(os, "sched_setscheduler"):
        policy = os.sched_getscheduler(0)
        param = os.sched_getparam(0)
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
            taken.granted.append(f"real-time scheduling (SCHED_FIFO {REALTIME_PRIORITY})")
            taken._undo.append(lambda: os.sched_setscheduler(0, policy, param))
        except OSError:
            taken.refused.append("real-time scheduling (no permission: an rtprio limit)")
            _raise_priority(taken)
    elif sys.platform == "win32":
        _windows(taken)
    else:
        _raise_priority(taken)
    return taken


def _raise_priority(taken: Scheduling) -> None:
    if not hasattr(os, "nice") or not hasattr(os, "getpriority"):
        return
    before = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        os.setpriority(os.PRIO_PROCESS, 0, before + NICE_RAISE)
        taken.granted.append(f"priority raised (nice {before + NICE_RAISE})")
        taken._undo.append(lambda: os.setpriority(os.PRIO_PROCESS, 0, before))
    except OSError:
        taken.refused.append("a raised priority (no permission)")


def _windows(taken: Scheduling) -> None:  # pragma: no cover - exercised on Windows only
    import ctypes

    kernel32 = ctypes.windll.kernel32  # type: ignore[attr-defined]
    winmm = ctypes.windll.winmm  # type: ignore[attr-defined]
    high_priority_class = 0x00000080
    process = kernel32.GetCurrentProcess()
    before = kernel32.GetPriorityClass(process)
    if kernel32.SetPriorityClass(process, high_priority_class):
        taken.granted.append("the high priority class")
        taken._undo.append(lambda: kernel32.SetPriorityClass(process, before))
    else:
        taken.refused.append("the high priority class")
    if winmm.timeBeginPeriod(1) == 0:
        taken.granted.append("a 1 ms system timer")
        taken._undo.append(lambda: winmm.timeEndPeriod(1))


@contextlib.contextmanager
def claimed(cpu: int | None = None, wanted: bool = True) -> Iterator[Scheduling]:
    """`claim` for the duration of a block (nothing when not `wanted`: simulated time)."""
    taken = claim(cpu) if wanted else Scheduling()
    try:
        yield taken
    finally:
        taken.restore()
