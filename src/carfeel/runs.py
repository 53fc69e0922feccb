"""What the commands do, as plain functions over config objects (the CLI only parses and prints)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from carfeel import __version__
from carfeel.errors import InputError
from carfeel.io.presets import load_shift
from carfeel.simulation.features import ShiftFeatures, shift_features
from carfeel.simulation.result import Result
from carfeel.simulation.shift import simulate_shift

DEFAULT_SHIFT_DURATION_S = 1.2
DEFAULT_SHIFT_PULL_OUT_DURATION_S = 2.0
MAX_SAMPLES = 50_000_000  # a bound on memory: 50 M samples of 7 signals is several GB


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
        mm = 1e3
        lines = [
            f"preset {self.preset}, seed {self.seed}: stages {' > '.join(f.stages)}",
            f"  synchronization  {f.synchronization_force_N:6.1f} N held "
            f"{f.synchronization_hold_s * 1e3:5.0f} ms at "
            f"{f.synchronization_position_m * mm:.1f} mm",
            f"  engagement peak  {f.engagement_peak_N:6.1f} N at "
            f"{f.engagement_position_m * mm:.1f} mm",
            f"  stop peak        {f.stop_peak_N:6.1f} N, "
            f"overshoot {f.stop_overshoot_m * mm:.2f} mm",
            f"  final            {f.final_stage} at {f.final_position_m * mm:.2f} mm",
            f"wrote {self.csv}" + (f" and {self.plot}" if self.plot else ""),
        ]
        return "\n".join(lines)


def run_shift(config: ShiftRun, csv_path: Path, plot_path: Path | None = None) -> ShiftSummary:
    """Simulate one engagement, write CSV (+ .json metadata beside it) and optionally the plot."""
    preset = load_shift(config.preset)
    duration = config.duration_s
    if duration is None:
        duration = (
            DEFAULT_SHIFT_PULL_OUT_DURATION_S if config.pull_out else DEFAULT_SHIFT_DURATION_S
        )
    if config.dt_s > duration:
        raise InputError(f"--dt {config.dt_s:g} s is longer than --duration {duration:g} s")
    samples = duration / config.dt_s * config.substeps
    if samples > MAX_SAMPLES:
        raise InputError(
            f"{samples:.3g} model steps asked for (duration / dt * substeps); at most "
            f"{MAX_SAMPLES:.0e}: shorten --duration or lengthen --dt"
        )
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


def demo(folder: Path) -> Iterator[str]:
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
