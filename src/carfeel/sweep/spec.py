"""A sweep's spec (TOML), validated once like a preset, and the cases it asks for.

    model = "shift"                  # shift | hpattern | steering
    preset = "paper-first-gear"      # shipped name, or a path (relative to the spec's folder)
    seeds = 4                        # seeds 0..3 for every parameter set (or a list of seeds)
    samples = 200                    # Monte Carlo draws (when a parameter has a distribution)
    sampling = "latin"               # random (default) | latin (Latin hypercube)
    sampling_seed = 1                # seed of the draws
    metrics = ["engagement_peak_N"]  # default: all of the model's (see METRICS)
    engine = "batch"                 # shift only: batch (vectorized, default) | pure

    [run]                            # what is simulated: shift duration, sequence, manoeuvre
    duration_s = 1.2

    [set]                            # fixed changes to the preset, by key path
    "driver.push_force_N" = 90.0

    [vary]                           # by key path: a grid of values, or a distribution
    "gearbox.chamfer.gear_inertia_kg_m2" = { values = [0.1, 0.153, 0.2] }
    "driver.push_velocity_m_s" = { distribution = "uniform", low = 0.15, high = 0.4 }
    "gearbox.engagement.sliding_friction_N" = { distribution = "normal", mean = 10, sd = 1 }
    "gearbox.neutral.static_friction_N" = { distribution = "truncnormal", mean = 1.5, sd = 0.3,
                                            low = 1.0, high = 2.0 }

The parameter sets are the grid's product times the draws (the same draws at every grid point);
each set runs every seed: one case, one row. Key paths name preset fields (`gearbox.stop.
stiffness_N_m`, `layout.gears[2].ratio`; an H-pattern's engagement preset under `shift.`) or
run settings (`run.speed_kmh`). Everything checkable is checked here, with every problem named in
one error; a drawn value that the preset's validation refuses (a normal draw out of range, a
sliding friction above the static) makes that row `invalid`, with the problem, not the sweep.

Here the TOML is read and its top keys checked; beside it: `definition` (the plain data),
`settings` (each model's [run] and metrics), `tables` ([set], [vary], seeds), `checks` (against
the preset and the run), `paths` (key paths, value checks), `base` (the preset's parameters),
`draws` (sampling, parameter sets), `cases` (cases, one case's parameters). Their public names
are importable from here as before.
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.errors import CarfeelError, PresetError
from carfeel.io import presets
from carfeel.sweep.base import HPatternCase, base_params
from carfeel.sweep.cases import apply, case_problems, cases, checked_case, iter_cases
from carfeel.sweep.checks import check_parameters
from carfeel.sweep.definition import (
    DISTRIBUTIONS,
    MAX_CASES,
    Case,
    SpecError,
    SweepSpec,
    Value,
    Vary,
)
from carfeel.sweep.draws import Draws, draws_of, iter_parameter_sets, parameter_sets
from carfeel.sweep.paths import field_type, value_problem
from carfeel.sweep.settings import (
    DEFAULT_CASES_PER_TASK,
    HPATTERN_METRICS,
    HPATTERN_SHIFT_METRICS,
    MAX_STEP_S,
    MODELS,
    RUN_KEYS,
    RUN_RANGES,
    SHIFT_METRICS,
    STEERING_METRICS,
    gears_of,
    metric_names,
    read_run,
)
from carfeel.sweep.tables import read_assignments, read_seeds, read_vary, said

__all__ = [  # the sweep's spec as one module: these were all defined here before the split
    "DEFAULT_CASES_PER_TASK",
    "DISTRIBUTIONS",
    "HPATTERN_METRICS",
    "HPATTERN_SHIFT_METRICS",
    "MAX_CASES",
    "MAX_SPEC_BYTES",
    "MAX_STEP_S",
    "MODELS",
    "RUN_KEYS",
    "RUN_RANGES",
    "SHIFT_METRICS",
    "STEERING_METRICS",
    "TOP_KEYS",
    "Case",
    "Draws",
    "HPatternCase",
    "SpecError",
    "SweepSpec",
    "Value",
    "Vary",
    "apply",
    "base_params",
    "case_problems",
    "cases",
    "checked_case",
    "draws_of",
    "field_type",
    "from_toml",
    "gears_of",
    "iter_cases",
    "iter_parameter_sets",
    "load",
    "metric_names",
    "parameter_sets",
    "value_problem",
]

TOP_KEYS = (
    "model",
    "preset",
    "seeds",
    "samples",
    "sampling",
    "sampling_seed",
    "metrics",
    "engine",
    "cases_per_task",
    "run",
    "set",
    "vary",
)
MAX_SPEC_BYTES = 1024 * 1024
"""The largest spec file read (a spec is a page of TOML; its grids' values are in it)."""


def load(path: Path) -> SweepSpec:
    """Read and validate a spec file; SpecError names every problem and its fix."""
    try:
        size = path.stat().st_size
        if size > MAX_SPEC_BYTES:
            raise SpecError(
                f"sweep spec {path} is {size} bytes; a spec is at most {MAX_SPEC_BYTES} bytes "
                "(a page of TOML: give long grids as distributions)"
            )
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SpecError(f"sweep spec {path} not found; give the path of a .toml file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"sweep spec {path} cannot be read: {exc}") from None
    return from_toml(text, str(path), path.parent)


def from_toml(text: str, label: str = "<spec>", folder: Path | None = None) -> SweepSpec:
    """Read and validate a spec's TOML (`folder`: where a preset's relative path starts);
    SpecError names every problem and its fix."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"sweep spec {label}: not valid TOML: {exc}") from None
    problems: list[str] = []
    model, preset_label, preset_text, engagement_text = _model_and_preset(
        data, label, folder, problems
    )
    try:
        base = base_params(model, preset_text, engagement_text)
    except CarfeelError as exc:
        raise SpecError(f"sweep spec {label}: preset {preset_label}: {exc}") from None

    seeds = read_seeds(data.get("seeds", 1), problems)
    run = read_run(model, data.get("run", {}), problems)
    fixed = read_assignments(data.get("set", {}), "set", problems)
    vary = read_vary(data.get("vary", {}), problems)
    check_parameters(model, base, run, fixed, vary, problems)
    samples = _samples(data, vary, problems)
    sampling, sampling_seed = _sampling(data, problems)
    metrics = _metrics(data, model, run, problems)
    engine, per_task = _engine(data, model, problems)
    if not problems:
        # The preset with [set] applied must itself be valid: else every row would be invalid.
        trouble = case_problems(model, base, dict(fixed))
        problems.extend(f"[set] makes the preset invalid: {p}" for p in trouble)
    n_cases = math.prod(len(v.values) for v in vary if v.values) * samples * max(len(seeds), 1)
    if n_cases > MAX_CASES:
        problems.append(
            f"{n_cases:.3g} cases asked for; at most {MAX_CASES:.0e}: fewer values, "
            "samples or seeds"
        )
    if problems:
        raise _error(label, problems)
    return SweepSpec(
        label=label,
        model=model,
        preset_label=preset_label,
        preset_text=preset_text,
        engagement_text=engagement_text,
        seeds=seeds,
        samples=samples,
        sampling=sampling,
        sampling_seed=sampling_seed,
        metrics=tuple(metrics),
        engine=engine,
        cases_per_task=per_task,
        run=tuple(run),
        fixed=tuple(fixed),
        vary=tuple(vary),
        text=text,
        hash=_digest(data, preset_text, engagement_text),
    )


def _digest(data: Mapping[str, Any], preset_text: str, engagement_text: str) -> str:
    """The spec's hash: its TOML's data, its presets' texts and carfeel's version (a part file
    resumes only the same)."""
    return hashlib.sha256(
        json.dumps(
            {
                "spec": data,
                "preset": preset_text,
                "engagement": engagement_text,
                "carfeel": __version__,
            },
            sort_keys=True,
            default=str,
        ).encode()
    ).hexdigest()


def _model_and_preset(
    data: Mapping[str, Any], label: str, folder: Path | None, problems: list[str]
) -> tuple[str, str, str, str]:
    """(model, preset label, text, engagement text); the top keys checked on the way. Without
    a model or a preset nothing else can be checked: SpecError at once."""
    for key in data:
        if key not in TOP_KEYS:
            problems.append(f"{key}: unknown key; a sweep spec has {', '.join(TOP_KEYS)}")
    model = data.get("model")
    if model not in MODELS:
        problems.append(f"model = {model!r}: expected one of {', '.join(MODELS)}")
        raise _error(label, problems)
    kind = "shift" if model == "shift" else model
    preset_name = data.get("preset", presets.DEFAULT_PRESETS[kind])
    if not isinstance(preset_name, str) or not preset_name:
        problems.append(f"preset = {preset_name!r}: expected a preset name or a .toml path")
        raise _error(label, problems)
    return model, *_resolve_preset(model, preset_name, folder)


def _samples(data: Mapping[str, Any], vary: Sequence[Vary], problems: list[str]) -> int:
    """The number of draws: given when a parameter has a distribution, else none (1)."""
    has_draws = any(v.distribution for v in vary)
    samples = data.get("samples", 0 if not has_draws else None)
    if has_draws and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
        problems.append(
            f"samples = {said(samples)}: a parameter has a distribution; give the number of "
            "draws, "
            "a whole number >= 1 (e.g. samples = 200)"
        )
        samples = 1
    elif not has_draws and samples not in (0, None):
        problems.append(
            f"samples = {said(samples)}: no parameter has a distribution (grids only); drop samples"
        )
    if isinstance(samples, int) and samples > MAX_CASES:
        problems.append(f"samples = {samples:.3g}: at most {MAX_CASES:.0e} cases in a sweep")
        samples = 1
    return max(int(samples or 1), 1)


def _sampling(data: Mapping[str, Any], problems: list[str]) -> tuple[Any, Any]:
    """(sampling, sampling_seed)."""
    sampling = data.get("sampling", "random")
    if sampling not in ("random", "latin"):
        problems.append(f"sampling = {sampling!r}: expected 'random' or 'latin'")
    sampling_seed = data.get("sampling_seed", 0)
    if isinstance(sampling_seed, bool) or not isinstance(sampling_seed, int) or sampling_seed < 0:
        problems.append(f"sampling_seed = {sampling_seed!r}: expected a whole number >= 0")
        sampling_seed = 0
    return sampling, sampling_seed


def _metrics(
    data: Mapping[str, Any], model: str, run: Sequence[tuple[str, Any]], problems: list[str]
) -> list[str]:
    """The metrics kept: the spec's list, or all of the model's."""
    known = metric_names(model, dict(run))
    metrics = data.get("metrics", list(known))
    if not isinstance(metrics, list) or not metrics or not all(isinstance(m, str) for m in metrics):
        problems.append(f"metrics = {metrics!r}: expected a list of names from {', '.join(known)}")
        metrics = list(known)
    for name in metrics:
        if name not in known:
            problems.append(
                f"metrics: unknown metric {name!r}; the {model} sweep keeps {', '.join(known)}"
            )
    return metrics


def _engine(data: Mapping[str, Any], model: str, problems: list[str]) -> tuple[Any, Any]:
    """(engine, cases per task)."""
    engine = data.get("engine", "batch" if model == "shift" else "pure")
    if engine not in ("batch", "pure") or (engine == "batch" and model != "shift"):
        problems.append(
            f"engine = {engine!r}: expected 'batch' (the vectorized single shift, model = "
            "'shift' only) or 'pure' (the models' own steps)"
        )
    per_task = data.get(
        "cases_per_task", DEFAULT_CASES_PER_TASK.get("batch" if engine == "batch" else model, 8)
    )
    if isinstance(per_task, bool) or not isinstance(per_task, int) or per_task < 1:
        problems.append(f"cases_per_task = {per_task!r}: expected a whole number >= 1")
        per_task = 1
    return engine, per_task


def _error(label: str, problems: list[str]) -> SpecError:
    return SpecError(f"sweep spec {label} is not valid:\n  " + "\n  ".join(problems))


def _resolve_preset(model: str, name: str, folder: Path | None) -> tuple[str, str, str]:
    """(label, text, engagement text) of the spec's preset: read here, sent to the workers."""
    looks_like_path = name.endswith(".toml") or "/" in name or "\\" in name
    if looks_like_path and folder is not None and not Path(name).is_absolute():
        name = str(folder / name)
    try:
        label, text = presets.resolve(model, name)
        engagement = ""
        if model == "hpattern":
            reference = presets.parse(label, text).get("engagement", "")
            if not isinstance(reference, str) or not reference:
                raise PresetError(
                    f"preset {label}: engagement: missing; expected a shift preset name"
                )
            if (reference.endswith(".toml") or "/" in reference) and not Path(
                reference
            ).is_absolute():
                base = Path(label).parent if label.endswith(".toml") else Path(".")
                reference = str(base / reference)
            engagement = presets.resolve("shift", reference)[1]
    except CarfeelError as exc:
        raise SpecError(f"preset = {name!r}: {exc}") from None
    return label, text, engagement
