"""Memory of long simulations (issue 27): `carfeel simulate hpattern / shift / steering` of a
short run (the reference) and a long one, each in a child process of its own: its wall time and
its own peak resident memory (VmHWM as it exits), with and without --plot. Prints numbers;
asserts nothing.

    python benchmarks/bench_simulate.py [--long-s 1000]

The H-pattern's length is set by its sequence (about 1.02 s a gear, 10.8 s for
N,1,2,3,4,5,4,3,2,1,N); the steering's by its step (--dt) through ISO 7401's step (5 s).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
from pathlib import Path

from measure import child

CYCLE_S = 10.23
"""Simulated seconds of each 1,2,3,4,5,4,3,2,1,N after the first N (the README's sequence)."""


def hpattern(seconds: float) -> list[str]:
    cycles = max(1, round(seconds / CYCLE_S))
    return ["hpattern", "--sequence", "N," + ",".join(["1,2,3,4,5,4,3,2,1,N"] * cycles)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--long-s", type=float, default=1000.0, help="the long run, s (1000)")
    args = parser.parse_args()
    print(
        f"CPython {platform.python_version()} on {platform.machine()}, {sys.platform}, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start"
    )
    long_s = args.long_s
    runs = {
        "hpattern": (hpattern(10.0), hpattern(long_s)),
        "shift": (["shift", "--duration", "10"], ["shift", "--duration", f"{long_s:g}"]),
        # ISO 7401's step lasts 5 s: --dt sets the samples (1 ms: 5,000).
        "steering": (
            ["steering", "--manoeuvre", "iso7401-step", "--dt", "0.001"],
            ["steering", "--manoeuvre", "iso7401-step", "--dt", f"{5.0 / (long_s * 1000):.3g}"],
        ),
    }
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "run.csv"
        for model, (short, long) in runs.items():
            for plot in (False, True):
                extra = ["--plot", str(Path(folder) / "run.png")] if plot else []
                lines = []
                for label, command in (("short", short), ("long", long)):
                    run = child(["-m", "carfeel.cli", "simulate", *command, "--out", str(out),
                                 *extra])  # fmt: skip
                    samples = sum(1 for _ in out.open()) - 1 if run.code == 0 else 0
                    lines.append((label, samples, out.stat().st_size / 1e6, run))
                for label, samples, size, run in lines:
                    print(
                        f"{model:8s} {'--plot ' if plot else '       '}{label:5s} "
                        f"{samples:9,d} samples ({size:6.1f} MB of CSV) {run.line()}"
                    )
                (_, n0, _, short_run), (_, n1, _, long_run) = lines
                print(
                    f"         growth {(long_run.peak_MB - short_run.peak_MB):+.1f} MB for "
                    f"{n1 - n0:,d} more samples "
                    f"({(long_run.peak_MB - short_run.peak_MB) * 1e6 / max(n1 - n0, 1):.1f} "
                    "bytes a sample)"
                )
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
