"""The release (issue 28): a wheel and an sdist build from the checkout; the wheel carries the
package, its data and its licence; the sdist carries what its tests need, and its tests pass run
against the sdist's own sources (not this checkout's installed package)."""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Build both with the venv's setuptools (`--no-isolation`: no download at test time)."""
    out = tmp_path_factory.mktemp("dist")
    done = subprocess.run(
        [sys.executable, "-m", "build", "--no-isolation", "--sdist", "--wheel",
         "--outdir", str(out), str(ROOT)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return out


@pytest.mark.slow  # builds twice and runs a share of the suite from the unpacked sdist
def test_the_wheel_and_the_sdist_build_and_the_sdist_tests_itself(dist: Path, tmp_path: Path):
    wheels = list(dist.glob("carfeel-*.whl"))
    sdists = list(dist.glob("carfeel-*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1
    with zipfile.ZipFile(wheels[0]) as wheel:
        names = set(wheel.namelist())
    assert "carfeel/__init__.py" in names and "carfeel/__main__.py" in names
    assert any(n.startswith("carfeel/presets/") and n.endswith(".toml") for n in names)
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert not any(n.startswith("tests/") for n in names)  # tests ship in the sdist only
    with tarfile.open(sdists[0]) as sdist:
        sdist.extractall(tmp_path, filter="data")
    (tree,) = tmp_path.glob("carfeel-*")
    for needed in ("LICENSE", "CHANGELOG.md", "pyproject.toml", "tests/conftest.py",
                   "tests/datafiles.py", "tests/data", "src/carfeel/cli.py"):  # fmt: skip
        assert (tree / needed).exists(), needed
    # The sdist's own sources first on the path: its tests see its package, not this checkout's.
    env = {**os.environ, "PYTHONPATH": str(tree / "src"), "CI": "1"}
    probe = subprocess.run(
        [sys.executable, "-c", "import carfeel; print(carfeel.__file__)"],
        capture_output=True, text=True, env=env, cwd=tree, check=True,
    )  # fmt: skip
    assert Path(probe.stdout.strip()).is_relative_to(tree)
    chosen = ["tests/test_public_api.py", "tests/test_import_rules.py", "tests/test_presets.py",
              "tests/test_telemetry.py"]  # fmt: skip
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-x", "-m", "not slow", "-p", "no:cacheprovider",
         *chosen],
        capture_output=True, text=True, env=env, cwd=tree, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert " passed" in done.stdout and " failed" not in done.stdout


def test_python_m_carfeel_answers_help():
    done = subprocess.run(
        [sys.executable, "-m", "carfeel", "--help"], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0
    assert "usage: carfeel" in done.stdout
