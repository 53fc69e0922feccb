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
        "of codemasters, f1, assetto, forza, outgauge, outsim, beamng, carfeel. For assetto, "
        "HOST:PORT is the game's (port 9996); for the others, where to listen.",
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    listen = actions.add_parser("listen", help="print what arrives; record the vehicle state")
    listen.add_argument("source", metavar="SOURCE", help="FORMAT:HOST:PORT to listen on")
    listen.add_argument("--duration", type=float, default=None, metavar="S",
                        help="seconds to listen (default: until Ctrl-C)")  # fmt: skip
    listen.add_argument("--record", metavar="FILE.csv", default=None,
                        help="one row per good packet: time_s and the vehicle state")  # fmt: skip
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


def _listen(args: argparse.Namespace) -> int:
    from carfeel.telemetry.receiver import Receiver, Source
    from carfeel.telemetry.state import FIELDS, gear_name

    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration {args.duration:g}: must be a positive number of seconds")
    source = Source.parse(args.source)
    record = Path(args.record) if args.record else None
    with Receiver(source) as receiver:
        handle = record.open("w", newline="") if record else None
        writer = csv.writer(handle) if handle else None
        if writer is not None:
            writer.writerow(("time_s", *FIELDS))
        start = last_print = time.monotonic()
        counted = 0
        if not args.json:
            host, port = receiver.address
            print(f"listening for {source.format.describe} on {host}:{port}; Ctrl-C stops",
                  flush=True)  # fmt: skip
        try:
            while args.duration is None or time.monotonic() - start < args.duration:
                if receiver.poll() and writer is not None:
                    s = receiver.latest
                    writer.writerow((f"{time.monotonic() - start:.4f}",
                                     *(getattr(s, f) for f in FIELDS)))  # fmt: skip
                now = time.monotonic()
                if not args.json and now - last_print >= 1.0:
                    rate = (receiver.packets - counted) / (now - last_print)
                    counted, last_print = receiver.packets, now
                    s = receiver.latest
                    print(
                        f"{rate:6.1f} Hz  speed {s.speed_m_s:7.2f} m/s  Ay "
                        f"{s.lateral_accel_m_s2:6.2f} m/s2  yaw {s.yaw_rate_rad_s:6.3f} rad/s  "
                        f"{s.engine_speed_rpm:6.0f} rpm  gear {gear_name(s.gear)}  clutch "
                        f"{s.clutch_pedal:.2f}  bad {receiver.bad}",
                        flush=True,
                    )
                time.sleep(0.001)
        except KeyboardInterrupt:
            pass
        finally:
            if handle is not None:
                handle.close()
        elapsed = time.monotonic() - start
        s = receiver.latest
        summary = {
            "format": source.format.name,
            "packets": receiver.packets,
            "bad": receiver.bad,
            "ignored": receiver.ignored,
            "duration_s": elapsed,
            "rate_hz": receiver.packets / elapsed if elapsed > 0 else 0.0,
            "car": s.car,
            "last": {f: (None if isinstance(v, float) and math.isnan(v) else v)
                     for f, v in zip(FIELDS, (getattr(s, f) for f in FIELDS), strict=True)},
        }  # fmt: skip
    if args.json:
        print(json.dumps(summary))
    else:
        recorded = f"; recorded {record}" if record else ""
        print(f"{receiver.packets} packets ({summary['rate_hz']:.1f} Hz), {receiver.bad} bad, "
              f"{receiver.ignored} ignored{recorded}")  # fmt: skip
    return 0


def _replay(args: argparse.Namespace) -> int:
    from carfeel.telemetry import replay

    fmt = replay.lookup_format(args.format)
    to = _address(args.to)
    path = Path(args.file)
    if not path.is_file():
        raise InputError(f"{path}: no such capture")
    size = replay.datagram_size(path, fmt, args.size)
    rate = args.rate_hz or replay.NATURAL_RATE_HZ.get(fmt.name, 100.0)
    if not (math.isfinite(rate) and 0.0 < rate <= 10_000.0):
        raise InputError(f"--rate-hz {rate:g}: allowed 0 < value <= 10000")
    packets = replay.datagrams(path, size)
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
    print(f"sent {sent} of {len(packets)} {size}-byte datagrams at {rate:g} Hz to {args.to}")
    return 0
