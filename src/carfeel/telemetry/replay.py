"""Sending a capture as the game would: fixed-size datagrams, concatenated in a file, sent at a
fixed rate; for Assetto Corsa, as its server (answer the handshake, stream after the subscribe,
stop on dismiss)."""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from carfeel.errors import InputError
from carfeel.telemetry.formats import (
    AC_DISMISS,
    AC_HANDSHAKE,
    AC_SUBSCRIBE_UPDATE,
    FORMATS,
    Format,
)

NATURAL_RATE_HZ = {"forza": 60.0, "assetto": 60.0, "f1": 60.0, "codemasters": 60.0,
                   "pcars": 30.0}  # fmt: skip
"""The games' usual send rates; 100 Hz for the rest (LFS, BeamNG, carfeel)."""


def datagram_size(path: Path, fmt: Format, size: int | None = None) -> int:
    """The capture's datagram size: given, or the one of the format's sizes that divides the
    file (the largest if several do)."""
    length = path.stat().st_size
    if size is not None:
        if length % size:
            raise InputError(f"{path}: {length} bytes is not a whole number of {size}-byte packets")
        return size
    fitting = [s for s in sorted(fmt.sizes) if length and length % s == 0]
    if not fitting:
        raise InputError(
            f"{path}: {length} bytes is not a whole number of {fmt.name} packets "
            f"({', '.join(map(str, sorted(fmt.sizes)))} bytes)"
        )
    return fitting[-1]


def datagrams(path: Path, size: int) -> list[bytes]:
    data = path.read_bytes()
    return [data[i : i + size] for i in range(0, len(data), size)]


def pcars_datagrams(path: Path) -> list[bytes]:
    """A Project CARS capture split by each datagram's type (the low 2 bits of its byte 2)."""
    from carfeel.telemetry.formats import PCARS_SIZES

    data = path.read_bytes()
    out: list[bytes] = []
    i = 0
    while i < len(data):
        size = PCARS_SIZES.get(data[i + 2] & 3) if i + 2 < len(data) else None
        if size is None or i + size > len(data):
            raise InputError(
                f"{path}: byte {i} does not start a Project CARS datagram (type "
                f"{data[i + 2] & 3 if i + 2 < len(data) else '?'}, {len(data) - i} bytes left)"
            )
        out.append(data[i : i + size])
        i += size
    return out


def paced(count: int, rate_hz: float) -> Iterator[int]:
    """Indices 0..count-1, each at its absolute deadline (sleep, so a late one does not shift
    the rest)."""
    start = time.perf_counter()
    for i in range(count):
        delay = start + i / rate_hz - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        yield i


def send(
    packets: list[bytes],
    to: tuple[str, int],
    rate_hz: float,
    sock: socket.socket | None = None,
    stop: Callable[[], bool] = lambda: False,
) -> int:
    """Send `packets` to `to` at `rate_hz`; return how many were sent."""
    own = sock is None
    s = sock or socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = 0
    try:
        for i in paced(len(packets), rate_hz):
            if stop():
                break
            s.sendto(packets[i], to)
            sent += 1
    finally:
        if own:
            s.close()
    return sent


def ac_response(car: str = "replay", driver: str = "carfeel", track: str = "capture") -> bytes:
    """The server's 408-byte handshake response: carName, driverName (wchar_t[50] each),
    identifier, version, trackName, trackConfig (wchar_t[50] each)."""

    def wide(text: str) -> bytes:
        return (text + "%").encode("utf-16-le").ljust(100, b"\0")

    return wide(car) + wide(driver) + struct.pack("<ii", 4242, 1) + wide(track) + wide("")


def serve_assetto(
    packets: list[bytes],
    bind: tuple[str, int],
    rate_hz: float,
    car: str = "replay",
    wait_s: float = 10.0,
    ready: Callable[[tuple[str, int]], None] | None = None,
) -> int:
    """Act as Assetto Corsa's telemetry server on `bind` for one client; return packets sent."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(bind)
        if ready is not None:
            ready(s.getsockname())
        s.settimeout(wait_s)
        client = None
        while True:
            try:
                data, address = s.recvfrom(64)
            except TimeoutError as exc:
                raise InputError(f"no Assetto Corsa client came within {wait_s:g} s") from exc
            if len(data) != 12:
                continue
            operation = struct.unpack("<iii", data)[2]
            if operation == AC_HANDSHAKE:
                client = address
                s.sendto(ac_response(car), address)
            elif operation == AC_SUBSCRIBE_UPDATE and address == client:
                break
        s.setblocking(False)
        dismissed = []

        def stop() -> bool:
            try:
                data, _ = s.recvfrom(64)
            except BlockingIOError:
                return False
            if len(data) == 12 and struct.unpack("<iii", data)[2] == AC_DISMISS:
                dismissed.append(True)
            return bool(dismissed)

        return send(packets, client, rate_hz, s, stop)


def lookup_format(name: str) -> Format:
    if name not in FORMATS:
        raise InputError(f"--format {name!r}: choose one of {', '.join(FORMATS)}")
    return FORMATS[name]
