"""The engagement model driven open loop by a recorded force, as the shift fit (`shift_fit`)
simulates it: at FIT_STEP_S, a step in which the stage changes redone in REFINE sub-steps, the
teeth's random draw replaced by a fitted resistance and chamfer travel."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from carfeel.identification.shift_traces import FloatArray
from carfeel.models.gearshift import engagement
from carfeel.models.gearshift.engagement import EngagementParams, EngagementState, Stage

FIT_STEP_S = 2e-4
"""Model step of the fits. The model's implicit Euler lags a free lever by about v * dt / 2,
and the teeth's position trades against their resistance; at 1 ms that lag moves the fitted
teeth by about 1 mm, at 0.2 ms by less than 0.2 mm."""
REFINE = 50


def simulate_open_loop(
    params: EngagementParams,
    state: EngagementState,
    start_s: float,
    sample_times_s: FloatArray,
    time_s: FloatArray,
    force_N: FloatArray,
    step_s: float = FIT_STEP_S,
    tooth_force_N: float | None = None,
    chamfer_travel_m: float | None = None,
) -> FloatArray:
    """Position (m) at `sample_times_s` of the engagement model driven by a recorded force (N).

    The model starts in `state` at `start_s` and steps by `step_s`, the force interpolated
    linearly at the end of each step (as the runner does); before `start_s` the position is the
    state's. A step in which the stage changes is redone in REFINE sub-steps, so a guard fires
    within step_s / REFINE of the crossing. `tooth_force_N`, if given, replaces the model's
    random tooth draw each time the lever enters the teeth from the ring; `chamfer_travel_m`
    the chamfers' indexing that the same draw sets: the lever carries the gear (the chamfer's
    inertia, picked up by a plastic impact, and its drag) over that much travel past the teeth
    (0: the teeth met gap to gap). Without it the chamfers' indexing is off.
    """
    bare = params
    if params.chamfer.gear_inertia_kg_m2 > 0.0 or params.chamfer.drag_torque_Nm > 0.0:
        chamfer = dataclasses.replace(params.chamfer, gear_inertia_kg_m2=0.0, drag_torque_Nm=0.0)
        bare = dataclasses.replace(params, chamfer=chamfer)
    model = bare if chamfer_travel_m is None else params
    index_mass = engagement.chamfer_load(params, None, None)[0] if model is params else 0.0
    lever_mass = params.engagement.mass_kg
    stop_s = float(sample_times_s[-1]) if len(sample_times_s) else start_s
    n = max(0, math.ceil((stop_s - start_s) / step_s - 1e-9))
    ends = start_s + step_s * np.arange(1, n + 1)
    forces = np.interp(ends, time_s, force_N).tolist()
    positions = [state.position_m]
    previous = float(np.interp(start_s, time_s, force_N))
    step, inputs, teeth, gate = (
        engagement.step, engagement.EngagementInputs, Stage.ENGAGEMENT, Stage.GATE_OPEN
    )  # fmt: skip
    fine = step_s / REFINE
    for k in range(n):
        force = forces[k]
        # Stepped from the gate, the model draws the tooth and meets the chamfers itself: with
        # the chamfer's inertia off there, the draw and the impact are set here instead.
        new, _ = step(state, inputs(force), bare if state.stage is gate else model, step_s)
        if new.stage is not state.stage:
            new = state
            for j in range(1, REFINE + 1):
                before = new.stage
                new, _ = step(new, inputs(previous + (force - previous) * j / REFINE),
                              bare if before is gate else model, fine)  # fmt: skip
                if new.stage is teeth and before is not teeth:
                    new = _entered_teeth(new, before is gate, params, tooth_force_N,
                                         chamfer_travel_m, index_mass, lever_mass)  # fmt: skip
        state = new
        positions.append(state.position_m)
        previous = force
    times = np.concatenate([[start_s], ends])
    return np.asarray(np.interp(sample_times_s, times, positions), dtype=float)


def _entered_teeth(
    state: EngagementState, from_ring: bool, params: EngagementParams,
    tooth_force_N: float | None, chamfer_travel_m: float | None, index_mass_kg: float,
    lever_mass_kg: float,
) -> EngagementState:  # fmt: skip
    """The state just in the teeth with the given draw: its tooth force, and (from the ring) the
    chamfers' end and their plastic impact (as the model's own step gives them)."""
    if tooth_force_N is not None:
        state = state._replace(tooth_force_N=tooth_force_N)
    if not from_ring:  # pushed in again after a pull: the same draw goes on
        return state
    if chamfer_travel_m is None:
        return state._replace(index_end_m=0.0)
    # The fit's chamfers meet at the teeth (contact_m 0) and turn the gear over the fitted
    # travel: one number per engagement, its impact where the knob shows it (`_met_chamfers`).
    end = params.teeth_position_m + chamfer_travel_m if chamfer_travel_m > 0.0 else 0.0
    v = state.velocity_m_s
    if state.position_m < end and index_mass_kg > 0.0:
        v = engagement.hand_over_velocity(v, lever_mass_kg, lever_mass_kg + index_mass_kg)
    return state._replace(index_end_m=end, velocity_m_s=v, contact_m=0.0)


def typical_chamfer_travel(gb: EngagementParams) -> float:
    """The chamfers' travel (m) at the tooth law's mean draw u = 1/2 (0 if that meets gap to
    gap): what an engagement without a fitted draw is simulated with."""
    miss = gb.chamfer.no_contact_fraction
    return (0.5 - miss) / (1.0 - miss) * gb.chamfer.travel_m if miss <= 0.5 else 0.0
