"""A gearshift's knob traces read, checked, prepared and segmented into engagements: the
first half of the shift fit (`shift_fit`'s docstring gives the rules: preparation, plateau,
arrival, window, stop, settled, tooth). Positions in m (+ toward the gear), forces in N (+ the
hand's push toward the gear), times in s.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification.signals import noise_sigma, resolution
from carfeel.simulation.result import Result
from carfeel.text import count

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
Trace = Result | Mapping[str, npt.ArrayLike]
REQUIRED = ("time_s", "position_m", "force_N")

MIN_SAMPLES = 50
MAX_SAMPLE_PERIOD_S = 5e-3
"""Sampled slower than 200 Hz, the start of a plateau and a tooth's impact are not resolved."""
MAX_TRAVEL_M = 0.2
"""A knob further than this from neutral is not a gear lever: the trace is in other units."""
NOISE_BAND = 3.0
"""Half-width of the plateau band, in sigmas of the position noise."""
BAND_FLOOR_M = 2e-6
MIN_PLATEAU_S = 0.04
KGF_SUSPECT_N = 20.0
"""A synchronization plateau below this at the knob is not a car's (a force in kgf reads 9.8x
low)."""
MIN_TRAVEL_M = 0.002
HIGH_FORCE_FRACTION = 0.5
LOW_FORCE_FRACTION = 0.1
STILL_WINDOW_S = 0.02
APPROACH_S = 0.04
STOP_WINDOW_S = 0.15
"""How long after reaching the stop the stop fit looks: overshoot, push, release, settling."""


@dataclass(frozen=True, slots=True)
class EngagementFeatures:
    """What one engagement of a trace shows. Positions in m, forces in N, times in s."""

    trace: int
    """Index of the trace in the sequence given to `fit_shift`."""
    start_time_s: float
    """When the knob reached the synchro ring (its approach extrapolated to the plateau)."""
    synchronization_position_m: float
    plateau_force_N: float
    plateau_duration_s: float
    """From the first to the last sample within the band (a multiple of the sample period)."""
    tooth_peak_force_N: float
    """Highest knob force between the synchronization and the stop; NaN if there is none."""
    tooth_peak_position_m: float
    stop_position_m: float
    """Largest position of the engagement (the overshoot into the end stop)."""
    settled_position_m: float
    overshoot_m: float
    synchronization_time_s: float = math.nan
    """Fitted: from the arrival at the ring to the gate's opening."""
    tooth_resistance_N: float = math.nan
    """Fitted: the teeth's sliding resistance in this engagement (friction + tooth draw)."""
    chamfer_travel_m: float = math.nan
    """Fitted: how far past the teeth the chamfers turned the gear (0: gap to gap); NaN where
    the base has no chamfer inertia or drag, or the engagement was not fitted."""


@dataclass(frozen=True)
class PreparedTrace:
    """One checked trace: measured samples (outliers replaced) and the uniform grid."""

    label: str
    index: int
    time_s: FloatArray
    position_m: FloatArray
    force_N: FloatArray
    keep: BoolArray
    """Samples that are not outliers: the ones the fits and figures compare."""
    sigma_m: float
    """One sample's position error: its noise and its resolution's q^2 / 12."""
    sigma_N: float
    dt_s: float
    grid_s: FloatArray
    x_med: FloatArray
    f_med: FloatArray
    x_smooth: FloatArray
    f_smooth: FloatArray
    f_wide: FloatArray
    resolution_m: float = 0.0
    """The step the position moves in (0: not quantized; `signals.resolution`)."""
    resolution_N: float = 0.0
    noise_m: float = 0.0
    """The position's noise alone (below its resolution the stairs are not dithered away)."""
    noise_N: float = 0.0


@dataclass(frozen=True)
class FoundEngagement:
    """An engagement as segmented, with the times the fits need."""

    trace: PreparedTrace
    features: EngagementFeatures
    plateau_end_s: float
    """Time of the plateau's last sample."""
    stop_reach_s: float
    """When the knob first reaches the settled position."""
    stop_end_s: float
    """End of the stop fit's window."""
    pull_s: float = math.nan
    """When the hand, having let go in gear, starts to pull the knob out (the last sample at
    rest before the pull); NaN if it never let go or never pulls."""
    pull_position_m: float = math.nan


# --- reading and preparing a trace -------------------------------------------------------------


def _label(trace: object, index: int) -> str:
    name = getattr(trace, "name", None)
    if name is None and isinstance(trace, Result):
        name = trace.metadata.get("name")
    return f"trace {index + 1}" + (f" ({name})" if name else "")  # counted from 1, as a user does


def _columns(trace: Trace, label: str) -> tuple[FloatArray, FloatArray, FloatArray]:
    if isinstance(trace, Result):
        names = trace.names
    elif isinstance(trace, Mapping):
        names = list(trace)
    else:
        raise InputError(
            f"{label}: expected a Result or a mapping of arrays, got {type(trace).__name__}"
        )
    missing = [c for c in REQUIRED if c not in names]
    if missing:
        raise InputError(
            f"{label}: missing column(s) {', '.join(missing)}; a shift trace needs time_s (s), "
            "position_m (m along the slot, 0 = neutral, + toward the gear) and force_N (N, the "
            "hand's force on the knob, + toward the gear)"
        )
    arrays = []
    for column in REQUIRED:
        try:
            values = np.asarray(trace[column], dtype=float)
        except (TypeError, ValueError):
            raise InputError(
                f"{label}: column {column} must hold numbers; {_first_non_number(trace[column])}"
            ) from None
        if values.ndim != 1:
            raise InputError(f"{label}: column {column} must be one-dimensional")
        arrays.append(values)
    t, x, f = arrays
    if not len(t) == len(x) == len(f):
        raise InputError(
            f"{label}: columns differ in length (time_s {len(t)}, position_m {len(x)}, "
            f"force_N {len(f)}); give one value of each per sample"
        )
    return t, x, f


def _first_non_number(values: Any) -> str:
    for i, value in enumerate(values):
        try:
            float(value)
        except (TypeError, ValueError):
            return f"sample {i + 1} is {str(value)!r}"
    return "it holds something else"


def checked_columns(trace: Trace, label: str) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A trace's time_s, position_m and force_N as float arrays, after the checks a fit and a
    validation need (numbers, finite, time increasing, sampled at 100 Hz or faster)."""
    t, x, f = _columns(trace, label)
    _check(label, t, x, f)
    return t, x, f


def _check(label: str, t: FloatArray, x: FloatArray, f: FloatArray) -> None:
    if len(t) < MIN_SAMPLES:
        raise InputError(
            f"{label}: {count(len(t), 'sample')}; a fit or a validation needs {MIN_SAMPLES} at "
            "least"
        )
    for column, values in zip(REQUIRED, (t, x, f), strict=True):
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            at = f" (t = {t[bad[0]]:g} s)" if np.isfinite(t[bad[0]]) else ""
            raise InputError(
                f"{label}: {column} holds {bad.size} NaN or infinite value(s), the first at "
                f"sample {bad[0] + 1}{at}; drop those samples (a gap is fine) or repair them"
            )
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        i = int(back[0]) + 1
        raise InputError(
            f"{label}: time_s does not increase at sample {i + 1} ({t[i - 1]:g} s, then "
            f"{t[i]:g} s); sort the samples by time and drop duplicates"
        )
    span = float(np.max(np.abs(x)))
    if span > MAX_TRAVEL_M:
        raise InputError(
            f"{label}: position_m reaches {span:.4g}, beyond any gear lever's travel "
            f"({MAX_TRAVEL_M:g} m): if it is in mm, divide it by 1000"
        )
    low, high = (float(v) for v in np.percentile(x, (1, 99)))
    if -low > 2.0 * max(high, MIN_TRAVEL_M):  # a pull-out may overshoot neutral a little
        raise InputError(
            f"{label}: position_m runs to {low * 1e3:.3g} mm and only to {high * 1e3:+.3g} mm "
            "the other way; carfeel's knob position is + toward the gear (0 = "
            "neutral): flip its sign (scale = -1 in a channel map), and force_N's too if a push "
            "into gear reads negative"
        )
    dt = float(np.median(np.diff(t)))
    if dt > MAX_SAMPLE_PERIOD_S * (1.0 + 1e-6):  # 200 Hz itself, as a float step, passes
        raise InputError(
            f"{label}: sampled every {dt * 1e3:.3g} ms; the segmentation needs at least "
            f"{1.0 / MAX_SAMPLE_PERIOD_S:.0f} Hz (a sample every {MAX_SAMPLE_PERIOD_S * 1e3:g} ms)"
        )


def _despike(values: FloatArray, threshold: float) -> tuple[FloatArray, BoolArray]:
    """Replace samples farther than `threshold` from their 5-sample median; (clean, outliers).

    Only the farthest sample of a window counts (a spike on a steep slope shifts its
    neighbours' medians too), and a second pass catches a spike two samples wide.
    """
    from scipy.ndimage import maximum_filter1d, median_filter

    clean = values.copy()
    outliers = np.zeros(len(values), dtype=bool)
    for _ in range(2):
        median = np.asarray(median_filter(clean, size=5, mode="nearest"), dtype=float)
        deviation = np.abs(clean - median)
        spike = (deviation > threshold) & (deviation >= maximum_filter1d(deviation, 5))
        clean = np.where(spike, median, clean)
        outliers |= spike
    return clean, outliers


def odd_at_least(n: float, least: int) -> int:
    return max(least, round(n) | 1)


def prepare_trace(
    trace: Trace, index: int, warnings: list[str], label: str | None = None
) -> PreparedTrace:
    from scipy.ndimage import median_filter
    from scipy.signal import savgol_filter

    label = label or _label(trace, index)
    t, x, f = _columns(trace, label)
    _check(label, t, x, f)
    # The sensors' measurement models: noise and resolution. A 0.05 mm encoder's stairs have no
    # noise between them: with its noise alone (0) every step was an "outlier", the plateau's
    # band was 2 um and the ring's sigma 0.
    noise_x, step_x, noise_f, step_f = noise_sigma(x), resolution(x), noise_sigma(f), resolution(f)
    sigma_x = math.hypot(noise_x, step_x / math.sqrt(12.0))
    sigma_f = math.hypot(noise_f, step_f / math.sqrt(12.0))
    x, out_x = _despike(x, 10.0 * sigma_x + 1e-5)
    f, out_f = _despike(f, 10.0 * sigma_f + 0.05 * float(np.percentile(np.abs(f), 99)))
    outliers = out_x | out_f
    if outliers.any():
        warnings.append(
            f"{label}: {int(outliers.sum())} outlier sample(s) replaced by the median of their "
            "neighbours and left out of the fits and figures"
        )
    steps = np.diff(t)
    dt = float(np.median(steps))
    gaps = steps > 2.0 * dt
    if gaps.any():
        warnings.append(
            f"{label}: {int(gaps.sum())} gap(s) in the samples, the longest "
            f"{steps.max() * 1e3:.3g} ms; bridged linearly for the segmentation, the force "
            "interpolated across them in the simulations"
        )
    grid = t[0] + dt * np.arange(int((t[-1] - t[0]) / dt + 1e-9) + 1)
    xg = np.interp(grid, t, x)
    fg = np.interp(grid, t, f)
    x_med = np.asarray(median_filter(xg, size=5, mode="nearest"), dtype=float)
    f_med = np.asarray(median_filter(fg, size=5, mode="nearest"), dtype=float)
    window = min(odd_at_least(0.007 / dt, 5), len(grid) - 1 + len(grid) % 2)
    x_smooth = np.asarray(savgol_filter(x_med, window, 2, mode="interp"), dtype=float)
    f_smooth = np.asarray(savgol_filter(f_med, window, 2, mode="interp"), dtype=float)
    f_wide = np.asarray(
        median_filter(fg, size=odd_at_least(STILL_WINDOW_S / dt, 5), mode="nearest"), dtype=float
    )
    return PreparedTrace(
        label, index, t, x, f, ~outliers, sigma_x, sigma_f, dt, grid, x_med, f_med, x_smooth,
        f_smooth, f_wide, step_x, step_f, noise_x, noise_f,
    )  # fmt: skip


def window_indices(tr: PreparedTrace, start_s: float, end_s: float) -> npt.NDArray[np.intp]:
    """Indices of the trace's kept samples with start_s <= t <= end_s."""
    inside = (tr.time_s >= start_s) & (tr.time_s <= end_s) & tr.keep
    return np.flatnonzero(inside)


# --- segmentation ------------------------------------------------------------------------------


def true_runs(mask: BoolArray) -> list[tuple[int, int]]:
    """[start, end) of each run of True."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    return [(int(a), int(b)) for a, b in zip(starts, ends, strict=True)]


def _plateaus(tr: PreparedTrace) -> tuple[list[tuple[int, int]], float, float]:
    """Plateaus [a, b) on the grid, the band's half-width (m) and the high force (N)."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    dt, x, f = tr.dt_s, tr.x_med, tr.f_med
    band = max(NOISE_BAND * tr.sigma_m, tr.resolution_m, BAND_FLOOR_M)  # a quantum's flicker
    n_still = odd_at_least(STILL_WINDOW_S / dt, 5)
    spread = maximum_filter1d(x, n_still) - minimum_filter1d(x, n_still)
    f_high = max(HIGH_FORCE_FRACTION * float(tr.f_wide.max()), 5.0 * tr.sigma_N)
    f_positive = 3.0 * tr.sigma_N
    cores: list[tuple[int, int]] = []
    for a, b in true_runs((spread <= 2.0 * band) & (f >= f_high)):
        if cores:  # a noisy sample may split a plateau: join the parts
            pa, pb = cores[-1]
            same = abs(float(np.median(x[pa:pb])) - float(np.median(x[a:b]))) <= band
            if a - pb <= n_still and same:
                cores[-1] = (pa, b)
                continue
        cores.append((a, b))
    plateaus: list[tuple[int, int]] = []
    for k, (a, b) in enumerate(cores):
        centre = float(np.median(x[a:b]))
        floor = plateaus[-1][1] if plateaus else 0
        while a - 1 >= floor and abs(x[a - 1] - centre) <= band and f[a - 1] > f_positive:
            a -= 1
        while b < len(x) and abs(x[b] - centre) <= band and f[b] > f_positive:
            b += 1
        if (b - a) * dt < MIN_PLATEAU_S:
            continue
        following = cores[k + 1][0] if k + 1 < len(cores) else len(x)
        if following <= b or x[b:following].max() < centre + MIN_TRAVEL_M:
            continue  # nothing moves on toward the gear: a push against the stop, or a balk
        plateaus.append((a, b))
    return plateaus, band, f_high


def _arrival(tr: PreparedTrace, first_s: float, centre: float, band: float) -> float:
    """When the knob reached `centre`: a line through its approach, or the first still sample."""
    idx = window_indices(tr, first_s - APPROACH_S, first_s)
    x = tr.position_m[idx]
    idx = idx[(x <= centre - max(band, 5e-5)) & (x >= centre - 2e-3)][-6:]
    if len(idx) < 2:
        return first_s
    slope, offset = np.polyfit(tr.time_s[idx], tr.position_m[idx], 1)
    if slope <= 0.0:
        return first_s
    t = float((centre - offset) / slope)
    return t if abs(t - first_s) <= 2.0 * tr.dt_s else first_s


def _sign_hint(tr: PreparedTrace) -> str:
    """How to fix a trace with no engagement: the sign flip under which it has some, if any."""
    for x_sign, f_sign, what in ((1.0, -1.0, "force_N"), (-1.0, -1.0, "position_m and force_N")):
        flipped = replace(tr, x_med=x_sign * tr.x_med, f_med=f_sign * tr.f_med,
                          f_wide=f_sign * tr.f_wide)  # fmt: skip
        found = len(_plateaus(flipped)[0])
        if found:
            return (
                f"with the sign of {what} flipped it holds {found} engagement(s): carfeel's force "
                "is + pushing toward the gear and its position + toward the gear; flip the sign "
                "(scale = -1 in a channel map)"
            )
    return (
        "check that the trace holds a push into gear, position_m in m (+ toward the gear) and "
        "force_N in N (+ pushing toward the gear)"
    )


def segment_engagements(tr: PreparedTrace, warnings: list[str]) -> list[FoundEngagement]:
    from scipy.signal import find_peaks

    plateaus, band, f_high = _plateaus(tr)
    if not plateaus:
        raise InputError(
            f"{tr.label}: no engagement found: no stretch of at least {MIN_PLATEAU_S * 1e3:.0f} "
            f"ms where the knob stays within +-{band * 1e3:.2g} mm while pushed with more than "
            f"{f_high:.3g} N, and then moves on at least {MIN_TRAVEL_M * 1e3:g} mm toward the "
            "gear; " + _sign_hint(tr)
        )
    g, x, f, dt = tr.grid_s, tr.x_med, tr.f_med, tr.dt_s
    found: list[FoundEngagement] = []
    for k, (a, b) in enumerate(plateaus):
        end = plateaus[k + 1][0] if k + 1 < len(plateaus) else len(g)
        where = f"{tr.label}, engagement at {g[a]:.3f} s"
        centre = float(np.median(x[a:b]))
        force = float(np.median(f[a + (b - a) // 2 : b]))
        i_max = b + int(np.argmax(tr.x_smooth[b:end]))
        x_max = float(tr.x_smooth[i_max])
        f_low = max(5.0 * tr.sigma_N, LOW_FORCE_FRACTION * force)
        after = np.arange(i_max, end)
        back = after[(f[after] < -f_low) | (x[after] < 0.5 * (x_max + centre))]
        i_back = int(back[0]) if back.size else end
        rest = np.arange(i_max, i_back)
        rest = rest[np.abs(f[rest]) <= f_low]
        if rest.size * dt >= 0.01:
            settled = float(np.median(x[rest]))
        else:
            tail = x[max(i_max, i_back - max(3, round(0.02 / dt))) : i_back]
            settled = float(np.median(tail)) if tail.size else x_max
            warnings.append(
                f"{where}: the driver never let go in gear; the settled position "
                f"({settled * 1e3:.2f} mm) is taken while pushed"
            )
        settled = min(settled, x_max)
        reach = np.flatnonzero(x[b : i_max + 1] >= settled)
        i_reach = b + int(reach[0]) if reach.size else i_max
        falling = np.flatnonzero(f[b:i_reach] < 0.5 * force)
        i_from = b + int(falling[0]) if falling.size else i_reach
        peak_force = peak_position = math.nan
        if i_reach - i_from >= 3:
            segment = tr.f_smooth[i_from:i_reach]
            peaks, _ = find_peaks(segment, prominence=max(3.0 * tr.sigma_N, 1e-9))
            if peaks.size:
                top = i_from + int(peaks[np.argmax(segment[peaks])])
                peak_force, peak_position = float(tr.f_smooth[top]), float(tr.x_smooth[top])
        if math.isnan(peak_force):
            warnings.append(f"{where}: no tooth peak between the synchronization and the stop")
        pulled = np.flatnonzero(f[i_max:end] < -f_low)
        stop_end = float(g[min(i_max + int(pulled[0]) if pulled.size else end, len(g) - 1)])
        features = EngagementFeatures(
            trace=tr.index,
            start_time_s=_arrival(tr, float(g[a]), centre, band),
            synchronization_position_m=centre,
            plateau_force_N=force,
            plateau_duration_s=float(g[b - 1] - g[a]),
            tooth_peak_force_N=peak_force,
            tooth_peak_position_m=peak_position,
            stop_position_m=x_max,
            settled_position_m=settled,
            overshoot_m=x_max - settled,
        )
        stop_end = min(stop_end, float(g[i_reach]) + STOP_WINDOW_S)
        # The knob at rest in gear before a pull: a state known again, for `_resimulate`.
        pull_s = pull_x = math.nan
        if rest.size * dt >= 0.01 and back.size and f[i_back] < -f_low:
            pull_s, pull_x = float(g[rest[-1]]), float(x[rest[-1]])
        found.append(FoundEngagement(tr, features, float(g[b - 1]), float(g[i_reach]), stop_end,
                            pull_s, pull_x))  # fmt: skip
    return found
