"""The fixed-rate loop: read the device, step the model, command the device, safely.

Against absolute deadlines (t0 + k * period), so one late tick does not shift the ones after it.
Before the loop, garbage collection is run and frozen (its 1-1.6 ms pauses would be overruns),
and the interpreter's switch interval is cut to 0.2 ms (threads beside the loop, the recorder's
writer, hand the GIL back quickly).
An overrun is a period longer than 1.5 times the nominal one; every period's error is kept for
the summary. Start-up: each axis is pulsed at a fifth of the force limit to check its polarity
(a reversed axis is flipped and said so), then the force limit ramps in.
"""

from __future__ import annotations

import contextlib
import gc
import math
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Protocol

from carfeel.realtime.clock import Clock, WallClock
from carfeel.realtime.devices.base import Device, DeviceLost
from carfeel.realtime.recording import Recorder
from carfeel.realtime.rendering import Renderer
from carfeel.realtime.safety import (
    ForceLimiter,
    OscillationGuard,
    PassivityController,
    SafetyLimits,
    Watchdog,
)

OVERRUN_FACTOR = 1.5
SWITCH_INTERVAL_S = 2e-4
"""sys.setswitchinterval while the loop runs (the default is 5 ms)."""
CALIBRATION_PULSE_S = 0.01
CALIBRATION_SETTLE_S = 0.1
CALIBRATION_FRACTION = 0.2
DAMPING_CREDIT = 0.5
"""The share of the device's declared damping the passivity observer credits: half, so that a
declared value twice too large still leaves the controller working."""


@dataclass(frozen=True, slots=True)
class LoopConfig:
    rate_hz: float = 1000.0
    duration_s: float = 10.0
    calibrate: bool = True
    passivity: bool = True
    """The passivity controller (off only to show, in tests, what it does)."""
    guard: bool = True
    """The oscillation guard (off only to show, in tests, what it prevents)."""
    polarity: tuple[float, ...] | None = None
    """Each axis's force polarity, where an identification measured it (then no polarity
    pulses are sent, whatever `calibrate` says)."""


@dataclass
class LoopSummary:
    periods: int
    overruns: int
    period_error_p50_us: float
    period_error_p99_us: float
    period_error_max_us: float
    peak_command: float
    """Largest command sent, device units (N, or Nm on a wheel)."""
    faults: list[str]
    gears: list[str]
    notes: list[str] = field(default_factory=list)
    stopped: str = "duration"
    time_at_limit_s: float = 0.0
    """Time any axis was commanded at its force limit."""
    oscillation_rms: float = 0.0
    """Largest 2-100 Hz rms of the command the oscillation guard saw (device units)."""
    passivity_acted_s: float = 0.0
    """Time the passivity controller added damping."""

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass(frozen=True, slots=True)
class SafetyChain:
    """The loop's safety chain, for an observer to read between ticks (never to change)."""

    limiter: ForceLimiter
    watchdog: Watchdog
    guard: OscillationGuard | None
    passivity: PassivityController | None


class LoopObserver(Protocol):
    """Watches a run from the loop's own thread (a live panel), at a bounded cost per tick.

    `started` is called once, before the start-up pulses; `tick` after every command with the
    row a recorder gets (the fade at the end included). `tick` returning True asks the loop to
    stop, through the same fade as a stop request."""

    def started(self, chain: SafetyChain) -> None: ...

    def tick(self, row: tuple[object, ...]) -> bool: ...


class PeriodErrors:
    """The ticks' period errors as counts per tenth of a microsecond: percentiles exact to
    that, in memory bounded by the spread of the errors, not the session's length (a list of
    every error grew a session 8 bytes a tick: 29 MB an hour)."""

    __slots__ = ("count", "counts", "largest")

    def __init__(self) -> None:
        self.counts: dict[int, int] = {}
        self.count = 0
        self.largest = -math.inf

    def add(self, error_us: float) -> None:
        key = round(error_us * 10.0)
        counts = self.counts
        counts[key] = counts.get(key, 0) + 1
        self.count += 1
        if error_us > self.largest:
            self.largest = error_us

    def percentile(self, fraction: float) -> float:
        """The error at `fraction` of the ticks, us (as the sorted list's element at that
        index), NaN without ticks."""
        if not self.count:
            return math.nan
        index = min(self.count - 1, int(fraction * self.count))
        seen = 0
        for key in sorted(self.counts):
            seen += self.counts[key]
            if seen > index:
                return key / 10.0
        return self.largest


def calibrate(
    device: Device,
    clock: Clock,
    period_ns: int,
    limiter: ForceLimiter,
    watchdog: Watchdog,
    origin_ns: int,
) -> list[float]:
    """Pulse each axis at a fifth of the limit; return +1 or -1 per axis (its force polarity).

    Range: every reading is checked by the watchdog (a NaN, or a reading beyond the device's
    travel, is a fault and the run does not start). Polarity: a pulse that moves the axis the
    wrong way means the device pushes against its commands; the sign then flips the commands
    (not the readings). The pulses go through the limiter, so they respect its slew too. Times
    are seconds since `origin_ns`, the run's start, as in the loop.
    """
    signs = []
    axes = device.info.axes
    dt = period_ns / 1e9
    deadline = clock.now_ns()

    def tick(commands: tuple[float, ...]) -> tuple[float, ...]:
        nonlocal deadline
        deadline += period_ns
        clock.sleep_until(deadline)
        t = (clock.now_ns() - origin_ns) / 1e9
        device.command(limiter.limit(commands, dt, CALIBRATION_FRACTION), t)
        positions = device.read(t).positions
        watchdog.check(positions, dt, t)
        return positions

    for axis in range(axes):
        start = tick((0.0,) * axes)[axis]
        way = 0.0
        pulse = [0.0] * axes
        pulse[axis] = CALIBRATION_FRACTION * limiter.limits.max_force
        departs = 0.005 * device.info.travel
        # The way the axis first moves, during the pulse or after it (a reading is a round trip
        # late: the pulse's motion shows once it is over).
        for _ in range(round(CALIBRATION_PULSE_S / dt)):
            moved = tick(tuple(pulse))[axis] - start
            way = way or (math.copysign(1.0, moved) if abs(moved) > departs else 0.0)
        # Let the axis come to rest before the next pulse (or the run).
        for _ in range(round(CALIBRATION_SETTLE_S / dt)):
            moved = tick((0.0,) * axes)[axis] - start
            way = way or (math.copysign(1.0, moved) if abs(moved) > departs else 0.0)
        signs.append(-1.0 if way < 0.0 else 1.0)
        if watchdog.faulted:
            break
    return signs + [1.0] * (axes - len(signs))


def run_loop(
    renderer: Renderer,
    device: Device,
    clock: Clock,
    config: LoopConfig,
    limits: SafetyLimits,
    recorder: Recorder | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    observer: LoopObserver | None = None,
    origin_ns: int | None = None,
) -> LoopSummary:
    """Run until the duration ends, `should_stop()` (or the observer) says so, or a fault has
    faded out. Times (the device's, the recording's) are seconds since `origin_ns` (the run's
    start, before any identification), or since the loop's start.

    The device is commanded to zero force before this returns, whatever happened.
    """
    period_ns = round(1e9 / config.rate_hz)
    dt = period_ns / 1e9
    axes = device.info.axes
    limiter = ForceLimiter(limits, axes)
    watchdog = Watchdog(limits, device.info.travel)
    info = device.info
    round_trip = math.ceil((info.command_delay_s + info.reading_delay_s) * config.rate_hz - 1e-6)
    guard = (
        OscillationGuard(
            axes, limits.max_force, info.travel, config.rate_hz, round_trip_ticks=round_trip
        )
        if config.guard
        else None
    )
    passivity = (
        PassivityController(
            axes,
            DAMPING_CREDIT * info.damping,
            deadband=1e-3 * limits.max_force * info.travel,
            # What one spring holding the device's force within its travel stores at most
            # (F^2 / 2K <= F * travel / 2 for K >= F / travel): a hand letting go of any
            # rendering's spring gives back no more than this.
            ceiling=0.5 * limits.max_force * info.travel,
            round_trip_ticks=round_trip,
        )
        if config.passivity
        else None
    )
    at_limit = 0
    top = 0.999 * limits.max_force
    notes: list[str] = []
    errors = PeriodErrors()
    overruns = 0
    max_force = 0.0
    stopped = "duration"
    polarity = list(config.polarity) if config.polarity is not None else [1.0] * axes
    asked = False
    if observer is not None:
        observer.started(SafetyChain(limiter, watchdog, guard, passivity))
    # Collected and frozen before the clock starts: a collection takes milliseconds, and a
    # device's time (a virtual plant integrates up to it) must not jump by that at the first tick.
    gc.collect()
    gc.freeze()
    # The recorder's writer thread formats a block of rows every 0.5 s: at the default 5 ms
    # switch interval it kept the GIL from the loop for 9-11 ms each time (measured); 0.2 ms
    # hands the GIL back to the loop within a fraction of a period.
    switch = sys.getswitchinterval()
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    origin = clock.now_ns() if origin_ns is None else origin_ns
    try:
        if config.calibrate and config.polarity is None:
            polarity = calibrate(device, clock, period_ns, limiter, watchdog, origin)
            for axis, sign in enumerate(polarity):
                if sign < 0:
                    notes.append(
                        f"axis {axis} moved against its command: its force is inverted from now on"
                    )
            if watchdog.faulted:
                stopped = "fault"
                return _summary(PeriodErrors(), 0, 0.0, watchdog, renderer, notes, stopped)
        start = clock.now_ns()
        last = start
        ticks = round(config.duration_s * config.rate_hz)
        # A renderer that measures (telemetry's packet-to-force latency) is told when each
        # tick's commands went out: on the wall clock only (simulated time has no latency).
        commanded: Callable[[int], None] | None = (
            getattr(renderer, "commanded", None) if isinstance(clock, WallClock) else None
        )
        for k in range(1, ticks + 1):
            deadline = start + k * period_ns
            clock.sleep_until(deadline)
            now = clock.now_ns()
            period = now - last
            last = now
            errors.add((period - period_ns) / 1e3)
            overrun = period > OVERRUN_FACTOR * period_ns
            overruns += overrun
            t = (now - origin) / 1e9
            try:
                sample = device.read(t)
            except DeviceLost as exc:
                watchdog.fault(f"device lost: {exc}")
                stopped = "fault"
                break
            positions = sample.positions
            watchdog.check(positions, period / 1e9, t)
            if watchdog.faulted:
                # Hold the model; fade what the device renders.
                envelope = watchdog.envelope(dt)
                commands = tuple(f * envelope for f in limiter.last)
                row: tuple[object, ...] = (math.nan,) * len(renderer.columns)
            else:
                commands, row = renderer.tick(sample, dt)
                envelope = 1.0
                if not all(math.isfinite(c) for c in commands):
                    watchdog.fault(f"the model gave a non-finite force at t = {t:.3f} s")
                elif passivity is not None:
                    commands = passivity.apply(commands, positions, dt)
            ramp = limits.start_fraction + (1.0 - limits.start_fraction) * min(
                1.0, (now - start) / 1e9 / limits.ramp_s
            )
            safe = limiter.limit(
                commands, dt, scale=min(ramp, envelope if watchdog.faulted else 1.0)
            )
            try:
                device.command(tuple(f * s for f, s in zip(safe, polarity, strict=True)), t)
            except DeviceLost as exc:
                watchdog.fault(f"device lost: {exc}")
                stopped = "fault"
                break
            if commanded is not None:
                commanded(clock.now_ns())
            max_force = max(max_force, *(abs(f) for f in safe))
            at_limit += any(abs(f) >= top for f in safe)
            if passivity is not None:
                passivity.applied(safe)
            if guard is not None and not watchdog.faulted:
                # What the rendering asks (before the limiter clips a swing's peaks flat and
                # hides whether it dies down), less the vibrations it renders on purpose; and
                # what the device was sent.
                effect = renderer.effect
                heard = (commands[0] - effect, *commands[1:]) if effect else commands
                trouble = guard.check(heard, positions, dt, safe)
                if trouble is not None:
                    watchdog.fault(f"{trouble} at t = {t:.3f} s")
            if recorder is not None:
                recorder.append((t, int(overrun), *safe, int(watchdog.faulted), *row))
            if observer is not None:
                asked = observer.tick((t, int(overrun), *safe, int(watchdog.faulted), *row))
            if watchdog.finished:
                stopped = "fault"
                break
            if asked or should_stop():
                stopped = "stopped"
                break
        if stopped != "fault":
            # A normal end, or a stop request: take the force away within the slew limit.
            # The ramp is recorded, so the fade can be checked from the file.
            deadline = clock.now_ns()
            blank = (math.nan,) * len(renderer.columns)
            while any(f != 0.0 for f in limiter.last):
                deadline += period_ns
                clock.sleep_until(deadline)
                t = (clock.now_ns() - origin) / 1e9
                safe = limiter.limit((0.0,) * axes, dt)
                device.command(tuple(f * s for f, s in zip(safe, polarity, strict=True)), t)
                if recorder is not None:
                    recorder.append((t, 0, *safe, int(watchdog.faulted), *blank))
                if observer is not None:
                    observer.tick((t, 0, *safe, int(watchdog.faulted), *blank))
    finally:
        gc.unfreeze()
        sys.setswitchinterval(switch)
        with contextlib.suppress(DeviceLost):  # a lost device renders nothing anyway
            device.command((0.0,) * axes, (clock.now_ns() - origin) / 1e9)
    summary = _summary(errors, overruns, max_force, watchdog, renderer, notes, stopped)
    summary.time_at_limit_s = at_limit * dt
    summary.oscillation_rms = guard.worst_rms if guard is not None else math.nan
    summary.passivity_acted_s = passivity.acted_s if passivity is not None else 0.0
    return summary


def _summary(
    errors: PeriodErrors,
    overruns: int,
    max_force: float,
    watchdog: Watchdog,
    renderer: Renderer,
    notes: list[str],
    stopped: str,
) -> LoopSummary:
    return LoopSummary(
        periods=errors.count,
        overruns=overruns,
        period_error_p50_us=errors.percentile(0.5),
        period_error_p99_us=errors.percentile(0.99),
        period_error_max_us=errors.largest if errors.count else math.nan,
        peak_command=max_force,
        faults=list(watchdog.faults),
        gears=list(renderer.gears),
        notes=notes,
        stopped=stopped,
    )
