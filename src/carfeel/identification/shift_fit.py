"""Fit the gearshift engagement (section 3 of the paper) to measured knob traces.

A trace has `time_s`, `position_m` (the knob along the engagement slot, 0 = neutral, + toward the
gear) and `force_N` (the hand's force on the knob, + toward the gear, as the paper's Fig. 5/6), at
200 Hz or more, with noise and gaps, and any number of engagements (push in, pull out, push in
again). No stage labels are needed.

Preparation. The noise of a signal is sigma = 1.4826 * MAD(second differences) / sqrt(6) (the
second difference of white noise has variance 6 sigma^2; the median ignores the moving parts).
A sample farther than 10 sigma (force: plus 5 % of its 99th percentile) from the median of its
5 neighbours is an outlier: replaced by that median, and left out of every comparison. The rules
below run on a uniform grid at the median sample period (gaps bridged linearly) and on 5-sample
medians of it; peaks and the stop on a Savitzky-Golay smoothing (quadratic, about 7 ms).

Segmentation rules, per trace:
  plateau   the knob stays within +-3 sigma (at least 2 um) of the plateau's median position for
            at least MIN_PLATEAU_S, while the force is positive and, for at least part of it,
            above half the highest force the trace holds for 20 ms; and then the knob moves on at
            least MIN_TRAVEL_M toward the gear before the next plateau (pushing against the end
            stop is still and forceful too, but nothing follows it). Duration = last - first
            sample in the band; force = the median over its second half (the first holds the
            hand's force building up).
  arrival   the approach (the last samples 0.05-2 mm short of the plateau) extrapolated by a line
            to the plateau's position: when the blocker ring stopped the knob.
  window    an engagement runs from the end of its plateau to the start of the next (or the end).
  stop      where the smoothed position is largest in the window.
  settled   the median position after the stop, before the knob is pulled back (force below -10 %
            of the plateau force, or halfway back to the plateau), while the force is within
            +-10 % of the plateau force (the driver has let go). Overshoot = stop - settled.
  tooth     the highest peak (prominence 3 sigma) of the smoothed force from where the force has
            fallen below half the plateau force to where the knob first reaches the settled
            position: neither the synchronization force nor the stop's impact counts.

Fit, over all engagements of all traces:
  synchronization_position_m and driver.push_force_N: medians of the plateaus (while blocked the
  driver pushes with F_max, eq. 10).
  teeth_position_m, teeth_end_position_m, and each engagement's teeth resistance R_i and gate
  opening instant: the force peak at the knob is the hand catching up with a lever the teeth have
  slowed (it comes near the teeth's end, and is about twice their resistance), so these are
  fitted by simulating the passage from the gate's opening to just before the stop, open loop,
  with the recorded force (the engagement model's own `step`; its random tooth draw replaced by
  R_i). synchronization_duration_s is the median of opening - arrival (finer than the plateau's
  samples). The teeth's sliding friction and `tooth_force_spread_N` are the bounds of a uniform
  law fitted to the R_i (the unbiased ones from min and max: the model draws U(0, 1) * spread);
  the static friction keeps the base's margin over the sliding. With one engagement the spread
  is kept from the base, with a warning.
  stop.stiffness_N_m, stop.damping_N_s_m and in_gear_position_m: the same simulation from the
  free travel just before the stop through the overshoot, the push against the stop, the release
  and the settling (STOP_WINDOW_S). x_gear may lie up to 2 mm below the settled position (the
  detent's friction holds the knob up to F_st / k off it).
  The fits are bounded least squares with the robust 'soft_l1' loss at 3 sigma of the noise.
  They simulate at FIT_STEP_S, and redo a step in which the stage changes in REFINE sub-steps, so
  a guard fires close to the crossing and the positions move smoothly with the parameters: the
  fitted values are the physical (continuous-time) ones, not ones tuned to the 1 ms model's own
  discretization error. Everything else is kept from the base preset; `check_shift` is run and
  what it finds is repaired (with a warning) or warned about.

Figures: each trace is simulated open loop with the fitted parameters and its recorded force,
from its first sample, restarting at each arrival at the synchro ring (the one point where the
knob's state is known: blocked, at rest); rms error and r^2 of the position, per trace and over
all, at the measured samples that are not outliers. `resimulate` does the same for `carfeel
validate`, where no engagement has a fitted resistance: the teeth resist with the preset's mean.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification.shift_traces import (
    APPROACH_S,
    KGF_SUSPECT_N,
    EngagementFeatures,
    FloatArray,
    FoundEngagement,
    PreparedTrace,
    Trace,
    odd_at_least,
    prepare_trace,
    segment_engagements,
    true_runs,
    window_indices,
)
from carfeel.io.presets import check_shift, load_shift
from carfeel.models.gearshift import engagement
from carfeel.models.gearshift.engagement import EngagementParams, EngagementState, Stage
from carfeel.simulation.shift import ShiftParams

GEAR_SLACK_M = 0.002
"""How far below the settled position x_gear may be fitted."""
FIT_STEP_S = 2e-4
"""Model step of the fits. The model's implicit Euler lags a free lever by about v * dt / 2,
and the teeth's position trades against their resistance; at 1 ms that lag moves the fitted
teeth by about 1 mm, at 0.2 ms by less than 0.2 mm."""
REFINE = 50
DIFF_STEP = 0.05
"""Forward-difference step of the Jacobians, in the scaled unknowns (mm, ms, N, kN/m, N*s/m)."""
SOFT_L1_SCALE = 3.0
TOLERANCE = 1e-4
"""ftol and xtol of the fits: far below the noise, and a few times faster than the default."""


@dataclass(frozen=True)
class ShiftFit:
    params: ShiftParams
    """The base preset with the fitted fields replaced."""
    engagements: tuple[EngagementFeatures, ...]
    figures: dict[str, float]
    """rms_error_m and r2 of the open-loop position, overall and per trace (`trace<i>.`), each
    trace's noise, the rms of the passage and stop fits, and each fitted value by its path in
    the preset (`gearbox.stop.stiffness_N_m`, `driver.push_force_N`, ...)."""
    warnings: tuple[str, ...]
    sigmas: dict[str, float] = dataclasses.field(default_factory=dict)
    """One standard deviation of each fitted value, by its path in the preset (NaN where the
    traces cannot give one: too few engagements, or the value was repaired or kept)."""
    departures: tuple[str, ...] = ()
    """Each trace's r2 and where its model departs most (`departure`), worst first."""


Progress = Callable[[int, float], None]
"""Called with the count of model evaluations and the current rms of the scaled residuals."""


def fit_shift(
    traces: Sequence[Trace], base: ShiftParams | None = None, progress: Progress | None = None
) -> ShiftFit:
    """Fit the engagement model and the driver's push force to measured knob traces.

    `traces`: Results (or mappings of arrays) with time_s (s), position_m (m) and force_N (N).
    `base`: the preset whose other fields are kept (default: the shipped paper-first-gear).
    Raises InputError naming the trace if one is malformed or holds no engagement.
    """
    if base is None:
        base = load_shift().params
    if len(traces) == 0:
        raise InputError(
            "no traces given; pass one or more Results with time_s, position_m and force_N"
        )
    warnings: list[str] = []
    prepared = [prepare_trace(trace, index, warnings) for index, trace in enumerate(traces)]
    found = [e for trace in prepared for e in segment_engagements(trace, warnings)]

    gb = base.gearbox
    x_sync = float(np.median([e.features.synchronization_position_m for e in found]))
    push = float(np.median([e.features.plateau_force_N for e in found]))
    if push < KGF_SUSPECT_N:
        warnings.append(
            f"the synchronization holds the knob with {push:.3g} N, below the {KGF_SUSPECT_N:g} N "
            "a car's synchronizer takes (the paper's: 78.5 N, 8 kgf): if force_N is in kgf, "
            'multiply it by 9.80665 (unit = "kgf" in a channel map) and fit again'
        )
    settled = float(np.median([e.features.settled_position_m for e in found]))

    count = [0]

    def tick(residual: FloatArray) -> None:
        count[0] += 1
        if progress is not None:
            progress(count[0], float(np.sqrt(np.mean(residual * residual))))

    sigmas: dict[str, float] = {}
    teeth, teeth_end, found, passage_rms = _fit_passage(
        found, gb, x_sync, settled, warnings, tick, sigmas
    )
    gb, contacts = _chamfer_evidence(found, gb, warnings)
    # The lever's mass from the free stretches, between the teeth the passage fit placed.
    _, free_figures = _fit_mass(prepared, found, gb, x_sync, teeth, teeth_end, settled, warnings)
    times = [e.features.synchronization_time_s for e in found]
    times = [t for t in times if math.isfinite(t)]
    if times:
        duration = float(np.median(times))
    else:
        duration = float(np.median([e.features.plateau_duration_s for e in found]))
    sliding, spread = _tooth_law([e.features.tooth_resistance_N for e in found], gb, warnings)
    margin = gb.engagement.static_friction_N - gb.engagement.sliding_friction_N
    gearbox = dataclasses.replace(
        gb,
        synchronization_position_m=x_sync,
        synchronization_duration_s=duration,
        teeth_position_m=teeth,
        teeth_end_position_m=teeth_end,
        in_gear_position_m=settled,
        tooth_force_spread_N=spread,
        engagement=dataclasses.replace(
            gb.engagement, sliding_friction_N=sliding, static_friction_N=sliding + margin
        ),
    )
    gearbox, stop_rms = _fit_stop(found, gearbox, settled, warnings, tick, sigmas)
    # The driver lets go as far before the gear as in the base.
    early = gb.in_gear_position_m - base.driver.release_position_m
    driver = dataclasses.replace(
        base.driver, push_force_N=push, release_position_m=gearbox.in_gear_position_m - early
    )
    params = _fix_up(ShiftParams(gearbox, driver), base, warnings)

    figures = _figures(prepared, found, params.gearbox)
    warnings.extend(_quality_warnings(prepared, figures))
    figures["engagements"] = float(len(found))
    figures["chamfer_contacts"] = float(contacts)
    figures["passage_rms_m"] = passage_rms
    figures.update(free_figures)
    figures["stop_rms_m"] = stop_rms
    for trace in prepared:
        figures[f"trace{trace.index}.position_noise_m"] = trace.sigma_m
        figures[f"trace{trace.index}.force_noise_N"] = trace.sigma_N
    fitted = _fitted_values(params)
    figures.update(fitted)
    sigmas.update(_median_sigmas(found, times))
    drawn = sum(math.isfinite(e.features.tooth_resistance_N) for e in found)
    sigmas.update(_tooth_law_sigmas(drawn, spread))
    # A value `_fix_up` repaired is no longer the fitted one: no sigma for it.
    as_fitted = _fitted_values(ShiftParams(gearbox, driver))
    sigmas = {k: sigmas.get(k, math.nan) if v == as_fitted[k] else math.nan
              for k, v in fitted.items()}  # fmt: skip
    order = sorted(prepared, key=lambda tr: figures[f"trace{tr.index}.r2"])
    departures = tuple(departure(figures, tr) for tr in order)
    return ShiftFit(params, tuple(e.features for e in found), figures, tuple(warnings), sigmas,
                    departures)  # fmt: skip


# --- open-loop simulation ----------------------------------------------------------------------


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


# --- the fits ----------------------------------------------------------------------------------


def _solve(
    residuals: Callable[[FloatArray], FloatArray],
    lower: FloatArray,
    upper: FloatArray,
    groups: Sequence[Sequence[int]],
    rows_of: Sequence[slice | None],
    tick: Callable[[FloatArray], None],
    start: FloatArray | None = None,
    max_nfev: int = 100,
) -> Any:
    """Bounded robust least squares from `start` (default 0) over unknowns scaled to order 1.

    The Jacobian is a forward difference of fixed step DIFF_STEP: scipy's relative steps vanish
    at 0, and the simulated positions move in quanta of a refined step that a step of 1e-8
    cannot see. The columns of a group touch disjoint rows (`rows_of`, None = all rows) and are
    differenced together, so per-engagement unknowns cost one simulation per kind, not per
    engagement.
    """
    from scipy.optimize import least_squares

    last: dict[bytes, FloatArray] = {}

    def fun(z: FloatArray) -> FloatArray:
        key = z.tobytes()
        if key not in last:
            last.clear()
            last[key] = residuals(z)
            tick(last[key])
        return last[key]

    def jac(z: FloatArray) -> FloatArray:
        f0 = fun(z)
        jacobian = np.zeros((len(f0), len(z)))
        for group in groups:
            cols = np.asarray(group)
            step = np.where(z[cols] + DIFF_STEP <= upper[cols], DIFF_STEP, -DIFF_STEP)
            moved = z.copy()
            moved[cols] += step
            change = residuals(moved) - f0
            for col, h in zip(cols, step, strict=True):
                rows = rows_of[col]
                if rows is None:
                    jacobian[:, col] = change / h
                else:
                    jacobian[rows, col] = change[rows] / h
        return jacobian

    return least_squares(
        fun, np.zeros(len(lower)) if start is None else start, jac=jac, bounds=(lower, upper),
        loss="soft_l1",
        f_scale=SOFT_L1_SCALE, xtol=TOLERANCE, ftol=TOLERANCE, max_nfev=max_nfev,
    )  # fmt: skip


def typical_chamfer_travel(gb: EngagementParams) -> float:
    """The chamfers' travel (m) at the tooth law's mean draw u = 1/2 (0 if that meets gap to
    gap): what an engagement without a fitted draw is simulated with."""
    miss = gb.chamfer.no_contact_fraction
    return (0.5 - miss) / (1.0 - miss) * gb.chamfer.travel_m if miss <= 0.5 else 0.0


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
    if not cases:
        warnings.append("no engagement could be used to fit the teeth; placed as in the base")
        return *fallback, list(found), math.nan
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
    k = 2 + 2 * n
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

    def unpack(z: FloatArray) -> tuple[float, float, FloatArray, FloatArray, list[float | None]]:
        teeth = teeth0 + z[0] * 1e-3
        opened = np.array([e.plateau_end_s - 0.5 * e.trace.dt_s for e, _ in cases])
        travels: list[float | None] = [0.0 if chamfered else None] * n
        for j, i in enumerate(contact):
            travels[i] = max(float(c0 + z[k + j] * 1e-3), 0.0)
        return (teeth, teeth + length0 + z[1] * 1e-3, opened + z[2 : 2 + n] * 1e-3,
                r0 + z[2 + n : k], travels)  # fmt: skip

    def predicted(z: FloatArray, forces: Forces = None) -> list[FloatArray]:
        teeth, teeth_end, opened, rs, travels = unpack(z)
        parts = []
        for (e, idx), start, r, travel in zip(cases, opened, rs, travels, strict=True):
            tr, ring = e.trace, e.features.synchronization_position_m
            params = dataclasses.replace(
                bare,
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

    measured = [e.trace.position_m[idx] for e, idx in cases]

    def residuals(
        z: FloatArray, targets: Sequence[FloatArray] = measured, forces: Forces = None
    ) -> FloatArray:
        return np.concatenate([(sim - y) / sigma for sim, y in zip(predicted(z, forces), targets,
                                                                    strict=True)])  # fmt: skip

    spans, row = [], 0
    for _, idx in cases:
        spans.append(slice(row, row + len(idx)))
        row += len(idx)
    groups = [[0], [1], list(range(2, 2 + n)), list(range(2 + n, k))]
    rows: list[slice | None] = [None, None, *spans, *spans, *(spans[i] for i in contact)]
    if m:
        groups.append(list(range(k, k + m)))
    solution = _solve(residuals, lower, upper, groups, rows, tick)
    if not solution.success:
        warnings.append(f"the teeth fit did not converge ({solution.message}); check the result")
    bias = _method_error(solution, predicted, residuals, [e.trace for e, _ in cases], lower,
                         upper, groups, rows, tick)  # fmt: skip
    teeth, teeth_end, opened, rs, travels = unpack(solution.x)
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
    rms = float(np.sqrt(np.mean(solution.fun**2))) * sigma
    covariances = _covariances(solution, spans, 2)
    sigmas["gearbox.teeth_position_m"] = _sigma_of(covariances, {0: 1.0}, bias) * 1e-3
    sigmas["gearbox.teeth_end_position_m"] = _sigma_of(covariances, {0: 1.0, 1: 1.0}, bias) * 1e-3
    return float(teeth), float(teeth_end), updated, rms


FREE_MARGIN_M = 5e-4
"""How far inside a free stretch's geometric ends its samples must lie (the guards' slack)."""
FREE_MIN_SPEED_M_S = 0.02
"""Below this the lever may stick: no sliding friction of known sign."""
FREE_WINDOW_S = 0.009


def _fit_mass(
    prepared: Sequence[PreparedTrace],
    found: Sequence[FoundEngagement],
    gb: EngagementParams,
    x_sync: float,
    teeth: float,
    teeth_end: float,
    settled: float,
    warnings: list[str],
) -> tuple[EngagementParams, dict[str, float]]:
    """The lever's mass m, the free stages' damping c and sliding friction F_sl from the free
    stretches (no spring, no contact), where F = m a + c v + F_sl sign(v): forward from the ring
    to the teeth and from the teeth's end to the stop, back out of gear toward the ring, sliding
    faster than FREE_MIN_SPEED_M_S. In its integral form over each stretch from its first sample,
    int F dt = m (v - v0) + c (x - x0) + F_sl sign(v) (t - t0), by linear least squares: no
    acceleration is needed (the hand's grip rings at about 30 Hz; a differentiated acceleration
    a fraction of a sample off the force turns that ringing into damping), and the velocities
    come from a Savitzky-Golay filter (cubic, FREE_WINDOW_S) of the position whose window lies in
    the stretch. The mass goes to every stage (one lever), the damping and friction to the free
    stages. The detents' force (the base preset's profile) acts along the stretches."""
    from scipy.optimize import least_squares
    from scipy.signal import savgol_filter

    from carfeel.models.gearshift.engagement import detent_force_N

    # The detents seat where these traces put neutral and the gear.
    seats = replace(gb, in_gear_position_m=settled)

    stretches = []
    ends = [(e.trace.index, e.plateau_end_s) for e in found]
    for tr in prepared:
        dt = tr.dt_s
        window = odd_at_least(FREE_WINDOW_S / dt, 5)
        if len(tr.grid_s) <= window:
            continue
        xg = np.interp(tr.grid_s, tr.time_s, tr.position_m)
        fg = np.interp(tr.grid_s, tr.time_s, tr.force_N)
        v = savgol_filter(xg, window, 2, deriv=1, delta=dt)
        x = savgol_filter(xg, window, 2)
        after = np.zeros(len(tr.grid_s), dtype=bool)
        for index, end_s in ends:
            if index == tr.index:
                after |= tr.grid_s > end_s
        m = FREE_MARGIN_M
        forward = (
            (v > FREE_MIN_SPEED_M_S)
            & after
            & (
                ((x > x_sync + m) & (x < teeth - m))
                | ((x > teeth_end + m) & (x < settled - GEAR_SLACK_M - m))
            )
        )
        backward = (
            (v < -FREE_MIN_SPEED_M_S)
            & (x > x_sync + m)
            & (x < settled - gb.detent_release_m - GEAR_SLACK_M - m)
        )
        for a, b in true_runs(forward | backward):
            if b - a >= 6:
                stretches.append((xg[a:b], fg[a:b], dt, float(np.sign(v[(a + b) // 2])),
                                  float(x[a]), float(v[a])))  # fmt: skip
    figures: dict[str, float] = {}
    if len(stretches) < 2:
        warnings.append(
            "too few free-travel stretches (sliding between the ring and the teeth, the teeth and "
            "the stop, or back out of gear) to fit the lever's mass; kept from the base"
        )
        return gb, figures
    sigma = max(float(np.median([tr.sigma_m for tr in prepared])), 1e-6)
    n = len(stretches)

    def residuals(z: FloatArray) -> FloatArray:
        mass, damping, friction, bias = z[0], z[1] * 10.0, z[2] * 10.0, z[3] * 10.0
        parts = []
        for i, (xs, fs, dt, sign, x0, v0) in enumerate(stretches):
            # Exact for a force linear over each step: v' = (F - F_sl s - c v) / m.
            decay = math.exp(-damping * dt / mass) if damping > 0 else 1.0
            gain = (1.0 - decay) / damping if damping > 0 else dt / mass
            pos, vel = x0 + z[4 + 2 * i] * 1e-3, v0 + z[5 + 2 * i] * 0.1
            out = [pos]
            for k in range(len(xs) - 1):
                # The spring-ball detents act in the free stages too (the base's profile).
                detent = detent_force_N(pos, seats)
                drive = 0.5 * (fs[k] + fs[k + 1]) + detent - bias - friction * sign
                new = vel * decay + gain * drive
                pos += 0.5 * (vel + new) * dt
                vel = new
                out.append(pos)
            parts.append((np.asarray(out) - xs) / sigma)
        return np.concatenate(parts)

    first = [gb.free_travel.mass_kg, gb.free_travel.damping_N_s_m / 10.0,
             gb.free_travel.sliding_friction_N / 10.0, 0.0]  # fmt: skip
    start = np.concatenate([first, np.zeros(2 * n)])
    lower = np.concatenate([[0.05, 0.0, 0.0, -np.inf], np.full(2 * n, -np.inf)])
    upper = np.concatenate([[20.0, 50.0, 10.0, np.inf], np.full(2 * n, np.inf)])
    # Each stretch's own start moves only its rows: finite differences grouped by that pattern.
    sizes = [len(stretch[0]) for stretch in stretches]
    sparsity = np.zeros((sum(sizes), len(start)), dtype=bool)
    sparsity[:, :4] = True
    row = 0
    for i, size in enumerate(sizes):
        sparsity[row : row + size, 4 + 2 * i : 6 + 2 * i] = True
        row += size
    solution = least_squares(residuals, start, bounds=(lower, upper), loss="soft_l1",
                             f_scale=3.0, jac_sparsity=sparsity)  # fmt: skip
    mass, damping, friction = (float(v) for v in solution.x[:3] * np.array([1.0, 10.0, 10.0]))
    figures["free_stretches"] = float(n)
    figures["free_rms_m"] = float(np.sqrt(np.mean(solution.fun**2))) * sigma
    figures["free_damping_N_s_m"] = damping
    figures["free_sliding_friction_N"] = friction
    figures["free_mass_kg"] = mass
    figures["force_bias_N"] = float(solution.x[3] * 10.0)
    jac = solution.jac.toarray() if hasattr(solution.jac, "toarray") else solution.jac
    try:
        covariance = np.linalg.inv(jac.T @ jac)
        figures["free_mass_sigma_kg"] = float(np.sqrt(covariance[0, 0]))
    except np.linalg.LinAlgError:
        figures["free_mass_sigma_kg"] = math.inf
    return gb, figures


def _tooth_law(
    resistances: Sequence[float], gb: EngagementParams, warnings: list[str]
) -> tuple[float, float]:
    """Sliding friction and spread (N) of the uniform law of the teeth's resistance."""
    rs = [r for r in resistances if math.isfinite(r)]
    n = len(rs)
    if n == 0:
        return gb.engagement.sliding_friction_N, gb.tooth_force_spread_N
    if n == 1:
        spread = gb.tooth_force_spread_N
        warnings.append(
            "one engagement: the spread of the tooth force is not identifiable from a single "
            f"engagement; tooth_force_spread_N kept from the base ({spread:g} N), the teeth's "
            "friction set so that the engagement's resistance is the law's mean"
        )
        return max(rs[0] - 0.5 * spread, 0.0), spread
    low, high = min(rs), max(rs)
    # The unbiased bounds of a uniform law from n draws (their expected extremes lie 1/(n+1)
    # of the width inside the bounds).
    lower = (n * low - high) / (n - 1)
    upper = (n * high - low) / (n - 1)
    if n < 4:
        warnings.append(
            f"{n} engagements: the spread of the tooth force rests on few draws; record more "
            "engagements for a firm value"
        )
    sliding = max(lower, 0.0)
    return sliding, max(upper - sliding, 0.0)


def _fit_stop(
    found: Sequence[FoundEngagement],
    gb: EngagementParams,
    settled: float,
    warnings: list[str],
    tick: Callable[[FloatArray], None],
    sigmas: dict[str, float],
) -> tuple[EngagementParams, float]:
    """Stop stiffness, damping and x_gear, simulating from the free travel through the stop."""
    cases = []
    for e in found:
        tr = e.trace
        # A line through the free travel just short of the stop gives the state to start from.
        idx = window_indices(tr, e.stop_reach_s - APPROACH_S, e.stop_reach_s)
        x = tr.position_m[idx]
        below = e.features.settled_position_m - GEAR_SLACK_M - 2e-4
        idx = idx[(x <= below) & (x >= gb.teeth_end_position_m + 5e-4)][-8:]
        compare = window_indices(tr, tr.time_s[idx[-1]] + 1e-9, e.stop_end_s) if len(idx) else idx
        slope = float(np.polyfit(tr.time_s[idx], tr.position_m[idx], 1)[0]) if len(idx) > 1 else 0
        if len(idx) < 2 or slope <= 0.0 or len(compare) < 5:
            warnings.append(
                f"{tr.label}, engagement at {e.features.start_time_s:.3f} s: too few samples "
                "before or in the stop; left out of the stop fit"
            )
            continue
        t0 = float(tr.time_s[idx[-1]])
        # A parabola gives the state at t0: the gear detent's suck-in accelerates the lever here.
        curve = np.polyfit(tr.time_s[idx] - t0, tr.position_m[idx], 2) if len(idx) > 3 else None
        offset = float(curve[2]) if curve is not None else float(tr.position_m[idx[-1]])
        speed = float(curve[1]) if curve is not None and curve[1] > 0.0 else slope
        state = engagement.initial_state()._replace(
            stage=Stage.FREE_TRAVEL, position_m=offset, velocity_m_s=speed
        )
        cases.append((tr, state, t0, compare))
    if not cases:
        warnings.append(
            "no engagement could be used to fit the stop; its stiffness and damping are the "
            "base's and x_gear is the settled position"
        )
        return gb, math.nan
    sigma = max(float(np.median([c[0].sigma_m for c in cases])), 1e-5)
    k0, c0 = gb.stop.stiffness_N_m, gb.stop.damping_N_s_m
    # Unknowns, scaled to order 1: kN/m, N*s/m, and mm from the settled position.
    lower = np.array([(500.0 - k0) / 1e3, -c0, -GEAR_SLACK_M * 1e3])
    upper = np.array([(2e6 - k0) / 1e3, 2000.0 - c0, 0.5])

    def params_of(z: FloatArray) -> EngagementParams:
        stop = dataclasses.replace(gb.stop, stiffness_N_m=k0 + z[0] * 1e3, damping_N_s_m=c0 + z[1])
        return dataclasses.replace(gb, stop=stop, in_gear_position_m=settled + z[2] * 1e-3)

    def predicted(z: FloatArray, forces: Forces = None) -> list[FloatArray]:
        params = params_of(z)
        return [simulate_open_loop(params, state, t0, tr.time_s[idx], tr.time_s,
                                   tr.force_N if forces is None else forces[tr.index])
                for tr, state, t0, idx in cases]  # fmt: skip

    measured = [tr.position_m[idx] for tr, _, _, idx in cases]

    def residuals(
        z: FloatArray, targets: Sequence[FloatArray] = measured, forces: Forces = None
    ) -> FloatArray:
        return np.concatenate([(sim - y) / sigma for sim, y in zip(predicted(z, forces), targets,
                                                                    strict=True)])  # fmt: skip

    groups, rows = [[0], [1], [2]], [None] * 3
    solution = _solve(residuals, lower, upper, groups, rows, tick)
    if not solution.success:
        warnings.append(f"the stop fit did not converge ({solution.message}); check the result")
    bias = _method_error(solution, predicted, residuals, [c[0] for c in cases], lower, upper,
                         groups, rows, tick)  # fmt: skip
    rms = float(np.sqrt(np.mean(solution.fun**2))) * sigma
    spans, row = [], 0
    for case in cases:
        spans.append(slice(row, row + len(case[3])))
        row += len(case[3])
    covariances = _covariances(solution, spans, 3)
    # And the jackknife over the engagements: each left out in turn, the rest refitted from the
    # solution. What differs from one engagement to the next (its approach, its hand) scatters
    # the stop's values more than the linear sandwich over six clusters says: the stiffness
    # scattered by 1.9 of its sigma over repeated fits.
    if len(cases) >= JACKKNIFE_MIN:
        covariances.append(_jackknife(solution, cases, params_of, sigma, lower, upper, tick))
    for i, (path, unit) in enumerate((("gearbox.stop.stiffness_N_m", 1e3),
                                      ("gearbox.stop.damping_N_s_m", 1.0),
                                      ("gearbox.in_gear_position_m", 1e-3))):  # fmt: skip
        sigmas[path] = _sigma_of(covariances, {i: 1.0}, bias) * unit
    # The knob rests in gear on one step of a quantized sensor that its noise does not dither:
    # where in the step x_gear lies no sample says, the same on every engagement (q / sqrt(12)
    # shared). Without it, 6 traces at 0.05 mm steps: x_gear 34 um off at a sigma of 8 um.
    steps = [c[0].resolution_m for c in cases if c[0].noise_m < 0.5 * c[0].resolution_m]
    if steps:
        shared = max(steps) / math.sqrt(12.0)
        sigmas["gearbox.in_gear_position_m"] = math.hypot(
            sigmas["gearbox.in_gear_position_m"], shared
        )
    return params_of(solution.x), rms


JACKKNIFE_MIN = 4
"""Engagements the stop fit needs before its jackknife is taken (fewer: too few to tell)."""


def _jackknife(
    solution: Any,
    cases: Sequence[tuple[PreparedTrace, EngagementState, float, npt.NDArray[np.intp]]],
    params_of: Callable[[FloatArray], EngagementParams],
    sigma: float,
    lower: FloatArray,
    upper: FloatArray,
    tick: Callable[[FloatArray], None],
) -> FloatArray:
    """The delete-one jackknife covariance of the stop fit's unknowns (scaled): (n-1)/n times
    the sum of the outer products of each leave-one-out refit's departure from their mean."""
    estimates = []
    for left in range(len(cases)):
        rest = [c for j, c in enumerate(cases) if j != left]

        def fun(z: FloatArray, rest: Sequence[Any] = rest) -> FloatArray:
            params = params_of(z)
            return np.concatenate([
                (simulate_open_loop(params, state, t0, tr.time_s[idx], tr.time_s, tr.force_N)
                 - tr.position_m[idx]) / sigma
                for tr, state, t0, idx in rest
            ])  # fmt: skip

        again = _solve(fun, lower, upper, [[0], [1], [2]], [None] * 3, tick,
                       start=np.clip(solution.x, lower, upper), max_nfev=30)  # fmt: skip
        estimates.append(np.asarray(again.x, dtype=float))
    d = np.array(estimates) - np.mean(estimates, axis=0)
    return np.asarray(d.T @ d * (len(cases) - 1) / len(cases))


def _covariance(solution: Any) -> FloatArray:
    """Gauss-Newton covariance of a fit's unknowns (in their scaled units): (J^T J)^-1 times
    the residuals' variance (they are in units of the noise, so about 1 for a model that fits).
    Residuals correlated in time (what a model misses hangs together along a run) make it a lower
    bound; an unknown the data cannot move gets an infinite variance."""
    jac = np.asarray(solution.jac, dtype=float)
    m, p = jac.shape
    variance = float(np.sum(np.asarray(solution.fun) ** 2)) / max(m - p, 1)
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    weak = s <= 1e-10 * (s[0] if len(s) else 1.0)
    cov = (vt[~weak].T / s[~weak] ** 2) @ vt[~weak] * variance
    if weak.any():
        loose = np.any(np.abs(vt[weak]) > 0.1, axis=0)
        cov[loose, :] = math.inf
        cov[:, loose] = math.inf
    return np.asarray(cov)


CORRELATION_BLOCK = 10
"""Samples per block of the residuals' correlation factor (`_covariances`): 20 ms at 500 Hz."""


def _covariances(solution: Any, cases: Sequence[slice], shared: int) -> list[FloatArray]:
    """Covariances of a simulation fit's unknowns whose rows come in cases (one engagement
    each; its own unknowns after the first `shared`): Gauss-Newton (`_covariance`) times the
    residuals' correlation factor within each case (the variance of their sums over blocks of
    CORRELATION_BLOCK samples over the sum of their squares: a knob's stairs, or what the model
    misses along a passage, hang together for many samples), and for the shared unknowns the
    cluster sandwich over the engagements (J^T J)^-1 (sum_c g_c g_c^T) (J^T J)^-1 with g_c =
    J_c^T r_c and the small-sample factor C / (C - p): what differs from one engagement to the
    next (its start, its draw) scatters the shared ones more than the noise would. The stop's
    stiffness came out 1.5 kN/m from the truth at a Gauss-Newton sigma of 13 N/m. A sigma is
    the largest of them (`_sigma_of`)."""
    r = np.asarray(solution.fun, dtype=float)
    jac = np.asarray(solution.jac, dtype=float)
    plain = _covariance(solution)
    total = float(np.sum(r * r))
    sums = 0.0
    for case in cases:
        part = r[case]
        ends = np.arange(CORRELATION_BLOCK, len(part), CORRELATION_BLOCK)
        sums += sum(float(np.sum(b)) ** 2 for b in np.split(part, ends))
    factor = max(sums / total, 1.0) if total > 0.0 else 1.0
    out = [plain, plain * factor]
    n = len(cases)
    if n > shared:
        scores = np.array([jac[case].T @ r[case] for case in cases])
        meat = scores.T @ scores * (n / (n - shared))
        _, sv, vt = np.linalg.svd(jac, full_matrices=False)
        keep = sv > 1e-10 * (sv[0] if len(sv) else 1.0)
        inverse = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
        robust = inverse @ meat @ inverse
        # Only the shared unknowns' block: an engagement's own unknowns zero its own score.
        robust[shared:, :] = 0.0
        robust[:, shared:] = 0.0
        out.append(robust)
    return out


def _sigma_of(
    covariances: Sequence[FloatArray], weights: Mapping[int, float],
    bias: FloatArray | None = None,
) -> float:  # fmt: skip
    """The largest standard deviation of sum(w_i x_i) over the covariances, and no less than
    the method's error in it (`_method_error`) where that is given."""
    idx, w = list(weights), np.array(list(weights.values()))
    variances = [float(w @ c[np.ix_(idx, idx)] @ w) for c in covariances]
    if not all(map(math.isfinite, variances)):
        return math.inf
    sigma = math.sqrt(max(max(variances), 0.0))
    return max(sigma, abs(float(w @ bias[idx]))) if bias is not None else sigma


def _replica(
    traces: Sequence[PreparedTrace], predicted: Sequence[FloatArray], seed: int = 0
) -> list[FloatArray]:
    """What each trace's sensor would have recorded of `predicted`: its noise added, and
    rounded to its resolution on the trace's own grid of values."""
    rng = np.random.default_rng(seed)
    out = []
    for tr, sim in zip(traces, predicted, strict=True):
        y = sim + rng.normal(0.0, tr.noise_m, len(sim)) if tr.noise_m > 0.0 else sim.copy()
        q = tr.resolution_m
        if q > 0.0:
            origin = float(tr.position_m[0])
            y = origin + np.round((y - origin) / q) * q
        out.append(np.asarray(y, dtype=float))
    return out


Forces = Mapping[int, FloatArray] | None
"""Each trace's force (by its index) to drive a fit's simulations with; None: as recorded."""


def _method_error(
    solution: Any, predicted: Callable[[FloatArray], list[FloatArray]],
    residuals: Callable[[FloatArray, Sequence[FloatArray], Forces], FloatArray],
    traces: Sequence[PreparedTrace], lower: FloatArray, upper: FloatArray,
    groups: Sequence[Sequence[int]], rows: Sequence[slice | None],
    tick: Callable[[FloatArray], None],
) -> FloatArray:  # fmt: skip
    """The fit's own error (scaled unknowns), by one replica of the experiment: the fitted
    model's traces recorded as the sensors would (`_replica`: the position's noise and
    resolution), fitted again as the traces were, from the same start, with the force driving
    the simulations carrying a fresh draw of its own noise (an error in the input the residuals
    cannot show: 1 N of it moved the stop's stiffness by 3 % from one draw to the next at a
    Gauss-Newton sigma of 0.4 %); the refit's departure from the fit. It holds what the sigmas
    of the position noise miss: a stop's ringing under a 0.05 mm resolution looks damped, the
    500 Hz samples of a 31 Hz ring (k +2 % without any noise), a solver that stops on the flat
    steps of a quantized cost. One draw: it also holds one draw of the noise, so `_sigma_of`
    takes the larger of it and the sigma, not their sum."""
    rng = np.random.default_rng(1)
    forces = {tr.index: tr.force_N + rng.normal(0.0, tr.noise_N, len(tr.force_N))
              for tr in traces}  # fmt: skip
    targets = _replica(traces, predicted(solution.x))
    again = _solve(lambda z: residuals(z, targets, forces), lower, upper, groups, rows, tick)
    return np.asarray(again.x - solution.x, dtype=float)


def _median_error(values: Sequence[float]) -> float:
    """Standard error of the median of `values`: 1.2533 s / sqrt(n), the large-sample one of a
    normal sample (within 5 % of the true one from n = 3 on); NaN from fewer than three."""
    v = [x for x in values if math.isfinite(x)]
    return 1.2533 * float(np.std(v, ddof=1)) / math.sqrt(len(v)) if len(v) >= 3 else math.nan


def _median_sigmas(found: Sequence[FoundEngagement], times: Sequence[float]) -> dict[str, float]:
    """The sigmas of the values that are medians over the engagements: the scatter between
    engagements (`_median_error`), but no less than what each plateau's own samples leave (its
    median's error, over the engagements) and, where the sensor's stairs are not dithered by
    its noise, its resolution's q / sqrt(12), shared by every plateau and so not averaged away
    (a quantized ring read the same on all six plateaus: a sigma of 0)."""

    def floor(sigma: float, samples: float, step: float, noise: float) -> float:
        within = 1.2533 * sigma / math.sqrt(max(samples, 1.0)) / math.sqrt(len(found))
        shared = step / math.sqrt(12.0) if noise < 0.5 * step else 0.0
        return math.hypot(within, shared)

    def combined(between: float, least: float) -> float:
        return math.nan if math.isnan(between) else max(between, least)

    # The plateau's position is the median over it, its force over its second half.
    samples = float(np.median([e.features.plateau_duration_s / e.trace.dt_s for e in found]))
    tr = found[0].trace
    ring = floor(float(np.median([e.trace.sigma_m for e in found])), samples,
                 max(e.trace.resolution_m for e in found), tr.noise_m)  # fmt: skip
    push = floor(float(np.median([e.trace.sigma_N for e in found])), samples / 2.0,
                 max(e.trace.resolution_N for e in found), tr.noise_N)  # fmt: skip
    return {
        "gearbox.synchronization_position_m": combined(
            _median_error([e.features.synchronization_position_m for e in found]), ring
        ),
        "gearbox.synchronization_duration_s": _median_error(times),
        "driver.push_force_N": combined(
            _median_error([e.features.plateau_force_N for e in found]), push
        ),
    }


def _tooth_law_sigmas(n: int, spread: float) -> dict[str, float]:
    """Standard deviations of the uniform law's bounds estimated from n draws (`_tooth_law`): for
    U(a, a + w), var(lower) = n w^2 / ((n + 1)(n + 2)(n - 1)) and var(spread) = 2 w^2 / ((n - 1)
    (n + 2)) (from the moments of the extremes); none from one draw."""
    if n < 2:
        return {}
    lower = spread * math.sqrt(n / ((n + 1) * (n + 2) * (n - 1)))
    return {
        "gearbox.engagement.sliding_friction_N": lower,
        "gearbox.engagement.static_friction_N": lower,
        "gearbox.tooth_force_spread_N": spread * math.sqrt(2.0 / ((n - 1) * (n + 2))),
    }


def _fix_up(params: ShiftParams, base: ShiftParams, warnings: list[str]) -> ShiftParams:
    """Repair what `check_shift` would find where a safe repair exists; warn about the rest."""
    g, d = params.gearbox, params.driver
    x_sync = g.synchronization_position_m
    if not x_sync < g.teeth_position_m < g.teeth_end_position_m < g.in_gear_position_m:
        b = base.gearbox
        # The base's teeth, shifted with the ring, and shrunk if the travel is shorter.
        room = g.in_gear_position_m - b.detent_release_m - x_sync
        scale = min(1.0, 0.9 * room / (b.teeth_end_position_m - b.synchronization_position_m))
        teeth = x_sync + scale * (b.teeth_position_m - b.synchronization_position_m)
        end = x_sync + scale * (b.teeth_end_position_m - b.synchronization_position_m)
        warnings.append(
            f"fitted positions out of order (synchronization {x_sync:.4g} m, teeth "
            f"{g.teeth_position_m:.4g}..{g.teeth_end_position_m:.4g} m, in gear "
            f"{g.in_gear_position_m:.4g} m); the teeth are placed as in the base instead"
        )
        g = dataclasses.replace(g, teeth_position_m=teeth, teeth_end_position_m=end)
    if g.in_gear.stiffness_N_m > g.stop.stiffness_N_m:
        warnings.append(
            f"gearbox.in_gear.stiffness_N_m lowered from {g.in_gear.stiffness_N_m:g} to the "
            f"fitted stop's {g.stop.stiffness_N_m:.4g} N/m (the detent may not be stiffer)"
        )
        g = dataclasses.replace(
            g, in_gear=dataclasses.replace(g.in_gear, stiffness_N_m=g.stop.stiffness_N_m)
        )
    held = g.stop.static_friction_N / g.stop.stiffness_N_m
    if g.settle_distance_m <= held:
        warnings.append(
            f"gearbox.settle_distance_m raised from {g.settle_distance_m:g} to {2 * held:.3g} m: "
            "the fitted stop's friction holds the knob farther off x_gear"
        )
        g = dataclasses.replace(g, settle_distance_m=2.0 * held)
    room = g.in_gear_position_m - g.teeth_end_position_m
    if g.detent_release_m >= room:
        warnings.append(
            f"gearbox.detent_release_m shortened from {g.detent_release_m:g} to {room / 2:.3g} m "
            "to fit between the teeth and the gear"
        )
        g = dataclasses.replace(g, detent_release_m=room / 2)
    if not g.teeth_end_position_m < d.release_position_m <= g.in_gear_position_m:
        d = dataclasses.replace(d, release_position_m=g.in_gear_position_m)
    if d.neutral_position_m >= g.synchronization_position_m:
        warnings.append(
            f"driver.neutral_position_m lowered from {d.neutral_position_m:g} m to half the "
            "fitted synchronization position"
        )
        d = dataclasses.replace(d, neutral_position_m=0.5 * g.synchronization_position_m)
    params = ShiftParams(g, d)
    warnings.extend(f"check_shift: {problem}" for problem in check_shift(params))
    return params


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


def _fitted_values(params: ShiftParams) -> dict[str, float]:
    g, d = params.gearbox, params.driver
    return {
        "gearbox.synchronization_position_m": g.synchronization_position_m,
        "gearbox.synchronization_duration_s": g.synchronization_duration_s,
        "gearbox.teeth_position_m": g.teeth_position_m,
        "gearbox.teeth_end_position_m": g.teeth_end_position_m,
        "gearbox.in_gear_position_m": g.in_gear_position_m,
        "gearbox.tooth_force_spread_N": g.tooth_force_spread_N,
        "gearbox.engagement.static_friction_N": g.engagement.static_friction_N,
        "gearbox.engagement.sliding_friction_N": g.engagement.sliding_friction_N,
        "gearbox.stop.stiffness_N_m": g.stop.stiffness_N_m,
        "gearbox.stop.damping_N_s_m": g.stop.damping_N_s_m,
        "driver.push_force_N": d.push_force_N,
    }
