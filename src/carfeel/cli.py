"""carfeel's command line: parse, call one function, print.

Exit codes: 0 done; 2 bad input (nothing run, nothing written over); 3 a real-time run stopped
by a safety fault (the force was faded to zero; the summary says which); 130 and 143 a run
stopped by SIGINT (Ctrl-C) or SIGTERM, after taking the force away (the shell's 128 + signal);
141 when the output was closed early (`carfeel ... | head`, SIGPIPE).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence

from carfeel import __version__
from carfeel.commands import (
    calibrate,
    channels,
    demo,
    devices,
    export,
    identify,
    metrics,
    panel,
    presets,
    run,
    simulate,
    sweep,
    telemetry,
)
from carfeel.errors import CarfeelError

DESCRIPTION = """\
carfeel: the feel of a car's primary controls from physics.

Simulate a manual gearshift engagement (synchronization, tooth engagement, end stop), the complete
H-pattern gearshift and the steering wheel torque through the ISO manoeuvres, plot them as in the
PERCRO 2005 paper, write the samples as CSV and compute steering feel metrics. Start with
`carfeel demo`.
"""

EPILOG = """\
examples:
  carfeel demo                                   simulate, plot and write into ./carfeel-demo
  carfeel simulate shift --out shift.csv --plot shift.png
  carfeel simulate shift --seed 7 --pull-out --out shift.csv
  carfeel simulate hpattern --sequence N,1,2,3,2,N --out hp.csv --plot hp.png
  carfeel simulate steering --manoeuvre iso3888 --out dlc.csv --plot dlc.png
  carfeel metrics steering dlc.csv --json        steering feel figures of a run or a log
  carfeel presets                                list the shipped presets
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="carfeel",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"carfeel {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    families = (demo, simulate, metrics, run, calibrate, identify, channels, devices, presets,
                telemetry, sweep, export, panel)  # fmt: skip
    for family in families:
        family.register(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        handler = getattr(args, "handler", None)
        if handler is not None:  # a command family in carfeel.commands
            code: int = handler(args)
            return code
        raise AssertionError(f"no handler for {args.command}")  # argparse requires one
    except CarfeelError as exc:
        print(f"carfeel: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader went away (`carfeel ... | head`): as the shell's tools
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE
    except OSError as exc:  # the file system said no: name the file and the reason
        where = exc.filename if exc.filename is not None else "a file"
        print(f"carfeel: error: cannot use {where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("carfeel: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
