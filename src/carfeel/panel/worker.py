"""The loop's own process: a `carfeel run` session watched and steered through the ring.

`main` is the entry point multiprocessing spawns. The `Observer` sees every tick from the loop's
thread (`realtime.loop.LoopObserver`) and does, at a bounded cost (a few microseconds):
- the tick's row into the ring (strings as codes, each new one announced by an event);
- at most one command from the panel (stop, retune, record start/stop);
- the retune under way, if any, one blend step (`tuning.Ramp`);
- the row into the recording, if one is open (files are opened and closed by helper threads,
  never in the loop's thread; rows wait in memory while a file opens);
- the status block at display rate;
- the parent's death: if the panel's process is gone (the parent pid changes, or the lifeline
  pipe reads end-of-file) the run stops, and the force fades as on Ctrl-C: a hand is on the
  device and nobody is watching it any more.
"""

from __future__ import annotations

import math
import os
import sys
import threading
import traceback
from collections import deque
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from carfeel.panel import ring
from carfeel.panel.tuning import Ramp

STATUS_EVERY = 33
"""Ticks between status writes (30 Hz at 1 kHz)."""
LATENCY_P99_EVERY = 30
"""Status writes between two counts of the latency's p99 (once a second)."""
LIFELINE_EVERY = 50
MAX_PENDING_ROWS = 10_000
"""Rows kept while a recording's file opens (10 s at 1 kHz; beyond, the oldest are dropped)."""


class Observer:
    """See the module. Every method but `finish`, `failed` and `close` runs in the loop's
    thread, between ticks."""

    def __init__(self, shm: Any, lifeline: Connection | None, parent_pid: int | None) -> None:
        self.shm = shm
        self.lifeline = lifeline
        self.parent_pid = parent_pid
        self.side: ring.LoopSide | None = None
        self.parts: Any = None
        self.chain: Any = None
        self.renderer: Any = None
        self.model = ""
        self.rate_hz = 1000.0
        self.codes: dict[str, float] = {}
        self.ticks = 0
        self.time_s = 0.0
        self.stop = False
        self.orphaned = False
        self.ramps: deque[Ramp] = deque()
        self.tuning: list[dict[str, Any]] = []
        self._recorder: Any = None
        self._opening: list[tuple[object, ...]] | None = None
        self._opened: Any = None
        self._record_path: str | None = None
        self._record_outputs: Any = None
        self._threads: list[threading.Thread] = []
        self._faults = 0
        self.priority = ""
        self.gears: list[str] | None = None
        self._engaged = 0
        self._statuses = 0
        self._latency_p99_s = math.nan

    # -- the session's hooks ---------------------------------------------------------------
    def prepare(self, parts: Any) -> None:
        self.parts = parts
        renderer = parts.renderer
        self.renderer = getattr(renderer, "inner", renderer)  # telemetry wraps the model's
        self.gears = getattr(self.renderer, "gears", None)
        self.model = str(parts.metadata["model"])
        self.rate_hz = float(parts.metadata["rate_hz"])
        self.side = ring.LoopSide(self.shm, len(parts.columns))
        self.side.event(("ready", self._describe(parts)))

    def started(self, chain: Any) -> None:
        self.chain = chain
        self._status(calibrating=True)

    def tick(self, row: tuple[object, ...]) -> bool:
        side = self.side
        assert side is not None
        codes = self.codes
        side.row([v if v.__class__ is not str else codes.get(v) or self._code(v) for v in row])
        self.ticks += 1
        self.time_s = row[0]  # type: ignore[assignment]
        if self._recorder is not None:
            self._recorder.append(row)
        elif self._opening is not None:
            self._opening.append(row)
            if self._opened is not None:
                self._take_opened()
            elif len(self._opening) > MAX_PENDING_ROWS:
                del self._opening[0]
        gears = self.gears
        if gears is not None and len(gears) != self._engaged:
            side.event(("engaged", list(gears[self._engaged :]), self.time_s))
            self._engaged = len(gears)
        if self.ramps:
            ramp = self.ramps[0]
            was = ramp.started
            if ramp.step():
                self.ramps.popleft()
                self.tuning.append({"time_s": self.time_s, "changes": ramp.changes})
                side.event(("tuned", ramp.changes, self.time_s))
            elif ramp.started and not was:
                side.event(("tuning", ramp.changes, self.time_s))
        command = side.command()
        if command is not None:
            self._command(command)
        if self.parent_pid is not None and os.getppid() != self.parent_pid:
            self._orphan("the panel's process is gone")
        elif self.lifeline is not None and self.ticks % LIFELINE_EVERY == 0:
            try:
                if self.lifeline.poll():
                    self.lifeline.recv()
            except (EOFError, OSError):
                self._orphan("the panel's pipe closed")
        if self.ticks % STATUS_EVERY == 0:
            self._status()
        return self.stop

    # -- commands ----------------------------------------------------------------------------
    def _command(self, command: Any) -> None:
        side = self.side
        assert side is not None
        kind = command[0]
        if kind == "stop":
            self.stop = True
        elif kind == "retune":
            self.ramps.append(Ramp(self.renderer, self.model, command, self.rate_hz))
        elif kind == "record_start":
            self._record_start(command[1])
        elif kind == "record_stop":
            self._record_stop()
        else:
            side.event(("error", f"the loop does not know the command {kind!r}"))

    def _orphan(self, why: str) -> None:
        if not self.orphaned:
            self.orphaned = True
            self.stop = True
            assert self.side is not None
            self.side.event(("orphaned", why, self.time_s))

    def _code(self, text: str) -> float:
        code = float(len(self.codes) + 1)
        self.codes[text] = code
        assert self.side is not None
        self.side.event(("vocabulary", code, text))
        return code

    # -- recording ---------------------------------------------------------------------------
    def _record_start(self, path: str) -> None:
        side = self.side
        assert side is not None
        if self._recorder is not None or self._opening is not None:
            side.event(("record_error", "a recording is already running: stop it first"))
            return
        self._opening = []
        self._opened = None
        self._record_path = path
        metadata = dict(self.parts.metadata)
        metadata["recording"] = {"started_s": self.time_s, "tuning_before": list(self.tuning)}
        columns = self.parts.columns

        def open_file() -> None:
            from carfeel.io.outputs import Outputs
            from carfeel.realtime.recording import Recorder

            try:
                outputs = Outputs()
                final = Path(path)
                staged = outputs.add(final, ".csv", partial=True)
                outputs.add(final.with_suffix(".json"), ".json", partial=True)
                self._record_outputs = outputs
                self._opened = Recorder(staged, columns, metadata)
                side.event(("recording", path, self.time_s))
            except Exception as exc:  # the folder said no: tell the page
                self._opened = exc

        self._spawn(open_file)

    def _take_opened(self) -> None:
        opened, pending = self._opened, self._opening
        self._opened = self._opening = None
        if isinstance(opened, Exception):
            assert self.side is not None
            self.side.event(("record_error", f"cannot record: {opened}"))
            return
        for row in pending or ():
            opened.append(row)
        self._recorder = opened

    def _record_stop(self, summary: dict[str, Any] | None = None, wait: bool = False) -> None:
        if self._opening is not None and self._opened is None and wait:
            for thread in self._threads:
                thread.join()
        if self._opening is not None and self._opened is not None:
            self._take_opened()
        recorder, outputs, path = self._recorder, self._record_outputs, self._record_path
        self._recorder = None
        self._opening = None
        if recorder is None:
            return
        side = self.side
        assert side is not None
        ended = {"stopped": "recording stopped", "stopped_s": self.time_s}
        info = summary if summary is not None else ended
        tuning = list(self.tuning)

        def close_file() -> None:
            try:
                recorder.metadata["tuning"] = tuning
                recorder.close(info)
                outputs.commit()
                side.event(("recorded", path, recorder.rows, self.time_s))
            except Exception as exc:
                side.event(("record_error", f"the recording {path} could not be closed: {exc}"))

        if wait:
            close_file()
        else:
            self._spawn(close_file)

    def _spawn(self, target: Any) -> None:
        from carfeel.realtime.scheduling import background

        def run() -> None:
            background()  # not on the loop's core at its priority
            target()

        thread = threading.Thread(target=run, name="carfeel-panel-file", daemon=True)
        self._threads.append(thread)
        thread.start()

    # -- status ------------------------------------------------------------------------------
    def _status(self, calibrating: bool = False) -> None:
        side, chain = self.side, self.chain
        if side is None or chain is None:
            return
        guard, passivity = chain.guard, chain.passivity
        faults = chain.watchdog.faults
        if len(faults) != self._faults:
            self._faults = len(faults)
            side.event(("fault", list(faults), self.time_s))
        values = (
            self.time_s,
            guard.current_rms if guard is not None else math.nan,
            math.sqrt(guard.force_limit) if guard is not None else math.nan,
            guard.held_s if guard is not None else math.nan,
            guard.hold_s if guard is not None else math.nan,
            passivity.acted_s if passivity is not None else math.nan,
            min(passivity.energy) if passivity is not None else math.nan,
            float(chain.watchdog.faulted),
            float(len(self.ramps) - (1 if self.ramps and self.ramps[0].started else 0)),
            float(bool(self.ramps and self.ramps[0].started)),
            float(self._recorder is not None or self._opening is not None),
            float(self._recorder.rows if self._recorder is not None else 0),
            float(calibrating),
            *self._telemetry_status(),
        )
        side.status(values)

    def _telemetry_status(self) -> tuple[float, float, float]:
        """Packet age, the newest packet-to-force latency and its p99 over the session, s (NaN
        without telemetry); the p99 is counted once a second (a tenth of a millisecond)."""
        source = getattr(self.parts.renderer, "source", None) if self.parts else None
        if source is None:
            return math.nan, math.nan, math.nan
        if self._statuses % LATENCY_P99_EVERY == 0:
            self._latency_p99_s = source.latencies.percentiles().get("p99", math.nan)
        self._statuses += 1
        return float(source.age_s), float(source.latency_s), self._latency_p99_s

    def _describe(self, parts: Any) -> dict[str, Any]:
        """What the panel needs to draw and to check tunings (pickled: dataclasses kept)."""
        r = self.renderer
        out: dict[str, Any] = {
            "columns": tuple(parts.columns),
            "info": parts.info,
            "sizing": parts.sizing,
            "scaling": parts.scaling,
            "limits": parts.limits,
            "metadata": parts.metadata,
            "rate_hz": self.rate_hz,
            "speed_m_s": float(getattr(r, "speed", 0.0)),
            "aligning": getattr(getattr(r, "rendering", None), "aligning", "front-axle"),
            "pid": os.getpid(),
            "priority": self.priority,
        }
        sized = getattr(r, "sized", None)
        if sized is not None:  # the physical steering: its coupling, for checking a tuning
            out["physical"] = sized
            out["substeps"] = int(getattr(r, "substeps", 1))
        pattern = getattr(r, "pattern", None)
        if pattern is not None:
            out["layout"] = pattern.layout
            out["gearbox"] = pattern.engagement
        elif self.model == "shift":
            out["gearbox"] = r.gearbox
        marks = getattr(getattr(r, "lever", None), "marks", None)
        if marks is not None:  # a lever: its ends, detents and positions, for its view
            out["lever"] = tuple(marks)
        return out

    # -- the end -----------------------------------------------------------------------------
    def finish(self, summary: dict[str, Any], text: str) -> None:
        if self.orphaned:
            summary = summary | {"stopped": "orphaned: the panel's process is gone"}
            text += "\nstopped: the panel's process is gone (the force was faded)"
        self._record_stop(summary, wait=True)
        if self.side is not None:
            self.side.event(("ended", summary, text, self.orphaned))

    def failed(self, message: str) -> None:
        if self.side is None:
            self.side = ring.LoopSide(self.shm, 1)
        self._record_stop({"stopped": "error", "error": message}, wait=True)
        self.side.event(("error", message))

    def close(self) -> None:
        for thread in self._threads:
            thread.join(timeout=5.0)
        if self.side is not None:
            self.side.close()
        else:
            self.shm.close()


def main(
    run_kwargs: dict[str, Any],
    shm_name: str,
    lifeline: Connection | None,
    parent_pid: int | None,
    cpu: int | None = None,
) -> None:
    """The spawned process: one session, then exit."""
    from carfeel.errors import CarfeelError
    from carfeel.realtime.session import RealtimeRun, run_realtime

    if cpu is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {cpu})
    # Wall clock only: a simulated run has no deadline, and would starve the panel's side.
    priority = raise_priority() if run_kwargs.get("clock", "wall") == "wall" else "normal"
    # The recorder's and the file threads must not hold the GIL for 5 ms while a tick waits.
    sys.setswitchinterval(2e-4)
    shm = ring.attach(shm_name)
    observer = Observer(shm, lifeline, parent_pid)
    observer.priority = priority
    try:
        run = RealtimeRun(**run_kwargs)
        result = run_realtime(run, observer=observer)
        observer.finish(_plain(result.as_dict()), result.text())
    except CarfeelError as exc:
        observer.failed(str(exc))
    except BaseException as exc:
        observer.failed(f"the loop's process failed: {exc!r}\n{traceback.format_exc()}")
        raise
    finally:
        observer.close()


LOOP_NICE = -10
"""The loop's process asks for this niceness: beside a browser and the panel's server on the
same cores, the scheduler then gives it about 9 times their share when they compete."""


def raise_priority() -> str:
    """Raise the process's scheduling priority where allowed; say what it runs at."""
    if not hasattr(os, "setpriority"):
        return "normal priority (no setpriority here)"
    try:
        os.setpriority(os.PRIO_PROCESS, 0, LOOP_NICE)
    except OSError:
        return f"nice {os.getpriority(os.PRIO_PROCESS, 0)} (not allowed to raise it)"
    return f"nice {LOOP_NICE}"


def _plain(value: Any) -> Any:
    from carfeel.text import finite

    return finite(value)
