"""Nobody gets into the panel who does not belong (issue 24): the credential on every route and
the WebSocket, in local and network mode; it never leaves in a cookie, a URL or a command line;
what a request may name is a whitelist; sizes are checked before anything is read; plots cannot
take the loop's time (they are drawn in a process of their own, a few at a time).

Starlette's TestClient for the routes (every route of the app, found by walking it, so a route
added later is tested too); `carfeel panel` in a subprocess for the sockets, the command line and
another local user (as root: the test runs its client as `nobody`).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import socket
import stat
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("starlette", reason="the panel needs carfeel[panel]")
pytest.importorskip("httpx2", reason="Starlette's TestClient needs httpx2 (carfeel[test])")

from starlette.routing import Mount, Route, WebSocketRoute
from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from carfeel.cli import main
from carfeel.panel import plotting
from carfeel.panel.auth import MAX_BODY_BYTES, PUBLIC
from carfeel.panel.config import PanelConfig
from carfeel.panel.server import STATIC, create_app

TOKEN = "the-panels-credential-0123456789"
JSON = {"Content-Type": "application/json"}
MODES = {"local": ("testserver",), "network": ()}
"""A panel on 127.0.0.1 accepts its own Host names only; one on the network any (DNS names)."""


def app_for(folder: Path, mode: str) -> Any:
    return create_app(PanelConfig(folder=folder, token=TOKEN, hosts=MODES[mode]))


def write_recording(folder: Path, name: str, rows: int = 2000) -> Path:
    """A small recording as the loop writes it (the columns a plot and a replay read)."""
    recordings = folder / "recordings"
    recordings.mkdir(parents=True, exist_ok=True)
    path = recordings / f"{name}.csv"
    lines = ["time_s,overrun,command_0,x_device,y_device,x_m,force_x_N,force_x_filtered_N"]
    for k in range(rows):
        t = k * 1e-3
        lines.append(f"{t:.3f},0,0.0,{0.01 * (k % 50):.4f},0.0,{0.01 * (k % 50):.4f},"
                     f"{k % 7:.1f},{k % 7:.1f}")  # fmt: skip
    path.write_text("\n".join(lines) + "\n")
    path.with_suffix(".json").write_text(json.dumps({"max_force": 10.0, "travel": 0.05}))
    return path


def requests_of(app: Any) -> list[tuple[str, str]]:
    """(method, path) of every HTTP route of the app, its path parameters filled in; fails on a
    kind of route this walk does not know (a new kind must be added here)."""
    out = []
    for route in app.routes:
        if isinstance(route, Route):
            path = route.path.replace("{name}", "x.csv")
            assert "{" not in path, f"fill in the parameters of {route.path}"
            out += [(m, path) for m in sorted(route.methods or {"GET"}) if m != "HEAD"]
        elif isinstance(route, Mount):
            out += [("GET", f"{route.path}/{p.name}") for p in sorted(STATIC.iterdir())]
            out.append(("GET", f"{route.path}/../server.py"))
        elif not isinstance(route, WebSocketRoute):
            raise AssertionError(f"a route of a kind this test does not walk: {route!r}")
    return out


WITHOUT = {
    "no credential": {},
    "a wrong one": {"Authorization": "Bearer " + TOKEN[:-1] + "x"},
    "the right one with a tail": {"Authorization": f"Bearer {TOKEN}x"},
    "basic instead of bearer": {"Authorization": f"Basic {TOKEN}"},
    "in a cookie": {"Cookie": f"carfeel_token={TOKEN}"},
    "as a subprotocol on HTTP": {"Sec-WebSocket-Protocol": f"carfeel, carfeel.token.{TOKEN}"},
}
"""What another client (another local user, a page on another site, another server that got
hold of a cookie) may send in place of the credential."""


@pytest.mark.parametrize("mode", MODES)
def test_every_route_refuses_a_client_without_the_credential(tmp_path, mode):
    write_recording(tmp_path, "x")
    app = app_for(tmp_path, mode)
    with TestClient(app) as client:
        routes = requests_of(app)
        assert len(routes) >= 14  # the API's routes, the page and its files
        for method, path in routes:
            for what, headers in WITHOUT.items():
                response = client.request(method, path, headers={**JSON, **headers}, content="{}")
                if path in PUBLIC:  # the package's own page: the same bytes as installed
                    assert response.status_code == 200, (path, what)
                    name = "index.html" if path == "/" else Path(path).name
                    assert response.content == (STATIC / name).read_bytes()
                else:
                    assert response.status_code == 401, (method, path, what, response.text)
                    assert "credential missing or wrong" in response.json()["error"]
                assert "set-cookie" not in response.headers, (path, what)
            # The token in the URL is refused too, and the answer says why.
            response = client.request(method, f"{path}?token={TOKEN}", headers=JSON, content="{}")
            if path not in PUBLIC:
                assert response.status_code == 401
                assert "a token in the URL is not taken" in response.json()["error"]
        # With the credential the same routes answer (the refusals above are the credential's).
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        for path in ("/api/options", "/api/session", "/api/recordings", "/static/index.html"):
            assert client.get(path, headers=bearer).status_code == 200, path
        assert client.get("/api/recordings/x.csv", headers=bearer).status_code == 200
        assert client.get("/static/../server.py", headers=bearer).status_code == 404


def closed_with(client: TestClient, url: str = "/api/stream", **kwargs: Any) -> int | None:
    """The close code of a stream the panel refuses; None when it is served."""
    try:
        with client.websocket_connect(url, **kwargs) as ws:
            ws.receive_json()
    except WebSocketDisconnect as exc:
        return int(exc.code)
    return None


@pytest.mark.parametrize("mode", MODES)
def test_the_stream_refuses_a_client_without_the_credential(tmp_path, mode):
    app = app_for(tmp_path, mode)
    assert any(isinstance(r, WebSocketRoute) and r.path == "/api/stream" for r in app.routes)
    token = f"carfeel.token.{TOKEN}"
    with TestClient(app) as client:
        refused: list[dict[str, Any]] = [
            {},
            {"subprotocols": ["carfeel", "carfeel.token.wrong-credential-000000"]},
            {"subprotocols": ["carfeel", f"{token}x"]},
            {"headers": {"Cookie": f"carfeel_token={TOKEN}"}},
            {"headers": {"Authorization": "Bearer not-it-0123456789"}},
        ]
        for kwargs in refused:
            assert closed_with(client, **kwargs) == 1008, kwargs
        assert closed_with(client, f"/api/stream?token={TOKEN}") == 1008
        # The page's way (a browser cannot set a WebSocket's headers) and a script's.
        with client.websocket_connect("/api/stream", subprotocols=["carfeel", token]) as ws:
            assert str(ws.accepted_subprotocol) == "carfeel"  # the token is never echoed
            assert ws.receive_json()["type"] == "session"
        bearer = {"Authorization": f"Bearer {TOKEN}"}
        assert closed_with(client, headers=bearer) is None
        # Another origin cannot open it, credential or not (a page elsewhere in the browser).
        origin = {"Origin": "http://evil.example"}
        assert closed_with(client, subprotocols=["carfeel", token], headers=origin) == 1008
        if mode == "local":  # DNS rebinding: another name for 127.0.0.1 is not this panel
            answer = client.get("/api/options", headers={"Host": "evil.example", **bearer})
            assert answer.status_code == 403


def test_bodies_are_bounded_before_they_are_read(tmp_path):
    app = app_for(tmp_path, "local")
    bearer = {"Authorization": f"Bearer {TOKEN}", **JSON}
    with TestClient(app, headers=bearer) as client:
        big = client.post("/api/session", content=b" " * (MAX_BODY_BYTES + 1))
        assert big.status_code == 413
        assert f"at most {MAX_BODY_BYTES} bytes" in big.json()["error"]

        def chunks() -> Iterator[bytes]:  # no Content-Length: read until it runs past
            for _ in range(100):
                yield b" " * 4096

        chunked = client.post("/api/session", content=chunks())
        assert chunked.status_code == 413 and "ran past" in chunked.json()["error"]
        deep = client.post("/api/session", content=b"[" * 30_000 + b"]" * 30_000)
        assert deep.status_code == 400 and "nests deeper" in deep.json()["error"]
        nan = client.post("/api/session", content=b'{"speed_kmh": NaN, "force": true}')
        assert nan.status_code == 400 and "NaN is not a JSON number" in nan.json()["error"]


def test_names_numbers_and_devices_are_checked_and_never_echoed_whole(tmp_path):
    secret = "root:$6$secret-hash-of-a-password:19000:0:99999:7:::"
    recordings = tmp_path / "recordings"
    recordings.mkdir(parents=True)
    (recordings / "shadow.csv").write_text(secret + "\n")
    (recordings / "shadow.json").write_text("{}")
    write_recording(tmp_path, "good")
    app = app_for(tmp_path, "local")
    with TestClient(app, headers={"Authorization": f"Bearer {TOKEN}", **JSON}) as client:

        def error(path: str, body: object) -> str:
            response = client.post(path, content=json.dumps(body))
            assert response.status_code == 400, response.text
            message: str = response.json()["error"]
            assert len(message) < 1000, len(message)  # nothing of 60 kB copied back
            assert "Traceback" not in message and secret not in message
            return message

        start = {"model": "hpattern", "force": True}
        long = "x" * 60_000
        assert "preset" in error("/api/session", {**start, "preset": long})
        assert "at most 200 characters" in error("/api/session", {**start, "device": long})
        assert "unknown field" in error("/api/session", {**start, long: 1})
        assert "beyond" in error("/api/session", {**start, "speed_kmh": 10**400})
        assert "from 0 to 2^64 - 1" in error("/api/session", {**start, "seed": 10**400})
        assert "from 0 to 2^64 - 1" in error("/api/session", {**start, "seed": -1})
        # A recording name ending in a line break (`$` matches before it) is not a name.
        assert "line break" in error("/api/recording", {"name": "run-7\n"})
        assert "line break" in error("/api/presets", {"name": "mine\n"})
        assert client.get("/api/recordings/good.csv%0A").status_code == 400
        # Devices: a whitelist. No path of the machine, no file outside the panel's folder, and
        # a file of the folder that is not a recording is refused without a word of it.
        devices = ("replay:/etc/shadow", "replay:../../etc/passwd", "evdev:/etc/shadow",
                   "evdev:/dev/input/event0", "sdl:7", "virtual:tank", "replay:shadow")  # fmt: skip
        for device in devices:
            message = error("/api/session", {**start, "device": device})
            assert "device" in message or "recording" in message, message
        assert "not a carfeel recording" in error(
            "/api/session", {**start, "device": "replay:shadow"}
        )
        # The page offers the recordings with a sidecar (the check above is the replay's).
        options = client.get("/api/options").json()
        assert options["devices"]["replays"] == ["replay:good", "replay:shadow"]
        panel = app.state.panel
        run = panel.run_of({**start, "device": "replay:good", "clock": "simulated"})
        assert run["device"] == f"replay:{(recordings / 'good.csv').resolve()}"
        assert panel.run_of({**start, "device": "virtual:shifter"})["device"] == "virtual:shifter"


HOSTILE = st.one_of(
    st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=30),
    st.sampled_from(["", "N,,1", "R,N", "virtual", "virtual:wheel", "replay:", "replay:..",
                     "sdl:", "sdl:\u00b2", "evdev:", "\u0000", "physical", "snow", "wall",
                     "simulated", "impedance", "forza:127.0.0.1:5300", 2**64, -(2**63), 10**400,
                     1e308, 5e-324]),
    st.lists(st.integers() | st.text(max_size=5), max_size=4),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=3),
)  # fmt: skip
FIELDS = ("model", "preset", "device", "mode", "speed_kmh", "hand", "clock", "sequence",
          "duration_s", "seed", "telemetry", "synchronizer", "rate_hz", "aligning",
          "device_delay_ms", "calibrate", "steering_model", "road")  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(body=st.dictionaries(st.sampled_from(FIELDS), HOSTILE, max_size=6))
def test_a_session_request_of_any_values_is_taken_or_refused_never_a_crash(body):
    """What a session's request holds is checked as `carfeel run`'s options are: any JSON value
    in any field is taken or an InputError (a 400), never another exception (a 500)."""
    from carfeel.errors import InputError

    panel = _PANEL.state.panel
    message = ""
    try:
        run = panel.run_of({**body, "force": True})
    except InputError as exc:
        message = str(exc)
    else:
        assert run["model"] in ("shift", "hpattern", "steering")
    assert len(message) < 2000  # a refusal quotes nothing long


_PANEL = create_app(PanelConfig(folder=Path(__file__).parent / "data" / "no-such-panel-folder",
                                token=TOKEN))  # fmt: skip
"""A panel whose folder does not exist (nothing is written: run_of only reads)."""


def test_a_device_this_machine_has_is_taken_and_only_such(tmp_path, monkeypatch):
    """A real device is one the listing found usable (force feedback, writable): the same
    path with no such device, or any other path, is refused. (A recorded listing: there is no
    /dev/input here.)"""
    from carfeel.errors import InputError
    from carfeel.realtime.devices import listing

    found = {"evdev": {"devices": [{"path": "/dev/input/event5", "constant_force": True,
                                    "writable": True},
                                   {"path": "/dev/input/event6", "constant_force": True,
                                    "writable": False}]},
             "sdl2": {"devices": [{"index": 0, "constant_force": True}]}}  # fmt: skip
    monkeypatch.setattr(listing, "describe_backends", lambda: found)
    panel = app_for(tmp_path, "local").state.panel
    assert panel.detected_devices() == ["evdev:/dev/input/event5", "sdl:0"]
    assert panel.device_of("evdev:/dev/input/event5") == "evdev:/dev/input/event5"
    assert panel.device_of("sdl:0") == "sdl:0"
    # A virtual plant unlike its catalogue's is names and numbers (the session checks them).
    assert panel.device_of("virtual:dd-wheel:mass=0.5x,delay_ms=6") == (
        "virtual:dd-wheel:mass=0.5x,delay_ms=6"
    )
    for other in ("virtual:dd-wheel:/etc/shadow", "virtual:tank:mass=1", "virtual:wheel:"):
        with pytest.raises(InputError, match="the panel opens the virtual devices"):
            panel.device_of(other)
    for other in ("evdev:/dev/input/event6", "evdev:/dev/input/../input/event5", "sdl:00",
                  "evdev:/etc/shadow"):  # fmt: skip
        with pytest.raises(InputError, match="the devices this machine has"):
            panel.device_of(other)


def test_a_tuning_number_of_401_digits_is_a_400_not_a_500():
    from carfeel.errors import InputError
    from carfeel.panel import tuning

    with pytest.raises(InputError) as refused:
        tuning.checked_value("torque.k1_Nm_s2_m", 10**400)
    assert "a whole number of 401 digits" in str(refused.value)
    assert "out of range: allowed" in str(refused.value)
    with pytest.raises(InputError) as refused:
        tuning.checked_value("torque.k1_Nm_s2_m", "x" * 60_000)
    assert len(str(refused.value)) < 300


# -- plots: a few at a time, in their own process ------------------------------------------------
class _Held:
    """An executor whose drawings finish when the test says so."""

    def __init__(self) -> None:
        self.submitted: list[tuple[Future[bytes], tuple[Any, ...]]] = []

    def submit(self, fn: Any, *args: Any) -> Future[bytes]:
        future: Future[bytes] = Future()
        self.submitted.append((future, args))
        return future


def test_plots_are_limited_shared_and_cached(tmp_path):
    paths = [write_recording(tmp_path, f"r{k}", rows=10) for k in range(plotting.MAX_WAITING + 2)]

    async def scenario() -> None:
        plots = plotting.Plots()
        held = _Held()
        plots._executor = lambda: held  # type: ignore[assignment,return-value]
        waiting = [asyncio.ensure_future(plots.get(p)) for p in paths[: plotting.MAX_WAITING]]
        twin = asyncio.ensure_future(plots.get(paths[0]))  # the same file: the same drawing
        await asyncio.sleep(0)
        assert len(held.submitted) == plotting.MAX_WAITING
        with pytest.raises(plotting.Busy) as busy:
            await plots.get(paths[-1])
        assert f"try again in {plotting.RETRY_AFTER_S} s" in str(busy.value)
        for k, (future, args) in enumerate(held.submitted):
            assert args == (str(paths[k]), paths[k].stem)
            future.set_result(b"png %d" % k)
        assert await asyncio.gather(*waiting) == [b"png %d" % k for k in range(len(waiting))]
        assert await twin == b"png 0"
        assert await plots.get(paths[1]) == b"png 1"  # cached: nothing drawn again
        assert len(held.submitted) == plotting.MAX_WAITING
        os.utime(paths[1], ns=(time.time_ns(), time.time_ns() + 10**9))  # the file changed
        again = asyncio.ensure_future(plots.get(paths[1]))
        await asyncio.sleep(0)
        assert len(held.submitted) == plotting.MAX_WAITING + 1
        held.submitted[-1][0].set_result(b"new")
        assert await again == b"new"

    asyncio.run(scenario())


def test_the_plot_worker_runs_at_the_lowest_priority_off_the_loops_core():
    if not hasattr(os, "sched_getscheduler"):
        pytest.skip("Linux: sched_setscheduler")
    code = (
        "import os; from carfeel.panel.plotting import lower_priority; lower_priority(0); "
        "print(os.sched_getscheduler(0) == os.SCHED_IDLE, sorted(os.sched_getaffinity(0)))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    idle, cores = done.stdout.split(" ", 1)
    assert idle == "True"
    if (os.cpu_count() or 1) > 1:
        assert 0 not in json.loads(cores)


# -- a real server: sockets, the command line, another user ------------------------------------
@contextlib.contextmanager
def panel_process(folder: Path, *options: str, env: dict[str, str] | None = None
                  ) -> Iterator[tuple[subprocess.Popen[str], str]]:  # fmt: skip
    """`carfeel panel --port 0 ...`; the process and the URL it printed."""
    process = subprocess.Popen(
        [sys.executable, "-m", "carfeel.cli", "panel", "--port", "0", "--dir", str(folder),
         *options],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        line = process.stdout.readline() if process.stdout else ""
        match = re.search(r"(http://\S+)", line)
        assert match, f"carfeel panel printed no URL: {line!r}"
        yield process, match.group(1)
    finally:
        process.terminate()
        process.wait(timeout=30)


def _status(url: str, method: str = "GET", headers: dict[str, str] | None = None,
            data: bytes | None = None, timeout_s: float = 60.0) -> int:  # fmt: skip
    request = urllib.request.Request(url, method=method, headers=headers or {}, data=data)
    try:
        with urllib.request.urlopen(request, timeout=timeout_s) as answer:
            return int(answer.status)
    except urllib.error.HTTPError as exc:
        return int(exc.code)


def _raw(address: tuple[str, int], request: bytes, timeout_s: float = 10.0) -> bytes:
    with socket.create_connection(address, timeout=timeout_s) as sock:
        sock.sendall(request)
        answer = b""
        while b"\r\n\r\n" not in answer:
            chunk = sock.recv(4096)
            if not chunk:
                break
            answer += chunk
        return answer


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.2"])
def test_a_running_panel_refuses_clients_without_the_credential(tmp_path, host):
    """Local mode (127.0.0.1) and network mode (any other address: 127.0.0.2 stands for one,
    so that nothing listens beyond this machine): the same refusals over real sockets."""
    write_recording(tmp_path, "r", rows=3000)
    with panel_process(tmp_path, "--host", host) as (_, url):
        assert "#token=" in url and "?token" not in url
        base, token = url.split("#token=")
        assert re.fullmatch(r"[A-Za-z0-9_-]{43}", token)  # 32 random bytes
        port = int(base.rstrip("/").rsplit(":", 1)[1])
        assert _status(base) == 200  # the page, which holds nothing
        assert _status(base + "api/options") == 401
        assert _status(base + f"api/options?token={token}") == 401
        assert _status(base + "api/options", headers={"Cookie": f"carfeel_token={token}"}) == 401
        body = json.dumps({"model": "hpattern", "force": True}).encode()
        assert _status(base + "api/session", "POST", JSON, body) == 401
        assert _status(base + "api/options", headers={"Authorization": f"Bearer {token}"}) == 200
        handshake = (
            f"GET /api/stream HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
            "Sec-WebSocket-Version: 13\r\n"
        )
        refused = _raw((host, port), (handshake + "\r\n").encode())
        assert b" 101 " not in refused.split(b"\r\n")[0], refused
        offered = f"Sec-WebSocket-Protocol: carfeel, carfeel.token.{token}\r\n\r\n"
        accepted = _raw((host, port), (handshake + offered).encode())
        assert b" 101 " in accepted.split(b"\r\n")[0], accepted
        assert b"sec-websocket-protocol: carfeel\r\n" in accepted.lower()
        assert token.encode() not in accepted
        # A body declared too large is refused before it is sent (the panel does not wait for
        # 300 MB: it answers at once).
        started = time.monotonic()
        head = (
            f"POST /api/session HTTP/1.1\r\nHost: {host}:{port}\r\nAuthorization: Bearer "
            f"{token}\r\nContent-Type: application/json\r\nContent-Length: 300000000\r\n\r\n"
        )
        declared = _raw((host, port), head.encode())
        assert b" 413 " in declared.split(b"\r\n")[0], declared
        assert time.monotonic() - started < 10.0  # a hang would time the socket out instead
        # Twenty plots at once: one drawn at a time, the rest wait (a few) or are told to come
        # back; none is an error.
        # (Each answer or the exception that took its place is kept: a thread that raised would
        # otherwise leave only an empty list behind.)
        statuses: list[int | str] = []

        def fetch() -> None:
            try:
                statuses.append(_status(base + "api/recordings/r/plot.png",
                                        headers={"Authorization": f"Bearer {token}"},
                                        timeout_s=150.0))  # fmt: skip
            except OSError as exc:  # a timeout: one drawing shared by all, on a loaded machine
                statuses.append(repr(exc))

        threads = [threading.Thread(target=fetch) for _ in range(20)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=180)
        assert len(statuses) == 20 and set(statuses) <= {200, 429}, statuses
        assert 200 in statuses


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
@pytest.mark.linux_only  # ps -eo, /proc/PID/cmdline
def test_the_credential_is_not_on_a_command_line_nor_sent_back(tmp_path):
    """What `ps` shows of the panel and of its loop's process, while a session runs, holds no
    credential (given in the environment here; generated, it is printed only)."""
    env = {**os.environ, "CARFEEL_PANEL_TOKEN": TOKEN}
    with panel_process(tmp_path, env=env) as (process, url):
        assert url.endswith(f"#token={TOKEN}")
        base = url.split("#")[0]
        body = json.dumps({"model": "hpattern", "clock": "simulated", "duration_s": 600,
                           "force": True}).encode()  # fmt: skip
        headers = {**JSON, "Authorization": f"Bearer {TOKEN}"}
        request = urllib.request.Request(base + "api/session", body, headers, method="POST")
        with urllib.request.urlopen(request, timeout=180) as answer:
            loop_pid = json.load(answer)["loop_process"]["pid"]
        shown = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
        assert str(loop_pid) in shown and str(process.pid) in shown
        assert TOKEN not in shown
        for pid in (process.pid, loop_pid):
            assert TOKEN.encode() not in Path(f"/proc/{pid}/cmdline").read_bytes()
        _status(base + "api/session/stop", "POST", headers, b"{}")


OTHER_USER = r"""
import json, os, sys, urllib.error, urllib.request
pid, token_file, url = int(sys.argv[1]), sys.argv[2], sys.argv[3]
out = {"uid": os.getuid()}
children = [p for p in os.listdir("/proc") if p.isdigit()
            and open(f"/proc/{p}/stat").read().split(") ")[-1].split()[1] == str(pid)]
out["cmdlines"] = [open(f"/proc/{p}/cmdline", "rb").read().decode("latin-1")
                   for p in [str(pid), *children]]
for what, path in (("environ", f"/proc/{pid}/environ"), ("token_file", token_file)):
    try:
        out[what] = open(path, "rb").read().decode("latin-1")
    except OSError as exc:
        out[what] = type(exc).__name__
statuses = {}
for path in ("api/options", "api/session"):
    try:
        statuses[path] = urllib.request.urlopen(url + path, timeout=30).status
    except urllib.error.HTTPError as exc:
        statuses[path] = exc.code
out["statuses"] = statuses
print(json.dumps(out))
"""


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0,
                    reason="needs root to act as another user")  # fmt: skip
def test_another_local_user_can_neither_read_the_credential_nor_get_in(tmp_path):
    """As `nobody`: the panel's command line (and its loop's) holds no credential, its
    environment and the 0600 token file cannot be read, and the API refuses the requests."""
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    token_file.chmod(0o600)
    folder = tmp_path / "panel"
    with panel_process(folder, "--token-file", str(token_file),
                       env={**os.environ, "CARFEEL_OTHER": TOKEN}) as (process, url):  # fmt: skip
        base = url.split("#")[0]
        tmp_path.chmod(0o755)  # the other user may look, as on a shared machine
        done = subprocess.run(
            ["/usr/bin/python3", "-c", OTHER_USER, str(process.pid), str(token_file), base],
            capture_output=True, text=True, user=65534, group=65534, timeout=120, check=False,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        seen = json.loads(done.stdout)
    assert seen["uid"] == 65534
    assert seen["cmdlines"] and all(TOKEN not in c for c in seen["cmdlines"])
    assert seen["environ"] == "PermissionError" and seen["token_file"] == "PermissionError"
    assert seen["statuses"] == {"api/options": 401, "api/session": 401}


@pytest.mark.parametrize(
    ("options", "setup", "message"),
    [
        (["--token", "a-long-enough-secret"], None, "every user of this machine reads it (ps"),
        (["--token-file", "{file}"], 0o644, "other users may read it (mode 644): chmod 600"),
        (["--token-file", "{file}"], "short", "16 to 256 letters"),
        (["--token-file", "{missing}"], None, "no such file"),
        (["--token-file", "{fifo}"], "fifo", "not a regular file"),
    ],
)
@pytest.mark.posix_only  # permission bits (Windows checks no ACL), os.mkfifo
def test_carfeel_panel_refuses_a_credential_others_could_read(tmp_path, capsys, options, setup,
                                                                message):  # fmt: skip
    file = tmp_path / "token"
    file.write_text("short" if setup == "short" else TOKEN)
    file.chmod(setup if isinstance(setup, int) else 0o600)
    fifo = tmp_path / "fifo"
    if setup == "fifo":
        os.mkfifo(fifo)
    paths = {"file": str(file), "missing": str(tmp_path / "none"), "fifo": str(fifo)}
    started = time.monotonic()
    assert main(["panel", "--dir", str(tmp_path / "p"), *(o.format(**paths) for o in options)]) == 2
    assert time.monotonic() - started < 30  # a FIFO does not hang it (no reader would come)
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "p").exists()
    assert stat.S_IMODE(file.stat().st_mode) in (0o600, 0o644)


def test_an_environment_credential_that_is_too_short_is_refused(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CARFEEL_PANEL_TOKEN", "short")
    assert main(["panel", "--dir", str(tmp_path / "p")]) == 2
    assert "$CARFEEL_PANEL_TOKEN: the credential is 16 to 256" in capsys.readouterr().err


def test_a_network_panel_names_an_address_another_machine_reaches():
    """`panel --host 0.0.0.0` printed only 127.0.0.1 (issue 28): the address it adds is this
    machine's own (it can be bound here) and not loopback."""
    import socket

    from carfeel.commands.panel import lan_addresses

    for address in lan_addresses():
        assert not address.startswith("127.")
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.bind((address, 0))  # an address of this machine's interfaces, or OSError
