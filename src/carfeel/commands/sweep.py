"""`carfeel sweep SPEC.toml --out R.parquet` and `carfeel sweep plot R.parquet --out DIR`."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

from carfeel.commands.common import positive_int
from carfeel.errors import InputError
from carfeel.sweep.files import SweepSummary, plot_results, run_sweep

__all__ = ["SweepSummary", "plot_results", "register", "run_sweep"]

EXIT_SIGINT, EXIT_SIGTERM = 130, 143


class Terminated(Exception):
    """SIGTERM during a sweep: stop as Ctrl-C does (the part file keeps what is done)."""


@contextlib.contextmanager
def _sigterm_stops() -> Iterator[None]:
    def stop(signum: int, frame: FrameType | None) -> None:
        raise Terminated

    try:
        previous = signal.signal(signal.SIGTERM, stop)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def register(commands: Any) -> None:
    sweep = commands.add_parser(
        "sweep",
        help="sweeps and Monte Carlo of a model over parameters and seeds, serial or on Dask",
        description="Run every case of a sweep spec (TOML: the model and preset, the parameters "
        "to vary as grids or distributions, the seeds, what to simulate, the metrics to keep) "
        "and write one row per case. `carfeel sweep plot RESULTS --out DIR` draws a results "
        "file's figures and page. See the README, 'Sweeps and Monte Carlo'.",
        epilog="An interrupted sweep (Ctrl-C, a kill) resumes when run again with the same spec "
        "and --out: its finished cases are kept in OUT.part.jsonl beside the output.",
    )
    sweep.add_argument(
        "what",
        nargs="+",
        metavar="SPEC.toml | plot RESULTS",
        help="the sweep spec to run, or `plot` and a results file",
    )
    sweep.add_argument(
        "--out",
        required=True,
        metavar="FILE.parquet|FILE.csv|DIR",
        help="results file (.parquet needs carfeel[batch]; .csv writes a .json "
        "sidecar); with `plot`, the folder for the figures",
    )
    where = sweep.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=positive_int,
        metavar="N",
        help="run on a Dask LocalCluster of N single-threaded worker processes (carfeel[batch])",
    )
    where.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on the Dask cluster whose scheduler is at ADDRESS (tcp://host:8786)",
    )
    sweep.add_argument(
        "--plot", metavar="DIR", help="also draw the figures and an HTML page into DIR"
    )
    sweep.add_argument(
        "--restart",
        action="store_true",
        help="discard the finished cases of an interrupted run (another spec's "
        "part file included) and start anew",
    )
    sweep.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    what = args.what
    if what[0] == "plot" and len(what) == 2:
        if args.workers or args.scheduler or args.plot or args.restart:
            raise InputError("`carfeel sweep plot RESULTS --out DIR` takes no other option")
        page, notes = plot_results(Path(what[1]), Path(args.out))
        print("\n".join([*notes, f"wrote {page} and its figures"]))
        return 0
    if len(what) != 1:
        raise InputError(
            f"expected one sweep spec (SPEC.toml) or `plot RESULTS`, got {' '.join(what)}"
        )
    try:
        with _sigterm_stops():
            summary = run_sweep(
                Path(what[0]),
                Path(args.out),
                workers=args.workers,
                scheduler=args.scheduler,
                plot=Path(args.plot) if args.plot else None,
                restart=args.restart,
            )
    except (KeyboardInterrupt, Terminated) as exc:
        from carfeel.sweep.runner import part_path

        print(
            f"\ncarfeel: sweep stopped; the finished cases are kept in "
            f"{part_path(Path(args.out))}: run the same command again to resume",
            file=sys.stderr,
        )
        return EXIT_SIGTERM if isinstance(exc, Terminated) else EXIT_SIGINT
    print(summary.text())
    return 0
