"""A sweep from its spec file to its results: `run_sweep` runs the cases (resuming an
interrupted run), writes the results (Parquet or CSV) and the plots, all or nothing;
`plot_results` draws a results file again. `carfeel sweep` is the command line over them."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.io.outputs import Outputs, check_writable

__all__ = ["SweepSummary", "plot_results", "run_sweep"]


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
    staged = _plot_outputs(
        outputs,
        folder,
        json.loads(meta["carfeel_parameters"]),
        list(json.loads(meta["carfeel_metrics"])),
    )
    with outputs:
        notes = plots.write(columns, meta, staged, results_path.stem)
    return folder / plots.PAGE, notes
