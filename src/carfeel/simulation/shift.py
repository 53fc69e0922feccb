"""The driver and the lever of one engagement, closed in a loop, and its simulation."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from carfeel.models.drivers import shift as driver
from carfeel.models.gearshift import engagement
from carfeel.simulation.result import Result
from carfeel.simulation.runner import stream
from carfeel.simulation.stream import Collector, Sink

MAX_STEP_S = 2e-3
"""Longest model step (dt / substeps) for which the driver-lever loop stays accurate."""


@dataclass(frozen=True, slots=True)
class ShiftParams:
    gearbox: engagement.EngagementParams
    """The engagement along the slot: positions, stage mechanics, detents and chamfers."""
    driver: driver.ShiftDriverParams
    """The driver's hand: eq. (10)'s push, its grip on the knob, and the pull out."""


class ShiftState(NamedTuple):
    driver: driver.DriverState
    lever: engagement.EngagementState


class ShiftOutputs(NamedTuple):
    position_m: float
    velocity_m_s: float
    force_N: float
    reaction_N: float
    stage: str
    driver_phase: str


def initial_state(seed: int = 0) -> ShiftState:
    return ShiftState(driver.initial_state(), engagement.initial_state(seed))


def step(
    state: ShiftState, inputs: None, params: ShiftParams, dt_s: float
) -> tuple[ShiftState, ShiftOutputs]:
    """One step of the loop: the driver feels the knob's last motion, then the lever moves.

    The hand sees the lever one step late (a causal loop without an algebraic loop). That delay
    sits inside the loop of the hand's grip (15 kN/m on 0.8 kg, about 28 Hz with the lever), so
    the model step must stay short: at most MAX_STEP_S. At 1 ms the results agree with 0.1 ms
    (tests/test_engagement.py); from 3 ms on the stop peak is overestimated and beyond a few tens
    of ms the loop goes unstable.
    """
    lever = state.lever
    driver_state, driver_out = driver.step(
        state.driver,
        driver.DriverInputs(lever.position_m, lever.velocity_m_s),
        params.driver,
        dt_s,
    )
    lever, out = engagement.step(
        lever, engagement.EngagementInputs(driver_out.force_N), params.gearbox, dt_s
    )
    return ShiftState(driver_state, lever), ShiftOutputs(
        out.position_m, out.velocity_m_s, out.force_N, out.reaction_N, out.stage, driver_out.phase
    )


def stream_shift(
    params: ShiftParams,
    sink: Sink,
    *,
    seed: int = 0,
    duration_s: float = 1.2,
    dt_s: float = 1e-3,
    substeps: int = 1,
) -> int:
    """A push from neutral into the gear (and back, if the driver pulls out), its samples to
    `sink` as the run goes (`carfeel.simulation.stream`); returns the number of samples."""
    _, n = stream(
        step, initial_state(seed), params, sink, duration_s=duration_s, dt_s=dt_s,
        substeps=substeps,
    )  # fmt: skip
    return n


def simulate_shift(
    params: ShiftParams,
    *,
    seed: int = 0,
    duration_s: float = 1.2,
    dt_s: float = 1e-3,
    substeps: int = 1,
    metadata: dict[str, str] | None = None,
) -> Result:
    """`stream_shift` into memory: the whole run as one Result."""
    kept = Collector()
    stream_shift(params, kept, seed=seed, duration_s=duration_s, dt_s=dt_s, substeps=substeps)
    return kept.result({"seed": str(seed), **(metadata or {})})


def stream_force_profile(
    gearbox: engagement.EngagementParams,
    time_s: Sequence[float],
    force_N: Sequence[float],
    sink: Sink,
    *,
    seed: int = 0,
    duration_s: float,
    dt_s: float = 1e-3,
    substeps: int = 1,
) -> int:
    """The lever driven open loop by a knob force (N) given at `time_s` (s), interpolated
    linearly (held before the first and after the last sample): a measured force replayed, its
    samples to `sink`; returns the number of samples."""
    times = np.asarray(time_s, dtype=float)
    forces = np.asarray(force_N, dtype=float)

    def inputs(t: float) -> engagement.EngagementInputs:
        return engagement.EngagementInputs(float(np.interp(t, times, forces)))

    _, n = stream(
        engagement.step, engagement.initial_state(seed), gearbox, sink, duration_s=duration_s,
        dt_s=dt_s, substeps=substeps, inputs=inputs,
    )  # fmt: skip
    return n


def simulate_force_profile(
    gearbox: engagement.EngagementParams,
    time_s: Sequence[float],
    force_N: Sequence[float],
    *,
    seed: int = 0,
    duration_s: float,
    dt_s: float = 1e-3,
    substeps: int = 1,
    metadata: dict[str, str] | None = None,
) -> Result:
    """`stream_force_profile` into memory: the whole run as one Result."""
    kept = Collector()
    stream_force_profile(
        gearbox, time_s, force_N, kept, seed=seed, duration_s=duration_s, dt_s=dt_s,
        substeps=substeps,
    )  # fmt: skip
    return kept.result({"seed": str(seed), **(metadata or {})})
