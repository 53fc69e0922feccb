"""The wall-clock loop with a recording (issue 27's recorder beside the loop): overruns and
period errors of `carfeel run --model shift` on the virtual joystick without `--record`, with
it, and with it but its writer thread left where it was born (on the loop's core at the loop's
SCHED_FIFO priority: the defect `scheduling.background` ends), each run in a child process, in
alternating rounds so that all three see the same load. Prints numbers; asserts nothing.
    python benchmarks/bench_recording.py [--seconds 10] [--rounds 2]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile

from measure import busy_s

CHILD = """
import sys
if sys.argv[1] == "inherited":  # the writer's start calls this: make it do nothing
    import carfeel.realtime.scheduling as scheduling
    scheduling.background = lambda: ""
from carfeel.cli import main
sys.exit(main(sys.argv[2:]))
"""
LINE = re.compile(r"(\d+) overruns .*p99 ([\d.]+) us, max ([\d.]+) us")


def run(kind: str, seconds: float, folder: str) -> str:
    args = ["run", "--model", "shift", "--duration", str(seconds)]
    if kind != "none":
        args += ["--record", os.path.join(folder, f"{kind}.csv")]
    before = busy_s()
    done = subprocess.run([sys.executable, "-c", CHILD, kind, *args], capture_output=True,
                          text=True, timeout=seconds * 10 + 120)  # fmt: skip
    others = busy_s() - before
    found = LINE.search(done.stdout + done.stderr)
    if found is None:
        return f"exit {done.returncode}: {(done.stdout + done.stderr).strip()[-300:]}"
    n, p99, peak = found.groups()
    return (f"{int(n):4d} overruns ({int(n) / seconds:.1f}/s), period error p99 {float(p99):7.1f}"
            f" us, max {float(peak):8.1f} us; machine {others:.1f} CPU-s meanwhile")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start")
    with tempfile.TemporaryDirectory() as folder:
        for r in range(args.rounds):
            print(f"round {r + 1}, {args.seconds:g} s each")
            for kind, text in (("none", "no recording     "), ("own", "recording        "),
                               ("inherited", "writer inherited ")):  # fmt: skip
                print(f"   {text} {run(kind, args.seconds, folder)}")
    print(f"load average {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    main()
