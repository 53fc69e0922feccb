"""The values the shift fit reads off its engagements as statistics, and their standard
errors: the uniform law of the teeth's resistance from the fitted draws (`_tooth_law`,
`_tooth_law_sigmas`), and the medians over the engagements (`_median_sigmas`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from carfeel.identification.shift_traces import FoundEngagement
from carfeel.models.gearshift.engagement import EngagementParams


def _tooth_law(
    resistances: Sequence[float], gb: EngagementParams, warnings: list[str]
) -> tuple[float, float]:
    """Sliding friction and spread (N) of the uniform law of the teeth's resistance."""
    rs = [r for r in resistances if math.isfinite(r)]
    n = len(rs)
    if n == 0:
        return gb.engagement.sliding_friction_N, gb.tooth_force_spread_N
    if n == 1:
        spread = gb.tooth_force_spread_N
        warnings.append(
            "one engagement: the spread of the tooth force is not identifiable from a single "
            f"engagement; tooth_force_spread_N kept from the base ({spread:g} N), the teeth's "
            "friction set so that the engagement's resistance is the law's mean"
        )
        return max(rs[0] - 0.5 * spread, 0.0), spread
    low, high = min(rs), max(rs)
    # The unbiased bounds of a uniform law from n draws (their expected extremes lie 1/(n+1)
    # of the width inside the bounds).
    lower = (n * low - high) / (n - 1)
    upper = (n * high - low) / (n - 1)
    if n < 4:
        warnings.append(
            f"{n} engagements: the spread of the tooth force rests on few draws; record more "
            "engagements for a firm value"
        )
    sliding = max(lower, 0.0)
    return sliding, max(upper - sliding, 0.0)


def _median_error(values: Sequence[float]) -> float:
    """Standard error of the median of `values`: 1.2533 s / sqrt(n), the large-sample one of a
    normal sample (within 5 % of the true one from n = 3 on); NaN from fewer than three."""
    v = [x for x in values if math.isfinite(x)]
    return 1.2533 * float(np.std(v, ddof=1)) / math.sqrt(len(v)) if len(v) >= 3 else math.nan


def _median_sigmas(found: Sequence[FoundEngagement], times: Sequence[float]) -> dict[str, float]:
    """The sigmas of the values that are medians over the engagements: the scatter between
    engagements (`_median_error`), but no less than what each plateau's own samples leave (its
    median's error, over the engagements) and, where the sensor's stairs are not dithered by
    its noise, its resolution's q / sqrt(12), shared by every plateau and so not averaged away
    (a quantized ring read the same on all six plateaus: a sigma of 0)."""

    def floor(sigma: float, samples: float, step: float, noise: float) -> float:
        within = 1.2533 * sigma / math.sqrt(max(samples, 1.0)) / math.sqrt(len(found))
        shared = step / math.sqrt(12.0) if noise < 0.5 * step else 0.0
        return math.hypot(within, shared)

    def combined(between: float, least: float) -> float:
        return math.nan if math.isnan(between) else max(between, least)

    # The plateau's position is the median over it, its force over its second half.
    samples = float(np.median([e.features.plateau_duration_s / e.trace.dt_s for e in found]))
    tr = found[0].trace
    ring = floor(float(np.median([e.trace.sigma_m for e in found])), samples,
                 max(e.trace.resolution_m for e in found), tr.noise_m)  # fmt: skip
    push = floor(float(np.median([e.trace.sigma_N for e in found])), samples / 2.0,
                 max(e.trace.resolution_N for e in found), tr.noise_N)  # fmt: skip
    return {
        "gearbox.synchronization_position_m": combined(
            _median_error([e.features.synchronization_position_m for e in found]), ring
        ),
        "gearbox.synchronization_duration_s": _median_error(times),
        "driver.push_force_N": combined(
            _median_error([e.features.plateau_force_N for e in found]), push
        ),
    }


def _tooth_law_sigmas(n: int, spread: float) -> dict[str, float]:
    """Standard deviations of the uniform law's bounds estimated from n draws (`_tooth_law`): for
    U(a, a + w), var(lower) = n w^2 / ((n + 1)(n + 2)(n - 1)) and var(spread) = 2 w^2 / ((n - 1)
    (n + 2)) (from the moments of the extremes); none from one draw."""
    if n < 2:
        return {}
    lower = spread * math.sqrt(n / ((n + 1) * (n + 2) * (n - 1)))
    return {
        "gearbox.engagement.sliding_friction_N": lower,
        "gearbox.engagement.static_friction_N": lower,
        "gearbox.tooth_force_spread_N": spread * math.sqrt(2.0 / ((n - 1) * (n + 2))),
    }
