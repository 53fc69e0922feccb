"""What Windows and macOS take differently, simulated here (issue 29): the other platform's
`sys.platform`, its missing modules, its coarse clock; and the workflow that runs the portable
tests on the real ones (.github/workflows/portable.yml), checked against pyproject's markers.

Nothing here has run on Windows or macOS: each test states what the code must do there, as
far as it can be said on Linux."""

from __future__ import annotations

import json
import math
import re
import socket
import subprocess
import sys
import textwrap
import time
import tomllib
from pathlib import Path
from typing import Any

import pytest

from carfeel.commands import panel as panel_command
from carfeel.errors import InputError
from carfeel.telemetry import gearout, replay, shm
from tests.test_telemetry_record import FORZA, _free_port, _listen, _packets, _rows, _wait_bound

ROOT = Path(__file__).resolve().parents[1]
WORKFLOW = ROOT / ".github" / "workflows" / "portable.yml"


# --- the panel's listening socket ----------------------------------------------------------


@pytest.mark.parametrize(("platform", "reused"), [("linux", True), ("win32", False)])
def test_the_panel_s_socket_does_not_share_its_port_on_windows(
    monkeypatch: pytest.MonkeyPatch, platform: str, reused: bool
) -> None:
    """Windows' SO_REUSEADDR lets a second socket bind a port another one listens on (POSIX's
    only allows a port in TIME_WAIT again): there, `carfeel panel` on a port in use would
    start instead of refusing, and share the port with the other program."""
    options: list[tuple[int, int]] = []

    class Recording(socket.socket):
        def setsockopt(self, *args: Any) -> None:
            options.append((args[0], args[1]))
            super().setsockopt(*args)

    monkeypatch.setattr(socket, "socket", Recording)
    monkeypatch.setattr(sys, "platform", platform)
    with panel_command.listen("127.0.0.1", 0):
        pass
    assert ((socket.SOL_SOCKET, socket.SO_REUSEADDR) in options) is reused


# --- gear output ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("platform", "said"),
    [("win32", "use --gear-output vjoy"), ("darwin", "carfeel has no gear output")],
)
def test_uinput_elsewhere_says_it_is_linux_s_and_what_there_is(
    monkeypatch: pytest.MonkeyPatch, platform: str, said: str
) -> None:
    """python-evdev installs on Linux only (the `devices` extra's marker): elsewhere the old
    message said to install carfeel[devices], which does not bring it."""
    monkeypatch.setitem(sys.modules, "evdev", None)  # not installed: ImportError
    monkeypatch.setattr(sys, "platform", platform)
    with pytest.raises(InputError) as refused:
        gearout.UInputGearOutput(6)
    text = str(refused.value)
    assert "Linux's" in text and said in text and "pip install" not in text


def test_uinput_on_linux_without_evdev_still_says_what_to_install(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setitem(sys.modules, "evdev", None)
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(InputError, match=r"pip install 'carfeel\[devices\]'"):
        gearout.UInputGearOutput(6)


# --- shared memory -------------------------------------------------------------------------


def test_a_live_map_on_macos_is_refused_with_what_to_read_instead(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """macOS has neither Windows' named memory nor a /dev/shm a bridge could write: it waited
    for ever, saying "is the game running?"."""
    monkeypatch.setattr(sys, "platform", "darwin")
    with pytest.raises(InputError, match=r"darwin has neither: read a file image \(iracing:file"):
        shm.MapReceiver(shm.MapSource(shm.MAP_FORMATS["iracing"]))


# --- text files ----------------------------------------------------------------------------

WRITERS = textwrap.dedent(
    """
    import json, sys, warnings, webbrowser
    from pathlib import Path

    import numpy as np

    from carfeel import cli
    from carfeel.commands.panel import open_in_browser
    from carfeel.simulation.result import Result
    from carfeel.simulation.stream import CsvWriter

    folder = Path(sys.argv[1])
    webbrowser.open = lambda url: True  # the page is written; no browser is started
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", EncodingWarning)
        result = Result(np.array([0.0, 0.001]), {"x_m": np.array([0.0, 1.0])}, {})
        result.to_csv(folder / "to_csv.csv")
        with CsvWriter(folder / "stream.csv") as writer:
            writer.write(result)
        assert cli.main(["telemetry", "listen", "forza:127.0.0.1:0", "--duration", "0.2",
                         "--json", "--record", str(folder / "telemetry.csv")]) == 0
        open_in_browser("http://127.0.0.1:9/#token=x")
    ours = [f"{Path(w.filename).name}:{w.lineno}" for w in seen
            if issubclass(w.category, EncodingWarning) and "carfeel" in Path(w.filename).parts]
    print("WARNED " + json.dumps(ours))
    """
)


def test_text_files_are_written_as_utf8_whatever_the_locale(tmp_path: Path) -> None:
    """A text file opened without `encoding` is written in the locale's encoding: Windows'
    ANSI code page (cp1252), where carfeel reads its CSV files as UTF-8. Python says where
    (`-X warn_default_encoding`): none of the writers of a run's files may rely on it."""
    done = subprocess.run(
        [sys.executable, "-X", "warn_default_encoding", "-c", WRITERS, str(tmp_path)],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    warned = json.loads(done.stdout.rsplit("WARNED ", 1)[1])
    assert warned == [], f"text files opened without an encoding at {warned}"
    assert (tmp_path / "telemetry.csv").read_text(encoding="utf-8").startswith("time_s,")


# --- clocks --------------------------------------------------------------------------------

WINDOWS_TICK_S = 1 / 64
"""time.monotonic's step on Windows before Python 3.13 (GetTickCount64: 15.6 ms)."""


def test_a_telemetry_recording_stamps_its_rows_finer_than_windows_monotonic_tick(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`telemetry listen --record` stamps each row with its arrival: on time.monotonic, which
    steps by 15.6 ms on Windows (3.11, 3.12), a 250 Hz stream's rows shared their stamps."""
    real = time.monotonic
    monkeypatch.setattr(
        time, "monotonic", lambda: math.floor(real() / WINDOWS_TICK_S) * WINDOWS_TICK_S
    )
    good = _packets(*FORZA)[:20]
    port, record = _free_port(), tmp_path / "state.csv"
    codes: list[int] = []
    listener = _listen(["telemetry", "listen", f"forza:127.0.0.1:{port}", "--duration", "2",
                        "--json", "--record", str(record)], codes)  # fmt: skip
    _wait_bound(port)
    assert replay.send(good, ("127.0.0.1", port), 250.0) == len(good)
    listener.join(30.0)
    assert codes == [0]
    arrivals = [float(r["time_s"]) for r in _rows(record)]
    assert len(arrivals) == len(good)
    assert len(set(arrivals)) == len(arrivals), arrivals
    assert arrivals == sorted(arrivals)


# --- the workflow --------------------------------------------------------------------------


def _registered_markers() -> set[str]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    lines = config["tool"]["pytest"]["ini_options"]["markers"]
    return {line.split(":", 1)[0].split("(", 1)[0].strip() for line in lines}


def test_the_portable_workflow_runs_the_registered_markers_on_windows_and_macos() -> None:
    """The workflow cannot run here: a renamed marker must break this test, not silently
    select every test (or none) in the job."""
    yaml = pytest.importorskip("yaml")
    workflow = yaml.safe_load(WORKFLOW.read_text(encoding="utf-8"))
    job = workflow["jobs"]["portable"]
    matrix = job["strategy"]["matrix"]
    assert {name.split("-")[0] for name in matrix["os"]} == {"windows", "macos"}
    chosen = {entry["os"].split("-")[0]: entry["markers"] for entry in matrix["include"]}
    assert set(chosen) == {"windows", "macos"}
    commands = "\n".join(step.get("run", "") for step in job["steps"])
    assert 'pytest -m "${{ matrix.markers }}"' in commands
    registered = _registered_markers()
    for system, expression in chosen.items():
        names = set(re.findall(r"[A-Za-z_]\w*", expression)) - {"not", "and", "or"}
        assert names <= registered, (system, expression, names - registered)
        assert "not linux_only" in expression and "not slow" in expression, system
    assert "not posix_only" in chosen["windows"]
