"""The shift fit's end stop (`_fit_stop`): its stiffness and damping and x_gear, fitted by
simulating from the free travel just before the stop through the overshoot and the settling,
with a jackknife over the engagements among its uncertainties."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.identification.shift_sim import simulate_open_loop
from carfeel.identification.shift_solver import (
    GEAR_SLACK_M,
    Forces,
    _covariances,
    _method_error,
    _sigma_of,
    _solve,
)
from carfeel.identification.shift_traces import (
    APPROACH_S,
    FloatArray,
    FoundEngagement,
    PreparedTrace,
    window_indices,
)
from carfeel.models.gearshift import engagement
from carfeel.models.gearshift.engagement import EngagementParams, EngagementState, Stage


def _fit_stop(
    found: Sequence[FoundEngagement],
    gb: EngagementParams,
    settled: float,
    warnings: list[str],
    tick: Callable[[FloatArray], None],
    sigmas: dict[str, float],
) -> tuple[EngagementParams, float]:
    """Stop stiffness, damping and x_gear, simulating from the free travel through the stop."""
    cases = _stop_cases(found, gb, warnings)
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


StopCase = tuple[PreparedTrace, EngagementState, float, npt.NDArray[np.intp]]
"""A case of the stop fit: the trace, the state the simulation starts from, its time (s), and
the indices of the samples it compares."""


def _stop_cases(
    found: Sequence[FoundEngagement], gb: EngagementParams, warnings: list[str]
) -> list[StopCase]:
    """The engagements whose free travel just short of the stop and whose stop have enough
    samples, each with the state a line (or parabola) through that travel gives; the others
    warned about."""
    cases: list[StopCase] = []
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
    return cases


JACKKNIFE_MIN = 4
"""Engagements the stop fit needs before its jackknife is taken (fewer: too few to tell)."""


def _jackknife(
    solution: Any,
    cases: Sequence[StopCase],
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
