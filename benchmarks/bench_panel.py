"""The 1 kHz loop with the live panel streaming to a headless browser, beside the same loop alone.

Runs, in one run of this script, one after the other (`--repeats` times, interleaved):
1. reference: the H-pattern on the virtual joystick, wall clock, 1 kHz, in its own process, as
   `carfeel run` runs it (no observer, no panel);
2. panel + browser: the same session started through the panel's API, its loop process
   streaming through the ring to the panel's server, which streams to Debian's chromium
   (headless, Playwright) showing the page at 30 frames a second;
3. panel + a stalled client: the same, with a WebSocket client that connects and never reads
   (a browser tab that hangs): it loses frames, the loop must lose nothing.
CPU pinning (Linux): every loop process is pinned to core 0 with `os.sched_setaffinity`; this
script, the panel's server and the browser (children inherit it) to core 1. The loop's
processes run at the panel's raised priority (nice -10 where allowed) in every case. Other
sessions on a shared machine are not pinned: compare the rows of one run, not runs.
    python benchmarks/bench_panel.py [--seconds 15] [--repeats 2]
Needs carfeel[panel,test] and /usr/bin/chromium. Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import base64
import json
import multiprocessing
import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

SEQUENCE = ("N", "1", "2", "3", "4", "5", "4", "3", "2", "1") * 20
LOOP_CPU, PANEL_CPU = 0, 1
CHROMIUM = "/usr/bin/chromium"
ARGS = [
    "--no-sandbox", "--disable-background-networking", "--disable-component-update",
    "--disable-sync", "--no-first-run", "--disable-quic", "--disable-gpu",
]  # fmt: skip
SERVER = """
import socket, sys, uvicorn
from pathlib import Path
from carfeel.panel.server import PanelConfig, create_app
app = create_app(PanelConfig(folder=Path(sys.argv[1]), loop_cpu=int(sys.argv[3])))
sock = socket.socket(); sock.bind(("127.0.0.1", int(sys.argv[2]))); sock.listen(16)
uvicorn.Server(uvicorn.Config(app, log_level="warning", ws_ping_interval=None)).run(sockets=[sock])
"""


def _reference(seconds: float, queue: Any) -> None:
    from carfeel.panel.worker import raise_priority
    from carfeel.realtime.session import RealtimeRun, run_realtime

    os.sched_setaffinity(0, {LOOP_CPU})
    priority = raise_priority()
    result = run_realtime(
        RealtimeRun(model="hpattern", duration_s=seconds, sequence=SEQUENCE, calibrate=False)
    )
    queue.put((result.as_dict(), priority))


def reference(seconds: float) -> dict[str, Any]:
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    process = ctx.Process(target=_reference, args=(seconds, queue))
    process.start()
    summary, priority = queue.get(timeout=seconds + 120)
    process.join()
    return summary | {"priority": priority}


def _call(port: int, method: str, path: str, body: object = None) -> dict[str, Any]:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(f"http://127.0.0.1:{port}{path}", data=data, method=method)
    if data is not None:
        request.add_header("Content-Type", "application/json")
    with urllib.request.urlopen(request, timeout=180) as response:
        answer: dict[str, Any] = json.load(response)
        return answer


def stalled_client(port: int) -> socket.socket:
    """A WebSocket client that completes the handshake and then never reads a byte."""
    sock = socket.create_connection(("127.0.0.1", port))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        f"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
        .encode()
    )
    answer = b""
    while b"\r\n\r\n" not in answer:
        answer += sock.recv(1)
    if b" 101 " not in answer.split(b"\r\n")[0]:
        raise RuntimeError(f"the panel refused the WebSocket: {answer!r}")
    return sock


def panel_session(port: int, seconds: float, client: str, browser: Any) -> dict[str, Any]:
    """One session through the panel while `client` ("browser" or "stalled") watches."""
    page = stalled = None
    if client == "browser":
        page = browser.new_page(viewport={"width": 1920, "height": 1080})
        page.goto(f"http://127.0.0.1:{port}/")
        page.wait_for_function("document.querySelectorAll('#model option').length === 3")
    else:
        stalled = stalled_client(port)
    _call(port, "POST", "/api/session", {
        "model": "hpattern", "duration_s": seconds, "sequence": ",".join(SEQUENCE),
        "calibrate": False, "force": True,
    })  # fmt: skip
    deadline = time.monotonic() + seconds + 120
    session = _call(port, "GET", "/api/session")
    while session["state"] != "ended" and time.monotonic() < deadline:
        time.sleep(0.5)
        session = _call(port, "GET", "/api/session")
    seen = {}
    if page is not None:
        seen = page.evaluate("window.panelStats")
        page.close()
    if stalled is not None:
        stalled.close()
    summary: dict[str, Any] = session.get("summary") or {}
    return summary | {"client": seen, "priority": session["loop_process"]["priority"]}


def describe(label: str, s: dict[str, Any]) -> None:
    print(
        f"{label:32s} periods {s['periods']:6d}  overruns {s['overruns']:5d}  period error "
        f"p50 {s['period_error_p50_us']:7.1f} us  p99 {s['period_error_p99_us']:8.1f} us  max "
        f"{s['period_error_max_us'] / 1e3:6.1f} ms  faults {len(s['faults'])}  gears "
        f"{len(s['gears'])}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        sys.exit("bench_panel needs Playwright: pip install -e '.[test,panel]'")
    if not Path(CHROMIUM).exists():
        sys.exit(f"bench_panel needs {CHROMIUM}: apt-get install chromium")
    os.sched_setaffinity(0, {PANEL_CPU})  # the server and the browser inherit it
    print(
        f"CPython {platform.python_version()}, {os.cpu_count()} cores; loops pinned to core "
        f"{LOOP_CPU}, this script, the panel's server and chromium to core {PANEL_CPU}; "
        f"{args.seconds:g} s per run; load average {os.getloadavg()[0]:.1f}"
    )
    folder = Path(tempfile.mkdtemp(prefix="bench-panel-"))
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = subprocess.Popen(
        [sys.executable, "-c", SERVER, str(folder), str(port), str(LOOP_CPU)]
    )
    try:
        for _ in range(200):
            try:
                _call(port, "GET", "/api/options")
                break
            except OSError:
                time.sleep(0.1)
        results: dict[str, list[dict[str, Any]]] = {"ref": [], "browser": [], "stalled": []}
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
            for k in range(args.repeats):
                results["ref"].append(reference(args.seconds))
                describe(f"[{k + 1}] reference (carfeel run)", results["ref"][-1])
                results["browser"].append(panel_session(port, args.seconds, "browser", browser))
                describe(f"[{k + 1}] panel + headless chromium", results["browser"][-1])
                results["stalled"].append(panel_session(port, args.seconds, "stalled", browser))
                describe(f"[{k + 1}] panel + a stalled client", results["stalled"][-1])
            browser.close()
        print(f"loop priority: {results['ref'][0]['priority']}")
        for run in results["browser"]:
            c = run["client"]
            print(
                f"the page received {c.get('frames')} frames, {c.get('rows')} rows "
                f"({c.get('lost')} skipped by the server to keep it current)"
            )
        for label, key in (("overruns", "overruns"), ("p99 us", "period_error_p99_us")):
            values = {name: [r[key] for r in runs] for name, runs in results.items()}
            print(
                f"{label:9s} reference {values['ref']}  browser {values['browser']}  stalled "
                f"{values['stalled']}"
            )
    finally:
        server.terminate()
        server.wait(timeout=30)


if __name__ == "__main__":
    main()
