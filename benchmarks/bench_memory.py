"""The memory of a long 1 kHz session (issue 27): a simulated session of a minute and one of an
hour (or `--long-s`), each in a fresh process, their peak resident memory (VmHWM) side by side:
the minute is the reference. Linux only (VmHWM). Asserts nothing; the numbers go in notes.
    python benchmarks/bench_memory.py [--long-s 3600] [--model steering] [--device virtual:wheel]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

SCRIPT = """
import json, sys
from carfeel.realtime.session import RealtimeRun, run_realtime
record = sys.argv[4] if len(sys.argv) > 4 and sys.argv[4] else None
run = RealtimeRun(model=sys.argv[1], device=sys.argv[2], clock="simulated", hand="none",
                  duration_s=float(sys.argv[3]), speed_kmh=60.0, record=record)
result = run_realtime(run)
peak = 0
with open("/proc/self/status") as status:
    for line in status:
        if line.startswith("VmHWM:"):
            peak = int(line.split()[1])
print(json.dumps({"peak_kb": peak, "periods": result.summary.periods}))
"""


def session(model: str, device: str, seconds: float, record: str) -> tuple[int, int, float]:
    env = {**os.environ, "CARFEEL_CONFIG_DIR": tempfile.mkdtemp(prefix="carfeel-bench-")}
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", SCRIPT, model, device, str(seconds), record],
                         capture_output=True, text=True, check=True, env=env)  # fmt: skip
    took = time.perf_counter() - start
    data = json.loads(out.stdout.strip().splitlines()[-1])
    return int(data["peak_kb"]), int(data["periods"]), took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--long-s", type=float, default=3600.0)
    parser.add_argument("--model", default="steering")
    parser.add_argument("--device", default="virtual:wheel")
    parser.add_argument("--record", action="store_true", help="record both sessions to CSV")
    args = parser.parse_args()
    folder = tempfile.mkdtemp(prefix="carfeel-bench-")
    print(f"a simulated session of {args.model} on {args.device}, hands off, 60 km/h; peak RSS")
    rows = []
    for seconds in (60.0, args.long_s):
        record = os.path.join(folder, f"s{seconds:g}.csv") if args.record else ""
        peak, periods, took = session(args.model, args.device, seconds, record)
        rows.append(peak)
        print(f"  {seconds:7.0f} s: {periods:8d} periods, peak {peak / 1024:7.1f} MB "
              f"({took:6.1f} s to run)")  # fmt: skip
    print(f"  the long session holds {(rows[1] - rows[0]) / 1024:+.1f} MB beside the minute's")


if __name__ == "__main__":
    main()
