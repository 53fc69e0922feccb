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
from carfeel.identification import baselines, rms_r2
from carfeel.identification.common import Progress, read_results, write_checked_preset
from carfeel.identification.steering_fit import (
    MEANINGS,
    MIN_EXPLAINED,
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
    angle and speed; the regressors delayed by `delay_s` (the torque's logging delay) as the fit
    shifts them, the friction's memory run over the log."""
    from carfeel.identification.steering_fit import PAPER_LAW, law_inputs

    ay = (
        log.lateral_accel_m_s2
        if log.lateral_accel_m_s2 is not None
        else transient_ay(log.time_s, log.speed_m_s, log.angle_rad, car.vehicle)
    )
    regressors = law_inputs(log, ay, delay_s)
    x = np.array([getattr(car.torque, name) for name in PAPER_LAW.names])
    return np.asarray(ay), np.asarray(PAPER_LAW.torque(x, regressors))


def _own_offset(log: SteeringLog, residual: np.ndarray, drift_s: float | None) -> np.ndarray:
    """The log's own torque offset (constant, or drifting with knots `drift_s` apart): a
    nuisance of the sensor and the road, estimated from this log's residual alone."""
    basis = offset_basis(log.time_s, drift_s)
    coefficients = np.linalg.lstsq(basis, residual, rcond=None)[0]
    return np.asarray(basis @ coefficients)


def part_name(name: str) -> str:
    """A log's name without its part's label (the fit part and the held-out part of one log)."""
    for label in (" (fit part)", " (held out)", " (first part)", " (last part)"):
        name = name.removesuffix(label)
    return name


def scores(
    log: SteeringLog, model: np.ndarray, drift_s: float | None, offset: float | np.ndarray = 0.0
) -> tuple[dict[str, float], np.ndarray]:
    """A log's figures against a model's torque: the headline with `offset` (the fit's own
    offset for its logs, a log's first part's for its last, none for a preset on its own) and,
    beside it, with the log's own offset (constant, or drifting with knots `drift_s` apart)
    removed, which flatters any model: a sensor's bias or a road's crown is then no error.
    Returns them and the offset removed."""
    removed = _own_offset(log, log.torque_Nm - model, drift_s)
    rms, r2 = rms_r2(log.torque_Nm, model + offset)
    rms_o, r2_o = rms_r2(log.torque_Nm, model + removed)
    figures = {
        "rms_error_Nm": rms, "r2": r2, "rms_error_offset_removed_Nm": rms_o,
        "r2_offset_removed": r2_o, "offset_Nm": float(np.mean(removed)),
        "offset_range_Nm": float(np.ptp(removed)),
    }  # fmt: skip
    return figures, removed


def steering_sections(
    car: SteeringCar,
    logs: Sequence[SteeringLog],
    folder: Path,
    *,
    drift_s: float | None = None,
    delay_s: float = 0.0,
    first: int = 1,
    offsets: dict[str, float] | None = None,
) -> tuple[list[report.Section], dict[str, dict[str, float]]]:
    """Per log: overlays, residuals and the feel metrics measured vs model; and the figures by
    log name (`scores`: the headline with `offsets[name]`, 0 for a log not in it)."""
    from carfeel.io.plots import plot_torque_validation

    sections, figures = [], {}
    ratio, base = car.vehicle.steering_ratio, car.vehicle.wheelbase_m
    for i, log in enumerate(logs, start=first - 1):
        ay, model = model_torque(car, log, delay_s)
        applied = (offsets or {}).get(log.name, 0.0)
        values, removed = scores(log, model, drift_s, applied)
        figures[log.name] = values
        shown = model + applied
        figure = plot_torque_validation(
            log.time_s, ay, log.torque_Nm, shown, folder / f"steering-{i + 1}.png",
            f"{Path(log.name).name}: measured vs model",
        )  # fmt: skip
        measured, simulated = (
            steering_feel(log.time_s, log.speed_m_s, log.angle_rad, ay, torque,
                          steering_ratio=ratio, wheelbase_m=base)
            for torque in (log.torque_Nm, model + removed)
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
        given = "the fit's own torque offset" if applied else "no torque offset"
        sections.append(report.Section(
            f"Log {i + 1}: {log.name}",
            [f"rms error {values['rms_error_Nm']:.4g} Nm, r2 {values['r2']:.4f} with {given} "
             f"({applied:.3g} Nm); with the log's own offset (mean "
             f"{values['offset_Nm']:.3g} Nm, range {values['offset_range_Nm']:.3g} Nm) removed, "
             f"which no prediction knows: {values['rms_error_offset_removed_Nm']:.4g} Nm, r2 "
             f"{values['r2_offset_removed']:.4f}; {count(len(log.time_s), 'sample')}, Ay "
             f"{source}", *missing],
            table, [figure],
        ))  # fmt: skip
    return sections, figures


def baseline_inputs(car: SteeringCar, log: SteeringLog) -> baselines.Inputs:
    ay = (
        log.lateral_accel_m_s2
        if log.lateral_accel_m_s2 is not None
        else transient_ay(log.time_s, log.speed_m_s, log.angle_rad, car.vehicle)
    )
    return baselines.Inputs(part_name(log.name), log.time_s, log.angle_rad, log.rate_rad_s,
                            np.asarray(ay), log.torque_Nm)  # fmt: skip


def compare_with_baselines(
    car: SteeringCar, train: Sequence[SteeringLog], test: Sequence[SteeringLog],
    delay_s: float, offsets: dict[str, float],
) -> dict[str, dict[str, dict[str, float]]]:  # fmt: skip
    """The model (its torque on `test` with `offsets` by log name, 0 where none) and the
    baselines trained on `train`, all scored on `test`: {model: {log or "all": figures}}."""
    out = baselines.compare([baseline_inputs(car, log) for log in train],
                            [baseline_inputs(car, log) for log in test])  # fmt: skip
    law: dict[str, dict[str, float]] = {}
    measured, predicted = [], []
    for log in test:
        _, model = model_torque(car, log, delay_s)
        model = model + offsets.get(log.name, 0.0)
        rms, r2 = rms_r2(log.torque_Nm, model)
        law[part_name(log.name)] = {"rms_error_Nm": rms, "r2": r2}
        measured.append(log.torque_Nm)
        predicted.append(model)
    rms, r2 = rms_r2(np.concatenate(measured), np.concatenate(predicted))
    law["all"] = {"rms_error_Nm": rms, "r2": r2}
    return {"model": law, **out}


def baseline_section(
    compared: dict[str, dict[str, dict[str, float]]], split: str
) -> report.Section:
    """The comparison as a report section: one row per model, r2 and rms over all the test
    samples, then r2 per log."""
    logs = [name for name in compared["model"] if name != "all"]
    head = ["model", "r2", "rms (Nm)", *(f"r2 {Path(n).name}" for n in logs)]
    rows = [
        [name, report.number(c["all"]["r2"]), report.number(c["all"]["rms_error_Nm"]),
         *(report.number(c[n]["r2"]) for n in logs)]
        for name, c in compared.items()
    ]  # fmt: skip
    best = max(compared, key=lambda name: compared[name]["all"]["r2"])
    verdict = (
        "the physical model predicts best"
        if best == "model"
        else f"the {best} baseline predicts better than the physical model: it misses what the "
        "black box finds in the data (Ay, the friction's history, the EPS dynamics?)"
    )
    return report.Section(
        "Beside black boxes, on the same split",
        [f"{split} The baselines: a linear fit a angle + b rate + c and a ridge regression on "
         "the angle, rate and Ay lagged 0 to 0.8 s, each with one intercept per log fitted on "
         f"its training part. No figure here removes an offset fitted on the scored samples. "
         f"Here {verdict}."],
        [head, *rows],
    )  # fmt: skip


def comparison_lines(compared: dict[str, dict[str, dict[str, float]]], split: str) -> list[str]:
    """The comparison as a summary prints it."""
    lines = [f"  beside black boxes ({split}): r2, rms (Nm) over all scored samples"]
    lines += [f"    {name:14s} {c['all']['r2']:8.4f} {c['all']['rms_error_Nm']:8.4g}"
              for name, c in compared.items()]  # fmt: skip
    return lines


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
    fit_vehicle: bool | None = None,
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
    fit_vehicle: bool | None,
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
    if fit.law_test is not None and fit.law_explains < MIN_EXPLAINED:
        raise InputError(
            f"the logs identify no steering feel: the fitted law (r2 {fit.r2:.3g}; every "
            f"parameter free, r2 {fit.free_fit.get('r2', math.nan):.3g}) removes "
            f"{fit.law_explains:.2%} of the torque's variance about a torque offset per log, "
            f"under the {MIN_EXPLAINED:.0%} a law must explain to be one (likelihood ratio "
            f"against none p = {fit.law_test.p_value:.2g}); a preset from them would be fitted "
            "to noise, so none is written. Log the manoeuvres that load the wheel: a weave, a "
            "lane change, a steady-state circle, parking"
        )
    held_figures: dict[str, dict[str, float]] = {}
    held_sections: list[report.Section] = []
    end_offsets = {part_name(name): v["offset_end_Nm"] for name, v in fit.per_log.items()}
    if held:
        # The held-out parts are predicted as the preset would: with the offset its own log's
        # fit ended with, not one fitted on them.
        carried = {log.name: end_offsets.get(part_name(log.name), 0.0) for log in held}
        if folder is not None:
            held_sections, held_figures = steering_sections(
                fit.car, held, folder, drift_s=drift_s, delay_s=fit.torque_delay_s,
                first=len(logs) + 1, offsets=carried,
            )  # fmt: skip
        else:
            held_figures = _figures_only(fit.car, held, drift_s, fit.torque_delay_s, carried)
        fit = dataclasses.replace(fit, holdout={"fit": fit.per_log, "held_out": held_figures})
        split = (f"Trained on the first {1 - holdout:.0%} of each log (the fit's part), scored "
                 f"on the last {holdout:.0%}.")  # fmt: skip
        compared = compare_with_baselines(fit.car, logs, held, fit.torque_delay_s, carried)
    else:
        split = ("In sample: trained and scored on the whole logs (a black box with 18 inputs "
                 "wins in sample more often than out of it; give --holdout 0.3 to compare on "
                 "data no model saw).")  # fmt: skip
        own = {log.name: end_offsets.get(part_name(log.name), 0.0) for log in logs}
        compared = compare_with_baselines(fit.car, logs, logs, fit.torque_delay_s, own)
        compared["model"] = {part_name(n): {"rms_error_Nm": v["rms_error_Nm"], "r2": v["r2"]}
                             for n, v in fit.per_log.items()}  # fmt: skip
        compared["model"]["all"] = {"rms_error_Nm": fit.rms_error_Nm, "r2": fit.r2}
    fit = dataclasses.replace(fit, baselines=compared, baseline_split=split)
    kept = [e.name for e in fit.estimates if e.status == "kept"]
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
             ("fitted" + (f": {e.note}" if e.note else "")) if e.status == "fitted" else e.note,
             MEANINGS.get(e.name, "")]
            for e in fit.estimates
        ]  # fmt: skip
        names, matrix = fit.correlation
        correlation = [["", *names]] + [
            [n, *(report.number(v, 2) for v in row)] for n, row in zip(names, matrix, strict=True)
        ]
        conditional = (
            f" The sigmas are conditional on the values kept from the base ({', '.join(kept)})."
            if kept
            else ""
        )
        summary = report.Section(
            "Fit",
            [f"rms error {fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}, {fit.iterations} evaluations; "
             f"torque logged {fit.torque_delay_s * 1e3:.3g} ms after the other channels "
             "(corrected). One sigma from a block sandwich covariance (blocks of 2 s)."
             + conditional,
             f"The free fit (every candidate free, before any is kept): rms error "
             f"{fit.free_fit['rms_error_Nm']:.4g} Nm, r2 {fit.free_fit['r2']:.4f}. A value is "
             "kept from the base only where the fit with it held there is as good (a likelihood "
             "ratio scaled for the residuals' correlation, p > 0.01); the tests are below.",
             *(f"Warning: {w}" for w in fit.warnings)],
            table,
        )  # fmt: skip
        tests = report.Section(
            "What is kept from the base, and the tests that decided",
            ["Each candidate (a parameter the logs hardly excite, or one the free fit leaves at "
             "a bound, within a sigma of one, unconstrained or poorly pinned) held at the base's "
             "value with every kept one before it, the rest refitted, against the free fit."],
            [["held at the base's values", "statistic", "dof", "p", "kept"]]
            + [[", ".join(t.held), report.number(t.statistic), str(t.dof),
                report.number(t.p_value, 2), "yes" if t.kept else "no: written as fitted"]
               for t in fit.keep_tests]
            + ([[f"{fit.law_test.held[0]}, against the law written", report.number(
                fit.law_test.statistic), str(fit.law_test.dof), report.number(
                fit.law_test.p_value, 2), (f"the law removes {fit.law_explains:.1%} of the "
                "variance about the offsets: " + ("not significantly better than none"
                if fit.law_test.kept else "significant"))]] if fit.law_test else []),
        )  # fmt: skip
        sections = [summary, tests, baseline_section(compared, split),
                    report.Section("Parameter correlations", [], correlation)]  # fmt: skip
        if held:
            sections.append(report.Section(
                "Cross-validation: the fitted part and the held-out part of each log",
                ["Each log's last part was left out of the fit; the preset is validated on it, "
                 "with the torque offset its fitted part ended with (the headline), and with the "
                 "held-out part's own offset removed beside it."],
                [["log", "fit rms (Nm)", "fit r2", "held-out rms (Nm)", "held-out r2",
                  "held-out r2, its offset removed"]]
                + [[part_name(a), report.number(fa["rms_error_Nm"]), report.number(fa["r2"]),
                    report.number(fb["rms_error_Nm"]), report.number(fb["r2"]),
                    report.number(fb["r2_offset_removed"])]
                   for (a, fa), fb in zip(fit.per_log.items(), held_figures.values(), strict=True)],
            ))  # fmt: skip
        own_offsets = {log.name: fit.per_log[log.name]["offset_Nm"] for log in logs}
        log_sections, _ = steering_sections(car, logs, folder, drift_s=drift_s,
                                            delay_s=fit.torque_delay_s,
                                            offsets=own_offsets)  # fmt: skip
        sections += log_sections
        sections += held_sections
        report.write(folder, f"Steering fit: {out.name}", sections)
    return fit


def _figures_only(
    car: SteeringCar, logs: Sequence[SteeringLog], drift_s: float | None, delay_s: float,
    offsets: dict[str, float],
) -> dict[str, dict[str, float]]:  # fmt: skip
    figures = {}
    for log in logs:
        _, model = model_torque(car, log, delay_s)
        figures[log.name] = scores(log, model, drift_s, offsets.get(log.name, 0.0))[0]
    return figures


VALIDATE_SPLIT = 0.3
"""validate's baselines are trained on the first 70 % of each log; all is scored on the rest."""


def validate(
    preset: str,
    paths: Sequence[Path],
    report_dir: Path,
    sources: Sources = Sources(),
    drift_s: float | None = None,
) -> dict[str, Any]:
    """Run a preset's model against logs; write the report; return the figures per log (the
    headline without any offset, `scores`) and, under "comparison", the model beside the
    baselines on each log's last 30 % (the baselines, and the model's offset, from its first
    70 %)."""
    try:
        car = load_steering(preset).params
    except PresetError as steering_error:
        return _validate_shift(preset, paths, report_dir, steering_error, sources)
    outputs = Outputs()
    folder = outputs.add_folder(report_dir)
    with outputs:  # the report replaces an older one only when it is complete
        logs, _ = load_logs(paths, sources)
        sections, figures = steering_sections(car, logs, folder, drift_s=drift_s)
        firsts, lasts = split_logs(logs, VALIDATE_SPLIT)
        offsets = {}
        for first, last in zip(firsts, lasts, strict=True):
            _, model = model_torque(car, first)
            offsets[last.name] = float(np.mean(first.torque_Nm - model))
        split = (
            f"Trained on the first {1 - VALIDATE_SPLIT:.0%} of each log (the baselines; the "
            f"model only its torque offset), scored on the last {VALIDATE_SPLIT:.0%}."
        )
        compared = compare_with_baselines(car, firsts, lasts, 0.0, offsets)
        sections.insert(0, baseline_section(compared, split))
        report.write(folder, f"Validation of {Path(preset).name}", sections)
    return {**figures, "comparison": {"split": split, **compared}}


def split_logs(
    logs: Sequence[SteeringLog], fraction: float
) -> tuple[list[SteeringLog], list[SteeringLog]]:
    """Each log's first part and its last `fraction` (in time), named as such."""
    firsts: list[SteeringLog] = []
    lasts: list[SteeringLog] = []
    for log in logs:
        t = log.time_s
        cut = int(np.searchsorted(t, t[0] + (1.0 - fraction) * (t[-1] - t[0])))
        for keep, into, label in ((slice(0, cut), firsts, "first part"),
                                  (slice(cut, None), lasts, "last part")):  # fmt: skip
            into.append(dataclasses.replace(
                log, name=f"{log.name} ({label})", time_s=t[keep], speed_m_s=log.speed_m_s[keep],
                angle_rad=log.angle_rad[keep], rate_rad_s=log.rate_rad_s[keep],
                torque_Nm=log.torque_Nm[keep],
                lateral_accel_m_s2=None if log.lateral_accel_m_s2 is None
                else log.lateral_accel_m_s2[keep],
                rate_error_rad_s=None if log.rate_error_rad_s is None
                else log.rate_error_rad_s[keep],
            ))  # fmt: skip
    return firsts, lasts


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
    if fit.free_fit and any(e.status == "kept" for e in fit.estimates):
        lines.append(
            f"  (the free fit: rms {fit.free_fit['rms_error_Nm']:.4g} Nm, r2 "
            f"{fit.free_fit['r2']:.4f}; the sigmas are conditional on what is kept)"
        )
    lines += [
        f"  {e.name:30s} {e.value:10.5g} +- {e.sigma:.2g}"
        if e.status == "fitted"
        else f"  {e.name:30s} {e.value:10.5g}   kept from the base"
        for e in fit.estimates
    ]
    lines.append(f"  torque logged {fit.torque_delay_s * 1e3:.3g} ms after the other channels")
    if fit.holdout:
        lines.append("  cross-validation (rms Nm, r2): fitted part | held-out part (with the fit "
                     "part's offset; r2 with its own offset removed)")  # fmt: skip
        lines += [
            f"  {part_name(a)}: {fa['rms_error_Nm']:.4g}, {fa['r2']:.4f} | "
            f"{fb['rms_error_Nm']:.4g}, {fb['r2']:.4f} ({fb['r2_offset_removed']:.4f})"
            for (a, fa), fb in zip(
                fit.holdout["fit"].items(), fit.holdout["held_out"].values(), strict=True
            )
        ]
    if fit.baselines:
        split = "held out" if fit.holdout else "in sample"
        lines += comparison_lines(fit.baselines, split)
    lines += [f"  {name}: rms {v['rms_error_Nm']:.4g} Nm, r2 {v['r2']:.4f}"
              for name, v in fit.per_log.items()]  # fmt: skip
    lines += [f"warning: {w}" for w in fit.warnings]
    return "\n".join(lines)
