"""The physical steering model, hands on, re-simulated for many parameter sets and log pieces
at once over numpy arrays: the fit's cheap twin of `carfeel.models.steering.physical.step`.

The pure step costs about 15 us a step in CPython (70 us on a loaded machine): a fit needs tens
of simulations of every log. Here one step advances a batch of shape (J, S) together: J
parameter sets (the trial point and its finite-difference neighbours) times S pieces of log,
so numpy's per-call overhead (about 1 us for each of some 150 array operations) is paid once
for the whole batch. Only the hands-on branch is here (the fit imposes the logged rim angle
and rate); pose and grip outputs are left out (nothing the torque depends on).

The arithmetic is the pure step's, in its order except where noted (the tyres' load-sensitive
mu and the stick elements' slide), so on the same inputs the two agree to rounding
(`tests/test_physical_fit.py` checks 1e-9 Nm over parking, the kinematic car, sliding tyres,
the assist's limit and the end stops; the rest of the difference is numpy's and libm's last
bit in sin, tan, atan and cos).

Parameters that may differ across J are any; those the time-wise precomputations use (the
vehicle, the relaxation length and the speed schedules' fade speeds) must be the same in every
set (checked).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.models.steering.physical import PhysicalParams, PhysicalState

FloatArray = npt.NDArray[np.float64]

STOP_MARGIN_RAD = 0.5
"""The end stops are computed at a step only when a rim or pinion angle of the batch comes
within this of the lock (elsewhere they are exactly 0)."""

CHUNK_STEPS = 32
"""Steps whose input-derived arrays are made at once."""

SHARED = (
    "relaxation_length_m",
    "assist_fade_speed_m_s",
    "active_return_fade_speed_m_s",
)
"""Fields every parameter set of a batch must share (with the whole vehicle)."""


@dataclass(frozen=True)
class Pieces:
    """S pieces of log on the 1 ms grid, all T steps long (a shorter piece holds its last
    input): the inputs of step k (at the end of the step) in row k, and each piece's start."""

    speed_m_s: FloatArray
    """(T, S)"""
    angle_rad: FloatArray
    """(T, S): the rim angle, imposed."""
    rate_rad_s: FloatArray
    """(T, S)"""
    start: FloatArray
    """(fields, S) (every set starts there) or (fields, J, S): the state each piece starts
    from, the fields in PhysicalState's order."""


FIELDS = PhysicalState._fields
"""The order of a state's fields along the first axis of the batch's state arrays."""


def stack_states(states: Sequence[PhysicalState]) -> FloatArray:
    """Per-piece states as one (fields, S) array."""
    return np.array([[float(v) for v in state] for state in states], dtype=float).T.copy()


def _column(params: Sequence[PhysicalParams], table: str, name: str, pieces: int) -> FloatArray:
    """One parameter of every set, repeated over the pieces: (J * S,)."""
    values = [float(getattr(getattr(p, table), name)) for p in params]
    return np.repeat(np.array(values), pieces)


def simulate(
    params: Sequence[PhysicalParams],
    pieces: Pieces,
    dt_s: float,
    capture: Sequence[int] = (),
    with_ay: bool = True,
    first_row: int = 0,
) -> tuple[FloatArray, FloatArray, dict[int, FloatArray]]:
    """(torque_Nm, lateral_accel_m_s2, states): the rim torque and Ay after each step, each
    (T, J, S), of every parameter set (J) on every piece (S) (Ay (0, J, S) without `with_ay`); and
    the states after the steps `capture` (rows), each (fields, J, S) (the pose fields 0: the
    torque does not see them). The torque from row `first_row` on only (row 0 of the array
    is that row): a run-in's torque is not wanted."""
    ay_too = with_ay
    first = params[0]
    for p in params[1:]:
        if p.vehicle != first.vehicle or any(
            getattr(p.tyres, n, None) != getattr(first.tyres, n, None)
            or getattr(p.system, n, None) != getattr(first.system, n, None)
            for n in SHARED
        ):
            raise ValueError(f"a batch's parameter sets must share the vehicle and {SHARED}")
    n_sets, n_pieces = len(params), pieces.speed_m_s.shape[1]
    n = n_sets * n_pieces  # flat: element j * S + s is set j on piece s

    def tyres(name: str) -> FloatArray:
        return _column(params, "tyres", name, n_pieces)

    def system(name: str) -> FloatArray:
        return _column(params, "system", name, n_pieces)

    veh = first.vehicle
    dt = dt_s
    sr = veh.steering_ratio
    length = veh.wheelbase_m
    a = veh.cg_to_front_axle_m
    b = length - a
    m = veh.mass_kg
    iz = veh.yaw_inertia_kg_m2
    lock = veh.steering_lock_rad
    fz_front = first.front_load_N
    fz_f, fz_r = 0.5 * fz_front, 0.5 * first.rear_load_N
    cf = 0.5 * veh.front_cornering_stiffness_N_rad
    cr = 0.5 * veh.rear_cornering_stiffness_N_rad

    # Per element, (B,).
    mu, e, t0 = tyres("friction_coefficient"), tyres("load_sensitivity"), tyres("pneumatic_trail_m")
    tenth_mu = 0.1 * mu
    height, track = tyres("cg_height_m"), tyres("track_m")
    share = tyres("front_roll_share")
    park_level = 2.0 / 3.0 * mu * fz_front * tyres("patch_radius_m")
    wind_up = tyres("wind_up_stiffness_Nm_rad")
    lam = system("kingpin_inclination_rad")
    jack = fz_front * system("kingpin_offset_m") * np.sin(lam) * np.cos(lam)
    trail_m = system("mechanical_trail_m")
    k_tb, c_tb = system("torsion_bar_stiffness_Nm_rad"), system("compensation_damping_Nm_s_rad")
    deadband, max_assist = system("assist_deadband_Nm"), system("max_assist_Nm")
    g_hs = system("assist_gain_high_speed_1_Nm")
    g_span = system("assist_gain_standstill_1_Nm") - g_hs
    d_hs = system("eps_damping_high_speed_Nm_s_rad")
    d_span = system("eps_damping_Nm_s_rad") - d_hs
    rise = system("eps_damping_rise_Nm_s3_rad_m2")
    ret_k, ret_max = system("active_return_Nm_rad"), system("active_return_max_Nm")
    rack_level, col_level = system("rack_friction_Nm"), system("column_friction_Nm")
    stiff = system("friction_stiffness_Nm_rad")
    presliding = system("presliding_damping_Nm_s_rad")
    rack_d = system("rack_damping_Nm_s_rad")
    ks, cs = system("stop_stiffness_Nm_rad"), system("stop_damping_Nm_s_rad")
    jr = system("rack_inertia_kg_m2")
    rack_over, col_over, park_over = rack_level / stiff, col_level / stiff, park_level / wind_up
    # The four tyres (front left, front right, rear left, rear right) as rows of (4, B). The
    # load-sensitive mu, mu * (1 - e * (Fz / Fz0 - 1)), as mu (1 + e) - (mu e / Fz0) Fz, and
    # the brush's C |alpha| / (3 mu Fz) with C / 3 taken first: equal to rounding, 6 fewer
    # operations on the (4, B) block than the pure step's order.
    nominal = np.repeat([[fz_f], [fz_f], [fz_r], [fz_r]], n, axis=1)
    stiffness = np.repeat([[cf], [cf], [cr], [cr]], n, axis=1)
    third = stiffness / 3.0
    t0_c = t0 * stiffness[:2]
    mu_top = np.broadcast_to(mu * (1.0 + e), (4, n))
    mu_slope = mu * e / nominal
    tenth4 = np.broadcast_to(tenth_mu, (4, n))

    # Per step and element, (C, B) for CHUNK_STEPS steps at a time: what depends on the inputs
    # alone (made ahead for numpy's sake, in chunks so the memory does not grow with T).
    def tiled(values: FloatArray) -> FloatArray:
        return np.tile(values, (1, n_sets))

    def chunk(k0: int) -> tuple[npt.NDArray[Any], ...]:
        rows = slice(k0, k0 + CHUNK_STEPS)
        speed = tiled(pieces.speed_m_s[rows])
        moving = speed >= veh.kinematic_speed_m_s
        fade = speed / first.system.assist_fade_speed_m_s
        back = speed / first.system.active_return_fade_speed_m_s
        k_all = speed * dt / first.tyres.relaxation_length_m
        return (
            speed, tiled(pieces.angle_rad[rows]), tiled(pieces.rate_rad_s[rows]), moving,
            np.where(moving, speed, 1.0), k_all, 1.0 + k_all, 1.0 / (1.0 + fade * fade),
            np.minimum(1.0, 0.5 * speed) / (1.0 + back * back * back * back),
        )  # fmt: skip

    moving_any = pieces.speed_m_s >= veh.kinematic_speed_m_s
    any_moving: list[bool] = np.asarray(moving_any.any(axis=1), dtype=bool).tolist()
    any_kinematic: list[bool] = np.asarray((~moving_any).any(axis=1), dtype=bool).tolist()
    near = (np.abs(pieces.angle_rad) > lock - STOP_MARGIN_RAD).any(axis=1)
    near_lock: list[bool] = np.asarray(near, dtype=bool).tolist()

    start = pieces.start
    if start.ndim == 2:
        start = np.broadcast_to(start[:, None, :], (len(FIELDS), n_sets, n_pieces))

    def full(name: str) -> FloatArray:
        return np.array(start[FIELDS.index(name)].reshape(n), dtype=float)

    theta, omega = full("pinion_angle_rad"), full("pinion_rate_rad_s")
    col_anchor, rack_anchor = full("column_anchor_rad"), full("rack_anchor_rad")
    park_anchor = full("park_anchor_rad")
    alpha_f, alpha_r = full("front_slip_rad"), full("rear_slip_rad")
    beta, r = full("sideslip_rad"), full("yaw_rate_rad_s")
    ay = full("lateral_accel_m_s2")

    steps = pieces.speed_m_s.shape[0]
    torque_out = np.empty((steps - first_row, n))
    ay_out = np.empty((steps, n) if ay_too else (0, n))
    slips, dfz = np.empty((4, n)), np.empty((4, n))
    zeros = np.zeros(n)
    wanted = set(capture)
    states: dict[int, FloatArray] = {}
    for k in range(steps):
        if k % CHUNK_STEPS == 0:
            speed, hands, hand_rates, moving, v_safe, k_all, onek_all, low_all, window_all = chunk(
                k
            )
            k0 = k
        c = k - k0
        v = speed[c]
        delta = theta / sr
        transfer = m * ay * height / track
        dfz_f = 0.5 * share * transfer
        dfz_r = 0.5 * transfer - dfz_f
        if any_moving[k]:
            vs, kk, onek = v_safe[c], k_all[c], onek_all[c]
            new_f = (alpha_f + kk * (delta - beta - a * r / vs)) / onek
            new_r = (alpha_r + kk * (b * r / vs - beta)) / onek
            slips[:2], slips[2:] = new_f, new_r
            dfz[0], dfz[1], dfz[2], dfz[3] = -dfz_f, dfz_f, -dfz_r, dfz_r
            load = nominal + dfz
            mu_i = np.maximum(tenth4, mu_top - mu_slope * load)
            # A tyre without load grips nothing: grip 0 gives x = inf (or 0 / tiny), so rest
            # 0 (or Fy 0): the pure brush's early return, without a branch.
            grip = np.maximum(mu_i * load, 0.0)
            x = third * np.abs(slips) / (grip + 1e-300)
            rest = np.maximum(1.0 - x, 0.0)
            rest3 = rest * rest * rest
            fy = np.copysign(grip, slips) * (1.0 - rest3)
            front, rear = fy[0] + fy[1], fy[2] + fy[3]
            pneumatic = t0_c[0] * new_f * rest3[0] + t0_c[1] * new_f * rest3[1]
            ay_new = (front + rear) / m
            beta_new = beta + dt * (ay_new / vs - r)
            r_new = r + dt * (a * front - b * rear) / iz
        if any_kinematic[k]:
            tan_delta = np.tan(delta)
            beta_k = np.arctan(b * tan_delta / length)
            r_k = v * np.cos(beta_k) * tan_delta / length
            ay_k = v * r_k
            front_k = m * ay_k * b / length
            pneumatic_k = t0 * front_k
            if any_moving[k]:
                mv = moving[c]
                front = np.where(mv, front, front_k)
                pneumatic = np.where(mv, pneumatic, pneumatic_k)
                ay_new = np.where(mv, ay_new, ay_k)
                beta_new = np.where(mv, beta_new, beta_k)
                r_new = np.where(mv, r_new, r_k)
                new_f = np.where(mv, new_f, 0.0)
                new_r = np.where(mv, new_r, 0.0)
            else:
                front, pneumatic, ay_new, beta_new, r_new = (
                    front_k,
                    pneumatic_k,
                    ay_k,
                    beta_k,
                    r_k,
                )
                new_f = new_r = zeros
        alpha_f, alpha_r, beta, r, ay = new_f, new_r, beta_new, r_new, ay_new

        # Kingpin torques, at the pinion.
        aligning = (trail_m * front + pneumatic) / sr
        jacking = jack * np.sin(delta) / sr
        park_anchor = (park_anchor + k_all[c] * delta) / onek_all[c]
        park, park_anchor = _stick(delta, park_anchor, park_level, wind_up, park_over)
        park = park / sr

        hand = hands[c]
        bar = k_tb * (hand - theta)
        bar_total = bar + c_tb * (hand_rates[c] - omega)
        low_speed = low_all[c]
        excess = np.maximum(np.abs(bar) - deadband, 0.0)
        boost = np.copysign(
            np.minimum(max_assist, (g_hs + g_span * low_speed) * excess * excess), bar
        )
        ret = np.minimum(np.maximum(ret_k * theta, -ret_max), ret_max) * window_all[c]
        rack_friction, rack_anchor = _stick(
            theta, rack_anchor, rack_level, stiff, rack_over, omega, presliding
        )
        damping = (rack_d + (d_hs + low_speed * d_span + rise * v * v)) * omega
        load_torque = aligning + jacking + park + rack_friction + damping
        stop: FloatArray | float = 0.0
        if near_lock[k] or np.abs(theta).max() > lock - STOP_MARGIN_RAD:
            stop = np.where(
                theta > lock,
                np.maximum(0.0, ks * (theta - lock) + cs * omega),
                np.where(theta < -lock, np.minimum(0.0, ks * (theta + lock) + cs * omega), 0.0),
            )
            load_torque = load_torque + stop
        rack_accel = (bar_total + boost - ret - load_torque) / jr
        omega = omega + dt * rack_accel
        theta = theta + dt * omega

        column, col_anchor = _stick(
            hand, col_anchor, col_level, stiff, col_over, hand_rates[c], presliding
        )
        if k >= first_row:
            torque_out[k - first_row] = (
                aligning + jacking + park + (rack_friction + column) + damping
                + jr * rack_accel + stop + (ret - boost)
            )  # fmt: skip
        if ay_too:
            ay_out[k] = ay
        if k in wanted:
            states[k] = np.stack([
                hand, hand_rates[c], theta, omega, col_anchor, rack_anchor, park_anchor,
                alpha_f, alpha_r, beta, r, zeros, zeros, zeros, ay,
            ]).reshape(len(FIELDS), n_sets, n_pieces)  # fmt: skip
    shape = (steps - first_row, n_sets, n_pieces)
    return torque_out.reshape(shape), ay_out.reshape((len(ay_out), n_sets, n_pieces)), states


def _stick(
    position: FloatArray, anchor: FloatArray, level: FloatArray, stiffness: FloatArray,
    over: FloatArray, rate: FloatArray | None = None, damping: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """The pure model's stick element over arrays: (torque, anchor); `over` = level /
    stiffness; with `rate` and `damping`, the damper that acts while it sticks. The anchor kept
    within `over` of the position is the pure step's slide (at its boundary the two may differ
    in the last bit)."""
    torque = stiffness * (position - anchor)
    anchor = np.minimum(np.maximum(anchor, position - over), position + over)
    bounded = np.minimum(np.maximum(torque, -level), level)
    if damping is None or rate is None:
        return bounded, anchor
    damped = np.minimum(np.maximum(torque + damping * rate, -level), level)
    return np.where(np.abs(torque) <= level, damped, bounded), anchor
