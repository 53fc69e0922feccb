"""The physical fit's solver (`physical_fit`): the batch evaluation of the residual and its
Jacobian's makings (`_evaluate`), the offsets and the delay with the model held, the bounded
Levenberg-Marquardt on soft_l1 (`_levenberg_marquardt`), the covariance a chunk of rows at a
time, and the fit that keeps from the base what stops at a bound (`_solve`)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.identification.delay import minimize_delay
from carfeel.identification.physical_predict import MAX_SWEEPS, Batch
from carfeel.identification.physical_runs import _Data
from carfeel.identification.physical_types import PARAMETERS, value_of, with_values
from carfeel.identification.uncertainty import (
    robust_scale,
    sandwich_finish,
    sandwich_terms,
    soft_l1_cost,
)
from carfeel.simulation.steering import SteeringCar

FloatArray = npt.NDArray[np.float64]
MAX_EVALUATIONS = 12
"""Most evaluations (each the point and its neighbours in one batch) of one fit
(`_levenberg_marquardt`); on the acceptance logs it stops by FTOL after 4-6."""
FTOL = 1e-6
"""A step that lowers the robust cost (or that the linearized model says would lower it) by
less than this share of it ends the fit: below it the batch's own join tolerance (SWEEP_TOL_NM)
moves the cost as much."""
XTOL = 1e-4
"""A step that moves the point (in its Jacobian's scale) by less than this share ends it."""
FD_STEP = 1e-3
"""Forward-difference step, relative to a parameter's scale."""


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


def covariance_at(
    data: _Data, batch: Batch, base: SteeringCar, x: FloatArray, free: npt.NDArray[np.bool_],
    r: FloatArray, counter: list[int],
) -> tuple[FloatArray, float]:  # fmt: skip
    """The covariance of the free entries of the solution x with the pure model's residual r
    (Nm; the batch's Jacobian at x, its pieces swept until they join up), and the largest
    difference of the batch's residual from r (Nm)."""
    exact = _evaluate(data, batch, base, x, free, counter, exact=True)
    check = float(np.max(np.abs(exact.r - r)))
    scale = robust_scale(r) or 0.1
    covariance, _ = _covariance(exact, r, np.flatnonzero(free), scale, data.blocks)
    del exact
    return covariance, check
