"""`carfeel simulate shift|hpattern|steering`: one run offline, its CSV, metadata and plot."""

from __future__ import annotations

import argparse
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from carfeel import __version__
from carfeel.analysis.hpattern_features import EngagementFigures, EngagementStream
from carfeel.analysis.shift_features import ShiftFeatures, ShiftFeatureStream
from carfeel.analysis.steering_feel import SteeringFeel
from carfeel.commands.common import (
    outputs_of,
    positive_float,
    positive_int,
    seed_arg,
    shown,
)
from carfeel.commands.metrics import feel_lines, feel_of
from carfeel.errors import InputError
from carfeel.io.force_profile import read_force_profile
from carfeel.io.presets import load_hpattern, load_shift, load_steering
from carfeel.models.drivers.hpattern import Script
from carfeel.models.gearshift.hpattern import NEUTRAL_GEAR, Layout
from carfeel.models.steering.physical import SLIDING_GRIP
from carfeel.simulation import manoeuvres
from carfeel.simulation.hpattern import MAX_STEP_S as HPATTERN_MAX_STEP_S
from carfeel.simulation.hpattern import HPatternRun, stream_hpattern
from carfeel.simulation.manoeuvres import MANOEUVRES
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
                lines.append(
                    f"  into {e.gear:2s}         synchronization "
                    f"{e.synchronization_s * 1e3:4.0f} ms at {e.plateau_N:5.1f} N, "
                    f"tooth peak {e.engagement_peak_N:5.1f} N"
                )
        else:  # a long run: each gear's figures over its engagements, not a line each
            for gear in dict.fromkeys(e.gear for e in self.engagements):
                into = [e for e in self.engagements if e.gear == gear]
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


def _spread(values: list[float], spec: str) -> str:
    """The range of `values` (NaN left out), or the one value they all have."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return "nan"
    low, high = format(min(finite), spec), format(max(finite), spec)
    return low if low == high else f"{low}-{high}"


def parse_sequence(text: str) -> tuple[str, ...]:
    gears = tuple(part.strip().upper() for part in text.split(","))
    if not gears or any(not g for g in gears):
        raise InputError(f"--sequence {text!r}: expected gear names separated by commas, N,1,2,N")
    return gears


def run_hpattern(
    config: HPatternRunConfig, csv_path: Path, plot_path: Path | None = None, staged: bool = False
) -> HPatternSummary:
    """Drive a gear sequence through the H-pattern; write CSV (+ .json metadata) and the plot.

    The CSV is written as the run goes, under CSV.part.csv until it has succeeded; `staged`:
    `csv_path` is already a name `Outputs` staged (the CLI), written as is."""
    preset = load_hpattern(config.layout)
    layout = preset.setup.layout
    names = [g.name for g in layout.gears]
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


def register(commands: Any) -> None:
    """Add `simulate` and their options."""
    simulate = commands.add_parser(
        "simulate",
        help="run a model offline in simulated time",
        description="Run a model offline in simulated time and write its samples as CSV.",
    )
    models = simulate.add_subparsers(dest="model", metavar="MODEL", required=True)
    shift = models.add_parser(
        "shift",
        help="one gear engagement, neutral to first, pushed by the paper's driver (eq. 10)",
        description="Simulate one gear engagement along the slot: the driver of eq. (10) pushes "
        "the knob from neutral through synchronization, tooth engagement and the end stop into "
        "gear, and (with --pull-out) back to neutral. CSV columns: time_s, position_m, "
        "velocity_m_s, force_N (the driver's force at the knob), reaction_N, stage, "
        "driver_phase.",
        epilog="The plot shows force and position vs time and force vs position (as the paper's "
        "Fig. 5, 6, 9 and 11), with the stages coloured.",
    )
    shift.add_argument(
        "--preset",
        default="paper-first-gear",
        metavar="NAME|PATH",
        help="shipped preset name or TOML file (default: paper-first-gear; see `carfeel presets`)",
    )
    shift.add_argument(
        "--seed", type=seed_arg, default=0, help="seed of the tooth-position draw (default: 0)"
    )
    shift.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        metavar="S",
        help="simulated time, s (default: 1.2, or 2.0 with --pull-out)",
    )
    shift.add_argument(
        "--dt",
        type=positive_float,
        default=1e-3,
        metavar="S",
        help="output sample period, s (default: 0.001, i.e. 1 kHz)",
    )
    shift.add_argument(
        "--substeps",
        type=positive_int,
        default=1,
        metavar="N",
        help="model steps per output sample (default: 1)",
    )
    shift.add_argument(
        "--pull-out",
        action="store_true",
        help="after settling in gear, pull the lever back to neutral",
    )
    shift.add_argument(
        "--force-profile",
        metavar="FILE.csv",
        help="drive the knob open loop with a recorded or hand-made force (CSV columns time_s, "
        "force_N; interpolated linearly) instead of the eq. (10) driver; the run lasts as long "
        "as the profile unless --duration says otherwise",
    )
    shift.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    shift.add_argument("--plot", metavar="FILE.png", help="also write a PNG plot")

    hpattern = models.add_parser(
        "hpattern",
        help="the complete H-pattern gearshift driven through a gear sequence",
        description="Simulate the 2-DOF H-pattern gearshift: a driver pulls out, selects in the "
        "neutral corridor and pushes each gear of --sequence in with the paper's law (eq. 10); "
        "every slot runs the single-gear engagement model, walls keep the knob on the paths, "
        "the synchronizer decides when the gate opens. CSV columns: time_s, x_m (engage, "
        "forward +), y_m (select), vx_m_s, vy_m_s, force_x_N, force_y_N (the driver's force on "
        "the knob), reaction_x_N, reaction_y_N (the gearbox's force on it), region, gear (N, R, "
        "1, 2 ...), event, stage, clutch_pedal, speed_difference_rad_s, grind_N, click_N, "
        "driver_phase, target.",
        epilog="layouts: 5r (default), 6r, 5r-reverse-left (see `carfeel presets`), or a TOML "
        "file. mistakes (K counts the gears of --sequence, not N): early-clutch:K releases the "
        "clutch while pushing into the K-th gear; wall:K pushes toward the K-th gear while the "
        "knob is still between planes.",
    )
    hpattern.add_argument(
        "--sequence", required=True, metavar="N,1,2,...",
        help="gears to go through, comma separated, e.g. N,1,2,3,2,N or N,R,N",
    )  # fmt: skip
    hpattern.add_argument(
        "--layout", default="5r", metavar="NAME|PATH",
        help="H-pattern preset name or TOML file (default: 5r)",
    )  # fmt: skip
    hpattern.add_argument(
        "--clutch", type=float, default=1.0, metavar="0..1",
        help="clutch pedal held during the run: 1 pressed to the floor (default), 0 released",
    )  # fmt: skip
    hpattern.add_argument(
        "--speed-kmh", type=float, default=30.0, metavar="V",
        help="vehicle speed during the shifts, km/h (default: 30)",
    )  # fmt: skip
    hpattern.add_argument(
        "--synchronizer", choices=("fixed", "physics"), default=None,
        help="fixed: the paper's synchronization time; physics: cone torque against the speed "
        "difference (default: the layout preset's)",
    )  # fmt: skip
    hpattern.add_argument(
        "--mistake", action="append", default=[], metavar="KIND:K",
        help="make a mistake on the K-th gear: early-clutch:K or wall:K (repeatable)",
    )  # fmt: skip
    hpattern.add_argument("--seed", type=seed_arg, default=0, help="tooth draw seed (default: 0)")
    hpattern.add_argument(
        "--dt", type=positive_float, default=1e-3, metavar="S",
        help="output sample period, s (default: 0.001)",
    )  # fmt: skip
    hpattern.add_argument(
        "--substeps", type=positive_int, default=1, metavar="N",
        help="model steps per output sample (default: 1)",
    )  # fmt: skip
    hpattern.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    hpattern.add_argument("--plot", metavar="FILE.png", help="also write a PNG plot")

    steering = models.add_parser(
        "steering",
        help="steering wheel torque (paper eqs. 1-7) on a car through an ISO manoeuvre",
        description="Simulate the steering wheel torque of the paper's law (tau0 aligning, tau1 "
        "tire spin, tau2 friction, tau3 damping) on a single-track car driven through a standard "
        "manoeuvre. CSV columns: time_s, speed_m_s, steering_angle_rad, steering_rate_rad_s, "
        "lateral_accel_m_s2, torque_Nm and its four terms, yaw_rate_rad_s, sideslip_rad, x_m, "
        "y_m, yaw_rad, cross_track_m, segment. Signs: positive to the left (counter-clockwise).",
        epilog="manoeuvres: iso4138 (steady-state circle, R 40 m, Ay in 0.5 m/s^2 steps, both "
        "ways), iso4138-limit (the same up to 1.1 g: the physical model's tyres saturate), "
        "iso3888 (ISO 3888-1 double lane change, 80 km/h), iso7401-step / iso7401-sine / "
        "iso7401-sweep (lateral transient response, 60 km/h), steer-cycle (lock to lock and back "
        "at standstill), weave (ISO 13674-1 on-centre, 0.2 Hz, 0.2 g, 100 km/h).",
    )
    steering.add_argument(
        "--manoeuvre", required=True, choices=MANOEUVRES, metavar="NAME",
        help="one of: " + ", ".join(MANOEUVRES),
    )  # fmt: skip
    steering.add_argument(
        "--speed-kmh",
        type=float,
        default=None,
        metavar="V",
        help="vehicle speed, km/h (default: the manoeuvre's standard speed)",
    )
    steering.add_argument(
        "--preset",
        default="b-segment",
        metavar="NAME|PATH",
        help="car preset name or TOML file (default: b-segment; see `carfeel presets`)",
    )
    steering.add_argument(
        "--dt", type=positive_float, default=1e-3, metavar="S",
        help="output sample period, s (default: 0.001)",
    )  # fmt: skip
    steering.add_argument(
        "--substeps", type=positive_int, default=1, metavar="N",
        help="model steps per output sample (default: 1)",
    )  # fmt: skip
    steering.add_argument(
        "--steering-model", choices=("paper", "physical"), default="paper",
        help="paper: the linear car and the paper's law (default); physical: brush tyres, "
        "nonlinear car, EPS steering system with assist, friction, jacking and stops",
    )  # fmt: skip
    steering.add_argument(
        "--road", choices=("dry", "wet", "snow"), default=None,
        help="road under the physical model's tyres: mu 1.0, 0.7, 0.3 in place of the preset's "
        "tyres.friction_coefficient (default: the preset's)",
    )  # fmt: skip
    steering.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    steering.add_argument("--plot", metavar="FILE.png", help="also write a PNG plot")
    simulate.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    code: int = {
        "shift": _simulate_shift,
        "steering": _simulate_steering,
        "hpattern": _simulate_hpattern,
    }[args.model](args)
    return code


def _simulate_shift(args: argparse.Namespace) -> int:
    staging = outputs_of(args)
    config = ShiftRun(
        preset=args.preset,
        seed=args.seed,
        duration_s=args.duration,
        dt_s=args.dt,
        substeps=args.substeps,
        pull_out=args.pull_out,
        force_profile=Path(args.force_profile) if args.force_profile else None,
    )
    with staging.outputs:
        summary = run_shift(config, staging.out, staging.plot, staged=True)
    print(staging.text(summary.text()))
    return 0


def _simulate_steering(args: argparse.Namespace) -> int:
    staging = outputs_of(args)
    config = SteeringRun(
        manoeuvre=args.manoeuvre,
        speed_kmh=args.speed_kmh,
        preset=args.preset,
        dt_s=args.dt,
        substeps=args.substeps,
        steering_model=args.steering_model,
        road=args.road,
    )
    with staging.outputs:
        summary = run_steering(config, staging.out, staging.plot, staged=True)
    print(staging.text(summary.text()))
    return 0


def _simulate_hpattern(args: argparse.Namespace) -> int:
    staging = outputs_of(args)
    sequence = parse_sequence(args.sequence)
    mistakes = {"early-clutch": 0, "wall": 0}
    for text in args.mistake:
        kind, _, number = text.partition(":")
        if kind not in mistakes or not number.isdigit():
            raise InputError(
                f"--mistake '{shown(text)}': expected early-clutch:K or wall:K, K the position of "
                "a gear in --sequence (1 for the first)"
            )
        if mistakes[kind]:
            raise InputError(f"--mistake {kind}: given twice; one {kind} mistake per run")
        if int(number) < 1:
            raise InputError(
                f"--mistake '{shown(text)}': K counts the gears of --sequence from 1 (not N); "
                "leave --mistake out for a run without one"
            )
        mistakes[kind] = int(number)
    config = HPatternRunConfig(
        sequence=sequence,
        layout=args.layout,
        clutch=args.clutch,
        speed_kmh=args.speed_kmh,
        seed=args.seed,
        synchronizer=args.synchronizer,
        early_clutch_release=mistakes["early-clutch"],
        wall_push=mistakes["wall"],
        dt_s=args.dt,
        substeps=args.substeps,
    )
    with staging.outputs:
        summary = run_hpattern(config, staging.out, staging.plot, staged=True)
    print(staging.text(summary.text()))
    return 0
