"""How stiff and how damped a rendering can be on a given device, from its rate, delays and
dynamics: the sizing of every coupling, servo, wall and damper the renderers put on a device.

The passivity bound (Colgate & Schenkel 1997; Diolaiti et al., IEEE T-RO 2006) for a virtual
spring K and damper B rendered at period T through a transport delay t_d is

    b > K * (T/2 + t_d) + B          (b: the device's own damping)

It holds for any passive hand, and it is what `passivity_index` reports. It ignores the
device's mass, which is what keeps a device with little damping (a direct-drive wheel) stable
against a spring well beyond that bound, and it cannot see what the velocity filter's lag and
the report rate cost. So the sizing here goes further: each axis is written as a discrete-time
linear system, exact at the loop's ticks:

    device      m*v' = u(t - t_c) - b*v       (zero-order hold over each tick: exact)
    reading     y_k = x(k*T - t_r), plus half a report period when reports are slower
    velocity    the renderer's own filter on (y_k - y_{k-1}) / T
    rendering   u_k = environment(y_k, v_k)   (linearized: a spring and damper, or the car)

with the delays rounded up to whole ticks (conservative), and the least damping ratio of its
poles is computed (`least_damping_ratio`). A rendering is offered on a device only where that
ratio is at least ZETA_MIN with no hand on the device: a released device then comes to rest.
What a hand adds (damping, mass) only helps. Quantization and sensor noise are bounded
separately: a gain times the reading's noise must stay below NOISE_FRACTION of the force limit.
This runs once at start-up (numpy and scipy are fine there); nothing here runs per tick.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from carfeel.realtime.devices.base import DeviceInfo

ZETA_MIN = 0.2
"""Least damping ratio of the hands-off loop a rendering must keep."""
NOISE_FRACTION = 0.015
"""A gain's share of the force limit from the reading's noise (3 sigma each way): 1.5 % keeps
the command's ripple at rest well below the 5 % a hand would feel as buzz."""

Sections = tuple[tuple[float, float, float, float, float], ...]
Environment = Callable[[Any, float, float], tuple[Any, float]]
"""(state, y, v) -> (next state, command): linear in all of its arguments."""


@dataclass(frozen=True, slots=True)
class AxisLoop:
    """One axis of a device inside the loop, device units."""

    mass: float
    damping: float
    rate_hz: float
    command_ticks: int
    reading_ticks: int
    velocity_sections: Sections

    @classmethod
    def of(cls, info: DeviceInfo, rate_hz: float, velocity_sections: Sections) -> AxisLoop:
        period = 1.0 / rate_hz
        hold = max(0.0, 0.5 / info.report_hz - 0.5 * period)
        return cls(
            mass=info.mass,
            damping=info.damping,
            rate_hz=rate_hz,
            command_ticks=math.ceil(info.command_delay_s / period - 1e-6),
            reading_ticks=math.ceil((info.reading_delay_s + hold) / period - 1e-6),
            velocity_sections=velocity_sections,
        )


@functools.lru_cache(maxsize=64)
def _device_step(mass: float, damping: float, period: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretization of m*v' = u - b*v: (Phi, Gamma). Cached: a sizing
    builds hundreds of loops of one device (the arrays are never written to)."""
    from scipy.linalg import expm

    a = np.array([[0.0, 1.0, 0.0], [0.0, -damping / mass, 1.0 / mass], [0.0, 0.0, 0.0]])
    e = expm(a * period)
    return e[:2, :2], e[:2, 2]


def closed_loop(axis: AxisLoop, environment: Environment, environment_size: int) -> np.ndarray:
    """The matrix of the hands-off loop over one tick (see the module's docstring)."""
    period = 1.0 / axis.rate_hz
    phi, gamma = _device_step(axis.mass, axis.damping, period)
    nr, nc, ns = axis.reading_ticks, axis.command_ticks, len(axis.velocity_sections)
    n = 2 + nr + nc + 1 + 2 * ns + environment_size

    def step(z: np.ndarray) -> np.ndarray:
        x, v = z[0], z[1]
        past_x = z[2 : 2 + nr]
        past_u = z[2 + nr : 2 + nr + nc]
        y_prev = z[2 + nr + nc]
        filt = z[3 + nr + nc : 3 + nr + nc + 2 * ns]
        env = z[3 + nr + nc + 2 * ns :]
        y = past_x[nr - 1] if nr else x
        signal = (y - y_prev) / period
        new_filt = []
        for i, (b0, b1, b2, a1, a2) in enumerate(axis.velocity_sections):
            z0, z1 = filt[2 * i], filt[2 * i + 1]
            out = b0 * signal + z0
            new_filt += [b1 * signal - a1 * out + z1, b2 * signal - a2 * out]
            signal = out
        env_next, u = environment(env, y, signal)
        applied = past_u[nc - 1] if nc else u
        dev = phi @ np.array([x, v]) + gamma * applied
        return np.concatenate(
            [
                dev,
                np.concatenate([[x], past_x[:-1]]) if nr else [],
                np.concatenate([[u], past_u[:-1]]) if nc else [],
                [y],
                new_filt,
                np.asarray(env_next, dtype=float).reshape(environment_size),
            ]
        )

    return np.column_stack([step(column) for column in np.eye(n)])


def least_damping_ratio(matrix: np.ndarray, rate_hz: float) -> float:
    """The smallest damping ratio of the loop's poles (negative: it grows). Poles at the
    origin (pure delays) and at z = 1 (a free handle at rest anywhere) are not oscillations."""
    worst = 1.0
    for z in np.linalg.eigvals(matrix):
        if abs(z) < 1e-9:
            continue
        s = complex(np.log(z)) * rate_hz
        if abs(s) < 1e-6:
            continue
        worst = min(worst, -s.real / abs(s))
    return worst


def spring_damper(stiffness: float, damping: float) -> Environment:
    """u = -K*y - B*v: a coupling to a lever that stands still, a wall, a hold."""

    def environment(state: Any, y: float, v: float) -> tuple[Any, float]:
        return state, -stiffness * y - damping * v

    return environment


def zeta_of(axis: AxisLoop, stiffness: float, damping: float) -> float:
    return least_damping_ratio(
        closed_loop(axis, spring_damper(stiffness, damping), 0), axis.rate_hz
    )


def _bisect(ok: Callable[[float], bool], low: float, high: float, iterations: int = 40) -> float:
    """The largest value in [low, high] for which `ok` holds, assuming it holds at `low`."""
    if ok(high):
        return high
    for _ in range(iterations):
        middle = math.sqrt(low * high) if low > 0.0 else 0.5 * high
        low, high = (middle, high) if ok(middle) else (low, middle)
    return low


@dataclass(frozen=True, slots=True)
class Sizing:
    """What a device can render hands-off, device units (N/m and N*s/m, or Nm/rad ...)."""

    stiffness: float
    """Largest spring (coupling, servo, wall) with a damping ratio of ZETA_MIN at least."""
    damping: float
    """The damping that goes with it (on the handle's filtered velocity)."""
    damping_cap: float
    """Largest velocity gain of any rendered damper (alone), the cap on every one."""
    zeta: float
    """Least damping ratio of the loop with that spring and damper, hands off."""
    latency_s: float
    passivity_index: float
    """(K*(T/2 + t_d) + B) / b: below 1 the rendering is passive for any hand."""


def noise_caps(info: DeviceInfo, rate_hz: float) -> tuple[float, float]:
    """Largest stiffness and velocity gain whose answer to the reading's noise (3 sigma) stays
    within NOISE_FRACTION of the force limit (the velocity is a difference over one tick, its
    noise reduced by the filter, about sqrt(cutoff / Nyquist) for the 50 Hz filter at 1 kHz)."""
    sigma = math.hypot(info.noise, info.resolution / math.sqrt(12.0))
    if sigma <= 0.0:
        return math.inf, math.inf
    budget = NOISE_FRACTION * info.max_force / 3.0
    velocity_sigma = sigma * math.sqrt(2.0) * rate_hz * math.sqrt(min(1.0, 100.0 / rate_hz))
    return budget / sigma, budget / velocity_sigma


@functools.lru_cache(maxsize=64)
def size(
    info: DeviceInfo, rate_hz: float, velocity_sections: Sections, zeta_min: float = ZETA_MIN
) -> Sizing:
    """The stiffest spring (and its damper) the device renders with zeta >= zeta_min."""
    axis = AxisLoop.of(info, rate_hz, velocity_sections)
    k_noise, b_noise = noise_caps(info, rate_hz)
    tiny = 1e-6 * info.max_force / max(info.travel, 1e-9)
    b_high = min(b_noise, 10.0 * info.mass * rate_hz)
    damping_cap = _bisect(lambda b: zeta_of(axis, tiny, b) >= zeta_min, 0.0, b_high)
    k_high = min(k_noise, info.mass * (math.pi * rate_hz) ** 2)
    best = (0.0, 0.0)
    for fraction in (0.0, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8):
        b = fraction * damping_cap
        if zeta_of(axis, tiny, b) < zeta_min:
            continue

        def stable(k: float, b: float = b) -> bool:
            return zeta_of(axis, k, b) >= zeta_min

        k = _bisect(stable, tiny, k_high, 30)
        if k > best[0]:
            best = (k, b)
    k, b = best
    period = 1.0 / rate_hz
    passivity = (
        (k * (0.5 * period + info.latency_s) + b) / info.damping if info.damping > 0 else math.inf
    )
    return Sizing(k, b, damping_cap, zeta_of(axis, k, b), info.latency_s, passivity)
