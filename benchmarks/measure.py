"""What the benchmarks measure a command by: its wall time, its own peak memory, and the CPU
the machine's other users took meanwhile (this machine's 2 cores are shared)."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import time
from dataclasses import dataclass

PEAK = (
    "import atexit, runpy, sys\n"
    "def peak():\n"
    "    hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')]\n"
    "    sys.stderr.write('peak ' + hwm[0].split()[1] + ' kB\\n')\n"
    "atexit.register(peak)\n"
    "args = sys.argv[1:]\n"
    "if args[0] == '-c':\n"
    "    sys.argv = ['-c', *args[2:]]\n"
    "    exec(compile(args[1], '<child>', 'exec'), {'__name__': '__main__'})\n"
    "else:\n"
    "    sys.argv = args\n"
    "    runpy.run_module(args[0], run_name='__main__', alter_sys=True)\n"
)
"""Runs `-m MODULE ARGS` or `-c CODE ARGS` and says its own peak memory (VmHWM) as it exits: a
child's ru_maxrss would count its parent's memory at the fork too."""


def busy_s() -> float:
    """CPU-seconds the whole machine has spent busy (user, nice, system, irq, softirq, steal)
    since it started, from /proc/stat."""
    with open("/proc/stat") as handle:
        fields = [int(v) for v in handle.readline().split()[1:]]
    user, nice, system, _idle, _iowait, irq, softirq, steal = fields[:8]
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class Measured:
    code: int
    wall_s: float
    peak_MB: float
    """The command's own peak resident memory (its workers are processes of their own)."""
    cpu_s: float
    """CPU-seconds of the command and every process it started and waited for."""
    others_s: float
    """CPU-seconds the machine spent on everything else meanwhile."""
    load: tuple[float, float]
    """The 1-minute load average before and after."""
    stderr: str

    def cores_left(self) -> float:
        """How many of the machine's cores the others left, on average, during the command."""
        return (os.cpu_count() or 1) - self.others_s / self.wall_s

    def line(self) -> str:
        return (
            f"exit {self.code}  {self.wall_s:6.1f} s  peak {self.peak_MB:6.1f} MB  "
            f"CPU {self.cpu_s:6.1f} s; the others took {self.others_s:5.1f} CPU-s "
            f"({self.cores_left():.2f} cores left); load {self.load[0]:.1f} -> {self.load[1]:.1f}"
        )


def child(command: list[str]) -> Measured:
    """`python -m MODULE ...` or `python -c CODE ...` (given without the interpreter) run as a
    child process, measured."""
    load0 = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    busy0 = busy_s()
    t0 = time.perf_counter()
    arguments = command[1:] if command[0] == "-m" else command
    done = subprocess.run([sys.executable, "-c", PEAK, *arguments], capture_output=True,
                          text=True, check=False)  # fmt: skip
    wall = time.perf_counter() - t0
    busy = busy_s() - busy0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    said = done.stderr.rsplit("peak ", 1)
    peak = float(said[1].split()[0]) / 1024 if len(said) == 2 else float("nan")
    others = max(busy - cpu, 0.0)
    return Measured(done.returncode, wall, peak, cpu, others, (load0, os.getloadavg()[0]),
                    done.stderr)  # fmt: skip
