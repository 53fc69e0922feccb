"""The panel's server: the page, a JSON API and a WebSocket stream (Starlette; uvicorn serves it).

The API (README, "The live panel"): every request but the page's own files carries the panel's
credential (`Authorization: Bearer T`; a WebSocket may offer the subprotocol `carfeel.token.T`
instead), whatever the address the panel listens on (`auth.Guard`); POSTs take JSON
(`Content-Type: application/json`, which a cross-site form cannot send) of at most
`auth.MAX_BODY_BYTES`; bad input is a 400 with {"error": message}, a body too large 413, a plot
when too many wait 429.

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
    WS   /api/stream                  frames at display rate (see `stream.Stream`)

The loop runs in its own process (`worker.main`); this process reads the ring at display rate
and never waits on the loop: a slow or dead browser loses frames, never loop periods.
"""

from __future__ import annotations

import json
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket

from carfeel.errors import CarfeelError, InputError
from carfeel.panel import plotting
from carfeel.panel.auth import BodyTooLarge, Guard
from carfeel.panel.config import PanelConfig
from carfeel.panel.state import Panel
from carfeel.panel.stream import Stream
from carfeel.panel.values import error_response, jsonable
from carfeel.text import shown

STATIC = Path(__file__).parent / "static"
MAX_WS_MESSAGE_BYTES = 64 * 1024
"""The largest message a WebSocket client may send (uvicorn closes the socket past it)."""


def _no_constant(name: str) -> Any:
    """NaN and Infinity are not JSON (RFC 8259), whatever Python's parser would take."""
    raise ValueError(f"{name} is not a JSON number")


def create_app(config: PanelConfig) -> Starlette:
    panel = Panel(config)

    def api(
        handler: Callable[[Request], Awaitable[Any]],
    ) -> Callable[[Request], Awaitable[Response]]:
        async def endpoint(request: Request) -> Response:
            try:
                result = await handler(request)
            except BodyTooLarge as exc:
                return error_response(413, str(exc))
            except CarfeelError as exc:
                return error_response(400, str(exc))
            except OSError as exc:
                return error_response(
                    400, f"cannot use {exc.filename or 'a file'}: {exc.strerror or exc}"
                )
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
