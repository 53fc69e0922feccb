"""The recordings' plots, drawn where they cannot take the loop's time.

A plot reads a whole recording and runs matplotlib: a second or more of CPU. In the panel's
server (a thread beside the event loop) six at once took the cores from the loop's process and
stalled it 28 ms (issue 24). So: one worker process for every plot (`Plots`), spawned on the
first one, at the lowest priority the system has (Linux's SCHED_IDLE: it runs only on a core
nothing else wants; Windows' idle priority class; else nice 19) and kept off the loop's core
when the loop is pinned. At most MAX_WAITING plots are drawn or waiting (one at a time;
beyond: `Busy`, a 429); requests for the same file share one drawing; the last CACHE_SIZE are
kept (by path, size and mtime: a file that changed is drawn anew).
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import os
import sys
from collections import OrderedDict
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from carfeel.errors import InputError

MAX_WAITING = 4
"""Plots drawn or waiting at once; a fifth is refused (429) until one is done."""
RETRY_AFTER_S = 2
CACHE_SIZE = 8
MAX_PLOT_BYTES = 256 * 1024 * 1024
"""The largest recording drawn (about 30 minutes at 1 kHz): the plot reads it whole."""


class Busy(InputError):
    """Too many plots are being drawn or waiting: try again in a few seconds."""


def lower_priority(avoid_cpu: int | None) -> None:
    """The plot worker's initializer: the lowest priority, and off the loop's core."""
    if sys.platform == "win32":  # Windows: the idle priority class (no nice, no SCHED_IDLE)
        import ctypes

        kernel32 = ctypes.windll.kernel32
        kernel32.SetPriorityClass(kernel32.GetCurrentProcess(), 0x00000040)  # IDLE_PRIORITY_CLASS
        return
    if hasattr(os, "sched_setscheduler") and hasattr(os, "SCHED_IDLE"):
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    if hasattr(os, "nice"):
        with contextlib.suppress(OSError):
            os.nice(19)
    if avoid_cpu is not None and hasattr(os, "sched_setaffinity"):
        others = os.sched_getaffinity(0) - {avoid_cpu}
        if others:
            os.sched_setaffinity(0, others)


def render(path: str, title: str) -> bytes:
    """The PNG of a recording (the paper's Fig. 10 and 11): runs in the worker process."""
    import tempfile

    from carfeel.io.plots import plot_recording
    from carfeel.simulation.result import Result

    with tempfile.TemporaryDirectory(prefix="carfeel-plot-") as tmp:
        recording = Result.from_csv(Path(path), drop_partial_last_line=True)
        return plot_recording(recording, Path(tmp) / "plot.png", title).read_bytes()


class Plots:
    """See the module. Used from the panel's event loop only (no lock needed)."""

    def __init__(self, avoid_cpu: int | None = None) -> None:
        self.avoid_cpu = avoid_cpu
        self._pool: ProcessPoolExecutor | None = None
        self._drawing: dict[tuple[str, int, int], asyncio.Future[bytes]] = {}
        self._cache: OrderedDict[tuple[str, int, int], bytes] = OrderedDict()

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=1,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=lower_priority,
                initargs=(self.avoid_cpu,),
            )
        return self._pool

    async def get(self, path: Path) -> bytes:
        info = path.stat()
        if info.st_size > MAX_PLOT_BYTES:
            raise InputError(
                f"{path.name} is {info.st_size / 1e6:.0f} MB; the panel plots recordings of at "
                f"most {MAX_PLOT_BYTES / 1e6:.0f} MB (download it and plot it with carfeel's "
                "plots in Python)"
            )
        key = (str(path), info.st_size, info.st_mtime_ns)
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        drawing = self._drawing.get(key)
        if drawing is None:
            if len(self._drawing) >= MAX_WAITING:
                raise Busy(
                    f"{len(self._drawing)} plots are being drawn or waiting (the panel draws "
                    f"one at a time, at the lowest priority, so that the loop keeps its time): "
                    f"try again in {RETRY_AFTER_S} s"
                )
            future: Future[bytes] = self._executor().submit(render, str(path), path.stem)
            drawing = asyncio.wrap_future(future)
            self._drawing[key] = drawing
            drawing.add_done_callback(lambda _: self._drawn(key))
        try:
            png = await asyncio.shield(drawing)  # one waiter leaving does not cancel the others'
        except BrokenProcessPool:
            self.close()  # the next plot starts a new worker
            raise InputError(
                f"the plot's process ended while drawing {path.name} (out of memory?)"
            ) from None
        return png

    def _drawn(self, key: tuple[str, int, int]) -> None:
        drawing = self._drawing.pop(key, None)
        if drawing is not None and not drawing.cancelled() and drawing.exception() is None:
            self._cache[key] = drawing.result()
            while len(self._cache) > CACHE_SIZE:
                self._cache.popitem(last=False)

    def close(self, wait: bool = False) -> None:
        """Drop the waiting drawings; with `wait`, also wait for the one under way (at the
        panel's end: its worker exits cleanly, leaving no semaphore behind)."""
        if self._pool is not None:
            self._pool.shutdown(wait=wait, cancel_futures=True)
            self._pool = None
