"""The shift fit's passage through the teeth (`_fit_passage`): the teeth's positions, and for
each engagement the gate's opening, its teeth resistance and (where the knob shows the chamfers'
impact, `_met_chamfers`) its chamfer travel, fitted by simulating from the gate's opening to
just before the stop; and whether the traces keep the base's chamfers (`_chamfer_evidence`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.identification.shift_sim import simulate_open_loop, typical_chamfer_travel
from carfeel.identification.shift_solver import (
    GEAR_SLACK_M,
    Forces,
    _covariances,
    _method_error,
    _sigma_of,
    _solve,
)
from carfeel.identification.shift_traces import FloatArray, FoundEngagement, window_indices
from carfeel.models.gearshift import engagement
from carfeel.models.gearshift.engagement import EngagementParams, Stage

IMPACT_SHARE = 0.9
"""An engagement met the chamfers (the gear's plastic impact at the teeth) where the knob's speed
drops within IMPACT_LAG_S by at least this share of the impact's own drop, 1 - m / (m + m_gear)
(`_met_chamfers`). Measured, 0.05 mm and 1 N of noise, the base's chamfers (a drop of 0.60):
0.57-0.70 where they met, 0.30-0.48 gap to gap (and with none at all); the cut 0.54."""
IMPACT_LAG_S = 0.006


def _met_chamfers(e: FoundEngagement, gb: EngagementParams) -> bool:
    """Whether an engagement's knob shows the chamfers' impact: its speed (differences of the
    samples, interpolated to the grid) falls in IMPACT_LAG_S by IMPACT_SHARE of the impact's
    drop, somewhere between the gate's opening and the stop while it moves (> 0.05 m/s). The
    impact is a jump no solver crosses (there or not), and a fit cannot choose for itself: the
    force replayed at the samples' times misses the hand's jump at the impact by up to a sample,
    so a fit gap to gap everywhere, its teeth 3.5 mm early, followed the replay better."""
    tr = e.trace
    mass = gb.engagement.mass_kg
    expected = 1.0 - mass / (mass + engagement.chamfer_load(gb, None, None)[0])
    g = tr.grid_s
    speed = np.gradient(np.interp(g, tr.time_s, tr.position_m), g)
    window = np.flatnonzero((g >= e.plateau_end_s) & (g <= e.stop_reach_s))
    lag = max(1, round(IMPACT_LAG_S / tr.dt_s))
    if len(window) <= lag:
        return False
    before, after = speed[window[:-lag]], speed[window[lag:]]
    moving = before > 0.05
    drop = np.where(moving, (before - after) / np.where(moving, before, 1.0), 0.0)
    return bool(np.max(drop) >= IMPACT_SHARE * expected)


CHAMFER_REJECT_P = 0.01
"""The base's chamfers are taken out of the fitted preset where no fitted engagement showed
their impact and, were they there, that would happen with a probability under this (each
engagement misses them with the base's no_contact_fraction, independently: with 0.2, three
engagements gap to gap already reject them)."""


def _chamfer_evidence(
    found: Sequence[FoundEngagement], gb: EngagementParams, warnings: list[str]
) -> tuple[EngagementParams, int]:
    """The gearbox with the base's chamfers kept, or taken out where the engagements reject
    them (`CHAMFER_REJECT_P`); and how many fitted engagements met them. A preset with chamfers
    the knob never showed simulates an impact at every engagement the traces do not have: a
    chamfer-free gearbox validated at 4.9 mm rms (r2 0.90) with the base's, 1.6 mm without."""
    if not (gb.chamfer.gear_inertia_kg_m2 > 0.0 or gb.chamfer.drag_torque_Nm > 0.0):
        return gb, 0
    fitted = [e for e in found if math.isfinite(e.features.chamfer_travel_m)]
    contacts = sum(_met_chamfers(e, gb) for e in fitted)
    miss = gb.chamfer.no_contact_fraction
    chance = miss ** len(fitted) if fitted else 1.0
    if contacts or not fitted:
        return gb, contacts
    if chance < CHAMFER_REJECT_P:
        warnings.append(
            f"none of the {len(fitted)} engagements showed the chamfers' impact (the knob slowed "
            "by the gear's inertia at the teeth), which the base's chamfers (no contact in "
            f"{miss:g} of engagements) would give with a probability of {chance:.2g}; the "
            "fitted preset has none (gearbox.chamfer.gear_inertia_kg_m2 and drag_torque_Nm 0)"
        )
        chamfer = dataclasses.replace(gb.chamfer, gear_inertia_kg_m2=0.0, drag_torque_Nm=0.0)
        return dataclasses.replace(gb, chamfer=chamfer), 0
    warnings.append(
        f"none of the {len(fitted)} engagements showed the chamfers' impact, which the base's "
        f"chamfers would give with a probability of {chance:.2g}: too few to tell; the base's "
        "chamfers are kept (fit more engagements to decide)"
    )
    return gb, 0


Case = tuple[FoundEngagement, npt.NDArray[np.intp]]
"""An engagement the passage fit uses, and the indices of its trace's samples it compares."""


def _fit_passage(
    found: Sequence[FoundEngagement],
    gb: EngagementParams,
    x_sync: float,
    settled: float,
    warnings: list[str],
    tick: Callable[[FloatArray], None],
    sigmas: dict[str, float],
) -> tuple[float, float, list[FoundEngagement], float]:
    """Teeth positions (m), the engagements with their synchronization time, teeth resistance
    and chamfer travel filled in, and the fit's rms (m)."""
    fallback = (
        x_sync + gb.teeth_position_m - gb.synchronization_position_m,
        x_sync + gb.teeth_end_position_m - gb.synchronization_position_m,
    )
    cases = _passage_cases(found, warnings)
    if not cases:
        warnings.append("no engagement could be used to fit the teeth; placed as in the base")
        return *fallback, list(found), math.nan
    passage, lower, upper = _passage(cases, gb, x_sync, settled, fallback)
    n, k, contact = len(cases), passage.k, passage.contact
    m = len(contact)
    spans, row = [], 0
    for _, idx in cases:
        spans.append(slice(row, row + len(idx)))
        row += len(idx)
    groups = [[0], [1], list(range(2, 2 + n)), list(range(2 + n, k))]
    rows: list[slice | None] = [None, None, *spans, *spans, *(spans[i] for i in contact)]
    if m:
        groups.append(list(range(k, k + m)))
    solution = _solve(passage.residuals, lower, upper, groups, rows, tick)
    if not solution.success:
        warnings.append(f"the teeth fit did not converge ({solution.message}); check the result")
    bias = _method_error(solution, passage.predicted, passage.residuals,
                         [e.trace for e, _ in cases], lower, upper, groups, rows,
                         tick)  # fmt: skip
    teeth, teeth_end, opened, rs, travels = passage.unpack(solution.x)
    updated = _with_passage(found, cases, opened, rs, travels)
    rms = float(np.sqrt(np.mean(solution.fun**2))) * passage.sigma
    covariances = _covariances(solution, spans, 2)
    sigmas["gearbox.teeth_position_m"] = _sigma_of(covariances, {0: 1.0}, bias) * 1e-3
    sigmas["gearbox.teeth_end_position_m"] = _sigma_of(covariances, {0: 1.0, 1: 1.0}, bias) * 1e-3
    return float(teeth), float(teeth_end), updated, rms


def _passage_cases(found: Sequence[FoundEngagement], warnings: list[str]) -> list[Case]:
    """The engagements with at least 8 samples from just before the gate's opening to just
    before the stop, with those samples' indices; the others warned about."""
    cases = []
    for e in found:
        tr = e.trace
        idx = window_indices(tr, e.plateau_end_s - 4.0 * tr.dt_s, e.stop_reach_s - 2.0 * tr.dt_s)
        if len(idx) >= 8:
            cases.append((e, idx))
        else:
            warnings.append(
                f"{tr.label}, engagement at {e.features.start_time_s:.3f} s: too few samples "
                "from the synchronization to the stop; left out of the teeth fit"
            )
    return cases


@dataclass
class _Passage:
    """The passage fit's simulations of its cases, in its unknowns z, scaled to order 1: the
    teeth and their length (mm from teeth0 and length0), each case's gate opening (ms from
    half a sample before its plateau's end), its resistance R_i (N from r0), and the chamfer
    travel of each case in `contact` (mm from c0, from z[k] on). `bare` is the gearbox with the
    teeth's own friction off: the draw R_i is their whole resistance."""

    cases: list[Case]
    bare: EngagementParams
    teeth0: float
    length0: float
    r0: float
    c0: float
    chamfered: bool
    contact: list[int]
    sigma: float
    """The position's noise (m) the residuals are in units of."""
    measured: list[FloatArray]

    @property
    def k(self) -> int:
        return 2 + 2 * len(self.cases)

    def unpack(self, z: FloatArray) -> tuple[float, float, FloatArray, FloatArray,
                                             list[float | None]]:  # fmt: skip
        """(teeth, teeth's end (m), gate openings (s), resistances (N), chamfer travels (m,
        None: chamfers off))."""
        n, k = len(self.cases), self.k
        teeth = self.teeth0 + z[0] * 1e-3
        opened = np.array([e.plateau_end_s - 0.5 * e.trace.dt_s for e, _ in self.cases])
        travels: list[float | None] = [0.0 if self.chamfered else None] * n
        for j, i in enumerate(self.contact):
            travels[i] = max(float(self.c0 + z[k + j] * 1e-3), 0.0)
        return (teeth, teeth + self.length0 + z[1] * 1e-3, opened + z[2 : 2 + n] * 1e-3,
                self.r0 + z[2 + n : k], travels)  # fmt: skip

    def predicted(self, z: FloatArray, forces: Forces = None) -> list[FloatArray]:
        """Each case's simulated position (m) at its samples, from its gate's opening."""
        teeth, teeth_end, opened, rs, travels = self.unpack(z)
        parts = []
        for (e, idx), start, r, travel in zip(self.cases, opened, rs, travels, strict=True):
            tr, ring = e.trace, e.features.synchronization_position_m
            params = dataclasses.replace(
                self.bare,
                synchronization_position_m=ring,
                teeth_position_m=teeth,
                teeth_end_position_m=teeth_end,
                in_gear_position_m=max(e.features.settled_position_m, teeth_end + 1e-4),
            )
            state = engagement.initial_state()._replace(
                stage=Stage.GATE_OPEN, position_m=ring, synchronization_progress=1.0
            )
            parts.append(simulate_open_loop(
                params, state, float(start), tr.time_s[idx], tr.time_s,
                tr.force_N if forces is None else forces[tr.index],
                tooth_force_N=float(r), chamfer_travel_m=travel,
            ))  # fmt: skip
        return parts

    def residuals(
        self, z: FloatArray, targets: Sequence[FloatArray] | None = None, forces: Forces = None
    ) -> FloatArray:
        """(simulated - targets) / sigma over every case's samples (targets: the measured)."""
        targets = self.measured if targets is None else targets
        return np.concatenate([(sim - y) / self.sigma for sim, y in zip(
            self.predicted(z, forces), targets, strict=True)])  # fmt: skip


def _passage(
    cases: list[Case], gb: EngagementParams, x_sync: float, settled: float,
    fallback: tuple[float, float],
) -> tuple[_Passage, FloatArray, FloatArray]:  # fmt: skip
    """The passage fit's simulations, starting from the base's teeth moved with the ring
    (`fallback`) and the tooth law's mean, and the bounds of its unknowns."""
    n = len(cases)
    margin = gb.engagement.static_friction_N - gb.engagement.sliding_friction_N
    # The teeth's resistance R_i is the tooth draw; the stage's own friction is 0 here.
    bare = dataclasses.replace(
        gb,
        engagement=dataclasses.replace(
            gb.engagement, sliding_friction_N=0.0, static_friction_N=margin
        ),
    )
    lo_teeth = x_sync + 2e-4
    hi_teeth = max(settled - GEAR_SLACK_M, lo_teeth + 1e-4)
    teeth0 = float(np.clip(fallback[0], lo_teeth, hi_teeth))
    length0 = float(np.clip(fallback[1] - fallback[0], 2e-4, settled - teeth0 - 1e-4))
    r0 = gb.engagement.sliding_friction_N + 0.5 * gb.tooth_force_spread_N
    chamfered = gb.chamfer.gear_inertia_kg_m2 > 0.0 or gb.chamfer.drag_torque_Nm > 0.0
    # Where the base has chamfers, each engagement that met them (`_met_chamfers`) has its own
    # travel over them: its share of the tooth draw (the gear's inertia, picked up at the teeth,
    # slows the knob by 60 %; left out, the teeth came out 4 mm early and the validation r2
    # -0.15). The others met the teeth gap to gap: no travel, no impact.
    met = [chamfered and _met_chamfers(e, gb) for e, _ in cases]
    contact = [i for i, m in enumerate(met) if m]
    m = len(contact)
    c0, c_max = typical_chamfer_travel(gb), gb.chamfer.travel_m
    # Unknowns, scaled to order 1: the teeth and their length in mm, the gate's opening instants
    # in ms (within a few samples of the plateau's end), R_i in N, the chamfer travels in mm.
    lower = np.concatenate(
        [[(lo_teeth - teeth0) * 1e3, (2e-4 - length0) * 1e3],
         [-3.5 * e.trace.dt_s * 1e3 for e, _ in cases], np.full(n, -r0), np.full(m, -c0 * 1e3)]
    )  # fmt: skip
    upper = np.concatenate(
        [[(hi_teeth - teeth0) * 1e3, (settled - x_sync - length0) * 1e3],
         [1.5 * e.trace.dt_s * 1e3 for e, _ in cases], np.full(n, 200.0),
         np.full(m, (c_max - c0) * 1e3)]
    )  # fmt: skip
    sigma = max(float(np.median([e.trace.sigma_m for e, _ in cases])), 1e-5)
    measured = [e.trace.position_m[idx] for e, idx in cases]
    passage = _Passage(cases, bare, teeth0, length0, r0, c0, chamfered, contact, sigma, measured)
    return passage, lower, upper


def _with_passage(
    found: Sequence[FoundEngagement], cases: Sequence[Case], opened: FloatArray,
    rs: FloatArray, travels: Sequence[float | None],
) -> list[FoundEngagement]:  # fmt: skip
    """The engagements with the passage fit's synchronization time (s), teeth resistance (N)
    and chamfer travel (m) (NaN where the fit did not use them, or the chamfers are off)."""
    fitted = {
        id(e): (float(start) - e.features.start_time_s, float(r),
                math.nan if travel is None else travel)
        for (e, _), start, r, travel in zip(cases, opened, rs, travels, strict=True)
    }  # fmt: skip
    updated = []
    for e in found:
        sync_time, resistance, travel = fitted.get(id(e), (math.nan, math.nan, math.nan))
        features = dataclasses.replace(
            e.features, synchronization_time_s=sync_time, tooth_resistance_N=resistance,
            chamfer_travel_m=travel,
        )  # fmt: skip
        updated.append(dataclasses.replace(e, features=features))
    return updated
