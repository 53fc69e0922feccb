"""The shift fit's free travel (`_fit_mass`): the lever's mass, the free stages' damping and
sliding friction from the stretches where the knob slides with no spring and no contact."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from carfeel.identification.shift_solver import GEAR_SLACK_M
from carfeel.identification.shift_traces import (
    FloatArray,
    FoundEngagement,
    PreparedTrace,
    odd_at_least,
    true_runs,
)
from carfeel.models.gearshift.engagement import EngagementParams

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

    from carfeel.models.gearshift.engagement import detent_force_N

    # The detents seat where these traces put neutral and the gear.
    seats = replace(gb, in_gear_position_m=settled)
    stretches = _free_stretches(prepared, found, gb, x_sync, teeth, teeth_end, settled)
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


Stretch = tuple[FloatArray, FloatArray, float, float, float, float]
"""A free stretch: its positions (m) and forces (N) on the trace's grid, the grid's step (s),
the sign of its velocity, and the smoothed position (m) and velocity (m/s) at its start."""


def _free_stretches(
    prepared: Sequence[PreparedTrace], found: Sequence[FoundEngagement], gb: EngagementParams,
    x_sync: float, teeth: float, teeth_end: float, settled: float,
) -> list[Stretch]:  # fmt: skip
    """The stretches of at least 6 grid points after an engagement's plateau where the knob
    slides freely (`_fit_mass`), FREE_MARGIN_M inside the free stages' ends."""
    from scipy.signal import savgol_filter

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
    return stretches
