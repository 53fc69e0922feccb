"""Black boxes beside the physics (issue 25): what a model of the steering torque must beat on
the same split of the same logs before an engineer should trust it.

    linear         torque = a angle + b rate + c (the three-term fit a reviewer put beside the
                   law on a real car: 0.16 / 0.07 / 0.20 out of sample against the law's
                   0.20 / -0.11 / 0.18)
    lagged ridge   ridge regression on the angle, the rate and Ay (measured, else the base
                   car's transient model) at lags of 0 to 0.8 s: the history a physical model
                   carries in its states (friction, EPS dynamics), as a black box gets it

Both have one intercept per log (as the law has one torque offset per log) fitted on the training
part of that log and used unchanged on its held-out part. The ridge's penalty is chosen by
contiguous 5-fold cross-validation in time on the training data (a sample's neighbours share its
noise: leaving single samples out would choose almost no penalty); the features are standardized
on the training data. Plain numpy: the solve is a few tens of columns.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.identification import rms_r2

FloatArray = npt.NDArray[np.float64]

LAGS_S = (0.0, 0.05, 0.1, 0.2, 0.4, 0.8)
"""The lagged ridge's lags (s): the fast EPS and tyre dynamics to the slow friction history."""
PENALTIES = tuple(10.0**k for k in range(-6, 3))
"""The ridge penalties tried, relative to the samples' count (standardized features)."""
FOLDS = 5
NAMES = ("linear", "lagged ridge")


@dataclass(frozen=True)
class Inputs:
    """One log as the baselines see it: time (s), angle (rad), rate (rad/s), Ay (m/s^2) and
    the torque (Nm), and which log it is (its own intercept)."""

    name: str
    time_s: FloatArray
    angle_rad: FloatArray
    rate_rad_s: FloatArray
    ay_m_s2: FloatArray
    torque_Nm: FloatArray


@dataclass(frozen=True)
class Model:
    """A fitted baseline: its features' means and scales, weights, and an intercept per log."""

    kind: str
    mean: FloatArray
    scale: FloatArray
    weights: FloatArray
    intercepts: dict[str, float]
    penalty: float


def _lagged(time_s: FloatArray, values: FloatArray, lag_s: float) -> FloatArray:
    """values(t - lag), held at the first sample before the log starts."""
    if lag_s == 0.0:
        return values
    return np.asarray(np.interp(time_s - lag_s, time_s, values))


def features(kind: str, log: Inputs) -> FloatArray:
    """The baseline's regressors of one log (columns), without the intercept."""
    if kind == "linear":
        return np.column_stack([log.angle_rad, log.rate_rad_s])
    columns = [
        _lagged(log.time_s, signal, lag)
        for lag in LAGS_S
        for signal in (log.angle_rad, log.rate_rad_s, log.ay_m_s2)
    ]
    return np.column_stack(columns)


def _solve(x: FloatArray, y: FloatArray, dummies: FloatArray, penalty: float) -> FloatArray:
    """Ridge weights of [x, dummies] (the dummies, intercepts, unpenalized)."""
    design = np.hstack([x, dummies])
    n = len(y)
    ridge = np.zeros(design.shape[1])
    ridge[: x.shape[1]] = penalty * n
    return np.asarray(np.linalg.solve(design.T @ design + np.diag(ridge), design.T @ y))


def fit(kind: str, logs: Sequence[Inputs]) -> Model:
    """The baseline fitted to the logs (the ridge's penalty by contiguous cross-validation)."""
    blocks = [features(kind, log) for log in logs]
    x = np.vstack(blocks)
    y = np.concatenate([log.torque_Nm for log in logs])
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale[scale == 0.0] = 1.0
    xs = (x - mean) / scale
    which = np.concatenate([np.full(len(b), i) for i, b in enumerate(blocks)])
    dummies = np.eye(len(logs))[which]
    penalty = 0.0
    if kind != "linear":
        penalty = _choose_penalty(xs, y, dummies, which)
    weights = _solve(xs, y, dummies, penalty)
    n_x = xs.shape[1]
    intercepts = {log.name: float(weights[n_x + i]) for i, log in enumerate(logs)}
    return Model(kind, mean, scale, weights[:n_x], intercepts, penalty)


def _choose_penalty(
    xs: FloatArray, y: FloatArray, dummies: FloatArray, which: npt.NDArray[np.int_]
) -> float:
    """The penalty of least held-out error over FOLDS contiguous folds of each log."""
    fold = np.zeros(len(y), dtype=int)
    for i in np.unique(which):
        rows = np.flatnonzero(which == i)
        fold[rows] = np.minimum(np.arange(len(rows)) * FOLDS // max(len(rows), 1), FOLDS - 1)
    best, best_error = PENALTIES[0], math.inf
    for penalty in PENALTIES:
        error = 0.0
        for k in range(FOLDS):
            test = fold == k
            if test.all() or not test.any():
                continue
            w = _solve(xs[~test], y[~test], dummies[~test], penalty)
            predicted = np.hstack([xs[test], dummies[test]]) @ w
            error += float(np.sum((y[test] - predicted) ** 2))
        if error < best_error:
            best, best_error = penalty, error
    return best


def predict(model: Model, log: Inputs) -> FloatArray:
    """The baseline's torque for a log: its own intercept if the model was trained on a part of
    it, else the mean of the intercepts."""
    x = (features(model.kind, log) - model.mean) / model.scale
    intercept = model.intercepts.get(log.name)
    if intercept is None:
        intercept = float(np.mean(list(model.intercepts.values())))
    return np.asarray(x @ model.weights + intercept)


def compare(
    train: Sequence[Inputs], test: Sequence[Inputs]
) -> dict[str, dict[str, dict[str, float]]]:
    """Each baseline fitted on `train`, scored on `test` (logs matched by name: their intercepts
    carry over): {baseline: {log name or "all": {"rms_error_Nm", "r2"}}}."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for kind in NAMES:
        model = fit(kind, train)
        figures: dict[str, dict[str, float]] = {}
        measured, predicted = [], []
        for log in test:
            guess = predict(model, log)
            rms, r2 = rms_r2(log.torque_Nm, guess)
            figures[log.name] = {"rms_error_Nm": rms, "r2": r2}
            measured.append(log.torque_Nm)
            predicted.append(guess)
        rms, r2 = rms_r2(np.concatenate(measured), np.concatenate(predicted))
        figures["all"] = {"rms_error_Nm": rms, "r2": r2, "penalty": model.penalty}
        out[kind] = figures
    return out
