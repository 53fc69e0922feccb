"""The live panel's API and WebSocket protocol (Starlette's TestClient), its tuning checks, its
ring, and the loop's process stopping when the panel's dies.

Sessions run on the virtual devices in simulated time (as fast as the loop's process goes), in
a real process spawned as `carfeel panel` spawns it; nothing here asserts a wall-clock figure.
"""

from __future__ import annotations

import csv
import itertools
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("starlette", reason="the panel needs carfeel[panel]")
pytest.importorskip("httpx2", reason="Starlette's TestClient needs httpx2 (carfeel[test])")

from starlette.testclient import TestClient

from carfeel.panel import ring
from carfeel.panel.config import PanelConfig
from carfeel.panel.server import create_app
from carfeel.panel.session import Session

JSON = {"Content-Type": "application/json"}
SEQUENCE = ",".join(["N", "1", "2", "3", "4", "N"] * 4)


TOKEN = "test-credential-0123456789"


def client_for(
    folder: Path, token: str = TOKEN, hosts: tuple[str, ...] = ("testserver",), **config: Any
) -> TestClient:
    """A client of a panel that sends the panel's credential with every request."""
    app = create_app(PanelConfig(folder=folder, token=token, hosts=hosts, **config))
    return TestClient(app, headers={"Authorization": f"Bearer {token}"})


def post(client: TestClient, path: str, body: object, **kwargs: Any):
    return client.post(path, content=json.dumps(body), headers=JSON, **kwargs)


def wait_for(
    client: TestClient, predicate, timeout_s: float = 120.0, what: str = ""
) -> dict[str, Any]:
    """Poll the session until `predicate(session)`; the loop runs in simulated time, so the
    wait is the loop's process's speed on a loaded machine, hence the generous limit."""
    deadline = time.monotonic() + timeout_s
    session: dict[str, Any] = {}
    while time.monotonic() < deadline:
        session = client.get("/api/session").json()
        if predicate(session):
            return session
        if session.get("state") in ("failed",):
            break
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}: {json.dumps(session)[:2000]}")


def synchronization_runs(path: Path) -> list[tuple[float, float]]:
    """(start time, duration) of every stretch the recording spent in `synchronization`."""
    runs = []
    start: float | None = None
    last = 0.0
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            if not row.get("time_s") or row.get("stage") in (None, "nan"):
                continue
            t = float(row["time_s"])
            if row["stage"] == "synchronization":
                if start is None:
                    start = t
                last = t
            elif start is not None:
                runs.append((start, last - start + 1e-3))
                start = None
    return runs


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_a_session_streams_tunes_records_and_stops(tmp_path):
    before = panel_segments()
    with client_for(tmp_path) as client:
        assert client.get("/api/session").json() == {"state": "idle"}
        options = client.get("/api/options").json()
        assert (
            "hpattern" in options["models"] and "virtual:joystick" in options["devices"]["joystick"]
        )
        start = post(client, "/api/session", {
            "model": "hpattern", "device": "virtual:joystick", "clock": "simulated",
            "sequence": SEQUENCE, "duration_s": 600, "force": True,
        })  # fmt: skip
        assert start.status_code == 200, start.text
        assert start.json()["device"]["name"] == "virtual joystick"
        # A second session while one runs is refused.
        again = post(client, "/api/session", {"model": "hpattern", "force": True})
        assert again.status_code == 400 and "running" in again.json()["error"]

        # The stream: frames with the rows the loop wrote, strings decoded, gears engaged.
        seen_gears: set[str] = set()
        frames = 0
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"columns": ["time_s", "gear", "stage", "x_m"], "every": 1})
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline and not {"1", "2"} <= seen_gears:
                message = ws.receive_json()
                if message["type"] != "frame" or "columns" not in message:
                    continue
                columns = message["columns"]
                frames += 1
                if frames > 3:  # the subscription has arrived: only the asked-for columns
                    assert set(columns) <= {"time_s", "gear", "stage", "x_m"}
                seen_gears |= {g for g in columns.get("gear", []) if g not in ("", "N")}
                times = columns["time_s"]
                assert times == sorted(times)
        assert {"1", "2"} <= seen_gears

        # Record, then tune the synchronization time: the loop's behaviour changes (measured
        # from the recording), after the tuning's ramp.
        assert post(client, "/api/recording", {"name": "tuned"}).status_code == 200
        wait_for(client, lambda s: s.get("status", {}) and s["status"]["recording"] == 1.0,
                 what="the recording")  # fmt: skip
        session = client.get("/api/session").json()
        before_tune = session["status"]["time_s"]
        wait_for(client, lambda s: s["status"]["time_s"] > before_tune + 4.0, what="4 s more")
        tune = post(client, "/api/tune", {"values": {"gearbox.synchronization_duration_s": 0.6}})
        assert tune.status_code == 200, tune.text
        assert tune.json()["changes"]["gearbox.synchronization_duration_s"] == {
            "old": 0.3, "new": 0.6}  # fmt: skip
        tuned = wait_for(client, lambda s: any(e["event"] == "tuned" for e in s["events"]),
                         what="the tuning to be applied")  # fmt: skip
        tuned_at = next(e["time_s"] for e in tuned["events"] if e["event"] == "tuned")
        ramp_at = next(e["time_s"] for e in tuned["events"] if e["event"] == "tuning")
        assert tuned_at - ramp_at == pytest.approx(0.2, abs=2e-3)  # the ramp, in loop time
        wait_for(client, lambda s: s["status"]["time_s"] > tuned_at + 5.0, what="5 s more")
        assert post(client, "/api/recording/stop", {}).status_code == 200
        wait_for(client, lambda s: any(e["event"] == "recorded" for e in s["events"]),
                 what="the recording to be written")  # fmt: skip
        listed = client.get("/api/recordings").json()["recordings"]
        assert [r["name"] for r in listed] == ["tuned.csv"]
        download = client.get("/api/recordings/tuned.csv")
        assert download.status_code == 200
        path = tmp_path / "downloaded.csv"
        path.write_bytes(download.content)
        runs = synchronization_runs(path)[1:]  # the first may have begun before the recording
        early = [d for t, d in runs if t < ramp_at]
        late = [d for t, d in runs if t > tuned_at]
        assert early and late, runs
        # 1 ms ticks in simulated time: a run lasts the duration to within a tick or two.
        assert all(0.28 <= d <= 0.32 for d in early), early
        assert all(0.58 <= d <= 0.62 for d in late), late
        sidecar = client.get("/api/recordings/tuned.json").json()
        assert sidecar["model"] == "hpattern" and sidecar["summary"]["stopped"]
        assert sidecar["tuning"][0]["changes"]["gearbox.synchronization_duration_s"] == [0.3, 0.6]
        plot = client.get("/api/recordings/tuned/plot.png")
        assert plot.status_code == 200 and plot.content[:8] == b"\x89PNG\r\n\x1a\n"

        # A tuning the preset's own checks refuse, with the reason.
        walls = post(client, "/api/tune", {"values": {"walls.stiffness_N_m": 30000}})
        assert walls.status_code == 400
        assert "K*T/2 + B" in walls.json()["error"]
        assert post(client, "/api/tune", {"values": {"walls.stiffness_N_m": -1}}).json()[
            "error"].startswith("walls.stiffness_N_m = -1 N/m is out of range")  # fmt: skip
        assert "not a tunable" in post(client, "/api/tune", {"values": {"torque.k1_Nm_s2_m": 1}}
                                       ).json()["error"]  # fmt: skip

        # Saved as a preset the loader takes back, with the tuned value.
        saved = post(client, "/api/presets", {"name": "slow-synchro"})
        assert saved.status_code == 200, saved.text
        from carfeel.io.presets import load_hpattern

        preset = load_hpattern(str(tmp_path / "presets" / "hpattern" / "slow-synchro.toml"))
        assert preset.shift.gearbox.synchronization_duration_s == 0.6
        assert "saved:slow-synchro" in client.get("/api/options").json()["presets"]["hpattern"]

        stop = client.post("/api/session/stop")
        assert stop.status_code == 200
        ended = wait_for(client, lambda s: s["state"] == "ended", what="the end")
        assert ended["summary"]["stopped"] == "stopped" and not ended["faults"]
        assert {"1", "2", "3", "4"} <= set(ended["summary"]["gears"])
    # The panel's end unlinks its shared memory (segments of other panels may exist).
    assert panel_segments() <= before


def panel_segments() -> set[Path]:
    return {p for p in Path("/dev/shm").glob("psm_*") if _is_panel_segment(p)}


def _is_panel_segment(path: Path) -> bool:
    try:
        with path.open("rb") as f:
            return f.read(4) == (ring.MAGIC).to_bytes(4, "little")
    except OSError:
        return False


def test_bad_input_is_refused_with_the_reason(tmp_path):
    with client_for(tmp_path) as client:

        def error(path: str, body: object) -> str:
            response = post(client, path, body)
            assert response.status_code == 400, response.text
            message: str = response.json()["error"]
            return message

        assert "force" in error("/api/session", {"model": "hpattern"})
        assert "choose one of" in error("/api/session", {"model": "boat", "force": True})
        assert "--speed-kmh" in error("/api/session", {"speed_kmh": 900, "force": True})
        assert "unknown field" in error("/api/session", {"colour": "red", "force": True})
        assert "shipped" in error("/api/session", {"preset": "../../etc/passwd", "force": True})
        assert "no '..'" in error("/api/session", {"preset": "saved:..", "force": True})
        assert "no session" in error("/api/tune", {"values": {"walls.stiffness_N_m": 1e4}})
        assert "no session" in error("/api/recording", {"name": "x"})
        response = client.post(
            "/api/session",
            content="model=hpattern",
            headers={"Content-Type": "application/x-www-form-urlencoded"},
        )
        assert response.status_code == 400 and "JSON" in response.json()["error"]
        # File names cannot leave the panel's folder.
        for name in ("../escape", "a/b", "..", ".hidden", "x" * 200):
            assert client.get(f"/api/recordings/{name}.csv").status_code in (400, 404)
        assert client.get("/api/recordings/..%2F..%2Fetc%2Fpasswd").status_code in (400, 404)
        assert client.get("/api/recordings/%2e%2e.csv").status_code in (400, 404)
        (tmp_path.parent / "secret.csv").write_text("time_s\n1\n")
        assert client.get("/api/recordings/..%2Fsecret.csv").status_code in (400, 404)


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_steering_tunings_are_checked_against_the_wheel(tmp_path):
    with client_for(tmp_path) as client:
        start = post(client, "/api/session", {
            "model": "steering", "device": "virtual:wheel", "clock": "simulated",
            "speed_kmh": 80, "duration_s": 600, "force": True,
        })  # fmt: skip
        assert start.status_code == 200, start.text
        wait_for(client, lambda s: s["state"] == "running", what="running")
        tunables = client.get("/api/tune").json()["tunables"]
        k1 = next(t for t in tunables if t["path"] == "torque.k1_Nm_s2_m")
        assert k1["value"] == 2.4 and k1["unit"] == "Nm/(m/s^2)"
        huge = post(client, "/api/tune", {"values": {"torque.k1_Nm_s2_m": 10**400}})
        assert huge.status_code == 400  # it was a 500 (OverflowError)
        assert "a whole number of 401 digits" in huge.json()["error"]
        stiff = post(client, "/api/tune", {"values": {"torque.k1_Nm_s2_m": 40.0}})
        assert stiff.status_code == 400
        assert "on-centre spring" in stiff.json()["error"]
        ok = post(client, "/api/tune", {"values": {"torque.k9_Nm_s_rad": 0.2,
                                                   "torque.k7_Nm": 0.5}})  # fmt: skip
        assert ok.status_code == 200, ok.text
        assert ok.json()["waits_for"] is None
        wait_for(client, lambda s: any(e["event"] == "tuned" for e in s["events"]),
                 what="tuned")  # fmt: skip
        values = {t["path"]: t["value"] for t in client.get("/api/tune").json()["tunables"]}
        assert values["torque.k9_Nm_s_rad"] == 0.2 and values["torque.k7_Nm"] == 0.5
        saved = post(client, "/api/presets", {"name": "light"})
        assert saved.status_code == 200, saved.text
        from carfeel.io.presets import load_steering

        car = load_steering(str(tmp_path / "presets" / "steering" / "light.toml")).params
        assert car.torque.k7_Nm == 0.5 and car.tyres is not None
        assert post(client, "/api/presets", {"name": "light"}).status_code == 400  # exists
        client.post("/api/session/stop")
        wait_for(client, lambda s: s["state"] == "ended", what="the end")


def test_the_physical_steering_runs_and_is_tuned_from_the_panel(tmp_path):
    """--steering-model physical from the API: the session reports its coupling; the tunables
    are the EPS system's and the tyres' (not the paper law's); a tuning the wheel cannot damp is
    refused with the reason, one it can is ramped in by the loop's process, and the next is
    checked on the new schedule; the saved preset holds it."""
    with client_for(tmp_path) as client:
        options = client.get("/api/options").json()
        assert options["steering_models"] == ["paper", "physical"]
        assert options["roads"] == ["dry", "wet", "snow"]
        physical = {t["path"] for t in options["tunables"]["steering:physical"]}
        assert "steering_system.eps_damping_high_speed_Nm_s_rad" in physical
        assert not physical & {t["path"] for t in options["tunables"]["steering"]}
        bad = post(client, "/api/session", {"model": "steering", "steering_model": "physical",
                                            "device": "virtual:wheel", "clock": "simulated",
                                            "road": "ice", "force": True})  # fmt: skip
        assert bad.status_code == 400 and "ice" in bad.json()["error"]
        start = post(client, "/api/session", {
            "model": "steering", "steering_model": "physical", "road": "wet",
            "device": "virtual:wheel", "clock": "simulated", "speed_kmh": 100,
            "duration_s": 600, "force": True,
        })  # fmt: skip
        assert start.status_code == 200, start.text
        s = wait_for(client, lambda s: s["state"] == "running", what="running")
        assert s["run"]["steering_model"] == "physical" and s["run"]["road"] == "wet"
        assert s["coupling"]["stiffness"] > 0 and s["coupling"]["zeta"] >= 0.05
        assert "torque_assist_Nm" in s["columns"]
        tunables = client.get("/api/tune").json()
        assert tunables["steering_model"] == "physical"
        values = {t["path"]: t["value"] for t in tunables["tunables"]}
        assert values["steering_system.eps_damping_high_speed_Nm_s_rad"] == 1.9
        refused = post(client, "/api/tune", {
            "values": {"steering_system.eps_damping_high_speed_Nm_s_rad": 0.0}})  # fmt: skip
        assert refused.status_code == 400
        assert "could not keep the released wheel damped" in refused.json()["error"]
        law = post(client, "/api/tune", {"values": {"torque.k9_Nm_s_rad": 0.2}})
        assert law.status_code == 400 and "not a tunable" in law.json()["error"]
        for trail in (0.06, 0.07):  # the second is checked on the first's schedule
            ok = post(client, "/api/tune", {"values": {"tyres.pneumatic_trail_m": trail}})
            assert ok.status_code == 200, ok.text
        wait_for(client, lambda s: sum(e["event"] == "tuned" for e in s["events"]) >= 2,
                 what="tuned twice")  # fmt: skip
        values = {t["path"]: t["value"] for t in client.get("/api/tune").json()["tunables"]}
        assert values["tyres.pneumatic_trail_m"] == 0.07
        saved = post(client, "/api/presets", {"name": "heavier"})
        assert saved.status_code == 200, saved.text
        from carfeel.io.presets import load_steering

        car = load_steering(str(tmp_path / "presets" / "steering" / "heavier.toml")).params
        assert car.tyres is not None and car.tyres.pneumatic_trail_m == 0.07
        client.post("/api/session/stop")
        s = wait_for(client, lambda s: s["state"] == "ended", what="the end")
        assert s["summary"]["stopped"] == "stopped" and not s["faults"]


def test_the_ring_never_hands_out_a_lapped_row():
    shm = ring.create()
    try:
        writer = ring.LoopSide(shm, 3)
        reader = ring.PanelSide(shm)
        for k in range(ring.ROW_CAPACITY * 2 + 10):
            writer.row((float(k), 2.0 * k, -1.0))
        rows, cursor, lost = reader.read_rows(0, 3)
        assert cursor == ring.ROW_CAPACITY * 2 + 10
        assert lost == cursor - len(rows)
        assert list(rows[:, 0]) == list(range(cursor - len(rows), cursor))
        assert (rows[:, 1] == 2.0 * rows[:, 0]).all()
        for k in range(5):
            writer.event(("n", k))
        assert reader.events() == [("n", k) for k in range(5)]
        for k in range(ring.EVENT_SLOTS + 3):
            writer.event(("m", k))
        events = reader.events()
        assert events[0][0] == "lost" and events[-1] == ("m", ring.EVENT_SLOTS + 2)
        assert all(reader.send(("c", k)) for k in range(ring.COMMAND_SLOTS))
        assert not reader.send(("one", "too many"))  # the loop has not taken any
        assert writer.command() == ("c", 0)
        assert reader.send(("c", 99))
        writer.status(tuple(float(i) for i in range(len(ring.STATUS))))
        status = reader.status()
        assert status is not None and status["guard_rms"] == 1.0
        del rows
        reader.close()
        writer.close()
    finally:
        shm.unlink()


def test_a_loop_that_ends_as_the_panel_looks_is_not_an_error():
    """The loop writes its last event (the summary) and exits between the panel's read of the
    events and its look at the process: the session ends with the summary, not with "the loop's
    process ended" (a browser page showed "ended: ?" for a stop on request)."""

    class EndsWhenLookedAt:
        exitcode = 0

        def __init__(self, loop: ring.LoopSide) -> None:
            self.loop = loop
            self.alive = True

        def is_alive(self) -> bool:
            if self.alive:
                self.alive = False
                self.loop.event(("ended", {"stopped": "stopped", "faults": []}, "summary text"))
            return self.alive

    run = {"model": "hpattern", "device": "virtual:joystick", "clock": "simulated"}
    session = Session(run, None, None)
    loop = ring.LoopSide(session.shm, 3)
    try:
        session.process = EndsWhenLookedAt(loop)
        session.state = "stopping"
        session.pump()
        assert session.state == "ended"
        assert session.error is None
        assert session.summary == {"stopped": "stopped", "faults": []}
        assert [e["event"] for e in session.events] == ["ended"]
    finally:
        loop.close()
        session.process = None  # nothing to join
        session.close()


PARENT = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from carfeel.panel.session import Session
    run = {"model": "hpattern", "device": "virtual:joystick", "clock": "simulated",
           "duration_s": 3600.0, "sequence": tuple("N12341N" * 200), "calibrate": False}
    session = Session(run, None, None)
    session.start(None)
    while session.ready is None:
        session.pump()
        time.sleep(0.01)
    session.side.send(("record_start", sys.argv[1]))
    print(session.process.pid, flush=True)
    while True:
        session.pump()
        time.sleep(0.03)
    """
)


@pytest.mark.skipif(not hasattr(os, "getppid") or sys.platform != "linux", reason="Linux")
@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_loop_fades_out_when_the_panel_dies(tmp_path):
    """SIGKILL the panel's process: nobody watches the device any more, so the loop's process
    stops on its own, through the fade, and keeps what it recorded. (Simulated time: the loop
    runs as it would, and a loaded machine's stalls cannot end it first.)"""
    record = tmp_path / "orphan.csv"
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT, str(record)], stdout=subprocess.PIPE, text=True
    )
    try:
        line = parent.stdout.readline() if parent.stdout else ""
        assert line.strip().isdigit(), "the panel's stand-in did not start its loop"
        loop_pid = int(line)
        deadline = time.monotonic() + 60
        while not (tmp_path / "orphan.part.csv").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(2.0)  # the virtual hand is shifting: forces are on
        assert _alive(loop_pid), "the loop ended before the test could kill its parent"
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 30
        while _alive(loop_pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(loop_pid), "the loop's process outlived the panel's"
    finally:
        if parent.poll() is None:
            parent.kill()
    sidecar = json.loads(record.with_suffix(".json").read_text())
    assert sidecar["summary"]["stopped"].startswith("orphaned")
    with record.open(newline="") as f:
        rows = list(csv.DictReader(f))
    commands = [abs(float(r["command_0"])) + abs(float(r["command_1"])) for r in rows]
    assert max(commands) > 0.1, "no force was on when the panel died: the test tests nothing"
    assert commands[-1] == 0.0
    slew = sidecar["max_slew_per_s"] / sidecar["rate_hz"]
    steps = [
        abs(float(b["command_0"]) - float(a["command_0"])) for a, b in itertools.pairwise(rows)
    ]
    assert max(steps[-50:]) <= slew * (1 + 1e-6)  # the fade respects the slew limit


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (not reaped yet) has ended
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[-1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--port", "70000"], "--port 70000: allowed 0 .. 65535"),
        (["--host", "my laptop"], "--host 'my laptop': give an IP address"),
        (["--dir", "{file}"], "it is a file, not a folder"),
        (["--dir", "{missing}/panel"], "does not exist"),
        (["--loop-cpu", "4096"], "--loop-cpu 4096: this machine has cores 0 .."),
    ],
)
def test_carfeel_panel_refuses_bad_options(tmp_path, capsys, options, message):
    from carfeel.cli import main

    (tmp_path / "a-file").write_text("")
    paths = {"file": str(tmp_path / "a-file"), "missing": str(tmp_path / "nowhere")}
    assert main(["panel", *(o.format(**paths) for o in options)]) == 2
    assert message in capsys.readouterr().err


def test_carfeel_panel_refuses_a_port_in_use(tmp_path, capsys):
    import socket

    from carfeel.cli import main

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = taken.getsockname()[1]
        assert main(["panel", "--port", str(port), "--dir", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert f"cannot listen on 127.0.0.1:{port}" in err and "choose another --port" in err
    assert "Traceback" not in err
    assert not (tmp_path / "p").exists()  # nothing created by a run that could not start


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
@pytest.mark.linux_only  # /dev/shm, /proc/PID/stat, a child's -SIGTERM
def test_the_panel_stops_promptly_with_a_stream_open_and_a_session_running(tmp_path):
    """SIGTERM to `carfeel panel` while a WebSocket client is connected (and reads nothing)
    and a session runs: uvicorn's shutdown must not wait on the stream, and the loop's
    process is stopped through its fade, not left behind."""
    import re

    from websockets.sync.client import connect

    before = panel_segments()
    process = subprocess.Popen(
        [sys.executable, "-m", "carfeel.cli", "panel", "--port", "0", "--dir", str(tmp_path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        line = process.stdout.readline() if process.stdout else ""
        match = re.search(r"http://([\d.]+:\d+)/#token=(\S+)", line)
        assert match, line
        address, token = match.groups()
        import urllib.request

        bearer = {"Authorization": f"Bearer {token}"}
        request = urllib.request.Request(
            f"http://{address}/api/session", method="POST", headers=JSON | bearer,
            data=json.dumps({"model": "hpattern", "clock": "simulated", "duration_s": 3600,
                             "sequence": SEQUENCE, "force": True}).encode(),
        )  # fmt: skip
        with urllib.request.urlopen(request, timeout=180) as answer:
            session = json.load(answer)
        loop_pid = session["loop_process"]["pid"]
        with connect(f"ws://{address}/api/stream", additional_headers=bearer) as ws:
            ws.recv(timeout=30)
            process.send_signal(signal.SIGTERM)
            process.wait(timeout=20)  # raises if the shutdown hangs
        # uvicorn shuts down gracefully, then re-raises the signal (the shell's 143).
        assert process.returncode == -signal.SIGTERM, (
            process.stderr.read() if process.stderr else ""
        )
        deadline = time.monotonic() + 10
        while _alive(loop_pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(loop_pid), "the loop's process outlived the panel"
    finally:
        if process.poll() is None:
            process.kill()
    assert panel_segments() <= before  # this panel's segment is gone
