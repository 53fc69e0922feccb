"""The WebSocket stream: one client's frames at display rate, the rows the loop wrote since the
last one (a slow client skips rows, never the loop)."""

from __future__ import annotations

import asyncio
import contextlib
import json
from dataclasses import dataclass, field
from typing import Any

from starlette.websockets import WebSocket, WebSocketDisconnect

from carfeel.panel.auth import SUBPROTOCOL
from carfeel.panel.session import Session
from carfeel.panel.state import Panel
from carfeel.panel.values import jsonable

MAX_FRAME_ROWS = 2000
"""A client that falls further behind than this (2 s at 1 kHz) skips to the newest rows."""
STRING_COLUMNS = ("region", "gear", "event", "stage")
BACKLOG_ROWS = 3000
"""A new client's first frame starts this many rows back (3 s at 1 kHz)."""


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
            self.cursor = self._start(s) if self.cursor < 0 else self.cursor
            out["session"] = s.describe()
        if not s.columns:
            return out
        if self.cursor < 0:
            self.cursor = self._start(s)
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

    @staticmethod
    def _start(s: Session) -> int:
        """Where a new client starts reading: BACKLOG_ROWS back from the newest row."""
        return max(0, s.side.rows_written - BACKLOG_ROWS)
