"""A knob force against time from a CSV file (time_s, force_N): read and checked once."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from carfeel.errors import InputError

MAX_FORCE_N = 1000.0
"""Beyond this a knob force is not a hand's: most likely another unit."""

_HOW = "a CSV file with a header line naming time_s and force_N and one sample per line"


def read_force_profile(path: Path) -> tuple[list[float], list[float]]:
    """(time_s, force_N) of a force profile; InputError naming the problem and its fix."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"force profile {path} not found; give {_HOW}") from None
    except IsADirectoryError:
        raise InputError(f"force profile {path} is a folder; give {_HOW}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"force profile {path} cannot be read ({exc}); give {_HOW}") from None
    rows = [
        (number, row)
        for number, row in enumerate(csv.reader(text.splitlines()), start=1)
        if row and row[0].strip() and not row[0].startswith("#")
    ]
    if not rows:
        raise InputError(f"force profile {path} is empty; give {_HOW}")
    header = [name.strip() for name in rows[0][1]]
    missing = [name for name in ("time_s", "force_N") if name not in header]
    if missing:
        raise InputError(
            f"force profile {path}: no column {' or '.join(missing)} in its header "
            f"({', '.join(header)}); give {_HOW}"
        )
    it, iforce = header.index("time_s"), header.index("force_N")
    times: list[float] = []
    forces: list[float] = []
    for line, row in rows[1:]:
        values = []
        for index, name in ((it, "time_s"), (iforce, "force_N")):
            cell = row[index].strip() if index < len(row) else ""
            try:
                value = float(cell)
            except ValueError:
                raise InputError(
                    f"force profile {path}, line {line}: {name} = {cell!r} is not a number"
                ) from None
            if not math.isfinite(value):
                raise InputError(
                    f"force profile {path}, line {line}: {name} = {cell} is not finite"
                )
            values.append(value)
        t, f = values
        if times and not t > times[-1]:
            raise InputError(
                f"force profile {path}, line {line}: time_s = {t:g} s does not follow "
                f"{times[-1]:g} s; times must increase"
            )
        if abs(f) > MAX_FORCE_N:
            raise InputError(
                f"force profile {path}, line {line}: force_N = {f:g} N is beyond "
                f"+-{MAX_FORCE_N:g} N; give the knob force in N"
            )
        times.append(t)
        forces.append(f)
    if len(times) < 2:
        raise InputError(f"force profile {path} has {len(times)} sample(s); give at least two")
    if times[0] < 0.0:
        raise InputError(
            f"force profile {path}: time_s starts at {times[0]:g} s; the run starts at 0 s"
        )
    return times, forces
