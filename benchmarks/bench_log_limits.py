"""Hostile log inputs (issue 24, point 6): each refused with exit 2, how fast and in how much
memory, beside the same command on a small good log in the same run. Prints only.

Each case runs `carfeel` in a fresh Python process that reports its own peak resident memory
(VmHWM, Linux; a process's baseline, Python + numpy + carfeel, is the reference's). The files
are written to a scratch folder first (about 1.5 GB of disk for a moment; not timed).
    python benchmarks/bench_log_limits.py [--keep]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHILD = """
import sys, time
from carfeel.cli import main
t0 = time.perf_counter()
code = main(sys.argv[1:])
elapsed = time.perf_counter() - t0
# VmHWM: this process's peak resident memory (ru_maxrss would carry the parent's across fork)
status = open("/proc/self/status").read().split("VmHWM:")[1].split()[0]
print(f"@@{code} {elapsed:.4f} {status}", file=sys.stderr)
"""


def run(args: list[str]) -> tuple[int, float, float, str]:
    """(exit code, seconds inside main, peak RSS in MB, the message's first 160 characters)."""
    done = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True)
    lines = done.stderr.strip().splitlines()
    marker = next(line for line in reversed(lines) if line.startswith("@@"))
    code, seconds, peak = marker[2:].split()
    message = " ".join(line for line in lines if not line.startswith("@@"))
    return int(code), float(seconds), int(peak) / 1024.0, message[:160]


def build(folder: Path, repo: Path) -> dict[str, list[str]]:
    """The cases' files, and the command each is given to."""
    good = folder / "good.csv"
    t = np.arange(0.0, 60.0, 0.005)
    rows = ["time_s,speed_m_s,steering_angle_rad,lateral_accel_m_s2,torque_Nm"]
    rows += [f"{x:.3f},20.0,{0.05 * np.sin(x):.6f},{0.8 * np.sin(x):.6f},{1.5 * np.sin(x):.6f}"
             for x in t]  # fmt: skip
    good.write_text("\n".join(rows) + "\n")
    long_line = folder / "line.csv"
    with long_line.open("wb") as handle:  # a header, then one 1 GB line
        handle.write(b"time_s,torque_Nm\n")
        block = b"1" * (1 << 24)
        for _ in range(64):
            handle.write(block)
        handle.write(b",1\n")
    many = folder / "rows.csv"
    with many.open("w") as handle:  # 10 million rows of 1 kHz: 2.8 hours
        handle.write("time_s,speed_m_s,steering_angle_rad,lateral_accel_m_s2,torque_Nm\n")
        rest = ",20.0,0.01,0.5,1.0\n"
        for k in range(100):
            handle.write("".join(f"{(k * 100_000 + i) * 1e-3:.3f}{rest}" for i in range(100_000)))
    deep = folder / "deep.toml"
    deep.write_text("[channels]\nspeed_m_s = " + "[" * 100_000 + "]" * 100_000 + "\n")
    dbc = folder / "huge-scale.dbc"
    source = repo / "tests" / "data" / "can"
    dbc.write_text((source / "toyota-rav4-2017.dbc").read_text().replace(
        "SG_ STEER_ANGLE : 3|12@0- (1.5,0)", "SG_ STEER_ANGLE : 3|12@0- (1e308,0)"))  # fmt: skip
    import pyarrow as pa
    import pyarrow.parquet as pq

    text_time = folder / "text-time.parquet"
    pq.write_table(pa.table({"time_s": ["9" * 50_000_000, "1"], "speed_m_s": [1.0, 1.0]}),
                   text_time)  # fmt: skip
    can_log = str(source / "toyota-rav4-2017-highway.candump.log")
    return {
        "reference: metrics of a good 60 s log": ["metrics", "steering", str(good)],
        "a 1 GB CSV line": ["metrics", "steering", str(long_line)],
        "a 10-million-row CSV": ["metrics", "steering", str(many)],
        "a channel map nested 100k deep": [
            "metrics",
            "steering",
            str(good),
            "--channels",
            str(deep),
        ],
        "a DBC scale of 1e308": ["channels", can_log, "--dbc", str(dbc)],
        "a Parquet text time column of 50 MB": ["channels", str(text_time)],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--keep", action="store_true", help="keep the scratch files")
    args = parser.parse_args()
    repo = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as scratch:
        t0 = time.perf_counter()
        cases = build(Path(scratch), repo)
        print(f"files written in {time.perf_counter() - t0:.1f} s")
        results = {}
        print(f"{'case':40s} {'exit':>4s} {'s':>7s} {'peak MB':>8s}  message")
        for label, command in cases.items():
            code, seconds, peak, message = run(command)
            results[label] = {"exit": code, "seconds": seconds, "peak_MB": peak}
            print(f"{label:40s} {code:4d} {seconds:7.3f} {peak:8.1f}  {message}")
        if args.keep:
            print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
