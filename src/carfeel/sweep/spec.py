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
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import re
import tomllib
import typing
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from carfeel import __version__, schema
from carfeel.errors import CarfeelError, InputError, PresetError
from carfeel.io import presets
from carfeel.models.drivers.hpattern import HPatternDriverParams
from carfeel.models.gearshift.hpattern import FeelParams, Layout, SelectParams, WallParams
from carfeel.models.gearshift.synchronizer import SynchronizerParams
from carfeel.simulation.hpattern import HPatternSetup
from carfeel.simulation.manoeuvres import MANOEUVRES
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import ROAD_FRICTION, STEERING_MODELS, SteeringCar

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
DISTRIBUTIONS = {
    "uniform": ("low", "high"),
    "normal": ("mean", "sd"),
    "truncnormal": ("mean", "sd", "low", "high"),
}
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
MAX_CASES = 10_000_000
"""The most cases a sweep may ask for (seeds included), checked before any is made."""
MAX_SPEC_BYTES = 1024 * 1024
"""The largest spec file read (a spec is a page of TOML; its grids' values are in it)."""


class SpecError(InputError):
    """A sweep spec is missing, malformed, or asks for what the models cannot do."""


Value = float | int | bool


@dataclass(frozen=True)
class Vary:
    """One varied parameter: a grid of values, or a distribution."""

    path: str
    values: tuple[Value, ...] = ()
    distribution: str = ""
    args: tuple[float, ...] = ()
    """The distribution's arguments in DISTRIBUTIONS order."""

    def sample(self, u: np.ndarray) -> np.ndarray:
        """The distribution's values at the uniform quantiles u (inverse CDF; scipy.special,
        not scipy.stats, whose import costs seconds)."""
        from scipy.special import ndtr, ndtri

        if self.distribution == "uniform":
            low, high = self.args
            return low + u * (high - low)
        if self.distribution == "normal":
            mean, sd = self.args
            return np.asarray(mean + sd * ndtri(u), dtype=float)
        mean, sd, low, high = self.args
        a, b = (low - mean) / sd, (high - mean) / sd
        sign = 1.0
        if a > 0.0:  # in the upper tail: mirror it to the lower, where the CDF keeps precision
            a, b, sign, u = -b, -a, -1.0, 1.0 - u
        lo, hi = ndtr(a), ndtr(b)
        drawn = mean + sign * sd * ndtri(lo + u * (hi - lo))
        return np.asarray(np.clip(drawn, low, high))  # the last ulp stays within the bounds


@dataclass(frozen=True)
class Case:
    """One simulation: a parameter set (by its index, `sample`) and a seed."""

    case_id: int
    sample: int
    seed: int
    values: tuple[tuple[str, Value], ...]


@dataclass(frozen=True)
class SweepSpec:
    """A validated spec; plain data, so it travels to Dask workers as it is."""

    label: str
    model: str
    preset_label: str
    preset_text: str
    engagement_text: str
    """hpattern: the text of the shift preset its slots engage with ('' otherwise)."""
    seeds: Sequence[int]
    """A range (`seeds = n`: never a tuple of n ints) or the spec's list as a tuple."""
    samples: int
    sampling: str
    sampling_seed: int
    metrics: tuple[str, ...]
    engine: str
    cases_per_task: int
    run: tuple[tuple[str, Any], ...]
    fixed: tuple[tuple[str, Value], ...]
    vary: tuple[Vary, ...]
    text: str
    """The spec's TOML, as given (kept in the results' metadata)."""
    hash: str

    @property
    def settings(self) -> dict[str, Any]:
        return dict(self.run)

    @property
    def parameters(self) -> tuple[str, ...]:
        return tuple(v.path for v in self.vary)

    @property
    def n_sets(self) -> int:
        grid = math.prod(len(v.values) for v in self.vary if v.values)
        return grid * self.samples

    @property
    def n_cases(self) -> int:
        return self.n_sets * len(self.seeds)

    def columns(self) -> list[str]:
        return ["case_id", "sample", "seed", *self.parameters, *self.metrics, "status", "problem"]


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
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"sweep spec {label}: not valid TOML: {exc}") from None
    problems: list[str] = []
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
    preset_label, preset_text, engagement_text = _resolve_preset(model, preset_name, folder)
    try:
        base = base_params(model, preset_text, engagement_text)
    except CarfeelError as exc:
        raise SpecError(f"sweep spec {label}: preset {preset_label}: {exc}") from None

    seeds = _seeds(data.get("seeds", 1), problems)
    run = _run(model, data.get("run", {}), problems)
    fixed = _assignments(data.get("set", {}), "set", problems)
    vary = _vary(data.get("vary", {}), problems)
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
    has_draws = any(v.distribution for v in vary)
    samples = data.get("samples", 0 if not has_draws else None)
    if has_draws and (isinstance(samples, bool) or not isinstance(samples, int) or samples < 1):
        problems.append(
            f"samples = {_said(samples)}: a parameter has a distribution; give the number of "
            "draws, "
            "a whole number >= 1 (e.g. samples = 200)"
        )
        samples = 1
    elif not has_draws and samples not in (0, None):
        problems.append(
            f"samples = {_said(samples)}: no parameter has a distribution (grids only); drop "
            "samples"
        )
    if isinstance(samples, int) and samples > MAX_CASES:
        problems.append(f"samples = {samples:.3g}: at most {MAX_CASES:.0e} cases in a sweep")
        samples = 1
    samples = max(int(samples or 1), 1)
    sampling = data.get("sampling", "random")
    if sampling not in ("random", "latin"):
        problems.append(f"sampling = {sampling!r}: expected 'random' or 'latin'")
    sampling_seed = data.get("sampling_seed", 0)
    if isinstance(sampling_seed, bool) or not isinstance(sampling_seed, int) or sampling_seed < 0:
        problems.append(f"sampling_seed = {sampling_seed!r}: expected a whole number >= 0")
        sampling_seed = 0
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
    digest = hashlib.sha256(
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
        hash=digest,
    )


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


@dataclass(frozen=True, slots=True)
class HPatternCase:
    """What an H-pattern sweep varies: the preset's tables (its key paths as in the preset
    file) and its engagement preset (under `shift.`)."""

    layout: Layout
    select: SelectParams
    walls: WallParams
    synchronizer: SynchronizerParams
    feel: FeelParams
    driver: HPatternDriverParams
    shift: ShiftParams

    @property
    def setup(self) -> HPatternSetup:
        return HPatternSetup(
            self.layout, self.select, self.walls, self.synchronizer, self.feel, self.driver
        )


@lru_cache(maxsize=8)
def base_params(model: str, preset_text: str, engagement_text: str = "") -> Any:
    """The preset's parameters (validated as `carfeel.io.presets` does), from its text."""
    if model == "shift":
        return presets.from_toml("shift", "preset", preset_text).params
    if model == "steering":
        return presets.from_toml("steering", "preset", preset_text).params
    shift = presets.from_toml("shift", "engagement", engagement_text).params
    data = presets.parse("preset", preset_text)
    problems: list[str] = []
    tables = {k: v for k, v in data.items() if k not in ("name", "source", "engagement")}
    setup = presets.build(HPatternSetup, tables, "", problems)
    if setup is None or problems:
        raise PresetError("not valid:\n  " + "\n  ".join(problems))
    problems = presets.check_hpattern(setup, shift)
    if problems:
        raise PresetError("not valid:\n  " + "\n  ".join(problems))
    return HPatternCase(
        setup.layout,
        setup.select,
        setup.walls,
        setup.synchronizer,
        setup.feel,
        setup.driver,
        shift,
    )


def _root_type(model: str) -> type[Any]:
    return {"shift": ShiftParams, "steering": SteeringCar, "hpattern": HPatternCase}[model]


_SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[([0-9]{1,6})\])?")
"""One segment of a key path: a field name, or a list's field with its index (`gears[2]`).
Always `fullmatch`: `$` would match before a trailing newline."""


def field_type(model: str, base: Any, path: str) -> tuple[Any, Any]:
    """(type, value in the preset) of the field at a key path; SpecError-free: raises KeyError
    with the reason."""
    if path.startswith("run."):
        name = path[4:]
        if name not in RUN_RANGES or name not in RUN_KEYS[model]:
            varied = [f"run.{k}" for k in RUN_RANGES if k in RUN_KEYS[model]]
            raise KeyError(
                f"the {model} sweep varies these run settings: {', '.join(varied) or 'none'}"
            )
        return float, None
    kind: Any = _root_type(model)
    value = base
    walked: list[str] = []
    for part in path.split("."):
        match = _SEGMENT.fullmatch(part)
        if match is None:
            raise KeyError(f"{part!r} is not a field name")
        name, index = match.group(1), match.group(2)
        kind = schema.optional_of(kind)
        if not dataclasses.is_dataclass(kind):
            raise KeyError(f"{'.'.join(walked)} is a value, not a table")
        hints = schema.type_hints(typing.cast(type, kind))
        if name not in hints:
            where = ".".join(walked) or "the preset"
            fields = ", ".join(hints)
            raise KeyError(f"{where} has no {name!r}; it has {fields}")
        kind = hints[name]
        value = getattr(value, name) if value is not None else None
        walked.append(part)
        if value is None and index is None and schema.optional_of(kind) is not kind:
            raise KeyError(f"the preset has no [{'.'.join(walked)}] table")
        if index is not None:
            if typing.get_origin(kind) is not tuple:
                raise KeyError(f"{name} is not a list; drop [{index}]")
            kind = typing.get_args(kind)[0]
            assert value is not None  # a tuple field of the preset
            if int(index) >= len(value):
                raise KeyError(f"{name} has {len(value)} entries (0..{len(value) - 1})")
            value = value[int(index)]
    kind = schema.optional_of(kind)
    if dataclasses.is_dataclass(kind) or typing.get_origin(kind) is tuple or kind is str:
        raise KeyError("it is a table, a list or a name; address a number inside it")
    return kind, value


_KINDS: dict[tuple[str, int, str], tuple[Any, Any]] = {}


def _kind(model: str, base: Any, path: str) -> Any:
    """`field_type`'s type, kept per preset and path (the entry holds its preset: an id is
    never another preset's while it is kept)."""
    key = (model, id(base), path)
    entry = _KINDS.get(key)
    if entry is None or entry[0] is not base:
        if len(_KINDS) > 4096:
            _KINDS.clear()
        entry = _KINDS[key] = (base, field_type(model, base, path)[0])
    return entry[1]


def _range_text(path: str) -> str:
    if path.startswith("run."):
        low, high = RUN_RANGES[path[4:]]
        return f"{low:g} <= value <= {high:g}"
    allowed = schema.range_of(path)
    return allowed.text(schema.unit_of(path.split(".")[-1])) if allowed else "any number"


def value_problem(
    model: str, base: Any, path: str, value: Value, kinds: bool = False
) -> str | None:
    """What is wrong with `value` at `path` (its type, its range), or None. `kinds`: the
    field's type looked up once per preset and path (a sweep's cases all ask the same)."""
    try:
        kind = _kind(model, base, path) if kinds else field_type(model, base, path)[0]
    except KeyError as exc:
        return f"{path}: unknown parameter: {exc.args[0]}"
    if not path.startswith("run."):
        return schema.number_problem(path, kind, value, whole_floats=True)
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{path} = {value!r}: expected a number with {_range_text(path)}"
    low, high = RUN_RANGES[path[4:]]
    if not (math.isfinite(float(value)) and low <= float(value) <= high):
        return f"{path} = {float(value):g} is out of range: allowed {_range_text(path)}"
    return None


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


def _seeds(value: Any, problems: list[str]) -> Sequence[int]:
    if isinstance(value, int) and not isinstance(value, bool) and value > MAX_CASES:
        problems.append(
            f"seeds = {value:.3g}: at most {MAX_CASES:.0e} cases in a sweep, seeds included; "
            "fewer seeds"
        )
        return range(1)
    if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
        return range(value)  # not a tuple: 10^8 seeds were 4 GB before they were counted
    if (
        isinstance(value, list)
        and value
        and all(isinstance(s, int) and not isinstance(s, bool) for s in value)
        and len(set(value)) == len(value)
    ):
        return tuple(value)
    problems.append(
        f"seeds = {_said(value)}: expected how many seeds (a whole number >= 1: seeds 0..n-1) "
        "or a list of distinct whole numbers"
    )
    return (0,)


def _said(value: Any) -> str:
    """A spec's value as a message quotes it: at most 60 characters of it."""
    text = repr(value) if not isinstance(value, list | str) or len(value) < 50 else (
        f"a {type(value).__name__} of {len(value)} items"
    )  # fmt: skip
    return text if len(text) <= 60 else f"{text[:48]}...{text[-9:]}"


def _run(model: str, table: Any, problems: list[str]) -> list[tuple[str, Any]]:
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
    if model == "hpattern":
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
    if model == "steering":
        manoeuvre = out.get("manoeuvre")
        if manoeuvre not in MANOEUVRES:
            problems.append(
                f"[run] manoeuvre = {manoeuvre!r}: expected one of {', '.join(MANOEUVRES)}"
            )
        if out.get("steering_model", "paper") not in STEERING_MODELS:
            problems.append(
                f"[run] steering_model = {out['steering_model']!r}: expected one "
                f"of {', '.join(STEERING_MODELS)}"
            )
        if out.get("road", "dry") not in ROAD_FRICTION:  # (no road: the preset's mu)
            problems.append(
                f"[run] road = {out['road']!r}: expected one of {', '.join(ROAD_FRICTION)}"
            )
    return sorted(out.items())


def _flatten(table: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out = []
    for key, value in table.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict) and not ({"values", "distribution"} & set(value)):
            out.extend(_flatten(value, f"{path}."))
        else:
            out.append((path, value))
    return out


def _assignments(table: Any, where: str, problems: list[str]) -> list[tuple[str, Value]]:
    if not isinstance(table, dict):
        problems.append(f"{where} = {table!r}: expected a table [{where}] of key path = value")
        return []
    out = []
    for path, value in _flatten(table):
        if isinstance(value, bool | int | float):
            out.append((path, value))
        else:
            problems.append(f"[{where}] {path} = {value!r}: expected a number or true/false")
    return out


def _vary(table: Any, problems: list[str]) -> list[Vary]:
    if not isinstance(table, dict):
        problems.append(
            f"vary = {table!r}: expected a table [vary] of key path = "
            "{ values = [...] } or { distribution = ... }"
        )
        return []
    out: list[Vary] = []
    for path, entry in _flatten(table):
        hint = (
            f'"{path}" = {{ values = [a, b, c] }} or {{ distribution = "uniform", low = a, '
            "high = b }"
        )
        if not isinstance(entry, dict):
            problems.append(f"[vary] {path} = {entry!r}: expected {hint}")
            continue
        if "values" in entry:
            values = entry["values"]
            extra = set(entry) - {"values"}
            if extra:
                problems.append(
                    f"[vary] {path}: {', '.join(sorted(extra))}: a grid takes only values"
                )
            if (
                not isinstance(values, list)
                or not values
                or not all(isinstance(x, bool | int | float) for x in values)
            ):
                problems.append(
                    f"[vary] {path}: values = {values!r}: expected a non-empty list "
                    "of numbers (or true/false)"
                )
                continue
            if len(set(values)) != len(values):
                problems.append(f"[vary] {path}: values = {values!r} repeats a value")
            out.append(Vary(path, values=tuple(values)))
            continue
        name = entry.get("distribution")
        if name not in DISTRIBUTIONS:
            problems.append(
                f"[vary] {path}: distribution = {name!r}: expected one of "
                + ", ".join(f"{d} ({', '.join(a)})" for d, a in DISTRIBUTIONS.items())
            )
            continue
        names = DISTRIBUTIONS[name]
        extra = set(entry) - {"distribution", *names}
        missing = [a for a in names if a not in entry]
        if extra or missing:
            problems.append(
                f"[vary] {path}: a {name} distribution takes {', '.join(names)}"
                + (f"; unknown {', '.join(sorted(extra))}" if extra else "")
                + (f"; missing {', '.join(missing)}" if missing else "")
            )
            continue
        args = [entry[a] for a in names]
        if not all(isinstance(a, int | float) and not isinstance(a, bool) for a in args) or not all(
            math.isfinite(a) for a in args
        ):
            problems.append(
                f"[vary] {path}: {name} arguments must be finite numbers, got "
                f"{dict(zip(names, args, strict=True))}"
            )
            continue
        out.append(Vary(path, distribution=name, args=tuple(float(a) for a in args)))
    return out


DRAW_BLOCK = 65_536
"""Parameter sets drawn at a time: a sweep's draws are made as its cases are, block by block."""


class Draws:
    """The draws of a spec's distributions, by sample index, made a block at a time: the same
    values as drawing all `samples` at once from numpy's PCG64 (plain: `rng.random((n, k))`;
    Latin: one permutation of n strata per parameter, then the uniforms), without holding them.
    A Latin hypercube keeps its strata (4 bytes per sample and parameter: 120 MB for 10^7
    samples of 3 parameters); plain draws keep nothing but the generator's state."""

    def __init__(self, spec: SweepSpec) -> None:
        self.vary = [v for v in spec.vary if v.distribution]
        self.samples = spec.samples
        rng = np.random.default_rng(spec.sampling_seed)
        self.strata: np.ndarray | None = None
        if self.vary and spec.sampling == "latin":  # one draw in each of `samples` strata
            self.strata = np.empty((spec.samples, len(self.vary)), dtype=np.int32)
            for j in range(len(self.vary)):
                self.strata[:, j] = rng.permutation(spec.samples)
        self.state: dict[str, Any] = dict(rng.bit_generator.state)
        """Where the uniforms start (after the permutations): each block advances from it."""

    def block(self, start: int, stop: int) -> dict[str, np.ndarray]:
        """Each varied path's draws of samples start..stop-1."""
        if not self.vary:
            return {}
        bits = np.random.PCG64()
        bits.state = typing.cast(Any, self.state)
        bits.advance(start * len(self.vary))  # one 64-bit output per uniform double
        u = np.random.Generator(bits).random((stop - start, len(self.vary)))
        if self.strata is not None:
            u = (self.strata[start:stop] + u) / self.samples
        return {v.path: v.sample(u[:, j]) for j, v in enumerate(self.vary)}


def iter_parameter_sets(spec: SweepSpec) -> Iterator[dict[str, Value]]:
    """Every parameter set, in order, made as it is asked for: the grid's product (spec order,
    the last key fastest) times the draws (the same `samples` draws at every grid point)."""
    for _, values in _parameter_sets(spec, 0, spec.n_sets):
        yield dict(values)


def _parameter_sets(
    spec: SweepSpec, first: int, stop: int
) -> Iterator[tuple[int, tuple[tuple[str, Value], ...]]]:
    """(index, values in the spec's order) of the parameter sets first..stop-1, made as they
    are asked for: each grid point's draws a block at a time (the blocks of DRAW_BLOCK samples
    the whole sweep draws, so a run of sets anywhere equals the same sets of the whole)."""
    grid = [v for v in spec.vary if v.values]
    sizes = [len(v.values) for v in grid]
    draws = draws_of(spec)
    index = first
    while index < stop:
        point, sample = divmod(index, spec.samples)
        fixed: dict[str, Value] = {}
        rest = point
        for v, size in zip(reversed(grid), reversed(sizes), strict=True):  # the last fastest
            rest, at = divmod(rest, size)
            fixed[v.path] = v.values[at]
        block = sample // DRAW_BLOCK * DRAW_BLOCK
        drawn = draws.block(block, min(block + DRAW_BLOCK, spec.samples))
        end = min(stop, point * spec.samples + min(block + DRAW_BLOCK, spec.samples))
        for i in range(index, end):
            s = i - point * spec.samples - block
            values = fixed | {path: float(column[s]) for path, column in drawn.items()}
            yield i, tuple((v.path, values[v.path]) for v in spec.vary)
        index = end


def parameter_sets(spec: SweepSpec) -> list[dict[str, Value]]:
    """Every parameter set as a list (small sweeps, tests); `iter_parameter_sets` makes them
    one at a time."""
    return list(iter_parameter_sets(spec))


def iter_cases(spec: SweepSpec, start: int = 0, stop: int | None = None) -> Iterator[Case]:
    """The cases start..stop-1 of the sweep (parameter set x seed, numbered from 0; all of
    them by default), made as they are asked for (a sweep of 10^7 cases never holds them; a
    task of a worker makes its own)."""
    stop = spec.n_cases if stop is None else stop
    if not 0 <= start <= stop <= spec.n_cases:
        raise ValueError(f"cases {start}..{stop} of a sweep of {spec.n_cases}")
    n_seeds = len(spec.seeds)
    if start == stop:
        return
    for index, items in _parameter_sets(spec, start // n_seeds, (stop - 1) // n_seeds + 1):
        for k in range(max(start - index * n_seeds, 0), min(stop - index * n_seeds, n_seeds)):
            yield Case(index * n_seeds + k, index, spec.seeds[k], items)


def cases(spec: SweepSpec) -> list[Case]:
    """Every case as a list (small sweeps, tests)."""
    return list(iter_cases(spec))


_DRAWS: dict[str, Draws] = {}


def draws_of(spec: SweepSpec) -> Draws:
    """The spec's Draws, made once per process (a worker's tasks of one sweep share them: a
    Latin hypercube's permutations of 10^7 strata take a second)."""
    draws = _DRAWS.get(spec.hash)
    if draws is None:
        _DRAWS.clear()  # one sweep at a time: the strata are 4 bytes a sample and parameter
        draws = _DRAWS[spec.hash] = Draws(spec)
    return draws


def apply(base: Any, values: Mapping[str, Value]) -> Any:
    """`base` with each key path (not `run.`) set to its value: one `dataclasses.replace` per
    table changed, with all of its changes (a path at a time replaced each table on the way
    once per path: half of a batched shift's time went to checking and applying its case)."""
    tree: dict[str, Any] = {}
    for path, value in values.items():
        if path.startswith("run."):
            continue
        node = tree
        *tables, leaf = path.split(".")
        for part in tables:
            node = node.setdefault(part, {})
        node[leaf] = value
    return _apply(base, tree) if tree else base


def _apply(obj: Any, tree: Mapping[str, Any]) -> Any:
    changes: dict[str, Any] = {}
    for part, change in tree.items():
        match = _SEGMENT.fullmatch(part)
        assert match is not None  # checked by field_type
        name, index = match.group(1), match.group(2)
        current = changes.get(name, getattr(obj, name))
        if index is not None:
            items = list(current)
            i = int(index)
            items[i] = _apply(items[i], change) if isinstance(change, dict) else change
            changes[name] = tuple(items)
        elif isinstance(change, dict):
            changes[name] = _apply(current, change)
        else:
            kind = type(current)
            changes[name] = (
                kind(change) if kind in (int, float) and not isinstance(change, bool) else change
            )
    return dataclasses.replace(obj, **changes)


def case_problems(model: str, base: Any, values: Mapping[str, Value]) -> list[str]:
    """The preset validation of one case: each value's type and range, then the preset's
    cross-parameter checks on the changed parameters."""
    return checked_case(model, base, values)[1]


def checked_case(model: str, base: Any, values: Mapping[str, Value]) -> tuple[Any, list[str]]:
    """(the case's parameters, or None, and its problems) after the preset validation."""
    problems = [
        p for path, v in values.items() if (p := value_problem(model, base, path, v, kinds=True))
    ]
    if problems:
        return None, problems
    params = apply(base, values)
    if model == "shift":
        problems = presets.check_shift(params)
    elif model == "steering":
        problems = presets.check_steering(params)
    else:
        problems = presets.check_shift(params.shift) + presets.check_hpattern(
            params.setup, params.shift
        )
    return (None if problems else params), problems
