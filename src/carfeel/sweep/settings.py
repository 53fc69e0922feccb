"""What each model's sweep runs and keeps: its run settings (`[run]`, read and checked here),
the run settings a sweep may vary with their range, its longest step, and its metrics."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from carfeel.simulation.manoeuvres import MANOEUVRES
from carfeel.simulation.steering import ROAD_FRICTION, STEERING_MODELS

MODELS = ("shift", "hpattern", "steering")

SHIFT_METRICS = {
    "synchronization_force_N": "median knob force on the synchronization plateau, N",
    "synchronization_peak_N": "highest knob force while the ring blocks, N",
    "synchronization_time_s": "how long the knob stayed at the synchro ring, s",
    "engagement_peak_N": "highest knob force in the teeth, N",
    "stop_peak_N": "highest knob force at the end stop, N",
    "stop_overshoot_m": "how far past the in-gear position the knob went, m",
    "shift_time_s": "from the start of the push to the knob at the end stop (the gear in), s",
    "balked": "the gear did not go in within the run",
}
HPATTERN_SHIFT_METRICS = {
    "synchronization_force_N": "median knob force on the plateau, N",
    "synchronization_time_s": "time at the synchro ring, s",
    "engagement_peak_N": "highest knob force in the teeth, N",
    "stop_peak_N": "highest knob force at the end stop, N",
    "engaged": "the gear went in",
}
HPATTERN_METRICS = {
    "total_time_s": "from the start to the last gear of the sequence engaged, s",
    "balked": "the sequence was not completed within the run",
    "ground": "the teeth ground (a failed blocking condition, or reverse at speed)",
    "peak_grind_N": "largest grinding vibration, N",
}
STEERING_METRICS = {
    "torque_gradient_Nm_per_g": "on-centre torque gradient (weave), Nm/g",
    "torque_at_0_1g_Nm": "torque at 0.1 g (weave), Nm",
    "deadband_g": "torque deadband (weave), g",
    "hysteresis_Nm": "torque hysteresis at 0 g (weave), Nm",
    "sensitivity_g_per_100deg": "steering sensitivity (weave), g per 100 deg",
    "understeer_gradient_deg_per_g": "understeer gradient (quasi-steady cornering), deg/g",
    "peak_torque_Nm": "largest steering wheel torque, Nm",
    "rms_lateral_accel_g": "rms lateral acceleration, g",
}
RUN_KEYS: dict[str, dict[str, tuple[type, ...]]] = {
    "shift": {"duration_s": (float, int), "dt_s": (float, int), "substeps": (int,)},
    "hpattern": {
        "sequence": (str, list),
        "speed_kmh": (float, int),
        "engine_rpm": (float, int),
        "clutch": (float, int),
        "synchronizer": (str,),
        "max_duration_s": (float, int),
        "dt_s": (float, int),
        "substeps": (int,),
    },
    "steering": {
        "manoeuvre": (str,),
        "speed_kmh": (float, int),
        "steering_model": (str,),
        "road": (str,),
        "dt_s": (float, int),
        "substeps": (int,),
    },
}
RUN_RANGES = {
    "speed_kmh": (0.0, 250.0),
    "engine_rpm": (0.0, 20000.0),
    "clutch": (0.0, 1.0),
}
"""Run settings a sweep may vary (`run.NAME`), with their allowed range."""
MAX_STEP_S = {"shift": 2e-3, "hpattern": 1e-3, "steering": 1e-3}
"""Longest model step of each model (simulation.*.MAX_STEP_S)."""
DEFAULT_CASES_PER_TASK = {"batch": 8192, "shift": 200, "hpattern": 8, "steering": 8}
"""About seconds of work per task on one core."""


def metric_names(model: str, run: Mapping[str, Any]) -> dict[str, str]:
    """Every metric a model's sweep can keep, with its description."""
    if model == "shift":
        return dict(SHIFT_METRICS)
    if model == "steering":
        return dict(STEERING_METRICS)
    names = {}
    for k, gear in enumerate(gears_of(run.get("sequence", "")), start=1):
        for name, text in HPATTERN_SHIFT_METRICS.items():
            names[f"shift{k}_{gear}_{name}"] = f"into {gear} (gear {k} of the sequence): {text}"
    names.update(HPATTERN_METRICS)
    return names


def gears_of(sequence: str | Sequence[str]) -> tuple[str, ...]:
    """The gears of a sequence, N not counted (as --mistake counts them)."""
    parts = sequence.split(",") if isinstance(sequence, str) else list(sequence)
    return tuple(p.strip().upper() for p in parts if p.strip().upper() != "N")


def read_run(model: str, table: Any, problems: list[str]) -> list[tuple[str, Any]]:
    """The spec's [run] settings, checked, sorted by name (each problem added to `problems`)."""
    if not isinstance(table, dict):
        problems.append(f"run = {table!r}: expected a table [run]")
        return []
    allowed = RUN_KEYS[model]
    out: dict[str, Any] = {}
    for key, value in table.items():
        if key not in allowed:
            problems.append(
                f"[run] {key}: unknown setting; the {model} sweep takes {', '.join(allowed)}"
            )
            continue
        if isinstance(value, bool) or not isinstance(value, allowed[key]):
            problems.append(
                f"[run] {key} = {value!r}: expected "
                f"{'a number' if float in allowed[key] else 'text'}"
            )
            continue
        out[key] = float(value) if float in allowed[key] else value  # type: ignore[arg-type]
    _check_steps(model, out, problems)
    if model == "hpattern":
        _check_hpattern(out, problems)
    if model == "steering":
        _check_steering(out, problems)
    return sorted(out.items())


def _check_steps(model: str, out: Mapping[str, Any], problems: list[str]) -> None:
    """Durations, steps and the ranges of the run settings a sweep may vary."""
    for key in ("duration_s", "dt_s", "max_duration_s"):
        if key in out and not (math.isfinite(out[key]) and out[key] > 0.0):
            problems.append(f"[run] {key} = {out[key]:g} s: expected > 0")
    if "substeps" in out and out["substeps"] < 1:
        problems.append(f"[run] substeps = {out['substeps']}: expected a whole number >= 1")
    for key, (low, high) in RUN_RANGES.items():
        if key in out and not low <= out[key] <= high:
            problems.append(f"[run] {key} = {out[key]:g}: allowed {low:g} <= value <= {high:g}")
    dt = out.get("dt_s", 1e-3)
    steps = out.get("substeps", 1)
    if dt / steps > MAX_STEP_S[model] * (1 + 1e-9):
        needed = math.ceil(dt / MAX_STEP_S[model] - 1e-9)
        problems.append(
            f"[run] dt_s / substeps = {dt / steps:g} s is longer than {MAX_STEP_S[model]:g} s, "
            f"where the {model} model stops being accurate; use substeps = {needed}"
        )


def _check_hpattern(out: dict[str, Any], problems: list[str]) -> None:
    """The sequence (a list of gears becomes its text, from N) and the synchronizer."""
    sequence = out.get("sequence")
    if sequence is None:
        problems.append('[run] sequence: missing; the gears to go through, e.g. "N,1,2,N"')
    elif isinstance(sequence, list) and not all(isinstance(g, str) for g in sequence):
        problems.append(f"[run] sequence = {sequence!r}: expected gear names")
    elif not gears_of(sequence):
        problems.append(f"[run] sequence = {sequence!r}: no gear to shift into")
    else:
        out["sequence"] = (
            ",".join(["N", *gears_of(sequence)]) if isinstance(sequence, list) else sequence
        )
    sync = out.get("synchronizer")
    if sync is not None and sync not in ("fixed", "physics"):
        problems.append(f"[run] synchronizer = {sync!r}: expected 'fixed' or 'physics'")


def _check_steering(out: Mapping[str, Any], problems: list[str]) -> None:
    """The manoeuvre, the steering model and the road by name."""
    manoeuvre = out.get("manoeuvre")
    if manoeuvre not in MANOEUVRES:
        problems.append(f"[run] manoeuvre = {manoeuvre!r}: expected one of {', '.join(MANOEUVRES)}")
    if out.get("steering_model", "paper") not in STEERING_MODELS:
        problems.append(
            f"[run] steering_model = {out['steering_model']!r}: expected one "
            f"of {', '.join(STEERING_MODELS)}"
        )
    if out.get("road", "dry") not in ROAD_FRICTION:  # (no road: the preset's mu)
        problems.append(f"[run] road = {out['road']!r}: expected one of {', '.join(ROAD_FRICTION)}")
