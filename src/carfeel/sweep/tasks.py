"""One task of a sweep: a run of consecutive cases simulated in one call, returned as a chunk
of rows by column.

A task is what a Dask worker (or the serial loop, or a multiprocessing pool) runs: seconds of
work, no files, no shared state. It travels as the spec and two case numbers (a few kilobytes,
whatever its size: the worker makes its cases itself, as `spec.iter_cases` makes them anywhere);
its chunk holds lists of int, float, bool, str and None by column, so it pickles and writes as
JSON in a few milliseconds. Each case goes through the preset validation first; a case that
fails it, or whose simulation fails, is a row with its status and problem, not an exception.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from carfeel.analysis.hpattern_features import EngagementStream
from carfeel.analysis.shift_features import ShiftFeatures, ShiftFeatureStream
from carfeel.errors import CarfeelError
from carfeel.simulation.stream import Columns, FiniteCheck, Tee
from carfeel.sweep.base import HPatternCase, base_params
from carfeel.sweep.cases import checked_case, iter_cases
from carfeel.sweep.definition import Case, SweepSpec
from carfeel.sweep.settings import gears_of

Row = dict[str, Any]

BATCH_MIN_LANES = 64
"""Fewer shifts than this in a task run the pure step instead: the batch's cost per step is
numpy's per-call overhead (about 300 calls) until a batch has a hundred lanes or so. Both give
the same rows, bit for bit (tests/test_batch_engagement.py)."""


@dataclass(frozen=True)
class Task:
    """The cases start..stop-1 of a sweep."""

    spec: SweepSpec
    start: int
    stop: int

    def __post_init__(self) -> None:
        if not 0 <= self.start < self.stop <= self.spec.n_cases:
            raise ValueError(
                f"a task of cases {self.start}..{self.stop - 1} of {self.spec.n_cases}"
            )

    def __len__(self) -> int:
        return self.stop - self.start

    @property
    def cases(self) -> tuple[Case, ...]:
        return tuple(iter_cases(self.spec, self.start, self.stop))


@dataclass(frozen=True)
class Chunk:
    """The rows of consecutive cases from `start`, by column (every column the same length)."""

    start: int
    columns: dict[str, list[Any]]

    def __len__(self) -> int:
        return len(self.columns["case_id"])

    @property
    def stop(self) -> int:
        return self.start + len(self)

    def rows(self) -> list[Row]:
        names = list(self.columns)
        columns = self.columns.values()
        return [dict(zip(names, values, strict=True)) for values in zip(*columns, strict=True)]

    def statuses(self) -> collections.Counter[str]:
        return collections.Counter(self.columns["status"])

    @classmethod
    def of(cls, rows: Sequence[Row]) -> Chunk:
        """The chunk of rows of consecutive cases, in order (ValueError if they are not)."""
        if not rows:
            raise ValueError("a chunk has at least one row")
        start = int(rows[0]["case_id"])
        if any(int(r["case_id"]) != start + i for i, r in enumerate(rows)):
            raise ValueError("a chunk's rows are consecutive cases, in order")
        names = list(rows[0])
        return cls(start, {n: [r.get(n) for r in rows] for n in names})

    def every(self, k: int) -> Chunk | None:
        """The rows whose case number is a multiple of `k` (None if none is)."""
        first = (-self.start) % k
        if first >= len(self):
            return None
        return Chunk(self.start + first, {n: v[first::k] for n, v in self.columns.items()})


def as_chunk(result: Chunk | Sequence[Row]) -> Chunk:
    """A task's result as a chunk (a task run by someone else's `execute` may give rows)."""
    return result if isinstance(result, Chunk) else Chunk.of(result)


def run_task(task: Task) -> list[Row]:
    """Simulate every case of `task`; one row per case, in order (`run_chunk` as rows)."""
    return run_chunk(task).rows()


def run_chunk(task: Task) -> Chunk:
    """Simulate every case of `task`: its rows by column."""
    spec = task.spec
    base = base_params(spec.model, spec.preset_text, spec.engagement_text)
    fixed = dict(spec.fixed)
    valid: list[tuple[Case, Any, dict[str, Any]]] = []
    rows: dict[int, Row] = {}
    cases = task.cases
    for case in cases:
        values = {**fixed, **dict(case.values)}
        params, problems = checked_case(spec.model, base, values)
        if problems:
            rows[case.case_id] = _row(spec, case, {}, "invalid", "; ".join(problems))
        else:
            valid.append((case, params, _settings(spec, values)))
    if spec.model == "shift" and spec.engine == "batch":
        rows.update(_shift_batch(spec, valid))
    else:
        simulate = {"shift": _shift_pure, "hpattern": _hpattern, "steering": _steering}[spec.model]
        for case, params, settings in valid:
            try:
                metrics = simulate(params, case.seed, settings)
            except (CarfeelError, ValueError, ArithmeticError) as exc:
                rows[case.case_id] = _row(spec, case, {}, "failed", str(exc))
                continue
            rows[case.case_id] = _row(spec, case, metrics, "ok", "")
    return Chunk.of([rows[case.case_id] for case in cases])


def _settings(spec: SweepSpec, values: dict[str, Any]) -> dict[str, Any]:
    settings = spec.settings
    for path, value in values.items():
        if path.startswith("run."):
            settings[path[4:]] = float(value)
    return settings


def _row(spec: SweepSpec, case: Case, metrics: dict[str, Any], status: str, problem: str) -> Row:
    row: Row = {"case_id": case.case_id, "sample": case.sample, "seed": case.seed}
    row.update(case.values)
    for name in spec.metrics:
        row[name] = metrics.get(name)
    row["status"] = status
    row["problem"] = problem
    return row


def shift_duration_s(spec_settings: dict[str, Any], pull_out: bool) -> float:
    return float(spec_settings.get("duration_s", 2.0 if pull_out else 1.2))


def shift_metrics(features: ShiftFeatures, time_to_stop_s: float) -> dict[str, Any]:
    """A shift's row from its features (the same for the pure and the batch engine)."""
    return {
        "synchronization_force_N": features.synchronization_force_N,
        "synchronization_peak_N": features.synchronization_peak_N,
        # Not measured where the ring never held the lever or still held it at the run's end.
        "synchronization_time_s": (
            features.synchronization_hold_s
            if "synchronization" in features.stages and features.final_stage != "synchronization"
            else math.nan
        ),
        "engagement_peak_N": features.engagement_peak_N,
        "stop_peak_N": features.stop_peak_N,
        "stop_overshoot_m": features.stop_overshoot_m,
        "shift_time_s": time_to_stop_s,
        "balked": "stop" not in features.stages,
    }


def _shift_pure(params: Any, seed: int, settings: dict[str, Any]) -> dict[str, Any]:
    from carfeel.simulation.shift import stream_shift

    features = ShiftFeatureStream(params.gearbox.in_gear_position_m)
    stream_shift(
        params,
        Tee(_Finite("non-finite position or force", ("position_m", "force_N")), features),
        seed=seed,
        duration_s=shift_duration_s(settings, params.driver.pull_out),
        dt_s=settings.get("dt_s", 1e-3),
        substeps=settings.get("substeps", 1),
    )
    return shift_metrics(features.features(), features.time_to_stop_s)


class _Finite(FiniteCheck):
    """A case's run stopped at its first non-finite number: the row says `message`."""

    def __init__(self, message: str, names: Sequence[str]) -> None:
        super().__init__("sweep", names)
        self.message = message

    def write(self, block: Any) -> None:
        try:
            super().write(block)
        except CarfeelError:
            raise ArithmeticError(self.message) from None


def _shift_batch(
    spec: SweepSpec, valid: Sequence[tuple[Case, Any, dict[str, Any]]]
) -> dict[int, Row]:
    """The valid cases of a task as one vectorized batch per distinct run length."""
    from carfeel.sweep.batch import ShiftBatch

    rows: dict[int, Row] = {}
    groups: dict[tuple[float, float, int], list[tuple[Case, Any]]] = {}
    for case, params, settings in valid:
        key = (
            shift_duration_s(settings, params.driver.pull_out),
            float(settings.get("dt_s", 1e-3)),
            int(settings.get("substeps", 1)),
        )
        groups.setdefault(key, []).append((case, params))
    for (duration, dt, substeps), members in groups.items():
        if len(members) < BATCH_MIN_LANES:
            for case, params in members:
                settings = {"duration_s": duration, "dt_s": dt, "substeps": substeps}
                try:
                    metrics = _shift_pure(params, case.seed, settings)
                    rows[case.case_id] = _row(spec, case, metrics, "ok", "")
                except ArithmeticError as exc:
                    rows[case.case_id] = _row(spec, case, {}, "failed", str(exc))
            continue
        batch = ShiftBatch([p for _, p in members], [c.seed for c, _ in members])
        run = batch.run(duration, dt, substeps)
        for i, (case, _) in enumerate(members):
            metrics = shift_metrics(run.features[i], float(run.time_to_stop_s[i]))
            ok = bool(run.finite[i])
            rows[case.case_id] = _row(
                spec,
                case,
                metrics,
                "ok" if ok else "failed",
                "" if ok else "non-finite position or force",
            )
    return rows


def _hpattern(params: Any, seed: int, settings: dict[str, Any]) -> dict[str, Any]:
    from carfeel.models.drivers.hpattern import Script
    from carfeel.simulation.hpattern import HPatternRun, stream_hpattern

    assert isinstance(params, HPatternCase)
    setup, shift = params.setup, params.shift
    gears = gears_of(settings["sequence"])
    sequence = tuple(g.strip().upper() for g in settings["sequence"].split(","))
    names = {g.name for g in setup.layout.gears}
    unknown = [g for g in gears if g not in names]
    if unknown:
        raise CarfeelError(f"no gear {', '.join(unknown)} in the layout; it has {sorted(names)}")
    from carfeel.io.presets import HPatternPreset

    preset = HPatternPreset("sweep", "", "", shift, setup)
    sync = settings.get("synchronizer")
    pattern = preset.pattern(None if sync is None else sync == "physics")
    script = Script(
        sequence, setup.layout, shift.driver, setup.driver, float(settings.get("clutch", 1.0))
    )
    dt = float(settings.get("dt_s", 1e-3))
    run = HPatternRun(
        pattern,
        script,
        float(settings.get("speed_kmh", 30.0)) / 3.6,
        float(settings.get("engine_rpm", 800.0)) * 2 * math.pi / 60,
        dt,
    )
    duration = float(settings.get("max_duration_s", 3.0 * len(sequence) + 5.0))
    figures = EngagementStream()
    stream_hpattern(
        run,
        Tee(_Finite("non-finite knob position or force", ("x_m", "y_m", "force_x_N")), figures),
        seed=seed,
        max_duration_s=duration,
        dt_s=dt,
        substeps=int(settings.get("substeps", 1)),
    )
    return hpattern_metrics(figures, gears)


def hpattern_metrics(figures: EngagementStream, gears: Sequence[str]) -> dict[str, Any]:
    """Per gear of the sequence (in order) and for the whole sequence."""
    engaged = figures.figures()
    out: dict[str, Any] = {}
    for k, gear in enumerate(gears, start=1):
        prefix = f"shift{k}_{gear}_"
        if k <= len(engaged):
            e = engaged[k - 1]
            out[prefix + "synchronization_force_N"] = e.plateau_N
            out[prefix + "synchronization_time_s"] = e.synchronization_s
            out[prefix + "engagement_peak_N"] = e.engagement_peak_N
            out[prefix + "stop_peak_N"] = e.stop_peak_N
            out[prefix + "engaged"] = True
        else:
            for name in (
                "synchronization_force_N",
                "synchronization_time_s",
                "engagement_peak_N",
                "stop_peak_N",
            ):
                out[prefix + name] = math.nan
            out[prefix + "engaged"] = False
    complete = len(engaged) >= len(gears)
    out["total_time_s"] = engaged[len(gears) - 1].time_s if complete else math.nan
    out["balked"] = not complete
    out["ground"] = figures.peak_grind_N > 0.0
    out["peak_grind_N"] = figures.peak_grind_N
    return out


def _steering(params: Any, seed: int, settings: dict[str, Any]) -> dict[str, Any]:
    from carfeel.analysis.steering_feel import G, steering_feel
    from carfeel.simulation import manoeuvres
    from carfeel.simulation.steering import stream_steering

    car = params
    model = settings.get("steering_model", "paper")
    if model == "physical" and not car.has_physical:
        raise CarfeelError(
            "the preset has no [tyres] and [steering_system] tables; the "
            "physical steering model needs them"
        )
    manoeuvre = manoeuvres.build(settings["manoeuvre"], car.vehicle, settings.get("speed_kmh"))
    kept = Columns(("speed_m_s", "steering_angle_rad", "lateral_accel_m_s2", "torque_Nm"))
    finite = _Finite("non-finite torque or lateral acceleration", kept.names[2:])
    stream_steering(
        car,
        manoeuvre,
        Tee(finite, kept),
        dt_s=float(settings.get("dt_s", 1e-3)),
        substeps=int(settings.get("substeps", 1)),
        model=model,
        road=settings.get("road") if model == "physical" else None,
    )
    result = kept.result()
    torque, ay = result["torque_Nm"], result["lateral_accel_m_s2"]
    feel = steering_feel(
        result.time_s,
        result["speed_m_s"],
        result["steering_angle_rad"],
        ay,
        torque,
        steering_ratio=car.vehicle.steering_ratio,
        wheelbase_m=car.vehicle.wheelbase_m,
    )
    metrics: dict[str, Any] = dict(feel.as_dict())
    metrics["peak_torque_Nm"] = float(np.abs(torque).max())
    metrics["rms_lateral_accel_g"] = float(math.sqrt(float((ay**2).mean())) / G)
    return metrics
