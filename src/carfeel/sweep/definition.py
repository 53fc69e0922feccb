"""A validated sweep spec as plain data, which travels to Dask workers as it is: `SweepSpec`, its
varied parameters (`Vary`: a grid of values, or a distribution with its inverse CDF), its cases
(`Case`: a parameter set and a seed) and `SpecError`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from carfeel.errors import InputError

DISTRIBUTIONS = {
    "uniform": ("low", "high"),
    "normal": ("mean", "sd"),
    "truncnormal": ("mean", "sd", "low", "high"),
}
MAX_CASES = 10_000_000
"""The most cases a sweep may ask for (seeds included), checked before any is made."""


class SpecError(InputError):
    """A sweep spec is missing, malformed, or asks for what the models cannot do."""


Value = float | int | bool


@dataclass(frozen=True)
class Vary:
    """One varied parameter: a grid of values, or a distribution."""

    path: str
    values: tuple[Value, ...] = ()
    distribution: str = ""
    args: tuple[float, ...] = ()
    """The distribution's arguments in DISTRIBUTIONS order."""

    def sample(self, u: np.ndarray) -> np.ndarray:
        """The distribution's values at the uniform quantiles u (inverse CDF; scipy.special,
        not scipy.stats, whose import costs seconds)."""
        from scipy.special import ndtr, ndtri

        if self.distribution == "uniform":
            low, high = self.args
            return low + u * (high - low)
        if self.distribution == "normal":
            mean, sd = self.args
            return np.asarray(mean + sd * ndtri(u), dtype=float)
        mean, sd, low, high = self.args
        a, b = (low - mean) / sd, (high - mean) / sd
        sign = 1.0
        if a > 0.0:  # in the upper tail: mirror it to the lower, where the CDF keeps precision
            a, b, sign, u = -b, -a, -1.0, 1.0 - u
        lo, hi = ndtr(a), ndtr(b)
        drawn = mean + sign * sd * ndtri(lo + u * (hi - lo))
        return np.asarray(np.clip(drawn, low, high))  # the last ulp stays within the bounds


@dataclass(frozen=True)
class Case:
    """One simulation: a parameter set (by its index, `sample`) and a seed."""

    case_id: int
    sample: int
    seed: int
    values: tuple[tuple[str, Value], ...]


@dataclass(frozen=True)
class SweepSpec:
    """A validated spec; plain data, so it travels to Dask workers as it is."""

    label: str
    model: str
    preset_label: str
    preset_text: str
    engagement_text: str
    """hpattern: the text of the shift preset its slots engage with ('' otherwise)."""
    seeds: Sequence[int]
    """A range (`seeds = n`: never a tuple of n ints) or the spec's list as a tuple."""
    samples: int
    sampling: str
    sampling_seed: int
    metrics: tuple[str, ...]
    engine: str
    cases_per_task: int
    run: tuple[tuple[str, Any], ...]
    fixed: tuple[tuple[str, Value], ...]
    vary: tuple[Vary, ...]
    text: str
    """The spec's TOML, as given (kept in the results' metadata)."""
    hash: str

    @property
    def settings(self) -> dict[str, Any]:
        return dict(self.run)

    @property
    def parameters(self) -> tuple[str, ...]:
        return tuple(v.path for v in self.vary)

    @property
    def n_sets(self) -> int:
        grid = math.prod(len(v.values) for v in self.vary if v.values)
        return grid * self.samples

    @property
    def n_cases(self) -> int:
        return self.n_sets * len(self.seeds)

    def columns(self) -> list[str]:
        return ["case_id", "sample", "seed", *self.parameters, *self.metrics, "status", "problem"]
