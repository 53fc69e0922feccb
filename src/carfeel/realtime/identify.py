"""Device identification: what the loop relies on about a device, measured, not assumed.

A device tells carfeel little (a real one its force limit at best; the rest is declared or a
default), and no real device matches what it is told. So at start-up, with the hand off, each
axis is excited a little and its response measured, as commercial bases and active shifters
calibrate at power-on:

    rest     REST_S with no force: the reading's noise, and motion that says a hand is on
    probe    a doublet (+F then -F, `PROBES`: from 5 % up to IDENTIFY_FRACTION of the limit,
             until the axis moves): the force's polarity and a first guess of the inertia
    chirp    CHIRP_S of a swept sine (4 -> 40 Hz) on top of a soft centring servo that keeps the
             axis within WINDOW_FRACTION of its travel; its amplitude is sized from the first
             guess so that the motion stays in that window
    sweeps   the servo, with a first fit of the chirp as feed-forward, drags the axis out and
             back at two steady speeds: the force it takes there is the damping and the
             friction, nothing else
    return   the servo brings the axis back and lets go

Every command goes through the force limiter (at most IDENTIFY_FRACTION of the limit, and its
slew) and every reading through the watchdog (NaN, beyond the travel, a stall), as in the loop.
Then, offline (numpy), per axis, with the same Savitzky-Golay smoothing on the readings and on
the commands (so that what smoothing does to one it does to the other):

    u(t - d) = m * x'' + b * x' + k * x + F_c * sign(x') + c      (device units)

is solved by least squares for the inertia m, viscous damping b, centring spring k (a grip or
the device's own), Coulomb friction F_c and a bias c, at each round-trip delay d on a grid of a
quarter tick, the best d refined by a parabola; samples where the axis nearly stands still
(where friction sticks and is not F_c) are left out. Uncertainties are the least-squares ones,
widened by the residuals' correlation. The delay found is the loop's whole round trip, with
the command's zero-order hold (half a tick) and the report's hold taken out, as
`stability.AxisLoop` counts them back in.

A hand on the device shows as motion at rest, a poor fit (what the hand does is not in the
model) or an inertia or damping beyond any device of its kind; then the identification is
refused with the reason: take the hand off and start again.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

from carfeel.errors import InputError
from carfeel.realtime.clock import Clock
from carfeel.realtime.devices.base import Device, DeviceInfo, DeviceLost
from carfeel.realtime.filters import SosFilter, butterworth_sections
from carfeel.realtime.safety import ForceLimiter, SafetyLimits, Watchdog

IDENTIFY_FRACTION = 0.25
"""The largest force of the excitation, a share of the device's force limit."""
WINDOW_FRACTION = 0.2
"""Each axis stays within this share of its travel of where it started."""
REST_S = 0.2
PROBE_QUIET_S = 0.15
PROBES = ((0.05, 0.015), (0.1, 0.015), (IDENTIFY_FRACTION, 0.015), (IDENTIFY_FRACTION, 0.04))
"""The probe's doublets, gentlest first: (share of the force limit, seconds each way)."""
CHIRP_S = 1.0
CHIRP_HZ = (4.0, 40.0)
SERVO_HZ = 2.0
"""The centring servo's natural frequency on the first guess of the inertia: far below any
coupling, so it is stable whatever the delay and the inertia turn out to be."""
SWEEP_SPEEDS = (0.1, 0.3, 1.0)
"""The sweeps' steady speeds, shares of the fastest (which covers half the window one way)."""
SWEEP_STEADY_S = 0.12
SWEEP_RAMP_S = 0.02
"""The shortest change of speed at either end of a sweep (longer where the force would not
do: a heavy wheel)."""
RETURN_S = 0.2
SMOOTH_HZ = 50.0
"""The low-pass on readings and commands alike (61 taps at 1 kHz)."""
STILL_FACTOR = 4.0
STUCK_TICKS = 8
"""The axis stands still where its velocity stays within STILL_FACTOR times its noise at rest
for STUCK_TICKS ticks or more."""
MAX_DELAY_S = 0.08
MODEL_ERROR = 0.005
DELAY_RESOLUTION_TICKS = 0.05
"""The least standard deviations of an inertia (a share of it) and a delay (of a tick): what
the model's own error is on plants without noise."""
MIN_R2 = 0.9
"""A fit that explains less of the command than this is not of a free device: a hand is on it,
or it is not the plant the model describes."""
PLAUSIBLE = {"joystick": (0.005, 5.0, 500.0), "wheel": (1e-3, 1.0, 10.0)}
"""Per kind, the range of a device's moving mass (kg, or kg m^2) and the largest damping
(N*s/m, or Nm*s/rad) a device of its kind has without a hand on it."""
MASS_MARGIN = 0.05
DELAY_MARGIN_TICKS = 0.125
"""The least uncertainty the sizing takes around an inertia and a delay: the resolution of the
check at a later start (its gain's scatter on an unchanged device, its grid of shifts), so that a
checked profile and a fresh identification size alike unless the check found more."""
CHECK_TOLERANCE = 0.25
"""A stored profile still holds when its model predicts a fresh probe's motion within this
share of the motion (a changed delay, inertia or polarity gives far more)."""


class IdentificationError(InputError):
    """The device could not be identified (a hand on it, it does not move, it runs away)."""


@dataclass(frozen=True, slots=True)
class AxisEstimate:
    """What one axis turned out to be, device units, each with its standard deviation."""

    polarity: float
    """+1, or -1 where the device pushes against its commands (its forces are inverted)."""
    mass: float
    mass_sigma: float
    damping: float
    damping_sigma: float
    friction: float
    friction_sigma: float
    stiffness: float
    stiffness_sigma: float
    round_trip_s: float
    """Command delay plus reading delay (the command's hold and the report's hold aside)."""
    round_trip_sigma_s: float
    report_hz: float
    noise: float
    """Standard deviation of the reading at rest, m or rad."""
    r2: float
    """Share of the commands' variance the model explains."""

    def as_dict(self) -> dict[str, float]:
        return {name: getattr(self, name) for name in self.__slots__}


@dataclass(frozen=True, slots=True)
class Identification:
    """A device's identification: per axis, and how it was made."""

    axes: tuple[AxisEstimate, ...]
    rate_hz: float
    duration_s: float
    peak_force: float
    """Largest force commanded during the excitation, device units."""
    max_force: float
    notes: tuple[str, ...] = ()

    @property
    def polarity(self) -> tuple[float, ...]:
        return tuple(a.polarity for a in self.axes)

    def info(self, base: DeviceInfo, shift_s: float = 0.0, gain: float = 1.0) -> DeviceInfo:
        """`base` with what was measured and where the truth may lie (`stability.plant_set`
        sizes for every plant of that set): per figure its estimate +- 3 sigma over all axes
        (the delay also +- the reports' phase, `_phase_s`), but at least the
        resolution of a later start's check (`profiles.check`: the inertia
        +-MASS_MARGIN, the delay +-DELAY_MARGIN_TICKS) and what such a check found: the largest
        `shift_s` of its probes' timing and `gain` of their reach (1: none)."""
        period = 1.0 / self.rate_hz
        found = abs(gain - 1.0)

        def mass_spread(a: AxisEstimate) -> float:
            return a.mass * max(3.0 * a.mass_sigma / a.mass, MASS_MARGIN, found)

        mass = max(a.mass for a in self.axes)
        light = min(a.mass - mass_spread(a) for a in self.axes)
        heavy = max(a.mass + mass_spread(a) for a in self.axes)
        damping = min(a.damping for a in self.axes)
        least = min(
            max(0.0, a.damping - max(3 * a.damping_sigma, found * a.damping)) for a in self.axes
        )
        most = max(a.damping + max(3 * a.damping_sigma, found * a.damping) for a in self.axes)
        trip = max(a.round_trip_s for a in self.axes)
        # A report is taken at a phase of the loop's tick that nobody controls (a device's
        # clock is not the host's): the round trip measured holds the phase of that moment,
        # and the truth may be up to a report period either side of it.
        spread = max(
            max(3 * a.round_trip_sigma_s + _phase_s(a.report_hz, self.rate_hz),
                DELAY_MARGIN_TICKS * period, abs(shift_s))
            for a in self.axes
        )  # fmt: skip
        short = max(0.0, min(a.round_trip_s for a in self.axes) - spread)
        report = min(a.report_hz for a in self.axes)
        stiffness = min(max(0.0, a.stiffness - 3 * a.stiffness_sigma) for a in self.axes)
        noise = max(a.noise for a in self.axes)
        return replace(
            base,
            mass=mass,
            damping=damping,
            stiffness=stiffness,
            command_delay_s=0.5 * trip,
            reading_delay_s=0.5 * trip,
            report_hz=report,
            noise=max(base.noise, noise),
            mass_range=(max(1e-9, light), heavy),
            damping_range=(least, most),
            delay_range_s=(short, trip + spread),
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "rate_hz": self.rate_hz,
            "duration_s": self.duration_s,
            "peak_force": self.peak_force,
            "peak_force_fraction": self.peak_force / self.max_force,
            "axes": [a.as_dict() for a in self.axes],
            "notes": list(self.notes),
        }


def _phase_s(report_hz: float, rate_hz: float) -> float:
    """How far a measured round trip may be from the truth for the reports' phase: a report
    period where the device reports as often as the loop ticks (each reading a report of a
    fixed, unknown age that drifts between runs), none where it reports more slowly (a
    reading's age then cycles through every phase within a report: the sizing's hold)."""
    return 1.0 / report_hz if report_hz >= 0.9 * rate_hz else 0.0


# ------------------------------------------------------------------ the excitation


@dataclass
class _Trace:
    """What one axis's excitation recorded: per tick, the commanded force (in the axis's own
    frame: polarity applied) and the reading, and where each phase starts."""

    forces: list[float] = field(default_factory=list)
    readings: list[float] = field(default_factory=list)
    phases: dict[str, int] = field(default_factory=dict)


class _Session:
    """The identification's own fixed-rate loop on one device, through the safety chain."""

    def __init__(
        self, device: Device, clock: Clock, rate_hz: float, origin_ns: int, limits: SafetyLimits
    ) -> None:
        self.device, self.clock = device, clock
        self.info = device.info
        self.axes = device.info.axes
        self.period_ns = round(1e9 / rate_hz)
        self.dt = self.period_ns / 1e9
        self.rate_hz = rate_hz
        self.origin_ns = origin_ns
        self.limiter = ForceLimiter(limits, self.axes)
        self.watchdog = Watchdog(limits, device.info.travel)
        self.deadline = clock.now_ns()
        self.last = self.deadline
        self.peak = 0.0
        self.positions: tuple[float, ...] = (0.0,) * self.axes

    def faulted(self) -> bool:
        return self.watchdog.faulted

    @property
    def time_s(self) -> float:
        return (self.clock.now_ns() - self.origin_ns) / 1e9

    def tick(self, forces: tuple[float, ...]) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """Command `forces` (after the limiter at IDENTIFY_FRACTION), read: (sent, readings)."""
        self.deadline += self.period_ns
        self.clock.sleep_until(self.deadline)
        now = self.clock.now_ns()
        period, self.last = (now - self.last) / 1e9, now
        t = (now - self.origin_ns) / 1e9
        scale = IDENTIFY_FRACTION
        if self.watchdog.faulted:
            scale *= self.watchdog.envelope(self.dt)
        sent = self.limiter.limit(forces, self.dt, scale)
        self.device.command(sent, t)
        self.peak = max(self.peak, *(abs(f) for f in sent))
        positions = self.device.read(t).positions
        self.watchdog.check(positions, period, t)
        self.positions = positions
        return sent, positions

    def pause(self) -> None:
        """Before work between ticks (a first fit): no force, and the time it takes is no
        stall (the deadlines start again at `resume`)."""
        self.fade()

    def resume(self) -> None:
        self.deadline = self.last = self.clock.now_ns()

    def fade(self) -> None:
        """Take the force away within the slew limit."""
        while any(f != 0.0 for f in self.limiter.last):
            self.tick((0.0,) * self.axes)


def _chirp(rate_hz: float, mass: float, window: float, top: float) -> list[float]:
    """A logarithmic sine sweep over CHIRP_HZ, its amplitude at each frequency what moves
    `mass` about a third of `window` (at most `top`), faded in and out over 50 ms."""
    f0, f1 = CHIRP_HZ
    n = round(CHIRP_S * rate_hz)
    growth = math.log(f1 / f0) / CHIRP_S
    values = []
    for i in range(n):
        t = i / rate_hz
        frequency = f0 * math.exp(growth * t)
        phase = 2.0 * math.pi * f0 * (math.exp(growth * t) - 1.0) / growth
        amplitude = min(top, mass * (2.0 * math.pi * frequency) ** 2 * window / 3.0)
        edge = min(1.0, t / 0.05, (CHIRP_S - t) / 0.05)
        values.append(amplitude * edge * math.sin(phase))
    return values


def _sweeps(
    rate_hz: float, window: float, mass: float, budget: float
) -> Iterator[tuple[float, float, float]]:
    """(position, velocity, acceleration) of the sweeps, from where the axis is: at each speed
    of SWEEP_SPEEDS (shares of the fastest, which covers half the window one way), out and
    back, each way SWEEP_STEADY_S at a steady speed between two smooth (cosine) changes that
    take at most half the force `budget` on `mass`."""
    steady = SWEEP_STEADY_S
    accel = 0.5 * budget / mass
    # The fastest speed whose ramps and steady part cover half the window:
    # v * (v * pi / (2 * accel) + steady) = window / 2.
    c = math.pi / (2.0 * accel)
    fastest = (-steady + math.sqrt(steady * steady + 2.0 * c * window)) / (2.0 * c)
    position = 0.0
    dt = 1.0 / rate_hz
    for share in SWEEP_SPEEDS:
        for direction in (1.0, -1.0):
            top = direction * share * fastest
            ramp = max(SWEEP_RAMP_S, abs(top) * c)
            n = round((2 * ramp + steady) * rate_hz)
            for i in range(n):
                t = i * dt
                if t < ramp:
                    speed = top * 0.5 * (1.0 - math.cos(math.pi * t / ramp))
                    change = top * 0.5 * math.pi / ramp * math.sin(math.pi * t / ramp)
                elif t < ramp + steady:
                    speed, change = top, 0.0
                else:
                    left = (t - ramp - steady) / ramp
                    speed = top * 0.5 * (1.0 + math.cos(math.pi * left))
                    change = -top * 0.5 * math.pi / ramp * math.sin(math.pi * left)
                position += speed * dt
                yield position, speed, change


def _excite_axis(session: _Session, axis: int, polarity: list[float]) -> _Trace:
    """Rest, probe, chirp, sweeps and return on one axis (the others get no force)."""
    import numpy as np

    info, rate, dt = session.info, session.rate_hz, session.dt
    # Everything that takes time is made before the first tick (the filter's design imports
    # scipy: a second, the first time).
    velocity = SosFilter(butterworth_sections(min(30.0, 0.3 * rate), rate))
    session.resume()  # the fit of the axis before took time: no stall
    trace = _Trace()
    zero = (0.0,) * session.axes
    window = WINDOW_FRACTION * info.travel
    top = IDENTIFY_FRACTION * info.max_force
    start = session.positions[axis]

    def send(force: float) -> float:
        forces = [0.0] * session.axes
        forces[axis] = force * polarity[axis]
        sent, positions = session.tick(tuple(forces))
        trace.forces.append(sent[axis] * polarity[axis])
        trace.readings.append(positions[axis])
        if abs(positions[axis] - start) > 1.5 * window and not session.faulted():
            session.watchdog.fault(
                f"axis {axis} ran {abs(positions[axis] - start):.3g} from where it started during "
                f"the identification (its window is {window:.3g}): a hand on it, or it is far "
                "lighter than its force suggests"
            )
        return positions[axis]

    trace.phases["rest"] = 0
    for _ in range(round(REST_S * rate)):
        send(0.0)
    # Probe: a doublet, stronger until the axis clearly moves.
    trace.phases["probe"] = len(trace.forces)
    noise = _spread(trace.readings)
    lsb = max(info.resolution, 1e-12)
    need = max(10 * lsb, 10.0 * noise)
    departs = 0.5 * need
    moved = force = pulse = first_way = 0.0
    for fraction, pulse in PROBES:
        force = fraction * info.max_force
        before = session.positions[axis]
        moved = first_way = 0.0
        for push in (force, -force, 0.0):
            for _ in range(round((pulse if push else PROBE_QUIET_S) * rate)):
                shift = send(push) - before
                moved = _largest(moved, shift)
                if not first_way and abs(shift) > departs:
                    # The way it first moves is the force's polarity (the largest excursion
                    # need not be: a spring on it swings it back past the start).
                    first_way = math.copysign(1.0, shift)
        if abs(moved) >= need or session.faulted():
            break
    if session.faulted():
        return trace
    if abs(moved) < need:
        raise IdentificationError(
            f"axis {axis} of {info.name} did not move under {force:.3g} "
            f"({force / info.max_force:.0%} of its force limit) for {1e3 * pulse:g} ms: it is "
            "held (a hand, a stop, a brake) or does not take force commands. Let go of it, or "
            "check that its force feedback is on"
        )
    if first_way < 0.0:
        polarity[axis] = -polarity[axis]
        # The probe pushed it the wrong way: its recorded forces are in the flipped frame.
        first = trace.phases["probe"]
        trace.forces[first:] = [-f for f in trace.forces[first:]]
    # A first guess of the inertia from the probe: a doublet moves a mass F T^2 / m.
    guess = abs(force) * pulse**2 / max(abs(moved), need)
    servo_k = guess * (2.0 * math.pi * SERVO_HZ) ** 2
    servo_b = 2.0 * 0.7 * math.sqrt(servo_k * guess)
    last = session.positions[axis]
    home = last

    def servo(reference: float, speed: float, extra: float) -> None:
        nonlocal last
        reading = session.positions[axis]
        v = velocity.step((reading - last) / dt)
        last = reading
        send(servo_k * (reference - reading) + servo_b * (speed - v) + extra)

    chirp = _chirp(rate, guess, window, top)
    trace.phases["chirp"] = len(trace.forces)
    for value in chirp:
        servo(home, 0.0, value)
        if session.faulted():
            return trace
    # A first fit of what the chirp showed drives the sweeps (the soft servo alone would lag
    # them by more than the window): feed-forward of inertia, damping and friction.
    session.pause()
    try:
        fitted = estimate_axis(
            np.array(trace.forces), np.array(trace.readings), rate, info.resolution,
            trace.phases["probe"], trace.phases["probe"],
        )  # fmt: skip
        mass, damping = fitted.mass, max(0.0, fitted.damping)
        friction = max(0.0, fitted.friction)
        if not mass > 0.0:
            mass, damping, friction = guess, 0.0, 0.0
    except IdentificationError:
        mass, damping, friction = guess, 0.0, 0.0
    session.resume()
    # The servo re-tuned on the fitted inertia (the probe's guess can be far off where friction
    # holds the doublet back: a servo three times too stiff for the true inertia rings through
    # a long delay).
    servo_k = mass * (2.0 * math.pi * SERVO_HZ) ** 2
    servo_b = 2.0 * 0.7 * math.sqrt(servo_k * mass)
    trace.phases["sweeps"] = len(trace.forces)
    for position, speed, accel in _sweeps(rate, window, mass, top):
        push = mass * accel + damping * speed + (math.copysign(friction, speed) if speed else 0.0)
        servo(home + position, speed, push)
        if session.faulted():
            return trace
    trace.phases["return"] = len(trace.forces)
    for _ in range(round(RETURN_S * rate)):
        servo(home, 0.0, 0.0)
    trace.phases["end"] = len(trace.forces)
    session.fade()
    for _ in range(round(0.05 * rate)):
        session.tick(zero)
    return trace


def _largest(a: float, b: float) -> float:
    return a if abs(a) >= abs(b) else b


def _spread(values: list[float]) -> float:
    """Standard deviation of a few readings (0 for fewer than two)."""
    if len(values) < 2:
        return 0.0
    mean = sum(values) / len(values)
    return math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))


# ------------------------------------------------------------------ the estimate


def estimate_axis(
    forces: Any,
    readings: Any,
    rate_hz: float,
    resolution: float,
    first: int,
    rest: int,
    steady: tuple[int, int] | None = None,
) -> AxisEstimate:
    """The least-squares fit of the module's model to one axis's trace (numpy arrays);
    `first` is where the excitation starts, `rest` how many samples of rest precede it, and
    `steady` the samples of the sweeps, if any: there the damping and the friction are fitted
    again with the inertia and the delay held (a delay a hundredth of a tick off looks, through
    the inertia at the chirp's frequencies, like damping; at a steady speed it does not)."""
    import numpy as np

    u = np.asarray(forces, dtype=float)
    y = np.asarray(readings, dtype=float)
    period = 1.0 / rate_hz
    noise = float(np.std(y[:rest])) if rest > 2 else 0.0
    # One linear low-pass (a windowed sinc, SMOOTH_HZ, symmetric: no lag) on both sides, then
    # exact differences of the smoothed readings: a linear filter commutes with the plant's
    # discrete dynamics, so the model holds between the smoothed signals as it does between the
    # raw ones. (Derivative filters would not match the smoothing of the commands, and a
    # Savitzky-Golay smoothing lets the readings' quantization through to the acceleration.)
    kernel = _smoothing_kernel(rate_hz)
    window = len(kernel)

    def smooth(values: Any) -> Any:
        return np.convolve(values, kernel, mode="same")

    x = smooth(y)
    v = np.gradient(x, period)
    a = np.zeros_like(x)
    a[1:-1] = (x[2:] - 2.0 * x[1:-1] + x[:-2]) / period**2
    us = smooth(u)
    lsb = max(resolution, noise, 1e-12)
    # Where the axis stands still for a while, its friction sticks and is not F_c: those
    # samples (and every sample whose smoothing reaches them) are left out.
    from scipy.ndimage import binary_opening, maximum_filter1d

    quiet = v[window : max(window + 1, rest - window)]
    floor = float(np.std(quiet)) if quiet.size > 10 else lsb * rate_hz / window
    slow = np.abs(v) < STILL_FACTOR * max(floor, 1e-12)
    stuck = binary_opening(slow, structure=np.ones(STUCK_TICKS, dtype=bool))
    keep = ~maximum_filter1d(stuck.astype(np.int8), size=window).astype(bool)
    keep[: first + window] = False
    keep[-window:] = False
    sign = smooth(np.sign(v))
    regressors = np.column_stack([a, v, x - x[first], sign, np.ones_like(x)])
    total = int(MAX_DELAY_S * rate_hz) + 2
    keep[: total + 1] = False
    index = np.flatnonzero(keep)
    if index.size < 50:
        raise IdentificationError(
            "the axis hardly moved during the identification: too few samples to fit "
            f"({index.size}); it is held, or its readings do not change"
        )
    matrix = regressors[index]

    def delayed(delay_ticks: float, where: Any) -> Any:
        whole = math.floor(delay_ticks)
        frac = delay_ticks - whole
        return (1.0 - frac) * us[where - whole] + frac * us[where - whole - 1]

    def cost_at(delay_ticks: float) -> float:
        target = delayed(delay_ticks, index)
        beta, *_ = np.linalg.lstsq(matrix, target, rcond=None)
        residual = target - matrix @ beta
        return float(residual @ residual)

    step = 0.25
    grid = np.arange(0.0, total - 1, step)
    costs = np.array([cost_at(d) for d in grid])
    best = int(np.argmin(costs))
    delay = float(grid[best])
    if 0 < best < len(grid) - 1:
        c0, c1, c2 = costs[best - 1 : best + 2]
        curvature = c0 - 2 * c1 + c2
        if curvature > 0:
            delay += step * 0.5 * (c0 - c2) / curvature
    target = delayed(delay, index)
    fit = _least_squares(matrix, target, window)
    # The sigmas with the delay as a parameter too (its column: how the target moves with it),
    # so that what a delay a little off could pass for (damping, at the chirp's frequencies)
    # widens them.
    slope = (delayed(delay + 0.05, index) - delayed(max(0.0, delay - 0.05), index)) / 0.1
    joint = _least_squares(np.column_stack([matrix, slope]), target, window)
    # The delay's sigma from the cost's curvature (a rise of the cost by one variance).
    around = [cost_at(max(0.0, delay - step)), fit.cost, cost_at(delay + step)]
    bend = (around[0] - 2 * around[1] + around[2]) / step**2
    scale = fit.variance * fit.inflation
    delay_sigma_ticks = math.sqrt(2.0 * scale / bend) if bend > 0 else 1.0
    spread = float(np.var(target))
    r2 = 1.0 - fit.cost / (len(index) * spread) if spread > 0 else 0.0
    m, b, k, friction, _ = (float(value) for value in fit.beta)
    sigma = [float(value) for value in joint.sigma]
    sigmas = {"b": sigma[1], "f": sigma[3]}
    if steady is not None:
        where = index[(index >= steady[0]) & (index < steady[1])]
        if where.size > 3 * window:
            # v, sign and the bias (the spring and inertia taken out as fitted).
            rows = regressors[where][:, [1, 3, 4]]
            aim = delayed(delay, where) - m * a[where] - k * (x[where] - x[first])
            again = _least_squares(rows, aim, window)
            # The steady speeds' damping and friction where they are the better determined.
            if float(again.sigma[0]) < sigmas["b"]:
                b, sigmas["b"] = float(again.beta[0]), float(again.sigma[0])
            if float(again.sigma[1]) < sigmas["f"]:
                friction, sigmas["f"] = float(again.beta[1]), float(again.sigma[1])
    report = _report_rate(y, v, rate_hz, lsb)
    hold = max(0.0, 0.5 / report - 0.5 * period)
    # The fitted delay holds the command's zero-order hold (half a tick) and the report's.
    trip = max(0.0, delay * period - 0.5 * period - hold)
    # Floors for what the model itself gets wrong (the plant integrates between ticks, the
    # smoothing is not exact): seen on noise-free plants, whose statistics alone claim more.
    sigma[0] = max(sigma[0], MODEL_ERROR * abs(m))
    delay_sigma_ticks = max(delay_sigma_ticks, DELAY_RESOLUTION_TICKS)
    return AxisEstimate(
        polarity=1.0, mass=m, mass_sigma=sigma[0], damping=b, damping_sigma=sigmas["b"],
        friction=friction, friction_sigma=sigmas["f"], stiffness=k, stiffness_sigma=sigma[2],
        round_trip_s=float(trip), round_trip_sigma_s=delay_sigma_ticks * period,
        report_hz=report, noise=noise, r2=r2,
    )  # fmt: skip


@dataclass(frozen=True)
class _Fit:
    beta: Any
    sigma: Any
    cost: float
    variance: float
    inflation: float


def _least_squares(matrix: Any, target: Any, window: int) -> _Fit:
    """Least squares with Newey-West standard deviations (Bartlett weights over twice the
    smoothing's window): the smoothing correlates the residuals, and how much that widens a
    coefficient's uncertainty depends on how fast its regressor varies (the damping's, at the
    chirp's frequencies, far less than a constant's)."""
    import numpy as np

    beta, *_ = np.linalg.lstsq(matrix, target, rcond=None)
    residual = target - matrix @ beta
    n, p = matrix.shape
    cost = float(residual @ residual)
    variance = cost / max(1, n - p)
    scores = matrix * residual[:, None]
    lags = min(2 * window, n - 1)
    meat = scores.T @ scores
    for k in range(1, lags + 1):
        weight = 1.0 - k / (lags + 1)
        cross = scores[k:].T @ scores[:-k]
        meat += weight * (cross + cross.T)
    bread = np.linalg.pinv(matrix.T @ matrix)
    covariance = bread @ meat @ bread * n / max(1, n - p)
    sigma = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    # The plain least-squares variance over the robust one: how much the correlation widens.
    plain = np.sqrt(np.maximum(np.diag(bread) * variance, 1e-300))
    inflation = float(np.max((sigma / plain) ** 2)) if sigma.size else 1.0
    return _Fit(beta, sigma, cost, variance, max(1.0, inflation))


def _smoothing_kernel(rate_hz: float) -> Any:
    """A windowed-sinc low-pass of SMOOTH_HZ (Hamming), about 60 ms long, unit gain."""
    from scipy.signal import firwin

    taps = 2 * round(0.03 * rate_hz) + 1
    return firwin(taps, min(SMOOTH_HZ, 0.4 * rate_hz), fs=rate_hz)


def _report_rate(y: Any, v: Any, rate_hz: float, lsb: float) -> float:
    """Reports per second: where the axis moves several quanta a tick, the share of ticks at
    which the reading changes (a slower report holds it in between)."""
    import numpy as np

    fast = np.abs(v[1:]) > 4.0 * lsb * rate_hz
    if int(fast.sum()) < 20:
        return rate_hz
    changed = np.diff(y)[fast] != 0.0
    share = float(changed.mean())
    return rate_hz if share > 0.9 else max(0.05, share) * rate_hz


# ------------------------------------------------------------------ one call


def identify(
    device: Device,
    clock: Clock,
    rate_hz: float,
    origin_ns: int,
    limits: SafetyLimits,
    announce: Callable[[str], None] | None = None,
) -> Identification:
    """Identify every axis of an open device (hands off), through the safety chain. Raises
    IdentificationError with the reason where the device cannot be identified (a fault of the
    safety chain included: the force has faded by then)."""
    import numpy as np

    info = device.info
    session = _Session(device, clock, rate_hz, origin_ns, limits)
    started = session.time_s
    if announce is not None:
        announce(
            f"identifying {info.name}: hands off the device for about "
            f"{info.axes * _axis_duration_s():.0f} s"
        )
    polarity = [1.0] * info.axes
    estimates = []
    notes: list[str] = []
    try:
        session.tick((0.0,) * info.axes)
        for axis in range(info.axes):
            trace = _excite_axis(session, axis, polarity)
            if session.faulted():
                session.fade()
                raise IdentificationError(
                    f"the identification of {info.name} stopped: {session.watchdog.faults[0]}"
                )
            rest = trace.phases["probe"]
            estimate = estimate_axis(
                np.array(trace.forces), np.array(trace.readings), rate_hz, info.resolution,
                trace.phases["probe"], rest, (trace.phases["sweeps"], trace.phases["return"]),
            )  # fmt: skip
            if estimate.mass <= 0.0:
                raise IdentificationError(
                    f"axis {axis} of {info.name} answered its excitation against its probe "
                    f"(a fitted inertia of {estimate.mass:.3g}): something pushed it. Let go of "
                    "it and start again"
                )
            estimate = replace(estimate, polarity=polarity[axis])
            _refuse_a_hand(info, axis, estimate, np.array(trace.readings[:rest]))
            estimates.append(estimate)
            if polarity[axis] < 0:
                notes.append(f"axis {axis} pushes against its commands: its force is inverted")
    except DeviceLost:
        raise
    finally:
        session.fade()
    return Identification(
        tuple(estimates), rate_hz, session.time_s - started, session.peak, info.max_force,
        tuple(notes),
    )  # fmt: skip


def _axis_duration_s() -> float:
    sweeps = len(SWEEP_SPEEDS) * 2 * (2 * SWEEP_RAMP_S + SWEEP_STEADY_S)
    probe = sum(2 * pulse + PROBE_QUIET_S for _, pulse in PROBES[:2])
    return REST_S + probe + CHIRP_S + sweeps + RETURN_S


def _refuse_a_hand(info: DeviceInfo, axis: int, estimate: AxisEstimate, rest: Any) -> None:
    """A hand on the device: motion at rest, a poor fit, or figures no device of its kind has."""
    import numpy as np

    name = f"axis {axis} of {info.name}"
    spread = float(np.ptp(rest)) if rest.size else 0.0
    # A free device at rest reads its noise and a quantum or two: a hand's tremor and drift
    # move it further.
    still = max(6.0 * max(info.resolution, 1e-12), 1e-4 * info.travel, 8.0 * info.noise)
    if spread > still:
        raise IdentificationError(
            f"{name} moved {spread:.3g} while no force was on it: a hand is on the device. "
            "Let go of it and start again (the identification needs it free for a few seconds)"
        )
    low, high, damping = PLAUSIBLE.get(info.kind, PLAUSIBLE["joystick"])
    if estimate.r2 < MIN_R2:
        raise IdentificationError(
            f"{name} does not move as a free device does (the fit explains {estimate.r2:.0%} of "
            "its forces): a hand is on it, or something else pushes it. Let go of it and start "
            "again"
        )
    if not low <= estimate.mass <= high or estimate.damping > damping:
        raise IdentificationError(
            f"{name} measured {estimate.mass:.3g} of inertia and {estimate.damping:.3g} of "
            f"damping, beyond any {info.kind} (inertia {low:g}..{high:g}, damping up to "
            f"{damping:g}): a hand is on it. Let go of it and start again"
        )
