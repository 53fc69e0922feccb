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
from typing import Any

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


# ------------------------------------------------------------------ the mismatch matrix

GRIP_N_M = 3500.0
GRIP_N_S_M = 15.0
"""A stiff grip (2-5 kN/m at a knob) with a hand's damping (tissue: 5-50 N*s/m, after Hajian
and Howe 1997; zeta 0.4 on the joystick's 0.1 kg); on a rim at RIM_RADIUS_M both times r^2."""
RIM_RADIUS_M = 0.15
TRUE_PLANTS = {
    "mass 0.4x": "mass=0.4x",
    "mass 0.6x": "mass=0.6x",
    "mass 2x": "mass=2x",
    "damping 0.1x": "damping=0.1x",
    "delay 2x": "delay_ms=4",
    "delay 3x": "delay_ms=6",
    "delay 4x": "delay_ms=8",
    "report 250 Hz": "report_hz=250",
    "grip": "grip",
}
"""The true plants of the mismatch matrix, as `virtual:KIND:...` changes to the catalogue's
(its delay is 2 ms each way: 2x is 4 ms); `grip` is GRIP_N_M at the knob."""
MISMATCH_HANDS = ("none", "release", "script")
OSCILLATION_FRACTION = 0.1
"""An oscillation of the command over this share of the force limit (its 2-100 Hz amplitude)
is one the guard must end within GUARD_S."""
GUARD_S = 0.2


@dataclass(frozen=True, slots=True)
class MismatchCell:
    """One run of a model on a virtual plant whose true dynamics differ from what it tells."""

    model: str
    plant: str
    true: str
    hand: str
    identify: str
    refused: str | None = None
    faults: tuple[str, ...] = ()
    ripple_fraction: float = math.nan
    """Peak-to-peak of the command over the last second, a share of the force limit."""
    at_limit: bool = False
    """Whether the command touched the force limit over the last second."""
    oscillating_s: float = 0.0
    """How long the command oscillated over OSCILLATION_FRACTION of the limit before the fade
    began (0 without a fault)."""
    knowledge: str = ""

    @property
    def stable(self) -> bool:
        """Refused with a reason, or calm at the end with nothing faulted."""
        if self.refused is not None:
            return True
        return not self.faults and self.ripple_fraction < RIPPLE_FRACTION and not self.at_limit

    @property
    def guarded(self) -> bool:
        """Refused, stable, or ended by the safety chain within GUARD_S of its oscillation."""
        if self.refused is not None:
            return True
        if self.faults:
            return self.oscillating_s <= GUARD_S
        return self.ripple_fraction < 2 * OSCILLATION_FRACTION and not self.at_limit


def true_spec(plant: str, true: str) -> str:
    """The `--device` of a plant with a true-plant change of TRUE_PLANTS."""
    change = TRUE_PLANTS[true]
    if change == "grip":
        arm = RIM_RADIUS_M**2 if plant in ("wheel", "dd-wheel") else 1.0
        change = f"grip={GRIP_N_M * arm:g},grip_damping={GRIP_N_S_M * arm:g}"
    return f"virtual:{plant}:{change}"


def oscillation_envelope(commands: np.ndarray, rate_hz: float) -> Any:
    """Per sample, the largest 2-100 Hz amplitude over the axes: the Hilbert envelope of the
    zero-phase band-passed command, offline and independent of the loop's guard (no window to
    lead or lag a growing swing)."""
    from scipy.signal import butter, hilbert, sosfiltfilt

    sos = butter(2, [2.0, min(100.0, 0.45 * rate_hz)], "bandpass", fs=rate_hz, output="sos")
    envelope = np.zeros(commands.shape[0])
    for column in commands.T:
        band = sosfiltfilt(sos, np.nan_to_num(column))
        envelope = np.maximum(envelope, np.abs(hilbert(band)))
    return envelope


def run_mismatch_cell(
    model: str,
    plant: str,
    true: str,
    hand: str,
    identify: str = "auto",
    speed_kmh: float = 100.0,
    settle_s: float = 2.0,
    guard: bool = True,
) -> MismatchCell:
    """One cell: a `carfeel run` in simulated time on `true_spec(plant, true)`, recorded."""
    import json
    from unittest import mock

    from carfeel.realtime import loop
    from carfeel.realtime.session import RealtimeRun, run_realtime
    from carfeel.simulation.result import Result

    wheel = model in WHEEL_MODELS
    duration: float | None
    if hand == "none":
        duration = 3.0 if not wheel else 2.2 + settle_s + 1.0
    elif wheel:
        duration = 2.2 + 1.0 + settle_s + 1.0 if hand == "release" else None
    elif model == "shift":
        duration = 2.2 + 2.0 + settle_s
    else:
        duration = 2.2 + 1.2 * len(SEQUENCE) + 1.0 + settle_s
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "cell.csv"
        run = RealtimeRun(
            model="steering" if wheel else model, device=true_spec(plant, true),
            duration_s=duration, sequence=SEQUENCE, speed_kmh=speed_kmh if wheel else 30.0,
            clock="simulated", record=path, hand=hand, identify=identify,
            steering_model="physical" if model == "physical" else "paper",
        )  # fmt: skip
        config = loop.LoopConfig
        patch = mock.patch(
            "carfeel.realtime.session.LoopConfig",
            lambda *a, **k: config(*a, **{**k, "guard": guard}),
        )
        try:
            with patch:
                result = run_realtime(run)
        except InputError as exc:
            return MismatchCell(model, plant, true, hand, identify, refused=str(exc))
        rec = Result.from_csv(path)
        meta = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
    limit = float(meta["max_force"])
    t = rec.time_s
    commands = np.column_stack(
        [np.asarray(rec[c], dtype=float) for c in rec.names if c.startswith("command_")]
    )
    keep = np.isfinite(np.asarray(rec[_force(model)], dtype=float))
    window = commands[keep][t[keep] >= t[keep][-1] - 1.0]
    ripple = float(np.max(np.ptp(window, axis=0))) / limit
    at_limit = bool(np.any(np.abs(window) >= 0.999 * limit))
    oscillating = 0.0
    faulted = np.flatnonzero(np.asarray(rec["fault"], dtype=float) > 0)
    if faulted.size:
        start = int(faulted[0])
        envelope = oscillation_envelope(commands, float(meta["rate_hz"])) / limit
        above = envelope > OSCILLATION_FRACTION
        i = start
        while i > 0 and above[i - 1]:
            i -= 1
        oscillating = float(t[start] - t[i]) if above[max(0, start - 1)] else 0.0
    return MismatchCell(
        model, plant, true, hand, identify, None, tuple(result.summary.faults), ripple,
        at_limit, oscillating, str(meta.get("device_knowledge", {}).get("how", "")),
    )  # fmt: skip


def mismatch_cells(
    models: tuple[str, ...] = MODELS, trues: tuple[str, ...] = tuple(TRUE_PLANTS)
) -> list[tuple[str, str, str, str]]:
    """(model, plant, true plant, hand) of every cell, in order."""
    return [
        (model, plant, true, hand)
        for model in models
        for plant in PLANTS_FOR[model]
        for true in trues
        for hand in MISMATCH_HANDS
    ]


def _mismatch(args: tuple[str, str, str, str, str, bool]) -> MismatchCell:
    model, plant, true, hand, identify, guard = args
    return run_mismatch_cell(model, plant, true, hand, identify, guard=guard)


def mismatch_matrix(
    identify: str = "auto",
    workers: int = 2,
    cells: list[tuple[str, str, str, str]] | None = None,
    guard: bool = True,
) -> list[MismatchCell]:
    """Every cell of the mismatch matrix (or `cells`), in a pool of `workers` processes."""
    jobs = [(*cell, identify, guard) for cell in (cells or mismatch_cells())]
    if workers <= 1:
        return [_mismatch(job) for job in jobs]
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers) as pool:
        return list(pool.map(_mismatch, jobs, chunksize=4))
