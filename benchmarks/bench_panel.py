"""The 1 kHz loop with the live panel streaming to a headless browser, beside the same loop alone.

Runs, in one run of this script, one after the other (`--repeats` times, interleaved):
1. reference: the H-pattern on the virtual joystick, wall clock, 1 kHz, in its own process, as
   `carfeel run` runs it (no observer, no panel);
2. panel + browser: the same session started through the panel's API, its loop process
   streaming through the ring to the panel's server, which streams to Debian's chromium
   (headless, Playwright) showing the page at 30 frames a second;
3. panel + a stalled client: the same, with a WebSocket client that connects and never reads
   (a browser tab that hangs): it loses frames, the loop must lose nothing;
4. panel idle: the same session through the panel with no client at all (the reference of 5);
5. panel + 20 plots at once: the same session while waves of 20 concurrent requests for the
   plots of recordings (twenty files, one per request, touched before each wave so that none
   is cached: every drawing is a real one) hit the panel, one wave as soon as the last is
   answered: the issue 24 attack (six at once stalled the loop 28 ms and faulted it). Each
   wave's answers are counted: drawn (200), told to come back (429), anything else.
CPU pinning (Linux): every loop process is pinned to core 0 with `os.sched_setaffinity`; this
script, the panel's server and the browser (children inherit it) to core 1. `--no-pin` leaves
everything unpinned (the loop, the server, its plot worker and the browser share both cores, as
`carfeel panel` does without --loop-cpu); `--old-plots` draws the plots as the panel did
before issue 24 (in a thread of its server, one at a time), for comparison. The loop's
processes run at the panel's raised
priority (nice -10 where allowed) in every case. Other sessions on a shared machine are not
pinned: compare the rows of one run, not runs.
6. limits (issue 24, before the sessions): what the panel answers, how long it takes and what
   the server's peak memory (VmHWM) is after it, for a 300 MB body declared, 300 MB sent
   chunked, a 60 kB name, a 401-digit tuning integer (a simulated session runs) and a request
   without the credential.
    python benchmarks/bench_panel.py [--seconds 15] [--repeats 2] [--no-pin] [--cases ...]
Needs carfeel[panel,test] and /usr/bin/chromium. Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import multiprocessing
import os
import platform
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
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
TOKEN = secrets.token_urlsafe(32)
SERVER = """
import os, socket, sys, uvicorn
from pathlib import Path
from carfeel.panel.config import PanelConfig
from carfeel.panel.server import create_app
cpu = int(sys.argv[3]) if sys.argv[3] != "none" else None
if sys.argv[4] == "old-plots":  # before issue 24: in a thread of the server, one at a time
    import asyncio, threading
    from carfeel.panel import plotting
    lock = threading.Lock()
    def draw(path):
        with lock:
            return plotting.render(str(path), path.stem)
    async def get(self, path):
        return await asyncio.to_thread(draw, path)
    plotting.Plots.get = get
app = create_app(PanelConfig(folder=Path(sys.argv[1]), token=os.environ["CARFEEL_PANEL_TOKEN"],
                             loop_cpu=cpu))
sock = socket.socket(); sock.bind(("127.0.0.1", int(sys.argv[2]))); sock.listen(64)
uvicorn.Server(uvicorn.Config(app, log_level="warning", ws_ping_interval=None)).run(sockets=[sock])
"""
PLOT_FILES = 20
PLOTS_AT_ONCE = 20


def _reference(seconds: float, hand: str, queue: Any, pin: bool) -> None:
    from carfeel.panel.worker import raise_priority
    from carfeel.realtime.session import RealtimeRun, run_realtime

    if pin:
        os.sched_setaffinity(0, {LOOP_CPU})
    priority = raise_priority()
    result = run_realtime(
        RealtimeRun(
            model="hpattern", duration_s=seconds, sequence=SEQUENCE, calibrate=False, hand=hand
        )
    )
    queue.put((result.as_dict(), priority))


def reference(seconds: float, hand: str, pin: bool) -> dict[str, Any]:
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    process = ctx.Process(target=_reference, args=(seconds, hand, queue, pin))
    process.start()
    summary, priority = queue.get(timeout=seconds + 120)
    process.join()
    out: dict[str, Any] = {**summary, "priority": priority}
    return out


class _Timed:
    """Times the loop between its first and its last tick (process time), doing nothing else;
    wraps the panel's observer when given one."""

    def __init__(self, inner: Any = None) -> None:
        self.inner, self.first, self.last, self.ticks = inner, 0.0, 0.0, 0

    def prepare(self, parts: Any) -> None:
        if self.inner is not None:
            self.inner.prepare(parts)

    def started(self, chain: Any) -> None:
        if self.inner is not None:
            self.inner.started(chain)

    def tick(self, row: tuple[object, ...]) -> bool:
        now = time.process_time()
        if not self.ticks:
            self.first = now
        self.last, self.ticks = now, self.ticks + 1
        return bool(self.inner.tick(row)) if self.inner is not None else False


def observer_cost(seconds: float) -> tuple[float, float]:
    """CPU per tick of the loop without and with the panel's observer writing the ring (same
    process, simulated clock, hand none: the loop's own work and nothing else), us; the best
    of two runs each, interleaved."""
    from carfeel.panel import ring
    from carfeel.panel.worker import Observer
    from carfeel.realtime.session import RealtimeRun, run_realtime

    run = RealtimeRun(model="hpattern", duration_s=seconds, clock="simulated", hand="none",
                      calibrate=False)  # fmt: skip
    costs: dict[bool, list[float]] = {False: [], True: []}
    for watched in (False, True, False, True):
        shm = ring.create()
        inner = Observer(shm, None, None) if watched else None
        timed = _Timed(inner)
        run_realtime(run, observer=timed)
        costs[watched].append((timed.last - timed.first) / (timed.ticks - 1) * 1e6)
        if inner is not None:
            inner.close()
        else:
            shm.close()
        shm.unlink()
    return min(costs[False]), min(costs[True])


def _call(port: int, method: str, path: str, body: object = None) -> dict[str, Any]:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(f"http://127.0.0.1:{port}{path}", data=data, method=method)
    request.add_header("Authorization", f"Bearer {TOKEN}")
    if data is not None:
        request.add_header("Content-Type", "application/json")
    with urllib.request.urlopen(request, timeout=180) as response:
        answer: dict[str, Any] = json.load(response)
        return answer


def _plot_status(port: int, name: str) -> int:
    request = urllib.request.Request(f"http://127.0.0.1:{port}/api/recordings/{name}/plot.png")
    request.add_header("Authorization", f"Bearer {TOKEN}")
    try:
        with urllib.request.urlopen(request, timeout=300) as response:
            response.read()
            return int(response.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)
    except OSError:
        return -1


def _peak_mb(pid: int) -> float:
    """A process's peak resident memory so far (Linux VmHWM), MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _answer(sock: socket.socket) -> str:
    answer = b""
    while b"\r\n" not in answer:
        chunk = sock.recv(4096)
        if not chunk:
            break
        answer += chunk
    return answer.split(b"\r\n")[0].decode(errors="replace")


def _timed_raw(port: int, head: str, chunks: int = 0) -> tuple[str, float]:
    """Send `head` (and, from a thread, up to `chunks` chunks of 64 kB of a chunked body until
    the answer comes); the answer's status line and the seconds it took."""
    piece = b"10000\r\n" + b" " * 0x10000 + b"\r\n"
    stop = threading.Event()
    t0 = time.perf_counter()
    with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
        sock.sendall(head.encode())

        def feed() -> None:
            with contextlib.suppress(OSError):
                for _ in range(chunks):
                    if stop.is_set():
                        return
                    sock.sendall(piece)

        sender = threading.Thread(target=feed, daemon=True)
        sender.start()
        status = _answer(sock)
        took = time.perf_counter() - t0
        stop.set()
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_RDWR)
        sender.join(timeout=60)
    return status, took


def limits(port: int, server_pid: int) -> None:
    """Section 6 of the module's docstring."""
    auth = f"Authorization: Bearer {TOKEN}\r\n"
    post = f"POST /api/session HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n{auth}"
    print(f"limits: the server's peak memory before: {_peak_mb(server_pid):.0f} MB")
    declared = post + "Content-Type: application/json\r\nContent-Length: 300000000\r\n\r\n"
    status, took = _timed_raw(port, declared)
    print(f"  300 MB body declared      {status:28s} {took * 1e3:7.1f} ms  peak "
          f"{_peak_mb(server_pid):.0f} MB")  # fmt: skip
    chunked = post + "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
    status, took = _timed_raw(port, chunked, chunks=4800)  # up to 300 MB
    print(f"  300 MB body sent chunked  {status:28s} {took * 1e3:7.1f} ms  peak "
          f"{_peak_mb(server_pid):.0f} MB")  # fmt: skip
    for label, path, body in (
        ("60 kB preset name", "/api/session", {"model": "hpattern", "force": True,
                                               "preset": "x" * 60_000}),
        ("401-digit tuning integer", "/api/tune", {"values": {"gearbox.stop.stiffness_N_m":
                                                              10**400}}),
    ):  # fmt: skip
        data = json.dumps(body).encode()
        head = (f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n{auth}Content-Type: "
                f"application/json\r\nContent-Length: {len(data)}\r\n\r\n")  # fmt: skip
        t0 = time.perf_counter()
        with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
            sock.sendall(head.encode() + data)
            status = _answer(sock)
        print(f"  {label:25s} {status:28s} {(time.perf_counter() - t0) * 1e3:7.1f} ms  peak "
              f"{_peak_mb(server_pid):.0f} MB")  # fmt: skip
    t0 = time.perf_counter()
    with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
        sock.sendall(f"GET /api/options HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
        status = _answer(sock)
    print(f"  without the credential    {status:28s} {(time.perf_counter() - t0) * 1e3:7.1f} ms")


def make_recordings(port: int, folder: Path, server_pid: int | None = None) -> list[str]:
    """PLOT_FILES copies of a 20 s recording of the benchmark's session (simulated clock);
    with the server's pid, the limits (section 6) are measured while that session runs."""
    _call(port, "POST", "/api/session", {
        "model": "hpattern", "duration_s": 600, "sequence": ",".join(SEQUENCE),
        "calibrate": False, "clock": "simulated", "hand": "script", "force": True,
    })  # fmt: skip
    _call(port, "POST", "/api/recording", {"name": "plotted-0"})
    while _call(port, "GET", "/api/session").get("status", {}).get("time_s", 0.0) < 20.0:
        time.sleep(0.2)
    _call(port, "POST", "/api/recording/stop", {})
    source = folder / "recordings" / "plotted-0.csv"
    while not source.with_suffix(".json").exists():
        time.sleep(0.2)
    if server_pid is not None:  # a session runs: the tuning's limit is checked on it
        limits(port, server_pid)
    _call(port, "POST", "/api/session/stop", {})
    while _call(port, "GET", "/api/session")["state"] != "ended":
        time.sleep(0.2)
    names = ["plotted-0"]
    for k in range(1, PLOT_FILES):
        shutil.copyfile(source, source.with_name(f"plotted-{k}.csv"))
        shutil.copyfile(source.with_suffix(".json"), source.with_name(f"plotted-{k}.json"))
        names.append(f"plotted-{k}")
    return names


class PlotWaves:
    """Waves of PLOTS_AT_ONCE concurrent plot requests until stopped; the files are touched
    before each wave, so that every drawing is a real one (nothing cached)."""

    def __init__(self, port: int, folder: Path, names: list[str]) -> None:
        self.port, self.folder, self.names = port, folder, names
        self.statuses: list[int] = []
        self.waves = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            for name in self.names:
                os.utime(self.folder / "recordings" / f"{name}.csv")
            targets = [self.names[k % len(self.names)] for k in range(PLOTS_AT_ONCE)]
            wave = [threading.Thread(target=self._fetch, args=(name,)) for name in targets]
            for thread in wave:
                thread.start()
            for thread in wave:
                thread.join()
            self.waves += 1

    def _fetch(self, name: str) -> None:
        self.statuses.append(_plot_status(self.port, name))

    def __enter__(self) -> PlotWaves:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def stalled_client(port: int) -> socket.socket:
    """A WebSocket client that completes the handshake and then never reads a byte."""
    sock = socket.create_connection(("127.0.0.1", port))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    key = base64.b64encode(os.urandom(16)).decode()
    request = (
        f"GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
        f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
        f"Authorization: Bearer {TOKEN}\r\n"
    )
    sock.sendall(request.encode() + b"\r\n")
    answer = b""
    while b"\r\n\r\n" not in answer:
        answer += sock.recv(1)
    if b" 101 " not in answer.split(b"\r\n")[0]:
        raise RuntimeError(f"the panel refused the WebSocket: {answer!r}")
    return sock


def panel_session(
    port: int, seconds: float, hand: str, client: str, browser: Any, plots: Any = None
) -> dict[str, Any]:
    """One session through the panel while `client` ("browser", "stalled", "idle" or "plots")
    watches (`plots`: a PlotWaves, started once the session runs)."""
    page = stalled = None
    if client == "browser":
        page = browser.new_page(viewport={"width": 1920, "height": 1080})
        page.goto(f"http://127.0.0.1:{port}/#token={TOKEN}")
        page.wait_for_function("document.querySelectorAll('#model option').length === 3")
    elif client == "stalled":
        stalled = stalled_client(port)
    _call(port, "POST", "/api/session", {
        "model": "hpattern", "duration_s": seconds, "sequence": ",".join(SEQUENCE),
        "calibrate": False, "hand": hand, "force": True,
    })  # fmt: skip
    deadline = time.monotonic() + seconds + 120
    with plots if plots is not None else contextlib.nullcontext():
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
    parser.add_argument("--hand", choices=("none", "script"), default="none",
                        help="the virtual hand: none (default: the loop's own cost) or script "
                        "(its 10 kHz plant and driver cost about 1 ms a tick on a loaded "
                        "2-core VM, and its stalls end runs)")  # fmt: skip
    parser.add_argument("--no-pin", action="store_true",
                        help="pin nothing (as carfeel panel without --loop-cpu)")  # fmt: skip
    parser.add_argument("--old-plots", action="store_true",
                        help="draw plots as before issue 24 (a thread of the server, one at a "
                        "time), for comparison")  # fmt: skip
    parser.add_argument("--cases", default="ref,browser,stalled,idle,plots",
                        help="which of ref, browser, stalled, idle, plots to run")  # fmt: skip
    args = parser.parse_args()
    cases = args.cases.split(",")
    pin = not args.no_pin
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        sys.exit("bench_panel needs Playwright: pip install -e '.[test,panel]'")
    if not Path(CHROMIUM).exists():
        sys.exit(f"bench_panel needs {CHROMIUM}: apt-get install chromium")
    if pin:
        os.sched_setaffinity(0, {PANEL_CPU})  # the server and the browser inherit it
    where = (f"loops pinned to core {LOOP_CPU}, this script, the panel's server and chromium "
             f"to core {PANEL_CPU}") if pin else "nothing pinned"  # fmt: skip
    print(
        f"CPython {platform.python_version()}, {os.cpu_count()} cores; {where}; "
        f"{args.seconds:g} s per run, hand {args.hand}; load average {os.getloadavg()[0]:.1f}"
    )
    plain, watched = observer_cost(5.0)
    print(
        f"CPU per tick, simulated clock, hand none, best of two: the loop {plain:.1f} us, with "
        f"the panel's observer writing the ring {watched:.1f} us (+{watched - plain:.1f} us)"
    )
    folder = Path(tempfile.mkdtemp(prefix="bench-panel-"))
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    env = {**os.environ, "CARFEEL_PANEL_TOKEN": TOKEN}
    cpu = str(LOOP_CPU) if pin else "none"
    plots_way = "old-plots" if args.old_plots else "plots"
    server = subprocess.Popen(
        [sys.executable, "-c", SERVER, str(folder), str(port), cpu, plots_way], env=env
    )
    try:
        for _ in range(200):
            try:
                _call(port, "GET", "/api/options")
                break
            except OSError:
                time.sleep(0.1)
        names = make_recordings(port, folder, server.pid) if "plots" in cases else []
        results: dict[str, list[dict[str, Any]]] = {c: [] for c in cases}
        waves: list[PlotWaves] = []
        labels = {"ref": "reference (carfeel run)", "browser": "panel + headless chromium",
                  "stalled": "panel + a stalled client", "idle": "panel, idle",
                  "plots": f"panel + {PLOTS_AT_ONCE} plots at once"}  # fmt: skip
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
            for k in range(args.repeats):
                for case in cases:
                    if case == "ref":
                        result = reference(args.seconds, args.hand, pin)
                    elif case == "plots":
                        waves.append(PlotWaves(port, folder, names))
                        result = panel_session(port, args.seconds, args.hand, case, browser,
                                               waves[-1])  # fmt: skip
                    else:
                        result = panel_session(port, args.seconds, args.hand, case, browser)
                    results[case].append(result)
                    describe(f"[{k + 1}] {labels[case]}", result)
            browser.close()
        print(f"loop priority: {next(iter(results.values()))[0]['priority']}; load average now "
              f"{os.getloadavg()[0]:.1f}")  # fmt: skip
        for run in results.get("browser", []):
            c = run["client"]
            print(
                f"the page received {c.get('frames')} frames, {c.get('rows')} rows "
                f"({c.get('lost')} skipped by the server to keep it current)"
            )
        for wave in waves:
            counted = {code: wave.statuses.count(code) for code in sorted(set(wave.statuses))}
            print(f"plots: {wave.waves} waves of {PLOTS_AT_ONCE}, answers {counted} "
                  "(200 drawn, 429 come back later)")  # fmt: skip
        for label, key in (("overruns", "overruns"), ("p99 us", "period_error_p99_us")):
            values = {name: [r[key] for r in runs] for name, runs in results.items()}
            print(f"{label:9s} " + "  ".join(f"{name} {v}" for name, v in values.items()))
        if "idle" in results and "plots" in results:
            idle = sum(r["overruns"] for r in results["idle"])
            hit = sum(r["overruns"] for r in results["plots"])
            faults = sum(len(r["faults"]) for r in results["plots"])
            print(f"plots / idle overruns: {hit} / {idle} = {hit / max(idle, 1):.2f}; faults "
                  f"under plots: {faults}")  # fmt: skip
    finally:
        server.terminate()
        server.wait(timeout=30)


if __name__ == "__main__":
    main()
