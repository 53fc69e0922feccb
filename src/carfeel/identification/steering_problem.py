"""The law's fit as a least-squares problem: the logs concatenated (`_data`) with their
regressors shiftable by a delay (cubic convolution or splines), the torque offsets' basis, and
the parameter vector x = [law, (K_us), delay, offsets, Ay biases] with its model, residual and
Jacobian (`_Problem`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.identification.signals import stretches
from carfeel.identification.steering_law import LawModel, Regressors
from carfeel.identification.steering_types import SteeringLog
from carfeel.identification.uncertainty import BLOCK_S

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
MIN_BLOCK_S = 0.5
BLOCKS_PER_PARAMETER = 4
"""Short logs get shorter blocks (to MIN_BLOCK_S) so that they hold this many per parameter
(`block_length`)."""
DELAY_STEP_S = 2e-4
"""Half-step of the delay's central difference (the splines are smooth far below a sample)."""
SATURATION_AY_M_S2 = 3.0
"""The law's saturation K2, K3 (and the Ay sensor's bias with it) is seen only in logs whose Ay
goes beyond this (99th percentile)."""


def offset_basis(time_s: FloatArray, drift_s: float | None) -> FloatArray:
    """Columns of a log's torque offset: one constant, or with `drift_s` hat functions on knots
    about `drift_s` apart (a piecewise-linear offset through the log)."""
    span = float(time_s[-1] - time_s[0])
    if drift_s is None or span < 1.5 * drift_s:
        return np.ones((len(time_s), 1))
    knots = np.linspace(time_s[0], time_s[-1], math.ceil(span / drift_s) + 1)
    return np.column_stack(
        [np.interp(time_s, knots, np.eye(len(knots))[k]) for k in range(len(knots))]
    )


@dataclass
class _Data:
    """The logs concatenated (`parts` of them), with each log's regressors as cubic splines of
    its own time for shifting them by a delay."""

    tau: FloatArray
    speed: FloatArray
    rate: FloatArray
    ay: FloatArray
    torque: FloatArray
    offsets: FloatArray
    parts: list[slice]
    blocks: npt.NDArray[np.intp]
    local: list[FloatArray]
    """Each log's own time from its first sample, s."""
    steps: FloatArray
    """Each sample's step from the one before (0 where a stretch starts)."""
    starts: BoolArray
    rate_error: FloatArray
    """Each sample's rate error (one sigma, rad/s; 0 where not known)."""
    ay_bias: FloatArray
    """The measured Ay's bias, a nuisance: one column over the logs with a measured Ay (none
    when they do not reach the law's saturation, SATURATION_AY_M_S2)."""
    _splines_by: dict[tuple[int, int], Any] = dataclasses.field(default_factory=dict)
    _cache: dict[float, Regressors] = dataclasses.field(default_factory=dict)

    def regressors(self, delay_s: float = 0.0) -> Regressors:
        """The regressors at t - delay_s (held at each log's first sample before it): cubic
        convolution (Catmull-Rom: C1 in the delay) on uniformly sampled logs, cubic splines on
        the others."""
        found = self._cache.get(delay_s)
        if found is not None:
            return found
        if delay_s == 0.0:
            speed, rate, ay = self.speed, self.rate, self.ay
        else:
            speed, rate, ay = (np.empty_like(self.speed) for _ in range(3))
            for k, (t, part) in enumerate(zip(self.local, self.parts, strict=True)):
                for c, (out, values) in enumerate(zip((speed, rate, ay),
                                                      (self.speed, self.rate, self.ay),
                                                      strict=True)):  # fmt: skip
                    out[part] = self._shifted((k, c), t, values[part], delay_s)
        found = Regressors(speed, rate, ay, np.abs(rate) * self.steps, self.starts)
        if len(self._cache) > 4:
            self._cache.clear()
        self._cache[delay_s] = found
        return found

    def _shifted(
        self, key: tuple[int, int], t: FloatArray, values: FloatArray, delay_s: float
    ) -> FloatArray:
        """One log's (key: log, signal) values at t - delay_s."""
        dt = (t[-1] - t[0]) / max(len(t) - 1, 1)
        if len(t) > 3 and np.allclose(np.diff(t), dt, rtol=1e-6, atol=1e-9):
            return cubic_shift(values, delay_s / dt)
        from scipy.interpolate import CubicSpline

        # By log and signal, never by id(values): `values` is a fresh slice whose id a later
        # slice of another signal reuses (a gap's log was fitted with its speed's spline as Ay).
        spline = self._splines_by.get(key)
        if spline is None:
            spline = self._splines_by[key] = CubicSpline(t, values)
        return np.asarray(spline(np.clip(t - delay_s, 0.0, t[-1])))


def cubic_shift(values: FloatArray, samples: float) -> FloatArray:
    """values(k - samples) by Catmull-Rom cubic convolution (the samples held beyond the ends):
    exact for cubics' samples, continuous with a continuous derivative in `samples`."""
    n = len(values)
    whole = math.floor(samples)
    u = 1.0 - (samples - whole) if samples != whole else 0.0
    base = np.arange(n) - whole - (1 if u > 0.0 else 0)
    taps = [values[np.clip(base + j, 0, n - 1)] for j in (-1, 0, 1, 2)]
    u2, u3 = u * u, u * u * u
    weights = (0.5 * (-u + 2.0 * u2 - u3), 0.5 * (2.0 - 5.0 * u2 + 3.0 * u3),
               0.5 * (u + 4.0 * u2 - 3.0 * u3), 0.5 * (-u2 + u3))  # fmt: skip
    return np.asarray(sum(w * tap for w, tap in zip(weights, taps, strict=True)))


def law_inputs(log: SteeringLog, ay: FloatArray, delay_s: float = 0.0) -> Regressors:
    """One log's regressors as the fit evaluates the law on them, shifted by `delay_s`."""
    return _data([log], [ay], None).regressors(delay_s)


def block_length(logs: Sequence[SteeringLog], parameters: int) -> float:
    """The sandwich's block (s): BLOCK_S, shorter (to MIN_BLOCK_S) where the logs hold fewer than
    BLOCKS_PER_PARAMETER blocks for each parameter: with about as many blocks as parameters the
    meat is nearly singular and its small-sample factor n_b / (n_b - p) runs away (15 on half a
    minute of a highway drive), and the keep rule's test then keeps anything."""
    span = sum(float(log.time_s[-1] - log.time_s[0]) for log in logs)
    wanted = span / (BLOCKS_PER_PARAMETER * max(parameters, 1))
    return float(min(BLOCK_S, max(MIN_BLOCK_S, wanted)))


def _data(
    logs: Sequence[SteeringLog], ays: Sequence[FloatArray], drift_s: float | None,
    block_s: float = BLOCK_S,
) -> _Data:  # fmt: skip
    taus, parts, bases, blocks, local, steps, starts = [], [], [], [], [], [], []
    start, first, block0 = 0.0, 0, 0
    for log in logs:
        t = log.time_s - log.time_s[0]
        local.append(t)
        taus.append(t + start)
        start += float(t[-1]) + 1e3
        parts.append(slice(first, first + len(t)))
        first += len(t)
        bases.append(offset_basis(log.time_s, drift_s))
        block = (t // block_s).astype(np.intp)
        blocks.append(block + block0)
        block0 += int(block[-1]) + 1
        step = np.diff(t, prepend=t[0])
        begins = np.zeros(len(t), dtype=bool)
        for a, _ in stretches(log.time_s):
            begins[a] = True
        steps.append(np.where(begins, 0.0, step))
        starts.append(begins)
    offsets = np.zeros((first, sum(b.shape[1] for b in bases)))
    column = 0
    for part, basis in zip(parts, bases, strict=True):
        offsets[part, column : column + basis.shape[1]] = basis
        column += basis.shape[1]
    # One bias for the logs' Ay sensor (a test's IMU and its mounting): the law's saturation
    # is what tells it from the torque offsets, so only where the logs reach it; a bias per log
    # wandered with its offset on a parking log (no Ay: the two are one).
    measured = [i for i, log in enumerate(logs) if log.lateral_accel_m_s2 is not None]
    ay_all = np.concatenate(ays)
    reach = len(measured) > 0 and float(np.percentile(np.abs(ay_all), 99)) >= SATURATION_AY_M_S2
    ay_bias = np.zeros((first, 1 if reach else 0))
    for i in measured if reach else []:
        ay_bias[parts[i], 0] = 1.0
    return _Data(
        np.concatenate(taus),
        np.concatenate([log.speed_m_s for log in logs]),
        np.concatenate([log.rate_rad_s for log in logs]),
        np.concatenate(ays),
        np.concatenate([log.torque_Nm for log in logs]),
        offsets, parts, np.concatenate(blocks), local, np.concatenate(steps),
        np.concatenate(starts),
        np.concatenate([log.rate_error_rad_s if log.rate_error_rad_s is not None
                        else np.zeros(len(log.time_s)) for log in logs]),
        ay_bias,
    )  # fmt: skip


@dataclass
class _Problem:
    """The full parameter vector x = [law, (K_us), delay, torque offsets, Ay biases] and what
    it predicts."""

    data: _Data
    law: LawModel
    k_us: float | None
    """The understeer gradient Ay was simulated at (fitting K_us), else None."""
    wheelbase: float
    base_x: FloatArray
    lower: FloatArray
    upper: FloatArray
    evaluations: list[int]
    progress: Callable[[int, float], None] | None
    weights: FloatArray | None = None
    """Each residual's weight: 1 / sqrt(1 + (dtau/drate * rate error / scale)^2), the rate's
    errors in variables (`eiv_weights`); None: all 1."""

    @property
    def n_law(self) -> int:
        return len(self.law.names)

    @property
    def delay_index(self) -> int:
        return self.n_law + (1 if self.k_us is not None else 0)

    @property
    def offset_slice(self) -> slice:
        start = self.delay_index + 1
        return slice(start, start + self.data.offsets.shape[1])

    @property
    def bias_slice(self) -> slice:
        return slice(self.offset_slice.stop, None)

    def regressors(self, x: FloatArray, delay_s: float | None = None) -> Regressors:
        """The regressors at the delay (x's, or `delay_s`), the measured Ay less its bias."""
        r = self.data.regressors(float(x[self.delay_index]) if delay_s is None else delay_s)
        if self.data.ay_bias.shape[1]:
            r = dataclasses.replace(r, ay=r.ay - self.data.ay_bias @ x[self.bias_slice])
        if self.k_us is None:
            return r
        gain = (1.0 + self.k_us / self.wheelbase * r.speed**2) / (
            1.0 + x[self.n_law] / self.wheelbase * r.speed**2
        )
        return dataclasses.replace(r, ay=r.ay * gain)

    def law_torque(self, x: FloatArray, delay_s: float | None = None) -> FloatArray:
        return self.law.torque(x[: self.n_law], self.regressors(x, delay_s))

    def model(self, x: FloatArray) -> FloatArray:
        """Model torque, offsets included."""
        offsets = self.data.offsets @ x[self.offset_slice]
        return np.asarray(self.law_torque(x) + offsets)

    def residual(self, x: FloatArray) -> FloatArray:
        """(model - measured), weighted."""
        r = np.asarray(self.model(x) - self.data.torque)
        return r if self.weights is None else r * self.weights

    def weighted_jacobian(self, x: FloatArray, free: BoolArray) -> FloatArray:
        jac = self.jacobian(x, free)
        return jac if self.weights is None else jac * self.weights[:, None]

    def jacobian(self, x: FloatArray, free: BoolArray) -> FloatArray:
        """d model / d x over the free entries."""
        n_law, di = self.n_law, self.delay_index
        r = self.regressors(x)
        columns = [self.law.jacobian(x[:n_law], r)]
        if self.k_us is not None:
            speed = r.speed
            ku = float(x[n_law])
            slope = self.law.d_torque_d_ay(x[:n_law], r.ay)
            stability = speed**2 / self.wheelbase
            columns.append((slope * (-r.ay * stability / (1.0 + ku * stability)))[:, None])
        if free[di]:
            d = float(x[di])
            up = self.law_torque(x, d + DELAY_STEP_S)
            down = self.law_torque(x, d - DELAY_STEP_S)
            columns.append(((up - down) / (2.0 * DELAY_STEP_S))[:, None])
        else:
            columns.append(np.zeros((len(r.speed), 1)))
        columns.append(self.data.offsets)
        if self.data.ay_bias.shape[1]:  # Ay - bias: the aligning term's slope, negated
            slope = self.law.d_torque_d_ay(x[:n_law], r.ay)
            columns.append(-slope[:, None] * self.data.ay_bias)
        return np.hstack(columns)[:, free]
