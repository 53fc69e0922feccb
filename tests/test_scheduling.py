"""What a wall-clock run takes from the system, and what its helper threads give back.

Linux threads inherit their creator's core and SCHED_FIFO: a recorder's writer started after
the claim ran at the loop's own FIFO priority on the loop's core, which the loop's timer does not
preempt, and held every 500th tick 1.4 ms late (13 ms when it yielded the GIL per row). These
tests read each thread's scheduling from the kernel (by its native id); they need the rights
to take SCHED_FIFO and two cores, which CI's machine has (root, two cores), and skip elsewhere
(a user without an rtprio limit gets the raised-priority path instead).
"""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

import pytest

from carfeel.realtime import scheduling
from carfeel.realtime.recording import Recorder

linux_only = pytest.mark.skipif(
    not sys.platform.startswith("linux") or len(os.sched_getaffinity(0)) < 2,
    reason="Linux scheduling, two cores",
)


def _fifo_allowed() -> bool:
    try:
        with scheduling.claimed(None) as taken:
            return any("SCHED_FIFO" in g for g in taken.granted)
    except OSError:
        return False


def _policy_and_cores(native_id: int) -> tuple[int, set[int]]:
    return os.sched_getscheduler(native_id), os.sched_getaffinity(native_id)


@linux_only
def test_a_helper_thread_leaves_the_loops_core_and_priority() -> None:
    if not _fifo_allowed():
        pytest.skip("SCHED_FIFO not permitted for this user")
    before = os.sched_getaffinity(0)
    seen: dict[str, object] = {}

    def helper() -> None:
        seen["inherited"] = _policy_and_cores(threading.get_native_id())
        seen["said"] = scheduling.background()
        seen["after"] = _policy_and_cores(threading.get_native_id())

    with scheduling.claimed(None) as taken:
        loop = max(before)
        assert f"pinned to CPU {loop}" in taken.granted
        thread = threading.Thread(target=helper)
        thread.start()
        thread.join()
        # The loop's thread keeps what it took.
        assert _policy_and_cores(threading.get_native_id()) == (os.SCHED_FIFO, {loop})
    assert seen["inherited"] == (os.SCHED_FIFO, {loop})  # what the defect was
    assert seen["after"] == (os.SCHED_OTHER, before - {loop})
    assert "ordinary scheduling" in str(seen["said"])
    # Given back: the process as before, and a helper outside a claim changes nothing.
    assert os.sched_getaffinity(0) == before and os.sched_getscheduler(0) == os.SCHED_OTHER
    assert scheduling.background() == ""


@linux_only
def test_the_recorders_writer_runs_off_the_loops_core(tmp_path: Path) -> None:
    if not _fifo_allowed():
        pytest.skip("SCHED_FIFO not permitted for this user")
    before = os.sched_getaffinity(0)
    with scheduling.claimed(None):
        recorder = Recorder(tmp_path / "r.csv", ("time_s", "x"), {"model": "shift"}, block=2)
        for n in range(4):
            recorder.append((n * 1e-3, 0.5))
        # The writer has written the first blocks: it has run its start.
        deadline = 200
        while recorder.rows < 4 and deadline:
            threading.Event().wait(0.01)
            deadline -= 1
        native = recorder._thread.native_id
        assert native is not None
        policy, cores = _policy_and_cores(native)
        recorder.close()
    assert policy == os.SCHED_OTHER
    assert max(before) not in cores and cores == before - {max(before)}
    assert (tmp_path / "r.csv").read_text().count("\n") == 5  # header + 4 rows
