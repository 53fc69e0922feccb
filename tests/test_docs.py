"""The documentation site (issue 28): it builds with --strict and no network, its generated
reference holds every CLI option and every preset field, and every command its tutorials and
how-tos show in a console block runs as written."""

from __future__ import annotations

import argparse
import html
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    built = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-d", str(out)],
        cwd=ROOT, capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-3000:]
    return out


def _page_text(site: Path, page: str) -> str:
    return html.unescape((site / page / "index.html").read_text(encoding="utf-8"))


def test_the_site_builds_strictly_and_loads_nothing_from_the_network(site: Path):
    for page in site.rglob("*.html"):
        text = page.read_text(encoding="utf-8")
        # no font service or CDN: what a page loads is the site's own
        for remote in re.findall(r'(?:src|href)="(https?://[^"]+)"', text):
            assert not re.search(r"fonts\.(googleapis|gstatic)|cdn", remote), (page, remote)


def _options(parser: argparse.ArgumentParser, trail: str = "carfeel") -> dict[str, set[str]]:
    found = {trail: {s for a in parser._actions for s in a.option_strings if s.startswith("--")}}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update(_options(sub, f"{trail} {name}"))
    return found


def test_every_cli_option_of_every_command_is_in_the_reference(site: Path):
    from carfeel.cli import build_parser

    page = _page_text(site, "reference/cli")
    commands = _options(build_parser())
    assert len(commands) > 20  # the walk found the sub-commands, not only the top
    for command, options in commands.items():
        assert command in page, command
        for option in options - {"--help"}:
            assert option in page, f"{command} {option}"


def test_every_preset_field_is_in_the_reference(site: Path):
    from carfeel.io import presets

    page = _page_text(site, "reference/presets")
    for kind in ("shift", "steering", "hpattern", "sequential", "prnd"):
        for name in presets.available(kind):
            text = presets.resolve(kind, name)[1]
            for table, value in presets.load_toml(name, text).items():
                keys = _keys(value, table) if isinstance(value, dict) else [table]
                for key in keys:
                    assert key in page, f"{kind} {name}: {key}"


def test_every_schema_field_has_its_row_with_the_schema_s_unit_and_range(site: Path):
    """The reference is the schema rendered: each field of each kind has a row whose unit and
    allowed range are the schema's (a range changed in carfeel.schema changes the page)."""
    from carfeel import schema
    from carfeel.simulation.hpattern import HPatternSetup
    from carfeel.simulation.prnd import PrndSetup
    from carfeel.simulation.sequential import SequentialSetup
    from carfeel.simulation.shift import ShiftParams
    from carfeel.simulation.steering import SteeringCar

    raw = (site / "reference/presets/index.html").read_text(encoding="utf-8")
    cell = r"<td>([^<]*)</td>"
    row = re.compile(rf"<tr>\n<td><code>([^<]+)</code></td>\n{cell}\n{cell}")
    rows = {
        html.unescape(m.group(1)): (html.unescape(m.group(2)), html.unescape(m.group(3)))
        for m in row.finditer(raw)
    }
    kinds = (ShiftParams, SteeringCar, HPatternSetup, SequentialSetup, PrndSetup)
    fields = [f for cls in kinds for f in schema.fields(cls)]
    assert len(fields) > 200
    for f in fields:
        assert f.path in rows, f.path
        unit, allowed = rows[f.path]
        shown = f.unit or {float: "-", int: "whole number"}.get(f.kind, unit)
        assert unit == shown, f.path
        assert allowed == (f.range_text() or "any"), f.path


def _keys(table: dict[str, object], prefix: str) -> list[str]:
    keys = []
    for k, v in table.items():
        if isinstance(v, dict):
            keys += _keys(v, f"{prefix}.{k}")
        else:
            keys.append(f"{prefix}.{k}")
    return keys


def documented_commands() -> list[tuple[str, str]]:
    """(page, command) for every `$ ` line of a ```console block in the tutorials and how-tos."""
    found = []
    for page in sorted([*DOCS.glob("tutorials/*.md"), *DOCS.glob("how-to/*.md")]):
        for block in re.findall(r"```console\n(.*?)```", page.read_text(encoding="utf-8"), re.S):
            for line in block.splitlines():
                if line.startswith("$ "):
                    found.append((page.relative_to(DOCS).as_posix(), line[2:]))
    return found


def test_the_pages_show_commands_to_run():
    pages = {page for page, _ in documented_commands()}
    assert {"tutorials/first-shift.md", "tutorials/car-from-logs.md"} <= pages


@pytest.mark.slow
def test_every_documented_command_runs_as_written(tmp_path: Path):
    """In a copy of the examples (the commands write files), with carfeel on the PATH as the
    install page says; each page's commands in order, in one folder, as a reader runs them."""
    shutil.copytree(ROOT / "examples", tmp_path / "examples")
    bin_dir = str(Path(sys.executable).parent)
    env = {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", "")}
    assert shutil.which("carfeel", path=env["PATH"]), "carfeel is not on the venv's PATH"
    for page, command in documented_commands():
        ran = subprocess.run(
            shlex.split(command), cwd=tmp_path, env=env, capture_output=True, text=True,
            timeout=600,
        )  # fmt: skip
        assert ran.returncode == 0, f"{page}: {command}\n{ran.stderr[-2000:]}"
