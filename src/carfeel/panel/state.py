"""The panel's state: its folder, the one session and the plots' process; what the API's routes
do to them (started, tuned, saved, recorded), over `choices`, `recordings` and `saving`."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

from starlette.applications import Starlette

from carfeel.errors import InputError
from carfeel.panel import choices, plotting, recordings, saving, tuning
from carfeel.panel.config import KINDS, PanelConfig
from carfeel.panel.session import Session
from carfeel.panel.values import safe_name

START_TIMEOUT_S = 180.0
"""Spawn, imports and the sizing: seconds on a quiet machine, a minute on a loaded one."""
DETECT_EVERY_S = 5.0
"""How long a look at the machine's devices holds (it opens each one)."""


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
        return choices.options(self.presets, self.detected_devices(), self.replays())

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
        return recordings.replays(self.recordings)

    def device_of(self, spec: str) -> str:
        """The device a request names, if the panel may open it (`choices.device_of`)."""
        return choices.device_of(spec, self.recordings, self.detected_devices)

    def run_of(self, body: dict[str, Any]) -> dict[str, Any]:
        """The request's session as RealtimeRun keyword arguments (`choices.run_of`)."""
        return choices.run_of(
            body,
            preset_folder=self.presets,
            recording_folder=self.recordings,
            detect=self.detected_devices,
            network=not self.config.hosts,
        )

    async def start(self, body: dict[str, Any]) -> Session:
        from carfeel.io.presets import (
            load_hpattern,
            load_prnd,
            load_sequential,
            load_shift,
            load_steering,
        )
        from carfeel.realtime.session import DEFAULT_PRESETS

        if self._starting or (self.session is not None and self.session.running):
            raise InputError("a session is running: stop it before starting another")
        run = self.run_of(body)
        model = run["model"]
        name = run["preset"] or DEFAULT_PRESETS[model]
        loader: dict[str, Callable[[str], Any]] = {
            "shift": load_shift, "hpattern": load_hpattern, "steering": load_steering,
            "sequential": load_sequential, "prnd": load_prnd}  # fmt: skip
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
            s.model, s.preset, s.physics, s.ready, s.steering_model,
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
        waits = {"shift": "the lever in neutral", "hpattern": "the lever in neutral",
                 "sequential": "the lever at rest, centred", "prnd": "the lever at rest in a "
                 "position"}  # fmt: skip
        return {
            "changes": {k: {"old": a, "new": b} for k, (a, b) in proposal.changes.items()},
            "ramp_s": tuning.RAMP_S,
            "waits_for": waits.get(s.model),
            "note": proposal.note or None,
        }

    def tunables(self) -> dict[str, Any]:
        s = self.need_session()
        values = tuning.values_of(s.kind, s.preset)
        return {
            "model": s.model,
            "steering_model": s.steering_model if s.model == "steering"
            else None,
            "tunables": [t.as_dict() | {"value": values[t.path]}
                         for t in tuning.tunables_for(s.kind)],
        }  # fmt: skip

    # -- files ---------------------------------------------------------------------------------
    def save_preset(self, body: dict[str, Any]) -> dict[str, Any]:
        name = safe_name(body.get("name"), "preset")
        return saving.save_preset(self.presets, self.need_session(), name)

    def record(self, body: dict[str, Any]) -> dict[str, Any]:
        name = body.get("name") or time.strftime("panel-%Y%m%d-%H%M%S")
        path = recordings.recording_path(self.recordings, name)  # checked first, session or not
        return recordings.record(self.need_session(), path)

    def record_stop(self) -> dict[str, Any]:
        return recordings.record_stop(self.need_session())

    def list_recordings(self) -> list[dict[str, Any]]:
        return recordings.list_recordings(self.recordings)

    def recording_file(self, name: str) -> Path:
        return recordings.recording_file(self.recordings, name)

    async def plot(self, name: str) -> bytes:
        """The recording's plot: drawn in the plots' own process (`plotting.Plots`)."""
        path = self.recording_file(f"{safe_name(name, 'recording')}.csv")
        return await self.plots.get(path)
