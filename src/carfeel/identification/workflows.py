"""What `carfeel fit` and `carfeel validate` do: read logs, fit or compare, write presets and
reports. Functions over paths and small configs; the CLI only parses and prints."""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from carfeel import __version__
from carfeel.analysis.steering_feel import steering_feel
from carfeel.errors import InputError, PresetError
from carfeel.identification import rms_r2
from carfeel.identification.steering_fit import (
    SteeringFit,
    SteeringLog,
    fit_steering,
    read_log,
    steady_ay,
)
from carfeel.io import report
from carfeel.io.presets import load_steering, to_toml
from carfeel.models.steering.torque import torque_terms
from carfeel.simulation.result import Result
from carfeel.simulation.steering import SteeringCar

FEEL_KEYS = (
    "torque_gradient_Nm_per_g", "torque_at_0_1g_Nm", "deadband_g", "hysteresis_Nm",
    "sensitivity_g_per_100deg", "understeer_gradient_deg_per_g",
)  # fmt: skip


class Progress:
    """A one-line progress display on stderr, for fits that take more than a moment."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label, self.enabled = label, enabled and sys.stderr.isatty()
        self.start = time.monotonic()
        self.shown = False

    def __call__(self, evaluations: int, rms: float) -> None:
        if self.enabled and time.monotonic() - self.start > 0.5:
            self.shown = True
            print(f"\r{self.label}: evaluation {evaluations}, rms {rms:.4g}", end="",
                  file=sys.stderr, flush=True)  # fmt: skip

    def done(self) -> None:
        if self.shown:
            print(file=sys.stderr)


def write_checked_preset(kind: str, out: Path, text: str) -> None:
    """Write a fitted preset only if carfeel's own loader accepts it (ranges, cross-checks);
    else InputError: a fit that leaves the physical ranges means the data, not the preset."""
    from carfeel.io.presets import from_toml

    try:
        from_toml(kind, str(out), text)
    except PresetError as exc:
        raise InputError(
            f"the fit gives a {kind} preset that carfeel would refuse, so {out} is not written:"
            f"\n{exc}\ncheck the logs' units and sign conventions (README, 'From your own car's "
            "logs') and that they hold the manoeuvres the fit needs"
        ) from None
    out.write_text(text)


def load_logs(paths: Sequence[Path]) -> list[SteeringLog]:
    logs = []
    for path in paths:
        logs.append(read_log(Result.from_csv(path), str(path)))
    return logs


def model_torque(car: SteeringCar, log: SteeringLog) -> tuple[np.ndarray, np.ndarray]:
    """(Ay, model torque) for a log: its measured Ay, else the car's steady state."""
    v = car.vehicle
    ay = (
        log.lateral_accel_m_s2
        if log.lateral_accel_m_s2 is not None
        else steady_ay(log.speed_m_s, log.angle_rad, v.steering_ratio,
                       v.understeer_gradient_rad_s2_m, v.wheelbase_m)
    )  # fmt: skip
    torque = torque_terms(log.speed_m_s, log.rate_rad_s, ay, car.torque, atan=np.arctan)[0]
    return np.asarray(ay), np.asarray(torque)


def steering_sections(
    car: SteeringCar, logs: Sequence[SteeringLog], folder: Path
) -> tuple[list[report.Section], dict[str, dict[str, float]]]:
    """Per log: overlays, residuals and the feel metrics measured vs model; and the figures
    (rms_error_Nm, r2) by log name."""
    from carfeel.io.plots import plot_torque_validation

    sections, figures = [], {}
    ratio, base = car.vehicle.steering_ratio, car.vehicle.wheelbase_m
    for i, log in enumerate(logs):
        ay, model = model_torque(car, log)
        rms, r2 = rms_r2(log.torque_Nm, model)
        figures[log.name] = {"rms_error_Nm": rms, "r2": r2}
        figure = plot_torque_validation(
            log.time_s, ay, log.torque_Nm, model, folder / f"steering-{i + 1}.png",
            f"{Path(log.name).name}: measured vs model",
        )  # fmt: skip
        measured, simulated = (
            steering_feel(log.time_s, log.speed_m_s, log.angle_rad, ay, torque,
                          steering_ratio=ratio, wheelbase_m=base)
            for torque in (log.torque_Nm, model)
        )  # fmt: skip
        table = [["metric", "measured", "model"]] + [
            [key, report.number(getattr(measured, key)), report.number(getattr(simulated, key))]
            for key in FEEL_KEYS
        ]
        source = "measured" if log.lateral_accel_m_s2 is not None else "from the car model"
        sections.append(report.Section(
            f"Log {i + 1}: {log.name}",
            [f"rms error {rms:.4g} Nm, mean residual {np.mean(model - log.torque_Nm):.3g} Nm, "
             f"r2 {r2:.4f}, {len(log.time_s)} samples, Ay {source}"],
            table, [figure],
        ))  # fmt: skip
    return sections, figures


def fit_steering_logs(
    paths: Sequence[Path],
    out: Path,
    *,
    base: str = "b-segment",
    fit_vehicle: bool = False,
    report_dir: Path | None = None,
    show_progress: bool = True,
) -> SteeringFit:
    """Fit the torque law to the logs; write the preset (and the report)."""
    preset = load_steering(base)
    logs = load_logs(paths)
    folder = report.prepare(report_dir) if report_dir is not None else None
    progress = Progress("fitting K1..K9", show_progress)
    fit = fit_steering(logs, preset.params, fit_vehicle=fit_vehicle, progress=progress)
    progress.done()
    lines = [
        f"Fitted by carfeel {__version__} to {', '.join(Path(p).name for p in paths)}",
        f"(rms error {fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}; torque sensor offset "
        f"{fit.torque_offset_Nm:.3g} Nm removed), from the base preset {preset.name}.",
        *(f"{e.name} = {e.value:.6g} +- {e.sigma:.2g}" for e in fit.estimates),
        *(f"warning: {w}" for w in fit.warnings),
    ]
    car = fit.car
    tables = {"vehicle": car.vehicle, "torque": car.torque, "driver": car.driver}
    text = to_toml(out.stem, "\n".join(lines), tables)
    write_checked_preset("steering", out, text)
    if folder is not None:
        table = [["parameter", "value", "1 sigma"]] + [
            [e.name, report.number(e.value, 6), report.number(e.sigma, 2)] for e in fit.estimates
        ]
        summary = report.Section(
            "Fit",
            [f"rms error {fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}, {fit.iterations} evaluations",
             *(f"Warning: {w}" for w in fit.warnings)],
            table,
        )  # fmt: skip
        sections, _ = steering_sections(car, logs, folder)
        report.write(folder, f"Steering fit: {out.name}", [summary, *sections])
    return fit


def validate(preset: str, paths: Sequence[Path], report_dir: Path) -> dict[str, Any]:
    """Run a preset's model against logs; write the report; return the figures."""
    try:
        car = load_steering(preset).params
    except PresetError as steering_error:
        return _validate_shift(preset, paths, report_dir, steering_error)
    logs = load_logs(paths)
    folder = report.prepare(report_dir)
    sections, figures = steering_sections(car, logs, folder)
    report.write(folder, f"Validation of {Path(preset).name}", sections)
    return figures


def _validate_shift(
    preset: str, paths: Sequence[Path], report_dir: Path, why: Exception
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

    figures: dict[str, Any] = shift_workflows.validate_traces(params, paths, report_dir)
    return figures


def fit_summary(fit: SteeringFit) -> str:
    lines = [f"fitted {len(fit.estimates)} parameters in {fit.iterations} evaluations: rms error "
             f"{fit.rms_error_Nm:.4g} Nm, r2 {fit.r2:.4f}"]  # fmt: skip
    lines += [f"  {e.name:30s} {e.value:10.5g} +- {e.sigma:.2g}" for e in fit.estimates]
    lines += [f"  {name}: rms {v['rms_error_Nm']:.4g} Nm, r2 {v['r2']:.4f}"
              for name, v in fit.per_log.items()]  # fmt: skip
    lines += [f"warning: {w}" for w in fit.warnings]
    return "\n".join(lines)
