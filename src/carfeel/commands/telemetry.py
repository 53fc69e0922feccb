"""`carfeel telemetry listen|replay`: see what a game sends; send a capture as the game would."""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

from carfeel.errors import InputError


def register(commands: Any) -> None:
    parser = commands.add_parser(
        "telemetry",
        help="receive a game's telemetry (listen) or send a capture as the game would (replay)",
        description="SOURCE is FORMAT:HOST:PORT (or FORMAT:PORT on 127.0.0.1) with FORMAT one "
        "of codemasters, f1, assetto, forza, outgauge, outsim, beamng, pcars, carfeel. For "
        "assetto, HOST:PORT is the game's (port 9996); for the others, where to listen. Packets "
        "are taken from the game's host only (127.0.0.1 on loopback); beyond loopback name it with "
        "--accept-from ADDR (or ,from=ADDR after the source). The shared-memory games (iracing) "
        "are FORMAT (the live map: Windows' named memory, on Linux the bridge's file under "
        "/dev/shm) or FORMAT:file:PATH (a file image: an iRacing .ibt is replayed at its rate).",
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    listen = actions.add_parser("listen", help="print what arrives; record the vehicle state")
    listen.add_argument("source", metavar="SOURCE", help="FORMAT:HOST:PORT to listen on")
    listen.add_argument("--duration", type=float, default=None, metavar="S",
                        help="seconds to listen (default: until Ctrl-C)")  # fmt: skip
    listen.add_argument("--record", metavar="FILE.csv", default=None,
                        help="one row per good packet: time_s (when it came, s), packet_time_s "
                        "(the game's own stamp, where the format has one) and the vehicle "
                        "state")  # fmt: skip
    listen.add_argument("--accept-from", metavar="ADDR", default=None,
                        help="take packets from ADDR only (an address, a network such as "
                        "192.168.1.0/24, or any); default: the game's host (127.0.0.1 on "
                        "loopback; required when listening beyond it)")  # fmt: skip
    listen.add_argument("--json", action="store_true", help="print the summary as JSON")
    listen.set_defaults(handler=_listen)
    replay = actions.add_parser("replay", help="send a capture (datagrams concatenated)")
    replay.add_argument("file", metavar="FILE", help="the capture: its datagrams concatenated")
    replay.add_argument("--format", required=True, metavar="FORMAT",
                        help="the capture's format (one of the FORMATs above)")  # fmt: skip
    replay.add_argument("--to", required=True, metavar="HOST:PORT",
                        help="where to send (assetto: where to serve, as the game)")  # fmt: skip
    replay.add_argument("--rate-hz", type=float, default=None, metavar="R",
                        help="datagrams a second (default: the game's usual, 60 Hz)")  # fmt: skip
    replay.add_argument(
        "--size",
        type=int,
        default=None,
        metavar="BYTES",
        help="datagram size (default: the format's size that fits the file)",
    )
    parser.set_defaults(handler=_dispatch)


def _dispatch(args: argparse.Namespace) -> int:
    if args.action == "listen":
        return _listen(args)
    return _replay(args)


def _address(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(f"--to {text!r}: expected HOST:PORT, e.g. 127.0.0.1:5300")
    return host, int(port)


LISTEN_BUFFER_BYTES = 4 * 1024 * 1024
"""The listener's kernel receive buffer (asked for; the system may give less, e.g. Linux's
rmem_max): a recorder wants every packet, where the loop wants only the newest (64 KiB)."""
WAIT_S = 0.1
MAP_TICK_S = 0.002
"""How often the listener reads a shared-memory map (500 Hz: above every game's rate)."""
"""The longest the listener sleeps in `select` between two looks at the clock."""


def _listen(args: argparse.Namespace) -> int:
    from carfeel.io.outputs import Outputs
    from carfeel.telemetry.receiver import Receiver, parse_source
    from carfeel.telemetry.shm import MapReceiver, MapSource

    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration {args.duration:g}: must be a positive number of seconds")
    source = parse_source(args.source, accept_from=args.accept_from)
    record = Path(args.record) if args.record else None
    outputs = Outputs()
    # A killed listener leaves NAME.part.csv readable; one that ends (duration, Ctrl-C) NAME.csv.
    staged = outputs.add(record, ".csv", partial=True) if record is not None else None
    receiver: Any = (
        MapReceiver(source)
        if isinstance(source, MapSource)
        else Receiver(source, LISTEN_BUFFER_BYTES)
    )
    with receiver, outputs:
        summary = _receive(args, receiver, staged)
    if args.json:
        print(json.dumps(summary))
    else:
        recorded = f"; recorded {summary['rows']} rows to {record}" if record else ""
        print(f"{receiver.counts()} ({summary['rate_hz']:.1f} Hz){recorded}")
    return 0


def _receive(args: argparse.Namespace, receiver: Any, staged: Path | None) -> dict[str, Any]:
    """Wait for datagrams in `select` (no fixed sleep: a 5 kHz stream is read as it comes),
    drain the socket each time, write one row per good packet, print once a second."""
    import select

    from carfeel.telemetry.state import FIELDS, VehicleState, gear_name

    handle = staged.open("w", newline="", encoding="utf-8") if staged is not None else None
    writer = csv.writer(handle) if handle is not None else None
    rows = 0
    start = last_print = time.monotonic()
    # A row's stamp: perf_counter (time.monotonic ticks every 15.6 ms on Windows before 3.13).
    origin = time.perf_counter()

    def write(state: VehicleState) -> None:
        nonlocal rows
        if writer is not None:
            writer.writerow((f"{time.perf_counter() - origin:.6f}", state.time_s,
                             *(getattr(state, f) for f in FIELDS)))  # fmt: skip
            rows += 1

    if writer is not None:
        writer.writerow(("time_s", "packet_time_s", *FIELDS))
    counted = 0
    mapped = receiver.socket is None  # shared memory or a file image: read each tick
    if not args.json:
        print(f"listening for {receiver.format.describe} on {receiver.where} (accepting "
              f"{receiver.source.describe_accept()}); Ctrl-C stops", flush=True)  # fmt: skip
    end = math.inf if args.duration is None else start + args.duration
    try:
        while (now := time.monotonic()) < end:
            if mapped:
                receiver.poll(write)
                if receiver.finished:
                    break  # a file image replayed to its end
                time.sleep(min(MAP_TICK_S, max(0.0, end - now)))
                now = time.monotonic()
            elif select.select([receiver.socket], [], [], min(WAIT_S, end - now))[0]:
                while receiver.poll(write):  # drain: MAX_PER_POLL at a time until empty
                    pass
            now = time.monotonic()
            if not args.json and now - last_print >= 1.0:
                rate = (receiver.packets - counted) / (now - last_print)
                counted, last_print = receiver.packets, now
                s = receiver.latest
                print(
                    f"{rate:6.1f} Hz  speed {s.speed_m_s:7.2f} m/s  Ay "
                    f"{s.lateral_accel_m_s2:6.2f} m/s2  yaw {s.yaw_rate_rad_s:6.3f} rad/s  "
                    f"{s.engine_speed_rpm:6.0f} rpm  gear {gear_name(s.gear)}  clutch "
                    f"{s.clutch_pedal:.2f}  bad {receiver.bad}  foreign {receiver.foreign}",
                    flush=True,
                )
    except KeyboardInterrupt:
        pass
    finally:
        if handle is not None:
            handle.close()
    elapsed = time.monotonic() - start
    # The rate over the time the packets came (first to last), not the time spent listening.
    span = (receiver.arrival_ns - receiver.first_ns) / 1e9
    rate_hz = (receiver.packets - 1) / span if receiver.packets > 1 and span > 0 else 0.0
    s = receiver.latest
    return {
        "format": receiver.format.name,
        "packets": receiver.packets,
        "bad": receiver.bad,
        "ignored": receiver.ignored,
        "foreign": receiver.foreign,
        "foreign_from": dict(receiver.foreign_from),
        "accepted": receiver.source.describe_accept(),
        "decoder_errors": receiver.errors,
        "rows": rows,
        "duration_s": elapsed,
        "receiving_s": span,
        "rate_hz": rate_hz,
        "car": s.car,
        "last": {f: (None if isinstance(v, float) and math.isnan(v) else v)
                 for f, v in zip(FIELDS, (getattr(s, f) for f in FIELDS), strict=True)},
    }  # fmt: skip


def _replay(args: argparse.Namespace) -> int:
    from carfeel.telemetry import replay

    fmt = replay.lookup_format(args.format)
    to = _address(args.to)
    path = Path(args.file)
    if not path.is_file():
        raise InputError(f"{path}: no such capture")
    if fmt.name == "pcars" and args.size is None:  # three packet types of three sizes
        packets = replay.pcars_datagrams(path)
        size = len(packets[0]) if packets else 0
    else:
        size = replay.datagram_size(path, fmt, args.size)
        packets = replay.datagrams(path, size)
    rate = args.rate_hz or replay.NATURAL_RATE_HZ.get(fmt.name, 100.0)
    if not (math.isfinite(rate) and 0.0 < rate <= 10_000.0):
        raise InputError(f"--rate-hz {rate:g}: allowed 0 < value <= 10000")
    try:
        if fmt.name == "assetto":
            print(f"serving {len(packets)} RTCarInfo packets as Assetto Corsa on {to[0]}:{to[1]}",
                  file=sys.stderr, flush=True)  # fmt: skip
            sent = replay.serve_assetto(packets, to, rate)
        else:
            sent = replay.send(packets, to, rate)
    except OSError as exc:
        raise InputError(f"--to {args.to}: {exc}") from exc
    except KeyboardInterrupt:
        return 130
    sizes = "-".join(map(str, sorted({len(p) for p in packets}))) or str(size)
    print(f"sent {sent} of {len(packets)} {sizes}-byte datagrams at {rate:g} Hz to {args.to}")
    return 0
