"""One offline run of a model to its files: `run_shift`, `run_steering` and `run_hpattern` take
a run's settings, write its CSV as it goes (with a .json of its metadata beside it) and its plot,
and return a summary of what it felt like. `carfeel simulate` is the command line over them; the
in-memory runs are `carfeel.simulate_shift` and friends (`carfeel.api`)."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from carfeel import __version__
from carfeel.analysis.hpattern_features import EngagementFigures, EngagementStream
from carfeel.analysis.shift_features import ShiftFeatures, ShiftFeatureStream
from carfeel.analysis.steering_feel import SteeringFeel, feel_lines, feel_of
from carfeel.errors import InputError
from carfeel.io.force_profile import read_force_profile
from carfeel.io.presets import HPatternPreset, load_hpattern, load_shift, load_steering
from carfeel.models.drivers.hpattern import Script
from carfeel.models.gearshift.hpattern import NEUTRAL_GEAR, Layout
from carfeel.models.steering.physical import SLIDING_GRIP
from carfeel.simulation import manoeuvres
from carfeel.simulation.hpattern import MAX_STEP_S as HPATTERN_MAX_STEP_S
from carfeel.simulation.hpattern import HPatternRun, stream_hpattern
from carfeel.simulation.result import Result
from carfeel.simulation.runner import samples_of
from carfeel.simulation.shift import MAX_STEP_S, stream_force_profile, stream_shift
from carfeel.simulation.steering import LINEAR_TYRE_LIMIT_G, stream_steering
from carfeel.simulation.steering import MAX_STEP_S as STEERING_MAX_STEP_S
from carfeel.simulation.stream import (
    Columns,
    CsvWriter,
    Envelope,
    FiniteCheck,
    Sink,
    Tee,
    every_for,
)
from carfeel.text import shown

DEFAULT_SHIFT_DURATION_S = 1.2


DEFAULT_SHIFT_PULL_OUT_DURATION_S = 2.0


MAX_SAMPLES = 50_000_000
"""A bound on a run's time and CSV, not its memory (streamed): 50 M H-pattern steps are about
25 min and 6 GB of CSV here (bench_simulate.py: 1 M in 30 s, 127 MB)."""


MIN_DT_S = 1e-6


def check_steps(duration_s: float, dt_s: float, substeps: int, max_step_s: float) -> None:
    """Reject step settings the models cannot honour, with what to do instead."""
    if dt_s < MIN_DT_S:
        raise InputError(f"--dt {dt_s:g} s is below {MIN_DT_S:g} s; the models need no finer step")
    if dt_s > duration_s:
        raise InputError(f"--dt {dt_s:g} s is longer than --duration {duration_s:g} s")
    if dt_s / substeps > max_step_s * (1 + 1e-9):
        needed = math.ceil(dt_s / max_step_s - 1e-9)
        raise InputError(
            f"model step --dt / --substeps = {dt_s / substeps:g} s is longer than "
            f"{max_step_s:g} s, where this model stops being accurate; use --substeps {needed} "
            "or a shorter --dt"
        )
    samples = duration_s / dt_s * substeps
    if samples > MAX_SAMPLES:
        raise InputError(
            f"{samples:.3g} model steps asked for (duration / dt * substeps); at most "
            f"{MAX_SAMPLES:.0e}: shorten --duration or lengthen --dt"
        )


def check_finite(result: Result, what: str) -> None:
    """CarfeelError naming the first non-finite signal of a run in memory (`FiniteCheck`)."""
    FiniteCheck(what).write(result)


@dataclass(frozen=True, slots=True)
class ShiftRun:
    """A `carfeel simulate shift` run."""

    preset: str = "paper-first-gear"
    seed: int = 0
    duration_s: float | None = None
    """None: long enough to settle in gear (and back to neutral with `pull_out`)."""
    dt_s: float = 1e-3
    substeps: int = 1
    pull_out: bool = False
    force_profile: Path | None = None
    """A CSV (time_s, force_N) that drives the knob open loop instead of the eq. (10) driver."""


@dataclass(frozen=True, slots=True)
class ShiftSummary:
    preset: str
    seed: int
    features: ShiftFeatures
    csv: Path
    plot: Path | None

    def text(self) -> str:
        f = self.features

        def at(value: float, unit: str, scale: float = 1.0, digits: int = 1) -> str:
            return "not reached" if math.isnan(value) else f"{value * scale:.{digits}f} {unit}"

        lines = [
            f"preset {self.preset}, seed {self.seed}: stages {' > '.join(f.stages)}",
            f"  synchronization  {at(f.synchronization_force_N, 'N')} held "
            f"{f.synchronization_hold_s * 1e3:.0f} ms at "
            f"{at(f.synchronization_position_m, 'mm', 1e3)}",
            f"  engagement peak  {at(f.engagement_peak_N, 'N')} at "
            f"{at(f.engagement_peak_position_m, 'mm', 1e3)} (teeth met at "
            f"{at(f.engagement_position_m, 'mm', 1e3)})",
            f"  stop peak        {at(f.stop_peak_N, 'N')}, overshoot "
            f"{at(f.stop_overshoot_m, 'mm', 1e3, 2)}",
            f"  final            {f.final_stage} at {f.final_position_m * 1e3:.2f} mm",
            f"wrote {self.csv}" + (f" and {self.plot}" if self.plot else ""),
        ]
        if f.final_stage not in ("in_gear", "neutral"):
            lines.insert(
                -1,
                f"  note: the run ended in {f.final_stage}; a longer --duration may let it settle",
            )
        return "\n".join(lines)


def run_shift(
    config: ShiftRun, csv_path: Path, plot_path: Path | None = None, staged: bool = False
) -> ShiftSummary:
    """Simulate one engagement, write CSV (+ .json metadata beside it) and optionally the plot.

    The CSV is written as the run goes, under CSV.part.csv until it has succeeded; `staged`:
    `csv_path` is already a name `Outputs` staged (the CLI), written as is."""
    preset = load_shift(config.preset)
    duration = config.duration_s
    if duration is None:
        duration = (
            DEFAULT_SHIFT_PULL_OUT_DURATION_S if config.pull_out else DEFAULT_SHIFT_DURATION_S
        )
    profile = None
    if config.force_profile is not None:
        if config.pull_out:
            raise InputError(
                "--pull-out and --force-profile exclude each other: the profile's force drives "
                "the knob; put the pull into the profile (negative force_N)"
            )
        profile = read_force_profile(config.force_profile)
        if config.duration_s is None:
            duration = float(profile[0][-1])
    check_steps(duration, config.dt_s, config.substeps, MAX_STEP_S)
    params = preset.params
    if config.pull_out != params.driver.pull_out:
        params = replace(params, driver=replace(params.driver, pull_out=config.pull_out))
    metadata = {
        "carfeel_version": __version__,
        "model": "shift",
        "preset": preset.name,
        "preset_source": config.preset,
        "seed": str(config.seed),
        "dt_s": repr(config.dt_s),
        "substeps": str(config.substeps),
        "duration_s": repr(duration),
        "pull_out": str(config.pull_out).lower(),
    }
    if profile is not None:
        metadata["force_profile"] = str(config.force_profile)
    features = ShiftFeatureStream(params.gearbox.in_gear_position_m)
    plot = None
    if plot_path is not None:
        expected = samples_of(duration, config.dt_s)
        plot = Envelope(every_for(expected), "force_N", ("position_m", "force_N", "stage"))
    with CsvWriter(csv_path, stage=not staged) as csv:
        sink = Tee(FiniteCheck("shift"), csv, features, *([plot] if plot else []))
        if profile is not None:
            stream_force_profile(
                params.gearbox, *profile, sink, seed=config.seed, duration_s=duration,
                dt_s=config.dt_s, substeps=config.substeps,
            )  # fmt: skip
        else:
            stream_shift(
                params, sink, seed=config.seed, duration_s=duration, dt_s=config.dt_s,
                substeps=config.substeps,
            )  # fmt: skip
    write_metadata({"seed": str(config.seed), **metadata}, csv_path)  # seed first, as before
    if plot_path is not None and plot is not None:
        from carfeel.io.plots import plot_shift

        plot_shift(
            plot.result(), plot_path, title=titled(f"{preset.name}, seed {config.seed}", plot)
        )
    return ShiftSummary(preset.name, config.seed, features.features(), csv_path, plot_path)


def titled(title: str, plot: Envelope) -> str:
    """A plot's title, saying how a long run was drawn."""
    note = plot.note()
    return f"{title} ({note})" if note else title


def write_metadata(metadata: Mapping[str, str], csv_path: Path) -> Path:
    """Write a run's metadata as JSON beside its CSV (FILE.csv -> FILE.json)."""
    target = csv_path.with_suffix(".json")
    clean = {k: _typed(v) for k, v in metadata.items()}
    target.write_text(json.dumps(clean, indent=2) + "\n", encoding="utf-8")
    return target


_NUMBER = re.compile(r"-?(0|[1-9][0-9]*)(\.[0-9]+)?([eE][-+]?[0-9]+)?")


def _typed(value: str) -> object:
    """A metadata value as JSON would type it: numbers and booleans as such, the rest text."""
    if value in ("true", "false"):
        return value == "true"
    if _NUMBER.fullmatch(value):
        number = float(value)
        return int(value) if value.lstrip("-").isdigit() else number
    return value


@dataclass(frozen=True, slots=True)
class SteeringRun:
    """A `carfeel simulate steering` run."""

    manoeuvre: str
    speed_kmh: float | None = None
    preset: str = "b-segment"
    dt_s: float = 1e-3
    substeps: int = 1
    steering_model: str = "paper"
    """paper (the linear car and eqs. 1-7) or physical (brush tyres, EPS steering system)."""
    road: str | None = None
    """The physical model's road (dry, wet, snow: a ROAD_FRICTION key), or None: the preset's
    own tyres.friction_coefficient."""


@dataclass(frozen=True, slots=True)
class SteeringSummary:
    preset: str
    description: str
    feel: SteeringFeel
    peak_torque_Nm: float
    rms_lateral_accel_g: float
    csv: Path
    plot: Path | None

    def text(self) -> str:
        lines = [
            f"preset {self.preset}: {self.description}",
            f"  peak torque {self.peak_torque_Nm:.2f} Nm, rms(Ay) {self.rms_lateral_accel_g:.3f} g",
            *feel_lines(self.feel),
            f"wrote {self.csv}" + (f" and {self.plot}" if self.plot else ""),
        ]
        return "\n".join(lines)


def run_steering(
    config: SteeringRun, csv_path: Path, plot_path: Path | None = None, staged: bool = False
) -> SteeringSummary:
    """Simulate one steering manoeuvre, write CSV (+ .json metadata) and optionally the plot.

    The CSV is written as the run goes, under CSV.part.csv until it has succeeded; `staged`:
    `csv_path` is already a name `Outputs` staged (the CLI), written as is."""
    preset = load_steering(config.preset)
    car = preset.params
    manoeuvre = manoeuvres.build(config.manoeuvre, car.vehicle, config.speed_kmh)
    duration = sum(segment.duration_s for segment in manoeuvre.segments)
    check_steps(duration, config.dt_s, config.substeps, STEERING_MAX_STEP_S)
    metadata = {
        "carfeel_version": __version__,
        "model": "steering",
        "manoeuvre": manoeuvre.name,
        "description": manoeuvre.description,
        "preset": preset.name,
        "preset_source": config.preset,
        "steering_ratio": repr(car.vehicle.steering_ratio),
        "wheelbase_m": repr(car.vehicle.wheelbase_m),
        "dt_s": repr(config.dt_s),
        "substeps": str(config.substeps),
    }
    physical = config.steering_model == "physical"
    if physical and not car.has_physical:
        raise InputError(
            f"preset {preset.name} has no [tyres] and [steering_system] tables; the physical "
            "steering model needs them (see the b-segment preset)"
        )
    if config.road is not None and not physical:
        raise InputError(
            "--road sets the physical model's tyres: give --steering-model physical too"
        )
    metadata["steering_model"] = config.steering_model
    if physical:
        params = car.physical(config.road)
        metadata["road"] = config.road or "the preset's"
        metadata["friction_coefficient"] = repr(params.tyres.friction_coefficient)
    kept = Columns(FEEL_COLUMNS)
    sliding = Sliding()
    plot = None
    if plot_path is not None:
        plot = Envelope(every_for(samples_of(duration, config.dt_s)), "torque_Nm")
    with CsvWriter(csv_path, stage=not staged) as csv:
        sink = Tee(
            FiniteCheck("steering"), csv, kept, *([sliding] if physical else []),
            *([plot] if plot else []),
        )  # fmt: skip
        stream_steering(
            car, manoeuvre, sink, dt_s=config.dt_s, substeps=config.substeps,
            model=config.steering_model, road=config.road if physical else None,
        )  # fmt: skip
    write_metadata(metadata, csv_path)
    if plot_path is not None and plot is not None:
        from carfeel.io.plots import plot_steering

        plot_steering(
            plot.result(), plot_path, titled(f"{preset.name}: {manoeuvre.description}", plot),
            manoeuvre.lanes,
        )  # fmt: skip
    series = kept.result()
    feel = feel_of(series, car.vehicle.steering_ratio, car.vehicle.wheelbase_m)
    ay = series["lateral_accel_m_s2"]
    peak_g = float(abs(ay).max()) / 9.80665
    if physical:
        if sliding.count:
            feel = replace(
                feel,
                notes=(
                    *feel.notes,
                    f"the car slides: an axle uses over {SLIDING_GRIP:.0%} of its grip for "
                    f"{sliding.count / sliding.samples * 100:.0f} % of the run (Ay peaks at "
                    f"{peak_g:.2f} g)",
                ),
            )
    elif peak_g > LINEAR_TYRE_LIMIT_G:
        feel = replace(
            feel,
            notes=(
                *feel.notes,
                f"Ay peaks at {peak_g:.2f} g: beyond about {LINEAR_TYRE_LIMIT_G:g} g real tyres "
                "saturate and this linear single-track model overstates the car",
            ),
        )
    return SteeringSummary(
        preset.name,
        manoeuvre.description,
        feel,
        float(abs(series["torque_Nm"]).max()),
        float(math.sqrt(float((ay**2).mean())) / 9.80665),
        csv_path,
        plot_path,
    )


FEEL_COLUMNS = ("speed_m_s", "steering_angle_rad", "lateral_accel_m_s2", "torque_Nm")
"""What the steering feel metrics read of a run (with its time): 40 bytes a sample kept."""


class Sliding:
    """Counts the samples where an axle of the physical model uses over SLIDING_GRIP of its
    grip (a sink of `carfeel.simulation.stream`)."""

    def __init__(self) -> None:
        self.count = 0
        self.samples = 0

    def write(self, block: Result) -> None:
        used = np.maximum(block["front_grip_used"], block["rear_grip_used"])
        self.count += int(np.count_nonzero(used > SLIDING_GRIP))
        self.samples += len(block)


@dataclass(frozen=True, slots=True)
class HPatternRunConfig:
    """A `carfeel simulate hpattern` run."""

    sequence: tuple[str, ...]
    layout: str = "5r"
    clutch: float = 1.0
    speed_kmh: float = 30.0
    engine_rpm: float = 800.0
    seed: int = 0
    synchronizer: str | None = None
    """None: the preset's mode; "fixed" (the paper's) or "physics"."""
    early_clutch_release: int = 0
    wall_push: int = 0
    dt_s: float = 1e-3
    substeps: int = 1
    max_duration_s: float | None = None
    """None: 3 s per entry of the sequence and 5 s more (a balked run ends there)."""


Engagement = EngagementFigures
"""One gear going in: what a report quotes of it."""


@dataclass(frozen=True, slots=True)
class HPatternSummary:
    layout: str
    mode: str
    requested: tuple[str, ...]
    engaged: tuple[str, ...]
    engagements: tuple[Engagement, ...]
    final_gear: str
    outside_max_m: float
    peak_grind_N: float
    duration_s: float
    csv: Path
    plot: Path | None

    @property
    def followed(self) -> bool:
        return self.engaged == tuple(g for g in self.requested if g != NEUTRAL_GEAR)

    def text(self) -> str:
        lines = [
            f"layout {self.layout}, synchronizer {self.mode}: sequence "
            f"{_listed(self.requested, ',')} in {self.duration_s:.2f} s",
            f"  gears engaged    {_listed(self.engaged, ' ') or 'none'}; now in {self.final_gear}",
        ]
        if len(self.engagements) <= MAX_LISTED:
            for e in self.engagements:
                if _split(e):
                    lines.append(
                        f"  into {e.gear:2s}         a split: the splitter, the lever in gear"
                    )
                    continue
                lines.append(
                    f"  into {e.gear:2s}         synchronization "
                    f"{e.synchronization_s * 1e3:4.0f} ms at {e.plateau_N:5.1f} N, "
                    f"tooth peak {e.engagement_peak_N:5.1f} N"
                )
        else:  # a long run: each gear's figures over its engagements, not a line each
            for gear in dict.fromkeys(e.gear for e in self.engagements):
                into = [e for e in self.engagements if e.gear == gear]
                if all(_split(e) for e in into):
                    lines.append(f"  into {gear:2s} x{len(into):<5d}  a split: the splitter, the "
                                 "lever in gear")  # fmt: skip
                    continue
                lines.append(
                    f"  into {gear:2s} x{len(into):<5d}  synchronization "
                    f"{_spread([e.synchronization_s * 1e3 for e in into], '.0f')} ms at "
                    f"{_spread([e.plateau_N for e in into], '.1f')} N, tooth peak "
                    f"{_spread([e.engagement_peak_N for e in into], '.1f')} N"
                )
        lines.append(f"  off the paths    at most {self.outside_max_m * 1e3:.2f} mm (into a wall)")
        if not self.followed:
            lines.append(
                "  note: the sequence was not completed in the run's time: a balk (the clutch not "
                "pressed far enough, reverse while rolling), or a gear the driver could not "
                "reach; see the stage, grind_N, driver_phase and target columns"
            )
        if self.peak_grind_N > 0.0:
            lines.append(f"  grinding         up to {self.peak_grind_N:.1f} N of vibration")
        lines.append(f"wrote {self.csv}" + (f" and {self.plot}" if self.plot else ""))
        return "\n".join(lines)


MAX_LISTED = 12
"""Engagements a summary lists one by one; a longer run is summed up per gear."""


def _listed(items: tuple[str, ...], separator: str, most: int = 24) -> str:
    """Items joined; a long list as its first and last ones and their count."""
    if len(items) <= most:
        return separator.join(items)
    return (
        f"{separator.join(items[:12])}{separator}...{separator}{separator.join(items[-3:])} "
        f"({len(items)})"
    )


def _split(e: Engagement) -> bool:
    """A truck's split: the gear changed in its slot, no ring blocked, no teeth met."""
    return e.synchronization_s == 0.0 and math.isnan(e.plateau_N)


def _spread(values: list[float], spec: str) -> str:
    """The range of `values` (NaN left out), or the one value they all have."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return "nan"
    low, high = format(min(finite), spec), format(max(finite), spec)
    return low if low == high else f"{low}-{high}"


@dataclass(frozen=True, slots=True)
class HPatternPlan:
    """An H-pattern run made from its settings, checked: what `run_hpattern` writes to files
    and `carfeel.simulate_hpattern` keeps in memory."""

    preset: HPatternPreset
    run: HPatternRun
    duration_s: float
    """The run's longest time, s (it ends settle time after the driver is done)."""
    mode: str
    """The synchronizer: fixed (the paper's timer) or physics."""
    metadata: dict[str, str]


def plan_hpattern(config: HPatternRunConfig) -> HPatternPlan:
    """The run of `config`, checked (gears the layout has, clutch 0..1, speed 0..250 km/h,
    --mistake within the sequence, steps the model can honour)."""
    preset = load_hpattern(config.layout)
    layout = preset.setup.layout
    names = layout.gear_names()
    unknown = [g for g in config.sequence if g != NEUTRAL_GEAR and g not in names]
    if unknown:
        raise InputError(
            f"--sequence: no gear {', '.join(shown(g) for g in unknown)} in layout {preset.name}; "
            f"it has N, {', '.join(names)}"
        )
    if not 0.0 <= config.clutch <= 1.0:
        raise InputError(f"--clutch {config.clutch:g}: allowed 0 (released) .. 1 (pressed)")
    if not 0.0 <= config.speed_kmh <= 250.0:
        raise InputError(f"--speed-kmh {config.speed_kmh:g}: allowed 0 <= value <= 250 km/h")
    # --mistake K names the K-th gear of the sequence (N entries not counted); the driver
    # counts every entry, so translate.
    gear_positions = [i + 1 for i, g in enumerate(config.sequence) if g != NEUTRAL_GEAR]
    entries = {}
    for option, value in (
        ("early-clutch", config.early_clutch_release),
        ("wall", config.wall_push),
    ):
        if value == 0:
            entries[option] = 0
        elif 1 <= value <= len(gear_positions):
            entries[option] = gear_positions[value - 1]
        else:
            raise InputError(
                f"--mistake {shown(f'{option}:{value}')}: allowed 1 .. {len(gear_positions)}, the "
                f"K-th gear (not counting N) of --sequence {','.join(config.sequence)}"
            )
    duration = config.max_duration_s or 3.0 * len(config.sequence) + 5.0
    check_steps(duration, config.dt_s, config.substeps, HPATTERN_MAX_STEP_S)
    physics = None if config.synchronizer is None else config.synchronizer == "physics"
    pattern = preset.pattern(physics)
    script = Script(
        config.sequence,
        layout,
        preset.shift.driver,
        preset.setup.driver,
        config.clutch,
        entries["early-clutch"],
        entries["wall"],
    )
    run_params = HPatternRun(
        pattern,
        script,
        config.speed_kmh / 3.6,
        config.engine_rpm * 2 * math.pi / 60,
        config.dt_s,
    )
    mode = "physics" if pattern.synchronizer.physics else "fixed"
    metadata = {
        "carfeel_version": __version__,
        "model": "hpattern",
        "layout": preset.name,
        "engagement": preset.engagement,
        "sequence": ",".join(config.sequence),
        "synchronizer": mode,
        "clutch": repr(config.clutch),
        "speed_kmh": repr(config.speed_kmh),
        "seed": str(config.seed),
        "dt_s": repr(config.dt_s),
        "substeps": str(config.substeps),
    }
    return HPatternPlan(preset, run_params, duration, mode, metadata)


def run_hpattern(
    config: HPatternRunConfig, csv_path: Path, plot_path: Path | None = None, staged: bool = False
) -> HPatternSummary:
    """Drive a gear sequence through the H-pattern; write CSV (+ .json metadata) and the plot.

    The CSV is written as the run goes, under CSV.part.csv until it has succeeded; `staged`:
    `csv_path` is already a name `Outputs` staged (the CLI), written as is."""
    planned = plan_hpattern(config)
    preset, layout, run_params, duration = (
        planned.preset,
        planned.preset.setup.layout,
        planned.run,
        planned.duration_s,
    )
    mode, metadata = planned.mode, planned.metadata
    figures = EngagementStream()
    outside = OutsideDistance(layout)
    sinks: list[Sink] = [figures, outside]
    plot = loops = None
    if plot_path is not None:
        from carfeel.io.plots import EngagementLoops

        plot = Envelope(
            every_for(samples_of(duration, config.dt_s)), _force_magnitude,
            ("x_m", "y_m", "force_x_N", "force_y_N"),
        )  # fmt: skip
        loops = EngagementLoops()
        sinks += [plot, loops]
    with CsvWriter(csv_path, stage=not staged) as csv:
        stream_hpattern(
            run_params, Tee(FiniteCheck("hpattern"), csv, *sinks), seed=config.seed,
            max_duration_s=duration, dt_s=config.dt_s, substeps=config.substeps,
        )  # fmt: skip
    write_metadata({"seed": str(config.seed), **metadata}, csv_path)
    if plot_path is not None and plot is not None:
        from carfeel.io.plots import plot_hpattern

        title = titled(f"{preset.name}, synchronizer {mode}", plot)
        plot_hpattern(plot.result(), layout, plot_path, title, loops)
    engagements = tuple(figures.figures())
    return HPatternSummary(
        preset.name,
        mode,
        config.sequence,
        tuple(e.gear for e in engagements),
        engagements,
        figures.final_gear,
        outside.max_m,
        figures.peak_grind_N,
        figures.final_time_s,
        csv_path,
        plot_path,
    )


def _force_magnitude(block: Result) -> np.ndarray:
    magnitude: np.ndarray = np.hypot(block["force_x_N"], block["force_y_N"])
    return magnitude


def engagements_of(result: Result) -> tuple[Engagement, ...]:
    """Each push that reached a gear: its synchronization time and plateau, its tooth peak."""
    figures = EngagementStream()
    figures.write(result)
    return tuple(figures.figures())


class OutsideDistance:
    """The farthest the knob went outside the legal paths, m (a sink of
    `carfeel.simulation.stream`; `outside_distance` of each block)."""

    def __init__(self, layout: Layout) -> None:
        self.layout = layout
        self.max_m = 0.0

    def write(self, block: Result) -> None:
        self.max_m = max(self.max_m, float(outside_distance(block, self.layout).max()))


def outside_distance(result: Result, layout: Layout) -> np.ndarray:
    """How far each sample lies outside the legal paths (corridor and slots), m (0 inside)."""
    x, y = result["x_m"], result["y_m"]
    planes = np.asarray(layout.planes_y_m)
    half_slot, half_corridor = layout.slot_width_m / 2, layout.corridor_width_m / 2
    # Corridor: |x| <= half width, y between the outer planes' slot edges.
    corridor = np.hypot(
        np.maximum(np.abs(x) - half_corridor, 0.0),
        np.maximum(np.maximum(planes[0] - half_slot - y, y - planes[-1] - half_slot), 0.0),
    )
    best = corridor
    for gear in layout.gears:
        along = gear.direction * x
        off = np.hypot(
            np.maximum(-along, 0.0), np.maximum(np.abs(y - planes[gear.plane]) - half_slot, 0.0)
        )
        best = np.minimum(best, off)
    return np.asarray(best)
