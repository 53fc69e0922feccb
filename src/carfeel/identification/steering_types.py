"""What the law's fit (`steering_fit`) and the physical model's (`physical_fit`) take and give:
a checked log (`SteeringLog`), one parameter's estimate and the fit's result."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.identification import keep, rms_r2
from carfeel.simulation.steering import SteeringCar

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SteeringLog:
    """One log's signals in SI units, checked, with the rate and Ay it will be fitted with."""

    name: str
    time_s: FloatArray
    speed_m_s: FloatArray
    angle_rad: FloatArray
    rate_rad_s: FloatArray
    torque_Nm: FloatArray
    lateral_accel_m_s2: FloatArray | None
    rate_logged: bool = False
    """The rate is the log's own (as logged, or smoothed), not derived from the angle."""
    rate_error_rad_s: FloatArray | None = None
    """One sigma of the rate at each sample (`signals.adaptive_estimate`): its errors in
    variables, which weight the fit (`_Problem.weights`); None: not known."""


@dataclass(frozen=True)
class Estimate:
    name: str
    value: float
    sigma: float
    """One standard deviation; NaN for a parameter kept from the base preset."""
    status: str = "fitted"
    """"fitted", or "kept": the base preset's value, which the data accept (the test's note)."""
    note: str = ""


@dataclass(frozen=True)
class SteeringFit:
    car: SteeringCar
    estimates: tuple[Estimate, ...]
    torque_offset_Nm: float
    """The mean of the logs' offsets (model + offset = measured)."""
    rms_error_Nm: float
    r2: float
    per_log: dict[str, dict[str, float]]
    """Per log: rms_error_Nm, r2, mean residual (the bias left), samples, offset_Nm (mean),
    offset_range_Nm (how far a drifting offset wandered), offset_end_Nm (its last value: what
    a later part of the log is predicted with) and, with a measured Ay, ay_offset_m_s2."""
    warnings: tuple[str, ...]
    iterations: int
    torque_delay_s: float = 0.0
    """How much later the torque was logged than the other channels (corrected in the fit)."""
    correlation: tuple[tuple[str, ...], tuple[tuple[float, ...], ...]] = ((), ())
    """(names, matrix) of the fitted parameters' correlations."""
    holdout: dict[str, dict[str, dict[str, float]]] = dataclasses.field(default_factory=dict)
    """With a held-out part: {"fit": figures per log, "held_out": figures per log}."""
    free_fit: dict[str, float] = dataclasses.field(default_factory=dict)
    """rms_error_Nm and r2 of the fit with every candidate free (before any is kept)."""
    keep_tests: tuple[keep.KeepTest, ...] = ()
    """The tests that decided what is kept from the base (`keep.keep_from_base`)."""
    baselines: dict[str, dict[str, dict[str, float]]] = dataclasses.field(default_factory=dict)
    """The model and the black boxes (`baselines`) on the same split: {name: {log or "all":
    figures}}, with `baseline_split` saying which."""
    baseline_split: str = ""
    law_test: keep.KeepTest | None = None
    """The written law against none (a torque offset per log only, `against_no_law`): with
    p > alpha the logs show no steering feel at all, whatever the parameters say."""
    law_explains: float = math.nan
    """The fraction of the torque's variance about the offsets that the written law removes
    (`against_no_law`): under MIN_EXPLAINED it explains nothing an engineer could use."""

    @property
    def conditional(self) -> bool:
        """The sigmas are conditional on values kept from the base."""
        return any(t.kept for t in self.keep_tests)

    def as_dict(self) -> dict[str, object]:
        names, matrix = self.correlation
        return {
            "parameters": {
                e.name: {
                    "value": e.value,
                    "sigma": e.sigma,
                    "status": e.status,
                    **({"note": e.note} if e.note else {}),
                }
                for e in self.estimates
            },
            "sigmas_conditional_on_kept": self.conditional,
            "correlation": {"parameters": list(names), "matrix": [list(r) for r in matrix]},
            "torque_offset_Nm": self.torque_offset_Nm,
            "torque_delay_s": self.torque_delay_s,
            "rms_error": self.rms_error_Nm,
            "rms_error_unit": "N m",
            "r2": self.r2,
            "free_fit": self.free_fit,
            "keep_tests": [t.as_dict() for t in self.keep_tests],
            **(
                {"law_test": {**self.law_test.as_dict(), "explains": self.law_explains}}
                if self.law_test is not None
                else {}
            ),
            "per_log": self.per_log,
            "warnings": list(self.warnings),
            "iterations": self.iterations,
            **({"cross_validation": self.holdout} if self.holdout else {}),
            **(
                {"baselines": {"split": self.baseline_split, **self.baselines}}
                if self.baselines
                else {}
            ),
        }


def log_figures(
    torque_Nm: FloatArray, residual_Nm: FloatArray, offset_Nm: FloatArray, samples: int
) -> dict[str, float]:
    """One log's figures for `SteeringFit.per_log` from its scored rows: the measured torque,
    the residual (model - measured) and the fitted offset there (Nm), and its sample count
    (NaN for the means of a log without scored rows)."""
    some = len(torque_Nm) > 0
    log_rms, log_r2 = rms_r2(torque_Nm, torque_Nm + residual_Nm)
    return {
        "rms_error_Nm": log_rms,
        "r2": log_r2,
        "mean_residual_Nm": float(np.mean(residual_Nm)) if some else math.nan,
        "samples": float(samples),
        "offset_Nm": float(np.mean(offset_Nm)) if some else math.nan,
        "offset_range_Nm": float(np.ptp(offset_Nm)) if some else 0.0,
        "offset_end_Nm": float(offset_Nm[-1]) if some else math.nan,
    }


def poorly_pinned(estimates: Sequence[Estimate]) -> list[str]:
    """A warning for each fitted parameter whose sigma is over half its (positive) value."""
    return [
        f"{e.name} = {e.value:.3g} +- {e.sigma:.2g}: the data pin it down poorly"
        for e in estimates
        if e.status == "fitted" and e.value > 0 and e.sigma > 0.5 * abs(e.value)
    ]
