"""N single shifts in lock step: the 1-DOF engagement and its eq. (10) driver over numpy arrays.

The physics is the pure step's (`models/gearshift/engagement.py`, `models/drivers/shift.py`,
`simulation/shift.py`), operation for operation: every lane computes the same IEEE-754 double
operations in the same order as the pure step would for its own parameters, so a lane's
trajectory equals the pure run bit for bit (`tests/test_batch_engagement.py`). What would need a
transcendental function per step is a per-lane constant computed once by the same `math` call
(the driver's exp(-h/T), the chamfers' tan); square roots are correctly rounded in both.

Events a lane meets a few times per shift (stage hand-overs, the tooth draw, the chamfers'
pick-up) are done lane by lane with the pure model's own functions; what happens every step (the
driver's hand, the stage's stick-slip step, both integrators, the detents and their energy
check) runs vectorized, each lane's branch chosen by masks.

numpy is not allowed in `models/` (it runs in the 1 kHz loop), so this lives here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.analysis.shift_features import ShiftFeatures
from carfeel.models.gearshift import engagement
from carfeel.models.gearshift.engagement import Stage
from carfeel.models.rng import next_uniform, seed_state
from carfeel.simulation.shift import ShiftParams

F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]

STAGES = tuple(Stage)
"""Stage codes: the index in this tuple (neutral 0 ... returning 7)."""
NEUTRAL, SYNC, GATE_OPEN, ENGAGED, FREE, STOP, IN_GEAR, RETURNING = range(8)
STAGE_NAMES = np.array([s.value for s in STAGES])
_CODE = {s: i for i, s in enumerate(STAGES)}
PUSH, RELEASE, PULL, IDLE = range(4)
_DONE = 1.0 - 1e-9  # as engagement._DONE


def _sel(mask: B, a: npt.ArrayLike, b: npt.ArrayLike) -> F64:
    """np.where(mask, a, b), short-cut when the mask is uniform (most masks, most steps)."""
    if not mask.any():
        return _full(b, mask)
    if mask.all():
        return _full(a, mask)
    return np.where(mask, a, b)


def _full(value: npt.ArrayLike, like: B) -> F64:
    if isinstance(value, np.ndarray) and value.shape == like.shape:
        return value
    return np.full(like.shape, value)


def _floats(values: Sequence[float]) -> F64:
    return np.array(values, dtype=np.float64)


@dataclass(frozen=True)
class _Detent:
    """One detent's constants per lane (see engagement._detent)."""

    seat: F64
    width: F64
    """Signed distance from the seat to the crest."""
    sign: float
    span: F64
    peak: F64
    help_: F64
    far: F64
    far_safe: F64
    has_far: B
    top: F64
    flat: F64
    """Potential beyond the far flank (the flat branch of _detent)."""
    flat_j: F64
    """_flat_J: the potential the energy check takes beyond the detent's reach."""
    reach: F64


def _detent_constants(params: Sequence[ShiftParams], neutral: bool) -> _Detent:
    gearboxes = [p.gearbox for p in params]
    ds = [g.neutral_detent if neutral else g.gear_detent for g in gearboxes]
    seat = _floats([0.0 if neutral else g.in_gear_position_m for g in gearboxes])
    width = _floats([d.width_m if neutral else -d.width_m for d in ds])
    span = _floats([d.width_m for d in ds])
    far = _floats([d.far_width_m for d in ds])
    return _Detent(
        seat=seat,
        width=width,
        sign=1.0 if neutral else -1.0,
        span=span,
        peak=_floats([d.seat_force_N for d in ds]),
        help_=_floats([d.far_force_N for d in ds]),
        far=far,
        far_safe=_sel(far > 0.0, far, 1.0),
        has_far=far > 0.0,
        top=_floats([d.seat_force_N * d.width_m * (2.0 / 3.0) for d in ds]),
        flat=_floats(
            [
                d.seat_force_N * d.width_m * (2.0 / 3.0)
                - d.far_force_N * d.far_width_m * (2.0 / 3.0)
                for d in ds
            ]
        ),
        flat_j=_floats([engagement._flat_J(d.width_m, d) for d in ds]),
        reach=_floats([d.width_m + d.far_width_m for d in ds]),
    )


def _detent(x: F64, d: _Detent) -> tuple[F64, F64, F64]:
    """(force, potential, stiffness) of one detent at x, every lane (engagement._detent)."""
    u = (x - d.seat) / d.width
    mirror = u < 0.0
    u = _sel(mirror, -u, u)
    sign = _sel(mirror, -d.sign, d.sign)
    # The flank toward the seat.
    one_u = 1.0 - u
    f_flank = -sign * 4.0 * d.peak * u * one_u
    e_flank = d.peak * d.span * u * u * (2.0 - u * (4.0 / 3.0))
    k_flank = 4.0 * d.peak * (1.0 - 2.0 * u) / d.span
    # Past the crest.
    w = _sel(d.has_far, (u - 1.0) * d.span / d.far_safe, 1.0)
    one_w = 1.0 - w
    f_far = sign * 4.0 * d.help_ * w * one_w
    e_far = d.top - d.help_ * d.far * w * w * (2.0 - w * (4.0 / 3.0))
    k_far = -4.0 * d.help_ * (1.0 - 2.0 * w) / d.far_safe
    flank = u < 1.0
    far = ~flank & (w < 1.0)
    force = _sel(flank, f_flank, _sel(far, f_far, 0.0))
    energy = _sel(flank, e_flank, _sel(far, e_far, d.flat))
    stiffness = _sel(flank, k_flank, _sel(far, k_far, 0.0))
    return force, energy, stiffness


def _energy(x: F64, d: _Detent) -> F64:
    """The potential only (engagement._detent(...)[1])."""
    u = (x - d.seat) / d.width
    u = _sel(u < 0.0, -u, u)
    e_flank = d.peak * d.span * u * u * (2.0 - u * (4.0 / 3.0))
    w = _sel(d.has_far, (u - 1.0) * d.span / d.far_safe, 1.0)
    e_far = d.top - d.help_ * d.far * w * w * (2.0 - w * (4.0 / 3.0))
    return _sel(u < 1.0, e_flank, _sel(w < 1.0, e_far, d.flat))


def stick_slip(
    x: F64,
    v: F64,
    force: F64,
    mass: F64,
    damping: F64,
    stiffness: F64,
    rest: F64,
    static: F64,
    sliding: F64,
    band: F64,
    h: float,
) -> tuple[F64, F64]:
    """`mechanics.stick_slip_step` over arrays: (position, velocity)."""
    m_h = mass / h
    impedance = m_h + damping + h * stiffness
    applied = force - stiffness * (x - rest)
    stuck = (-band < v) & (v < band) & (-static <= applied) & (applied <= static)
    drive = m_h * v + applied
    stops = (-sliding <= drive) & (drive <= sliding)
    friction = _sel(drive > 0.0, sliding, -sliding)
    velocity = (drive - friction) / impedance
    still = stuck | stops
    return _sel(still, x, x + h * velocity), _sel(still, 0.0, velocity)


def stick_slip_midpoint(
    x: F64,
    v: F64,
    force: F64,
    mass: F64,
    damping: F64,
    stiffness: F64,
    rest: F64,
    static: F64,
    sliding: F64,
    band: F64,
    h: float,
) -> tuple[F64, F64]:
    """`mechanics.stick_slip_midpoint_step` over arrays: (position, velocity)."""
    applied = force - stiffness * (x - rest)
    stuck = (-band < v) & (v < band) & (-static <= applied) & (applied <= static)
    stop = mass * v / h + applied - (0.5 * damping + 0.25 * h * stiffness) * v
    halts = (-sliding <= stop) & (stop <= sliding) & (stop * v >= 0.0) & ~stuck
    drive = 2.0 * mass * v / h + applied
    stops = (-sliding <= drive) & (drive <= sliding) & ~stuck & ~halts
    friction = _sel(drive > 0.0, sliding, -sliding)
    mid = (drive - friction) / (2.0 * mass / h + damping + 0.5 * h * stiffness)
    x1 = _sel(stuck | stops, x, _sel(halts, x + 0.5 * h * v, x + h * mid))
    v1 = _sel(stuck | stops | halts, 0.0, 2.0 * mid - v)
    return x1, v1


@dataclass
class BatchTrace:
    """What each lane did at every output sample: (samples, lanes) arrays."""

    dt_s: float
    position_m: F64
    force_N: F64
    stage: npt.NDArray[np.int8]

    def time_s(self) -> F64:
        return np.arange(1, self.position_m.shape[0] + 1, dtype=np.float64) * self.dt_s


@dataclass
class BatchRun:
    """A batch's figures per lane, and its trace if it was recorded."""

    features: list[ShiftFeatures]
    time_to_stop_s: F64
    """Time of the first sample at the end stop (the gear is in), NaN if never."""
    finite: B
    """The lane's position and force stayed finite."""
    trace: BatchTrace | None


class _Features:
    """`shift_features` accumulated sample by sample (O(lanes) memory, not O(samples))."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.k = 0
        self.first = np.full(len(STAGES) * n, -1, dtype=np.int64)
        self.flat_lane = np.arange(n)
        self.sync_count = np.zeros(n, dtype=np.int64)
        self.sync_peak = np.full(n, -np.inf)
        self.sync_lanes: list[npt.NDArray[np.intp]] = []
        self.sync_forces: list[F64] = []
        self.sync_x = np.full(n, np.nan)
        self.teeth_x = np.full(n, np.nan)
        self.teeth_peak = np.full(n, -np.inf)
        self.teeth_peak_x = np.full(n, np.nan)
        self.stop_peak = np.full(n, -np.inf)
        self.stop_x = np.full(n, -np.inf)
        self.finite = np.ones(n, dtype=bool)

    def add(self, stage: npt.NDArray[np.int8], x: F64, force: F64) -> None:
        at = stage.astype(np.intp) * self.n + self.flat_lane
        new = self.first[at] < 0
        if new.any():
            self.first[at[new]] = self.k
            lanes = np.flatnonzero(new)
            entering = stage[lanes]
            for code, target in ((SYNC, self.sync_x), (ENGAGED, self.teeth_x)):
                hit = lanes[entering == code]
                target[hit] = x[hit]
        sync = stage == SYNC
        if sync.any():
            lanes = np.flatnonzero(sync)
            self.sync_count[lanes] += 1
            values = force[lanes]
            self.sync_peak[lanes] = np.maximum(self.sync_peak[lanes], values)
            self.sync_lanes.append(lanes)
            self.sync_forces.append(values)
        teeth = stage == ENGAGED
        if teeth.any():
            better = teeth & (force > self.teeth_peak)
            self.teeth_peak = _sel(better, force, self.teeth_peak)
            self.teeth_peak_x = _sel(better, x, self.teeth_peak_x)
        stop = stage == STOP
        if stop.any():
            self.stop_peak = _sel(stop, np.maximum(self.stop_peak, force), self.stop_peak)
            self.stop_x = _sel(stop, np.maximum(self.stop_x, x), self.stop_x)
        self.finite &= np.isfinite(x) & np.isfinite(force)
        self.k += 1

    def result(
        self, params: Sequence[ShiftParams], dt_s: float, stage: npt.NDArray[np.int8], x: F64
    ) -> tuple[list[ShiftFeatures], F64]:
        times = np.arange(1, self.k + 1, dtype=np.float64) * dt_s
        dt = float(times[1] - times[0]) if self.k > 1 else math.nan
        first = self.first.reshape(len(STAGES), self.n)
        medians = np.full(self.n, np.nan)
        if self.sync_lanes:
            # np.median of each lane's plateau, vectorized: the middle value, or the mean
            # (a + b) / 2 of the two middle values, exactly as np.median computes it.
            lanes = np.concatenate(self.sync_lanes)
            forces = np.concatenate(self.sync_forces)
            order = np.lexsort((forces, lanes))
            lanes, forces = lanes[order], forces[order]
            starts = np.flatnonzero(np.r_[True, lanes[1:] != lanes[:-1]])
            counts = np.diff(np.r_[starts, len(lanes)])
            upper = starts + counts // 2
            lower = np.where(counts % 2 == 1, upper, upper - 1)
            medians[lanes[starts]] = (forces[lower] + forces[upper]) / 2.0
        nan = math.nan
        names = [str(name) for name in STAGE_NAMES]
        firsts = first.T.tolist()
        sync_x, teeth_x = self.sync_x.tolist(), self.teeth_x.tolist()
        sync_peak, teeth_peak = self.sync_peak.tolist(), self.teeth_peak.tolist()
        teeth_peak_x, stop_peak = self.teeth_peak_x.tolist(), self.stop_peak.tolist()
        stop_x, median_list = self.stop_x.tolist(), medians.tolist()
        hold = (self.sync_count * dt).tolist()
        finals, final_x = stage.tolist(), x.tolist()
        out = []
        for i, p in enumerate(params):
            entry = firsts[i]
            entered = sorted((k, c) for c, k in enumerate(entry) if k >= 0)
            sync, teeth, stop = entry[SYNC] >= 0, entry[ENGAGED] >= 0, entry[STOP] >= 0
            out.append(
                ShiftFeatures(
                    stages=tuple(names[c] for _, c in entered),
                    synchronization_position_m=sync_x[i] if sync else nan,
                    synchronization_force_N=median_list[i] if sync else nan,
                    synchronization_peak_N=sync_peak[i] if sync else nan,
                    synchronization_hold_s=hold[i],
                    engagement_position_m=teeth_x[i] if teeth else nan,
                    engagement_peak_N=teeth_peak[i] if teeth else nan,
                    engagement_peak_position_m=teeth_peak_x[i] if teeth else nan,
                    stop_peak_N=stop_peak[i] if stop else nan,
                    stop_overshoot_m=(stop_x[i] - p.gearbox.in_gear_position_m if stop else nan),
                    final_stage=names[finals[i]],
                    final_position_m=final_x[i],
                )
            )
        stop_first = first[STOP]
        to_stop = np.where(stop_first >= 0, times[np.maximum(stop_first, 0)], np.nan)
        return out, to_stop


class ShiftBatch:
    """N shifts (the pure `simulation.shift.step` loop) stepped together.

    `params[i]` and `seeds[i]` are lane i's; they may all differ. `run` gives the samples a pure
    `simulate_shift(params[i], seed=seeds[i], duration_s, dt_s, substeps)` would record.
    """

    def __init__(self, params: Sequence[ShiftParams], seeds: Sequence[int]) -> None:
        if len(params) != len(seeds) or not params:
            raise ValueError("one seed per parameter set, at least one lane")
        self.params = list(params)
        n = self.n = len(params)
        self.lane = np.arange(n)
        g = [p.gearbox for p in params]
        d = [p.driver for p in params]
        self.gearboxes = g
        # Gearbox constants per lane.
        self.x_sync = _floats([p.synchronization_position_m for p in g])
        self.x_teeth = _floats([p.teeth_position_m for p in g])
        self.x_teeth_end = _floats([p.teeth_end_position_m for p in g])
        self.x_gear = _floats([p.in_gear_position_m for p in g])
        self.stop_end = _floats([p.stop_travel_m for p in g])
        self.x_end = _floats([p.in_gear_position_m + p.stop_travel_m for p in g])
        self.x_release = _floats([p.in_gear_position_m - p.detent_release_m for p in g])
        self.bound = _floats(
            [
                p.neutral.stiffness_N_m * p.synchronization_position_m
                + (p.neutral_detent.seat_force_N + p.ring_release_force_N)
                for p in g
            ]
        )
        self.hold = _floats([p.hold_force_N for p in g])
        self.sync_s = _floats([p.synchronization_duration_s for p in g])
        self.by_force = np.array([p.synchronization_force_N > 0.0 for p in g], dtype=bool)
        self.ref_less_hold = _floats([p.synchronization_force_N - p.hold_force_N for p in g])
        self.desync_s = _floats([p.desynchronization_time_s for p in g])
        self.neg_reversal = _floats([-p.reversal_force_N for p in g])
        self.reversal_s = _floats([p.reversal_time_s for p in g])
        self.band = _floats([p.stick_velocity_m_s for p in g])
        self.settle_v = _floats([p.settle_velocity_m_s for p in g])
        self.settle_x = _floats([p.settle_distance_m for p in g])
        self.link_k = _floats([p.linkage_stiffness_N_m for p in g])
        self.link_c = _floats([p.linkage_damping_N_s_m for p in g])
        self.neutral_mass = _floats([p.neutral.mass_kg for p in g])
        loads = [engagement.chamfer_load(p, None, None) for p in g]
        self.index_mass = _floats([m for m, _ in loads])
        self.index_drag = _floats([f for _, f in loads])
        # Stage tables, flattened (stage * n + lane); the blocked stage takes neutral's values
        # (its lanes are overwritten by the ring's hold).
        table: dict[str, list[float]] = {k: [] for k in ("m", "k", "c", "fs", "fsl", "x0")}
        for stage in STAGES:
            for p in g:
                mech, rest = engagement.mechanics(
                    p, Stage.NEUTRAL if stage is Stage.SYNCHRONIZATION else stage
                )
                table["m"].append(mech.mass_kg)
                table["k"].append(mech.stiffness_N_m)
                table["c"].append(mech.damping_N_s_m)
                table["fs"].append(mech.static_friction_N)
                table["fsl"].append(mech.sliding_friction_N)
                table["x0"].append(rest)
        self.table = {k: _floats(v) for k, v in table.items()}
        self.n_detent = _detent_constants(params, neutral=True)
        self.g_detent = _detent_constants(params, neutral=False)
        # Driver constants per lane.
        self.push_f = _floats([p.push_force_N for p in d])
        self.push_v = _floats([p.push_velocity_m_s for p in d])
        self.pull_f = _floats([p.pull_force_N for p in d])
        self.pull_v = _floats([p.pull_velocity_m_s for p in d])
        self.hand_m = _floats([p.hand_mass_kg for p in d])
        self.hand_k = _floats([p.hand_stiffness_N_m for p in d])
        self.hand_c = _floats([p.hand_damping_N_s_m for p in d])
        self.release_x = _floats([p.release_position_m for p in d])
        self.hold_s = _floats([p.hold_s for p in d])
        self.pull_out = np.array([p.pull_out for p in d], dtype=bool)
        self.neutral_x = _floats([p.neutral_position_m for p in d])
        self.drivers = d
        # State: the lever at rest in neutral, the hand on it (initial_state of both models).
        zeros = np.zeros(n)
        self.stage = np.zeros(n, dtype=np.int8)
        self.x = zeros.copy()
        self.v = zeros.copy()
        self.stage_time = zeros.copy()
        self.progress = zeros.copy()
        self.tooth = zeros.copy()
        self.rng = [seed_state(s) for s in seeds]
        self.index_end = zeros.copy()
        self.contact = zeros.copy()
        self.reversal = zeros.copy()
        self.phase = np.zeros(n, dtype=np.int8)
        self.phase_time = zeros.copy()
        self.hand_x = zeros.copy()
        self.hand_v = zeros.copy()
        self.activation = zeros.copy()
        self._h: float | None = None

    def _set_step(self, h: float) -> None:
        """The constants that depend on the model step h."""
        self._h = h
        self.d_sync = h / self.sync_s
        self.d_desync = h / self.desync_s
        self.exp_act = _floats([math.exp(-h / p.activation_time_s) for p in self.drivers])
        self.exp_rel = _floats([math.exp(-h / p.release_time_s) for p in self.drivers])
        self.hand_mh = self.hand_m / h
        self.hand_hk = h * self.hand_k

    def run(
        self, duration_s: float, dt_s: float = 1e-3, substeps: int = 1, record: bool = False
    ) -> BatchRun:
        """Step every lane for `duration_s`, one output sample every `dt_s` (as `runner.run`);
        `record` keeps every sample (memory: samples x lanes x 17 bytes)."""
        n_samples = round(duration_s / dt_s)
        if n_samples < 1 or substeps < 1 or not dt_s > 0.0:
            raise ValueError("need dt_s > 0, substeps >= 1 and at least one sample")
        h = dt_s / substeps
        self._set_step(h)
        shape = (n_samples, self.n) if record else (0, self.n)
        positions = np.empty(shape)
        forces = np.empty(shape)
        stages = np.empty(shape, dtype=np.int8)
        figures = _Features(self.n)
        force = np.zeros(self.n)
        with np.errstate(all="ignore"):  # branches not taken may divide by zero: masked out
            for k in range(n_samples):
                for _ in range(substeps):
                    force = self._driver_step(h)
                    self._lever_step(force, h)
                figures.add(self.stage, self.x, force)
                if record:
                    positions[k] = self.x
                    forces[k] = force
                    stages[k] = self.stage
        features, to_stop = figures.result(self.params, dt_s, self.stage, self.x)
        trace = BatchTrace(dt_s, positions, forces, stages) if record else None
        return BatchRun(features, to_stop, figures.finite, trace)

    def _driver_step(self, h: float) -> F64:
        """`models.drivers.shift.step` for every lane; returns the knob force, N."""
        x, v, phase = self.x, self.v, self.phase
        nxt = phase.copy()
        nxt[(phase == PUSH) & (x >= self.release_x) & (v <= 0.0)] = RELEASE
        done = (phase == RELEASE) & (self.phase_time >= self.hold_s)
        nxt[done] = np.where(self.pull_out[done], PULL, IDLE)
        nxt[(phase == PULL) & (x <= self.neutral_x)] = IDLE
        same = nxt == phase
        self.phase_time = _sel(same, self.phase_time + h, 0.0)
        releasing = nxt == RELEASE
        pulling = nxt == PULL
        act = _sel(same | releasing, self.activation, 0.0)
        act = _sel(releasing, act * self.exp_rel, 1.0 - (1.0 - act) * self.exp_act)
        scaled = act * _sel(pulling, self.pull_f, self.push_f)
        bias = _sel(pulling, -scaled, scaled)
        gain = scaled / _sel(pulling, self.pull_v, self.push_v)
        k, c, m_h = self.hand_k, self.hand_c, self.hand_mh
        impedance = m_h + gain + c + self.hand_hk
        v_h = (m_h * self.hand_v + bias - k * (self.hand_x - x) + c * v) / impedance
        x_h = self.hand_x + h * v_h
        force = k * (x_h - x) + c * (v_h - v)
        idle = nxt == IDLE
        self.phase = nxt
        self.hand_x = _sel(idle, x, x_h)
        self.hand_v = _sel(idle, v, v_h)
        self.activation = _sel(idle, 0.0, act)
        return _sel(idle, 0.0, force)

    def _hand_over(
        self, v: F64, x: F64, old: npt.NDArray[np.int8], new: npt.NDArray[np.int8]
    ) -> F64:
        """engagement._hand_over on the lanes whose stage changed (a few per shift)."""
        changed = np.flatnonzero(old != new)
        if changed.size:
            v = v.copy()
            for i in changed.tolist():
                v[i] = engagement._hand_over(
                    float(v[i]), float(x[i]), STAGES[old[i]], STAGES[new[i]], self.gearboxes[i]
                )
        return v

    def _lever_step(self, force: F64, h: float) -> None:
        """`models.gearshift.engagement.step` for every lane, with the driver's force."""
        stage0 = self.stage
        x, v, progress = self.x, self.v, self.progress
        stage = stage0.copy()
        # Guards on force and time, before the motion of this step.
        blocked = stage0 == SYNC
        held: B | None = None
        if blocked.any():
            drop = blocked & (force < self.bound) & (force < self.hold)
            stage[drop] = NEUTRAL
            loaded = blocked & ~drop
            rate = self.d_sync
            scaled = loaded & self.by_force
            if scaled.any():  # the cone's rate grows with the axial load (engagement.step)
                rate = _sel(scaled, rate * ((force - self.hold) / self.ref_less_hold), rate)
            progress = _sel(loaded, progress + rate, progress)
            opens = loaded & (progress >= _DONE)
            stage[opens] = GATE_OPEN
            held = loaded & ~opens
        pulls = force < self.neg_reversal
        pulled = (stage0 == ENGAGED) & pulls
        held_in = (stage0 == STOP) | (stage0 == IN_GEAR)
        reversal = _sel(pulled | (held_in & pulls), self.reversal + h, 0.0)
        stage[pulled & (reversal >= self.reversal_s) & (v <= 0.0)] = RETURNING
        drifting = (stage0 == NEUTRAL) & (progress > 0.0)
        progress = _sel(drifting, np.maximum(0.0, progress - self.d_desync), progress)
        v = self._hand_over(v, x, stage0, stage)

        at = stage.astype(np.intp) * self.n + self.lane
        t = self.table
        mech_mass = t["m"][at]
        stiffness = t["k"][at]
        damping = t["c"][at]
        rest = t["x0"][at]
        engaged = stage == ENGAGED
        contact = self.contact
        heavy = engaged & (contact <= x) & (x < self.index_end)
        extra = _sel(engaged, self.tooth, 0.0)
        mass = _sel(heavy, mech_mass + self.index_mass, mech_mass)
        extra = _sel(heavy, extra + self.index_drag, extra)
        # The detents, linearized where they stiffen.
        nd, gd = self.n_detent, self.g_detent
        near_n = (-nd.reach < x) & (x < nd.reach)
        off_g = x - self.x_gear
        near_g = (-gd.reach < off_g) & (off_g < gd.reach)
        f_n, u_n, k_n = _detent(x, nd)
        f_g, u_g, k_g = _detent(x, gd)
        detent = _sel(near_n, f_n, 0.0)
        k_detent = _sel(near_n, k_n, 0.0)
        detent = _sel(near_g, detent + f_g, detent)
        k_detent = _sel(near_g, k_detent + k_g, k_detent)
        stiffer = k_detent > 0.0
        rest = _sel(stiffer, (stiffness * rest + k_detent * x) / (stiffness + k_detent), rest)
        stiffness = _sel(stiffer, stiffness + k_detent, stiffness)
        k_detent = _sel(stiffer, k_detent, 0.0)
        static = t["fs"][at] + extra
        sliding = t["fsl"][at] + extra
        applied = force + detent
        args = (x, v, applied, mass, damping, stiffness, rest, static, sliding, self.band, h)
        x_be, v_be = stick_slip(*args)
        x_mid, v_mid = stick_slip_midpoint(*args)
        midpoint = (stage == STOP) | (stage == IN_GEAR)
        x1 = _sel(midpoint, x_mid, x_be)
        v1 = _sel(midpoint, v_mid, v_be)
        # The detents' work beyond the fall of their potential comes out of the kinetic energy.
        near_n1 = (-nd.reach < x1) & (x1 < nd.reach)
        off_g1 = x1 - self.x_gear
        near_g1 = (-gd.reach < off_g1) & (off_g1 < gd.reach)
        dx = x1 - x
        excess = (detent - 0.5 * k_detent * dx) * dx
        either_n = near_n | near_n1
        either_g = near_g | near_g1
        before = _sel(near_n, u_n, nd.flat_j)
        after = _sel(near_n1, _energy(x1, nd), nd.flat_j)
        excess = _sel(either_n, excess + (after - before), excess)
        before = _sel(near_g, u_g, gd.flat_j)
        after = _sel(near_g1, _energy(x1, gd), gd.flat_j)
        excess = _sel(either_g, excess + (after - before), excess)
        gains = (x1 != x) & (either_n | either_g) & (excess > 0.0)
        kinetic = 0.5 * mass * v1 * v1
        pays = gains & (kinetic > excess)
        stays = gains & ~pays
        v1 = _sel(pays, v1 * np.sqrt(1.0 - excess / kinetic), v1)
        x1 = _sel(stays, x, x1)
        v1 = _sel(stays, 0.0, v1)

        # Guards on position, at the end of the motion of this step.
        new = stage.copy()
        index_end = self.index_end
        x_sync = self.x_sync
        reaches_ring = (stage == NEUTRAL) & (x1 >= x_sync) & (v1 > 0.0)
        new[reaches_ring] = SYNC
        x1 = _sel(reaches_ring, x_sync, x1)
        v1 = _sel(reaches_ring, 0.0, v1)
        # The rear stop behind neutral (plastic, at -x_gear).
        behind = (stage == NEUTRAL) & ~reaches_ring & (x1 < -self.x_gear)
        x1 = _sel(behind, -self.x_gear, x1)
        v1 = _sel(behind, 0.0, v1)
        gate = stage == GATE_OPEN
        new[gate & (x1 < x_sync)] = RETURNING
        teeth = gate & (x1 >= x_sync) & (x1 >= self.x_teeth)
        new[teeth] = ENGAGED
        lined_up = engaged & (x1 >= index_end)
        meets = lined_up & (index_end > 0.0) & ~heavy & (x < contact)  # met and passed in a step
        index_end = _sel(lined_up, 0.0, index_end)
        new[engaged & (x1 >= self.x_teeth_end)] = FREE
        new[engaged & (x1 < self.x_teeth_end) & (x1 < self.x_teeth)] = RETURNING
        free = stage == FREE
        at_stop = free & (x1 >= self.x_gear)
        new[at_stop] = STOP
        if at_stop.any():
            # No energy gained entering the stop: the kinetic energy is capped at its value
            # plus the driver's work up to x_gear less the detents' climb (engagement.step).
            xg = self.x_gear
            climb = (_energy(xg, nd) + _energy(xg, gd)) - (_energy(x, nd) + _energy(x, gd))
            gained = force * (xg - x) - climb
            cap = 0.5 * mech_mass * v * v + gained
            over = at_stop & (0.5 * mech_mass * v1 * v1 > cap)
            capped = _sel(cap > 0.0, np.sqrt(2.0 * cap / mech_mass), 0.0)
            v1 = _sel(over, capped, v1)
        x1 = _sel(at_stop, self.x_gear, x1)
        new[free & ~at_stop & (x1 < self.x_teeth_end)] = RETURNING
        hard = midpoint & (self.stop_end > 0.0) & (x1 > self.x_end)  # the gate's end, plastic
        x1 = _sel(hard, self.x_end, x1)
        v1 = _sel(hard, 0.0, v1)
        off = x1 - self.x_gear
        pulled_out = (reversal > 0.0) & (reversal >= self.reversal_s)  # a pull, held
        out = midpoint & (x1 < self.x_release) & pulled_out
        new[out] = RETURNING
        settled = (
            (stage == STOP)
            & ~out
            & (-self.settle_v < v1)
            & (v1 < self.settle_v)
            & (-self.settle_x < off)
            & (off < self.settle_x)
        )
        new[settled] = IN_GEAR
        returning = stage == RETURNING
        home = returning & (x1 <= x_sync)
        new[home] = NEUTRAL
        progress = _sel(home, 0.0, progress)
        again = returning & ~home & (v1 > 0.0) & (force > 0.0)
        new[again & (x < self.x_teeth)] = GATE_OPEN
        new[again & (x >= self.x_teeth) & (x < self.x_teeth_end)] = ENGAGED
        new[again & (x >= self.x_teeth_end)] = FREE
        tooth = self.tooth
        drawn = np.flatnonzero(teeth)
        if drawn.size:
            tooth, index_end, contact = tooth.copy(), index_end.copy(), contact.copy()
            for i in drawn.tolist():
                p = self.gearboxes[i]
                self.rng[i], u = next_uniform(self.rng[i])
                tooth[i] = u * p.tooth_force_spread_N
                miss = p.chamfer.no_contact_fraction
                index_end[i] = contact[i] = 0.0
                if u >= miss:
                    travel = p.chamfer.travel_m
                    contact[i] = p.teeth_position_m + (u - miss) / (1.0 - miss) * travel
                    index_end[i] = p.teeth_position_m + travel
        v1 = self._hand_over(v1, x1, stage, new)
        crossing = (contact <= x1) & (x1 < index_end) & ~heavy
        picks = np.flatnonzero((new == ENGAGED) & (meets | crossing))
        if picks.size:
            v1 = v1.copy()
            for i in picks.tolist():
                m = float(mech_mass[i])
                v1[i] = engagement.hand_over_velocity(
                    float(v1[i]), m, m + float(self.index_mass[i])
                )
        if held is not None and held.any():
            # The ring holds these lanes: the whole step is the hold (rigid, or the linkage).
            x_held = x.copy()
            v_held = np.zeros(self.n)
            linked = held & (self.link_k > 0.0)
            if linked.any():
                zero = np.zeros(self.n)
                xl, vl = stick_slip(
                    x,
                    v,
                    force,
                    self.neutral_mass,
                    self.link_c,
                    self.link_k,
                    x_sync,
                    zero,
                    zero,
                    zero,
                    h,
                )
                behind = xl < x_sync
                xl = _sel(behind, x_sync, xl)
                vl = _sel(behind, 0.0, vl)
                x_held = _sel(linked, xl, x_held)
                v_held = _sel(linked, vl, v_held)
            x1 = _sel(held, x_held, x1)
            v1 = _sel(held, v_held, v1)
        self.stage_time = _sel(new == stage0, self.stage_time + h, 0.0)
        self.stage, self.x, self.v = new, x1, v1
        self.progress, self.tooth, self.index_end = progress, tooth, index_end
        self.contact = contact
        self.reversal = reversal
