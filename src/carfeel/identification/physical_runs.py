"""The logs as the physical fit (`physical_fit`) drives and scores the model with them: each log
cut at its gaps into gap-free runs on the model's 1 ms grid (`Run`, `runs_of`, the rim angle
fused with a logged rate), the pure model's sequential run over them (`reference`), and the
scored samples of all logs concatenated (`_Data`: the torque, the offsets' basis, the blocks of
the sandwich covariance)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification.signals import lowpass
from carfeel.identification.steering_problem import offset_basis
from carfeel.identification.steering_types import SteeringLog
from carfeel.identification.uncertainty import BLOCK_S
from carfeel.models.steering import physical
from carfeel.models.steering.physical import PhysicalInputs, PhysicalParams, PhysicalState
from carfeel.simulation.steering import physical_start

FloatArray = npt.NDArray[np.float64]
DT_S = 1e-3
"""The step the model is simulated at: the 1 kHz loop's (the presets are checked for it)."""
SETTLE_S = 0.5
"""Each run's first seconds, simulated but not scored: the model starts in the linear car's
steady state with its frictions relaxed, which the real car's were not."""
FUSION_HZ = 1.0
"""Crossover of the angle's complementary filter (`fused_angle`)."""
GAP_RESTART_S = 1.0
"""A gap in a log longer than this starts the model again (shorter ones are interpolated)."""


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
