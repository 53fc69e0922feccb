"""A spec's parameters checked against its preset and its run: each key path and value (grids,
distributions), a parameter given twice, parameters the run's model does not read, and what a
case would only find when it runs (a gear the layout lacks, a manoeuvre at a speed)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from carfeel.errors import CarfeelError
from carfeel.sweep.definition import DISTRIBUTIONS, Value, Vary
from carfeel.sweep.paths import field_type, value_problem
from carfeel.sweep.settings import gears_of


def check_parameters(
    model: str,
    base: Any,
    run: Sequence[tuple[str, Any]],
    fixed: Sequence[tuple[str, Value]],
    vary: Sequence[Vary],
    problems: list[str],
) -> None:
    """Every problem of the spec's [set] and [vary] against the preset `base` and [run]
    (`run`: the checked settings), added to `problems`."""
    paths = [path for path, _ in fixed] + [v.path for v in vary]
    for path in {p for p in paths if paths.count(p) > 1}:
        problems.append(f"{path}: given more than once in [set] and [vary]; give it once")
    for key, _ in run:
        if f"run.{key}" in paths:
            problems.append(f"run.{key}: given in [run] and in [set] or [vary]; give it once")
    for path, value in fixed:
        _check_value(model, base, path, value, "set", problems)
    for v in vary:
        _check_vary(model, base, v, problems)
    _check_used(model, base, dict(run), paths, problems)
    if not problems:
        _check_runs(model, base, dict(run), fixed, vary, problems)


def _check_used(
    model: str, base: Any, run: Mapping[str, Any], paths: list[str], problems: list[str]
) -> None:
    """Every parameter set or varied must be one the run's model reads: else its rows would
    come out identical, as if it did not matter."""
    if model == "steering":
        physical = run.get("steering_model", "paper") == "physical"
        if "road" in run and not physical:
            problems.append(
                '[run] road sets the physical model\'s tyres: add steering_model = "physical", '
                "or drop road"
            )
        if "road" in run and "tyres.friction_coefficient" in paths:
            problems.append(
                "tyres.friction_coefficient and [run] road both give the tyres' mu: give one"
            )
        for path in paths:
            table = path.split(".")[0]
            if not physical and table in ("tyres", "steering_system"):
                problems.append(
                    f"{path}: only the physical steering model reads it; add [run] "
                    'steering_model = "physical", or drop it'
                )
            elif physical and table == "torque":
                problems.append(
                    f"{path}: the paper's torque law reads it, not the physical model (its "
                    "torque comes from its tyres and steering system); drop it, or use "
                    'steering_model = "paper"'
                )
    elif model == "hpattern" and "synchronizer.physics" not in paths:
        chosen = run.get("synchronizer")
        physics = chosen == "physics" if chosen is not None else base.synchronizer.physics
        if not physics:
            named = [p for p in paths if p.startswith("synchronizer.") or p == "run.engine_rpm"]
            if "engine_rpm" in run:
                named.append("[run] engine_rpm")
            for path in named:
                problems.append(
                    f"{path}: only the physics synchronizer reads it (this run's is the fixed "
                    'synchronization time); add [run] synchronizer = "physics", or drop it'
                )


def _check_runs(
    model: str,
    base: Any,
    run: Mapping[str, Any],
    fixed: Sequence[tuple[str, Any]],
    vary: Sequence[Vary],
    problems: list[str],
) -> None:
    """What a case would only find when it runs, found before any does: the sequence's gears in
    the preset's layout, the manoeuvre at every speed the grid gives it."""
    if model == "hpattern" and isinstance(run.get("sequence"), str):
        varied = {v.path.split(".")[0] for v in vary} | {p.split(".")[0] for p, _ in fixed}
        if "layout" not in varied:
            names = {g.name.upper() for g in base.layout.gears}
            unknown = [g for g in gears_of(run["sequence"]) if g not in names]
            if unknown:
                problems.append(
                    f"[run] sequence: no gear {', '.join(dict.fromkeys(unknown))} in the "
                    f"preset's layout; it has {', '.join(sorted(names))}"
                )
    if model == "steering" and isinstance(run.get("manoeuvre"), str):
        from carfeel.simulation import manoeuvres

        speeds: list[Any] = [run.get("speed_kmh")]
        for v in vary:
            if v.path == "run.speed_kmh":
                speeds = list(v.values) if v.values else [None]
        speeds += [value for path, value in fixed if path == "run.speed_kmh"]
        for speed in dict.fromkeys(speeds):
            if speed is not None and not isinstance(speed, int | float):
                continue
            try:
                manoeuvres.build(run["manoeuvre"], base.vehicle, speed)
            except CarfeelError as exc:
                where = "" if speed is None else f" at run.speed_kmh = {speed:g}"
                problems.append(f"[run] manoeuvre = {run['manoeuvre']!r}{where}: {exc}")


def _check_value(
    model: str, base: Any, path: str, value: Value, where: str, problems: list[str]
) -> None:
    problem = value_problem(model, base, path, value)
    if problem is not None:
        problems.append(f"[{where}] {problem}")


def _check_vary(model: str, base: Any, v: Vary, problems: list[str]) -> None:
    try:
        kind, _ = field_type(model, base, v.path)
    except KeyError as exc:
        problems.append(f"[vary] {v.path}: unknown parameter: {exc.args[0]}")
        return
    for value in v.values:
        _check_value(model, base, v.path, value, "vary", problems)
    if not v.distribution:
        return
    if kind is not float:
        problems.append(
            f"[vary] {v.path} is {'true/false' if kind is bool else 'a whole number'}"
            ": give a grid of values, not a distribution"
        )
        return
    names = DISTRIBUTIONS[v.distribution]
    args = dict(zip(names, v.args, strict=True))
    if "sd" in args and not args["sd"] > 0.0:
        problems.append(f"[vary] {v.path}: sd = {args['sd']:g} must be > 0")
    if "low" in args and not args["low"] < args["high"]:
        problems.append(
            f"[vary] {v.path}: low = {args['low']:g} must be below high = {args['high']:g}"
        )
    for name in ("low", "high", "mean"):
        if name in args:
            problem = value_problem(model, base, v.path, args[name])
            if problem is not None:
                what = "a bound" if name != "mean" else "the mean"
                problems.append(f"[vary] {v.path}: {name} is {what} of the draws: {problem}")
