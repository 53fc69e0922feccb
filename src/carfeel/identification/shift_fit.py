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

Here: the fit's steps, the repairs and the result. The parts: `shift_traces` (reading, checking
and segmenting the traces), `shift_sim` (the open-loop simulation), `shift_solver` (the least
squares and the sigmas of the simulation fits), `shift_passage` (the teeth and the chamfers),
`shift_free` (the lever's mass), `shift_stop` (the end stop), `shift_statistics` (the tooth law
and the medians' sigmas) and `shift_figures` (the re-simulated traces, their figures,
`resimulate`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from carfeel.errors import InputError
from carfeel.identification.shift_figures import MIN_R2 as MIN_R2
from carfeel.identification.shift_figures import _figures, _quality_warnings, departure
from carfeel.identification.shift_figures import resimulate as resimulate
from carfeel.identification.shift_free import _fit_mass
from carfeel.identification.shift_passage import _chamfer_evidence, _fit_passage
from carfeel.identification.shift_solver import _covariance as _covariance
from carfeel.identification.shift_solver import _solve as _solve
from carfeel.identification.shift_statistics import _median_error as _median_error
from carfeel.identification.shift_statistics import _median_sigmas
from carfeel.identification.shift_statistics import _tooth_law as _tooth_law
from carfeel.identification.shift_statistics import _tooth_law_sigmas as _tooth_law_sigmas
from carfeel.identification.shift_stop import _fit_stop
from carfeel.identification.shift_traces import (
    KGF_SUSPECT_N,
    EngagementFeatures,
    FloatArray,
    FoundEngagement,
    PreparedTrace,
    Trace,
    prepare_trace,
    segment_engagements,
)
from carfeel.io.presets import check_shift, load_shift
from carfeel.simulation.shift import ShiftParams


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

    count = [0]

    def tick(residual: FloatArray) -> None:
        count[0] += 1
        if progress is not None:
            progress(count[0], float(np.sqrt(np.mean(residual * residual))))

    sigmas: dict[str, float] = {}
    as_fitted, found, fits = _fit_engagements(prepared, found, base, warnings, tick, sigmas)
    params = _fix_up(as_fitted, base, warnings)

    figures = _figures(prepared, found, params.gearbox)
    warnings.extend(_quality_warnings(prepared, figures))
    figures["engagements"] = float(len(found))
    figures.update(fits)
    for trace in prepared:
        figures[f"trace{trace.index}.position_noise_m"] = trace.sigma_m
        figures[f"trace{trace.index}.force_noise_N"] = trace.sigma_N
    fitted = _fitted_values(params)
    figures.update(fitted)
    # A value `_fix_up` repaired is no longer the fitted one: no sigma for it.
    fitted_as_fitted = _fitted_values(as_fitted)
    sigmas = {k: sigmas.get(k, math.nan) if v == fitted_as_fitted[k] else math.nan
              for k, v in fitted.items()}  # fmt: skip
    order = sorted(prepared, key=lambda tr: figures[f"trace{tr.index}.r2"])
    departures = tuple(departure(figures, tr) for tr in order)
    return ShiftFit(params, tuple(e.features for e in found), figures, tuple(warnings), sigmas,
                    departures)  # fmt: skip


def _plateau_medians(
    found: Sequence[FoundEngagement], warnings: list[str]
) -> tuple[float, float, float]:
    """The synchronization position (m), the push force (N, warned about where it looks like
    kgf) and the settled position (m): medians over the engagements."""
    x_sync = float(np.median([e.features.synchronization_position_m for e in found]))
    push = float(np.median([e.features.plateau_force_N for e in found]))
    if push < KGF_SUSPECT_N:
        warnings.append(
            f"the synchronization holds the knob with {push:.3g} N, below the {KGF_SUSPECT_N:g} N "
            "a car's synchronizer takes (the paper's: 78.5 N, 8 kgf): if force_N is in kgf, "
            'multiply it by 9.80665 (unit = "kgf" in a channel map) and fit again'
        )
    settled = float(np.median([e.features.settled_position_m for e in found]))
    return x_sync, push, settled


def _fit_engagements(
    prepared: Sequence[PreparedTrace],
    found: list[FoundEngagement],
    base: ShiftParams,
    warnings: list[str],
    tick: Callable[[FloatArray], None],
    sigmas: dict[str, float],
) -> tuple[ShiftParams, list[FoundEngagement], dict[str, float]]:
    """The fitted gearbox and driver (before `_fix_up`), the engagements with what the passage
    fit gave each, and the fits' own figures (in the report's order); each fitted value's sigma
    into `sigmas`."""
    gb = base.gearbox
    x_sync, push, settled = _plateau_medians(found, warnings)
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
    sigmas.update(_median_sigmas(found, times))
    drawn = sum(math.isfinite(e.features.tooth_resistance_N) for e in found)
    sigmas.update(_tooth_law_sigmas(drawn, spread))
    fits = {"chamfer_contacts": float(contacts), "passage_rms_m": passage_rms, **free_figures,
            "stop_rms_m": stop_rms}  # fmt: skip
    return ShiftParams(gearbox, driver), found, fits


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
