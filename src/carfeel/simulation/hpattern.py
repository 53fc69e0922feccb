"""The 2-D driver on the H-pattern gearshift, closed in a loop, and its simulation."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple

from carfeel.models.drivers import hpattern as driver
from carfeel.models.drivers.hpattern import HPatternDriverParams, Script
from carfeel.models.gearshift import hpattern
from carfeel.models.gearshift.hpattern import HPatternInputs, HPatternParams
from carfeel.models.gearshift.synchronizer import SynchronizerParams
from carfeel.simulation.result import Result
from carfeel.simulation.runner import stream
from carfeel.simulation.stream import Collector, Sink

MAX_STEP_S = 1e-3
"""Longest model step: the hand's grip is coupled one step late, as in the 1-DOF shift, and the
gate walls (20 kN/m on the lever) want it at 1 ms or less."""


@dataclass(frozen=True, slots=True)
class HPatternRun:
    pattern: HPatternParams
    script: Script
    vehicle_speed_m_s: float
    engine_speed_rad_s: float
    sample_s: float = 1e-3
    """Output sample period: an event stays in the outputs this long, so sub-steps keep it."""


class LoopState(NamedTuple):
    driver: driver.HPatternDriverState
    knob: hpattern.HPatternState
    last: hpattern.HPatternOutputs | None
    event: str = ""
    event_age_s: float = 0.0


class LoopOutputs(NamedTuple):
    x_m: float
    y_m: float
    vx_m_s: float
    vy_m_s: float
    force_x_N: float
    force_y_N: float
    reaction_x_N: float
    reaction_y_N: float
    region: str
    gear: str
    event: str
    stage: str
    clutch_pedal: float
    speed_difference_rad_s: float
    grind_N: float
    click_N: float
    driver_phase: str
    target: str


def initial_state(params: HPatternRun, seed: int = 0) -> LoopState:
    """The knob at rest in neutral; the input shaft turning with the engine (clutch engaged)."""
    knob = hpattern.initial_state(params.pattern, seed, params.engine_speed_rad_s)
    return LoopState(driver.initial_state(), knob, None)


def step(
    state: LoopState, inputs: None, params: HPatternRun, dt_s: float
) -> tuple[LoopState, LoopOutputs]:
    """The driver feels the knob's last motion, then the knob moves."""
    knob = state.knob
    x = knob.direction * knob.lever.position_m
    vx = knob.direction * knob.lever.velocity_m_s
    driver_state, hand = driver.step(
        state.driver,
        driver.HPatternDriverInputs(x, knob.y_m, vx, knob.vy_m_s),
        params.script,
        dt_s,
    )
    knob, out = hpattern.step(
        knob,
        HPatternInputs(
            hand.force_x_N,
            hand.force_y_N,
            hand.clutch_pedal,
            params.vehicle_speed_m_s,
            params.engine_speed_rad_s,
            hand.range_high,
            hand.splitter_high,
        ),
        params.pattern,
        dt_s,
    )
    # An event is reported for a whole output sample, whichever sub-step it happened in.
    event, age = (out.event, 0.0) if out.event else (state.event, state.event_age_s + dt_s)
    shown = event if age < params.sample_s - 1e-12 else ""
    return LoopState(driver_state, knob, out, event, age), LoopOutputs(
        out.x_m, out.y_m, out.vx_m_s, out.vy_m_s, out.force_x_N, out.force_y_N,
        out.reaction_x_N, out.reaction_y_N, out.region, out.gear, shown, out.stage,
        hand.clutch_pedal, out.speed_difference_rad_s, out.grind_N, out.click_N, hand.phase,
        hand.target,
    )  # fmt: skip


def finished(state: LoopState) -> bool:
    """The driver has gone through the whole sequence and let go."""
    return state.driver.phase is driver.Phase.DONE


def stream_hpattern(
    params: HPatternRun,
    sink: Sink,
    *,
    seed: int = 0,
    max_duration_s: float = 60.0,
    dt_s: float = 1e-3,
    substeps: int = 1,
    settle_s: float = 0.3,
) -> int:
    """Drive through the script's sequence, the samples to `sink` as the run goes; stop
    `settle_s` after the driver is done. Returns the number of samples."""
    done_for = 0

    def stop_when(state: LoopState) -> bool:
        nonlocal done_for
        if finished(state):
            done_for += 1
            return done_for * dt_s >= settle_s
        return False

    _, n = stream(
        step, initial_state(params, seed), params, sink, duration_s=max_duration_s, dt_s=dt_s,
        substeps=substeps, stop_when=stop_when,
    )  # fmt: skip
    return n


def simulate_hpattern(
    params: HPatternRun,
    *,
    seed: int = 0,
    max_duration_s: float = 60.0,
    dt_s: float = 1e-3,
    substeps: int = 1,
    settle_s: float = 0.3,
    metadata: Mapping[str, str] | None = None,
) -> Result:
    """`stream_hpattern` into memory: the whole run as one Result."""
    kept = Collector()
    stream_hpattern(
        params, kept, seed=seed, max_duration_s=max_duration_s, dt_s=dt_s, substeps=substeps,
        settle_s=settle_s,
    )  # fmt: skip
    return kept.result({"seed": str(seed), **(metadata or {})})


@dataclass(frozen=True, slots=True)
class HPatternSetup:
    """What an H-pattern preset holds besides the engagement (which a shift preset gives)."""

    layout: hpattern.Layout
    """The gate: the planes, the gear slots, the neutral corridor (and a truck's box)."""
    select: hpattern.SelectParams
    """The select (y) axis: the lever's mass, friction and springs across the gate."""
    walls: hpattern.WallParams
    """The gate's walls: the corridor's edges where no slot opens, and its ends."""
    synchronizer: SynchronizerParams
    """Synchronizer, clutch and input shaft: when the synchro gate opens; grinding."""
    feel: hpattern.FeelParams
    """Latch and click cues on top of the gearbox's own forces."""
    driver: HPatternDriverParams
    """How the offline driver selects across the gate (its push and pull: the shift preset's)."""
