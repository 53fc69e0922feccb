"""The fuzz of a page layout's file image, shared by the shared-memory games' tests."""

from __future__ import annotations

import random
from collections.abc import Callable

from carfeel.telemetry import pages
from carfeel.telemetry.state import VehicleState, plausible


def fuzz_pages(
    layout: pages.PageLayout,
    base: bytes,
    span: int,
    seed: object,
    trials: int,
    check: Callable[[VehicleState], None] = lambda s: None,
) -> tuple[int, int]:
    """Bytes flipped within the first `span` (1, a few or many a trial; every tenth trial all of
    them random): the reader is refused at open with a reason (ValueError), or it reads and
    never raises; `check` is run on every state it keeps. Returns (kept, refused)."""
    rng = random.Random(str(seed))
    kept = refused = 0
    for trial in range(trials):
        data = bytearray(base)
        for _ in range(rng.choice((1, 16, 256))):
            data[rng.randrange(span)] = rng.randrange(256)
        if trial % 10 == 0:
            data[:span] = rng.randbytes(span)
        try:
            reader = pages.PagesReader(layout, (bytes(data),), True)
        except ValueError:
            refused += 1
            continue
        for s in reader.read(0.0):
            if s is not None and plausible(s):
                kept += 1
                check(s)
    return kept, refused
