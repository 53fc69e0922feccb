"""Conditioning of measured signals for the fits: gap-free stretches, zero-phase low-pass,
a sensor's noise and resolution, an adaptive derivative, and a vectorized linear recurrence.

The adaptive derivative (`adaptive_derivative`) is the errors-in-variables answer for a rate made
from a measured angle (issue 25): the angle of a real car is quantized (0.1 deg on a Lincoln MKZ,
1.5 deg on a RAV4 without its fraction signal) and noisy, and a fixed-window derivative either
follows the quantization's stairs (a wheel turning 1 deg/s crosses a 0.1 deg step every 0.1 s:
the rate comes out as pulses, zero between them) or rounds off quick steers. Near a reversal the
stairs flatten the rate into a dead band, exactly where the friction's atan(rate / K8) changes
sign: a fixed 81 ms window took K8 16 % high at 5 sigma on the acceptance logs. Local quadratic
fits (Savitzky-Golay) over windows from 21 ms to 1.28 s are compared at every sample and the
widest whose estimate agrees with every narrower one within their noise (the intersection of
confidence intervals rule, Katkovnik 1999; Goldenshluger and Nemirovski 1997) is taken: wide where
the steering is smooth (a reversal, a slow ramp: many stairs averaged), narrow at a quick steer.
The noise each window's estimate carries comes from the measurement model: the sensor's own noise
(the MAD of second differences) and its resolution's q^2 / 12.
"""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

ICI_WINDOWS_S = (0.021, 0.041, 0.081, 0.161, 0.321, 0.641, 1.281)
"""The derivative's candidate windows (about 2x apart)."""
ICI_MEDIAN = 5
"""Samples of the running median over the chosen windows (module text at its use)."""
ICI_GAMMA = 3.0
"""Half-width of the confidence intervals, in sigmas of each window's noise. Measured on the
acceptance logs (0.1 deg steps, 0.02 deg of noise; K8 against the truth): 1.5 sigmas +94 %
(narrow windows chosen on noise), 2 +38 %, 3 +0.0 %, 4 -3.1 %, 6 -3.7 % (quick steers rounded)."""


def stretches(time_s: FloatArray) -> list[tuple[int, int]]:
    """[start, end) of each gap-free stretch: cut where a step exceeds 1.5 median steps."""
    steps = np.diff(time_s)
    dt = float(np.median(steps)) if len(steps) else 1.0
    cuts = np.concatenate([[0], np.flatnonzero(steps > 1.5 * dt) + 1, [len(time_s)]])
    return [(int(a), int(b)) for a, b in itertools.pairwise(cuts)]


def lowpass(time_s: FloatArray, values: FloatArray, cutoff_hz: float) -> FloatArray:
    """Zero-phase 4th-order Butterworth low-pass (forward and back: 8th-order magnitude, 0.4 %
    down at half the corner), per gap-free stretch; the corner is kept under 40 % of the sample
    rate. Stretches too short to filter pass as they are."""
    from scipy.signal import butter, sosfiltfilt

    out = np.array(values, dtype=float, copy=True)
    dt = float(np.median(np.diff(time_s)))
    sos = butter(4, min(cutoff_hz, 0.4 / dt), fs=1.0 / dt, output="sos")
    for a, b in stretches(time_s):
        if b - a > 30:
            out[a:b] = sosfiltfilt(sos, values[a:b])
    return out


def noise_sigma(values: FloatArray) -> float:
    """White noise of a signal from its second differences (their variance is 6 sigma^2; the
    median ignores where the signal itself moves)."""
    if len(values) < 3:
        return 0.0
    second = np.diff(values, 2)
    return 1.4826 * float(np.median(np.abs(second - np.median(second)))) / math.sqrt(6.0)


def resolution(values: FloatArray) -> float:
    """The step a quantized signal moves in (0 if it is not quantized): every change between
    samples an integer multiple of the smallest usual one (its 5th percentile), 99 % of them
    within 0.1 % of a multiple; with 20 changes at least."""
    changes = np.abs(np.diff(values))
    changes = changes[changes > 1e-12 * max(float(np.max(np.abs(values))), 1e-300)]
    if changes.size < 20:
        return 0.0
    step = float(np.percentile(changes, 5))
    if not step > 0.0:
        return 0.0
    ratio = changes / step
    if np.mean(np.abs(ratio - np.round(ratio)) < 1e-3) < 0.99:
        return 0.0
    return step


def measurement_sigma(values: FloatArray) -> float:
    """One sample's error: the sensor's noise and its resolution's uniform q^2 / 12."""
    step = resolution(values)
    return math.sqrt(noise_sigma(values) ** 2 + step * step / 12.0)


def adaptive_derivative(
    time_s: FloatArray, values: FloatArray, deriv: int = 1, sigma: float | None = None,
    windows_s: tuple[float, ...] = ICI_WINDOWS_S, gamma: float = ICI_GAMMA,
) -> FloatArray:  # fmt: skip
    """The signal (deriv 0) or its rate (deriv 1) by local quadratic fits whose window is chosen
    per sample by the intersection of confidence intervals (module docstring), per gap-free
    stretch; `sigma` the measurement's error (default `measurement_sigma`)."""
    return adaptive_estimate(time_s, values, deriv, sigma, windows_s, gamma)[0]


def adaptive_estimate(
    time_s: FloatArray, values: FloatArray, deriv: int = 1, sigma: float | None = None,
    windows_s: tuple[float, ...] = ICI_WINDOWS_S, gamma: float = ICI_GAMMA,
) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """`adaptive_derivative` and its error at every sample (one standard deviation): the chosen
    window's noise and its smoothing bias, a third of how far the next wider window's estimate
    lies from it (a quadratic fit's bias grows with the window squared: twice the window, four
    times the bias). Large where nothing resolves the signal (a rate that jumps within a sample
    at a steer cycle's reversal, where no window is narrow enough)."""
    from scipy.ndimage import median_filter

    out = np.zeros_like(values, dtype=float) if deriv else np.array(values, dtype=float)
    spread_out = np.zeros_like(out)
    if len(values) < 3:
        return out, spread_out
    dt = float(np.median(np.diff(time_s)))
    error = measurement_sigma(values) if sigma is None else sigma
    for a, b in stretches(time_s):
        piece = values[a:b]
        sizes = sorted({max(5, round(w / dt) | 1) for w in windows_s})
        sizes = [n for n in sizes if n <= b - a]
        if not sizes:
            if deriv and b - a > 1:
                out[a:b] = np.gradient(piece, time_s[a:b])
            continue
        estimates, spreads = [], []
        for n in sizes:
            estimates.append(_savgol(piece, n, deriv, dt))
            spreads.append(_savgol_noise(n, deriv, dt, b - a) * error)
        est = np.array(estimates)
        noise = np.array(spreads)
        half = gamma * noise
        low = np.maximum.accumulate(est - half, axis=0)
        high = np.minimum.accumulate(est + half, axis=0)
        agreed = np.cumprod(low <= high, axis=0).astype(bool)
        chosen = np.maximum(agreed.sum(axis=0) - 1, 0)
        # A narrow window picked at one sample among wide ones is the rule's false alarm (its
        # intervals miss each other by chance, about 1 sample in 500): a rate spike from noise.
        # A quick steer's narrow picks span its samples; a running median keeps those.
        chosen = np.asarray(median_filter(chosen, size=ICI_MEDIAN, mode="nearest"))
        columns = np.arange(b - a)
        out[a:b] = est[chosen, columns]
        wider = np.minimum(chosen + 1, len(sizes) - 1)
        bias = np.abs(est[wider, columns] - out[a:b]) / 3.0
        spread_out[a:b] = np.sqrt(noise[chosen, columns] ** 2 + bias**2)
    return out, spread_out


@functools.cache
def _savgol_noise(window: int, deriv: int, dt: float, length: int) -> FloatArray:
    """Per sample of a stretch, the standard deviation of `_savgol`'s estimate for unit white
    noise: the centred filter's inside, and at each end the polynomial fitted to the first (last)
    window evaluated off its centre (mode 'interp'), whose error grows toward the end (the
    centred figure there made the adaptive window's intervals too narrow: false rate spikes at
    every log's first and last samples)."""
    from scipy.signal import savgol_coeffs

    centre = float(np.sqrt(np.sum(savgol_coeffs(window, 2, deriv=deriv, delta=dt, use="dot") ** 2)))
    out = np.full(length, centre)
    half = window // 2
    for position in range(min(half, length)):
        weights = savgol_coeffs(window, 2, deriv=deriv, delta=dt, pos=position, use="dot")
        spread = float(np.sqrt(np.sum(weights**2)))
        out[position] = spread
        if length - 1 - position >= half:
            out[length - 1 - position] = spread
    return out


def _savgol(values: FloatArray, window: int, deriv: int, dt: float) -> FloatArray:
    """scipy's quadratic Savitzky-Golay filter (mode 'interp'), by overlap-add FFT convolution
    for long windows (a 1.28 s window over 10 minutes at 1 kHz: 0.8e9 products directly)."""
    from scipy.signal import oaconvolve, savgol_coeffs, savgol_filter

    if window <= 65 or len(values) < 4 * window:
        return np.asarray(savgol_filter(values, window, 2, deriv=deriv, delta=dt, mode="interp"))
    out = np.asarray(oaconvolve(values, savgol_coeffs(window, 2, deriv=deriv, delta=dt),
                                mode="same"))  # fmt: skip
    half = window // 2
    ends = (values[:window], values[-window:])
    out[:half] = savgol_filter(ends[0], window, 2, deriv=deriv, delta=dt, mode="interp")[:half]
    out[-half:] = savgol_filter(ends[1], window, 2, deriv=deriv, delta=dt, mode="interp")[-half:]
    return out


RECURRENCE_BLOCK = 16
"""Samples solved at once by `linear_recurrence`."""
RESET_LOG_DECAY = -40.0
"""A step's decay below exp(-40) (4e-18) is a reset: taken as that, so a block's factors stay
within exp(+-640) and never overflow."""


def linear_recurrence(log_decay: FloatArray, drive: FloatArray) -> FloatArray:
    """y_k = exp(log_decay_k) y_(k-1) + drive_k from y_(-1) = 0, vectorized: within blocks of
    RECURRENCE_BLOCK samples y_k = e^(L_k) sum_(j<=k) drive_j e^(-L_j) with L the block's
    cumulative log decay (the recent terms dominate the sum, so its rounding is relative to
    y_k), the blocks' ends carried one to the next. log_decay <= 0; -inf is a reset."""
    n = len(drive)
    if n == 0:
        return np.zeros(0)
    size = RECURRENCE_BLOCK
    blocks = -(-n // size)
    pad = blocks * size - n
    la = np.concatenate([np.maximum(log_decay, RESET_LOG_DECAY), np.zeros(pad)])
    cumulative = np.cumsum(la.reshape(blocks, size), axis=1)
    b = np.concatenate([drive, np.zeros(pad)]).reshape(blocks, size)
    decay = np.exp(cumulative)
    local = decay * np.cumsum(b * np.exp(-cumulative), axis=1)
    ends, factors = local[:, -1], cumulative[:, -1]
    if blocks <= 64:
        carried = np.empty(blocks)
        state = 0.0
        for i, (end, factor) in enumerate(zip(ends.tolist(), np.exp(factors).tolist(),
                                              strict=True)):  # fmt: skip
            carried[i] = state
            state = end + factor * state
    else:  # the blocks' ends are a recurrence of their own
        carried = np.concatenate([[0.0], linear_recurrence(factors, ends)[:-1]])
    return np.asarray((local + decay * carried[:, None]).reshape(-1)[:n])
