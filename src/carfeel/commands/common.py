"""What the command families share: argument types, JSON output, output files, exit codes."""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from carfeel.io.outputs import Outputs, check_writable
from carfeel.models.rng import MAX_SEED
from carfeel.text import finite, shown, to_json

__all__ = [
    "EXIT_FAULT",
    "MAX_SEED",
    "check_writable",
    "finite",
    "outputs_of",
    "positive_float",
    "positive_int",
    "seed_arg",
    "shown",
    "to_json",
]

EXIT_FAULT = 3
"""A run stopped by a safety fault (stall, lost device, NaN, limit cycle)."""


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0.0 or value != value or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return value


def seed_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{shown(text)}'") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(
            f"expected a whole number from 0 to 2^64 - 1, got '{shown(text)}'"
        )
    return value


@dataclass
class Staging:
    """A run's --out (with its .json sidecar) and --plot, staged until the run has succeeded."""

    outputs: Outputs
    out: Path
    """Where to write the CSV (its sidecar beside it, same stem) until the run has succeeded."""
    plot: Path | None
    finals: dict[str, str]

    def text(self, message: str) -> str:
        """A message with the staged names replaced by the files the user asked for."""
        for staged, final in self.finals.items():
            message = message.replace(staged, final)
        return message


def outputs_of(args: argparse.Namespace) -> Staging:
    """--out (and its .json sidecar) and --plot, checked before any work is done and written
    under temporary names until the run has succeeded (`with staging.outputs:`)."""
    outputs = Outputs()
    out = Path(args.out)
    staged = outputs.add(out, ".csv", partial=True)
    outputs.add(out.with_suffix(".json"), ".json", partial=True)  # written beside the CSV
    finals = {str(staged): str(out)}
    plot = None
    if args.plot:
        plot = outputs.add(Path(args.plot), ".png")
        finals[str(plot)] = args.plot
    return Staging(outputs, staged, plot, finals)


def source_options(parser: argparse.ArgumentParser) -> None:
    """--channels and --dbc: how to read logs that are not carfeel's CSV (`carfeel.io.logs`)."""
    parser.add_argument("--channels", metavar="MAP.toml",
                        help="channel map: which signal of the logs is which channel, with units "
                        "(README, 'Channel maps')")  # fmt: skip
    parser.add_argument("--dbc", metavar="FILE.dbc", help="DBC to decode CAN logs with")


def sources_of(args: argparse.Namespace) -> tuple[Path | None, Path | None]:
    return (Path(args.channels) if args.channels else None, Path(args.dbc) if args.dbc else None)


def lever_run_options(parser: argparse.ArgumentParser, kind: str, default: str) -> None:
    """`--preset`, `--dt` and `--out` of a one-axis lever's offline run (`simulate sequential`,
    `simulate prnd`)."""
    parser.add_argument(
        "--preset", default=default, metavar="NAME|PATH",
        help=f"{kind} preset name or TOML file (default: {default})",
    )  # fmt: skip
    parser.add_argument(
        "--dt", type=positive_float, default=1e-3, metavar="S",
        help="model step and sample period, s (default: 0.001)",
    )  # fmt: skip
    parser.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    parser.set_defaults(plot=None)


def check_lever_step(dt_s: float, largest_s: float, lever: str) -> None:
    """InputError unless `dt_s` is small enough for the lever's walls (stiff springs)."""
    from carfeel.errors import InputError

    if dt_s > largest_s:
        raise InputError(
            f"--dt {dt_s:g}: at most {largest_s:g} s ({lever}'s walls need small steps)"
        )


def changes(values: Iterable[object]) -> list[str]:
    """`values` with each run of repeats shown once: the gears or positions a lever went
    through."""
    out: list[str] = []
    for value in values:
        if not out or str(value) != out[-1]:
            out.append(str(value))
    return out
