"""The marks of the tests that build the FMU's C with gcc's flags for Linux x86-64 (elsewhere the
export takes FMPy's CMake build, which those tests do not check)."""

from __future__ import annotations

import shutil

import pytest

GCC_BUILD = [
    pytest.mark.skipif(
        shutil.which("cc") is None and shutil.which("gcc") is None,
        reason="no C compiler (make test installs gcc)",
    ),
    pytest.mark.linux_only,
    pytest.mark.needs_tools,
]
