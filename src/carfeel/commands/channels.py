"""`carfeel channels FILE`: what a log holds, so a channel map can be written for it."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from carfeel.commands.common import to_json


def register(commands: Any) -> None:
    """Add `channels` and its options."""
    channels = commands.add_parser(
        "channels",
        help="list the signals of a log (name, unit, samples, rate, range)",
        description="List what a log holds (CSV, Parquet, MDF4, or a CAN log with --dbc), so a "
        "channel map (--channels MAP.toml) can be written for it.",
    )
    channels.add_argument("file", metavar="FILE", help="the log to list")
    channels.add_argument("--dbc", metavar="FILE.dbc", help="DBC to decode a CAN log with")
    channels.add_argument("--json", action="store_true", help="print one JSON object")
    channels.set_defaults(handler=_channels)


def _channels(args: argparse.Namespace) -> int:
    from carfeel.io.logs import describe

    rows = describe(Path(args.file), Path(args.dbc) if args.dbc else None)
    if args.json:
        print(to_json({"file": args.file, "signals": rows}))
        return 0
    print(f"{args.file}: {len(rows)} signal(s)")
    for r in rows:
        group = f"  (group {r['group']})" if "group" in r else ""
        print(f"  {r['signal']:48s} {r['unit'] or '-':8s} {r['samples']:8d} samples "
              f"{r['rate_hz']:8.1f} Hz  {r['min']:.4g} .. {r['max']:.4g}{group}")  # fmt: skip
    return 0
