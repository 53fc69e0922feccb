"""A command's peak memory, measured in a child process of its own (never pytest's)."""

from __future__ import annotations

import subprocess
import sys

PEAK = (
    "import atexit, sys\n"
    "def peak():\n"
    "    hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')]\n"
    "    sys.stderr.write('peak ' + hwm[0].split()[1] + ' kB\\n')\n"
    "atexit.register(peak)\n"
    "from carfeel.cli import main\n"
    "sys.exit(main(sys.argv[1:]))\n"
)
"""`carfeel ARGS` that says its peak memory as it exits: VmHWM, the process's own (a child's
ru_maxrss counts its parent's memory at the fork, pytest's hundreds of MB after Dask)."""


def carfeel_peak(
    args: list[str], timeout_s: float = 300.0
) -> tuple[subprocess.CompletedProcess[str], int]:
    """(the finished child, its peak resident memory in kB) of `carfeel ARGS` (Linux: it reads
    /proc/self/status)."""
    done = subprocess.run(
        [sys.executable, "-c", PEAK, *args],
        capture_output=True, text=True, timeout=timeout_s, check=False,
    )  # fmt: skip
    said = done.stderr.rsplit("peak ", 1)
    assert len(said) == 2, done.stderr
    return done, int(said[1].split()[0])
