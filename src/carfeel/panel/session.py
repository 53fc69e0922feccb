"""One loop process and its ring as the panel sees them: the process started and stopped, its
events, status and health read at display rate, its state described for the API."""

from __future__ import annotations

import asyncio
import contextlib
import math
import multiprocessing
import os
import time
from collections import deque
from dataclasses import asdict
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.panel import ring, tuning
from carfeel.panel.values import jsonable

STOP_TIMEOUT_S = 10.0


class Session:
    """One loop process and its ring, as the panel sees them."""

    def __init__(self, run: dict[str, Any], preset: Any, physics: bool | None) -> None:
        self.run = run
        self.model: str = run["model"]
        self.steering_model: str = run.get("steering_model", "paper")
        self.kind = tuning.kind_of(self.model, self.steering_model)
        """The tunables' model key (the physical steering's differ from the law's)."""
        self.preset = preset
        self.physics = physics
        self.state = "starting"
        self.error: str | None = None
        self.summary: dict[str, Any] | None = None
        self.text = ""
        self.ready: dict[str, Any] | None = None
        self.columns: tuple[str, ...] = ()
        self.vocabulary: dict[float, str] = {}
        self.status: dict[str, float] | None = None
        self.events: deque[dict[str, Any]] = deque(maxlen=200)
        self.faults: list[str] = []
        self.recording: str | None = None
        self.engaged: list[str] = []
        """Every gear engaged so far, in order (the loop's own list, one event per gear)."""
        self.tuning_history: list[dict[str, Any]] = []
        self.shm = ring.create()
        self.side = ring.PanelSide(self.shm)
        self.process: Any = None
        self.lifeline: Any = None
        self.cursor = 0
        self.periods: deque[float] = deque(maxlen=10_000)
        self.last_t: float | None = None
        self.overruns = 0
        self.rows = 0
        self.health: dict[str, float] = {}
        self.at_limit: deque[float] = deque(maxlen=1000)
        self.unlinked = False
        self.changed = asyncio.Event()
        self.model_speed_m_s: float | None = None
        """The model's speed in the newest row, where telemetry drives it."""

    def start(self, cpu: int | None) -> None:
        from carfeel.panel import worker

        ctx = multiprocessing.get_context("spawn")
        receive_end, self.lifeline = ctx.Pipe(duplex=False)
        self.process = ctx.Process(
            target=worker.main,
            args=(self.run, self.shm.name, receive_end, os.getpid(), cpu),
            name="carfeel-loop",
            daemon=True,  # at the panel's exit: SIGTERM, which the loop answers with its fade
        )
        self.process.start()
        receive_end.close()

    @property
    def running(self) -> bool:
        return self.state in ("starting", "calibrating", "running", "stopping")

    def index(self, name: str) -> int | None:
        return self.columns.index(name) if name in self.columns else None

    def pump(self) -> None:
        """Events, status and loop health from the ring (the panel's event loop, 30 Hz)."""
        for event in self.side.events():
            self._event(event)
        status = self.side.status()
        if status is not None:
            self.status = status
            if self.state == "calibrating" and not status["calibrating"] and self.rows:
                self.state = "running"
        if self.columns:
            rows, self.cursor, _ = self.side.read_rows(self.cursor, len(self.columns))
            if len(rows):
                self._health(rows)
                speed = self.index("model_speed_m_s")  # telemetry moves it
                if speed is not None and math.isfinite(rows[-1, speed]):
                    self.model_speed_m_s = float(rows[-1, speed])
        if self.process is not None and not self.process.is_alive() and self.running:
            # What it wrote between the read above and its exit (its "ended", with the summary)
            # comes first: only a loop that ended without saying so is an error.
            for event in self.side.events():
                self._event(event)
            if self.running:
                code = self.process.exitcode
                self._event(("error", f"the loop's process ended (exit code {code})"))
        if self.process is not None and not self.process.is_alive() and not self.unlinked:
            self.unlink()

    def _health(self, rows: Any) -> None:
        import numpy as np

        t = rows[:, 0]
        if self.last_t is not None:
            periods = np.diff(np.concatenate(([self.last_t], t)))
        else:
            periods = np.diff(t)
        self.last_t = float(t[-1])
        self.periods.extend(periods.tolist())
        self.overruns += int(np.nansum(rows[:, 1]))
        self.rows += len(rows)
        limits = self.ready["limits"] if self.ready else None
        if limits is not None:
            axes = self.ready["info"].axes if self.ready else 1
            command = np.abs(rows[:, 2 : 2 + axes]).max(axis=1)
            self.at_limit.extend((command >= 0.999 * limits.max_force).tolist())
        if self.state == "calibrating":
            self.state = "running"
        if self.periods:
            recent = np.asarray(self.periods)
            error = (recent - 1.0 / self.ready["rate_hz"]) * 1e6 if self.ready else recent
            window = recent[-1000:]
            self.health = {
                "rate_hz": float(len(window) / max(window.sum(), 1e-9)),
                "overruns": float(self.overruns),
                "period_error_p99_us": float(np.percentile(error, 99)),
                "period_error_max_us": float(error.max()),
                "periods": float(self.rows),
                "at_limit_share": float(np.mean(self.at_limit)) if self.at_limit else 0.0,
            }

    def _event(self, event: tuple[Any, ...]) -> None:
        kind = event[0]
        record: dict[str, Any] = {"event": kind, "wall": time.time()}
        if kind == "ready":
            self.ready = event[1]
            self.columns = self.ready["columns"]
            self.state = "calibrating"
        elif kind == "vocabulary":
            self.vocabulary[event[1]] = event[2]
            return
        elif kind == "engaged":
            self.engaged.extend(event[1])
            self.changed.set()
            return
        elif kind == "tuning":
            record |= {"changes": event[1], "time_s": event[2]}
        elif kind == "tuned":
            record |= {"changes": event[1], "time_s": event[2]}
            self.tuning_history.append(record)
        elif kind == "recording":
            self.recording = event[1]
            record |= {"path": Path(event[1]).name, "time_s": event[2]}
        elif kind == "recorded":
            self.recording = None
            record |= {"path": Path(event[1]).name, "rows": event[2], "time_s": event[3]}
        elif kind == "record_error":
            self.recording = None
            record["message"] = event[1]
        elif kind == "fault":
            self.faults = list(event[1])
            record["faults"] = self.faults
        elif kind == "orphaned":
            record["message"] = event[1]
        elif kind == "ended":
            self.summary, self.text = event[1], event[2]
            self.faults = list(self.summary.get("faults", []))
            self.state = "ended"
            record["stopped"] = self.summary.get("stopped")
        elif kind == "error":
            self.error = str(event[1])
            self.state = "failed" if self.state in ("starting", "calibrating") or not self.rows \
                else "ended"  # fmt: skip
            record["message"] = self.error
        elif kind == "lost":
            record["count"] = event[1]
        self.events.append(record)
        self.changed.set()

    def send(self, command: tuple[Any, ...]) -> None:
        if not self.running:
            raise InputError("no session is running: start one first")
        if not self.side.send(command):
            raise InputError(
                "the loop is not taking commands (16 waiting): it is stalled or stopping"
            )

    def stop(self) -> None:
        if self.running and self.state != "stopping":
            self.side.send(("stop",))
            self.state = "stopping"
            self.changed.set()

    def unlink(self) -> None:
        """The segment's name goes (the memory stays mapped for the last frames)."""
        if not self.unlinked:
            self.unlinked = True
            with contextlib.suppress(FileNotFoundError):
                self.shm.unlink()

    def close(self) -> None:
        if self.process is not None and self.process.pid is not None:  # started
            self.process.join(timeout=STOP_TIMEOUT_S)
            if self.process.is_alive():  # pragma: no cover - a loop that ignores its stop
                self.process.terminate()
                self.process.join(timeout=STOP_TIMEOUT_S)
        if self.lifeline is not None:
            self.lifeline.close()
        self.unlink()
        self.side.close()

    def decode(self, name: str, values: Any) -> list[Any]:
        vocabulary = self.vocabulary
        return [vocabulary.get(v, "") if not math.isnan(v) else "" for v in values.tolist()]

    def describe(self) -> dict[str, Any]:
        ready = self.ready or {}
        info = ready.get("info")
        out: dict[str, Any] = {
            "state": self.state,
            "model": self.model,
            "run": self.run,
            "error": self.error,
            "summary": self.summary,
            "text": self.text,
            "faults": self.faults,
            "recording": Path(self.recording).name if self.recording else None,
            "engaged": self.engaged,
            "columns": list(self.columns),
            "events": list(self.events)[-30:],
            "health": self.health,
            "status": self.status,
            "tuning_history": self.tuning_history,
        }
        if info is not None:
            limits = ready["limits"]
            out["device"] = {
                "name": info.name,
                "kind": info.kind,
                "axes": info.axes,
                "max_force": info.max_force,
                "travel": info.travel,
                "unit": "Nm" if info.kind == "wheel" else "N",
                "delay_ms": (info.command_delay_s + info.reading_delay_s) * 1e3,
                "report_hz": info.report_hz,
            }
            out["limits"] = {"max_force": limits.max_force, "max_slew_per_s": limits.max_slew_per_s,
                             "fade_s": limits.fade_s, "stall_s": limits.stall_s,
                             "ramp_s": limits.ramp_s}  # fmt: skip
            out["sizing"] = asdict(ready["sizing"])
            # How the device is known: identified hands off, its profile checked, or declared.
            out["knowledge"] = ready["metadata"].get("device_knowledge")
            out["scaling"] = asdict(ready["scaling"])
            out["rate_hz"] = ready["rate_hz"]
            out["loop_process"] = {"pid": ready["pid"], "priority": ready["priority"]}
            out["speed_kmh"] = ready["speed_m_s"] * 3.6
            if "physical" in ready:  # the physical steering's coupling (as sized at start-up)
                sized = ready["physical"]
                out["coupling"] = {
                    "stiffness": sized.coupling_stiffness,
                    "share": sized.share,
                    "zeta": min(sized.zeta),
                    "top_speed_kmh": sized.top_speed_m_s * 3.6,
                }
            if "layout" in ready:
                out["layout"] = jsonable(ready["layout"])
            if "lever" in ready:
                out["lever"] = [{"position_m": x, "name": name} for x, name in ready["lever"]]
            if "gearbox" in ready:
                g = ready["gearbox"]
                out["gearbox"] = {
                    "synchronization_position_m": g.synchronization_position_m,
                    "teeth_position_m": g.teeth_position_m,
                    "teeth_end_position_m": g.teeth_end_position_m,
                    "in_gear_position_m": g.in_gear_position_m,
                }
        return jsonable(out)  # type: ignore[no-any-return]
