"""The stability matrix: every model on every virtual plant it fits, at several delays, with the
hand holding, absent, or letting go, in simulated time. The tests and `benchmarks/` use it.

A cell passes when, over the last second of the run (after the script and settling), the
command's peak-to-peak stays below 5 % of the device's force limit, the force is never at the
limit then, and the model's own forces stay physical; or when the loop refused the combination
at start-up with its reason.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carfeel.errors import InputError

PLANTS_FOR = {
    "shift": ("joystick", "shifter"),
    "hpattern": ("joystick", "shifter"),
    "steering": ("wheel", "dd-wheel"),
    "physical": ("wheel", "dd-wheel"),
}
MODES_FOR = {
    "shift": ("impedance", "admittance"),
    "hpattern": ("impedance", "admittance"),
    "steering": ("impedance",),
    "physical": ("impedance",),
}
MODELS = tuple(PLANTS_FOR)
"""The matrix's models: `physical` is `--model steering --steering-model physical`."""
WHEEL_MODELS = ("steering", "physical")
DELAYS_MS = (0.0, 2.0, 4.0, 8.0)
HANDS = ("script", "none", "release")
SEQUENCE = ("N", "1", "2", "N")
"""A short H-pattern script for the matrix: out of neutral, two gears, back."""
RIPPLE_FRACTION = 0.05
MODEL_FORCE_LIMIT_N = 300.0
"""Larger forces at a 100 N-class knob (the model's units) are not physical."""
MODEL_TORQUE_LIMIT_NM = 40.0


@dataclass(frozen=True, slots=True)
class Cell:
    model: str
    mode: str
    plant: str
    delay_ms: float
    hand: str
    ripple: float = math.nan
    """Peak-to-peak of the command over the last second, device units."""
    ripple_fraction: float = math.nan
    at_limit: bool = False
    """Whether the command touched the force limit over the last second."""
    model_peak: float = math.nan
    """Largest force (N) or torque (Nm) of the model over the run."""
    gears: tuple[str, ...] = ()
    faults: tuple[str, ...] = ()
    refused: str | None = None

    @property
    def passed(self) -> bool:
        if self.refused is not None:
            return True
        limit = MODEL_TORQUE_LIMIT_NM if self.model in WHEEL_MODELS else MODEL_FORCE_LIMIT_N
        return (
            self.ripple_fraction < RIPPLE_FRACTION
            and not self.at_limit
            and self.model_peak < limit
            and not self.faults
        )


def run_cell(
    model: str,
    mode: str,
    plant: str,
    delay_ms: float,
    hand: str,
    speed_kmh: float = 100.0,
    rate_hz: float = 1000.0,
    settle_s: float = 2.0,
) -> Cell:
    """One cell of the matrix (a `carfeel run` in simulated time, recorded to a scratch file)."""
    from carfeel.realtime.session import RealtimeRun, run_realtime
    from carfeel.simulation.result import Result

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "cell.csv"
        wheel = model in WHEEL_MODELS
        duration = None
        if wheel and hand != "script":
            duration = 2.2 + 1.0 + settle_s + 1.0
        elif not wheel and hand == "none":
            duration = 3.0
        elif model == "shift":
            duration = 2.2 + 2.0 + settle_s
        elif model == "hpattern":
            duration = 2.2 + 1.2 * len(SEQUENCE) + 1.0 + settle_s
        run = RealtimeRun(
            model="steering" if wheel else model, device=f"virtual:{plant}", mode=mode,
            rate_hz=rate_hz, duration_s=duration, sequence=SEQUENCE,
            speed_kmh=speed_kmh if wheel else 30.0, clock="simulated", record=path, hand=hand,
            device_delay_ms=delay_ms,
            steering_model="physical" if model == "physical" else "paper",
        )  # fmt: skip
        try:
            result = run_realtime(run)
        except InputError as exc:
            return Cell(model, mode, plant, delay_ms, hand, refused=str(exc))
        rec = Result.from_csv(path)
        limit = rec_limit(path)
    t = rec.time_s
    # Rows of the ramp-down after the run carry no model values.
    keep = np.isfinite(np.asarray(rec[_force(model)], dtype=float))
    times = t[keep]
    commands = np.column_stack(
        [np.asarray(rec[c], dtype=float)[keep] for c in rec.names if c.startswith("command_")]
    )
    last = times >= times[-1] - 1.0
    window = commands[last]
    ripple = float(np.max(np.ptp(window, axis=0)))
    at_limit = bool(np.any(np.abs(window) >= 0.999 * limit))
    forces = np.abs(np.asarray(rec[_force(model)], dtype=float)[keep])
    return Cell(
        model, mode, plant, delay_ms, hand, ripple, ripple / limit, at_limit,
        float(np.max(forces)), tuple(result.summary.gears), tuple(result.summary.faults),
    )  # fmt: skip


def _force(model: str) -> str:
    return {"shift": "force_N", "hpattern": "force_x_N", "steering": "torque_Nm",
            "physical": "torque_Nm"}[model]  # fmt: skip


def rec_limit(path: Path) -> float:
    import json

    meta = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
    return float(meta["max_force"])


def matrix(models: tuple[str, ...] = MODELS) -> list[Cell]:
    """Every cell, in order."""
    return [
        run_cell(model, mode, plant, delay, hand)
        for model in models
        for mode in MODES_FOR[model]
        for plant in PLANTS_FOR[model]
        for delay in DELAYS_MS
        for hand in HANDS
    ]
