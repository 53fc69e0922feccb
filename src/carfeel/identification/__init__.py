"""Identification from measured logs, and validation of the models against them."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt


def rms_r2(measured: npt.ArrayLike, model: npt.ArrayLike) -> tuple[float, float]:
    """(rms of model - measured, coefficient of determination r2); r2 is NaN for a measured
    signal without variance, where it would say nothing."""
    measured, model = np.asarray(measured, dtype=float), np.asarray(model, dtype=float)
    residual = model - measured
    total = float(np.sum((measured - measured.mean()) ** 2))
    r2 = 1.0 - float(np.sum(residual**2)) / total if total > 0.0 else math.nan
    return float(np.sqrt(np.mean(residual**2))), r2
