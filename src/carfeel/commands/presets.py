"""`carfeel presets`: the shipped presets."""

from __future__ import annotations

import argparse
from typing import Any

from carfeel.commands.common import (
    to_json,
)


def register(commands: Any) -> None:
    """Add `presets` and their options."""
    presets = commands.add_parser(
        "presets",
        help="list the shipped presets",
        description="List the presets that ship with carfeel, by kind.",
    )
    presets.add_argument("--json", action="store_true", help="print one JSON object")
    presets.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    code: int = _presets(args)
    return code


def _presets(args: argparse.Namespace) -> int:
    from carfeel.io.presets import PRESET_KINDS, available

    listing = {kind: available(kind) for kind in PRESET_KINDS}
    if args.json:
        print(to_json(listing))
    else:
        for kind, names in listing.items():
            print(f"{kind}: {', '.join(names)}")
    return 0
