"""What `carfeel fit` and `carfeel validate` do: read logs, fit or compare, write presets and
reports. Functions over paths and small configs; the CLI only parses and prints."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from carfeel import __version__
from carfeel.analysis.steering_feel import LABELS, SteeringFeel, steering_feel
from carfeel.errors import InputError, PresetError
from carfeel.identification import rms_r2
from carfeel.identification.common import Progress, read_results, write_checked_preset
from carfeel.identification.steering_fit import (
    MEANINGS,
    SteeringFit,
    SteeringLog,
    fit_steering,
    offset_basis,
    read_log,
    transient_ay,
)
from carfeel.io import report
from carfeel.io.outputs import Outputs
from carfeel.io.presets import load_steering, to_toml
from carfeel.models.steering.torque import torque_terms
from carfeel.simulation.result import Result
from carfeel.simulation.steering import SteeringCar
from carfeel.text import count

FEEL_KEYS = (
    "torque_gradient_Nm_per_g", "torque_at_0_1g_Nm", "deadband_g", "hysteresis_Nm",
    "sensitivity_g_per_100deg", "understeer_gradient_deg_per_g",
)  # fmt: skip


@dataclass(frozen=True)
class Sources:
    """Where the logs come from: a channel map and a DBC for files other than carfeel's CSV."""

    channels: Path | None = None
    dbc: Path | None = None


def load_logs(
    paths: Sequence[Path], sources: Sources = Sources(), holdout: float = 0.0
) -> tuple[list[SteeringLog], list[SteeringLog]]:
    """The logs to fit, and with `holdout` > 0 the last fraction of each (in time) kept apart
    to validate on: a guard against over-fitting."""
    if not 0.0 <= holdout < 0.9:
        raise InputError(f"--holdout {holdout:g}: give a fraction of each log from 0 to 0.9")
    fitted: list[SteeringLog] = []
    held: list[SteeringLog] = []
    for path, result in zip(paths, read_results(paths, sources.channels, sources.dbc), strict=True):
        if holdout == 0.0:
            fitted.append(read_log(result, str(path)))
            continue
        t = result.time_s
        cut = t[0] + (1.0 - holdout) * (t[-1] - t[0])
        for keep, into, label in ((t < cut, fitted, "fit part"), (t >= cut, held, "held out")):
            part = Result(t[keep], {k: v[keep] for k, v in result.signals.items()})
            into.append(read_log(part, f"{path} ({label})"))
    return fitted, held


def model_torque(
    car: SteeringCar, log: SteeringLog, delay_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """(Ay, model torque) for a log: its measured Ay, else the transient car's from the logged
    angle and speed; the regressors delayed by `delay_s` (the torque's logging delay)."""
    ay = (
        log.lateral_accel_m_s2
        if log.lateral_accel_m_s2 is not None
        else transient_ay(log.time_s, log.speed_m_s, log.angle_rad, car.vehicle)
    )
    speed, rate = log.speed_m_s, log.rate_rad_s
    if delay_s != 0.0:
        speed, rate, ay = (
            np.interp(log.time_s - delay_s, log.time_s, v) for v in (speed, rate, ay)
        )
    torque = torque_terms(speed, rate, ay, car.torque, atan=np.arctan)[0]
    return np.asarray(ay), np.asarray(torque)


def _own_offset(log: SteeringLog, residual: np.ndarray, drift_s: float | None) -> np.ndarray:
    """The log's own torque offset (constant, or drifting with knots `drift_s` apart): a
    nuisance of the sensor and the road, estimated from this log's residual alone."""
    basis = offset_basis(log.time_s, drift_s)
    coefficients = np.linalg.lstsq(basis, residual, rcond=None)[0]
    return np.asarray(basis @ coefficients)


def steering_sections(
    car: SteeringCar,
    logs: Sequence[SteeringLog],
    folder: Path,
    *,
    drift_s: float | None = None,
    delay_s: float = 0.0,
    first: int = 1,
) -> tuple[list[report.Section], dict[str, dict[str, float]]]:
    """Per log: overlays, residuals and the feel metrics measured vs model; and the figures
    (rms_error_Nm, r2) by log name."""
    from carfeel.io.plots import plot_torque_validation

    sections, figures = [], {}
    ratio, base = car.vehicle.steering_ratio, car.vehicle.wheelbase_m
    for i, log in enumerate(logs, start=first - 1):
        ay, model = model_torque(car, log, delay_s)
        offset = _own_offset(log, log.torque_Nm - model, drift_s)
        raw_rms, _ = rms_r2(log.torque_Nm, model)
        model = model + offset
        rms, r2 = rms_r2(log.torque_Nm, model)
        figures[log.name] = {
            "rms_error_Nm": rms, "r2": r2, "offset_Nm": float(np.mean(offset)),
            "offset_range_Nm": float(np.ptp(offset)), "rms_error_without_offset_Nm": raw_rms,
        }  # fmt: skip
        figure = plot_torque_validation(
            log.time_s, ay, log.torque_Nm, model, folder / f"steering-{i + 1}.png",
            f"{Path(log.name).name}: measured vs model",
        )  # fmt: skip
        measured, simulated = (
            steering_feel(log.time_s, log.speed_m_s, log.angle_rad, ay, torque,
                          steering_ratio=ratio, wheelbase_m=base)
            for torque in (log.torque_Nm, model)
        )  # fmt: skip
        # The law is driven with the log's angle and Ay: an understeer gradient from them would
        # be the log's own. The model's is its car's (the preset's linear car).
        simulated = dataclasses.replace(
            simulated, understeer_gradient_deg_per_g=car.vehicle.understeer_gradient_deg_per_g
        )
        table, missing = feel_table(measured, simulated)
        missing.append(
            "The model's understeer gradient is its car's (the preset's), not one from this log: "
            "the law is driven with the log's angle and Ay."
        )
        source = (
            "measured" if log.lateral_accel_m_s2 is not None else "from the transient car model"
        )
        sections.append(report.Section(
            f"Log {i + 1}: {log.name}",
            [f"rms error {rms:.4g} Nm, r2 {r2:.4f}, with the log's own torque offset "
             f"(mean {np.mean(offset):.3g} Nm, range {np.ptp(offset):.3g} Nm) removed; "
             f"{raw_rms:.4g} Nm without it; {count(len(log.time_s), 'sample')}, Ay {source}",
             *missing],
            table, [figure],
        ))  # fmt: skip
    return sections, figures


def feel_table(measured: SteeringFeel, model: SteeringFeel) -> tuple[list[list[str]], list[str]]:
    """The feel metrics this log gives, measured and modelled side by side (an empty table if it
    gives none), and one line naming those it does not give, with the reasons."""
    given = [
        key for key in FEEL_KEYS
        if math.isfinite(getattr(measured, key)) or math.isfinite(getattr(model, key))
    ]  # fmt: skip
    table = [["metric", "measured", "model"]] + [
        [f"{LABELS[key][0]} ({LABELS[key][1]})", report.number(getattr(measured, key)),
         report.number(getattr(model, key))]
        for key in given
    ]  # fmt: skip
    absent = [LABELS[key][0] for key in FEEL_KEYS if key not in given]
    if not absent:
        return table, []
    why = "; ".join(dict.fromkeys(measured.notes)) or "the data do not give them"
    line = f"Feel metrics not given for this log ({', '.join(absent)}): {why}."
    return (table if given else []), [line]


def fit_steering_logs(
    paths: Sequence[Path],
    out: Path,
    *,
    base: str = "b-segment",
    fit_vehicle: bool = False,
    report_dir: Path | None = None,
    show_progress: bool = True,
    sources: Sources = Sources(),
    drift_s: float | None = None,
    holdout: float = 0.0,
) -> SteeringFit:
    """Fit the torque law to the logs; write the preset (and the report). With `holdout`, the
    last fraction of each log is validated on, and both figures are in `fit.per_log`. The
    preset and the report are staged and replace what was there only when both are done."""
    outputs = Outputs()
    staged = outputs.add(out, ".toml")
    folder = outputs.add_folder(report_dir) if report_dir is not None else None
    with outputs:
        return _fit_steering_logs(
            paths, out, staged, folder, base=base, fit_vehicle=fit_vehicle,
            show_progress=show_progress, sources=sources, drift_s=drift_s, holdout=holdout,
        )  # fmt: skip


def _fit_steering_logs(
    paths: Sequence[Path],
    out: Path,
    staged: Path,
    folder: Path | None,
    *,
    base: str,
    fit_vehicle: bool,
    show_progress: bool,
    sources: Sources,
    drift_s: float | None,
    holdout: float,
) -> SteeringFit:
    preset = load_steering(base)
    logs, held = load_logs(paths, sources, holdout)
    progress = Progress("fitting K1..K9", show_progress)
    fit = fit_steering(logs, preset.params, fit_vehicle=fit_vehicle, drift_s=drift_s,
                       progress=progress)  # fmt: skip
    progress.done()
    if not any(e.status == "fitted" for e in fit.estimates):
        last = fit.keep_tests[-1] if fit.keep_tests else None
        test = f" (likelihood ratio p = {last.p_value:.2g})" if last is not None else ""
        raise InputError(
            f"the logs identify none of the law's parameters: the base preset {preset.name}'s law "
            f"explains r2 {fit.r2:.3g} of them (with a torque offset per log and the delay "
            f"fitted), the free fit's r2 {fit.free_fit.get('r2', math.nan):.3g} is not "
            f"significantly better{test}; the preset would be the base's, so none is written. "
            "Why: "
            + "; ".join(fit.warnings)
            + ". Log the manoeuvres named (a weave, a steady-state circle, parking)"
        )
    held_figures: dict[str, dict[str, float]] = {}
    held_sections: list[report.Section] = []
    if held:
        if folder is not None:
            held_sections, held_figures = steering_sections(
                fit.car, held, folder, drift_s=drift_s, delay_s=fit.torque_delay_s,
                first=len(logs) + 1,
            )  # fmt: skip
        else:
            held_figures = _figures_only(fit.car, held, drift_s, fit.torque_delay_s)
        fit = dataclasses.replace(fit, holdout={"fit": fit.per_log, "held_out": held_figures})
    lines = [
        f"Fitted by carfeel {__version__} to {', '.join(Path(p).name for p in paths)}",
        f"(rms error {fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}; torque offset "
        f"{fit.torque_offset_Nm:.3g} Nm and torque delay {fit.torque_delay_s * 1e3:.3g} ms "
        f"removed), from the base preset {preset.name}.",
        *(f"{e.name} = {e.value:.6g} +- {e.sigma:.2g}" if e.status == "fitted"
          else f"{e.name} = {e.value:.6g}: {e.note}" for e in fit.estimates),
        *(f"warning: {w}" for w in fit.warnings),
    ]  # fmt: skip
    car = fit.car
    tables = {"vehicle": car.vehicle, "torque": car.torque, "driver": car.driver}
    text = to_toml(out.stem, "\n".join(lines), tables)
    write_checked_preset("steering", out, text, staged, fit.warnings)
    if folder is not None:
        table = [["parameter", "value", "1 sigma", "status", "what it is"]] + [
            [e.name, report.number(e.value, 6), report.number(e.sigma, 2),
             "fitted" if e.status == "fitted" else e.note, MEANINGS.get(e.name, "")]
            for e in fit.estimates
        ]  # fmt: skip
        names, matrix = fit.correlation
        correlation = [["", *names]] + [
            [n, *(report.number(v, 2) for v in row)] for n, row in zip(names, matrix, strict=True)
        ]
        summary = report.Section(
            "Fit",
            [f"rms error {fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}, {fit.iterations} evaluations; "
             f"torque logged {fit.torque_delay_s * 1e3:.3g} ms after the other channels "
             "(corrected). One sigma from a block sandwich covariance (blocks of 2 s).",
             *(f"Warning: {w}" for w in fit.warnings)],
            table,
        )  # fmt: skip
        sections = [summary, report.Section("Parameter correlations", [], correlation)]
        if held:
            sections.append(report.Section(
                "Cross-validation: the fitted part and the held-out part of each log",
                ["Each log's last part was left out of the fit; the preset is validated on it. "
                 "Figures with each part's own torque offset removed."],
                [["log", "fit rms (Nm)", "fit r2", "held-out rms (Nm)", "held-out r2"]]
                + [[a.removesuffix(" (fit part)"), report.number(fa["rms_error_Nm"]),
                    report.number(fa["r2"]), report.number(fb["rms_error_Nm"]),
                    report.number(fb["r2"])]
                   for (a, fa), fb in zip(fit.per_log.items(), held_figures.values(), strict=True)],
            ))  # fmt: skip
        log_sections, _ = steering_sections(car, logs, folder, drift_s=drift_s,
                                            delay_s=fit.torque_delay_s)  # fmt: skip
        sections += log_sections
        sections += held_sections
        report.write(folder, f"Steering fit: {out.name}", sections)
    return fit


def _figures_only(
    car: SteeringCar, logs: Sequence[SteeringLog], drift_s: float | None, delay_s: float
) -> dict[str, dict[str, float]]:
    figures = {}
    for log in logs:
        _, model = model_torque(car, log, delay_s)
        model = model + _own_offset(log, log.torque_Nm - model, drift_s)
        rms, r2 = rms_r2(log.torque_Nm, model)
        figures[log.name] = {"rms_error_Nm": rms, "r2": r2}
    return figures


def validate(
    preset: str,
    paths: Sequence[Path],
    report_dir: Path,
    sources: Sources = Sources(),
    drift_s: float | None = None,
) -> dict[str, Any]:
    """Run a preset's model against logs; write the report; return the figures."""
    try:
        car = load_steering(preset).params
    except PresetError as steering_error:
        return _validate_shift(preset, paths, report_dir, steering_error, sources)
    outputs = Outputs()
    folder = outputs.add_folder(report_dir)
    with outputs:  # the report replaces an older one only when it is complete
        logs, _ = load_logs(paths, sources)
        sections, figures = steering_sections(car, logs, folder, drift_s=drift_s)
        report.write(folder, f"Validation of {Path(preset).name}", sections)
    return figures


def _validate_shift(
    preset: str, paths: Sequence[Path], report_dir: Path, why: Exception, sources: Sources
) -> dict[str, Any]:
    from carfeel.io.presets import load_shift

    try:
        params = load_shift(preset).params
    except PresetError as shift_error:
        reasons = dict.fromkeys((str(why), str(shift_error)))  # one line if both say the same
        raise InputError(
            f"{preset} is neither a steering nor a shift preset:\n" + "\n".join(reasons)
        ) from None
    from carfeel.identification import shift_workflows

    figures: dict[str, Any] = shift_workflows.validate_traces(
        params, paths, report_dir, sources.channels, sources.dbc
    )
    return figures


def fit_summary(fit: SteeringFit) -> str:
    fitted = sum(e.status == "fitted" for e in fit.estimates)
    lines = [f"fitted {fitted} of {len(fit.estimates)} parameters (and a torque offset per log) in "
             f"{fit.iterations} evaluations: rms error "
             f"{fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}"]  # fmt: skip
    lines += [
        f"  {e.name:30s} {e.value:10.5g} +- {e.sigma:.2g}"
        if e.status == "fitted"
        else f"  {e.name:30s} {e.value:10.5g}   kept from the base"
        for e in fit.estimates
    ]
    lines.append(f"  torque logged {fit.torque_delay_s * 1e3:.3g} ms after the other channels")
    if fit.holdout:
        lines.append("  cross-validation (rms Nm, r2): fitted part | held-out part")
        lines += [
            f"  {a}: {fa['rms_error_Nm']:.4g}, {fa['r2']:.4f} | {fb['rms_error_Nm']:.4g}, "
            f"{fb['r2']:.4f}"
            for (a, fa), fb in zip(
                fit.holdout["fit"].items(), fit.holdout["held_out"].values(), strict=True
            )
        ]
    lines += [f"  {name}: rms {v['rms_error_Nm']:.4g} Nm, r2 {v['r2']:.4f}"
              for name, v in fit.per_log.items()]  # fmt: skip
    lines += [f"warning: {w}" for w in fit.warnings]
    return "\n".join(lines)
