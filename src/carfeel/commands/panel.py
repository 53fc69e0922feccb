"""`carfeel panel`: the live panel in a browser (the extra `carfeel[panel]`)."""

from __future__ import annotations

import argparse
import ipaddress
import os
import secrets
import socket
from pathlib import Path
from typing import Any

from carfeel.errors import InputError

LOCAL = ("127.0.0.1", "localhost", "::1")


def register(commands: Any) -> None:
    """Add `panel` and its options."""
    panel = commands.add_parser(
        "panel",
        help="a live panel in the browser: start, watch, tune and record sessions",
        description="Serve a local web page that starts and stops real-time sessions (the loop "
        "runs in its own process), shows the H-pattern, the stages, force and position (raw "
        "and 20 Hz filtered), force against position, the steering's torque terms and the "
        "loop's health and safety state live, tunes parameters (checked and ramped in) and "
        "records. The force is turned on only by the page's Start button; Stop, Ctrl-C or "
        "the panel's end fade it out. Its JSON + WebSocket API is in the README.",
    )
    panel.add_argument("--host", default="127.0.0.1",
                       help="address to listen on (default 127.0.0.1: this machine only; any "
                       "other needs a token)")  # fmt: skip
    panel.add_argument("--port", type=int, default=8765, help="port (default 8765; 0: any free)")
    panel.add_argument("--token", default=None,
                       help="a secret every request must carry (generated and printed in the "
                       "URL when the host is not local and none is given)")  # fmt: skip
    panel.add_argument("--dir", default="carfeel-panel", metavar="FOLDER",
                       help="where recordings and saved presets go (default ./carfeel-panel); "
                       "no file name given on the page leaves it")  # fmt: skip
    panel.add_argument("--open", action="store_true", help="open the page in the browser")
    panel.add_argument("--loop-cpu", type=int, default=None, metavar="N",
                       help="pin the loop's process to core N (Linux); run the panel and the "
                       "browser on the others (taskset -c ...) so that they cannot take its "
                       "time")  # fmt: skip
    panel.set_defaults(handler=_handle)


def check(args: argparse.Namespace) -> tuple[str | None, Path]:
    """The token to require (None: none) and the folder; InputError for bad options."""
    if not 0 <= args.port <= 65535:
        raise InputError(f"--port {args.port}: allowed 0 .. 65535")
    host = args.host
    try:
        ipaddress.ip_address(host)
    except ValueError:
        if host != "localhost":
            raise InputError(
                f"--host {host!r}: give an IP address to listen on (127.0.0.1, 0.0.0.0, ...)"
            ) from None
    token = args.token
    if token is not None and (len(token) < 8 or not token.isprintable() or " " in token):
        raise InputError("--token: at least 8 printable characters, no spaces")
    if token is None and host not in LOCAL:
        token = secrets.token_urlsafe(18)
    cores = os.cpu_count() or 1
    if args.loop_cpu is not None:
        if not hasattr(os, "sched_setaffinity"):
            raise InputError("--loop-cpu: this system cannot pin a process to a core")
        if not 0 <= args.loop_cpu < cores:
            raise InputError(f"--loop-cpu {args.loop_cpu}: this machine has cores 0 .. {cores - 1}")
    folder = Path(args.dir)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"--dir {folder}: it is a file, not a folder")
    if not folder.parent.is_dir() and not folder.exists():
        raise InputError(f"--dir {folder}: its folder {folder.parent} does not exist")
    return token, folder


def _handle(args: argparse.Namespace) -> int:
    token, folder = check(args)
    try:
        import uvicorn

        from carfeel.panel.server import PanelConfig, create_app
    except ImportError as exc:
        raise InputError(
            f"carfeel panel needs the extra carfeel[panel] ({exc.name} is missing): "
            "pip install 'carfeel[panel]'"
        ) from None
    sock = listen(args.host, args.port)  # before anything is created: a port in use is exit 2
    folder.mkdir(exist_ok=True)
    hosts: tuple[str, ...] = ("127.0.0.1", "localhost", "[::1]")
    if args.host not in LOCAL:
        hosts = ()  # reached by whatever name the network gives it; the token guards it
    app = create_app(PanelConfig(folder=folder, token=token, hosts=hosts, loop_cpu=args.loop_cpu))
    config = uvicorn.Config(app, host=args.host, port=args.port, log_level="warning",
                            timeout_graceful_shutdown=5, ws_ping_interval=None)  # fmt: skip
    server = uvicorn.Server(config)
    port = sock.getsockname()[1]
    url_host = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host
    if ":" in url_host:
        url_host = f"[{url_host}]"
    url = f"http://{url_host}:{port}/" + (f"?token={token}" if token else "")

    def announce() -> None:
        print(f"carfeel panel: {url}  (recordings and presets in {folder}/; Ctrl-C stops)",
              flush=True)  # fmt: skip
        if args.open:
            import webbrowser

            webbrowser.open(url)

    _serve(server, sock, announce)
    return 0


def listen(host: str, port: int) -> socket.socket:
    """The listening socket, bound here so that a port in use is bad input (exit 2)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise InputError(
            f"cannot listen on {host}:{port}: {exc.strerror or exc}; choose another --port"
        ) from None
    sock.listen(64)
    sock.set_inheritable(True)
    return sock


def _serve(server: Any, sock: socket.socket, announce: Any) -> None:
    """Run uvicorn on `sock`; print the URL once it serves."""
    import asyncio

    async def main() -> None:
        task = asyncio.create_task(server.serve(sockets=[sock]))
        while not server.started and not task.done():
            await asyncio.sleep(0.05)
        if server.started:
            announce()
        await task

    asyncio.run(main())
