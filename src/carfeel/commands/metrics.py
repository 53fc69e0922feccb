"""`carfeel metrics steering`: the steering feel figures of a run or a measured log."""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.analysis.steering_feel import LABELS, SteeringFeel, feel_lines, feel_of
from carfeel.commands.common import source_options, sources_of, to_json
from carfeel.errors import InputError
from carfeel.io.presets import load_steering
from carfeel.simulation.result import Result
from carfeel.text import count

REQUIRED_STEERING_COLUMNS = (
    "time_s",
    "speed_m_s",
    "steering_angle_rad",
    "lateral_accel_m_s2",
    "torque_Nm",
)


FEEL_LABELS = LABELS


def steering_metrics(
    csv_path: Path,
    preset: str | None = None,
    channels: Path | None = None,
    dbc: Path | None = None,
) -> SteeringFeel:
    """The feel metrics of a steering CSV (a run of carfeel's or a measured log; other formats
    and a channel map through `carfeel.io.logs`).

    The understeer gradient needs the steering ratio and wheelbase: from `preset` if given, else
    from the run's metadata file beside the CSV, else the default car preset.
    """
    from carfeel.identification.common import check_torque_logged, read_results

    result = read_results([csv_path], channels, dbc)[0]
    if "torque_Nm" not in result.names and "steering_torque_Nm" in result.names:
        result = Result(
            result.time_s,
            {
                ("torque_Nm" if k == "steering_torque_Nm" else k): v
                for k, v in result.signals.items()
            },
        )
    missing = [c for c in REQUIRED_STEERING_COLUMNS if c not in result.names]
    if missing:
        raise InputError(
            f"{csv_path}: missing column(s) {', '.join(missing)}; a steering log needs "
            f"{', '.join(REQUIRED_STEERING_COLUMNS)} (SI units: s, m/s, rad, m/s^2, Nm)"
        )
    for name in REQUIRED_STEERING_COLUMNS:
        values = result[name]
        if values.dtype.kind != "f":
            raise InputError(f"{csv_path}: column {name} must hold numbers")
        bad = ~np.isfinite(values)
        if bad.any():
            row = int(np.flatnonzero(bad)[0]) + 2
            raise InputError(f"{csv_path}, line {row}: {name} is not a finite number")
    if len(result) < 3:
        raise InputError(
            f"{csv_path}: {count(len(result), 'row')}; the metrics need a run of samples"
        )
    steps = np.diff(result.time_s)
    if np.any(steps <= 0):
        row = int(np.flatnonzero(steps <= 0)[0]) + 3
        raise InputError(f"{csv_path}, line {row}: time_s does not increase from the row before")
    check_torque_logged(str(csv_path), "torque_Nm", result["torque_Nm"])
    ratio, wheelbase, where = _car_geometry(csv_path, preset)
    _check_angle_unit(csv_path, result, preset, ratio, wheelbase)
    feel = feel_of(result, ratio, wheelbase)
    note = (
        f"understeer gradient with steering ratio {ratio:g} and wheelbase {wheelbase:g} m {where}"
    )
    return replace(feel, notes=(*feel.notes, note))


def _check_angle_unit(
    csv_path: Path, result: Result, preset: str | None, ratio: float, wheelbase: float
) -> None:
    """An angle in degrees makes the sensitivity 57 times too small: Ay gives it away."""
    from carfeel.identification.steering_checks import (
        ay_angle_correlation,
        ay_gain,
        looks_like_degrees,
        opposite_sign_problem,
    )

    vehicle = replace(
        load_steering(preset or "b-segment").params.vehicle,
        steering_ratio=ratio, wheelbase_m=wheelbase,
    )  # fmt: skip
    gain = ay_gain(result["speed_m_s"], result["steering_angle_rad"],
                   result["lateral_accel_m_s2"], vehicle)  # fmt: skip
    problem = opposite_sign_problem(
        str(csv_path),
        ay_angle_correlation(result.time_s, result["speed_m_s"], result["steering_angle_rad"],
                             result["lateral_accel_m_s2"], vehicle),
    )  # fmt: skip
    if problem:
        raise InputError(problem)
    if looks_like_degrees(abs(gain)):
        raise InputError(
            f"{csv_path}: the measured lateral_accel_m_s2 is {gain:.3g} times the steady-state Ay "
            "of the car from speed and steering_angle_rad (about 1 expected): the angle looks like "
            "degrees; convert it to radians"
        )


def _car_geometry(csv_path: Path, preset: str | None) -> tuple[float, float, str]:
    """(steering ratio, wheelbase, where they came from) for a log's understeer gradient."""
    if preset is None:
        meta_path = csv_path.with_suffix(".json")
        if meta_path.is_file():
            try:
                meta = json.loads(meta_path.read_text(encoding="utf-8"))
                ratio, wheelbase = float(meta["steering_ratio"]), float(meta["wheelbase_m"])
                if ratio > 0.0 and wheelbase > 0.0 and math.isfinite(ratio * wheelbase):
                    return ratio, wheelbase, f"from {meta_path.name}"
            except (ValueError, KeyError, TypeError, UnicodeDecodeError, OSError):
                pass  # not ours, or not a steering run: fall back to the default car
    name = preset or "b-segment"
    vehicle = load_steering(name).params.vehicle
    hint = "" if preset else " (no metadata beside the CSV; give --preset for your car)"
    return vehicle.steering_ratio, vehicle.wheelbase_m, f"of preset {name}{hint}"


def register(commands: Any) -> None:
    """Add `metrics` and their options."""
    metrics = commands.add_parser(
        "metrics",
        help="figures computed from a run or a measured log",
        description="Compute figures from a CSV written by carfeel or measured on a car.",
    )
    metric_kinds = metrics.add_subparsers(dest="kind", metavar="KIND", required=True)
    feel = metric_kinds.add_parser(
        "steering",
        help="steering feel: torque gradient, torque at 0.1 g, deadband, hysteresis, "
        "sensitivity, understeer gradient",
        description="Steering feel metrics (after ISO 13674-1) of a CSV with the columns "
        "time_s, speed_m_s, steering_angle_rad, lateral_accel_m_s2, torque_Nm. A weave "
        "(carfeel simulate steering --manoeuvre weave) gives all six.",
    )
    feel.add_argument("csv", metavar="FILE.csv", help="run or log to analyse")
    feel.add_argument("--json", action="store_true", help="print one JSON object")
    source_options(feel)
    feel.add_argument(
        "--preset",
        default=None,
        metavar="NAME|PATH",
        help="car preset for the steering ratio and wheelbase (default: from the run's .json "
        "beside the CSV, else b-segment)",
    )
    metrics.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    code: int = _metrics_steering(args)
    return code


def _metrics_steering(args: argparse.Namespace) -> int:
    feel = steering_metrics(Path(args.csv), args.preset, *sources_of(args))
    if args.json:
        values = {k: (None if math.isnan(v) else v) for k, v in feel.as_dict().items()}
        print(to_json({**values, "notes": list(feel.notes)}))
    else:
        print(f"steering feel of {args.csv}:")
        print("\n".join(feel_lines(feel)))
    return 0
