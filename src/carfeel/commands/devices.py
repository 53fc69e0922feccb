"""`carfeel devices`: the force-feedback devices the backends see."""

from __future__ import annotations

import argparse
from typing import Any

from carfeel.commands.common import (
    to_json,
)


def register(commands: Any) -> None:
    """Add `devices` and their options."""
    devices = commands.add_parser(
        "devices",
        help="list the force-feedback devices evdev and SDL2 can see",
        description="List the force-feedback devices the evdev (Linux) and SDL2 backends see, "
        "and say plainly when there is none or a backend library is missing.",
    )
    devices.add_argument("--json", action="store_true", help="print one JSON object")
    devices.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    code: int = _devices(args)
    return code


def _devices(args: argparse.Namespace) -> int:
    from carfeel.realtime.devices.listing import describe_backends, list_devices

    if args.json:
        print(to_json(describe_backends()))
    else:
        print("\n".join(list_devices()))
    return 0
