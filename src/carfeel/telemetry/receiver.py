"""The UDP receiver: a non-blocking socket drained each tick, never blocking the loop.

Why not a thread: the latest-value handoff a thread needs costs a lock or a GIL hand-over on the
loop's side anyway, and the thread wakes the loop's core 60-1000 times a second; draining a
non-blocking socket costs one failing `recv_into` (about 1 us) on a tick with nothing and about
2 us a datagram (`benchmarks/bench_telemetry.py` measures it). A flood cannot slow the loop: at
most `MAX_PER_POLL` datagrams are read a tick, and the kernel's receive buffer is kept small so
that what waits is recent (the rest is dropped by the kernel, not by us).

Every datagram is hostile until checked: one from an address the source does not accept is
dropped and counted (`foreign`), one that is not a packet of the format is counted bad, and
`poll` never raises, whatever the bytes (a decoder that did would be counted bad and named in
`errors`).
"""

from __future__ import annotations

import contextlib
import errno
import ipaddress
import math
import platform
import socket
import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

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
    decode_datagram,
    outsim_pack2,
)
from carfeel.telemetry.state import VehicleState, plausible

MAX_PER_POLL = 64
RECEIVE_BUFFER_BYTES = 64 * 1024
AC_RETRY_S = 1.0
"""Assetto Corsa: the handshake is sent again every second until the game answers."""
ANY = "any"
"""`--accept-from any`: packets from every address (say so: the default is the game's host)."""
FOREIGN_SHOWN = 8
"""Foreign addresses remembered for the summary (the count goes on past them)."""
_ACCEPT_MEMO = 1024
_SO_TIMESTAMPNS = 35
"""SO_TIMESTAMPNS (= SCM_TIMESTAMPNS) of asm-generic/socket.h: Python's socket module does not
name it; the architectures below use the generic value (alpha, mips, parisc and sparc do not)."""
KERNEL_STAMPS = sys.platform == "linux" and platform.machine() in (
    "x86_64", "aarch64", "arm64", "riscv64",
)  # fmt: skip
"""Linux stamps each datagram with its arrival (SO_TIMESTAMPNS): the packet-to-force latency
then counts from the network's arrival, not from the poll that read it (up to a tick later).
Elsewhere a datagram's arrival is when it was read."""
STAMP_TRUSTED_NS = 10_000_000_000
"""A stamp older than this (or in the future: the real-time clock was stepped) is not used."""
_TIMESPEC = struct.Struct("@qq")
"""struct timespec on 64-bit Linux (time_t, long): the ancillary data of SCM_TIMESTAMPNS."""
_ANCILLARY_BYTES = socket.CMSG_SPACE(_TIMESPEC.size) if KERNEL_STAMPS else 0

Network = ipaddress.IPv4Network


def _loopback(address: str) -> bool:
    return ipaddress.IPv4Address(address).is_loopback


def _resolve(text: str, host: str, what: str) -> str:
    """An IPv4 address for `host` (a name is looked up once, here, not per packet)."""
    try:
        return str(ipaddress.IPv4Address(host))
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None, socket.AF_INET, socket.SOCK_DGRAM)
    except (OSError, UnicodeError) as exc:
        raise InputError(f"telemetry source {text!r}: unknown {what} {host!r} ({exc})") from exc
    return str(infos[0][4][0])


def _route_to(address: str) -> str:
    """The local address the system would send to `address` from (no packet is sent)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect((address, 9))
            return str(probe.getsockname()[0])
        except OSError:
            return "0.0.0.0"


@dataclass(frozen=True, slots=True)
class Source:
    """`FORMAT:HOST:PORT` (or `FORMAT:PORT`, on 127.0.0.1), checked once, optionally followed by
    `,from=ADDR`: whose packets to take (an address, a network such as 192.168.1.0/24, or
    `any`). Port 0 listens on any free port (`Receiver.address` says which).

    HOST is where to listen, except for Assetto Corsa, where it is the game's (carfeel is its
    client, listening on the interface that reaches it). By default only the game's host is
    accepted: on a loopback address, 127.0.0.1 (the game on this machine); for Assetto Corsa,
    the game's address. A source that listens beyond loopback must say whom it accepts."""

    format: Format
    host: str
    port: int
    bind_host: str = "127.0.0.1"
    """The local address the socket is bound to."""
    accept: tuple[Network, ...] | None = (Network("127.0.0.1/32"),)
    """The addresses packets are taken from; None: any."""

    @classmethod
    def parse(cls, text: str, accept_from: str | None = None, network: bool = True) -> Source:
        """`accept_from` overrides the text's `,from=`; `network` False refuses any source that
        would listen beyond loopback (the panel started for this machine only)."""
        spec, *options = text.split(",")
        for option in options:
            key, eq, value = option.partition("=")
            if key.strip() != "from" or not eq or not value.strip():
                raise InputError(
                    f"telemetry source {text!r}: {option!r} is not an option; the one option "
                    "is ,from=ADDR (e.g. forza:0.0.0.0:5300,from=192.168.1.20)"
                )
            accept_from = accept_from if accept_from is not None else value.strip()
        name, _, rest = spec.partition(":")
        base, at, opts = name.partition("@")
        if base == "outsim" and at:  # OutSimPack2: outsim@OPTS, OPTS as in LFS's cfg.txt (hex)
            try:
                fmt = outsim_pack2(int(opts, 16))
            except ValueError as exc:
                raise InputError(
                    f"telemetry source {text!r}: outsim@OPTS takes LFS's OutSim Opts in hex, "
                    f"with OSMain (8) among them, e.g. outsim@1ff ({exc})"
                ) from exc
        elif name in FORMATS:
            fmt = FORMATS[name]
        else:
            raise InputError(
                f"telemetry source {text!r}: the format {name!r} is not one of "
                f"{', '.join(FORMATS)} (SOURCE is FORMAT:HOST:PORT, e.g. forza:127.0.0.1:5300), "
                f"nor a shared-memory game ({', '.join(_map_formats())}: FORMAT or "
                "FORMAT:file:PATH)"
            )
        return cls._address(text, fmt, rest, accept_from, network)

    @classmethod
    def _address(
        cls, text: str, fmt: Format, rest: str, accept_from: str | None, network: bool
    ) -> Source:
        host, _, port_text = rest.rpartition(":")
        if not rest:
            port_text = str(fmt.default_port)
        host = host or "127.0.0.1"
        if not port_text.isdigit() or not 0 <= int(port_text) < 65536:
            raise InputError(
                f"telemetry source {text!r}: the port {port_text!r} is not a number 0..65535"
            )
        assetto = fmt.name == "assetto"
        if assetto and int(port_text) == 0:
            raise InputError(f"telemetry source {text!r}: give the game's port (9996)")
        address = _resolve(text, host, "game host" if assetto else "host")
        if assetto:
            bind = "127.0.0.1" if _loopback(address) else _route_to(address)
            default: tuple[Network, ...] | None = (Network(f"{address}/32"),)
        else:
            bind = address
            default = (Network("127.0.0.1/32"),) if _loopback(address) else None
        if accept_from is not None:
            accept = _accept(text, accept_from)
        elif default is not None:
            accept = default
        else:
            where = "every interface" if bind == "0.0.0.0" else bind
            raise InputError(
                f"telemetry source {text!r} listens on {where}: say whose packets to take with "
                "--accept-from ADDR (the game's machine, e.g. 192.168.1.20; a network, e.g. "
                "192.168.1.0/24; or any), or listen on 127.0.0.1 for a game on this machine"
            )
        if not network and not _loopback(bind):
            raise InputError(
                f"telemetry source {text!r} would listen on {bind}, beyond this machine: the "
                "panel was started for this machine only (its sessions listen on 127.0.0.1); "
                "start the panel with --host for the network to take telemetry from it"
            )
        return cls(fmt, address, int(port_text), bind, accept)

    @property
    def text(self) -> str:
        return f"{self.format.name}:{self.host}:{self.port}"

    def describe_accept(self) -> str:
        if self.accept is None:
            return "any address"
        return ", ".join(
            str(n.network_address) if n.prefixlen == 32 else str(n) for n in self.accept
        )


def _map_formats() -> list[str]:
    from carfeel.telemetry.shm import MAP_FORMATS

    return list(MAP_FORMATS)


def _accept(text: str, value: str) -> tuple[Network, ...] | None:
    """`--accept-from`'s value: None for any."""
    value = value.strip()
    if value == ANY:
        return None
    try:
        return (ipaddress.IPv4Network(value, strict=False),)
    except ValueError:
        pass
    if "/" in value:
        raise InputError(
            f"--accept-from {value!r}: not an IPv4 network (e.g. 192.168.1.0/24) for {text!r}"
        )
    address = _resolve(text, value, "--accept-from host")
    return (Network(f"{address}/32"),)


class Receiver:
    """Receive one source's datagrams; `poll()` reads what waits and keeps the latest good state.

    Counters: `packets` (decoded to a state that passed the checks), `bad` (wrong size, not the
    format's, failing the checks, NaN where it must not be), `ignored` (no vehicle state: other
    packet types, a paused game) and `foreign` (from an address the source does not accept,
    dropped before decoding; `foreign_from` names the first few). `poll` returns how many good
    states arrived since the last call; `first_ns` and `arrival_ns` are when the first and the
    latest good ones were read (time.monotonic_ns()).
    """

    def __init__(self, source: Source, buffer_bytes: int = RECEIVE_BUFFER_BYTES) -> None:
        self.source = source
        self.format = source.format
        self.latest = VehicleState()
        self.packets = self.bad = self.ignored = self.foreign = 0
        self.foreign_from: dict[str, int] = {}
        self.errors = 0
        """Datagrams a decoder raised on (counted bad too): a bug, never expected."""
        self.first_error = ""
        self.first_ns = 0
        self.arrival_ns = 0
        """When the latest good state arrived, time.perf_counter_ns() (the loop's wall clock):
        the kernel's receive stamp where it gives one (`KERNEL_STAMPS`), else when it was
        read."""
        self.stamped = False
        """The arrivals are the kernel's stamps."""
        self._buffer = bytearray(2048)
        self._view = memoryview(self._buffer)
        self._memo: dict[str, bool] = {}
        self.car = ""
        self.notes: list[str] = []
        """What the run's summary should say of this source (the car's profile)."""
        self.torque_scale_Nm = math.nan
        """The car profile's torque scale (the game's torque at the wheel's full force), N*m."""
        self.subscribed = False
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, buffer_bytes)
        self._assetto = source.format.name == "assetto"
        try:
            # Assetto Corsa is a server: we are its client, on any port of the interface to it.
            sock.bind((source.bind_host, 0 if self._assetto else source.port))
        except OSError as exc:
            sock.close()
            raise InputError(_bind_error(source, exc)) from exc
        sock.setblocking(False)
        if KERNEL_STAMPS and _TIMESPEC.size == 16:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
                self.stamped = True
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

    def accepts(self, address: str) -> bool:
        """Whether packets from `address` are taken (memoized: one dict lookup a datagram)."""
        known = self._memo.get(address)
        if known is not None:
            return known
        networks = self.source.accept
        try:
            ip = ipaddress.IPv4Address(address)
            ok = networks is None or any(ip in n for n in networks)
        except ValueError:
            ok = False
        if len(self._memo) < _ACCEPT_MEMO:
            self._memo[address] = ok
        return ok

    def _send_to_game(self, operation: int) -> None:
        # The game may not be there yet: the handshake is sent again later.
        with contextlib.suppress(OSError):
            self.socket.sendto(ac_request(operation), (self.source.host, self.source.port))
        self._sent_s = time.monotonic()

    def _handshake(self) -> None:
        self._send_to_game(AC_HANDSHAKE)

    def _foreign(self, address: str) -> None:
        self.foreign += 1
        if address in self.foreign_from or len(self.foreign_from) < FOREIGN_SHOWN:
            self.foreign_from[address] = self.foreign_from.get(address, 0) + 1

    @property
    def where(self) -> str:
        host, port = self.bound
        return f"{host}:{port}"

    def poll(
        self, sink: Callable[[VehicleState], object] | None = None, now_s: float | None = None
    ) -> int:
        """Read what waits (at most MAX_PER_POLL datagrams); `sink` is given every good state in
        the order they came (a recorder: none is lost between polls). `now_s` is for the file
        replays' clock (a socket has its own). Never raises."""
        fresh = 0
        fmt = self.format
        view = self._view
        latest = self.latest
        accepts = self._memo.get
        stamp = 0
        for _ in range(MAX_PER_POLL):
            try:
                n, sender, stamped_ns = self._receive()
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP port unreachable from an earlier send to the game
                continue
            host = sender[0]
            if not (accepts(host) or self.accepts(host)):
                self._foreign(host)
                continue
            if self._assetto and n == AC_RESPONSE_SIZE:
                self.car = ac_car_name(view[:n])
                self._send_to_game(AC_SUBSCRIBE_UPDATE)
                self.subscribed = True
                continue
            try:
                state = decode_datagram(fmt, view[:n], latest)
            except Exception as exc:  # a decoder's bug must not end a session: counted, named
                self.errors += 1
                self.first_error = self.first_error or f"{type(exc).__name__}: {exc}"
                self.bad += 1
                continue
            if state is None:
                self.ignored += 1
            elif plausible(state):
                if self._assetto and self.car:
                    state = state._replace(car=self.car)
                latest = state
                stamp = stamped_ns
                fresh += 1
                if sink is not None:
                    sink(state)
            else:
                self.bad += 1
        if fresh:
            self.packets += fresh
            self.latest = latest
            now = time.perf_counter_ns()
            # The kernel stamps on the real-time clock: how long ago it came, taken to the loop's
            # clock (a stamp from a stepped real-time clock is not believed).
            late = time.time_ns() - stamp
            self.arrival_ns = now - late if 0 <= late < STAMP_TRUSTED_NS else now
            self.first_ns = self.first_ns or self.arrival_ns
        elif self._assetto and not self.subscribed and time.monotonic() - self._sent_s > AC_RETRY_S:
            self._handshake()
        return fresh

    def _receive(self) -> tuple[int, Any, int]:
        """One datagram into the buffer: (its size, the sender, the kernel's arrival stamp on
        the real-time clock in ns, or 0)."""
        if not self.stamped:
            n, sender = self.socket.recvfrom_into(self._buffer)
            return n, sender, 0
        n, ancillary, _, sender = self.socket.recvmsg_into([self._buffer], _ANCILLARY_BYTES)
        for level, kind, data in ancillary:
            ours = level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS
            if ours and len(data) >= _TIMESPEC.size:
                seconds, nanoseconds = _TIMESPEC.unpack_from(data)
                return n, sender, seconds * 1_000_000_000 + nanoseconds
        return n, sender, 0

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

    def counts(self) -> str:
        """The counters in words, for a summary."""
        text = f"{self.packets} good packets, {self.bad} bad, {self.ignored} ignored"
        if self.foreign:
            shown = ", ".join(f"{a} ({k})" for a, k in self.foreign_from.items())
            more = ", ..." if sum(self.foreign_from.values()) < self.foreign else ""
            text += (
                f", {self.foreign} from addresses not accepted (dropped: {shown}{more}; "
                f"accepted: {self.source.describe_accept()}, see --accept-from)"
            )
        if self.errors:
            text += f"; {self.errors} raised in the decoder (a bug: {self.first_error})"
        return text

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


def parse_source(text: str, accept_from: str | None = None) -> Any:
    """A UDP `Source` or a shared-memory `MapSource` from the command line's SOURCE."""
    from carfeel.telemetry.shm import parse_map_source

    mapped = parse_map_source(text)
    if mapped is not None:
        if accept_from is not None or ",from=" in text:
            raise InputError(
                f"telemetry source {text!r} reads shared memory or a file: --accept-from (and "
                ",from=) are for the UDP games"
            )
        return mapped
    return Source.parse(text, accept_from=accept_from)


def open_receiver(text: str, buffer_bytes: int = RECEIVE_BUFFER_BYTES) -> Any:
    """The receiver for SOURCE: a UDP `Receiver`, or a `MapReceiver` for a shared-memory game
    (its live map or a file image); both poll alike."""
    from carfeel.telemetry.shm import MapReceiver, MapSource

    source = parse_source(text)
    if isinstance(source, MapSource):
        return MapReceiver(source)
    return Receiver(source, buffer_bytes)


def _bind_error(source: Source, exc: OSError) -> str:
    where = f"telemetry source {source.text}: cannot listen on {source.bind_host}"
    if exc.errno == errno.EADDRINUSE or getattr(exc, "winerror", None) == 10048:
        other = source.port + 1 if source.port < 65535 else 5300
        return (
            f"{where}:{source.port} (in use: another program, or another carfeel, listens "
            "there). Stop it, or choose another port here and set the game to send to it "
            f"(e.g. {source.format.name}:{source.bind_host}:{other})"
        )
    if exc.errno == errno.EADDRNOTAVAIL:
        return f"{where}: no interface of this machine has that address"
    if exc.errno == errno.EACCES:
        return f"{where}:{source.port}: permission denied (ports below 1024 need privileges)"
    return f"{where}:{source.port} ({exc})"
