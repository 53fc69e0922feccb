"""The batch simulation of the physical fit (`physical_fit`): every run cut into pieces
(`pieces_of`) and all of them, for the trial point and its finite-difference neighbours at once,
simulated by `physical_batch` and swept until the pieces join up (`Batch`); what it gives is
each parameter set's torque at the scored samples (`Predicted`), its slope there, and on request
the point's torque on the whole 1 ms grid."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.identification import physical_batch
from carfeel.identification.physical_runs import DT_S, Reference, Run, _Data
from carfeel.models.steering.physical import PhysicalParams

FloatArray = npt.NDArray[np.float64]
SEGMENT_S = 1.0
BURN_IN_S = 0.25
"""The pieces' length and their run-in (simulated before the piece, from the state there): most
of a wrong start dies out in it (the rack's modes in 0.1 s, the car's in 0.3 s), so the sweeps
join up sooner."""
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
MAX_BATCH = 1024
"""Largest batch (sets x pieces) simulated at once: bigger ones run in groups."""
MAX_GROUP_PIECES = 256
"""Most pieces in a group whatever the sets: a group's inputs are 3 x 1250 rows x 8 bytes a
piece, so the one-set run of `_solve`'s grids, 1024 pieces at once, made 30 MB of them (the
largest thing an hour's fit held); 256 pieces of one set run at about half the lane rate."""


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
