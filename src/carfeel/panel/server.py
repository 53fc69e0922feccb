"""The panel's server: the page, a JSON API and a WebSocket stream (Starlette; uvicorn serves it).

The API (README, "The live panel"): every request but the page's own files carries the panel's
credential (`Authorization: Bearer T`; a WebSocket may offer the subprotocol `carfeel.token.T`
instead), whatever the address the panel listens on; POSTs take JSON (`Content-Type:
application/json`, which a cross-site form cannot send) of at most MAX_BODY_BYTES; bad input is a
400 with {"error": message}, a body too large 413, a plot when too many wait 429.

    GET  /api/options                 models, modes, devices, presets, hands, tunables
    GET  /api/session                 the session: state, configuration, sizing, summary
    POST /api/session                 start one: {"model", "preset", "device", ..., "force": true}
    POST /api/session/stop            stop it (the force fades as on Ctrl-C)
    GET  /api/tune                    the tunable parameters and their values now
    POST /api/tune                    {"values": {path: number}}: checked, then ramped in
    POST /api/presets                 {"name"}: the parameters now as a preset file
    GET  /api/recordings              the recordings in the panel's folder
    POST /api/recording               {"name"}: start recording; POST /api/recording/stop
    GET  /api/recordings/NAME.csv     (and .json, and /api/recordings/NAME/plot.png)
    WS   /api/stream                  frames at display rate (see `Stream`)

The loop runs in its own process (`worker.main`); this process reads the ring at display rate
and never waits on the loop: a slow or dead browser loses frames, never loop periods.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import math
import multiprocessing
import os
import re
import secrets
import sys
import time
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping, MutableMapping
from dataclasses import asdict, dataclass, field, is_dataclass
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from carfeel.errors import CarfeelError, InputError
from carfeel.models.rng import MAX_SEED
from carfeel.panel import plotting, ring, tuning
from carfeel.text import finite, shown

STATIC = Path(__file__).parent / "static"
STREAM_HZ = 30.0
MAX_FRAME_ROWS = 2000
"""A client that falls further behind than this (2 s at 1 kHz) skips to the newest rows."""
STRING_COLUMNS = ("region", "gear", "event", "stage")
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,79}")
"""A file name of the panel's folder; always `fullmatch` (`$` matches before a final newline)."""
MAX_BODY_BYTES = 64 * 1024
"""The largest request body (a session's or a tuning's is under 2 kB); larger is refused with
413 before it is read, a chunked one as soon as it runs past."""
MAX_WS_MESSAGE_BYTES = 64 * 1024
"""The largest message a WebSocket client may send (uvicorn closes the socket past it)."""
START_TIMEOUT_S = 180.0
"""Spawn, imports and the sizing: seconds on a quiet machine, a minute on a loaded one."""
STOP_TIMEOUT_S = 10.0
KINDS = {"shift": "shift", "hpattern": "hpattern", "steering": "steering"}
MAX_SIDECAR_BYTES = 1024 * 1024
DETECT_EVERY_S = 5.0
"""How long a look at the machine's devices holds (it opens each one)."""

Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
ASGI = Callable[[Scope, Receive, Send], Awaitable[None]]


@dataclass
class PanelConfig:
    folder: Path
    """Recordings go to folder/recordings, presets to folder/presets/KIND; nothing leaves it."""
    token: str = field(default_factory=lambda: secrets.token_urlsafe(32))
    """Every request but the page's own files carries it (`Guard`); a panel always has one."""
    hosts: tuple[str, ...] = ("127.0.0.1", "localhost", "[::1]")
    """Host headers accepted (a page elsewhere reaching 127.0.0.1 by DNS rebinding is refused)."""
    loop_cpu: int | None = None
    """Pin the loop's process to this core (benchmarks)."""
    stream_hz: float = STREAM_HZ


def said(value: object) -> str:
    """A request's value as an error message quotes it: its repr, shortened when long (a name
    of 60 kB is not copied back into the answer)."""
    if isinstance(value, str) and len(value) > 200:
        value = value[:100] + value[-50:]  # the repr of 60 kB need not be built to shorten it
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 128:
        return f"(a whole number of {value.bit_length()} bits)"
    if isinstance(value, list | dict) and len(value) > 20:
        return f"(a {type(value).__name__} of {len(value)} items)"
    return shown(repr(value), 60)


def safe_name(name: object, what: str) -> str:
    """A file name for the panel's folder: letters, digits, '.', '_', '-'; no way out of it."""
    if not isinstance(name, str) or not NAME.fullmatch(name) or ".." in name:
        raise InputError(
            f"{what} name {said(name)}: use 1-80 letters, digits, '.', '_' or '-' (starting "
            "with a letter or digit; no '/', no '..', no line break: files stay in the panel's "
            "folder)"
        )
    return name


def inside(folder: Path, name: str) -> Path:
    path = (folder / name).resolve()
    if not path.is_relative_to(folder.resolve()):
        raise InputError(f"{said(name)} would leave the panel's folder {folder}")
    return path


VIRTUAL_CHANGES = re.compile(r"[A-Za-z_]+=[0-9.eE+-]+x?(,[A-Za-z_]+=[0-9.eE+-]+x?)*")
"""`virtual:KIND:KEY=VALUE,...`'s changes to the true plant: names and numbers, nothing else."""
MAX_TEXT_CHARS = 200
"""The longest text field of a session's request (a device, a mode, a telemetry source)."""


def number_of(key: str, value: object) -> float:
    """A request's number as a float; InputError (not an OverflowError) for a whole number
    beyond any float, a string or a boolean."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{key} {said(value)}: expected a number")
    try:
        return float(value)
    except OverflowError:
        raise InputError(f"{key} {said(value)}: a number beyond {sys.float_info.max:.3g}") from None


def replay_problem(path: Path) -> str | None:
    """Why `path` is not a recording the replay device can play, in words that quote nothing
    of the file (a file is data: its lines never reach an answer); None when it is one."""
    from carfeel.realtime.devices.replay import JOYSTICK_COLUMNS, WHEEL_COLUMNS

    if path.name.endswith(".part.csv"):
        return f"{path.name} is still being recorded: replay it once it is stopped"
    if not path.with_suffix(".json").is_file():
        return f"{path.name} has no sidecar {path.with_suffix('.json').name} (written with it)"
    with path.open("rb") as handle:
        head = handle.read(64 * 1024)
    first, newline, _ = head.partition(b"\n")
    try:
        names = first.decode("utf-8").strip().split(",")
    except UnicodeDecodeError:
        names = []
    kinds = (JOYSTICK_COLUMNS, WHEEL_COLUMNS)
    if not newline or names[:1] != ["time_s"] or not any(set(k) <= set(names) for k in kinds):
        return (
            f"{path.name} is not a carfeel recording: its first line must name time_s and "
            f"{' and '.join(JOYSTICK_COLUMNS)} or {' and '.join(WHEEL_COLUMNS)}"
        )
    return None


def jsonable(value: Any) -> Any:
    """Dataclasses, tuples and NaN as strict JSON values."""
    if is_dataclass(value) and not isinstance(value, type):
        value = asdict(value)
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return finite(value)


class Session:
    """One loop process and its ring, as the panel sees them."""

    def __init__(self, run: dict[str, Any], preset: Any, physics: bool | None) -> None:
        self.run = run
        self.model: str = run["model"]
        self.kind = tuning.kind_of(self.model, run.get("steering_model", "paper"))
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
            if "gearbox" in ready:
                g = ready["gearbox"]
                out["gearbox"] = {
                    "synchronization_position_m": g.synchronization_position_m,
                    "teeth_position_m": g.teeth_position_m,
                    "teeth_end_position_m": g.teeth_end_position_m,
                    "in_gear_position_m": g.in_gear_position_m,
                }
        return jsonable(out)  # type: ignore[no-any-return]


class Panel:
    """The server's state: the folder, the one session, the clients."""

    def __init__(self, config: PanelConfig) -> None:
        self.config = config
        self.folder = config.folder
        self.recordings = self.folder / "recordings"
        self.presets = self.folder / "presets"
        self.session: Session | None = None
        self.closing = asyncio.Event()
        self._pump: asyncio.Task[None] | None = None
        self.plots = plotting.Plots(config.loop_cpu)
        self._detected: tuple[float, list[str]] | None = None
        self._starting = False
        self._tuning = False

    # -- lifetime ------------------------------------------------------------------------------
    @contextlib.asynccontextmanager
    async def lifespan(self, app: Starlette) -> AsyncIterator[None]:
        self.recordings.mkdir(parents=True, exist_ok=True)
        for kind in KINDS:
            (self.presets / kind).mkdir(parents=True, exist_ok=True)
        self._pump = asyncio.create_task(self._pumping())
        try:
            yield
        finally:
            self.closing.set()
            await asyncio.sleep(2.0 / self.config.stream_hz)  # the streams see it and end
            await self.shutdown()
            await asyncio.to_thread(self.plots.close, True)

    async def shutdown(self) -> None:
        """Stop the session (its fade) and wait for the loop's process to end."""
        if self._pump is not None:
            self._pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._pump
        session = self.session
        if session is not None:
            with contextlib.suppress(Exception):
                session.stop()
            await asyncio.to_thread(session.close)

    async def _pumping(self) -> None:
        while True:
            await asyncio.sleep(1.0 / self.config.stream_hz)
            if self.session is not None:
                try:
                    self.session.pump()
                except Exception as exc:  # pragma: no cover - keep serving; say what broke
                    self.session.error = f"the panel could not read the loop's ring: {exc!r}"

    # -- sessions ------------------------------------------------------------------------------
    def options(self) -> dict[str, Any]:
        from carfeel.io.presets import available
        from carfeel.realtime.devices.virtual import PLANTS
        from carfeel.realtime.hands import HANDS
        from carfeel.realtime.rendering import MODES
        from carfeel.realtime.session import DEFAULT_PRESETS, MODELS
        from carfeel.simulation.steering import ROAD_FRICTION, STEERING_MODELS

        presets = {
            kind: [*available(kind), *(f"saved:{p.stem}" for p in
                                       sorted((self.presets / kind).glob("*.toml")))]
            for kind in KINDS
        }  # fmt: skip
        return {
            "models": list(MODELS),
            "modes": list(MODES),
            "default_presets": DEFAULT_PRESETS,
            "presets": presets,
            "devices": {
                "joystick": [f"virtual:{k}" for k, v in PLANTS.items() if v[2] == "joystick"],
                "wheel": [f"virtual:{k}" for k, v in PLANTS.items() if v[2] == "wheel"],
                "real": self.detected_devices(),
                "replays": self.replays(),
            },
            "hands": list(HANDS),
            "clocks": ["wall", "simulated"],
            "telemetry_formats": _telemetry_formats(),
            "steering_models": list(STEERING_MODELS),
            "roads": list(ROAD_FRICTION),
            "tunables": {
                m: [t.as_dict() for t in tuning.tunables_for(m)] for m in (*MODELS, tuning.PHYSICAL)
            },
        }

    def detected_devices(self) -> list[str]:
        """The force-feedback devices this machine has now, as `--device` names them: what a
        request may name beside the virtual ones (looked up at most every DETECT_EVERY_S)."""
        now = time.monotonic()
        running = self.session is not None and self.session.running
        # Looking opens every device: not while a session drives one (the list it started with
        # stands until it ends).
        stale = self._detected is None or now - self._detected[0] > DETECT_EVERY_S
        if stale and not (running and self._detected is not None):
            from carfeel.realtime.devices.listing import describe_backends

            try:
                backends = describe_backends()
            except Exception:  # pragma: no cover - a backend that breaks offers nothing
                backends = {"evdev": {"devices": []}, "sdl2": {"devices": []}}
            found = [f"evdev:{d['path']}" for d in backends["evdev"]["devices"]
                     if d.get("constant_force") and d.get("writable")]  # fmt: skip
            found += [f"sdl:{d['index']}" for d in backends["sdl2"]["devices"]
                      if d.get("constant_force")]  # fmt: skip
            self._detected = (now, found)
        assert self._detected is not None
        return list(self._detected[1])

    def replays(self) -> list[str]:
        """replay:NAME of every finished recording in the panel's folder."""
        files = sorted(self.recordings.glob("*.csv"))
        done = [p for p in files if not p.name.endswith(".part.csv")]
        return [f"replay:{p.stem}" for p in done if p.with_suffix(".json").is_file()]

    def device_of(self, spec: str) -> str:
        """The device a request names, if the panel may open it: a virtual one, one detected on
        this machine, or replay:NAME of a recording in the panel's folder (as its path)."""
        from carfeel.realtime.devices.virtual import PLANTS

        virtual = ["virtual", *(f"virtual:{k}" for k in PLANTS)]
        if spec in virtual:
            return spec
        kind, _, changes = spec.removeprefix("virtual:").partition(":")
        if spec.startswith("virtual:") and kind in PLANTS and VIRTUAL_CHANGES.fullmatch(changes):
            return spec  # a virtual plant unlike its catalogue's: numbers the session checks
        if spec.startswith("replay:"):
            name = spec[len("replay:") :]
            path = self.recording_file(name if name.endswith(".csv") else f"{name}.csv")
            problem = replay_problem(path)
            if problem is not None:
                raise InputError(f"device {said(spec)}: {problem}")
            return f"replay:{path}"
        detected = self.detected_devices()
        if spec in detected:
            return spec
        raise InputError(
            f"device {said(spec)}: the panel opens the virtual devices "
            f"({', '.join(virtual[1:])}), the devices this machine has "
            f"({', '.join(detected) or 'none detected: carfeel devices says why'}) and "
            f"replay:NAME of a recording in {self.recordings}"
        )

    def preset_spec(self, model: str, preset: object) -> str | None:
        if preset in (None, ""):
            return None
        if not isinstance(preset, str):
            raise InputError(f"preset {said(preset)}: expected a preset name")
        if preset.startswith("saved:"):
            name = safe_name(preset[6:], "preset")
            path = inside(self.presets / KINDS[model], f"{name}.toml")
            if not path.is_file():
                raise InputError(f"no saved {model} preset {name!r} in {self.presets / model}")
            return str(path)
        from carfeel.io.presets import available

        if preset not in available(model):
            raise InputError(
                f"preset {said(preset)}: the shipped {model} presets are "
                f"{', '.join(available(model))} (or saved:NAME for one saved from the panel)"
            )
        return preset

    def run_of(self, body: dict[str, Any]) -> dict[str, Any]:
        """The request's session as RealtimeRun keyword arguments, checked as `carfeel run`'s."""
        from carfeel.realtime.run_options import MODELS, RealtimeRun, check_run
        from carfeel.simulation.sequence import parse_sequence

        allowed = {"model", "preset", "device", "mode", "speed_kmh", "hand", "clock", "sequence",
                   "duration_s", "seed", "telemetry", "synchronizer", "rate_hz", "force",
                   "aligning", "device_delay_ms", "calibrate", "steering_model",
                   "road"}  # fmt: skip
        unknown = sorted(set(body) - allowed)
        if unknown:
            raise InputError(f"unknown field {', '.join(said(k) for k in unknown[:5])}; a "
                             f"session takes {', '.join(sorted(allowed))}")  # fmt: skip
        if body.get("force") is not True:
            raise InputError(
                'starting a session turns the force on: say so with "force": true (the page\'s '
                "Start button does)"
            )
        model = body.get("model", "hpattern")
        if not isinstance(model, str) or model not in MODELS:
            raise InputError(f"model {said(model)}: choose one of {', '.join(MODELS)}")
        run: dict[str, Any] = {"model": model}
        texts = ("device", "mode", "hand", "clock", "telemetry", "synchronizer", "aligning",
                 "steering_model", "road")  # fmt: skip
        for key in texts:
            value = body.get(key)
            if value is None or value == "":
                continue
            if not isinstance(value, str):
                raise InputError(f"{key} {said(value)}: expected a string")
            if len(value) > MAX_TEXT_CHARS:
                raise InputError(f"{key} {said(value)}: at most {MAX_TEXT_CHARS} characters")
            run[key] = value
        if "device" in run:  # what a request may open: a whitelist, not a path
            run["device"] = self.device_of(run["device"])
        for key in ("speed_kmh", "duration_s", "rate_hz", "device_delay_ms"):
            value = body.get(key)
            if value is None or value == "":
                continue
            run[key] = number_of(key, value)
        seed = body.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
            raise InputError(f"seed {said(seed)}: expected a whole number from 0 to 2^64 - 1")
        run["seed"] = seed
        if "calibrate" in body:
            if not isinstance(body["calibrate"], bool):
                raise InputError(f"calibrate {said(body['calibrate'])}: expected true or false")
            run["calibrate"] = body["calibrate"]
        if model == "steering":
            run.setdefault("mode", "impedance")
        sequence = body.get("sequence")
        if sequence not in (None, "") and model == "hpattern":
            if isinstance(sequence, list):
                sequence = ",".join(str(s) for s in sequence)
            if not isinstance(sequence, str):
                raise InputError(f"sequence {said(sequence)}: expected gears such as N,1,2,N")
            run["sequence"] = parse_sequence(sequence)
        run.setdefault("duration_s", 600.0)
        run["preset"] = self.preset_spec(model, body.get("preset"))
        try:
            check_run(RealtimeRun(**run))
        except TypeError as exc:  # pragma: no cover - the fields are filtered above
            raise InputError(str(exc)) from None
        if "telemetry" in run:  # loopback only, unless the panel itself is on the network
            from carfeel.telemetry.receiver import Source

            Source.parse(run["telemetry"], network=not self.config.hosts)
        return run

    async def start(self, body: dict[str, Any]) -> Session:
        from carfeel.io.presets import load_hpattern, load_shift, load_steering
        from carfeel.realtime.session import DEFAULT_PRESETS

        if self._starting or (self.session is not None and self.session.running):
            raise InputError("a session is running: stop it before starting another")
        run = self.run_of(body)
        model = run["model"]
        name = run["preset"] or DEFAULT_PRESETS[model]
        loader: dict[str, Callable[[str], Any]] = {
            "shift": load_shift, "hpattern": load_hpattern, "steering": load_steering}  # fmt: skip
        loaded = loader[model](name)
        preset = loaded.params if model != "hpattern" else loaded
        physics = None if run.get("synchronizer") is None else run["synchronizer"] == "physics"
        self._starting = True
        try:
            old = self.session
            if old is not None:
                self.session = None
                await asyncio.to_thread(old.close)
            session = Session(run, preset, physics)
            session.preset_name = name  # type: ignore[attr-defined]
            try:
                await asyncio.to_thread(session.start, self.config.loop_cpu)
            except BaseException:  # no process: its 4 MB segment goes now, not at the exit
                session.close()
                raise
            self.session = session
            deadline = time.monotonic() + START_TIMEOUT_S
            while session.state == "starting" and time.monotonic() < deadline:
                await asyncio.sleep(0.02)
                session.pump()
            if session.state == "starting":
                session.stop()
                raise InputError(f"the loop's process did not start within {START_TIMEOUT_S:g} s")
            if session.state == "failed":
                raise InputError(session.error or "the session could not start")
            return session
        finally:
            self._starting = False

    def need_session(self) -> Session:
        if self.session is None:
            raise InputError("no session: start one first")
        return self.session

    def tuning_session(self) -> tuning.Session:
        s = self.need_session()
        if s.ready is None:
            raise InputError("the session is still starting: tune it once it runs")
        return tuning.Session(
            s.model, s.preset, s.physics, s.ready, s.run.get("steering_model", "paper"),
            s.run.get("road"), s.model_speed_m_s,
        )  # fmt: skip

    async def tune(self, body: dict[str, Any]) -> dict[str, Any]:
        values = body.get("values")
        if not isinstance(values, dict):
            raise InputError('a tuning is {"values": {"path": number, ...}}')
        s = self.need_session()
        if not s.running:
            raise InputError("the session has ended: start one to tune")
        checking = self.tuning_session()
        if checking.kind == tuning.PHYSICAL:  # re-sized: about a second, off the event loop
            if self._tuning:
                raise InputError("a tuning is being checked: wait for its answer")
            self._tuning = True
            try:
                proposal = await asyncio.to_thread(tuning.propose, checking, values)
            finally:
                self._tuning = False
            if self.session is not s or not s.running:
                raise InputError("the session ended while the tuning was checked")
        else:
            proposal = tuning.propose(checking, values)
        s.send(proposal.command)
        s.preset = proposal.preset
        if checking.kind == tuning.PHYSICAL and s.ready is not None:  # the next is checked on it
            s.ready = s.ready | {"physical": proposal.command[3]}
        pending = s.model != "steering"
        return {
            "changes": {k: {"old": a, "new": b} for k, (a, b) in proposal.changes.items()},
            "ramp_s": tuning.RAMP_S,
            "waits_for": "the lever in neutral" if pending else None,
            "note": proposal.note or None,
        }

    def tunables(self) -> dict[str, Any]:
        s = self.need_session()
        values = tuning.values_of(s.kind, s.preset)
        return {
            "model": s.model,
            "steering_model": s.run.get("steering_model", "paper") if s.model == "steering"
            else None,
            "tunables": [t.as_dict() | {"value": values[t.path]}
                         for t in tuning.tunables_for(s.kind)],
        }  # fmt: skip

    # -- files ---------------------------------------------------------------------------------
    def save_preset(self, body: dict[str, Any]) -> dict[str, Any]:
        from carfeel.io import presets as io_presets

        name = safe_name(body.get("name"), "preset")
        s = self.need_session()
        model = s.model
        folder = self.presets / KINDS[model]
        target = inside(folder, f"{name}.toml")
        if target.exists():
            raise InputError(f"preset {name!r} exists in {folder}: choose another name")
        history = "; ".join(
            f"{path} {change[0]:g} -> {change[1]:g}"
            for record in s.tuning_history
            for path, change in record["changes"].items()
        )
        base = getattr(s, "preset_name", "")
        source = (f"Tuned live in carfeel panel from preset {base} on "
                  f"{time.strftime('%Y-%m-%d %H:%M')}: {history or 'no change'}.")  # fmt: skip
        written = []
        p = s.preset
        if model == "shift":
            texts = [(target, "shift", io_presets.to_toml(name, source, {
                "gearbox": p.gearbox, "driver": p.driver}))]  # fmt: skip
        elif model == "steering":
            tables = {"vehicle": p.vehicle, "torque": p.torque, "driver": p.driver}
            if p.tyres is not None:
                tables |= {"tyres": p.tyres, "steering_system": p.steering_system}
            texts = [(target, "steering", io_presets.to_toml(name, source, tables))]
        else:
            engagement = inside(self.presets / "shift", f"{name}-engagement.toml")
            if engagement.exists():
                raise InputError(f"preset {engagement.name} exists: choose another name")
            shift_text = io_presets.to_toml(f"{name}-engagement", source, {
                "gearbox": p.shift.gearbox, "driver": p.shift.driver})  # fmt: skip
            setup = p.setup
            text = io_presets.to_toml(
                name, source,
                {"layout": setup.layout, "select": setup.select, "walls": setup.walls,
                 "synchronizer": setup.synchronizer, "feel": setup.feel, "driver": setup.driver},
                extra={"engagement": f"../shift/{engagement.name}"},
            )  # fmt: skip
            texts = [(engagement, "shift", shift_text), (target, "hpattern", text)]
        staged = [(path.with_name(f".{path.stem}.part.toml"), path) for path, _, _ in texts]
        try:
            for (part, _), (_, kind, text) in zip(staged, texts, strict=True):
                if kind == "hpattern":  # checked against the staged engagement beside it
                    text = text.replace(f"../shift/{staged[0][1].name}",
                                        f"../shift/{staged[0][0].name}")  # fmt: skip
                part.write_text(text, encoding="utf-8")
            # The loader must take them back: the panel never writes a preset carfeel refuses.
            for (part, _), (_, kind, _) in zip(staged, texts, strict=True):
                if kind == "hpattern":
                    io_presets.load_hpattern(str(part))
                else:
                    io_presets.load(kind, str(part))
            for (part, path), (_, _, text) in zip(staged, texts, strict=True):
                part.write_text(text, encoding="utf-8")
                os.replace(part, path)
                written.append(path.name)
        finally:
            for part, _ in staged:
                with contextlib.suppress(FileNotFoundError):
                    part.unlink()
        return {"saved": written, "preset": f"saved:{name}", "folder": str(folder)}

    def recording_path(self, name: object) -> Path:
        stem = safe_name(name, "recording")
        stem = stem[:-4] if stem.endswith(".csv") else stem
        return inside(self.recordings, f"{stem}.csv")

    def record(self, body: dict[str, Any]) -> dict[str, Any]:
        name = body.get("name") or time.strftime("panel-%Y%m%d-%H%M%S")
        path = self.recording_path(name)  # the name is checked first, session or not
        s = self.need_session()
        if path.exists() or path.with_suffix(".json").exists():
            raise InputError(f"recording {path.name} exists: choose another name")
        if s.recording is not None:
            raise InputError(f"recording {Path(s.recording).name} is running: stop it first")
        s.send(("record_start", str(path)))
        s.recording = str(path)
        return {"recording": path.name}

    def record_stop(self) -> dict[str, Any]:
        s = self.need_session()
        if s.recording is None:
            raise InputError("no recording is running")
        s.send(("record_stop",))
        return {"stopping": Path(s.recording).name}

    def list_recordings(self) -> list[dict[str, Any]]:
        out = []
        for csv in sorted(self.recordings.glob("*.csv")):
            partial = csv.name.endswith(".part.csv")
            sidecar = csv.with_suffix(".json")
            summary = None
            # A sidecar is a page of JSON; one of megabytes is not read for a listing.
            if sidecar.is_file() and not partial and sidecar.stat().st_size <= MAX_SIDECAR_BYTES:
                with contextlib.suppress(ValueError, OSError, AttributeError):
                    summary = json.loads(sidecar.read_text(encoding="utf-8")).get("summary")
            stat = csv.stat()
            out.append({
                "name": csv.name, "bytes": stat.st_size, "modified": stat.st_mtime,
                "partial": partial, "summary": jsonable(summary),
            })  # fmt: skip
        return out

    def recording_file(self, name: str) -> Path:
        safe_name(name, "recording file")
        if not name.endswith((".csv", ".json")):
            raise InputError(f"{said(name)}: a recording is NAME.csv with its NAME.json")
        path = inside(self.recordings, name)
        if not path.is_file():
            raise InputError(f"no recording {said(name)} in {self.recordings}")
        return path

    async def plot(self, name: str) -> bytes:
        """The recording's plot: drawn in the plots' own process (`plotting.Plots`)."""
        path = self.recording_file(f"{safe_name(name, 'recording')}.csv")
        return await self.plots.get(path)


def _telemetry_formats() -> list[str]:
    try:
        from carfeel.telemetry.formats import FORMATS
    except ImportError:  # pragma: no cover
        return []
    return sorted(FORMATS)


# -- the ASGI layer ----------------------------------------------------------------------------
def _no_constant(name: str) -> Any:
    """NaN and Infinity are not JSON (RFC 8259), whatever Python's parser would take."""
    raise ValueError(f"{name} is not a JSON number")


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


PUBLIC = frozenset({"/", "/static/panel.js", "/static/panel.css"})
"""What is served without the credential: the page and its script and style, the package's own
files (the same bytes as in site-packages), which hold no data and no secret. The page reads the
credential from its URL's fragment (`#token=T`, which a browser never sends to a server)."""
SUBPROTOCOL = "carfeel"
TOKEN_PROTOCOL = "carfeel.token."
"""A browser cannot set headers on a WebSocket: the page offers the subprotocols `carfeel` and
`carfeel.token.T`; the panel answers with `carfeel` (the token is never echoed)."""


def bearer(headers: Mapping[str, str]) -> str:
    """The token of an `Authorization: Bearer T` header ('' without one)."""
    given = headers.get("authorization", "")
    return given[7:].strip() if given[:7].lower() == "bearer " else ""


class Guard:
    """Refuses what lacks the credential, comes with a foreign Host, a WebSocket from a foreign
    Origin, and a body over MAX_BODY_BYTES (before it is read). The credential goes in the
    `Authorization: Bearer T` header (a WebSocket: that header, or the subprotocol
    `carfeel.token.T`); never in a cookie (cookies are not port-scoped: every other server on
    127.0.0.1 would receive it) nor in a URL (address bar, history, logs, the Referer). Only
    PUBLIC is served without it."""

    def __init__(self, app: ASGI, config: PanelConfig) -> None:
        self.app, self.config = app, config

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        problem = self.problem(scope, headers)
        if problem is None and scope["type"] == "http":
            problem = body_problem(headers)
            if problem is not None:
                await _error(413, problem)(scope, receive, send)
                return
            receive = _bounded(receive, MAX_BODY_BYTES)
        if problem is None:
            await self.app(scope, receive, send)
            return
        if scope["type"] == "websocket":
            await receive()  # the connect message
            await send({"type": "websocket.close", "code": 1008, "reason": problem[:120]})
            return
        response = _error(401 if problem.startswith("credential") else 403, problem)
        response.headers["WWW-Authenticate"] = 'Bearer realm="carfeel panel"'
        await response(scope, receive, send)

    def problem(self, scope: Scope, headers: dict[str, str]) -> str | None:
        """What is wrong with the request (None: nothing)."""
        host = headers.get("host", "")
        name = host.rsplit(":", 1)[0] if not host.endswith("]") else host
        if self.config.hosts and name not in self.config.hosts and host not in self.config.hosts:
            return f"host {shown(host)!r} is not this panel's"
        origin = headers.get("origin")
        if scope["type"] == "websocket" and origin and origin.split("://", 1)[-1] != host:
            return f"origin {shown(origin)!r} is not this panel's page"
        if (
            scope["type"] == "http"
            and scope["path"] in PUBLIC
            and scope["method"] in ("GET", "HEAD")
        ):
            return None
        given = bearer(headers)
        if not given and scope["type"] == "websocket":
            offered = [p.strip() for p in headers.get("sec-websocket-protocol", "").split(",")]
            given = next((p[len(TOKEN_PROTOCOL) :] for p in offered
                          if p.startswith(TOKEN_PROTOCOL)), "")  # fmt: skip
        if given and hmac.compare_digest(given.encode(), self.config.token.encode()):
            return None
        hint = (
            "; a token in the URL is not taken (it stays in the address bar, the history and "
            "logs): send the header"
            if b"token=" in scope.get("query_string", b"") else ""
        )  # fmt: skip
        return (
            "credential missing or wrong: send Authorization: Bearer TOKEN (the page takes it "
            f"from the URL carfeel panel printed, http://...#token=...){hint}"
        )


def body_problem(headers: Mapping[str, str]) -> str | None:
    """A declared body over MAX_BODY_BYTES, refused before a byte of it is read."""
    length = headers.get("content-length")
    if length is None:
        return None
    if not length.isascii() or not length.strip().isdigit() or len(length) > 20:
        return f"Content-Length {shown(length)!r} is not a byte count"
    if int(length) > MAX_BODY_BYTES:
        return (f"the body is {int(length)} bytes; the panel takes at most {MAX_BODY_BYTES} "
                "bytes in a request")  # fmt: skip
    return None


class BodyTooLarge(InputError):
    """A chunked body ran past MAX_BODY_BYTES while it was read."""


def _bounded(receive: Receive, limit: int) -> Receive:
    """`receive` that stops a body (one without a Content-Length: chunked) past `limit` bytes."""
    seen = 0

    async def receiving() -> MutableMapping[str, Any]:
        nonlocal seen
        message = await receive()
        if message["type"] == "http.request":
            seen += len(message.get("body", b""))
            if seen > limit:
                raise BodyTooLarge(
                    f"the body ran past {limit} bytes, the most the panel takes in a request"
                )
        return message

    return receiving


def create_app(config: PanelConfig) -> Starlette:
    panel = Panel(config)

    def api(
        handler: Callable[[Request], Awaitable[Any]],
    ) -> Callable[[Request], Awaitable[Response]]:
        async def endpoint(request: Request) -> Response:
            try:
                result = await handler(request)
            except BodyTooLarge as exc:
                return _error(413, str(exc))
            except CarfeelError as exc:
                return _error(400, str(exc))
            except OSError as exc:
                return _error(400, f"cannot use {exc.filename or 'a file'}: {exc.strerror or exc}")
            if isinstance(result, Response):
                return result
            return JSONResponse(jsonable(result))

        return endpoint

    async def body_of(request: Request) -> dict[str, Any]:
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            raise InputError("send JSON, with Content-Type: application/json")
        data = await request.body()  # bounded by the Guard: MAX_BODY_BYTES at most
        try:
            body = json.loads(data, parse_constant=_no_constant)
        except RecursionError:
            raise InputError(
                f"the body nests deeper than JSON's parser goes ({len(data)} bytes): a request "
                "is an object of plain values"
            ) from None
        except ValueError as exc:
            raise InputError(f"the body is not JSON: {shown(str(exc), 120)}") from None
        if not isinstance(body, dict):
            raise InputError("the body is a JSON object")
        return body

    async def index(request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    async def options(request: Request) -> Any:
        return panel.options()

    async def session_get(request: Request) -> Any:
        return panel.session.describe() if panel.session else {"state": "idle"}

    async def session_start(request: Request) -> Any:
        body = await body_of(request)
        session = await panel.start(body)
        return session.describe()

    async def session_stop(request: Request) -> Any:
        session = panel.need_session()
        session.stop()
        return session.describe()

    async def tune_get(request: Request) -> Any:
        return panel.tunables()

    async def tune_post(request: Request) -> Any:
        return await panel.tune(await body_of(request))

    async def presets_post(request: Request) -> Any:
        return panel.save_preset(await body_of(request))

    async def recordings(request: Request) -> Any:
        return {"recordings": panel.list_recordings(), "folder": str(panel.recordings)}

    async def record_start(request: Request) -> Any:
        return panel.record(await body_of(request))

    async def record_stop(request: Request) -> Any:
        return panel.record_stop()

    async def download(request: Request) -> Any:
        path = panel.recording_file(request.path_params["name"])
        return FileResponse(path, filename=path.name)

    async def plot(request: Request) -> Any:
        try:
            data = await panel.plot(request.path_params["name"])
        except plotting.Busy as exc:
            return JSONResponse({"error": str(exc)}, status_code=429,
                                headers={"Retry-After": str(plotting.RETRY_AFTER_S)})  # fmt: skip
        return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})

    async def stream(websocket: WebSocket) -> None:
        await Stream(panel, websocket).run()

    routes = [
        Route("/", index),
        Route("/api/options", api(options)),
        Route("/api/session", api(session_get), methods=["GET"]),
        Route("/api/session", api(session_start), methods=["POST"]),
        Route("/api/session/stop", api(session_stop), methods=["POST"]),
        Route("/api/tune", api(tune_get), methods=["GET"]),
        Route("/api/tune", api(tune_post), methods=["POST"]),
        Route("/api/presets", api(presets_post), methods=["POST"]),
        Route("/api/recordings", api(recordings), methods=["GET"]),
        Route("/api/recording", api(record_start), methods=["POST"]),
        Route("/api/recording/stop", api(record_stop), methods=["POST"]),
        Route("/api/recordings/{name}/plot.png", api(plot), methods=["GET"]),
        Route("/api/recordings/{name}", api(download), methods=["GET"]),
        WebSocketRoute("/api/stream", stream),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    app = Starlette(routes=routes, lifespan=panel.lifespan)
    app.state.panel = panel
    app.add_middleware(Guard, config=config)
    return app


@dataclass
class Stream:
    """One WebSocket client. Each frame (JSON, at the panel's display rate):
        {"type": "frame", "session": state, "columns": {name: [values...]}, "lost": rows,
         "status": {...}, "health": {...}}
    with the rows the loop wrote since the last frame (strings for region, gear, event,
    stage); {"type": "session", ...} whenever the session changes (started, tuned,
    recorded, ended). A client may send {"columns": [names], "every": n} to receive only those
    columns and every n-th row. A receive task notices a closed socket at once (uvicorn's
    shutdown waits for handlers that would only notice it when they send)."""

    panel: Panel
    websocket: WebSocket
    cursor: int = -1
    wanted: list[str] | None = None
    every: int = 1
    session: Session | None = None
    seen_events: int = -1
    closed: asyncio.Event = field(default_factory=asyncio.Event)

    async def run(self) -> None:
        offered = self.websocket.scope.get("subprotocols") or []
        await self.websocket.accept(subprotocol=SUBPROTOCOL if SUBPROTOCOL in offered else None)
        receiver = asyncio.create_task(self._receive())
        try:
            while not self.closed.is_set() and not self.panel.closing.is_set():
                await asyncio.sleep(1.0 / self.panel.config.stream_hz)
                message = self._frame()
                if message is not None:
                    await self.websocket.send_text(json.dumps(message, allow_nan=False))
        except (WebSocketDisconnect, RuntimeError, ConnectionError):
            pass
        finally:
            receiver.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await receiver
            with contextlib.suppress(Exception):
                await self.websocket.close()

    async def _receive(self) -> None:
        try:
            while True:
                message = await self.websocket.receive()
                if message["type"] == "websocket.disconnect":
                    break
                text = message.get("text")
                if text:
                    self._subscribe(text)
        except Exception:
            pass
        finally:
            self.closed.set()

    def _subscribe(self, text: str) -> None:
        try:
            request = json.loads(text)
        except (ValueError, RecursionError):
            return
        if isinstance(request, dict):
            columns = request.get("columns")
            if isinstance(columns, list) and all(isinstance(c, str) for c in columns):
                self.wanted = columns
            every = request.get("every")
            if isinstance(every, int) and 1 <= every <= 1000:
                self.every = every

    def _frame(self) -> dict[str, Any] | None:
        s = self.panel.session
        if s is None:
            if self.session is None and self.seen_events == -1:
                self.seen_events = 0
                return {"type": "session", "session": {"state": "idle"}}
            return None
        out: dict[str, Any] = {"type": "frame", "state": s.state}
        if s is not self.session or len(s.events) != self.seen_events or s.changed.is_set():
            s.changed.clear()
            self.session, self.seen_events = s, len(s.events)
            self.cursor = max(0, s.side.rows_written - 3000) if self.cursor < 0 else self.cursor
            out["session"] = s.describe()
        if not s.columns:
            return out
        if self.cursor < 0:
            self.cursor = max(0, s.side.rows_written - 3000)
        behind = s.side.rows_written - self.cursor
        lost = 0
        if behind > MAX_FRAME_ROWS:
            lost = behind - MAX_FRAME_ROWS
            self.cursor += lost
        rows, self.cursor, lapped = s.side.read_rows(self.cursor, len(s.columns))
        lost += lapped
        if self.every > 1:
            rows = rows[:: self.every]
        names = self.wanted or list(s.columns)
        columns: dict[str, Any] = {}
        for name in names:
            i = s.index(name)
            if i is None:
                continue
            values = rows[:, i]
            if name in STRING_COLUMNS:
                columns[name] = s.decode(name, values)
            else:
                columns[name] = [None if v != v else round(v, 6) for v in values.tolist()]
        out |= {"columns": columns, "lost": lost, "status": s.status, "health": s.health}
        return jsonable(out)  # type: ignore[no-any-return]
