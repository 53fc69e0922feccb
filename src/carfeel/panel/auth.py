"""The panel's guard: the credential on every request but the page's own files, the Host and a
WebSocket's Origin checked, and a request's body bounded (ASGI middleware)."""

from __future__ import annotations

import hmac
from collections.abc import Awaitable, Callable, Mapping, MutableMapping
from typing import Any

from carfeel.errors import InputError
from carfeel.panel.config import PanelConfig
from carfeel.panel.values import error_response
from carfeel.text import shown

MAX_BODY_BYTES = 64 * 1024
"""The largest request body (a session's or a tuning's is under 2 kB); larger is refused with
413 before it is read, a chunked one as soon as it runs past."""


Scope = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
Send = Callable[[MutableMapping[str, Any]], Awaitable[None]]
ASGI = Callable[[Scope, Receive, Send], Awaitable[None]]


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
                await error_response(413, problem)(scope, receive, send)
                return
            receive = _bounded(receive, MAX_BODY_BYTES)
        if problem is None:
            await self.app(scope, receive, send)
            return
        if scope["type"] == "websocket":
            await receive()  # the connect message
            await send({"type": "websocket.close", "code": 1008, "reason": problem[:120]})
            return
        response = error_response(401 if problem.startswith("credential") else 403, problem)
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
