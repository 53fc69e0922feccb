"""The sizes a log may have, and what a message about one may quote.

Sizes are checked before anything is allocated: a file beyond them is refused with the limit
named. The readers look the limits up here when they run (`log_limits.MAX_SAMPLES`), so a test
may lower one with monkeypatch.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable
from pathlib import Path

from carfeel.errors import InputError

MAX_SAMPLES = 4_000_000
"""Most samples of one signal (67 min at 1 kHz, 5.5 h at 200 Hz): a fit holds a few arrays of
this length per parameter; a longer log is cut or resampled first."""
MAX_VALUES = 24_000_000
"""Most numbers read from one file at once (192 MB as float64): rows x the columns read."""
MAX_LINE_BYTES = 1 << 20
"""Longest CSV line (1 MiB: a header of 30,000 channel names)."""
MAX_MAP_BYTES = 1 << 20
"""Largest channel map (1 MiB; one is a few hundred bytes)."""
MAX_DBC_BYTES = 64 << 20
"""Largest DBC file (a car's whole bus is a few MB)."""
MAX_CAN_FRAMES = 40_000_000
"""Most frames read from a CAN log (3.5 h of a busy 500 kbit/s bus)."""
MAX_RAW_VALUE = 1e15
"""A decoded or converted value beyond this is not a measurement (a DBC scale of 1e308 made
every sample infinite); refused with the signal named."""
MAX_NAME_SHOWN = 80
"""Names and cells quoted in messages are cut to this many characters (a file's text is data:
a 50 MB cell must not come back in an error)."""


def shown(text: object) -> str:
    """`text` as a message may quote it: cut to MAX_NAME_SHOWN characters, quoted."""
    value = str(text)
    if len(value) > MAX_NAME_SHOWN:
        value = value[:MAX_NAME_SHOWN] + f"... ({len(value)} characters)"
    return repr(value)


def close(name: str, known: Iterable[str]) -> str:
    """A message's " (did you mean 'X'?)" for the known name closest to `name`, or ""."""
    match = difflib.get_close_matches(name[:200], [k[:200] for k in known], n=1)
    return f" (did you mean {shown(match[0])}?)" if match else ""


def byte_size(size: int) -> str:
    """A size as a message gives it: MiB, KiB or bytes."""
    for shift, unit in ((20, "MiB"), (10, "KiB")):
        if size >= 1 << shift and size % (1 << shift) == 0:
            return f"{size >> shift} {unit}"
    return f"{size:,} bytes"


def too_many(path: Path, what: str, found: str, limit: int) -> InputError:
    """The error for a log beyond one of the limits (`what` 'has', 'holds'; `found` the count)."""
    return InputError(
        f"{path}: {what} {found}, beyond the {limit:,} carfeel reads from one log: cut the log "
        "into parts (or resample it) and give them one by one"
    )
