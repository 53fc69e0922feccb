"""The live panel in a real browser: Debian's chromium, headless, driven by Playwright, against
`carfeel panel` running as a user runs it (a subprocess on a free port).

The loop runs on the virtual devices in simulated time; what is asserted is what the page
shows and what the loop did (measured from the recording the page downloads), never a
wall-clock figure. chromium comes from the distribution (`make test` installs it as root);
`playwright install` cannot download a browser here.
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.test_panel import synchronization_runs

# A real browser beside the panel: make test (and CI) runs these, make check does not.
pytestmark = [pytest.mark.slow, pytest.mark.needs_tools]  # chromium (CARFEEL_CHROMIUM)

CHROMIUM = Path(os.environ.get("CARFEEL_CHROMIUM", "/usr/bin/chromium"))
ARGS = [
    "--no-sandbox", "--disable-background-networking", "--disable-component-update",
    "--disable-sync", "--no-first-run", "--disable-quic", "--disable-gpu",
]  # fmt: skip
TIMEOUT_MS = 120_000
"""Generous: the loop's process starts (imports, sizing) on a machine shared with others."""
SEQUENCE = ",".join(["N", "1", "2", "3", "4", "N"] * 40)
"""Long: the loop runs in simulated time, several times faster than the page's clicks."""


def _need_browser() -> Any:
    """Playwright and chromium, or a failure that says how to get them. A skip only where
    neither can be installed (not root, chromium missing)."""
    root = hasattr(os, "geteuid") and os.geteuid() == 0
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        message = "Playwright is missing: pip install -e '.[test,panel]' (make test does)"
        pytest.fail(message) if root or os.environ.get("CI") else pytest.skip(message)
    if not CHROMIUM.exists():
        message = (
            f"{CHROMIUM} is missing: apt-get update && apt-get install -y chromium "
            "(make test does it as root)"
        )
        if root or os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message + "; not root, so skipped")
    return sync_playwright


@contextlib.contextmanager
def serving(folder: Path, *options: str) -> Iterator[str]:
    """`carfeel panel --port 0 ...` in a subprocess; its URL (as printed, #token=... included)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "carfeel.cli", "panel", "--port", "0", "--dir", str(folder),
         *options],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        line = process.stdout.readline() if process.stdout else ""
        match = re.search(r"(http://\S+)", line)
        assert match, f"carfeel panel did not print its URL: {line!r}"
        yield match.group(1)
    finally:
        process.terminate()
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:  # pragma: no cover - uvicorn's shutdown hung
            process.kill()
            raise AssertionError("carfeel panel did not stop within 30 s of SIGTERM") from None


@pytest.fixture(scope="module")
def panel(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    folder = tmp_path_factory.mktemp("panel")
    with serving(folder) as url:
        yield url, folder


@pytest.fixture
def page(panel: tuple[str, Path]) -> Iterator[Any]:
    sync_playwright = _need_browser()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS, headless=True)
        context = browser.new_context(viewport={"width": 1920, "height": 1080},
                                      accept_downloads=True)  # fmt: skip
        tab = context.new_page()
        tab.set_default_timeout(TIMEOUT_MS)
        problems: list[str] = []
        tab.on("console", lambda m: problems.append(m.text) if m.type in ("error",) else None)
        tab.on("pageerror", lambda e: problems.append(f"page error: {e}"))
        tab.problems = problems
        tab.goto(panel[0])
        tab.wait_for_function("document.querySelectorAll('#model option').length === 5")
        yield tab
        browser.close()


def test_the_page_loads_without_console_errors(page: Any) -> None:
    assert page.text_content("#state") == "IDLE"
    from carfeel.io.presets import available

    # Every packaged H-pattern (the panel lists the package's, in the package's order).
    assert page.eval_on_selector_all("#preset option", "o => o.map(x => x.value)") == (
        available("hpattern")
    )
    assert {"5r", "6r", "7r"} <= set(available("hpattern"))
    page.select_option("#model", "steering")
    assert "virtual:wheel" in page.eval_on_selector_all(
        "#device option", "o => o.map(x => x.value)"
    )
    page.wait_for_timeout(500)
    assert page.problems == []


def test_a_session_started_from_the_page(
    page: Any, panel: tuple[str, Path], tmp_path: Path
) -> None:
    page.select_option("#model", "hpattern")
    page.select_option("#clock", "simulated")
    page.fill("#sequence", SEQUENCE)
    page.click("#start")
    page.wait_for_function("document.querySelector('#state').textContent === 'RUNNING'")
    page.wait_for_selector("input[data-path='gearbox.synchronization_duration_s']")

    # Gears engage, and the page shows them: the big gear display and the list.
    page.fill("#rec-input", "from-the-page")
    page.click("#record")
    page.wait_for_function("document.querySelector('#rec-indicator').offsetParent !== null")
    shown: set[str] = set()
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not {"1", "2"} <= shown:
        shown.add(page.text_content("#gear") or "")
        page.wait_for_timeout(20)
    assert {"1", "2"} <= shown, shown
    page.wait_for_function("Number(document.querySelector('#gears').dataset.count) >= 3")

    # A parameter changed on the page.
    field = "input[data-path='gearbox.synchronization_duration_s']"
    assert page.input_value(field) == "0.3"
    page.fill(field, "0.6")
    page.click("#apply")
    page.wait_for_function("document.querySelector('#tune-msg').textContent.startsWith('applied')")
    # Four more engagements after it, then the recording is stopped from the page.
    page.wait_for_function("document.querySelector('#events').textContent.includes('tuned:')")
    count = int(page.get_attribute("#gears", "data-count") or 0)
    page.wait_for_function(f"Number(document.querySelector('#gears').dataset.count) >= {count + 4}")
    page.click("#record")
    link = page.wait_for_selector("#recordings a.dl-csv")
    with page.expect_download() as download:
        link.click()
    csv_path = tmp_path / "from-the-page.csv"
    download.value.save_as(csv_path)
    with page.expect_download() as download:
        page.click("#recordings a.dl-json")
    sidecar = json.loads(Path(download.value.path()).read_text())

    # Read it: the loop's synchronizations took the new time once the change was in.
    with csv_path.open(newline="") as f:
        header = next(csv.reader(f))
    assert header[:3] == ["time_s", "overrun", "command_0"] and "stage" in header
    tuned = sidecar["tuning"][0]
    assert tuned["changes"] == {"gearbox.synchronization_duration_s": [0.3, 0.6]}
    runs = synchronization_runs(csv_path)[1:]
    early = [d for t, d in runs if t < tuned["time_s"] - 0.2]
    late = [d for t, d in runs if t > tuned["time_s"]]
    assert early and late, runs
    assert all(0.28 <= d <= 0.32 for d in early), early
    assert all(0.58 <= d <= 0.62 for d in late), late

    # Its plot opens from the page.
    page.click("#recordings button.plot")
    page.wait_for_function(
        "document.querySelector('#plot-img').complete && "
        "document.querySelector('#plot-img').naturalWidth > 500"
    )
    page.click("#plot-close")

    page.click("#stop")
    page.wait_for_function("document.querySelector('#state').textContent === 'ENDED'")
    assert page.text_content("#start-msg") == "ended: stopped on request"
    assert page.problems == []


def test_a_lever_session_from_the_page(page: Any) -> None:
    from carfeel.realtime.run_options import DEFAULT_SEQUENCES

    page.select_option("#model", "sequential")
    # The hand's script field takes the lever's default moves, not the H-pattern's gears.
    assert page.input_value("#sequence") == ",".join(DEFAULT_SEQUENCES["sequential"])
    page.select_option("#clock", "simulated")
    page.click("#start")
    # This session's, not the module's earlier one's (its ENDED state and gears stay shown
    # until the new session's first description arrives).
    page.wait_for_function("document.querySelector('#where').textContent.startsWith('sequential')")
    page.wait_for_function(
        "document.querySelector('#pattern-title').textContent.startsWith('Sequential lever')"
    )
    # (In simulated time a gear may be held for less than a frame: the list, not the display.)
    page.wait_for_function("Number(document.querySelector('#gears').dataset.count) >= 7")
    assert (page.text_content("#gears") or "").split() == ["1", "2", "1", "N", "R", "N", "1"]
    # The lever's view drew its marks: the force-position canvas is not the empty one.
    drawn = page.evaluate(
        "(() => { const c = document.querySelector('#force-position');"
        " const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;"
        " let lit = 0; for (let i = 0; i < d.length; i += 4) if (d[i] > 230) lit++;"
        " return lit; })()"
    )
    assert drawn > 200, drawn  # the white filtered trace, not a blank canvas's few letters
    page.wait_for_function(
        "['ENDED', 'RUNNING'].includes(document.querySelector('#state').textContent)"
    )
    if page.text_content("#state") == "RUNNING":
        page.click("#stop")
    page.wait_for_function("document.querySelector('#state').textContent === 'ENDED'")
    assert page.problems == []


def test_a_steering_session_shows_its_views(page: Any) -> None:
    page.select_option("#model", "steering")
    page.select_option("#clock", "simulated")
    page.click("#start")
    page.wait_for_function("document.querySelector('#state').textContent === 'RUNNING'")
    assert page.is_visible("#steering-views") and not page.is_visible("#gearbox-views")
    page.wait_for_selector("input[data-path='torque.k1_Nm_s2_m']")
    # A tuning the wheel cannot render is refused on the page, with the reason.
    page.fill("input[data-path='torque.k1_Nm_s2_m']", "40")
    page.click("#apply")
    page.wait_for_function("document.querySelector('#tune-msg').classList.contains('error')")
    assert "on-centre spring" in (page.text_content("#tune-msg") or "")
    page.wait_for_timeout(1000)
    page.click("#stop")
    page.wait_for_function("document.querySelector('#state').textContent === 'ENDED'")
    # Chromium logs the refusal's HTTP 400 as a console error: that one, and nothing else.
    assert page.problems == [
        "Failed to load resource: the server responded with a status of 400 (Bad Request)"
    ]


def test_the_physical_steering_from_the_page(page: Any) -> None:
    """The steering model and the road are offered for the steering only (the road for the
    physical model only); the page shows the session's model and its coupling, and tunes the
    physical model's own parameters."""
    assert not page.is_visible("#steering-model-row")
    page.select_option("#model", "steering")
    assert page.is_visible("#steering-model-row") and not page.is_visible("#road-row")
    page.select_option("#steering-model", "physical")
    assert page.is_visible("#road-row")
    page.select_option("#road", "wet")
    page.select_option("#clock", "simulated")
    page.click("#start")
    page.wait_for_function("document.querySelector('#state').textContent === 'RUNNING'")
    assert "steering (physical, wet road)" in (page.text_content("#where") or "")
    page.wait_for_function("document.querySelector('#device-info').textContent"
                           ".includes(\"physical model's coupling\")")  # fmt: skip
    field = "input[data-path='tyres.pneumatic_trail_m']"
    page.wait_for_selector(field)
    assert page.query_selector("input[data-path='torque.k1_Nm_s2_m']") is None
    page.fill(field, "0.06")
    page.click("#apply")
    page.wait_for_function("document.querySelector('#tune-msg').textContent.startsWith('applied')")
    page.wait_for_function("document.querySelector('#events').textContent.includes('tuned:')")
    page.click("#stop")
    page.wait_for_function("document.querySelector('#state').textContent === 'ENDED'")
    assert page.text_content("#start-msg") == "ended: stopped on request"
    assert page.problems == []


@contextlib.contextmanager
def another_server() -> Iterator[tuple[str, list[str]]]:
    """A second web server on 127.0.0.1 (another port: what another local user might run),
    recording every request it receives, whole; its page tries the panel's API and stream."""
    import http.server
    import threading

    received: list[str] = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            received.append(f"{self.requestline}\n{self.headers}")
            page = b"""<!doctype html><title>other</title><script>
            const panel = new URLSearchParams(location.search).get("panel");
            fetch(panel + "api/options", {credentials: "include"})
              .then(r => { document.title = "fetched " + r.status; })
              .catch(e => { document.title = "fetch failed"; });
            </script>"""
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.end_headers()
            self.wfile.write(page)

        def log_message(self, *args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/", received
    finally:
        server.shutdown()
        server.server_close()


def test_the_credential_stays_in_its_tab_and_reaches_no_other_server(tmp_path: Path) -> None:
    """The panel's URL carries the credential in its fragment (never sent to a server): the page
    keeps it in the tab's sessionStorage and takes it out of the address bar; no cookie is set,
    so another server on 127.0.0.1 (another port) receives nothing of it, and its pages cannot
    read it (another origin). A tab opened without it is refused by the API."""
    sync_playwright = _need_browser()
    with serving(tmp_path) as url, another_server() as (other, received), sync_playwright() as p:
        base, token = url.split("#token=")
        assert re.fullmatch(r"[A-Za-z0-9_-]{43}", token), url
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS, headless=True)
        context = browser.new_context()
        tab = context.new_page()
        problems: list[str] = []
        tab.on("console", lambda m: problems.append(m.text) if m.type == "error" else None)
        tab.on("pageerror", lambda e: problems.append(str(e)))
        tab.goto(url)
        tab.wait_for_function("document.querySelectorAll('#model option').length === 5")
        tab.wait_for_function("window.panelStats.frames > 0")  # the stream connected
        assert problems == [], problems
        assert tab.url == base and token not in tab.evaluate("location.href + history.state")
        assert tab.evaluate("sessionStorage.getItem('carfeel-token')") == token
        assert context.cookies() == []  # nothing another port would receive
        # The same browser, the same tab, at the other server: its page asks the panel (with
        # credentials: "include"), and it is refused; the other server received no credential.
        tab.goto(f"{other}?panel={base}")
        tab.wait_for_function("document.title.startsWith('fetch')")
        assert tab.evaluate("sessionStorage.getItem('carfeel-token')") is None
        assert received and all(token not in request for request in received), received
        # Back in the panel's origin the tab still has it; a new tab (no fragment) has not.
        tab.goto(base)
        tab.wait_for_function("window.panelStats.frames > 0")
        fresh = context.new_page()
        fresh.goto(base)
        fresh.wait_for_function("document.querySelector('#start-msg').textContent !== ''")
        assert "no credential" in (fresh.text_content("#start-msg") or "")
        browser.close()
