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

import bisect
import dataclasses
import functools
import itertools
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
    """One axis of a device inside the loop, device units. The whole round trip (commands
    and readings, plus the report's hold in whole ticks) is put on the command side: in a
    linear loop only the delay around it matters, and a fractional delay is discretized
    exactly (the hold over a tick splits between two commands)."""

    mass: float
    damping: float
    rate_hz: float
    delay_ticks: int
    """Whole ticks of delay around the loop."""
    delay_fraction: float
    """The rest, 0 <= fraction < 1 of a tick."""
    velocity_sections: Sections
    stiffness: float = 0.0
    """The device's own centring spring (or a grip on it), N/m or Nm/rad."""
    hand: tuple[float, float, float, float] | None = None
    """A hand on the handle (device units): its mass, its grip's stiffness and damping to the
    handle, and the damping its muscle puts on the hand's own velocity; None: hands off."""

    @classmethod
    def of(
        cls,
        info: DeviceInfo,
        rate_hz: float,
        velocity_sections: Sections,
        mass: float | None = None,
        damping: float | None = None,
        round_trip_s: float | None = None,
    ) -> AxisLoop:
        """The axis as `info` describes it, or with another mass, damping or round trip."""
        period = 1.0 / rate_hz
        hold = max(0.0, 0.5 / info.report_hz - 0.5 * period)
        trip = info.round_trip_s if round_trip_s is None else round_trip_s
        ticks = trip / period + 1e-9
        whole = math.floor(ticks)
        fraction = ticks - whole
        if fraction < 1e-6:
            fraction = 0.0
        return cls(
            mass=info.mass if mass is None else mass,
            damping=info.damping if damping is None else damping,
            rate_hz=rate_hz,
            delay_ticks=whole + math.ceil(hold / period - 1e-6),
            delay_fraction=fraction,
            velocity_sections=velocity_sections,
            stiffness=info.stiffness,
        )


def plant_set(info: DeviceInfo, rate_hz: float, sections: Sections) -> tuple[AxisLoop, ...]:
    """The plants a rendering must be stable on: the one `info` describes and, where it says
    how uncertain that is (`mass_range`, `damping_range`, `delay_range_s`), the corners where a
    loop is least damped: the least damping with the longest delay, at the lightest and at the
    heaviest mass, and the lightest mass with the shortest delay (`tests/test_stability.py`
    samples the inside of the set against these)."""
    nominal = AxisLoop.of(info, rate_hz, sections)
    if info.mass_range is None and info.damping_range is None and info.delay_range_s is None:
        return (nominal,)
    light, heavy = info.mass_range or (info.mass, info.mass)
    least = (info.damping_range or (info.damping, info.damping))[0]
    short, long = info.delay_range_s or (info.round_trip_s, info.round_trip_s)
    corners = {nominal}
    for mass, trip in ((light, long), (heavy, long), (light, short)):
        corners.add(AxisLoop.of(info, rate_hz, sections, mass, least, trip))
    if info.stiffness > 0.0:
        # A spring measured on the device may be a hand that lets go: the free device too.
        corners |= {dataclasses.replace(a, stiffness=0.0) for a in list(corners)}
    return tuple(sorted(corners, key=lambda a: (a.mass, a.damping, a.delay_ticks, a.stiffness)))


def own_damping_ratio(axis: AxisLoop) -> float:
    """The least damping ratio of the device alone in the loop (nothing rendered): 1 for a
    free handle (no oscillation), its own spring's mode's ratio where it has one."""
    return zeta_of(axis, 0.0, 0.0)


ZETA_FLOOR = 0.05
"""The least a rendering keeps where the device alone is less damped than ZETA_MIN."""


def goal_of(axis: AxisLoop, zeta_min: float) -> float:
    """What a rendering must keep on this plant: zeta_min; where the device alone is less
    damped (a stiff grip on a light rim, whose mode the rendering cannot damp through its
    delay), ZETA_FLOOR, or half the device's own ratio where even that is above it."""
    own = own_damping_ratio(axis)
    return min(zeta_min, max(min(ZETA_FLOOR, own - 0.005), 0.5 * own))


@functools.lru_cache(maxsize=128)
def _device_step(
    mass: float,
    damping: float,
    stiffness: float,
    period: float,
    fraction: float,
    hand: tuple[float, float, float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretization of m*x'' = u - b*x' - k*x (and of a hand held to
    the handle by its grip, when given) with the input held `fraction` of a tick late: (Phi,
    Gamma for this tick's command, Gamma for the one before); the state (x, v[, x_h, v_h]).
    Cached: a sizing builds hundreds of loops of one device (the arrays are never written to)."""
    from scipy.linalg import expm

    if hand is None:
        a = np.array(
            [[0.0, 1.0, 0.0], [-stiffness / mass, -damping / mass, 1.0 / mass], [0.0, 0.0, 0.0]]
        )
    else:
        m_h, k_h, c_h, c_m = hand
        a = np.array(
            [
                [0.0, 1.0, 0.0, 0.0, 0.0],
                [-(stiffness + k_h) / mass, -(damping + c_h) / mass, k_h / mass, c_h / mass,
                 1.0 / mass],
                [0.0, 0.0, 0.0, 1.0, 0.0],
                [k_h / m_h, c_h / m_h, -k_h / m_h, -(c_h + c_m) / m_h, 0.0],
                [0.0, 0.0, 0.0, 0.0, 0.0],
            ]
        )  # fmt: skip
    n = a.shape[0] - 1
    whole = expm(a * period)
    if fraction <= 0.0:
        return whole[:n, :n], whole[:n, n], np.zeros(n)
    late = expm(a * (1.0 - fraction) * period)  # the current command over the tick's end
    early = expm(a * fraction * period)  # the previous one over its start
    # The previous command acts first, then the state moves on under the current one.
    previous = late[:n, :n] @ early[:n, n]
    return whole[:n, :n], late[:n, n], previous


def closed_loop(axis: AxisLoop, environment: Environment, environment_size: int) -> np.ndarray:
    """The matrix of the hands-off loop over one tick (see the module's docstring)."""
    period = 1.0 / axis.rate_hz
    phi, gamma, gamma_previous = _device_step(
        axis.mass, axis.damping, axis.stiffness, period, axis.delay_fraction, axis.hand
    )
    d = len(gamma)
    fractional = axis.delay_fraction > 0.0
    nc = axis.delay_ticks + (1 if fractional else 0)
    ns = len(axis.velocity_sections)
    n = d + nc + 1 + 2 * ns + environment_size

    def step(z: np.ndarray) -> np.ndarray:
        x = z[0]
        past_u = z[d : d + nc]
        y_prev = z[d + nc]
        filt = z[d + 1 + nc : d + 1 + nc + 2 * ns]
        env = z[d + 1 + nc + 2 * ns :]
        y = x
        signal = (y - y_prev) / period
        new_filt = []
        for i, (b0, b1, b2, a1, a2) in enumerate(axis.velocity_sections):
            z0, z1 = filt[2 * i], filt[2 * i + 1]
            out = b0 * signal + z0
            new_filt += [b1 * signal - a1 * out + z1, b2 * signal - a2 * out]
            signal = out
        env_next, u = environment(env, y, signal)
        whole = axis.delay_ticks
        applied = past_u[whole - 1] if whole else u
        dev = phi @ z[:d] + gamma * applied
        if fractional:
            dev = dev + gamma_previous * past_u[whole]
        return np.concatenate(
            [
                dev,
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


def spring_damper_integral(stiffness: float, damping: float, ticks: float) -> Environment:
    """u = -K*(y - e) - B*v with e_next = e - y/ticks: a spring whose zero moves back by the
    stretch over `ticks` (integral action: the wall's feed-forward of the push it holds)."""

    def environment(state: Any, y: float, v: float) -> tuple[Any, float]:
        e = np.asarray(state, dtype=float).reshape(-1)[0]
        return [e - y / ticks], -stiffness * (y - e) - damping * v

    return environment


def zeta_of(
    axes: AxisLoop | tuple[AxisLoop, ...],
    stiffness: float,
    damping: float,
    integral_s: float = 0.0,
) -> float:
    """The least damping ratio of a spring and damper on an axis, or the least over a set;
    with `integral_s` > 0, the spring's zero moving back by the stretch over that time
    constant (`spring_damper_integral`)."""
    if isinstance(axes, AxisLoop):
        axes = (axes,)
    if integral_s <= 0.0:
        plain = spring_damper(stiffness, damping)
        return min(least_damping_ratio(closed_loop(a, plain, 0), a.rate_hz) for a in axes)
    return min(
        least_damping_ratio(
            closed_loop(a, spring_damper_integral(stiffness, damping, integral_s * a.rate_hz), 1),
            a.rate_hz,
        )
        for a in axes
    )


def least_over(
    axes: tuple[AxisLoop, ...], environment: Environment, environment_size: int
) -> float:
    """The least damping ratio of a linear environment's loop over a set of plants."""
    return min(
        least_damping_ratio(closed_loop(a, environment, environment_size), a.rate_hz) for a in axes
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


def reading_noise(info: DeviceInfo, rate_hz: float) -> tuple[float, float]:
    """The reading's noise (1 sigma): of the position, and of the renderers' velocity (a
    difference over one tick, its noise reduced by the filter, about sqrt(cutoff / Nyquist)
    for the 50 Hz filter at 1 kHz); device units."""
    sigma = math.hypot(info.noise, info.resolution / math.sqrt(12.0))
    return sigma, sigma * math.sqrt(2.0) * rate_hz * math.sqrt(min(1.0, 100.0 / rate_hz))


def noise_caps(info: DeviceInfo, rate_hz: float) -> tuple[float, float]:
    """Largest stiffness and velocity gain whose answer to the reading's noise (3 sigma) stays
    within NOISE_FRACTION of the force limit (`reading_noise`)."""
    sigma, velocity_sigma = reading_noise(info, rate_hz)
    if sigma <= 0.0:
        return math.inf, math.inf
    budget = NOISE_FRACTION * info.max_force / 3.0
    return budget / sigma, budget / velocity_sigma


@functools.lru_cache(maxsize=64)
def size(
    info: DeviceInfo, rate_hz: float, velocity_sections: Sections, zeta_min: float = ZETA_MIN
) -> Sizing:
    """The stiffest spring (and its damper) the device renders with zeta >= zeta_min, on every
    plant of its uncertainty set (`plant_set`)."""
    axis = plant_set(info, rate_hz, velocity_sections)
    goals = [goal_of(a, zeta_min) for a in axis]

    def holds(k: float, b: float) -> bool:
        return all(zeta_of(a, k, b) >= g for a, g in zip(axis, goals, strict=True))

    k_noise, b_noise = noise_caps(info, rate_hz)
    tiny = 1e-6 * info.max_force / max(info.travel, 1e-9)
    heavy = max(a.mass for a in axis)
    b_high = min(b_noise, 10.0 * heavy * rate_hz)
    damping_cap = _bisect(lambda b: holds(tiny, b), 0.0, b_high)
    k_high = min(k_noise, heavy * (math.pi * rate_hz) ** 2)
    best = (0.0, 0.0)
    for fraction in (0.0, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8):
        b = fraction * damping_cap
        if not holds(tiny, b):
            continue

        def stable(k: float, b: float = b) -> bool:
            return holds(k, b)

        k = _bisect(stable, tiny, k_high, 30)
        if k > best[0]:
            best = (k, b)
    k, b = best
    period = 1.0 / rate_hz
    passivity = (
        (k * (0.5 * period + info.latency_s) + b) / info.damping if info.damping > 0 else math.inf
    )
    return Sizing(k, b, damping_cap, zeta_of(axis, k, b), info.latency_s, passivity)


@dataclass(frozen=True, slots=True)
class RingWall:
    """A blocking stage's wall that stiffens with the push, device units: piecewise linear,
    through (stretches[i], forces[i]) from (0, 0), each piece with its damper, as stiff as the
    device renders stably with a hand pushing at either end of it (`size_ring_wall`); behind
    the blocked position and beyond the last piece, the first and the last pieces go on."""

    stretches: tuple[float, ...]
    """m (or rad) past the blocked position, rising from 0."""
    forces: tuple[float, ...]
    """N (or Nm) the wall holds there, rising from 0."""
    dampings: tuple[float, ...]
    """N*s/m on the handle's filtered velocity, one a piece (len(stretches) - 1)."""
    integrals: tuple[float, ...] = ()
    """s, one a piece: the time constant with which the wall's zero moves back by the stretch
    while the handle pushes on (0 or none: the piece's spring alone)."""
    pushing_on: float = 0.0
    """m/s (or rad/s): the velocity reading above which the handle counts as pushing on (the
    reading's noise, 1 sigma: below it a handle at rest reads forward half the time)."""

    def piece(self, stretch: float) -> int:
        """Which piece a stretch is on (the first behind, the last beyond)."""
        return max(0, min(len(self.dampings) - 1, bisect.bisect_right(self.stretches, stretch) - 1))

    def force(self, stretch: float, velocity: float) -> float:
        """The wall's force for a stretch past the blocked position and the handle's velocity
        (device units, pushing back: the command is its negative)."""
        i = self.piece(stretch)
        xs, fs = self.stretches, self.forces
        slope = (fs[i + 1] - fs[i]) / (xs[i + 1] - xs[i])
        return fs[i] + slope * (stretch - xs[i]) + self.dampings[i] * velocity

    def stretch_for(self, force: float) -> float:
        """The stretch at which the wall holds `force` at rest (the inverse of `force`)."""
        xs, fs = self.stretches, self.forces
        i = max(0, min(len(self.dampings) - 1, bisect.bisect_right(fs, force) - 1))
        return xs[i] + (force - fs[i]) * (xs[i + 1] - xs[i]) / (fs[i + 1] - fs[i])


RING_PUSH_SHARES = (0.0, 0.025, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
"""Pushes (shares of the device's force limit) at which the ring wall's pieces begin and end."""
RING_FEED_FORWARD_S = 0.1
"""s: the time constant of the ring wall's feed-forward (its zero moving back by the stretch
while the hand pushes on), where a piece keeps zeta_min with it."""
RING_DAMPING_SHARES = (0.0, 0.5, 1.0)
"""Shares of the sized damper tried on each piece (a hand's muscle damps the handle already:
on a stiff grip less rendered damping leaves more room for the spring)."""


@functools.lru_cache(maxsize=16)
def size_ring_wall(
    info: DeviceInfo,
    rate_hz: float,
    velocity_sections: Sections,
    hand_damping_per_N: float,
    hand: tuple[float, float, float],
    zeta_min: float = ZETA_MIN,
    feed_forward: bool = True,
) -> RingWall:
    """The wall of a stage that blocks only while the hand pushes (the synchronizer's ring,
    which lets go once the push falls under its hold). A hand pushing with F is the paper's
    (eq. 10): its muscle F = a*F_max*(1 - v_h/V0) puts F/V0 of damping on the hand's mass
    (`hand_damping_per_N` = 1/V0, s/m at the device), which holds the handle through its grip
    (`hand`: mass, grip stiffness and damping, device units). Each piece between two pushes of
    RING_PUSH_SHARES gets the stiffest spring (with the damper of RING_DAMPING_SHARES that
    allows the most) keeping zeta_min on every plant of the device's set with the hand at
    either push on it (at no push: hands off, the sizing's own plants). Hands off, the wall
    holds only until its force falls under the ring's hold: a part of a swing, on a spring
    that stores less energy than the coupling would for the same push.

    With `feed_forward`, each piece is sized with its feed-forward acting all the time (the
    spring's zero moving back by the stretch over RING_FEED_FORWARD_S; conservative, since
    `rendering.RingHold` moves it only while the handle pushes on) and keeps it where some
    spring holds zeta_min so; elsewhere the piece is the spring alone."""
    sizing = size(info, rate_hz, velocity_sections, zeta_min)
    base = plant_set(info, rate_hz, velocity_sections)
    pushes = [share * info.max_force for share in RING_PUSH_SHARES]

    def plants(push: float) -> tuple[AxisLoop, ...]:
        if push <= 0.0:
            return base
        grip = (*hand, hand_damping_per_N * push)
        return tuple(dataclasses.replace(a, hand=grip) for a in base)

    def holds(both: tuple[AxisLoop, ...], b: float) -> Callable[[float], bool]:
        return lambda k: zeta_of(both, k, b) >= zeta_min

    def plain(both: tuple[AxisLoop, ...], k_high: float) -> tuple[float, float]:
        """The stiffest (spring, damper) keeping zeta_min, from the sizing's up."""
        best = (sizing.stiffness, sizing.damping)
        for share in RING_DAMPING_SHARES:
            b = share * sizing.damping
            if zeta_of(both, best[0], b) < zeta_min:
                continue
            k = _bisect(holds(both, b), best[0], k_high, 20)
            if k > best[0]:
                best = (k, b)
        return best

    def fed(both: tuple[AxisLoop, ...], k_high: float) -> tuple[float, float] | None:
        """The same with the feed-forward: the stiffest point of a grid from a quarter to 16
        times the sizing's spring (the feed-forward holds the push, so the spring may be
        softer than the coupling's; too soft a spring under a slow integrator swings slowly,
        so the springs that hold are a band, searched from the top), bisected toward the
        next; None where no spring keeps zeta_min with it."""
        best: tuple[float, float] | None = None
        grid = np.geomspace(0.25 * sizing.stiffness, min(k_high, 16.0 * sizing.stiffness), 10)
        for share in RING_DAMPING_SHARES:
            b = share * sizing.damping

            def ok(k: float, b: float = b) -> bool:
                return zeta_of(both, k, b, RING_FEED_FORWARD_S) >= zeta_min

            i = next((i for i in range(len(grid) - 1, -1, -1) if ok(float(grid[i]))), None)
            if i is None:
                continue
            k = float(grid[i]) if i + 1 == len(grid) else _bisect(ok, grid[i], grid[i + 1], 6)
            if best is None or k > best[0]:
                best = (k, b)
        return best

    stretches, dampings, integrals = [0.0], [], []
    for low, high in itertools.pairwise(pushes):
        both = plants(low) + plants(high)
        k_high = (max(a.mass for a in both) + hand[0]) * (math.pi * rate_hz) ** 2
        with_feed = fed(both, k_high) if feed_forward else None
        k, b = with_feed if with_feed is not None else plain(both, k_high)
        stretches.append(stretches[-1] + (high - low) / k)
        dampings.append(b)
        integrals.append(RING_FEED_FORWARD_S if with_feed is not None else 0.0)
    return RingWall(
        tuple(stretches),
        tuple(pushes),
        tuple(dampings),
        tuple(integrals),
        reading_noise(info, rate_hz)[1],
    )
