"""carfeel's Python API: what a rig, a notebook or a test bench scripts, on one page.

    import carfeel as cf

    shift = cf.simulate_shift("paper-first-gear", seed=1)        # a Result: columns by name
    print(cf.shift_features(shift, "paper-first-gear").synchronization_force_N)
    drive = cf.simulate_steering("b-segment", "iso7401-step", speed_kmh=80.0)
    print(cf.steering_feel(drive, "b-segment").torque_gradient_Nm_per_g)
    frame = drive.to_pandas()                                    # needs pandas

Every function takes a preset by name (one carfeel ships: `cf.preset_names("shift")`), by path
(a TOML file), or as the loaded object (`cf.load_shift_preset(...)`). Units are SI with the unit
in the name (`speed_kmh` is the one exception, as a driver reads it); steering signs ISO 8855
(angles, rates, Ay and torques positive to the left), a shift's position and force positive
into the gear.
Bad input raises `carfeel.InputError` (or `PresetError`) with a message that says what to fix.

The names here are stable from one minor version to the next; everything else in the package
may move (`tests/test_public_api.py` pins this list).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if (
    TYPE_CHECKING
):  # the API's own types, imported when a function runs (keeps `import carfeel` light)
    from carfeel.analysis.shift_features import ShiftFeatures
    from carfeel.analysis.steering_feel import SteeringFeel
    from carfeel.io.presets import Preset
    from carfeel.realtime.session import RealtimeResult, RealtimeRun
    from carfeel.simulation.result import Result
    from carfeel.simulation.shift import ShiftParams
    from carfeel.simulation.steering import SteeringCar

__all__ = [
    "export_fmu",
    "fit_physical",
    "fit_shift",
    "fit_steering",
    "preset_names",
    "run_device",
    "run_sweep",
    "shift_features",
    "simulate_hpattern",
    "simulate_shift",
    "simulate_steering",
    "steering_feel",
    "validate_steering",
]


def preset_names(kind: str) -> list[str]:
    """The names of the presets carfeel ships for `kind` (shift, steering or hpattern)."""
    from carfeel.io import presets as _presets

    return _presets.available(kind)


def _shift_params(preset: str | Path | Preset[ShiftParams] | ShiftParams) -> ShiftParams:
    from carfeel.io.presets import Preset, load_shift

    if isinstance(preset, str | Path):
        return load_shift(str(preset)).params
    if isinstance(preset, Preset):
        params: ShiftParams = preset.params
        return params
    return preset


def _steering_car(preset: str | Path | Preset[SteeringCar] | SteeringCar) -> SteeringCar:
    from carfeel.io.presets import Preset, load_steering

    if isinstance(preset, str | Path):
        return load_steering(str(preset)).params
    if isinstance(preset, Preset):
        car: SteeringCar = preset.params
        return car
    return preset


def simulate_shift(
    preset: str | Path | Preset[ShiftParams] | ShiftParams = "paper-first-gear",
    *,
    seed: int = 0,
    duration_s: float = 1.2,
    dt_s: float = 1e-3,
    substeps: int = 1,
) -> Result:
    """A push from neutral into the gear by the preset's simulated driver (and back out if the
    preset's driver pulls out), `duration_s` long at `dt_s` (s) per sample, `substeps` model
    steps per sample. Columns: time_s, position_m, velocity_m_s, force_N (the hand's, N,
    positive into the gear), stage, ... (`result.names`). `seed` draws the tooth phase."""
    from carfeel.runs import check_steps
    from carfeel.simulation import shift

    check_steps(duration_s, dt_s, substeps, shift.MAX_STEP_S)
    return shift.simulate_shift(
        _shift_params(preset), seed=seed, duration_s=duration_s, dt_s=dt_s, substeps=substeps
    )


def simulate_steering(
    preset: str | Path | Preset[SteeringCar] | SteeringCar = "b-segment",
    manoeuvre: str = "iso4138",
    *,
    speed_kmh: float | None = None,
    model: str = "paper",
    road: str | None = None,
    dt_s: float = 1e-3,
    substeps: int = 1,
) -> Result:
    """An ISO manoeuvre (`carfeel.simulation.manoeuvres.MANOEUVRES`: iso4138, iso3888,
    iso7401-step, ...) driven by the closed-loop driver at `speed_kmh` (km/h; None: the
    manoeuvre's own), the wheel's torque from the paper's law (`model="paper"`) or the physical
    model (`"physical"`, on `road`: dry, wet or snow). Columns: time_s, steering_angle_rad,
    torque_Nm (positive to the left), lateral_accel_m_s2, speed_m_s, ..."""
    from carfeel.errors import InputError
    from carfeel.runs import check_steps
    from carfeel.simulation import manoeuvres, steering

    car = _steering_car(preset)
    if model not in steering.STEERING_MODELS:
        raise InputError(f"model {model!r}: one of {', '.join(steering.STEERING_MODELS)}")
    if model == "physical" and not car.has_physical:
        raise InputError("this preset has no [tyres] and [steering_system] tables; the physical "
                         "model needs them (see the b-segment preset)")  # fmt: skip
    if road is not None and model != "physical":
        raise InputError("road sets the physical model's tyres: give model='physical' too")
    if road is not None and road not in steering.ROAD_FRICTION:
        raise InputError(f"road {road!r}: one of {', '.join(steering.ROAD_FRICTION)}")
    plan = manoeuvres.build(manoeuvre, car.vehicle, speed_kmh)
    check_steps(sum(s.duration_s for s in plan.segments), dt_s, substeps, steering.MAX_STEP_S)
    return steering.simulate_steering(
        car, plan, dt_s=dt_s, substeps=substeps, model=model, road=road,
        metadata={"steering_ratio": repr(car.vehicle.steering_ratio),
                  "wheelbase_m": repr(car.vehicle.wheelbase_m)},
    )  # fmt: skip


def simulate_hpattern(
    layout: str | Path = "5r",
    sequence: str | Sequence[str] = "N,1,2,N",
    *,
    clutch: float = 1.0,
    speed_kmh: float = 30.0,
    engine_rpm: float = 800.0,
    synchronizer: str | None = None,
    seed: int = 0,
    dt_s: float = 1e-3,
    substeps: int = 1,
    max_duration_s: float | None = None,
) -> Result:
    """The simulated driver shifting `sequence` (gear names, N for neutral) through an
    H-pattern `layout` (a shipped name or a TOML path) with the clutch at `clutch` (0 released,
    1 pressed) and the car at `speed_kmh`; the synchronizer `fixed` (the paper's timer),
    `physics`, or None (the preset's). Columns: time_s, x_m and y_m (the knob: x across the
    gate, y along the lever's travel, + toward the odd gears), force_x_N and force_y_N (the
    hand's), gear, stage, grind_N, ... The run ends 0.3 s after the driver is done, or at
    `max_duration_s` (None: 3 s a gear and 5 s more)."""
    from carfeel.runs import HPatternRunConfig, plan_hpattern
    from carfeel.simulation import hpattern
    from carfeel.simulation.sequence import parse_sequence

    gears = parse_sequence(sequence) if isinstance(sequence, str) else tuple(sequence)
    plan = plan_hpattern(HPatternRunConfig(
        gears, str(layout), clutch, speed_kmh, engine_rpm, seed, synchronizer,
        dt_s=dt_s, substeps=substeps, max_duration_s=max_duration_s,
    ))  # fmt: skip
    return hpattern.simulate_hpattern(
        plan.run, seed=seed, max_duration_s=plan.duration_s, dt_s=dt_s, substeps=substeps,
        metadata=plan.metadata,
    )  # fmt: skip


def shift_features(
    result: Result, preset: str | Path | Preset[ShiftParams] | ShiftParams = "paper-first-gear"
) -> ShiftFeatures:
    """What a shift feels like (peak force, synchronization time and plateau, the double bump,
    ...) from a shift's Result; `preset` the one it ran (its in-gear position)."""
    from carfeel.analysis import shift_features as _features

    return _features.shift_features(result, _shift_params(preset).gearbox.in_gear_position_m)


def steering_feel(
    result: Result, preset: str | Path | Preset[SteeringCar] | SteeringCar | None = None
) -> SteeringFeel:
    """The six feel metrics (torque gradient at centre, Nm/g; hysteresis; deadband; ...) of a
    steering Result or a log read into one; `preset` gives the steering ratio and wheelbase the
    yaw-rate metrics need (None: those read n/a)."""
    from carfeel.analysis import steering_feel as _feel

    car = None if preset is None else _steering_car(preset)
    return _feel.steering_feel(
        result["time_s"], result["speed_m_s"], result["steering_angle_rad"],
        result["lateral_accel_m_s2"], result["torque_Nm"],
        steering_ratio=None if car is None else car.vehicle.steering_ratio,
        wheelbase_m=None if car is None else car.vehicle.wheelbase_m,
    )  # fmt: skip


def run_device(run: RealtimeRun, say: Any = None) -> RealtimeResult:
    """A session of the 1 kHz loop as `carfeel run` runs it (`carfeel.RealtimeRun`: model,
    device, preset, clock, hand, ...): the device known (identified or its profile checked),
    the rendering sized, the safety chain armed. `say` (a callable taking text) hears what the
    run announces. A safety fault ends the run with the force faded and reads in
    `result.summary.faults`."""
    from carfeel.realtime.session import run_realtime

    return run_realtime(run, say=say)


def fit_steering(
    logs: Sequence[str | Path],
    out: str | Path,
    *,
    base: str = "b-segment",
    report_dir: str | Path | None = None,
    channels: str | Path | None = None,
    dbc: str | Path | None = None,
    holdout: float = 0.0,
) -> Any:
    """The paper's steering law fitted to measured logs (carfeel CSV, CSV/Parquet/MDF4 with a
    `channels` map, CAN with a `dbc`), written as a preset to `out` (only if the data support
    it), with a report in `report_dir`. Returns the fit (values, sigmas, r2, warnings)."""
    from carfeel.identification.workflows import fit_steering_logs

    return _fit_logs(fit_steering_logs, logs, out, base, report_dir, channels, dbc, holdout)


def fit_physical(
    logs: Sequence[str | Path],
    out: str | Path,
    *,
    base: str = "b-segment",
    report_dir: str | Path | None = None,
    channels: str | Path | None = None,
    dbc: str | Path | None = None,
    holdout: float = 0.0,
) -> Any:
    """The physical steering model (tyres, rack, column) fitted to measured logs; as
    `fit_steering`."""
    from carfeel.identification.physical_workflows import fit_physical_logs

    return _fit_logs(fit_physical_logs, logs, out, base, report_dir, channels, dbc, holdout)


def _fit_logs(
    fitter: Any,
    logs: Sequence[str | Path],
    out: str | Path,
    base: str,
    report_dir: str | Path | None,
    channels: str | Path | None,
    dbc: str | Path | None,
    holdout: float,
) -> Any:
    """A steering fit (the law's or the physical model's) as the command line calls it."""
    return fitter(
        [Path(p) for p in logs], Path(out), base=base, show_progress=False,
        report_dir=None if report_dir is None else Path(report_dir),
        sources=_sources(channels, dbc), holdout=holdout,
    )  # fmt: skip


def fit_shift(
    traces: Sequence[str | Path],
    out: str | Path,
    *,
    base: str = "paper-first-gear",
    report_dir: str | Path | None = None,
    channels: str | Path | None = None,
    dbc: str | Path | None = None,
) -> dict[str, Any]:
    """A shift preset fitted to measured shift traces (time, position, force), written to `out`
    only where the fit explains them (r2 >= 0.8); its figures as a dict."""
    from carfeel.identification.shift_workflows import fit_shift_traces

    return fit_shift_traces(
        [Path(p) for p in traces], Path(out), base=base, show_progress=False,
        report_dir=None if report_dir is None else Path(report_dir),
        channels=None if channels is None else Path(channels),
        dbc=None if dbc is None else Path(dbc),
    )  # fmt: skip


def validate_steering(
    preset: str | Path,
    logs: Sequence[str | Path],
    report_dir: str | Path,
    *,
    channels: str | Path | None = None,
    dbc: str | Path | None = None,
) -> dict[str, Any]:
    """A steering preset predicted on logs it was not fitted to: r2 and rms per log, beside a
    linear fit and a lagged ridge on the same split; a report in `report_dir`."""
    from carfeel.identification.workflows import validate

    return validate(str(preset), [Path(p) for p in logs], Path(report_dir),
                    sources=_sources(channels, dbc))  # fmt: skip


def _sources(channels: str | Path | None, dbc: str | Path | None) -> Any:
    from carfeel.identification.workflows import Sources

    return Sources(None if channels is None else Path(channels), None if dbc is None else Path(dbc))


def run_sweep(
    spec: str | Path,
    out: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    plot: str | Path | None = None,
    restart: bool = False,
) -> Any:
    """A design-space sweep (a spec TOML: the model, its preset, what varies and how, the
    seeds, the metrics) run serially, on a local Dask cluster of `workers`, or on the cluster
    at `scheduler`; the results written to `out` (.parquet or .csv) and, with `plot`, a folder
    of figures. Resumes an interrupted run of the same spec unless `restart`. Returns the
    summary (`.text()` reads it; `.run` holds the counts)."""
    from carfeel.sweep.files import run_sweep as _run_sweep

    return _run_sweep(
        Path(spec), Path(out), workers=workers, scheduler=scheduler,
        plot=None if plot is None else Path(plot), restart=restart,
    )  # fmt: skip


def export_fmu(
    model: str,
    out: str | Path,
    *,
    preset: str | None = None,
    seed: int = 0,
    fmi_version: int = 2,
    steering_model: str = "paper",
    builder: str = "auto",
) -> list[str]:
    """An FMU (FMI 2 or 3, co-simulation) of the shift or steering model with `preset`'s values
    as its parameters, written to `out` (`.fmu`); `builder` auto, gcc or cmake (FMPy's CMake
    build, for Windows and macOS). Returns the files it holds."""
    from carfeel.export import fmu

    spec = fmu.spec_for(model, preset, seed=seed, steering_model=steering_model)
    return fmu.export_fmu(spec, fmi_version, Path(out), builder)
