"""One line of progress on a terminal, redrawn in place: the sweep's bar and a fit's evaluation
counter supply its text. Nothing is written when the stream (stderr) is not a terminal. A leaf:
it imports nothing of carfeel."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO


class Progress:
    """A line the caller's text redraws (`\\r`) on a terminal, at most every `every_s` s (0:
    at every call) and not before `delay_s` s have passed since it was made (0: at once)."""

    def __init__(
        self,
        stream: TextIO | None = None,
        *,
        enabled: bool = True,
        delay_s: float = 0.0,
        every_s: float = 0.0,
    ) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled and self.stream.isatty()
        self.delay_s, self.every_s = delay_s, every_s
        self.started = time.monotonic()
        self.shown = False
        """Whether a line was drawn."""
        self._drawn_at = 0.0

    def show(
        self, text: str | Callable[[], str], now: float | None = None, last: bool = False
    ) -> None:
        """Draw `text` (or what it returns: made only when drawn) over the line when due; the
        `last` one is due whenever the delay has passed. `now`: time.monotonic(), s."""
        if not self.enabled:
            return
        now = time.monotonic() if now is None else now
        if self.delay_s > 0.0 and now - self.started <= self.delay_s:
            return
        if not last and self.every_s > 0.0 and now - self._drawn_at <= self.every_s:
            return
        self._drawn_at, self.shown = now, True
        self.stream.write("\r" + (text if isinstance(text, str) else text()))
        self.stream.flush()

    def close(self, always: bool = False) -> None:
        """End the line (a newline) if one was drawn, or on a terminal `always`."""
        if self.shown or (always and self.enabled):
            self.stream.write("\n")
            self.stream.flush()
