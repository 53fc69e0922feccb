"""`carfeel panel`: the live panel in a browser (the extra `carfeel[panel]`)."""

from __future__ import annotations

import argparse
import ipaddress
import os
import re
import secrets
import socket
import stat
import sys
from pathlib import Path
from typing import Any

from carfeel.errors import InputError

LOCAL = ("127.0.0.1", "localhost", "::1")
TOKEN_ENV = "CARFEEL_PANEL_TOKEN"
TOKEN = re.compile(r"[A-Za-z0-9._~-]{16,256}")
"""A credential's characters: safe in a URL's fragment and in a WebSocket subprotocol."""
MAX_TOKEN_FILE_BYTES = 4096
MAX_CONNECTIONS = 64
"""Connections uvicorn serves at once (pages, scripts, streams); more are answered 503."""


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
                       help="address to listen on (default 127.0.0.1: this machine only; the "
                       "credential is needed on every address)")  # fmt: skip
    panel.add_argument("--port", type=int, default=8765, help="port (default 8765; 0: any free)")
    panel.add_argument("--token-file", default=None, metavar="FILE",
                       help="read the credential from FILE (only you may read it: chmod 600); "
                       f"or set ${TOKEN_ENV}; default: a new one, printed in the URL's "
                       "#token=... (16-256 letters, digits, '.', '_', '~', '-')")  # fmt: skip
    panel.add_argument("--token", default=None, help=argparse.SUPPRESS)  # refused: ps shows it
    panel.add_argument("--dir", default="carfeel-panel", metavar="FOLDER",
                       help="where recordings and saved presets go (default ./carfeel-panel); "
                       "no file name given on the page leaves it")  # fmt: skip
    panel.add_argument("--open", action="store_true", help="open the page in the browser")
    panel.add_argument("--loop-cpu", type=int, default=None, metavar="N",
                       help="pin the loop's process to core N (Linux); run the panel and the "
                       "browser on the others (taskset -c ...) so that they cannot take its "
                       "time")  # fmt: skip
    panel.set_defaults(handler=_handle)


def check(args: argparse.Namespace) -> tuple[str, Path]:
    """The credential to require and the folder; InputError for bad options."""
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
    token = token_of(args)
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


def token_of(args: argparse.Namespace) -> str:
    """The panel's credential: from --token-file, else $CARFEEL_PANEL_TOKEN, else a new one.
    Never from the command line, which every user of the machine can read (ps, /proc)."""
    if args.token is not None:
        raise InputError(
            "--token puts the secret on the command line, where every user of this machine "
            "reads it (ps, /proc/PID/cmdline): put it in a file only you can read (chmod 600) "
            f"and give --token-file FILE, or set {TOKEN_ENV}; without either the panel makes "
            "one and prints it in its URL"
        )
    if args.token_file is not None:
        where, text = f"--token-file {args.token_file}", read_token_file(Path(args.token_file))
    elif os.environ.get(TOKEN_ENV):
        where, text = f"${TOKEN_ENV}", os.environ[TOKEN_ENV]
    else:
        return secrets.token_urlsafe(32)
    if not TOKEN.fullmatch(text):
        raise InputError(
            f"{where}: the credential is 16 to 256 letters, digits, '.', '_', '~' or '-' "
            f"(it has {len(text)} characters{'' if text.isascii() else ', not all ASCII'}); "
            "python -c 'import secrets; print(secrets.token_urlsafe(32))' makes one"
        )
    return text


def read_token_file(path: Path) -> str:
    """A credential file's one line; InputError when another user could read it (POSIX: a
    group or other permission bit, or another owner) or it is not a small regular file."""
    try:
        # O_NONBLOCK: a FIFO given as the file must not hang the start; it is refused below.
        descriptor = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(descriptor, "rb") as handle:
            info = os.fstat(handle.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise InputError(f"--token-file {path}: not a regular file")
            if info.st_size > MAX_TOKEN_FILE_BYTES:
                raise InputError(
                    f"--token-file {path}: {info.st_size} bytes; a credential file holds one "
                    f"line (at most {MAX_TOKEN_FILE_BYTES} bytes)"
                )
            if os.name == "posix":
                if info.st_mode & 0o077:
                    raise InputError(
                        f"--token-file {path}: other users may read it (mode "
                        f"{stat.S_IMODE(info.st_mode):03o}): chmod 600 {path}"
                    )
                if info.st_uid != os.getuid():
                    raise InputError(f"--token-file {path}: it belongs to another user")
            data = handle.read(MAX_TOKEN_FILE_BYTES + 1)
    except FileNotFoundError:
        raise InputError(f"--token-file {path}: no such file") from None
    except OSError as exc:
        raise InputError(f"--token-file {path}: cannot read it: {exc.strerror or exc}") from None
    try:
        return data.decode("ascii").strip()
    except UnicodeDecodeError:
        raise InputError(f"--token-file {path}: not ASCII text") from None


def open_in_browser(url: str) -> None:
    """Open `url` without putting its credential on a command line: the browser is given a
    file (mode 0600 in a folder of mode 0700) that sends it on, removed a minute later."""
    import json
    import tempfile
    import threading
    import webbrowser

    folder = Path(tempfile.mkdtemp(prefix="carfeel-panel-"))
    page = folder / "open.html"
    descriptor = os.open(page, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(descriptor, "w", encoding="utf-8") as f:
        f.write(f"<!doctype html><meta charset=utf-8><title>carfeel panel</title>"
                f"<script>location.replace({json.dumps(url)})</script>")  # fmt: skip

    def remove() -> None:
        import shutil

        shutil.rmtree(folder, ignore_errors=True)

    timer = threading.Timer(60.0, remove)
    timer.daemon = True
    timer.start()
    webbrowser.open(page.as_uri())


def _handle(args: argparse.Namespace) -> int:
    token, folder = check(args)
    try:
        import uvicorn

        from carfeel.panel.config import PanelConfig
        from carfeel.panel.server import MAX_WS_MESSAGE_BYTES, create_app
    except ImportError as exc:
        raise InputError(
            f"carfeel panel needs the extra carfeel[panel] ({exc.name} is missing): "
            "pip install 'carfeel[panel]'"
        ) from None
    sock = listen(args.host, args.port)  # before anything is created: a port in use is exit 2
    folder.mkdir(exist_ok=True)
    hosts: tuple[str, ...] = ("127.0.0.1", "localhost", "[::1]")
    if args.host not in LOCAL:
        hosts = ()  # reached by whatever name the network gives it; the credential guards it
    app = create_app(PanelConfig(folder=folder, token=token, hosts=hosts, loop_cpu=args.loop_cpu))
    config = uvicorn.Config(
        app, host=args.host, port=args.port, log_level="warning", timeout_graceful_shutdown=5,
        ws_ping_interval=None, ws_max_size=MAX_WS_MESSAGE_BYTES,
        limit_concurrency=MAX_CONNECTIONS,  # beyond: 503, not a server out of sockets
    )  # fmt: skip
    server = uvicorn.Server(config)
    port = sock.getsockname()[1]
    url_host = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host
    if ":" in url_host:
        url_host = f"[{url_host}]"
    # The fragment is never sent to a server: the page reads it, keeps it in the tab's
    # sessionStorage and removes it from the address bar.
    url = f"http://{url_host}:{port}/#token={token}"

    wide = args.host in ("0.0.0.0", "::")
    others = [f"http://{a}:{port}/#token={token}" for a in lan_addresses()] if wide else []

    def announce() -> None:
        print(f"carfeel panel: {url}  (recordings and presets in {folder}/; Ctrl-C stops)",
              flush=True)  # fmt: skip
        for other in others:  # --host 0.0.0.0: what another machine types
            print(f"  from another machine: {other}", flush=True)
        if args.open:
            open_in_browser(url)

    _serve(server, sock, announce)
    return 0


def lan_addresses() -> list[str]:
    """This machine's address on its default route (what another machine on the LAN reaches),
    found by a UDP socket's connect, which sends nothing; none when there is no route."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect(("10.255.255.255", 9))
            address = str(probe.getsockname()[0])
        except OSError:
            return []
    return [] if address.startswith("127.") or address == "0.0.0.0" else [address]


def listen(host: str, port: int) -> socket.socket:
    """The listening socket, bound here so that a port in use is bad input (exit 2)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    if sys.platform != "win32":  # Windows' SO_REUSEADDR binds a port another socket listens on
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
