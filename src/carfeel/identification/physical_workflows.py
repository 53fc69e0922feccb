"""`carfeel fit steering --steering-model physical` and `carfeel validate --steering-model
physical`: the physical steering model (issue 13) fitted to logs and checked against them, as
`workflows` does for the paper's law (same logs, checks, offsets, report and preset rules)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from carfeel import __version__
from carfeel.analysis.steering_feel import steering_feel
from carfeel.errors import InputError, PresetError
from carfeel.identification import rms_r2
from carfeel.identification.common import Progress, write_checked_preset
from carfeel.identification.physical_fit import MEANINGS, SETTLE_S, fit_physical, simulate_log
from carfeel.identification.steering_fit import SteeringFit, SteeringLog
from carfeel.identification.workflows import (
    Sources,
    _own_offset,
    feel_table,
    load_logs,
    part_name,
)
from carfeel.io import report
from carfeel.io.outputs import Outputs
from carfeel.io.presets import load_steering, to_toml
from carfeel.simulation.steering import SteeringCar


def physical_car(preset: str, role: str) -> tuple[str, SteeringCar]:
    """(name, car) of a steering preset that has the physical model's tables; else InputError
    naming what is missing (`role`: the option that named the preset)."""
    try:
        loaded = load_steering(preset)
    except PresetError as exc:
        raise InputError(
            f"{role} {preset}: --steering-model physical needs a steering (car) preset:\n{exc}"
        ) from None
    if not loaded.params.has_physical:
        raise InputError(
            f"{role} {preset}: the preset has no [tyres] and [steering_system] tables, so it has "
            "no physical steering model; use a car that has them (b-segment, d-segment, or a "
            "preset fitted with --steering-model physical), or --steering-model paper"
        )
    return loaded.name, loaded.params


def _figures(
    car: SteeringCar, log: SteeringLog, drift_s: float | None, delay_s: float,
    applied: float = 0.0,
) -> tuple[dict[str, float], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """A log's figures against the model (scored samples: past each stretch's first SETTLE_S):
    the headline with the offset `applied` (the fit's for its own logs and their held-out parts,
    none for a preset on its own), the log's own offset removed beside it; and the model's Ay,
    its torque with the headline's offset, the log's own offset and the scored mask."""
    ay, model, scored = simulate_log(car, log, delay_s)
    residual = np.where(scored, log.torque_Nm - model, 0.0)
    offset = np.zeros_like(model)
    if scored.any():
        part = dataclasses.replace(log, time_s=log.time_s[scored])
        offset[scored] = _own_offset(part, residual[scored], drift_s)
        offset[~scored] = float(np.mean(offset[scored]))
    measured, raw = log.torque_Nm[scored], model[scored]
    rms, r2 = rms_r2(measured, raw + applied)
    rms_o, r2_o = rms_r2(measured, raw + offset[scored])
    figures = {
        "rms_error_Nm": rms, "r2": r2, "rms_error_offset_removed_Nm": rms_o,
        "r2_offset_removed": r2_o, "offset_Nm": float(np.mean(offset[scored])),
        "offset_range_Nm": float(np.ptp(offset[scored])),
    }  # fmt: skip
    if log.lateral_accel_m_s2 is not None:
        figures["rms_lateral_accel_error_m_s2"] = rms_r2(log.lateral_accel_m_s2[scored],
                                                         ay[scored])[0]  # fmt: skip
    return figures, ay, model + applied, offset, scored


def physical_sections(
    car: SteeringCar,
    logs: Sequence[SteeringLog],
    folder: Path,
    *,
    drift_s: float | None = None,
    delay_s: float = 0.0,
    first: int = 1,
    offsets: dict[str, float] | None = None,
) -> tuple[list[report.Section], dict[str, dict[str, float]]]:
    """Per log: overlays, residuals and the feel metrics measured vs model; and the figures
    (the headline with `offsets[name]`, 0 for a log not in it)."""
    from carfeel.io.plots import plot_torque_validation

    sections, figures = [], {}
    ratio, base = car.vehicle.steering_ratio, car.vehicle.wheelbase_m
    for i, log in enumerate(logs, start=first - 1):
        applied = (offsets or {}).get(log.name, 0.0)
        values, ay, model, own, scored = _figures(car, log, drift_s, delay_s, applied)
        figures[log.name] = values
        measured_ay = log.lateral_accel_m_s2 if log.lateral_accel_m_s2 is not None else ay
        figure = plot_torque_validation(
            log.time_s[scored], measured_ay[scored], log.torque_Nm[scored], model[scored],
            folder / f"steering-{i + 1}.png",
            f"{Path(log.name).name}: measured vs physical model",
        )  # fmt: skip
        keep = scored
        measured_feel, model_feel = (
            steering_feel(log.time_s[keep], log.speed_m_s[keep], log.angle_rad[keep],
                          a[keep], torque[keep], steering_ratio=ratio, wheelbase_m=base)
            for a, torque in ((measured_ay, log.torque_Nm), (ay, model - applied + own))
        )  # fmt: skip
        table, missing = feel_table(measured_feel, model_feel)
        source = "measured" if log.lateral_accel_m_s2 is not None else "the model's (none logged)"
        ay_line = ""
        if "rms_lateral_accel_error_m_s2" in values:
            error = values["rms_lateral_accel_error_m_s2"]
            ay_line = f"; the model's Ay against the logged one: rms {error:.3g} m/s^2"
        sections.append(report.Section(
            f"Log {i + 1}: {log.name}",
            [f"rms error {values['rms_error_Nm']:.4g} Nm, r2 {values['r2']:.4f} with "
             f"{'the fit' + chr(39) + 's own' if applied else 'no'} torque offset "
             f"({applied:.3g} Nm); with the log's own offset (mean {values['offset_Nm']:.3g} "
             f"Nm, range {values['offset_range_Nm']:.3g} Nm) removed, which no prediction "
             f"knows: {values['rms_error_offset_removed_Nm']:.4g} Nm, r2 "
             f"{values['r2_offset_removed']:.4f}; {int(scored.sum())} "
             f"of {len(log.time_s)} samples scored (each stretch's first {SETTLE_S:g} s is the "
             f"model's start); Ay for the measured metrics {source}{ay_line}. The model is "
             "driven by the logged rim angle and rate and the logged speed.", *missing],
            table, [figure],
        ))  # fmt: skip
    return sections, figures


def fit_physical_logs(
    paths: Sequence[Path],
    out: Path,
    *,
    base: str = "b-segment",
    report_dir: Path | None = None,
    show_progress: bool = True,
    sources: Sources | None = None,
    drift_s: float | None = None,
    holdout: float = 0.0,
) -> SteeringFit:
    """Fit the physical model to the logs; write the report (if asked), then the preset (the
    base car's tables with the fitted values in them, checked by the loader): a preset is
    replaced only when everything before it succeeded (both are staged, as the law's are)."""
    outputs = Outputs()
    staged = outputs.add(out, ".toml")
    folder = outputs.add_folder(report_dir) if report_dir is not None else None
    with outputs:
        return _fit_physical_logs(
            paths, out, staged, folder, base=base, show_progress=show_progress,
            sources=sources, drift_s=drift_s, holdout=holdout,
        )  # fmt: skip


def _fit_physical_logs(
    paths: Sequence[Path],
    out: Path,
    staged: Path,
    folder: Path | None,
    *,
    base: str,
    show_progress: bool,
    sources: Sources | None,
    drift_s: float | None,
    holdout: float,
) -> SteeringFit:
    base_name, base_car = physical_car(base, "--base")
    logs, held = load_logs(paths, sources or Sources(), holdout)
    progress = Progress("fitting the physical steering model", show_progress)
    fit = fit_physical(logs, base_car, drift_s=drift_s, progress=progress)
    progress.done()
    if not any(e.status == "fitted" for e in fit.estimates):
        raise InputError(
            f"the logs identify none of the physical model's parameters (r2 {fit.r2:.3g}): the "
            f"preset would be the base {base_name}'s, so none is written. Why: "
            + "; ".join(fit.warnings)
        )
    held_figures: dict[str, dict[str, float]] = {}
    held_sections: list[report.Section] = []
    if held:
        ends = {
            part_name(n): v.get("offset_end_Nm", v["offset_Nm"]) for n, v in fit.per_log.items()
        }
        carried = {log.name: ends.get(part_name(log.name), 0.0) for log in held}
        if folder is not None:
            held_sections, held_figures = physical_sections(
                fit.car, held, folder, drift_s=drift_s, delay_s=fit.torque_delay_s,
                first=len(logs) + 1, offsets=carried,
            )  # fmt: skip
        else:
            held_figures = {
                log.name: _figures(fit.car, log, drift_s, fit.torque_delay_s,
                                   carried[log.name])[0]
                for log in held
            }  # fmt: skip
        fit = dataclasses.replace(fit, holdout={"fit": fit.per_log, "held_out": held_figures})
    lines = [
        f"Physical steering model fitted by carfeel {__version__} to "
        f"{', '.join(Path(p).name for p in paths)}",
        f"(rms error {fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}; torque offset "
        f"{fit.torque_offset_Nm:.3g} Nm and torque delay {fit.torque_delay_s * 1e3:.3g} ms "
        f"removed), from the base preset {base_name}. Everything not listed here is the base "
        "car's, the paper law's K1..K9 included (fit them with --steering-model paper).",
        *(f"{e.name} = {e.value:.6g} +- {e.sigma:.2g}" if e.status == "fitted"
          else f"{e.name} = {e.value:.6g}: {e.note}" for e in fit.estimates),
        *(f"warning: {w}" for w in fit.warnings),
    ]  # fmt: skip
    car = fit.car
    tables = {"vehicle": car.vehicle, "torque": car.torque, "driver": car.driver,
              "tyres": car.tyres, "steering_system": car.steering_system}  # fmt: skip
    text = to_toml(out.stem, "\n".join(lines), tables)
    if folder is not None:
        _fit_report(fit, out, folder, logs, held, held_figures, held_sections, drift_s)
    write_checked_preset("steering", out, text, staged, fit.warnings)
    return fit


def _fit_report(
    fit: SteeringFit, out: Path, folder: Path, logs: Sequence[SteeringLog],
    held: Sequence[SteeringLog], held_figures: dict[str, dict[str, float]],
    held_sections: list[report.Section], drift_s: float | None,
) -> None:  # fmt: skip
    table = [["parameter", "value", "1 sigma", "status", "what it is"]] + [
        [e.name, report.number(e.value, 6), report.number(e.sigma, 2),
         e.status if e.status == "fitted" else f"kept: {e.note}", MEANINGS.get(e.name, "")]
        for e in fit.estimates
    ]  # fmt: skip
    names, matrix = fit.correlation
    correlation = [["", *names]] + [
        [n, *(report.number(v, 2) for v in row)] for n, row in zip(names, matrix, strict=True)
    ]
    summary = report.Section(
        "Fit of the physical steering model",
        [f"rms error {fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}, {fit.iterations} simulations "
         "of the logs (a finite-difference Jacobian counts one per parameter); torque logged "
         f"{fit.torque_delay_s * 1e3:.3g} ms after the other channels (corrected). The model is "
         "re-simulated with the logged rim angle and rate and the logged speed imposed; one "
         "sigma from a block sandwich covariance (blocks of 2 s).",
         *(f"Warning: {w}" for w in fit.warnings)],
        table,
    )  # fmt: skip
    sections = [summary, report.Section("Parameter correlations", [], correlation)]
    if held:
        sections.append(report.Section(
            "Cross-validation: the fitted part and the held-out part of each log",
            ["Each log's last part was left out of the fit; the preset is validated on it "
             "(simulated from its own start) with the torque offset its fitted part ended with "
             "(the headline), and with the held-out part's own offset removed beside it."],
            [["log", "fit rms (Nm)", "fit r2", "held-out rms (Nm)", "held-out r2",
              "held-out r2, its offset removed"]]
            + [[part_name(a), report.number(fa["rms_error_Nm"]),
                report.number(fa["r2"]), report.number(fb["rms_error_Nm"]),
                report.number(fb["r2"]), report.number(fb["r2_offset_removed"])]
               for (a, fa), fb in zip(fit.per_log.items(), held_figures.values(), strict=True)],
        ))  # fmt: skip
    own = {log.name: fit.per_log[log.name]["offset_Nm"] for log in logs}
    log_sections, _ = physical_sections(fit.car, logs, folder, drift_s=drift_s,
                                        delay_s=fit.torque_delay_s, offsets=own)  # fmt: skip
    report.write(folder, f"Physical steering fit: {out.name}",
                 [*sections, *log_sections, *held_sections])  # fmt: skip


def validate_physical(
    preset: str,
    paths: Sequence[Path],
    report_dir: Path,
    sources: Sources | None = None,
    drift_s: float | None = None,
) -> dict[str, Any]:
    """The physical model of a preset against logs: the report, and the figures per log."""
    _, car = physical_car(preset, "--preset")
    outputs = Outputs()
    folder = outputs.add_folder(report_dir)
    with outputs:  # the report replaces an older one only when it is complete
        logs, _ = load_logs(paths, sources or Sources())
        sections, figures = physical_sections(car, logs, folder, drift_s=drift_s)
        report.write(folder, f"Validation of the physical model of {Path(preset).name}", sections)
    return figures
