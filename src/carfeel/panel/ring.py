"""The shared memory between the loop's process and the panel's: rows, events, commands, status.

One segment, created by the panel (the one place that creates and unlinks it), attached by the
loop's process. Every region has a single writer and a single reader and is lock-free: the
writer fills a slot, then publishes it by raising a counter; the reader copies what the counter
says is there and checks afterwards that the writer has not lapped it. Nothing waits.

    header    counters (u64): rows written, events written, commands written, commands read,
              status version (odd while the loop writes it)
    status    STATUS float64 fields, written by the loop at display rate
    rows      ROW_CAPACITY rows of MAX_COLUMNS float64: each tick's recorded row (strings coded)
    events    loop -> panel: pickled messages (ready, vocabulary, tuned, recorded, ended)
    commands  panel -> loop: pickled messages (stop, retune, record); the loop takes at most one
              a tick, the panel never writes more than COMMAND_SLOTS ahead of it

The loop's side uses only `struct` (no numpy on the loop's import path); the panel's side reads
the rows with numpy. On Python 3.11 a process attaching to a segment registers it with the
resource tracker, which unlinks what is left registered when its last user exits: the loop's
process is spawned by multiprocessing and shares the panel's tracker, so its registration is the
panel's own (a set) and the panel's `unlink` removes it; unregistering in the child would
unregister the panel's too (and the tracker would complain at the panel's unlink).
"""

from __future__ import annotations

import pickle
import struct
import threading
from multiprocessing import shared_memory
from typing import Any

MAGIC = 0x4C524643  # "CFRL"
VERSION = 1
MAX_COLUMNS = 64
ROW_CAPACITY = 8192
"""8 s of rows at 1 kHz: the panel reads at 30 Hz, so it is lapped only after 8 s of stall."""
EVENT_SLOTS = 64
EVENT_SLOT_BYTES = 32768
COMMAND_SLOTS = 16
COMMAND_SLOT_BYTES = 65536

STATUS = (
    "time_s",
    "guard_rms",
    "guard_limit_rms",
    "guard_held_s",
    "guard_hold_s",
    "passivity_acted_s",
    "passivity_energy",
    "faulted",
    "tune_pending",
    "tune_ramp",
    "recording",
    "recorded_rows",
    "calibrating",
    "telemetry_age_s",
    "telemetry_latency_s",
    "telemetry_latency_p99_s",
)
"""The status fields, in order (see `worker.Observer._status`)."""

_U64 = struct.Struct("<Q")
_HEADER = struct.Struct("<IIII")
_SLOT_LEN = struct.Struct("<I")
ROWS_WRITTEN, EVENTS_WRITTEN, COMMANDS_WRITTEN, COMMANDS_READ, STATUS_VERSION = (
    16,
    24,
    32,
    40,
    48,
)
STATUS_OFFSET = 64
ROWS_OFFSET = STATUS_OFFSET + 8 * 32
ROW_BYTES = 8 * MAX_COLUMNS
EVENTS_OFFSET = ROWS_OFFSET + ROW_CAPACITY * ROW_BYTES
COMMANDS_OFFSET = EVENTS_OFFSET + EVENT_SLOTS * EVENT_SLOT_BYTES
SIZE = COMMANDS_OFFSET + COMMAND_SLOTS * COMMAND_SLOT_BYTES


class RingError(RuntimeError):
    """A segment that is not a panel's, or a message too large for its slot."""


def _buffer(shm: shared_memory.SharedMemory) -> memoryview:
    buf = shm.buf
    if buf is None:  # pragma: no cover - a closed segment
        raise RingError(f"shared memory {shm.name} is closed")
    return buf


def create() -> shared_memory.SharedMemory:
    """A new, zeroed segment (the panel's; it unlinks it when the session is over)."""
    shm = shared_memory.SharedMemory(create=True, size=SIZE)
    buf = _buffer(shm)
    buf[:STATUS_OFFSET] = bytes(STATUS_OFFSET)
    _HEADER.pack_into(buf, 0, MAGIC, VERSION, ROW_CAPACITY, MAX_COLUMNS)
    return shm


def attach(name: str) -> shared_memory.SharedMemory:
    shm = shared_memory.SharedMemory(name=name)
    magic, version, *_ = _HEADER.unpack_from(_buffer(shm), 0)
    if magic != MAGIC or version != VERSION:
        shm.close()
        raise RingError(f"shared memory {name} is not a carfeel panel's (version {VERSION})")
    return shm


def _put(buf: Any, offset: int, size: int, message: object) -> None:
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    if len(data) + _SLOT_LEN.size > size:
        raise RingError(f"a message of {len(data)} bytes does not fit a {size}-byte slot")
    _SLOT_LEN.pack_into(buf, offset, len(data))
    buf[offset + 4 : offset + 4 + len(data)] = data


def _get(buf: Any, offset: int) -> Any:
    (length,) = _SLOT_LEN.unpack_from(buf, offset)
    return pickle.loads(bytes(buf[offset + 4 : offset + 4 + length]))


class LoopSide:
    """The loop's end: writes rows, events and status, takes commands. `struct` only."""

    def __init__(self, shm: shared_memory.SharedMemory, columns: int) -> None:
        if columns > MAX_COLUMNS:
            raise RingError(f"{columns} columns: a panel's ring holds at most {MAX_COLUMNS}")
        self.shm = shm
        self.buf: memoryview = _buffer(shm)
        self.columns = columns
        self._row = struct.Struct(f"<{columns}d")
        self._status = struct.Struct(f"<{len(STATUS)}d")
        self._rows = 0
        self._events = _U64.unpack_from(self.buf, EVENTS_WRITTEN)[0]
        self._read = _U64.unpack_from(self.buf, COMMANDS_READ)[0]
        self._status_version = 0
        self._lock = threading.Lock()
        """Events come from the loop's thread and from the recorder's helper threads."""

    def row(self, values: Any) -> None:
        """One tick's row (floats; the loop's thread only)."""
        k = self._rows
        self._row.pack_into(self.buf, ROWS_OFFSET + (k % ROW_CAPACITY) * ROW_BYTES, *values)
        self._rows = k + 1
        _U64.pack_into(self.buf, ROWS_WRITTEN, k + 1)

    def event(self, message: object) -> None:
        with self._lock:
            k = self._events
            _put(self.buf, EVENTS_OFFSET + (k % EVENT_SLOTS) * EVENT_SLOT_BYTES, EVENT_SLOT_BYTES,
                 message)  # fmt: skip
            self._events = k + 1
            _U64.pack_into(self.buf, EVENTS_WRITTEN, k + 1)

    def status(self, values: Any) -> None:
        v = self._status_version
        _U64.pack_into(self.buf, STATUS_VERSION, v + 1)  # odd: being written
        self._status.pack_into(self.buf, STATUS_OFFSET, *values)
        self._status_version = v + 2
        _U64.pack_into(self.buf, STATUS_VERSION, v + 2)

    def command(self) -> Any:
        """The next command, or None (one at most: a bounded cost per tick)."""
        if _U64.unpack_from(self.buf, COMMANDS_WRITTEN)[0] <= self._read:
            return None
        k = self._read
        message = _get(self.buf, COMMANDS_OFFSET + (k % COMMAND_SLOTS) * COMMAND_SLOT_BYTES)
        self._read = k + 1
        _U64.pack_into(self.buf, COMMANDS_READ, k + 1)
        return message

    def close(self) -> None:
        del self.buf
        self.shm.close()


class PanelSide:
    """The panel's end: reads rows (numpy), events and status; sends commands."""

    def __init__(self, shm: shared_memory.SharedMemory) -> None:
        import numpy as np

        self._np = np
        self.shm = shm
        self.buf: memoryview = _buffer(shm)
        self.rows = np.ndarray(
            (ROW_CAPACITY, MAX_COLUMNS), dtype="<f8", buffer=self.buf, offset=ROWS_OFFSET
        )
        self._events_read = 0
        self._lock = threading.Lock()

    def _counter(self, offset: int) -> int:
        value: int = _U64.unpack_from(self.buf, offset)[0]
        return value

    @property
    def rows_written(self) -> int:
        return self._counter(ROWS_WRITTEN)

    def read_rows(self, cursor: int, columns: int) -> tuple[Any, int, int]:
        """(rows since `cursor` still in the ring, the new cursor, rows lost to lapping)."""
        np = self._np
        end = self.rows_written
        start = max(cursor, end - ROW_CAPACITY + 64)  # keep clear of the slot being written
        if start >= end:
            return np.empty((0, columns)), end, 0
        index = np.arange(start, end) % ROW_CAPACITY
        block = self.rows[index, :columns].copy()
        after = self.rows_written
        stale = max(0, after - ROW_CAPACITY + 1 - start)  # overwritten while we copied
        lost = start - cursor + min(stale, end - start)
        return block[stale:], end, lost

    def events(self) -> list[Any]:
        """The events since the last call; a panel lapped by more than EVENT_SLOTS loses the
        oldest (said by a ("lost", n) event)."""
        end = self._counter(EVENTS_WRITTEN)
        out: list[Any] = []
        start = max(self._events_read, end - EVENT_SLOTS + 1)
        if start > self._events_read:
            out.append(("lost", start - self._events_read))
        for k in range(start, end):
            out.append(_get(self.buf, EVENTS_OFFSET + (k % EVENT_SLOTS) * EVENT_SLOT_BYTES))
        self._events_read = end
        return out

    def status(self) -> dict[str, float] | None:
        """The latest status, or None before the loop has written one."""
        fmt = struct.Struct(f"<{len(STATUS)}d")
        for _ in range(8):
            before = self._counter(STATUS_VERSION)
            if before == 0:
                return None
            values = fmt.unpack_from(self.buf, STATUS_OFFSET)
            if before % 2 == 0 and self._counter(STATUS_VERSION) == before:
                return dict(zip(STATUS, values, strict=True))
        return None

    def send(self, message: object) -> bool:
        """Queue a command for the loop; False when the loop has COMMAND_SLOTS unread (it is
        not taking them: stalled or gone)."""
        with self._lock:
            written = self._counter(COMMANDS_WRITTEN)
            if written - self._counter(COMMANDS_READ) >= COMMAND_SLOTS:
                return False
            _put(self.buf, COMMANDS_OFFSET + (written % COMMAND_SLOTS) * COMMAND_SLOT_BYTES,
                 COMMAND_SLOT_BYTES, message)  # fmt: skip
            _U64.pack_into(self.buf, COMMANDS_WRITTEN, written + 1)
            return True

    def close(self) -> None:
        del self.rows, self.buf
        self.shm.close()
