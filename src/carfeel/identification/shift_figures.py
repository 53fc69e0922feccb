"""How well a shift preset follows measured knob traces: each trace simulated open loop with
its recorded force, restarted where the knob's state is known (`_resimulate`), its rms error
and r2 (`_figures`), where it departs most (`departure`), and `resimulate` for `carfeel
validate`."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from carfeel.errors import InputError
from carfeel.identification.shift_sim import simulate_open_loop, typical_chamfer_travel
from carfeel.identification.shift_traces import (
    FloatArray,
    FoundEngagement,
    PreparedTrace,
    Trace,
    prepare_trace,
    segment_engagements,
)
from carfeel.models.gearshift import engagement
from carfeel.models.gearshift.engagement import EngagementParams, Stage
from carfeel.simulation.shift import ShiftParams


def _resimulate(
    tr: PreparedTrace, found: Sequence[FoundEngagement], gb: EngagementParams, typical_N: float
) -> FloatArray:
    """The trace's position (m) at its kept samples, simulated open loop with its force from its
    first sample, restarted blocked at the synchro ring at each engagement's arrival; the teeth
    resist with the engagement's fitted resistance, or `typical_N` where it has none."""
    mine = sorted(
        (e.features.start_time_s, e.features.tooth_resistance_N, e.features.chamfer_travel_m)
        for e in found
        if e.trace is tr
    )
    pulls = [(e.pull_s, e.pull_position_m) for e in found
             if e.trace is tr and math.isfinite(e.pull_s)]  # fmt: skip
    typical_m = typical_chamfer_travel(gb)
    x0 = float(tr.position_m[0])
    if x0 >= gb.in_gear_position_m - gb.detent_release_m:
        stage = Stage.IN_GEAR
    elif x0 < gb.synchronization_position_m:
        stage = Stage.NEUTRAL
    else:
        stage = Stage.RETURNING
    # (start, stage, position, teeth resistance, chamfer travel) of each piece.
    first = mine[0][1:] if mine else (typical_N, typical_m)
    pieces = [(float(tr.time_s[0]), stage, x0, *first)]
    pieces += [(t, Stage.SYNCHRONIZATION, gb.synchronization_position_m, r, c) for t, r, c in mine]
    # A pull out of gear starts from rest in gear, where the knob was: open loop from the ring,
    # the release's detent threshold turned 1 N of force noise into a knob left in gear for
    # 0.1 s, 13 mm off with the true parameters.
    pieces += [(t, Stage.IN_GEAR, x, typical_N, typical_m) for t, x in pulls]
    pieces.sort(key=lambda piece: piece[0])
    # And once the knob is out of the gear's detent, from where it is at its speed: the pull is
    # the hand's, closed loop, and a replayed force meets the detent's threshold within a
    # newton (it held a knob the truth's parameters released: in gear 0.3 s too long).
    releases = _releases(tr, gb, [t for t, _ in pulls])
    velocity = dict(zip((t for t, _, _ in releases), (v for _, _, v in releases), strict=True))
    pieces += [(t, Stage.RETURNING, x, typical_N, typical_m) for t, x, _ in releases]
    pieces.sort(key=lambda piece: piece[0])
    idx = np.flatnonzero(tr.keep)
    sim = np.zeros(len(idx))
    sliding = gb.engagement.sliding_friction_N
    for k, (start, stage, x, r, c) in enumerate(pieces):
        end = pieces[k + 1][0] if k + 1 < len(pieces) else math.inf
        part = np.flatnonzero((tr.time_s[idx] >= start) & (tr.time_s[idx] < end))
        if part.size == 0:
            continue
        state = engagement.initial_state()._replace(
            stage=stage, position_m=x, velocity_m_s=velocity.get(start, 0.0)
        )
        tooth = max((r if math.isfinite(r) else typical_N) - sliding, 0.0)
        sim[part] = simulate_open_loop(
            gb, state, start, tr.time_s[idx[part]], tr.time_s, tr.force_N, tooth_force_N=tooth,
            chamfer_travel_m=c if math.isfinite(c) else typical_m,
        )  # fmt: skip
    return sim


def _releases(
    tr: PreparedTrace, gb: EngagementParams, pulls: Sequence[float]
) -> list[tuple[float, float, float]]:
    """(time, position, velocity) where the smoothed knob, pulled from rest in gear at each of
    `pulls`, first passes the gear detent's release (x_gear - detent_release) on its way out."""
    edge = gb.in_gear_position_m - gb.detent_release_m
    speed = np.gradient(tr.x_smooth, tr.grid_s)
    out = []
    for t in pulls:
        after = np.flatnonzero((tr.grid_s > t) & (tr.x_smooth < edge))
        if after.size and speed[after[0]] < 0.0:
            i = int(after[0])
            out.append((float(tr.grid_s[i]), float(tr.x_smooth[i]), float(speed[i])))
    return out


def _figures(
    traces: Sequence[PreparedTrace], found: Sequence[FoundEngagement], gb: EngagementParams
) -> dict[str, float]:
    """rms error (m) and r^2 of each trace's open-loop position, and over all traces; and where
    each trace departs most from its model (`trace<i>.worst_time_s`, the measured and the
    model's position there)."""
    figures: dict[str, float] = {}
    sum_sq = sum_tot = 0.0
    count = 0
    typical = float(np.nanmedian([e.features.tooth_resistance_N for e in found]))
    for tr in traces:
        idx = np.flatnonzero(tr.keep)
        sim = _resimulate(tr, found, gb, typical)
        measured = tr.position_m[idx]
        sq = float(np.sum((sim - measured) ** 2))
        tot = float(np.sum((measured - measured.mean()) ** 2))
        figures[f"trace{tr.index}.rms_error_m"] = math.sqrt(sq / len(idx))
        figures[f"trace{tr.index}.r2"] = 1.0 - sq / tot if tot > 0 else math.nan
        worst = int(np.argmax(np.abs(sim - measured)))
        figures[f"trace{tr.index}.worst_time_s"] = float(tr.time_s[idx[worst]])
        figures[f"trace{tr.index}.worst_measured_m"] = float(measured[worst])
        figures[f"trace{tr.index}.worst_model_m"] = float(sim[worst])
        sum_sq += sq
        sum_tot += tot
        count += len(idx)
    figures["rms_error_m"] = math.sqrt(sum_sq / count)
    figures["r2"] = 1.0 - sum_sq / sum_tot if sum_tot > 0 else math.nan
    return figures


MIN_R2 = 0.8
"""A trace whose model (driven by its force, restarted at each arrival at the ring) follows it
with a lower r^2 is warned about; a fit whose r^2 over all traces is lower writes no preset
(`shift_workflows`): the fitted values would describe another mechanism."""


def departure(figures: Mapping[str, float], tr: PreparedTrace) -> str:
    """Where a trace's model departs most from it, as a message says it."""
    i = tr.index
    return (
        f"{tr.label}: r2 {figures[f'trace{i}.r2']:.3g}, rms "
        f"{figures[f'trace{i}.rms_error_m'] * 1e3:.3g} mm, departing most at "
        f"{figures[f'trace{i}.worst_time_s']:.3f} s (the knob at "
        f"{figures[f'trace{i}.worst_measured_m'] * 1e3:.1f} mm, the model at "
        f"{figures[f'trace{i}.worst_model_m'] * 1e3:.1f} mm)"
    )


def _quality_warnings(traces: Sequence[PreparedTrace], figures: Mapping[str, float]) -> list[str]:
    """A warning for each trace the model follows with r2 under MIN_R2."""
    return [
        f"{departure(figures, tr)}: under the {MIN_R2:g} of a model that follows the trace; "
        "the fitted values describe the other traces better than this one"
        for tr in traces
        if not figures[f"trace{tr.index}.r2"] > MIN_R2
    ]


@dataclass(frozen=True)
class Resimulation:
    """A trace next to a preset's model driven by the trace's force (kept samples only)."""

    time_s: FloatArray
    force_N: FloatArray
    measured_m: FloatArray
    model_m: FloatArray
    engagements: int


def resimulate(trace: Trace, params: ShiftParams, label: str = "trace") -> Resimulation:
    """What `carfeel validate` compares: the preset's engagement model driven open loop by the
    trace's recorded force, restarted at each arrival at the synchro ring that the segmentation
    finds (the one point where the knob's state is known), the teeth resisting with the mean of
    the preset's law (sliding friction + spread / 2). Outliers are left out; InputError as for
    a fit, naming `label`."""
    warnings: list[str] = []
    tr = prepare_trace(trace, 0, warnings, label)
    try:
        found = segment_engagements(tr, warnings)
    except InputError:  # no engagement (a pull-out, neutral only): one piece from the start
        found = []
    gb = params.gearbox
    typical = gb.engagement.sliding_friction_N + 0.5 * gb.tooth_force_spread_N
    idx = np.flatnonzero(tr.keep)
    model = _resimulate(tr, found, gb, typical)
    return Resimulation(tr.time_s[idx], tr.force_N[idx], tr.position_m[idx], model, len(found))
