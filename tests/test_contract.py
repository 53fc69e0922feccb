"""One contract over every model step (DESIGN.md, principle 10).

Each entry: a pure step, its params, an initial state for a seed, an input signal, and how long to
run. Every model must give finite outputs, the same result for the same seed, and converge as
the step shrinks.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from carfeel.models.drivers import shift as driver
from carfeel.models.gearshift import engagement
from carfeel.simulation import shift
from carfeel.simulation.runner import run
from tests.conftest import default_params


@dataclass(frozen=True)
class Contract:
    name: str
    step: Callable[..., Any]
    params: Any
    initial: Callable[[int], Any]
    inputs: Callable[[float], Any] | None
    duration_s: float
    position: str  # a signal that must converge as dt shrinks
    tolerance: float  # RMS difference allowed between dt = 1 ms and 0.1 ms, in its unit


def contracts() -> list[Contract]:
    p = default_params()
    return [
        Contract(
            "engagement",
            engagement.step,
            p.gearbox,
            lambda seed: engagement.initial_state(seed),
            lambda t: engagement.EngagementInputs(55.0 if t < 0.9 else -15.0),
            1.5,
            "position_m",
            # Open loop the lever reaches 1.2 m/s after the gate opens; events are resolved to
            # one step, so runs may differ by up to 1 ms x 1.2 m/s = 1.2 mm for a while.
            1.2e-3,
        ),
        Contract(
            "shift driver",
            driver.step,
            p.driver,
            lambda seed: driver.initial_state(),
            lambda t: driver.DriverInputs(min(t, 0.2) * 0.1, 0.1 if t < 0.2 else 0.0),
            0.6,
            "force_N",
            0.5,  # N; the hand's fastest mode is 4 ms, well resolved by 1 ms steps
        ),
        Contract(
            "shift loop",
            shift.step,
            p,
            lambda seed: shift.initial_state(seed),
            None,
            1.2,
            "position_m",
            0.3e-3,  # see test_engagement.test_one_ms_steps_and_tenth_ms_substeps
        ),
    ]


CONTRACTS = contracts()


@pytest.mark.parametrize("c", CONTRACTS, ids=lambda c: c.name)
def test_finite_outputs(c):
    result, _ = run(c.step, c.initial(1), c.params, duration_s=c.duration_s, inputs=c.inputs)
    for name in result.names:
        values = result[name]
        if values.dtype.kind == "f":
            assert np.all(np.isfinite(values)), name


@pytest.mark.parametrize("c", CONTRACTS, ids=lambda c: c.name)
def test_same_seed_same_result(c):
    a, _ = run(c.step, c.initial(9), c.params, duration_s=c.duration_s, inputs=c.inputs)
    b, _ = run(c.step, c.initial(9), c.params, duration_s=c.duration_s, inputs=c.inputs)
    for name in a.names:
        assert np.array_equal(a[name], b[name]), name


@pytest.mark.parametrize("c", CONTRACTS, ids=lambda c: c.name)
def test_converges_as_dt_shrinks(c):
    def rms(substeps_a: int, substeps_b: int) -> float:
        a, _ = run(
            c.step,
            c.initial(2),
            c.params,
            duration_s=c.duration_s,
            inputs=c.inputs,
            substeps=substeps_a,
        )
        b, _ = run(
            c.step,
            c.initial(2),
            c.params,
            duration_s=c.duration_s,
            inputs=c.inputs,
            substeps=substeps_b,
        )
        return math.sqrt(float(np.mean((a[c.position] - b[c.position]) ** 2)))

    coarse = rms(1, 20)
    finer = rms(10, 20)
    assert coarse < c.tolerance
    # The error against a fine reference shrinks with the step.
    assert finer <= coarse + 1e-12
