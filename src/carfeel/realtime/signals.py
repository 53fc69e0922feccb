"""A run's signal handling: Ctrl-C and SIGTERM become a stop request the loop polls."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def stop_on_signals() -> Iterator[list[str]]:
    """Ctrl-C and SIGTERM ask the loop to stop (it zeroes the force first); the list holds the
    signal's name once one came."""
    flag: list[str] = []

    def handler(signum: int, frame: Any) -> None:
        if not flag:
            flag.append(signal.Signals(signum).name)

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
