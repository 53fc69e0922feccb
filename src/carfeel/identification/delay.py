"""The search for the torque's delay behind the other channels that both steering fits share
(each with its own cost: the law's re-evaluated, the physical model's simulated torque
shifted)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

MAX_DELAY_S = 0.25
"""Largest delay of the torque (s) either way the fits look for (CAN messages' latencies)."""
RESCAN_S = 0.005
"""After the fit, a delay scan that finds a better minimum further than this starts it again."""


def minimize_delay(cost: Callable[[float], float]) -> float:
    """The delay (s) of least `cost`: a grid of 21 over +-MAX_DELAY_S, then a bounded search
    within a grid step of its best point (kept only where it does better)."""
    from scipy.optimize import minimize_scalar

    grid = np.linspace(-MAX_DELAY_S, MAX_DELAY_S, 21)
    best = float(grid[int(np.argmin([cost(float(d)) for d in grid]))])
    step = float(grid[1] - grid[0])
    found = minimize_scalar(
        cost, bounds=(max(best - step, -MAX_DELAY_S), min(best + step, MAX_DELAY_S)),
        method="bounded", options={"xatol": 1e-4},
    )  # fmt: skip
    return float(found.x) if found.fun <= cost(best) else best
