"""The recordings the tests stand on, vendored under `tests/data/` with their licences.

A clone tests itself: nothing here reads `../shared` or a machine path. A missing file is a
failure, never a skip (the files are part of the repository; a test without its data proves
nothing).
"""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parent / "data"


def data_file(*parts: str) -> Path:
    """The vendored file `tests/data/PARTS...`; the test fails if it is not there."""
    path = DATA.joinpath(*parts)
    if not path.is_file():
        pytest.fail(
            f"test data {path.relative_to(DATA.parent)} is missing: it is part of the "
            "repository (see tests/data/README.md)",
            pytrace=False,
        )
    return path
