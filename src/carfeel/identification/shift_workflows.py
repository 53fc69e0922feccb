"""What `carfeel fit shift` and the shift half of `carfeel validate` do."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.identification import rms_r2
from carfeel.identification.common import Progress, read_results, write_checked_preset
from carfeel.identification.shift_fit import checked_columns, fit_shift, resimulate
from carfeel.io import report
from carfeel.io.presets import load_shift, to_toml
from carfeel.simulation.result import Result
from carfeel.simulation.shift import ShiftParams

COLUMNS = ("time_s", "position_m", "force_N")


def read_traces(
    paths: Sequence[Path], channels: Path | None = None, dbc: Path | None = None
) -> list[Result]:
    traces = []
    for path, result in zip(paths, read_results(paths, channels, dbc), strict=True):
        t, x, f = checked_columns(result, str(path))
        traces.append(Result(t, {"position_m": x, "force_N": f}, {"name": Path(path).name}))
    return traces


def _sections(
    params: ShiftParams, traces: Sequence[Result], paths: Sequence[Path], folder: Path
) -> tuple[list[report.Section], dict[str, Any]]:
    from carfeel.io.plots import plot_shift_validation

    sections, figures = [], {}
    for i, (trace, path) in enumerate(zip(traces, paths, strict=True)):
        run = resimulate(trace, params, str(path))
        rms, r2 = rms_r2(run.measured_m, run.model_m)
        figures[str(path)] = {"rms_error_m": rms, "r2": r2}
        png = plot_shift_validation(
            run.time_s,
            run.force_N,
            run.measured_m,
            run.model_m,
            folder / f"shift-{i + 1}.png",
            f"{Path(path).name}: measured vs the model driven by the measured force",
        )
        sections.append(
            report.Section(
                f"Trace {i + 1}: {path}",
                [
                    f"{run.engagements} engagement(s); position rms error {rms * 1e3:.3g} mm, "
                    f"r2 {r2:.4f}. The model is driven by the recorded force, "
                    "restarted at each arrival at the synchro ring, the teeth resisting with the "
                    "preset's mean (sliding friction + spread / 2).",
                ],
                figures=[png],
            )
        )
    return sections, figures


def fit_shift_traces(
    paths: Sequence[Path],
    out: Path,
    *,
    base: str = "paper-first-gear",
    report_dir: Path | None = None,
    show_progress: bool = True,
    channels: Path | None = None,
    dbc: Path | None = None,
) -> dict[str, Any]:
    """Fit the engagement to the traces; write the preset (and the report); the fit as data."""
    preset = load_shift(base)
    traces = read_traces(paths, channels, dbc)
    folder = report.prepare(report_dir) if report_dir is not None else None
    progress = Progress("fitting the shift", show_progress)
    fit = fit_shift(traces, preset.params, progress=progress)
    progress.done()
    params = fit.params
    lines = [
        f"Fitted by carfeel {__version__} to {', '.join(Path(p).name for p in paths)}, from "
        f"the base preset {preset.name}: {len(fit.engagements)} engagement(s); position rms "
        f"error {fit.figures.get('rms_error_m', float('nan')) * 1e3:.3g} mm, r2 "
        f"{fit.figures.get('r2', float('nan')):.4f}.",
        *(f"warning: {w}" for w in fit.warnings),
    ]
    text = to_toml(out.stem, "\n".join(lines), {"gearbox": params.gearbox, "driver": params.driver})
    write_checked_preset("shift", out, text)
    result: dict[str, Any] = {
        "rms_error": fit.figures.get("rms_error_m"),
        "rms_error_unit": "m",
        "r2": fit.figures.get("r2"),
        "parameters": {
            k: v for k, v in fit.figures.items() if k.startswith(("gearbox.", "driver."))
        },
        "figures": {
            k: v for k, v in fit.figures.items() if not k.startswith(("gearbox.", "driver."))
        },
        "engagements": [dataclasses.asdict(e) for e in fit.engagements],
        "warnings": list(fit.warnings),
        "preset": str(out),
    }
    if folder is not None:
        table = [["parameter", "value"]] + [
            [k, report.number(v, 6)] for k, v in result["parameters"].items()
        ]
        summary = report.Section("Fit", [*lines], table)
        sections, _ = _sections(params, traces, paths, folder)
        report.write(folder, f"Shift fit: {out.name}", [summary, *sections])
    return result


def validate_traces(
    params: ShiftParams,
    paths: Sequence[Path],
    report_dir: Path,
    channels: Path | None = None,
    dbc: Path | None = None,
) -> dict[str, Any]:
    traces = read_traces(paths, channels, dbc)
    folder = report.prepare(report_dir)
    sections, figures = _sections(params, traces, paths, folder)
    report.write(folder, "Validation of a shift preset", sections)
    return figures


def summary_text(result: dict[str, Any], out: Path) -> str:
    lines = [
        f"fitted {len(result['engagements'])} engagement(s): position rms error "
        f"{(result['rms_error'] or float('nan')) * 1e3:.3g} mm, r2 {result['r2']:.4f}",
    ]
    lines += [f"  {k:44s} {v:.5g}" for k, v in result["parameters"].items()]
    lines += [f"warning: {w}" for w in result["warnings"]]
    lines.append(f"wrote {out}")
    return "\n".join(lines)
