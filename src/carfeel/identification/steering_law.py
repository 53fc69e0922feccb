"""The torque law as the fit sees it (`LawModel`: names, bounds, torque and its Jacobian over
the `Regressors`), and the paper's (`PAPER_LAW`, K1..K9 of eqs. 4-7 with the friction's memory
K10, K11). Another steering model can be served by another instance without touching the fit."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.identification.signals import linear_recurrence
from carfeel.models.steering.torque import SteeringTorqueParams, torque_terms

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
K_NAMES = ("k1_Nm_s2_m", "k2", "k3", "k4_1_Nm", "k5_s_m_Nm", "k6_rad_s", "k7_Nm", "k8_rad_s",
           "k9_Nm_s_rad", "k10_Nm", "k11_rad")  # fmt: skip
MEANINGS = {
    "k1_Nm_s2_m": "K1, aligning: on-centre torque per m/s^2 of Ay, Nm s^2/m (x 9.81: Nm/g)",
    "k2": "K2, aligning saturation: tau0 = K1 Ay / (1 + K2 |Ay|^K3), (m/s^2)^-K3",
    "k3": "K3, aligning saturation exponent",
    "k4_1_Nm": "K4, tyre spin at standstill: tau1 = atan(rate / K6) / (K4 + K5 V), 1/Nm",
    "k5_s_m_Nm": "K5, tyre spin falling with speed V, s/(m Nm)",
    "k6_rad_s": "K6, steering rate at which the tyre spin builds, rad/s",
    "k7_Nm": "K7, friction level: tau2 = K7 atan(rate / K8), Nm",
    "k8_rad_s": "K8, steering rate within which the friction builds, rad/s",
    "k9_Nm_s_rad": "K9, damping: tau3 = K9 rate, Nm s/rad",
    "k10_Nm": "K10, friction with memory: its level, Nm (tau2 + K10 z, z a Dahl element)",
    "k11_rad": "K11, the steering angle over which that friction builds after a reversal, rad",
    "understeer_gradient_rad_s2_m": "the car's understeer gradient K_us (fitted without a "
    "measured Ay), rad per m/s^2",
}
"""What each fitted parameter is (the paper's eqs. 4-7 and the friction's memory), for reports."""
LOWER = (1e-3, 0.0, 0.3, 1e-2, 0.0, 1e-2, 0.0, 1e-3, 0.0, 0.0, 1e-3)
UPPER = (50.0, 10.0, 3.0, 100.0, 100.0, 10.0, 20.0, 5.0, 5.0, 20.0, 0.1)


@dataclass(frozen=True)
class Regressors:
    """What a law is evaluated on, sample by sample over the concatenated logs: speed (m/s),
    rate (rad/s), Ay (m/s^2), and for a law with memory the angle each sample's step turned
    (|rate| dt, rad) and where a gap-free stretch starts (memory from rest)."""

    speed: FloatArray
    rate: FloatArray
    ay: FloatArray
    turned: FloatArray
    starts: BoolArray


@dataclass(frozen=True)
class LawModel:
    """A torque law as the fit sees it: parameter names and bounds, the torque and its Jacobian
    in the parameters over `Regressors`, its slope in Ay (for the understeer gradient), and the
    parameters as a preset's."""

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    torque: Callable[[FloatArray, Regressors], FloatArray]
    jacobian: Callable[[FloatArray, Regressors], FloatArray]
    d_torque_d_ay: Callable[[FloatArray, FloatArray], FloatArray]
    params: Callable[[FloatArray], SteeringTorqueParams]


def _law(x: FloatArray) -> SteeringTorqueParams:
    return SteeringTorqueParams(*(float(v) for v in x[: len(K_NAMES)]))


def friction_memory(
    regressors: Regressors, k11_rad: float, sensitivity: bool = False
) -> tuple[FloatArray, FloatArray | None]:
    """The law's friction memory z at every sample (`torque.friction_memory_step` run over the
    samples, from 0 at each stretch's start), and with `sensitivity` dz/dK11 (its own
    recurrence), both by `signals.linear_recurrence`."""
    sign = np.sign(regressors.rate)
    log_decay = np.where(regressors.starts, -np.inf, -regressors.turned / k11_rad)
    decay = np.exp(log_decay)
    z = linear_recurrence(log_decay, np.where(regressors.starts, 0.0, (1.0 - decay) * sign))
    if not sensitivity:
        return z, None
    before = np.concatenate([[0.0], z[:-1]])
    drive = np.where(regressors.starts, 0.0,
                     (before - sign) * decay * regressors.turned / k11_rad**2)  # fmt: skip
    return z, linear_recurrence(log_decay, drive)


def _paper_torque(x: FloatArray, r: Regressors) -> FloatArray:
    law = _law(x)
    torque = np.asarray(torque_terms(r.speed, r.rate, r.ay, law, atan=np.arctan)[0])
    if law.k10_Nm != 0.0:
        torque = torque + law.k10_Nm * friction_memory(r, law.k11_rad)[0]
    return torque


def _paper_jacobian(x: FloatArray, r: Regressors) -> FloatArray:
    """d torque / d (K1..K11), one column each."""
    k1, k2, k3, k4, k5, k6, k7, k8, _, k10, k11 = (float(v) for v in x[: len(K_NAMES)])
    speed, rate, ay = r.speed, r.rate, r.ay
    abs_ay = np.abs(ay)
    power = np.where(abs_ay > 0.0, abs_ay**k3, 0.0)
    log_ay = np.where(abs_ay > 0.0, np.log(np.where(abs_ay > 0.0, abs_ay, 1.0)), 0.0)
    d = 1.0 + k2 * power
    spin_atan = np.arctan(rate / k6)
    e = k4 + k5 * np.abs(speed)
    z, dz = friction_memory(r, k11, sensitivity=k10 != 0.0)
    return np.column_stack([
        ay / d,
        -k1 * ay * power / d**2,
        -k1 * ay * k2 * power * log_ay / d**2,
        -spin_atan / e**2,
        -np.abs(speed) * spin_atan / e**2,
        (1.0 / e) / (1.0 + (rate / k6) ** 2) * (-rate / k6**2),
        np.arctan(rate / k8),
        k7 / (1.0 + (rate / k8) ** 2) * (-rate / k8**2),
        rate,
        z,
        k10 * dz if dz is not None else np.zeros_like(z),
    ])  # fmt: skip


def _paper_d_ay(x: FloatArray, ay: FloatArray) -> FloatArray:
    k1, k2, k3 = (float(v) for v in x[:3])
    power = np.abs(ay) ** k3
    return np.asarray(k1 * (1.0 + k2 * (1.0 - k3) * power) / (1.0 + k2 * power) ** 2)


PAPER_LAW = LawModel(K_NAMES, LOWER, UPPER, _paper_torque, _paper_jacobian, _paper_d_ay, _law)
"""Eqs. (4)-(7) of the paper, with the friction's memory (K10, K11; `torque`)."""
MEMORY = (K_NAMES.index("k10_Nm"), K_NAMES.index("k11_rad"))
