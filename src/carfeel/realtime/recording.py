"""Recordings of a run: every sample, written in blocks by a writer thread, readable if killed.

The loop only appends a row to a list (well under a microsecond); every `block` rows the list
goes to a writer thread that formats it, writes it and flushes it, so a killed process leaves
whole blocks on disk (at most the last line cut short, which the reader drops). A JSON sidecar
(FILE.json) holds the metadata from the start, and the summary at the end.
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

BLOCK_ROWS = 500
YIELD_ROWS = 25
"""Rows the writer formats before it lets the loop thread have the GIL back."""


class Recorder:
    def __init__(
        self,
        path: Path,
        columns: Sequence[str],
        metadata: Mapping[str, Any],
        block: int = BLOCK_ROWS,
    ) -> None:
        self.path = path
        self.columns = tuple(columns)
        self.metadata = dict(metadata)
        self.block = block
        self.rows = 0
        self._pending: list[tuple[object, ...]] = []
        self._queue: queue.Queue[list[tuple[object, ...]] | None] = queue.Queue()
        self._file = path.open("w", encoding="utf-8", newline="")
        self._file.write(",".join(self.columns) + "\n")
        self._file.flush()
        self._write_sidecar()
        self._thread = threading.Thread(target=self._writer, name="carfeel-recorder", daemon=True)
        self._thread.start()

    @property
    def sidecar(self) -> Path:
        return self.path.with_suffix(".json")

    def _write_sidecar(self) -> None:
        text = json.dumps(self.metadata, indent=2, default=str) + "\n"
        tmp = self.sidecar.with_suffix(".json.tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, self.sidecar)

    def append(self, row: tuple[object, ...]) -> None:
        self._pending.append(row)
        if len(self._pending) >= self.block:
            self._queue.put(self._pending)
            self._pending = []

    def _writer(self) -> None:
        from carfeel.realtime.scheduling import background

        background()  # not on the loop's core at its priority (see `background`)
        while True:
            rows = self._queue.get()
            if rows is None:
                return
            # Formatted a few rows at a time, yielding the GIL between them: a whole block at
            # once kept the loop thread waiting 4-9 ms at every flush (0.4-1 ms this way).
            for first in range(0, len(rows), YIELD_ROWS):
                chunk = rows[first : first + YIELD_ROWS]
                self._file.write("".join(",".join(_text(v) for v in row) + "\n" for row in chunk))
                time.sleep(0)
            self._file.flush()
            self.rows += len(rows)

    def close(self, summary: Mapping[str, Any] | None = None) -> None:
        """Write what is left, close the file, and add the summary to the sidecar."""
        if self._pending:
            self._queue.put(self._pending)
            self._pending = []
        self._queue.put(None)
        self._thread.join()
        self._file.close()
        if summary is not None:
            self.metadata["summary"] = dict(summary)
            self._write_sidecar()


def _text(value: object) -> str:
    if isinstance(value, float):
        return format(value, ".9g")
    return str(value)
