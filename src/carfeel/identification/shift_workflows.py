"""What `carfeel fit shift` and the shift half of `carfeel validate` do."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.errors import InputError
from carfeel.identification import rms_r2
from carfeel.identification.common import Progress, read_results, write_checked_preset
from carfeel.identification.shift_fit import MIN_R2, fit_shift, resimulate
from carfeel.identification.shift_traces import checked_columns
from carfeel.io import report
from carfeel.io.outputs import Outputs
from carfeel.io.presets import load_shift, to_toml
from carfeel.simulation.result import Result
from carfeel.simulation.shift import ShiftParams
from carfeel.text import count

COLUMNS = ("time_s", "position_m", "force_N")
MEANINGS = {
    "gearbox.synchronization_position_m": "where the knob meets the synchro ring (from neutral)",
    "gearbox.synchronization_duration_s": "how long the ring holds the knob (the plateau)",
    "gearbox.teeth_position_m": "where the sleeve meets the gear's dog teeth",
    "gearbox.teeth_end_position_m": "where the teeth are passed (free travel to the stop)",
    "gearbox.in_gear_position_m": "the knob's rest position in gear (x_gear)",
    "gearbox.tooth_force_spread_N": "spread of the teeth's random extra resistance",
    "gearbox.engagement.static_friction_N": "the teeth's static friction",
    "gearbox.engagement.sliding_friction_N": "the teeth's sliding friction (the law's minimum)",
    "gearbox.stop.stiffness_N_m": "the end stop's stiffness",
    "gearbox.stop.damping_N_s_m": "the end stop's damping",
    "driver.push_force_N": "the driver's push during synchronization (eq. 10's F_max)",
}
"""What each fitted shift parameter is, for reports."""
SIGMA_NOTE = (
    "One sigma from the traces' noise: Gauss-Newton for the values fitted by simulation (the "
    "teeth, the stop), the standard error of the median over three or more engagements (ring, "
    "duration, push) and the order statistics of the uniform law for the teeth's friction and "
    "spread; n/a where the traces cannot give one. What the method itself misses (the teeth "
    "trade with their resistance by about 0.1 mm; x_gear may sit below the settled position) "
    "is not in them: take them as lower bounds."
)


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
                    f"{count(run.engagements, 'engagement')}; position rms error "
                    f"{rms * 1e3:.3g} mm, "
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
    """Fit the engagement to the traces; write the preset (and the report); the fit as data.
    The preset and the report replace what was there only when both are done."""
    outputs = Outputs()
    staged = outputs.add(out, ".toml")
    folder = outputs.add_folder(report_dir) if report_dir is not None else None
    with outputs:
        return _fit_shift_traces(
            paths, out, staged, folder, base=base, show_progress=show_progress,
            channels=channels, dbc=dbc,
        )  # fmt: skip


def _fit_warnings(warnings: Sequence[str]) -> str:
    """The fit's own warnings, other than its traces' r2 (named already), for a refusal: what
    the fit found odd (a force in kgf) is often why its model cannot follow the traces."""
    said = [w for w in warnings if "under the" not in w or "of a model that follows" not in w]
    return f"The fit warned: {'; '.join(said)}. " if said else ""


def _fit_shift_traces(
    paths: Sequence[Path],
    out: Path,
    staged: Path,
    folder: Path | None,
    *,
    base: str,
    show_progress: bool,
    channels: Path | None,
    dbc: Path | None,
) -> dict[str, Any]:
    preset = load_shift(base)
    traces = read_traces(paths, channels, dbc)
    progress = Progress("fitting the shift", show_progress)
    fit = fit_shift(traces, preset.params, progress=progress)
    progress.done()
    r2 = fit.figures.get("r2", math.nan)
    if not r2 > MIN_R2:
        chamfer = preset.params.gearbox.chamfer
        raise InputError(
            f"the fitted shift model follows the traces with r2 {r2:.4g}, under the {MIN_R2:g} "
            f"a preset needs, so {out} is not written; worst: {'; '.join(fit.departures[:3])}. "
            f"{_fit_warnings(fit.warnings)}The "
            "model is driven by each trace's recorded force from its arrival at the synchro "
            "ring: a knob that goes where the model does not means a mechanism the base preset "
            f"{preset.name} lacks or has otherwise (its chamfers: gear inertia "
            f"{chamfer.gear_inertia_kg_m2:g} kg m^2, drag {chamfer.drag_torque_Nm:g} Nm), a "
            "force or position in other units or of the other sign, or pushes the segmentation "
            "did not see; fit with --base a preset of this gearbox, or check the traces' "
            "channels (carfeel channels FILE)"
        )
    params = fit.params
    lines = [
        f"Fitted by carfeel {__version__} to {', '.join(Path(p).name for p in paths)}, from "
        f"the base preset {preset.name}: {count(len(fit.engagements), 'engagement')}; position rms "
        f"error {fit.figures.get('rms_error_m', float('nan')) * 1e3:.3g} mm, r2 "
        f"{fit.figures.get('r2', float('nan')):.4f}.",
        *(f"warning: {w}" for w in fit.warnings),
    ]
    text = to_toml(out.stem, "\n".join(lines), {"gearbox": params.gearbox, "driver": params.driver})
    write_checked_preset("shift", out, text, staged, fit.warnings)
    result: dict[str, Any] = {
        "rms_error": fit.figures.get("rms_error_m"),
        "rms_error_unit": "m",
        "r2": fit.figures.get("r2"),
        "parameters": {
            k: v for k, v in fit.figures.items() if k.startswith(("gearbox.", "driver."))
        },
        "uncertainties": dict(fit.sigmas),
        "figures": {
            k: v for k, v in fit.figures.items() if not k.startswith(("gearbox.", "driver."))
        },
        "engagements": [dataclasses.asdict(e) for e in fit.engagements],
        "warnings": list(fit.warnings),
        "preset": str(out),
    }
    if folder is not None:
        table = [["parameter", "value", "1 sigma", "what it is"]] + [
            [k, report.number(v, 6), report.number(fit.sigmas.get(k), 2), MEANINGS.get(k, "")]
            for k, v in result["parameters"].items()
        ]
        summary = report.Section("Fit", [*lines, SIGMA_NOTE], table)
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
    outputs = Outputs()
    folder = outputs.add_folder(report_dir)
    with outputs:  # the report replaces an older one only when it is complete
        traces = read_traces(paths, channels, dbc)
        sections, figures = _sections(params, traces, paths, folder)
        report.write(folder, "Validation of a shift preset", sections)
    return figures


def summary_text(result: dict[str, Any], out: Path) -> str:
    lines = [
        f"fitted {count(len(result['engagements']), 'engagement')}: position rms error "
        f"{(result['rms_error'] or float('nan')) * 1e3:.3g} mm, r2 {result['r2']:.4f}",
    ]
    sigmas = result.get("uncertainties", {})
    lines += [
        f"  {k:44s} {v:10.5g}" + (f" +- {sigmas[k]:.2g}" if math.isfinite(sigmas.get(k, math.nan))
                                  else "")
        for k, v in result["parameters"].items()
    ]  # fmt: skip
    lines += [f"warning: {w}" for w in result["warnings"]]
    lines.append(f"wrote {out}")
    return "\n".join(lines)
