"""The UDP receiver: a non-blocking socket drained each tick, never blocking the loop.

Why not a thread: the latest-value handoff a thread needs costs a lock or a GIL hand-over on the
loop's side anyway, and the thread wakes the loop's core 60-1000 times a second; draining a
non-blocking socket costs one failing `recv_into` (about 1 us) on a tick with nothing and about
2 us a datagram (`benchmarks/bench_telemetry.py` measures it). A flood cannot slow the loop: at
most `MAX_PER_POLL` datagrams are read a tick, and the kernel's receive buffer is kept small so
that what waits is recent (the rest is dropped by the kernel, not by us).
"""

from __future__ import annotations

import contextlib
import errno
import math
import socket
import time
from dataclasses import dataclass

from carfeel.errors import InputError
from carfeel.telemetry.formats import (
    AC_DISMISS,
    AC_HANDSHAKE,
    AC_RESPONSE_SIZE,
    AC_SUBSCRIBE_UPDATE,
    FORMATS,
    Format,
    ac_car_name,
    ac_request,
    outsim_pack2,
)
from carfeel.telemetry.state import VehicleState, plausible

MAX_PER_POLL = 64
RECEIVE_BUFFER_BYTES = 64 * 1024
AC_RETRY_S = 1.0
"""Assetto Corsa: the handshake is sent again every second until the game answers."""


@dataclass(frozen=True, slots=True)
class Source:
    """`FORMAT:HOST:PORT` (or `FORMAT:PORT`, on 127.0.0.1), checked once. Port 0 listens on
    any free port (`Receiver.address` says which)."""

    format: Format
    host: str
    port: int

    @classmethod
    def parse(cls, text: str) -> Source:
        name, _, rest = text.partition(":")
        base, at, options = name.partition("@")
        if base == "outsim" and at:  # OutSimPack2: outsim@OPTS, OPTS as in LFS's cfg.txt (hex)
            try:
                pack2 = outsim_pack2(int(options, 16))
            except ValueError as exc:
                raise InputError(
                    f"telemetry source {text!r}: outsim@OPTS takes LFS's OutSim Opts in hex, "
                    f"with OSMain (8) among them, e.g. outsim@1ff ({exc})"
                ) from exc
            return cls._address(text, pack2, rest)
        if name not in FORMATS:
            raise InputError(
                f"telemetry source {text!r}: the format {name!r} is not one of "
                f"{', '.join(FORMATS)} (SOURCE is FORMAT:HOST:PORT, e.g. forza:0.0.0.0:5300)"
            )
        return cls._address(text, FORMATS[name], rest)

    @classmethod
    def _address(cls, text: str, fmt: Format, rest: str) -> Source:
        host, _, port_text = rest.rpartition(":")
        if not rest:
            port_text = str(fmt.default_port)
        host = host or "127.0.0.1"
        if not port_text.isdigit() or not 0 <= int(port_text) < 65536:
            raise InputError(
                f"telemetry source {text!r}: the port {port_text!r} is not a number 0..65535"
            )
        if fmt.name == "assetto" and int(port_text) == 0:
            raise InputError(f"telemetry source {text!r}: give the game's port (9996)")
        try:
            socket.getaddrinfo(host, None, socket.AF_INET, socket.SOCK_DGRAM)
        except OSError as exc:
            raise InputError(f"telemetry source {text!r}: unknown host {host!r} ({exc})") from exc
        return cls(fmt, host, int(port_text))


class Receiver:
    """Receive one source's datagrams; `poll()` reads what waits and keeps the latest good state.

    Counters: `packets` (decoded to a state that passed the checks), `bad` (wrong size, failing
    the checks, NaN where it must not be) and `ignored` (no vehicle state: other packet types, a
    paused game). `poll` returns how many good states arrived since the last call.
    """

    def __init__(self, source: Source) -> None:
        self.source = source
        self.format = source.format
        self.latest = VehicleState()
        self.packets = self.bad = self.ignored = 0
        self.arrival_ns = 0
        """time.monotonic_ns() of the poll that saw the latest good state (for the benchmark)."""
        self._buffer = bytearray(2048)
        self._view = memoryview(self._buffer)
        self.car = ""
        self.subscribed = False
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
        self._assetto = source.format.name == "assetto"
        try:
            # Assetto Corsa is a server: we are its client on any local port.
            sock.bind(
                ("0.0.0.0" if self._assetto else source.host, 0 if self._assetto else source.port)
            )
        except OSError as exc:
            sock.close()
            why = "in use" if exc.errno == errno.EADDRINUSE else str(exc)
            raise InputError(
                f"telemetry source {source.format.name}:{source.host}:{source.port}: cannot "
                f"listen there ({why})"
            ) from exc
        sock.setblocking(False)
        self.socket = sock
        self.bound = self.address
        """Where it listens (port 0 given: the one the system chose)."""
        self._sent_s = -math.inf
        if self._assetto:
            self._handshake()

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.socket.getsockname()[:2]
        return str(host), int(port)

    def _send_to_game(self, operation: int) -> None:
        # The game may not be there yet: the handshake is sent again later.
        with contextlib.suppress(OSError):
            self.socket.sendto(ac_request(operation), (self.source.host, self.source.port))
        self._sent_s = time.monotonic()

    def _handshake(self) -> None:
        self._send_to_game(AC_HANDSHAKE)

    def poll(self) -> int:
        fresh = 0
        fmt = self.format
        sizes, decode, other = fmt.sizes, fmt.decode, fmt.other_sizes
        recv = self.socket.recv_into
        view = self._view
        latest = self.latest
        for _ in range(MAX_PER_POLL):
            try:
                n = recv(self._buffer)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP port unreachable from an earlier send to the game
                continue
            if n not in sizes:
                if self._assetto and n == AC_RESPONSE_SIZE:
                    self.car = ac_car_name(view[:n])
                    self._send_to_game(AC_SUBSCRIBE_UPDATE)
                    self.subscribed = True
                elif other:
                    self.ignored += 1
                else:
                    self.bad += 1
                continue
            state = decode(view[:n], latest)
            if state is None:
                self.ignored += 1
            elif plausible(state):
                latest = state
                fresh += 1
            else:
                self.bad += 1
        if fresh:
            self.packets += fresh
            if self._assetto and self.car:
                latest = latest._replace(car=self.car)
            self.latest = latest
            self.arrival_ns = time.monotonic_ns()
        elif self._assetto and not self.subscribed and time.monotonic() - self._sent_s > AC_RETRY_S:
            self._handshake()
        return fresh

    def flush(self, limit: int = 1024) -> int:
        """Drop what queued before now (at most `limit` datagrams, more than the 64 KiB buffer
        holds, so that a flood cannot hold it up); return how many. The kernel
        keeps the oldest datagrams when its buffer is full, so a backlog from before the loop
        started would otherwise be read as news."""
        dropped = 0
        for _ in range(limit):
            try:
                self.socket.recv_into(self._buffer)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                pass
            dropped += 1
        return dropped

    def close(self) -> None:
        """Idempotent; tells Assetto Corsa we are gone (dismiss)."""
        if self.socket.fileno() < 0:
            return
        if self._assetto and self.subscribed:
            self._send_to_game(AC_DISMISS)
        self.socket.close()

    def __enter__(self) -> Receiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
