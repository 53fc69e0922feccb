"""`carfeel sweep SPEC.toml --out R.parquet` and `carfeel sweep plot R.parquet --out DIR`."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from carfeel.commands.common import positive_int
from carfeel.errors import InputError
from carfeel.io.outputs import Outputs, check_writable

EXIT_SIGINT, EXIT_SIGTERM = 130, 143


class Terminated(Exception):
    """SIGTERM during a sweep: stop as Ctrl-C does (the part file keeps what is done)."""


@dataclass(frozen=True)
class SweepSummary:
    run: Any
    """sweep.runner.SweepRun"""
    out: Path
    plot: Path | None

    def text(self) -> str:
        run = self.run
        spec = run.spec
        lines = [
            f"sweep {spec.label}: {spec.model} ({spec.preset_label}), {spec.n_cases} cases "
            f"({spec.n_sets} parameter sets x {len(spec.seeds)} seeds), {run.where}"
            + (f", engine {spec.engine}" if spec.model == "shift" else ""),
            f"  {run.count('ok')} ok, {run.count('invalid')} refused by the preset validation, "
            f"{run.count('failed')} failed; {run.simulated} simulated in {run.elapsed_s:.1f} s"
            + (f", {run.resumed} kept from the interrupted run" if run.resumed else ""),
        ]
        invalid = run.tally.first_invalid
        if invalid is not None:
            lines.append(f"  first refused: case {invalid['case_id']}: {invalid['problem']}")
            if any(v.distribution == "normal" for v in spec.vary):
                lines.append(
                    "  note: a normal distribution draws outside the preset's ranges; "
                    "truncnormal keeps the draws within low..high"
                )
        lines += [f"  note: {note}" for note in run.notes]
        lines.append(f"wrote {self.out}" + (f" and {self.plot}/" if self.plot else ""))
        return "\n".join(lines)


def run_sweep(
    spec_path: Path,
    out: Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    plot: Path | None = None,
    restart: bool = False,
    progress: Any = None,
) -> SweepSummary:
    """Run a sweep spec (resuming an interrupted run of it) and write its results and plots.

    Nothing is written over before every case is done; an interruption leaves the part file
    (see `carfeel.sweep.runner`) and the files that were there."""
    from carfeel.sweep import plots, results, runner, spec

    sweep = spec.load(spec_path)
    if out.suffix.lower() not in results.FORMATS:
        raise InputError(f"--out {out}: expected a .parquet or .csv file name")
    if out.suffix.lower() == ".parquet":
        results.pyarrow()
    if workers is not None or scheduler is not None:
        runner.dask_modules()
    outputs = Outputs()
    fmt = out.suffix.lower()
    staged_out = outputs.add(out, fmt)
    sidecar = outputs.add(out.with_suffix(".json"), ".json") if fmt == ".csv" else None
    staged_plots: dict[str, Path] = {}
    if plot is not None:
        staged_plots = _plot_outputs(outputs, plot, sweep.parameters, sweep.metrics)
    part = runner.PartFile(runner.part_path(out), sweep)
    check_writable(part.path)
    try:
        # The rows stream to the part file as tasks finish and are written from it, in order:
        # memory does not grow with the number of cases.
        run = runner.run_cases(
            sweep, part, workers=workers, scheduler=scheduler, restart=restart,
            progress=progress, keep_rows=False,
        )  # fmt: skip
        with outputs:
            results.write_chunks(part.chunks_in_order(), sweep, staged_out, fmt, sidecar)
            if plot is not None:
                every = plots.every_for(sweep.n_cases)
                columns, meta = results.columns_of_chunks(part.chunks_in_order(every), sweep)
                if every > 1:
                    meta["carfeel_plotted"] = plots.sampled_note(every, sweep.n_cases)
                plots.write(columns, meta, staged_plots, Path(sweep.label).stem)
    except BaseException:
        outputs.discard()
        raise
    part.remove()
    return SweepSummary(run, out, plot)


def _plot_outputs(outputs: Outputs, folder: Path, parameters: Any, metrics: Any) -> dict[str, Path]:
    from carfeel.sweep import plots

    if folder.exists() and not folder.is_dir():
        raise InputError(f"--plot {folder} exists and is not a folder")
    names = plots.file_names(parameters, metrics)
    if not folder.exists():  # made, whole, only once the run has succeeded
        staged = outputs.add_folder(folder)
        return {name: staged / name for name in names}
    return {name: outputs.add(folder / name, Path(name).suffix) for name in names}


def plot_results(results_path: Path, folder: Path) -> tuple[Path, list[str]]:
    """The figures and page of a results file (Parquet or CSV) written by a sweep."""
    from carfeel.sweep import plots, results

    columns, meta = results.read(results_path, max_rows=plots.MAX_PLOTTED_ROWS)
    outputs = Outputs()
    import json

    staged = _plot_outputs(
        outputs,
        folder,
        json.loads(meta["carfeel_parameters"]),
        list(json.loads(meta["carfeel_metrics"])),
    )
    with outputs:
        notes = plots.write(columns, meta, staged, results_path.stem)
    return folder / plots.PAGE, notes


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
