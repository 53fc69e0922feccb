"""Fit the physical steering model (issue 13) to measured logs by re-simulation (output error).

The model has state (rack, frictions, tyres' lag, the car), so it cannot be fitted sample by
sample as the paper's law is: each trial parameter set is simulated over the logs with the
logged rim angle and rate imposed (`hands_on` = 1) and the logged speed, at the 1 ms step the
model runs at, and its rim torque is compared with the logged one at the logs' samples.

Fitted (`PARAMETERS`), each where the logs excite it (decided before the fit, from the logs):
the EPS assist gains at standstill and at speed, the column and rack friction, the EPS damping
at speed, the tyres' pneumatic trail and the road's friction coefficient mu. Beside them, as for
the law: a torque offset per log (constant or drifting, `drift_s`) and one delay of the torque
behind the other channels (a scan with the model held: no re-simulation, the simulated torque
is shifted). Everything else (geometry, inertias, torsion bar, the tyres' stiffness and the
rest of the EPS map) is the base car's: a car's data sheet has it, the torque hardly sees it.

Cost, and how it is kept small: the pure step costs about 15 us a step, so a 60 s log is about
1 s per simulation and a finite-difference Jacobian of p parameters p of them. Instead, each
log is cut into pieces of SEGMENT_S (each with a BURN_IN_S run-in), and all pieces of all logs,
for the trial point and its p neighbours at once, run through `physical_batch` (the same
arithmetic over numpy arrays: about 1 us per simulated step in a batch of 700). A piece starts
from the state the piece before it reached there for the same parameters, so the pieces are
swept (`Batch`) until they join up, within SWEEP_TOL_NM: then each parameter set's torque is
the pure model's over the whole log (the final check against the pure model,
`batch_check_Nm`, is about 1e-9 Nm), and the Jacobian carries the states' memory (a stuck
friction, the patches' wind-up at standstill) across pieces. The starts are guessed from the
last evaluation moved by its finite-difference sensitivities, so near the solution one sweep
suffices. The fit's rms and figures come from a final run of the pure model.

The inputs the model is driven with: the speed as `read_log` conditions it (1 Hz zero-phase);
the rate as logged (or low-passed, or derived, as for the law); the angle complementary-fused
with a logged rate (`fused_angle`), between samples a cubic Hermite through angle and rate.
The first SETTLE_S of each stretch of log is simulated but not scored: the model starts in the
linear car's steady state with its frictions relaxed, which the real car's were not.
Uncertainties, kept parameters and their reasons, the robust loss and the output are those of
`steering_fit` (`SteeringFit`, a block sandwich covariance over 2 s blocks).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification import physical_batch, rms_r2, uncertainty
from carfeel.identification.delay import MAX_DELAY_S, RESCAN_S, minimize_delay
from carfeel.identification.signals import lowpass
from carfeel.identification.steering_checks import check_units
from carfeel.identification.steering_fit import PARKING_SPEED_M_S
from carfeel.identification.steering_problem import offset_basis
from carfeel.identification.steering_types import (
    Estimate,
    SteeringFit,
    SteeringLog,
    log_figures,
    poorly_pinned,
)
from carfeel.identification.uncertainty import (
    BLOCK_S,
    robust_scale,
    sandwich_finish,
    sandwich_terms,
    soft_l1_cost,
)
from carfeel.models.steering import physical
from carfeel.models.steering.physical import PhysicalInputs, PhysicalParams, PhysicalState
from carfeel.models.vehicle.single_track import STANDARD_GRAVITY_M_S2
from carfeel.simulation.steering import SteeringCar, physical_start

FloatArray = npt.NDArray[np.float64]
DT_S = 1e-3
"""The step the model is simulated at: the 1 kHz loop's (the presets are checked for it)."""
SETTLE_S = 0.5
SEGMENT_S = 1.0
BURN_IN_S = 0.25
"""The pieces' length and their run-in (simulated before the piece, from the state there): most
of a wrong start dies out in it (the rack's modes in 0.1 s, the car's in 0.3 s), so the sweeps
join up sooner."""
FUSION_HZ = 1.0
"""Crossover of the angle's complementary filter (`fused_angle`)."""
GAP_RESTART_S = 1.0
"""A gap in a log longer than this starts the model again (shorter ones are interpolated)."""
MAX_EVALUATIONS = 12
"""Most evaluations (each the point and its neighbours in one batch) of one fit
(`_levenberg_marquardt`); on the acceptance logs it stops by FTOL after 4-6."""
FTOL = 1e-6
"""A step that lowers the robust cost (or that the linearized model says would lower it) by
less than this share of it ends the fit: below it the batch's own join tolerance (SWEEP_TOL_NM)
moves the cost as much."""
XTOL = 1e-4
"""A step that moves the point (in its Jacobian's scale) by less than this share ends it."""
MAX_SWEEPS = 3
SWEEP_TOL_NM = 1e-4
"""How close a piece must start to where the piece before it left off, each state weighted by
about how much torque a unit of it makes (STATE_WEIGHTS, Nm per unit): 1e-4 Nm is 1/500 of the
sensors' noise and a tenth of what a finite-difference step moves the torque by."""
STATE_WEIGHTS = np.array([
    0.0, 0.0,  # rim angle and rate: imposed
    300.0,  # pinion angle: torsion bar, stick spring and stops, Nm/rad
    10.0,  # pinion rate: the EPS damping, and the angle it makes within the rack's 20 ms
    100.0, 100.0,  # column and rack anchors: the stick springs
    300.0,  # park anchor (at the wheels): wind-up 4000 Nm/rad / SR
    300.0, 300.0,  # slips: trail x cornering stiffness / SR
    300.0,  # sideslip: as the slips
    30.0,  # yaw rate: a * r / V of front slip at 25 m/s
    0.0, 0.0, 0.0,  # pose: the torque does not see it
    0.1,  # Ay: through the load transfer
])  # fmt: skip
BATCH_CHECK_NM = 1e-3
FD_STEP = 1e-3
"""Forward-difference step, relative to a parameter's scale."""
MAX_BATCH = 1024
"""Largest batch (sets x pieces) simulated at once: bigger ones run in groups."""
MAX_GROUP_PIECES = 256
"""Most pieces in a group whatever the sets: a group's inputs are 3 x 1250 rows x 8 bytes a
piece, so the one-set run of `_solve`'s grids, 1024 pieces at once, made 30 MB of them (the
largest thing an hour's fit held); 256 pieces of one set run at about half the lane rate."""


@dataclass(frozen=True)
class PhysicalFit(SteeringFit):
    """A `SteeringFit` of the physical model, with what its simulations cost and how closely
    the batch matched the pure model."""

    batch_check_Nm: float = math.nan
    """Largest difference of the batch's residual from the pure model's at the solution."""
    sweeps: int = 0
    """Batches run (each over every piece that had to be simulated again)."""
    simulated_s: float = 0.0
    """Model time simulated in all, over every parameter set (s)."""

    def as_dict(self) -> dict[str, object]:
        return {
            **super().as_dict(),
            "simulation": {"batch_check_Nm": self.batch_check_Nm, "sweeps": self.sweeps,
                           "simulated_s": self.simulated_s},
        }  # fmt: skip


@dataclass(frozen=True)
class Parameter:
    """One fitted parameter: its table and field in the preset, bounds (the preset's ranges),
    and a scale (a typical size, for the finite differences)."""

    name: str
    table: str
    lower: float
    upper: float
    scale: float


PARAMETERS = (
    Parameter("assist_gain_standstill_1_Nm", "steering_system", 0.0, 20.0, 1.0),
    Parameter("assist_gain_high_speed_1_Nm", "steering_system", 0.0, 20.0, 0.1),
    Parameter("column_friction_Nm", "steering_system", 0.0, 10.0, 0.3),
    Parameter("rack_friction_Nm", "steering_system", 0.0, 20.0, 0.5),
    Parameter("eps_damping_high_speed_Nm_s_rad", "steering_system", 0.0, 10.0, 1.0),
    Parameter("pneumatic_trail_m", "tyres", 0.0, 0.1, 0.02),
    Parameter("friction_coefficient", "tyres", 0.05, 2.0, 0.5),
)
NAMES = tuple(p.name for p in PARAMETERS)
MEANINGS = {
    "assist_gain_standstill_1_Nm": "EPS boost gain parked: assist = gain (|torsion-bar torque| - "
    "deadband)^2, 1/Nm",
    "assist_gain_high_speed_1_Nm": "EPS boost gain at speed (the gain falls to it with speed), "
    "1/Nm",
    "column_friction_Nm": "Coulomb friction of the column, felt at the rim, Nm",
    "rack_friction_Nm": "Coulomb friction of the rack, at the pinion, Nm",
    "eps_damping_high_speed_Nm_s_rad": "EPS damping at speed (rises to it with speed), Nm s/rad",
    "pneumatic_trail_m": "the tyres' pneumatic trail at zero slip (collapses as they slide), m",
    "friction_coefficient": "the road's friction coefficient mu (dry about 1.0)",
}
"""What each fitted parameter is, for the report."""

LIMIT_G = 0.6
"""mu is seen only past about this lateral acceleration (the brush's trail collapses there)."""


def value_of(car: SteeringCar, parameter: Parameter) -> float:
    table = car.tyres if parameter.table == "tyres" else car.steering_system
    return float(getattr(table, parameter.name))


def with_values(car: SteeringCar, values: Sequence[float] | FloatArray) -> SteeringCar:
    """The car with PARAMETERS set to `values`."""
    assert car.tyres is not None and car.steering_system is not None
    tyres = {
        p.name: float(v) for p, v in zip(PARAMETERS, values, strict=True) if p.table == "tyres"
    }
    system = {p.name: float(v) for p, v in zip(PARAMETERS, values, strict=True)
              if p.table == "steering_system"}  # fmt: skip
    return dataclasses.replace(
        car,
        tyres=dataclasses.replace(car.tyres, **tyres),
        steering_system=dataclasses.replace(car.steering_system, **system),
    )


@dataclass
class Run:
    """One gap-free stretch of a log on the model's 1 ms grid: grid point 0 is the start state,
    step k goes to grid point k with the inputs there. The inputs on the grid are made for a
    window when asked (`inputs`), not held: at 100 Hz a log has ten grid points a sample."""

    log: int
    samples: slice
    """The log's samples in this stretch."""
    start_s: float
    steps: int
    time_s: FloatArray
    """The stretch's samples: times, speed, fused angle and rate (views of the log's)."""
    speed_samples_m_s: FloatArray
    angle_samples_rad: FloatArray
    rate_samples_rad_s: FloatArray

    @property
    def grid_s(self) -> FloatArray:
        return np.asarray(self.start_s + DT_S * np.arange(self.steps + 1), dtype=np.float64)

    def inputs(self, first: int, stop: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(speed, angle, rate) at grid points first..stop-1: the speed and rate linearly
        interpolated, the angle a cubic Hermite through the samples' angle and rate (linearly
        interpolated, quick steers lost 0.002-0.003 Nm of rms on clean logs). Both are local
        (a point sees the two samples around it), so a window's values are the whole run's."""
        from scipy.interpolate import CubicHermiteSpline

        grid = self.start_s + DT_S * np.arange(first, stop)
        t = self.time_s
        a = max(int(np.searchsorted(t, grid[0], side="right")) - 1, 0)
        b = min(int(np.searchsorted(t, grid[-1], side="left")) + 1, len(t))
        b = max(b, min(a + 2, len(t)))
        seg = slice(a, b)
        hermite = CubicHermiteSpline(t[seg], self.angle_samples_rad[seg],
                                     self.rate_samples_rad_s[seg])  # fmt: skip
        return (
            np.interp(grid, t[seg], self.speed_samples_m_s[seg]),
            np.asarray(hermite(grid)),
            np.interp(grid, t[seg], self.rate_samples_rad_s[seg]),
        )


def fused_angle(log: SteeringLog) -> FloatArray:
    """The rim angle the model is driven with: with a logged rate, its integral above
    FUSION_HZ and the logged angle below (complementary, zero-phase, per gap-free stretch);
    the logged angle as it is otherwise.

    The rim meets the torsion bar and the column's stick spring (about 215 Nm/rad together):
    0.02 deg of angle noise is 0.075 Nm of torque noise and, through the frictions' stick
    elements, a bias. Measured on the acceptance logs with noise on the angle alone: as logged,
    up to 1.7 % (the rack friction); low-passed at 20 Hz, 0.43 %; fused, 0.02 %. The rate's
    integral wanders by about 0.003 deg within a second; the angle's noise above 1 Hz is gone.
    A rate derived from the angle adds nothing, so then the angle is used as logged."""
    if not log.rate_logged:
        return log.angle_rad
    from scipy.interpolate import CubicSpline

    integral = CubicSpline(log.time_s, log.rate_rad_s).antiderivative()(log.time_s)
    return np.asarray(integral + lowpass(log.time_s, log.angle_rad - integral, FUSION_HZ))


def runs_of(logs: Sequence[SteeringLog]) -> list[Run]:
    """Every log cut at gaps longer than GAP_RESTART_S, each stretch on a 1 ms grid."""
    runs = []
    for i, log in enumerate(logs):
        t = log.time_s
        angle = fused_angle(log)
        cuts = np.concatenate([[0], np.flatnonzero(np.diff(t) > GAP_RESTART_S) + 1, [len(t)]])
        for a, b in itertools.pairwise(cuts.tolist()):
            steps = math.floor((t[b - 1] - t[a]) / DT_S + 1e-9)
            if steps < 1:
                continue
            seg = slice(a, b)
            runs.append(Run(
                i, seg, float(t[a]), steps, t[seg], log.speed_m_s[seg], angle[seg],
                log.rate_rad_s[seg],
            ))  # fmt: skip
    return runs


def start_state(params: PhysicalParams, run: Run) -> PhysicalState:
    """Steady cornering of the linear car at the run's first speed and angle, frictions relaxed."""
    return physical_start(params, float(run.speed_samples_m_s[0]), float(run.angle_samples_rad[0]))


@dataclass
class Reference:
    """A sequential run of the pure model over every stretch: the torque at every grid point
    (point 0 repeats point 1; none when it was sampled instead), Ay at the run's samples, the
    torque at the times asked for (`at`), and the states at the points asked for."""

    torque_Nm: list[npt.NDArray[np.floating]]
    lateral_accel_m_s2: list[FloatArray]
    states: dict[tuple[int, int], PhysicalState]
    sampled_Nm: list[FloatArray]


WINDOW_STEPS = 4096
"""Grid points of a run's inputs made at once (`Run.inputs`) by the sequential runs."""


def reference(
    params: PhysicalParams, runs: Sequence[Run], keep: dict[int, set[int]] | None = None,
    *, grid_dtype: type[np.floating] = np.float64, at: Sequence[FloatArray] | None = None,
) -> Reference:  # fmt: skip
    """The pure model (`physical.step`) over each run; the states at grid points keep[run].
    The torque's grid in `grid_dtype` (float32 for a delay scan: half the memory, 3e-7 Nm of
    rounding), or with `at` (sorted times per run, s) the torque interpolated there as the
    windows pass and no grid kept: an hour's grid is 29 MB in float64."""
    torques: list[npt.NDArray[np.floating]] = []
    ays, sampled, states = [], [], {}
    step, inputs = physical.step, PhysicalInputs
    for i, run in enumerate(runs):
        wanted = keep.get(i, set()) if keep else set()
        state = start_state(params, run)
        if 0 in wanted:
            states[(i, 0)] = state
        torque = np.empty(run.steps + 1, grid_dtype) if at is None else None
        times = at[i] if at is not None else None
        here = np.empty(len(times)) if times is not None else None
        ay = np.empty(len(run.time_s))  # at the samples: each window's, through its grid
        before = (math.nan, math.nan)  # the torque and Ay at the grid point before the window
        for first in range(1, run.steps + 1, WINDOW_STEPS):
            stop = min(first + WINDOW_STEPS, run.steps + 1)
            speed, angle, rate = run.inputs(first, stop)
            window_t, window = np.empty(stop - first), np.empty(stop - first)
            rows = zip(speed.tolist(), angle.tolist(), rate.tolist(), strict=True)
            for k, (v, a, w) in enumerate(rows, start=first):
                state, out = step(state, inputs(v, a, w, 0.0, 1.0), params, DT_S)
                window_t[k - first], window[k - first] = out.torque_Nm, out.lateral_accel_m_s2
                if k in wanted:
                    states[(i, k)] = state
            if torque is not None:
                torque[first:stop] = window_t
            grid = run.start_s + DT_S * np.arange(first - 1, stop)
            last = stop > run.steps
            for values, samples, out_at, held in (
                (window, run.time_s, ay, before[1]),
                (window_t, times, here, before[0]),
            ):
                if samples is None or out_at is None:
                    continue
                values = np.concatenate([[values[0] if first == 1 else held], values])
                lo = 0 if first == 1 else int(np.searchsorted(samples, grid[0], side="left"))
                hi = (len(samples) if last
                      else int(np.searchsorted(samples, grid[-1], side="right")))  # fmt: skip
                out_at[lo:hi] = np.interp(samples[lo:hi], grid, values)
            before = (float(window_t[-1]), float(window[-1]))
        if torque is not None:
            torque[0] = torque[min(1, run.steps)]
            torques.append(torque)
        if here is not None:
            sampled.append(here)
        ays.append(ay)
    return Reference(torques, ays, states, sampled)


@dataclass
class Pieces:
    """The runs cut into pieces for `physical_batch`: piece p of run `run[p]` starts at grid
    point `begin[p]` (its run-in) and is scored over grid points (`score[p]`, `end[p]`];
    `before[p]` is the piece before it in its run (-1 for a run's first), whose state after
    row `row[p]` of its own window is where piece p starts."""

    run: list[int]
    begin: list[int]
    score: list[int]
    end: list[int]
    before: list[int]
    row: list[int]
    length: int


def pieces_of(runs: Sequence[Run]) -> Pieces:
    seg, burn = round(SEGMENT_S / DT_S), round(BURN_IN_S / DT_S)
    out = Pieces([], [], [], [], [], [], seg + burn)
    for i, run in enumerate(runs):
        for c in range(0, run.steps, seg):
            begin = max(0, c - burn)
            out.before.append(len(out.run) - 1 if c > 0 else -1)
            out.row.append(begin - out.begin[-1] - 1 if c > 0 else -1)
            out.run.append(i)
            out.begin.append(begin)
            out.score.append(c)
            out.end.append(min(c + seg, run.steps))
    return out


@dataclass
class Predicted:
    """The batch's torque at the scored samples, logged late by the evaluation's delay: the
    point's (N) and each neighbour's difference from it ((J - 1, N), in float32: a difference
    of about 1e-3 Nm keeps 7 digits, and half the memory of the largest thing the fit holds)."""

    point_Nm: FloatArray
    differences_Nm: npt.NDArray[np.float32]

    def torque(self, j: int) -> FloatArray:
        """Set j's torque (0: the point)."""
        if j == 0:
            return self.point_Nm
        return np.asarray(self.point_Nm + self.differences_Nm[j - 1], dtype=np.float64)


class Batch:
    """Every piece of every run, for several parameter sets at once (`physical_batch`), swept
    until the pieces join up: each piece starts from the state the piece before it in its run
    reached there, for the same set, within SWEEP_TOL_NM. Then every set's torque is the pure
    model's run over the whole log, to about that.

    What a sweep keeps of a piece is its torque at the scored samples it covers (at the
    evaluation's delay), written as each group of pieces is simulated: memory in proportion to
    the log's samples and the sets, not to the 1 ms grid (ten points a sample at 100 Hz).

    A sweep's starts are guessed from the last evaluation: its point's states moved to first
    order by the neighbours' (finite-difference) sensitivities, so near the solution one sweep
    suffices; the first guess is a reference run's states."""

    def __init__(self, runs: Sequence[Run], pieces: Pieces, ref: Reference, data: _Data) -> None:
        self.runs, self.pieces, self.data = list(runs), pieces, data
        starts = [ref.states[(i, b)] for i, b in zip(pieces.run, pieces.begin, strict=True)]
        self.point = physical_batch.stack_states(starts)  # (fields, S)
        for name in ("x_m", "y_m", "yaw_rad"):  # the batch leaves the pose out
            self.point[physical_batch.FIELDS.index(name)] = 0.0
        self.x: FloatArray | None = None
        self.sensitivity: dict[int, FloatArray] = {}
        self.sweeps = 0
        self.evaluations = 0
        self.simulated_s = 0.0

    def guess(self, x: FloatArray, neighbours: Sequence[tuple[int, float]]) -> FloatArray:
        """(fields, J, S): starts for the point x and its neighbours (index, step)."""
        out = np.empty((self.point.shape[0], 1 + len(neighbours), self.point.shape[1]))
        point = out[:, 0, :]  # made in place: at an hour of log each (fields, S) is 0.4 MB
        point[...] = self.point
        if self.x is not None:
            for i, sens in self.sensitivity.items():
                point += sens * (x[i] - self.x[i])
        for j, (i, h) in enumerate(neighbours, start=1):
            out[:, j, :] = point
            if i in self.sensitivity:
                out[:, j, :] += self.sensitivity[i] * h
        return out

    def run(
        self, sets: Sequence[PhysicalParams], x: FloatArray,
        neighbours: Sequence[tuple[int, float]], delay_s: float = 0.0,
        max_sweeps: int = MAX_SWEEPS, grids: list[npt.NDArray[np.floating]] | None = None,
    ) -> tuple[Predicted, npt.NDArray[np.float32], float]:  # fmt: skip
        """Every set's torque at the scored samples, logged `delay_s` late; the first
        set's slope there (Nm/s: d torque / d time of the interpolant); and how far (weighted,
        in Nm) a piece's start was off in the last sweep. With `grids`, the first set's torque
        at every grid point is written there too (one array per run, as `Reference`'s)."""
        pieces = self.pieces
        n_pieces = len(pieces.run)
        starts = self.guess(x, neighbours)
        has_before = np.array(pieces.before) >= 0
        before = np.array(pieces.before)[has_before]
        reached = np.zeros_like(starts)
        predicted = Predicted(
            np.empty(len(self.data.time_s)),
            np.empty((len(sets) - 1, len(self.data.time_s)), np.float32),
        )
        slope = np.empty(len(self.data.time_s), np.float32)
        rows = self._rows(delay_s)
        chosen = np.arange(n_pieces)
        change = 0.0
        for _ in range(max_sweeps):
            self._sweep(sets, starts, chosen, reached, rows, delay_s, predicted, slope, grids)
            self.sweeps += 1
            # Each piece starts where the one before it got to, field by field in place (a
            # whole (fields, J, S) copy or difference is 4 MB at an hour of log).
            off = np.zeros(n_pieces)
            for f, weight in enumerate(STATE_WEIGHTS.tolist()):
                joined = reached[f][:, before]
                if weight > 0.0:
                    moved = np.abs(joined - starts[f][:, has_before]).max(axis=0) * weight
                    off[has_before] = np.maximum(off[has_before], moved)
                starts[f][:, has_before] = joined
            change = float(off.max())
            if change <= SWEEP_TOL_NM:
                break
            chosen = np.flatnonzero(off > SWEEP_TOL_NM)  # the rest already start right
        self.evaluations += 1
        self.x = x.copy()
        self.point = starts[:, 0, :]
        for j, (i, h) in enumerate(neighbours, start=1):  # kept from before when none
            self.sensitivity[i] = (starts[:, j, :] - starts[:, 0, :]) / h
        return predicted, slope, change

    def _rows(self, delay_s: float) -> npt.NDArray[np.intp]:
        """(S + 1): piece p scores the data's rows rows[p]:rows[p + 1], the samples whose time
        less the delay falls in its scored span (a run's first and last pieces take the
        samples before and after the run's grid too: the torque is held there)."""
        pieces, data = self.pieces, self.data
        bounds = np.empty(len(pieces.run) + 1, dtype=np.intp)
        p = 0
        for i, (run, times, span) in enumerate(zip(self.runs, data.run_times, data.run_rows,
                                                   strict=True)):  # fmt: skip
            first = p
            while p < len(pieces.run) and pieces.run[p] == i:
                p += 1
            edges = run.start_s + DT_S * np.array(pieces.score[first + 1 : p])
            assert span.start is not None
            bounds[first] = span.start
            bounds[first + 1 : p] = span.start + np.searchsorted(times - delay_s, edges)
            bounds[p] = span.stop
        return bounds

    def _sweep(
        self, sets: Sequence[PhysicalParams], starts: FloatArray, chosen: npt.NDArray[np.intp],
        reached: FloatArray, rows: npt.NDArray[np.intp], delay_s: float, predicted: Predicted,
        slope: npt.NDArray[np.float32], grids: list[npt.NDArray[np.floating]] | None,
    ) -> None:  # fmt: skip
        """One batch over the pieces `chosen`: their torque at their samples into `predicted`
        and `slope`, and where each was at its successor's start row (fields, J, S) into
        `reached`."""
        pieces, runs, data = self.pieces, self.runs, self.data
        n_sets, length = len(sets), pieces.length
        after = {q: p for p, q in enumerate(pieces.before) if q >= 0}  # piece -> its successor
        group = max(1, min(MAX_BATCH // n_sets, MAX_GROUP_PIECES))
        for first in range(0, len(chosen), group):
            some = chosen[first : first + group].tolist()
            speed = np.empty((length, len(some)))
            angle, rate = np.empty_like(speed), np.empty_like(speed)
            for column, p in enumerate(some):
                run = runs[pieces.run[p]]
                begin = pieces.begin[p]
                stop = min(begin + 1 + length, run.steps + 1)
                v, a, w = run.inputs(begin + 1, stop)
                n = stop - begin - 1  # past the run's end a piece holds its last input
                speed[:n, column], speed[n:, column] = v, v[-1]
                angle[:n, column], angle[n:, column] = a, a[-1]
                rate[:n, column], rate[n:, column] = w, w[-1]
            start = starts[:, :, some]
            capture = sorted({pieces.row[after[p]] for p in some if p in after})
            batch = physical_batch.Pieces(speed, angle, rate, start)
            # The torque from the row before the first scored one (interpolation needs it).
            row0 = min(max(pieces.score[p] - pieces.begin[p] - 1, 0) for p in some)
            torque, _, states = physical_batch.simulate(
                sets, batch, DT_S, capture, with_ay=False, first_row=row0
            )
            self.simulated_s += length * DT_S * n_sets * len(some)
            for column, p in enumerate(some):
                if p in after:
                    reached[:, :, p] = states[pieces.row[after[p]]][:, :, column]
                if grids is not None:
                    begin, score, end = pieces.begin[p], pieces.score[p], pieces.end[p]
                    grid = grids[pieces.run[p]]
                    grid[score + 1 : end + 1] = torque[
                        score - begin - row0 : end - begin - row0, 0, column
                    ]
                    if score == 0:
                        grid[0] = grid[min(1, len(grid) - 1)]
                lo, hi = int(rows[p]), int(rows[p + 1])
                if hi <= lo:
                    continue
                run = runs[pieces.run[p]]
                # Row k of the piece is grid point begin + 1 + k.
                position = (data.time_s[lo:hi] - delay_s - run.start_s) / DT_S - pieces.begin[p] - 1
                last = max(pieces.end[p] - pieces.begin[p] - 1, 1)  # the row of grid point end
                k = np.clip(np.floor(position), 0, last - 1).astype(np.intp)
                f = np.clip(position - k, 0.0, 1.0)
                low, high = torque[k - row0, :, column], torque[k + 1 - row0, :, column]
                values = low + f[:, None] * (high - low)  # (samples, sets)
                predicted.point_Nm[lo:hi] = values[:, 0]
                predicted.differences_Nm[:, lo:hi] = (values[:, 1:] - values[:, :1]).T
                inside = (position >= 0.0) & (position <= last)
                slope[lo:hi] = np.where(inside, (high[:, 0] - low[:, 0]) / DT_S, 0.0)
            del torque, states, batch  # before the next group's are made


@dataclass
class _Data:
    """The scored samples of all logs, concatenated."""

    time_s: FloatArray
    torque_Nm: FloatArray
    offsets: FloatArray
    blocks: npt.NDArray[np.intp]
    runs: list[Run]
    run_rows: list[slice]
    """Where each run's scored samples sit in the concatenation."""
    run_times: list[FloatArray]
    log_rows: list[slice]
    """Each log's scored rows (its runs are consecutive)."""

    def predict(self, grids: Sequence[npt.NDArray[np.floating]], delay_s: float) -> FloatArray:
        """(J, N): the model's torque at the scored samples, logged `delay_s` late (the grids
        float64 or float32, one (J, steps + 1) array per run)."""
        n_sets = grids[0].shape[0]
        out = np.empty((n_sets, len(self.time_s)))
        for run, rows, times, grid in zip(self.runs, self.run_rows, self.run_times, grids,
                                          strict=True):  # fmt: skip
            for j in range(n_sets):
                out[j, rows] = on_grid(run.start_s, grid[j], times - delay_s)
        return out


def on_grid(start_s: float, values: npt.NDArray[np.floating], times_s: FloatArray) -> FloatArray:
    """`values` on the 1 ms grid from `start_s`, linearly interpolated at `times_s` and held
    beyond its ends (np.interp's answer to rounding), without making the grid's times: an hour
    of log is 3.6 million grid points, and a float64 array of them per call was the largest
    thing the delay scan made."""
    last = len(values) - 1
    position = (times_s - start_s) / DT_S
    k = np.clip(np.floor(position), 0, max(last - 1, 0)).astype(np.intp)
    f = np.clip(position - k, 0.0, 1.0)
    low = values[k].astype(np.float64)
    high = values[np.minimum(k + 1, last)]
    return np.asarray(low + f * (high - low))


def _data(logs: Sequence[SteeringLog], runs: Sequence[Run], drift_s: float | None) -> _Data:
    times, torques, bases, blocks, run_rows = [], [], [], [], []
    log_rows: list[list[int]] = [[] for _ in logs]  # the first and last row of each log's
    block0, first = 0, 0
    bases_of = [offset_basis(log.time_s, drift_s) for log in logs]
    width = sum(b.shape[1] for b in bases_of)
    starts = np.cumsum([0] + [b.shape[1] for b in bases_of])
    for run in runs:
        log = logs[run.log]
        t = log.time_s[run.samples]
        first_scored = int(np.searchsorted(t, t[0] + SETTLE_S, side="left"))
        scored = slice(run.samples.start + first_scored, run.samples.stop)
        n_scored = run.samples.stop - scored.start
        ts = log.time_s[scored]
        times.append(ts)
        torques.append(log.torque_Nm[scored])
        basis = np.zeros((n_scored, width))
        basis[:, starts[run.log] : starts[run.log + 1]] = bases_of[run.log][scored]
        bases.append(basis)
        block = ((ts - log.time_s[0]) // BLOCK_S).astype(np.intp)
        blocks.append(block + block0)
        block0 += int(block[-1]) + 1 if len(block) else 0
        run_rows.append(slice(first, first + n_scored))
        log_rows[run.log].extend([first, first + n_scored])
        first += n_scored
    if first == 0:
        raise InputError(
            f"the logs are too short: the physical model's fit scores each stretch from "
            f"{SETTLE_S:g} s on (its start is the model's, not the car's)"
        )
    _, dense = np.unique(np.concatenate(blocks), return_inverse=True)
    time_s = np.concatenate(times)
    return _Data(
        time_s, np.concatenate(torques), np.vstack(bases),
        dense.astype(np.intp), list(runs), run_rows, [time_s[rows] for rows in run_rows],
        [slice(r[0], r[-1]) if r else slice(0, 0) for r in log_rows],
    )  # fmt: skip


def excitation(
    logs: Sequence[SteeringLog], simulated_ay: Sequence[FloatArray], base: SteeringCar
) -> dict[int, str]:
    """PARAMETERS the logs cannot identify, by index, with the reason (decided before the fit).

    Thresholds: parking is V < 2 m/s with the wheel turning (> 0.5 rad/s) in 1 % of the
    samples (as for the law's tyre spin); the assist at speed needs 2 % of the samples above
    15 m/s (where its gain is within 15 % of the high-speed one) with the torque 1.5 Nm past
    the deadband (boost = gain * excess^2: 2 Nm^2 per unit of gain at the least); friction needs
    4 reversals of the steering; the damping 1 % of the samples above 10 m/s steered faster
    than 1 rad/s; the trail 5 % at speed with |Ay| > 1 m/s^2; mu 1 % beyond LIMIT_G (measured
    Ay, else the base model's), or parking: the dry-park moment the patches slide at is
    (2/3) mu Fz r_patch, so parked the model sees mu too (kept at the base's while parking is
    fitted, a wrong mu went into the assist gain: +12 % on the command line test's logs)."""
    speed = np.concatenate([log.speed_m_s for log in logs])
    rate = np.concatenate([log.rate_rad_s for log in logs])
    torque = np.concatenate([log.torque_Nm for log in logs])
    ay = np.concatenate([
        log.lateral_accel_m_s2 if log.lateral_accel_m_s2 is not None else sim
        for log, sim in zip(logs, simulated_ay, strict=True)
    ])  # fmt: skip
    assert base.steering_system is not None
    deadband = base.steering_system.assist_deadband_Nm
    reversals = 0
    for log in logs:
        moving = log.rate_rad_s[np.abs(log.rate_rad_s) > 0.05]
        reversals += int(np.count_nonzero(np.diff(np.sign(moving)) != 0))
    kept: dict[int, str] = {}
    parked = (speed < PARKING_SPEED_M_S) & (np.abs(rate) > 0.5)
    index = {name: i for i, name in enumerate(NAMES)}
    if parked.mean() < 0.01:
        kept[index["assist_gain_standstill_1_Nm"]] = (
            "kept from the base preset: the logs have almost no parking manoeuvres (V < 2 m/s "
            "with the wheel turning); add a steer cycle at standstill"
        )
    fast = speed > 15.0
    if np.mean(fast & (np.abs(torque) > deadband + 1.5)) < 0.02:
        kept[index["assist_gain_high_speed_1_Nm"]] = (
            "kept from the base preset: the torque at speed (V > 15 m/s) hardly leaves the "
            "assist's deadband; add a lane change or a steady circle at speed"
        )
    if reversals < 4:
        for name in ("column_friction_Nm", "rack_friction_Nm"):
            kept[index[name]] = (
                "kept from the base preset: the steering reverses fewer than 4 times; add a "
                "weave or a steer cycle"
            )
    if np.mean((speed > 10.0) & (np.abs(rate) > 1.0)) < 0.01:
        kept[index["eps_damping_high_speed_Nm_s_rad"]] = (
            "kept from the base preset: the wheel is hardly turned fast (> 1 rad/s) at speed; "
            "add a step steer or a sine steer at speed"
        )
    if np.mean((speed > 10.0) & (np.abs(ay) > 1.0)) < 0.05:
        kept[index["pneumatic_trail_m"]] = (
            "kept from the base preset: the logs hardly corner at speed (|Ay| > 1 m/s^2 above "
            "10 m/s); add a weave"
        )
    if np.mean(np.abs(ay) > LIMIT_G * STANDARD_GRAVITY_M_S2) < 0.01 and parked.mean() < 0.01:
        kept[index["friction_coefficient"]] = (
            f"kept from the base preset: Ay stays under {LIMIT_G:g} g, where the tyres' grip "
            "is not yet felt, and the logs have no parking (where the patches slide at a moment "
            "proportional to it); add a circle driven to the limit"
        )
    return kept


def fit_physical(
    logs: Sequence[SteeringLog],
    base: SteeringCar,
    *,
    drift_s: float | None = None,
    estimate_delay: bool = True,
    progress: Callable[[int, float], None] | None = None,
) -> PhysicalFit:
    """Fit PARAMETERS (and a torque offset per log and the torque's delay) to the logs; what
    they cannot identify keeps the base's value (status "kept", with the reason)."""
    if not logs:
        raise InputError("no logs given")
    if not base.has_physical:
        raise InputError(
            "the base preset has no [tyres] and [steering_system] tables, so it has no physical "
            "steering model to fit; start from a car that has them (--base b-segment or "
            "d-segment) or fit the paper's law (--steering-model paper)"
        )
    if drift_s is not None and not drift_s > 0:
        raise InputError(f"--drift {drift_s:g}: the knot spacing must be a positive time in s")
    unit_warnings = check_units(logs, base.vehicle)
    runs = runs_of(logs)
    pieces = pieces_of(runs)
    data = _data(logs, runs, drift_s)
    n_par, n_off = len(PARAMETERS), data.offsets.shape[1]
    base_x = np.array([value_of(base, p) for p in PARAMETERS])
    # x: the model's parameters, the torque's delay (s), the offsets' coefficients (Nm).
    lower = np.array([p.lower for p in PARAMETERS] + [-MAX_DELAY_S] + [-5.0] * n_off)
    upper = np.array([p.upper for p in PARAMETERS] + [MAX_DELAY_S] + [5.0] * n_off)
    wanted: dict[int, set[int]] = {}
    for index, begin in zip(pieces.run, pieces.begin, strict=True):
        wanted.setdefault(index, set()).add(begin)
    ref = reference(base.physical(), runs, wanted, grid_dtype=np.float32)
    batch = Batch(runs, pieces, ref, data)
    sim_ay = [np.zeros(len(log.time_s)) for log in logs]
    for run, ay_samples in zip(runs, ref.lateral_accel_m_s2, strict=True):
        sim_ay[run.log][run.samples] = ay_samples
    ref.states.clear()  # the batch has taken its starts
    free = np.ones(n_par + 1 + n_off, dtype=bool)
    free[n_par] = estimate_delay
    notes: dict[int, str] = {}
    for i, why in excitation(logs, sim_ay, base).items():
        free[i], notes[i] = False, why
    x = np.concatenate([base_x, [0.0], np.zeros(n_off)])
    grids = [t[None, :] for t in ref.torque_Nm]
    if estimate_delay:
        # Placed first by a scan on the base model (the cost has a minimum every period of a
        # weave), then fitted with the rest: a CAN delay of tens of ms left out of the first
        # solve pushed its parameters to their bounds.
        x[n_par] = _scan_delay(data, grids, x)
    x[n_par + 1 :] = _offsets(data, grids, float(x[n_par]))
    del ref, grids  # the base model's grid (ten points a sample at 100 Hz) is done with
    mu_index = NAMES.index("friction_coefficient")
    if free[mu_index]:
        x[mu_index] = _mu_start(logs, sim_ay, base_x[mu_index])
    del sim_ay
    counter = [0]
    excited, excited_notes = free.copy(), dict(notes)
    x, free, grids = _solve(data, batch, base, x, free, notes, lower, upper, counter, progress)
    if estimate_delay:
        found = _scan_delay(data, grids, x)
        if abs(found - x[n_par]) > RESCAN_S:  # a better minimum elsewhere: solve from there
            x[n_par] = found
            free, notes = excited, excited_notes  # what stops at a bound, decided afresh
            x[:n_par][~free[:n_par]] = base_x[~free[:n_par]]
            x, free, grids = _solve(data, batch, base, x, free, notes, lower, upper, counter,
                                    progress)  # fmt: skip
    del grids
    delay = float(x[n_par])
    # The figures from the pure model; the covariance from the batch at the same point (the
    # same run to rounding: their largest difference is reported by `batch_check_Nm`).
    final = reference(with_values(base, x[:n_par]).physical(), runs,
                      at=[times - delay for times in data.run_times])  # fmt: skip
    r = np.empty(len(data.time_s))  # the residual; the model is torque + r
    for rows, sampled in zip(data.run_rows, final.sampled_Nm, strict=True):
        r[rows] = sampled
    del final
    r += data.offsets @ x[n_par + 1 :]
    r -= data.torque_Nm
    exact = _evaluate(data, batch, base, x, free, counter, exact=True)
    check = float(np.max(np.abs(exact.r - r)))
    scale = robust_scale(r) or 0.1
    covariance, _ = _covariance(exact, r, np.flatnonzero(free), scale, data.blocks)
    del exact
    sigma_all = np.full(len(x), math.nan)
    sigma_all[free] = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    estimates = tuple(
        Estimate(name, float(x[i]), float(sigma_all[i]), "fitted" if free[i] else "kept",
                 notes.get(i, ""))
        for i, name in enumerate(NAMES)
    )  # fmt: skip
    correlation = uncertainty.correlation(covariance, free, n_par, NAMES)
    warnings = [*unit_warnings, *_identifiability(estimates)]
    if check > BATCH_CHECK_NM:
        warnings.append(
            f"the fit's batch simulation differs from the model by up to {check:.2g} Nm at the "
            "solution (its pieces did not join up): the uncertainties are approximate"
        )
    per_log: dict[str, dict[str, float]] = {}
    offset_values = data.offsets @ x[n_par + 1 :]
    for log, rows in zip(logs, data.log_rows, strict=True):
        per_log[log.name] = log_figures(
            data.torque_Nm[rows], r[rows], offset_values[rows], len(log.time_s)
        )
    rms, r2 = rms_r2(data.torque_Nm, data.torque_Nm + r)
    if not r2 > 0.5:
        warnings.append(
            f"r2 {r2:.3g}: the physical model explains little of the torque; check the logs' "
            "units, signs and columns, and the base car, before using this preset"
        )
    return PhysicalFit(
        with_values(base, x[:n_par]), estimates, float(np.mean(offset_values)), rms, r2, per_log,
        tuple(warnings), counter[0], delay, correlation, batch_check_Nm=check,
        sweeps=batch.sweeps, simulated_s=batch.simulated_s,
    )  # fmt: skip


def _mu_start(
    logs: Sequence[SteeringLog], simulated_ay: Sequence[FloatArray], base_mu: float
) -> float:
    """mu scaled by how far the measured Ay goes beyond LIMIT_G against the base model's on the
    same steering (the measured peak over the simulated one); the base's without measured Ay."""
    measured, simulated = [], []
    for log, sim in zip(logs, simulated_ay, strict=True):
        if log.lateral_accel_m_s2 is not None:
            measured.append(np.abs(log.lateral_accel_m_s2))
            simulated.append(np.abs(sim))
    if not measured:
        return base_mu
    peak = float(np.percentile(np.concatenate(measured), 99.5))
    model = float(np.percentile(np.concatenate(simulated), 99.5))
    if peak < LIMIT_G * STANDARD_GRAVITY_M_S2 or model <= 0.0:
        return base_mu
    return float(np.clip(base_mu * peak / model, 0.3 * base_mu, 2.0 * base_mu))


def _offsets(data: _Data, grids: Sequence[npt.NDArray[np.floating]], delay_s: float) -> FloatArray:
    """The offsets' least-squares values with the model held."""
    model = data.predict(grids, delay_s)[0]
    coefficients = np.linalg.lstsq(data.offsets, data.torque_Nm - model, rcond=None)[0]
    return np.asarray(np.clip(coefficients, -4.9, 4.9))


def _scan_delay(data: _Data, grids: Sequence[npt.NDArray[np.floating]], x: FloatArray) -> float:
    """The torque's delay (s) that fits best with the model held (its simulated torque shifted):
    a grid over +-MAX_DELAY_S, then a bounded search around the best point; the soft_l1 cost
    with each trial's offsets refitted."""
    point = [g[:1] for g in grids]
    n_par = len(PARAMETERS)
    r0 = data.predict(point, float(x[n_par]))[0] + data.offsets @ x[n_par + 1 :] - data.torque_Nm
    scale = robust_scale(r0) or 0.1

    def cost(delay: float) -> float:
        rest = data.torque_Nm - data.predict(point, delay)[0]
        offsets = np.linalg.lstsq(data.offsets, rest, rcond=None)[0]
        z = ((rest - data.offsets @ offsets) / scale) ** 2
        return float(np.mean(np.sqrt(1.0 + z)))

    return minimize_delay(cost)


@dataclass
class _Evaluation:
    """One batch evaluation at x: the residual (model + offsets - measured, N) and what makes
    the Jacobian's rows a chunk at a time (`rows`): the whole Jacobian is never held (at an
    hour of 100 Hz log it is 30 MB, and a dense solver copies it several times)."""

    x: FloatArray
    r: FloatArray
    differences_Nm: npt.NDArray[np.float32]
    """(J - 1, N): each neighbour's torque less the point's (`Predicted`)."""
    slope: npt.NDArray[np.float32]
    neighbours: list[tuple[int, float]]
    offsets: FloatArray

    def rows(self, lo: int, hi: int, idx: npt.NDArray[np.intp]) -> FloatArray:
        """d residual / d x[idx] at rows lo:hi: forward differences for the model's
        parameters, the simulated torque's slope for the delay (the model's torque at
        t - delay), the offsets' basis for theirs."""
        n_par = len(PARAMETERS)
        jac = np.zeros((hi - lo, len(self.x)))
        for j, (i, h) in enumerate(self.neighbours):
            jac[:, i] = self.differences_Nm[j, lo:hi] / h
        jac[:, n_par] = -self.slope[lo:hi]
        jac[:, n_par + 1 :] = self.offsets[lo:hi]
        return jac[:, idx]


CHUNK_ROWS = 16384
"""Rows of the Jacobian made at once (about 1.5 MB)."""


def _evaluate(
    data: _Data, batch: Batch, base: SteeringCar, x: FloatArray, free: npt.NDArray[np.bool_],
    counter: list[int], exact: bool = False,
) -> _Evaluation:  # fmt: skip
    """The residual at x and its Jacobian's makings (`_Evaluation`), in one batch: the point
    and a forward-difference neighbour for each free model parameter (the neighbours cost
    little more than the point: numpy's overhead is per step, not per element)."""
    n_par = len(PARAMETERS)
    sets = [with_values(base, x[:n_par]).physical()]
    neighbours = []
    for i in np.flatnonzero(free[:n_par]).tolist():
        p = PARAMETERS[i]
        h = FD_STEP * max(abs(float(x[i])), p.scale)
        if x[i] + h > p.upper:
            h = -h
        trial = x[:n_par].copy()
        trial[i] += h
        sets.append(with_values(base, trial).physical())
        neighbours.append((i, h))
    counter[0] += len(sets)
    sweeps = max(len(batch.pieces.run), MAX_SWEEPS) if exact else MAX_SWEEPS
    predicted, slope, _ = batch.run(sets, x, neighbours, float(x[n_par]), max_sweeps=sweeps)
    r = predicted.point_Nm  # the residual in its place: the point's torque is not kept
    r += data.offsets @ x[n_par + 1 :]
    r -= data.torque_Nm
    return _Evaluation(x.copy(), r, predicted.differences_Nm, slope, neighbours, data.offsets)


def _normal_equations(
    ev: _Evaluation, idx: npt.NDArray[np.intp], scale: float
) -> tuple[FloatArray, FloatArray]:
    """(A, g): soft_l1's Gauss-Newton matrix sum w J J^T and gradient sum w r J over the free
    entries idx, w = 1 / sqrt(1 + (r / scale)^2) (its IRLS weight), summed a chunk at a time."""
    a, g = np.zeros((len(idx), len(idx))), np.zeros(len(idx))
    for lo in range(0, len(ev.r), CHUNK_ROWS):
        hi = min(lo + CHUNK_ROWS, len(ev.r))
        jac, r = ev.rows(lo, hi, idx), ev.r[lo:hi]
        weight = 1.0 / np.sqrt(1.0 + (r / scale) ** 2)
        a += jac.T @ (jac * weight[:, None])
        g += jac.T @ (weight * r)
    return a, g


def _covariance(
    ev: _Evaluation, r: FloatArray, idx: npt.NDArray[np.intp], scale: float,
    blocks: npt.NDArray[np.intp],
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:  # fmt: skip
    """`uncertainty.sandwich` of the residual r with ev's Jacobian over idx, a chunk of rows
    at a time (the column norms in a first pass)."""
    squares = np.zeros(len(idx))
    for lo in range(0, len(r), CHUNK_ROWS):
        squares += np.sum(ev.rows(lo, min(lo + CHUNK_ROWS, len(r)), idx) ** 2, axis=0)
    norms = np.sqrt(squares)
    norms[norms == 0.0] = 1.0
    n_blocks = int(blocks.max()) + 1
    a, g = np.zeros((len(idx), len(idx))), np.zeros((n_blocks, len(idx)))
    for lo in range(0, len(r), CHUNK_ROWS):
        hi = min(lo + CHUNK_ROWS, len(r))
        part_a, part_g = sandwich_terms(ev.rows(lo, hi, idx) / norms, r[lo:hi], scale,
                                        blocks[lo:hi], n_blocks)  # fmt: skip
        a += part_a
        g += part_g
    covariance, _, unconstrained = sandwich_finish(a, g, norms)
    return covariance, unconstrained


@dataclass
class _Point:
    """What the solver keeps of an evaluation it accepted: the residual, soft_l1's normal
    equations at the solver's scale, and the covariance at the residual's own scale. The
    Jacobian's makings (40 bytes a sample) are let go, so that the next trial is the only
    evaluation held: two of them were the largest thing an hour's fit held."""

    x: FloatArray
    r: FloatArray
    cost: float
    a: FloatArray
    g: FloatArray
    covariance: FloatArray
    unconstrained: npt.NDArray[np.bool_]


def _settle(
    ev: _Evaluation, idx: npt.NDArray[np.intp], scale: float, blocks: npt.NDArray[np.intp]
) -> _Point:
    """`_Point` of ev: three passes over its Jacobian's chunks (a batch evaluation costs
    hundreds of such passes)."""
    a, g = _normal_equations(ev, idx, scale)
    covariance, unconstrained = _covariance(ev, ev.r, idx, robust_scale(ev.r) or scale, blocks)
    return _Point(ev.x, ev.r, soft_l1_cost(ev.r, scale), a, g, covariance, unconstrained)


@dataclass
class _Solution:
    x: FloatArray
    active: npt.NDArray[np.int_]
    """Per free entry: -1 held at its lower bound, +1 at its upper, 0 inside."""
    point: _Point


def _levenberg_marquardt(
    evaluate: Callable[[FloatArray], _Evaluation], x0: FloatArray, idx: npt.NDArray[np.intp],
    lower: FloatArray, upper: FloatArray, scale: float, first: _Point,
    settle: Callable[[_Evaluation], _Point],
) -> _Solution:  # fmt: skip
    """A bounded Levenberg-Marquardt on soft_l1 (IRLS Gauss-Newton steps, damped in the
    Jacobian's own column scale as scipy's x_scale="jac"; an entry at a bound whose gradient
    points out is held there), from the settled evaluation `first` at x0. Stops when a step
    lowers the cost by under FTOL of it, moves the scaled point by under XTOL of its size, or
    after MAX_EVALUATIONS evaluations. Every evaluation runs the batch once, so their number is
    the fit's cost: it does not grow with the log's length."""
    lo, hi = lower[idx], upper[idx]
    point, x = first, x0.copy()
    cost = point.cost
    damping = 1e-3
    evaluations = 1
    while evaluations < MAX_EVALUATIONS:
        a, g = point.a, point.g
        z = x[idx]
        d = np.sqrt(np.diag(a))
        d[d == 0.0] = 1.0
        inner = _held(z, g, lo, hi) == 0
        if not inner.any():
            break
        scaled = a[np.ix_(inner, inner)] / np.outer(d[inner], d[inner])
        moved = False
        while evaluations < MAX_EVALUATIONS:
            system = scaled + damping * np.eye(len(scaled))
            step = np.zeros(len(idx))
            step[inner] = -np.linalg.solve(system, g[inner] / d[inner]) / d[inner]
            trial = x.copy()
            trial[idx] = np.clip(z + step, lo, hi)
            taken = trial[idx] - z
            expected = -float(g @ taken) - 0.5 * float(taken @ a @ taken)
            if expected <= FTOL * cost:  # the linear model promises less than the tolerance
                return _Solution(x, _held(z, g, lo, hi), point)
            candidate = evaluate(trial)
            evaluations += 1
            new_cost = soft_l1_cost(candidate.r, scale)
            if new_cost < cost:
                gain = cost - new_cost
                moved_by = float(np.linalg.norm((trial[idx] - z) * d))
                point = settle(candidate)
                del candidate
                x, cost = trial, new_cost
                damping = max(damping / 3.0, 1e-9)
                moved = True
                if gain <= FTOL * cost or moved_by <= XTOL * (XTOL + float(np.linalg.norm(z * d))):
                    return _Solution(x, _held(x[idx], point.g, lo, hi), point)
                break
            del candidate
            damping *= 10.0
            if damping > 1e8:
                break
        if not moved:
            break
    return _Solution(x, _held(x[idx], point.g, lo, hi), point)


def _held(
    z: FloatArray, gradient: FloatArray, lower: FloatArray, upper: FloatArray
) -> npt.NDArray[np.int_]:
    """-1 where z is at its lower bound and descent would take it lower, +1 at the upper bound
    likewise, 0 elsewhere."""
    span = 1e-12 * (upper - lower)
    low = (z <= lower + span) & (gradient > 0)
    high = (z >= upper - span) & (gradient < 0)
    return np.where(low, -1, np.where(high, 1, 0)).astype(np.int_)


def _solve(
    data: _Data, batch: Batch, base: SteeringCar, x0: FloatArray,
    free0: npt.NDArray[np.bool_], notes: dict[int, str], lower: FloatArray, upper: FloatArray,
    counter: list[int], progress: Callable[[int, float], None] | None,
) -> tuple[FloatArray, npt.NDArray[np.bool_], list[npt.NDArray[np.floating]]]:  # fmt: skip
    """A bounded fit of the free entries (`_levenberg_marquardt`); what stops at a bound or in
    an unconstrained direction is kept from the base and the rest fitted again (at most
    twice). Returns x, the free mask and the model's grids at x."""
    n_par = len(PARAMETERS)
    base_x = np.array([value_of(base, p) for p in PARAMETERS])
    x_all, free = x0.copy(), free0.copy()
    for attempt in range(3):
        idx = np.flatnonzero(free)
        held = free.copy()

        def evaluate(x: FloatArray, held: npt.NDArray[np.bool_] = held) -> _Evaluation:
            ev = _evaluate(data, batch, base, x, held, counter)
            if progress is not None:
                progress(counter[0], float(np.sqrt(np.mean(ev.r * ev.r))))
            return ev

        x_all[idx] = np.clip(x_all[idx], lower[idx] + 1e-9, upper[idx] - 1e-9)
        first = evaluate(x_all)
        scale = robust_scale(first.r) or 0.1

        def settle(ev: _Evaluation, idx: npt.NDArray[np.intp] = idx, scale: float = scale
                   ) -> _Point:  # fmt: skip
            return _settle(ev, idx, scale, data.blocks)

        point = settle(first)
        del first
        solution = _levenberg_marquardt(evaluate, x_all, idx, lower, upper, scale, point, settle)
        del point
        x_all = solution.x
        covariance, unconstrained = solution.point.covariance, solution.point.unconstrained
        stuck: dict[int, str] = {}
        for j, i in enumerate(idx.tolist()):
            if i >= n_par:
                continue
            if solution.active[j] != 0:
                bound = lower[i] if solution.active[j] < 0 else upper[i]
                stuck[i] = (f"kept from the base preset: the fit stopped at the bound {bound:g}, "
                            "the logs cannot place it")  # fmt: skip
            elif unconstrained[j]:
                stuck[i] = "kept from the base preset: the logs do not constrain it"
            else:  # within one sigma of a bound the logs cannot tell the value from the bound
                sigma = math.sqrt(max(float(covariance[j, j]), 0.0))
                value = float(x_all[i])
                near = lower[i] if value - lower[i] <= upper[i] - value else upper[i]
                if math.isfinite(near) and abs(value - near) < sigma:
                    stuck[i] = (
                        f"kept from the base preset: the fit ({value:.3g} +- {sigma:.2g}) lies "
                        f"within one sigma of its bound {near:g}, the logs cannot place it"
                    )
        del solution
        if not stuck or attempt == 2:
            break
        for i, why in stuck.items():
            free[i], notes[i] = False, why
            x_all[i] = base_x[i]
    grids = [np.empty(run.steps + 1, np.float32) for run in batch.runs]  # for the delay scan
    batch.run([with_values(base, x_all[:n_par]).physical()], x_all, [], grids=grids)
    return x_all, free, [grid[None, :] for grid in grids]


def _identifiability(estimates: Sequence[Estimate]) -> list[str]:
    warnings = []
    for reason in dict.fromkeys(e.note for e in estimates if e.status == "kept"):
        kept = [e.name for e in estimates if e.note == reason]
        warnings.append(f"{', '.join(kept)} not identifiable, {reason}")
    return warnings + poorly_pinned(estimates)


def simulate_log(
    car: SteeringCar, log: SteeringLog, delay_s: float = 0.0
) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """(Ay, torque, scored) of the physical model (the pure step) driven by a log's angle, rate
    and speed, at the log's samples (the torque shifted by `delay_s`); `scored` is False in
    each stretch's first SETTLE_S."""
    params = car.physical()
    runs = runs_of([log])
    ref = reference(params, runs)
    ay = np.zeros(len(log.time_s))
    torque = np.zeros(len(log.time_s))
    scored = np.zeros(len(log.time_s), dtype=bool)
    for run, t_grid, ay_samples in zip(runs, ref.torque_Nm, ref.lateral_accel_m_s2,
                                       strict=True):  # fmt: skip
        t = log.time_s[run.samples]
        torque[run.samples] = np.interp(t - delay_s, run.grid_s, t_grid)
        ay[run.samples] = ay_samples
        scored[run.samples] = t >= t[0] + SETTLE_S
    return ay, torque, scored
