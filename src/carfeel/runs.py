"""What the commands do, as plain functions over config objects (the CLI only parses and prints)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from carfeel import __version__
from carfeel.analysis.shift_features import ShiftFeatures, shift_features
from carfeel.analysis.steering_feel import SteeringFeel, steering_feel
from carfeel.errors import CarfeelError, InputError
from carfeel.io.presets import load_hpattern, load_shift, load_steering
from carfeel.models.drivers.hpattern import Script
from carfeel.models.gearshift.hpattern import NEUTRAL_GEAR, Layout
from carfeel.simulation import manoeuvres
from carfeel.simulation.hpattern import MAX_STEP_S as HPATTERN_MAX_STEP_S
from carfeel.simulation.hpattern import HPatternRun, simulate_hpattern
from carfeel.simulation.result import Result
from carfeel.simulation.shift import MAX_STEP_S, simulate_shift
from carfeel.simulation.steering import LINEAR_TYRE_LIMIT_G, simulate_steering
from carfeel.simulation.steering import MAX_STEP_S as STEERING_MAX_STEP_S

DEFAULT_SHIFT_DURATION_S = 1.2
DEFAULT_SHIFT_PULL_OUT_DURATION_S = 2.0
MAX_SAMPLES = 50_000_000  # a bound on memory: 50 M samples of 7 signals is several GB
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
    for name in result.names:
        values = result[name]
        if values.dtype.kind == "f" and not np.all(np.isfinite(values)):
            raise CarfeelError(
                f"the {what} simulation produced non-finite {name}; this is a bug or a preset at "
                "the edge of its ranges: please report it with the preset and options used"
            )


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
            f"{at(f.engagement_position_m, 'mm', 1e3)}",
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


def run_shift(config: ShiftRun, csv_path: Path, plot_path: Path | None = None) -> ShiftSummary:
    """Simulate one engagement, write CSV (+ .json metadata beside it) and optionally the plot."""
    preset = load_shift(config.preset)
    duration = config.duration_s
    if duration is None:
        duration = (
            DEFAULT_SHIFT_PULL_OUT_DURATION_S if config.pull_out else DEFAULT_SHIFT_DURATION_S
        )
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
    result = simulate_shift(
        params,
        seed=config.seed,
        duration_s=duration,
        dt_s=config.dt_s,
        substeps=config.substeps,
        metadata=metadata,
    )
    check_finite(result, "shift")
    features = shift_features(result, params.gearbox.in_gear_position_m)
    result.to_csv(csv_path)
    write_metadata(result, csv_path)
    if plot_path is not None:
        from carfeel.io.plots import plot_shift

        plot_shift(result, plot_path, title=f"{preset.name}, seed {config.seed}")
    return ShiftSummary(preset.name, config.seed, features, csv_path, plot_path)


def write_metadata(result: Result, csv_path: Path) -> Path:
    """Write the run's metadata as JSON beside its CSV (FILE.csv -> FILE.json)."""
    target = csv_path.with_suffix(".json")
    clean = {k: v for k, v in result.metadata.items()}
    target.write_text(json.dumps(clean, indent=2) + "\n", encoding="utf-8")
    return target


@dataclass(frozen=True, slots=True)
class SteeringRun:
    """A `carfeel simulate steering` run."""

    manoeuvre: str
    speed_kmh: float | None = None
    preset: str = "b-segment"
    dt_s: float = 1e-3
    substeps: int = 1


REQUIRED_STEERING_COLUMNS = (
    "time_s",
    "speed_m_s",
    "steering_angle_rad",
    "lateral_accel_m_s2",
    "torque_Nm",
)


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


FEEL_LABELS = {
    "torque_gradient_Nm_per_g": ("torque gradient at 0 g", "Nm/g"),
    "torque_at_0_1g_Nm": ("torque at 0.1 g", "Nm"),
    "deadband_g": ("torque deadband", "g"),
    "hysteresis_Nm": ("torque hysteresis (at 0 g)", "Nm"),
    "sensitivity_g_per_100deg": ("steering sensitivity", "g/100 deg"),
    "understeer_gradient_deg_per_g": ("understeer gradient", "deg/g"),
}


def feel_lines(feel: SteeringFeel) -> list[str]:
    lines = []
    for key, value in feel.as_dict().items():
        label, unit = FEEL_LABELS[key]
        shown = "n/a" if math.isnan(value) else f"{value:.3g} {unit}"
        lines.append(f"  {label:28s} {shown}")
    lines.extend(f"  note: {note}" for note in feel.notes)
    return lines


def run_steering(
    config: SteeringRun, csv_path: Path, plot_path: Path | None = None
) -> SteeringSummary:
    """Simulate one steering manoeuvre, write CSV (+ .json metadata) and optionally the plot."""
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
    result = simulate_steering(
        car, manoeuvre, dt_s=config.dt_s, substeps=config.substeps, metadata=metadata
    )
    check_finite(result, "steering")
    feel = feel_of(result, car.vehicle.steering_ratio, car.vehicle.wheelbase_m)
    result.to_csv(csv_path)
    write_metadata(result, csv_path)
    if plot_path is not None:
        from carfeel.io.plots import plot_steering

        plot_steering(result, plot_path, f"{preset.name}: {manoeuvre.description}", manoeuvre.lanes)
    ay = result["lateral_accel_m_s2"]
    peak_g = float(abs(ay).max()) / 9.80665
    if peak_g > LINEAR_TYRE_LIMIT_G:
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
        float(abs(result["torque_Nm"]).max()),
        float(math.sqrt(float((ay**2).mean())) / 9.80665),
        csv_path,
        plot_path,
    )


def feel_of(
    result: Result, steering_ratio: float | None, wheelbase_m: float | None
) -> SteeringFeel:
    return steering_feel(
        result.time_s,
        result["speed_m_s"],
        result["steering_angle_rad"],
        result["lateral_accel_m_s2"],
        result["torque_Nm"],
        steering_ratio=steering_ratio,
        wheelbase_m=wheelbase_m,
    )


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
    from carfeel.identification.common import read_results

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
        raise InputError(f"{csv_path}: {len(result)} rows; the metrics need a run of samples")
    steps = np.diff(result.time_s)
    if np.any(steps <= 0):
        row = int(np.flatnonzero(steps <= 0)[0]) + 3
        raise InputError(f"{csv_path}, line {row}: time_s does not increase from the row before")
    ratio, wheelbase, where = _car_geometry(csv_path, preset)
    feel = feel_of(result, ratio, wheelbase)
    note = (
        f"understeer gradient with steering ratio {ratio:g} and wheelbase {wheelbase:g} m {where}"
    )
    return replace(feel, notes=(*feel.notes, note))


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


@dataclass(frozen=True, slots=True)
class Engagement:
    """One gear going in: what a report quotes of it."""

    gear: str
    synchronization_s: float
    plateau_N: float
    engagement_peak_N: float


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
            f"{','.join(self.requested)} in {self.duration_s:.2f} s",
            f"  gears engaged    {' '.join(self.engaged) or 'none'}; now in {self.final_gear}",
        ]
        for e in self.engagements:
            lines.append(
                f"  into {e.gear:2s}         synchronization "
                f"{e.synchronization_s * 1e3:4.0f} ms at {e.plateau_N:5.1f} N, "
                f"tooth peak {e.engagement_peak_N:5.1f} N"
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


def parse_sequence(text: str) -> tuple[str, ...]:
    gears = tuple(part.strip().upper() for part in text.split(","))
    if not gears or any(not g for g in gears):
        raise InputError(f"--sequence {text!r}: expected gear names separated by commas, N,1,2,N")
    return gears


def run_hpattern(
    config: HPatternRunConfig, csv_path: Path, plot_path: Path | None = None
) -> HPatternSummary:
    """Drive a gear sequence through the H-pattern; write CSV (+ .json metadata) and the plot."""
    preset = load_hpattern(config.layout)
    layout = preset.setup.layout
    names = [g.name for g in layout.gears]
    unknown = [g for g in config.sequence if g != NEUTRAL_GEAR and g not in names]
    if unknown:
        raise InputError(
            f"--sequence: no gear {', '.join(unknown)} in layout {preset.name}; it has "
            f"N, {', '.join(names)}"
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
                f"--mistake {option}:{value}: allowed 1 .. {len(gear_positions)}, the K-th gear "
                f"(not counting N) of --sequence {','.join(config.sequence)}"
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
    result = simulate_hpattern(
        run_params, seed=config.seed, max_duration_s=duration, dt_s=config.dt_s,
        substeps=config.substeps, metadata=metadata,
    )  # fmt: skip
    check_finite(result, "hpattern")
    result.to_csv(csv_path)
    write_metadata(result, csv_path)
    if plot_path is not None:
        from carfeel.io.plots import plot_hpattern

        plot_hpattern(result, layout, plot_path, f"{preset.name}, synchronizer {mode}")
    return HPatternSummary(
        preset.name,
        mode,
        config.sequence,
        tuple(e.split()[1] for e in result["event"] if e.startswith("engage")),
        engagements_of(result),
        str(result["gear"][-1]),
        float(outside_distance(result, layout).max()),
        float(abs(result["grind_N"]).max()),
        float(result.time_s[-1]),
        csv_path,
        plot_path,
    )


def engagements_of(result: Result) -> tuple[Engagement, ...]:
    """Each push that reached a gear: its synchronization time and plateau, its tooth peak."""
    dt = float(result.time_s[1] - result.time_s[0])
    stages, events, force_x = result["stage"], result["event"], result["force_x_N"]
    engaged = [i for i, e in enumerate(events) if e.startswith("engage")]
    out, start = [], 0
    for i in engaged:
        window = slice(start, i + 1)
        sync = stages[window] == "synchronization"
        teeth = stages[window] == "engagement"
        force = np.abs(force_x[window])
        out.append(
            Engagement(
                events[i].split()[1],
                float(sync.sum() * dt),
                float(np.median(force[sync])) if sync.any() else math.nan,
                float(force[teeth].max()) if teeth.any() else math.nan,
            )
        )
        start = i + 1
    return tuple(out)


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


def demo(folder: Path, clock: str = "wall") -> Iterator[str]:
    """Run the demo into `folder`, yielding a line to print per step."""
    if folder.exists() and not folder.is_dir():
        raise InputError(f"--out-dir {folder} exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    yield f"carfeel {__version__} demo: writing into {folder.resolve()}"
    summary = run_shift(ShiftRun(seed=0, pull_out=True), folder / "shift.csv", folder / "shift.png")
    yield "gear engagement, neutral to first and back (paper Fig. 5/6/9/11):"
    yield summary.text()
    peaks = []
    for seed in range(1, 6):
        s = run_shift(ShiftRun(seed=seed), folder / f"shift-seed{seed}.csv")
        peaks.append(s.features.engagement_peak_N)
    finite = [p for p in peaks if not math.isnan(p)]
    yield (
        "engagement peaks over seeds 1-5 (the teeth meet at random): "
        + ", ".join(f"{p:.1f}" for p in finite)
        + " N"
    )
    yield ""
    yield "the complete H-pattern (5+R), up and down the box at 30 km/h:"
    pattern = run_hpattern(
        HPatternRunConfig(parse_sequence("N,1,2,3,4,5,4,3,2,1,N"), speed_kmh=30.0),
        folder / "hpattern.csv",
        folder / "hpattern.png",
    )
    yield pattern.text()
    yield "and into reverse at standstill, with the synchronizer's physics:"
    reverse = run_hpattern(
        HPatternRunConfig(parse_sequence("N,R,N"), speed_kmh=0.0, synchronizer="physics"),
        folder / "hpattern-reverse.csv",
        folder / "hpattern-reverse.png",
    )
    yield reverse.text()
    yield ""
    yield "the H-pattern on the virtual force-feedback joystick, in real time (1 kHz):"
    from carfeel.io.plots import plot_recording
    from carfeel.realtime.session import RealtimeRun, run_realtime

    record = folder / "realtime-hpattern.csv"
    live = run_realtime(
        RealtimeRun(model="hpattern", mode="admittance", record=record, clock=clock)
    )
    plot_recording(
        Result.from_csv(record, drop_partial_last_line=True),
        folder / "realtime-hpattern.png",
        "H-pattern on the virtual joystick, admittance (the paper's scheme)",
    )
    yield live.text()
    yield f"plotted {folder / 'realtime-hpattern.png'} (cf. paper Fig. 10 and 11)"
    yield ""
    yield "steering wheel torque, ISO 3888-1 double lane change (paper Fig. 3):"
    dlc = run_steering(
        SteeringRun("iso3888"), folder / "steering-iso3888.csv", folder / "steering-iso3888.png"
    )
    yield dlc.text()
    yield ""
    yield "steering feel from an ISO 13674-1 weave:"
    weave = run_steering(
        SteeringRun("weave"), folder / "steering-weave.csv", folder / "steering-weave.png"
    )
    yield weave.text()
    yield ""
    yield from _demo_identification(folder)


def as_logged(run: Result, seed: int, rate_hz: float = 200.0) -> Result:
    """A simulated steering run as a test rig would log it: `rate_hz`, white noise of 0.05 Nm,
    0.02 deg, 0.05 m/s^2 and 0.05 m/s, and no rate column (the fit derives it)."""
    rng = np.random.default_rng(seed)
    idx = np.arange(
        0, len(run.time_s), max(1, round(1.0 / (rate_hz * np.median(np.diff(run.time_s)))))
    )
    n = idx.size
    noise = {"speed_m_s": 0.05, "steering_angle_rad": math.radians(0.02),
             "lateral_accel_m_s2": 0.05, "torque_Nm": 0.05}  # fmt: skip
    signals = {name: run[name][idx] + rng.normal(0.0, sigma, n) for name, sigma in noise.items()}
    signals["steering_torque_Nm"] = signals.pop("torque_Nm")
    return Result(run.time_s[idx], signals)


def _demo_identification(folder: Path) -> Iterator[str]:
    from carfeel.identification.workflows import fit_steering_logs, fit_summary

    yield (
        "identification: K1..K9 fitted back from the weave, the lane change and a parking steer "
        "cycle, logged with noise:"
    )
    car = load_steering().params
    runs = {
        "weave": Result.from_csv(folder / "steering-weave.csv"),
        "iso3888": Result.from_csv(folder / "steering-iso3888.csv"),
        "steer-cycle": simulate_steering(car, manoeuvres.build("steer-cycle", car.vehicle)),
    }
    paths = []
    for seed, (name, run) in enumerate(runs.items()):
        path = folder / f"logged-{name}.csv"
        as_logged(run, seed).to_csv(path)
        paths.append(path)
    fit = fit_steering_logs(
        paths, folder / "fitted-b-segment.toml", report_dir=folder / "fit-report",
        show_progress=False,
    )  # fmt: skip
    yield fit_summary(fit)
    true = car.torque
    yield (
        f"  (the b-segment preset the logs came from: K1 {true.k1_Nm_s2_m:g}, K4 {true.k4_1_Nm:g}, "
        f"K7 {true.k7_Nm:g}, K9 {true.k9_Nm_s_rad:g})"
    )
    yield f"wrote {folder / 'fitted-b-segment.toml'} and {folder / 'fit-report' / 'index.html'}"
