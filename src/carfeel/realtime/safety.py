"""Safety: never hurt a hand, never leave a force on.

- `ForceLimiter`: every command is clipped to the largest force and then to the largest change
  per step (slew); a NaN or infinite command counts as zero. It holds for any input sequence
  (a property test checks it).
- `Watchdog`: a fault (a stall of the loop, a NaN or out-of-range reading, a lost device) starts a
  fade: the force envelope goes linearly from 1 to 0 within `fade_s`, and the run stops. A stall
  cannot be answered while it lasts; the devices' own hold time (their effects end by themselves)
  covers it, and on the next tick the watchdog fades from there.
- Ramp-in: after the start-up calibration the largest force rises from `start_fraction` of the
  limit to all of it over `ramp_s`.
- `PassivityController` (after Hannaford & Ryu 2002), per axis, the second line of defence
  behind the sizing (`stability.py`): it counts the work the device's force does on the handle;
  when the rendering has put out more energy than it took in (and the device burnt), it lowers
  the force until the books balance again.
- `OscillationGuard`: any sustained oscillation of the command, 2-100 Hz, the handle still or
  swinging end to end (regular half-cycles over a tenth of the limit that do not die down while
  the rendering feeds them; the limit reached both ways; a buzz) is a fault like any other: the
  force fades to zero and the run reports it.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass

from carfeel.realtime.filters import SosFilter, bandpass


@dataclass(frozen=True, slots=True)
class SafetyLimits:
    max_force: float
    """Largest force (N) or torque (Nm) per axis, device units."""
    max_slew_per_s: float
    """Largest change of the command per second."""
    fade_s: float = 0.05
    stall_s: float = 0.02
    """A tick later than this after the previous one is a stall."""
    range_margin: float = 0.1
    """A reading beyond (1 + margin) x the device's travel is out of range."""
    ramp_s: float = 1.0
    start_fraction: float = 0.2


class ForceLimiter:
    """Clip to the largest force, then to the largest slew, per axis."""

    __slots__ = ("_last", "limits")

    def __init__(self, limits: SafetyLimits, axes: int) -> None:
        self.limits = limits
        self._last = [0.0] * axes

    @property
    def last(self) -> tuple[float, ...]:
        return tuple(self._last)

    def limit(
        self, commands: tuple[float, ...], dt_s: float, scale: float = 1.0
    ) -> tuple[float, ...]:
        """The commands made safe; `scale` (0..1) lowers the largest force (ramp-in, fade)."""
        top = self.limits.max_force * min(1.0, max(0.0, scale))
        step = self.limits.max_slew_per_s * dt_s
        out = []
        for i, wanted in enumerate(commands):
            if not math.isfinite(wanted):
                wanted = 0.0
            wanted = min(top, max(-top, wanted))
            last = self._last[i]
            value = min(last + step, max(last - step, wanted))
            # A lowered ceiling (fade) wins over the slew: never above the ceiling.
            value = min(top, max(-top, value)) if abs(value) > top else value
            self._last[i] = value
            out.append(value)
        return tuple(out)


class Watchdog:
    """Watches each tick; after a fault, `envelope` fades from 1 to 0 over `fade_s`."""

    __slots__ = ("_fade_left", "faults", "limits", "travel")

    def __init__(self, limits: SafetyLimits, travel: float) -> None:
        self.limits = limits
        self.travel = travel
        self.faults: list[str] = []
        self._fade_left: float | None = None

    @property
    def faulted(self) -> bool:
        return self._fade_left is not None

    def fault(self, reason: str) -> None:
        """Start the fade; the first fault is the one reported (later ones follow from it)."""
        if self._fade_left is None:
            self.faults.append(reason)
            self._fade_left = self.limits.fade_s

    def check(self, positions: tuple[float, ...], period_s: float, time_s: float) -> None:
        """Record a fault for a stall or a bad reading at this tick."""
        if period_s > self.limits.stall_s:
            self.fault(
                f"stall: {period_s * 1e3:.1f} ms between ticks at t = {time_s:.3f} s (the loop "
                f"was not run for longer than {self.limits.stall_s * 1e3:g} ms: the machine is "
                "busy. Close other programs, give the loop a core of its own (--loop-cpu N), or "
                "run it where real-time scheduling is allowed: see the run's 'scheduling' note)"
            )
        bound = self.travel * (1.0 + self.limits.range_margin)
        for axis, value in enumerate(positions):
            if not math.isfinite(value):
                self.fault(f"axis {axis} read {value} at t = {time_s:.3f} s")
            elif abs(value) > bound:
                self.fault(
                    f"axis {axis} read {value:.4g}, beyond the travel {self.travel:g} at "
                    f"t = {time_s:.3f} s"
                )

    def envelope(self, dt_s: float) -> float:
        """1 before any fault; then down to 0 linearly over fade_s, one tick at a time."""
        if self._fade_left is None:
            return 1.0
        self._fade_left = max(0.0, self._fade_left - dt_s)
        return self._fade_left / self.limits.fade_s

    @property
    def finished(self) -> bool:
        """The fade is over: the force is zero and the run should stop."""
        return self._fade_left is not None and self._fade_left <= 0.0


RECOVERY_S = 0.25
"""Time constant (s) with which the passivity controller's energy deficit decays to its
deadband: a force it cut comes back, not never."""


class PassivityController:
    """Passivity observer and controller per axis (after Hannaford & Ryu, IEEE T-RO 2002).

    Observer: the energy the rendering has taken from the handle, device units (J):
        E += -u_{k-1-n} * (x_k - x_{k-1}) + b * (x_k - x_{k-1})^2 / T
    the work the handle did on the rendering over the tick the reading describes (a reading is
    the handle as it was n ticks of round trip ago, and the force acting on it then is the one
    commanded n ticks before this one: the delayed form of Ryu, Artigas & Preusche 2010), plus
    what the device's own damping b dissipated (the plant is passive; the rendering may spend
    what it burns). A rendering that is passive with the device keeps E >= 0.
    Controller: with a few ms of round trip a damper comes too late to dissipate at a limit
    cycle's frequency (its phase turns it into a spring or worse), so the controller scales the
    force down instead, from 1 at E = -deadband to 0 at E = -(deadband + band): the energy a
    rendering can put out is bounded. E is capped above at `ceiling` so that energy stored long
    ago cannot hide new generation; the ceiling must hold what a rendering's spring stores from
    the hand (a sized coupling pushed to the device's force: F^2 / 2K), or a hand letting go of
    it reads as generation. A deficit decays toward the deadband with RECOVERY_S: with the force
    cut, a handle at rest does no work, so without it a rendering cut once would stay dead (the
    handle left off its rest) until the hand did work against a force that is not there. The
    deficit is remembered whole (no floor): a deep one, a limit cycle's, takes RECOVERY_S *
    ln(deficit / band) to come back, and the cycle does not resume at once.
    """

    __slots__ = ("_commands", "_energy", "_last_position", "acted_s", "band", "ceiling",
                 "damping", "deadband")  # fmt: skip

    def __init__(
        self,
        axes: int,
        damping: float,
        deadband: float,
        ceiling: float,
        round_trip_ticks: int = 0,
    ) -> None:
        self.damping = damping
        self.deadband = deadband
        self.band = 4.0 * deadband
        self.ceiling = ceiling
        self._energy = [0.0] * axes
        self._commands = [deque([0.0] * (round_trip_ticks + 1)) for _ in range(axes)]
        """Per axis, the commands of the last round trip, oldest first."""
        self._last_position: list[float | None] = [None] * axes
        self.acted_s = 0.0
        """Time during which the controller lowered the force, s."""

    @property
    def energy(self) -> tuple[float, ...]:
        return tuple(self._energy)

    def apply(
        self, commands: tuple[float, ...], positions: tuple[float, ...], dt_s: float
    ) -> tuple[float, ...]:
        out = []
        acted = False
        for i, (u, x) in enumerate(zip(commands, positions, strict=True)):
            last = self._last_position[i]
            moved = 0.0 if last is None or not math.isfinite(x) else x - last
            self._last_position[i] = x if math.isfinite(x) else last
            gained = -self._commands[i][0] * moved + self.damping * moved * moved / dt_s
            energy = min(self.ceiling, self._energy[i] + gained)
            if energy < -self.deadband:  # a deficit recovers (a cut force does no work)
                energy += (-self.deadband - energy) * min(1.0, dt_s / RECOVERY_S)
            self._energy[i] = energy
            if energy < -self.deadband:
                scale = max(0.0, 1.0 - (-energy - self.deadband) / self.band)
                u *= scale
                acted = True
            out.append(u)
        if acted:
            self.acted_s += dt_s
        return tuple(out)

    def applied(self, commands: tuple[float, ...]) -> None:
        """What the device was really commanded this tick (after the limiter): the observer's
        u. Call once per tick, after `apply`."""
        for i, u in enumerate(commands):
            past = self._commands[i]
            past.popleft()
            past.append(u)


class OscillationGuard:
    """A fault for any sustained oscillation on any axis, 2-100 Hz, with the handle still or
    swinging end to end. Per axis, the command the rendering asks (less the vibrations the
    model renders on purpose; before the limiter, which would clip a swing's peaks flat and
    hide whether it dies down) goes through a 2-100 Hz band-pass, and three rules watch it:

    - cycles: CYCLES half-cycles in a row, each swinging over `force_fraction` of the force
      limit, none below DECAY of the one before (a sized loop's ringing, zeta >= 0.2, halves
      each half-cycle; DECAY is zeta 0.07), at a steady pace; below VOLUNTARY_HZ (as slow as a
      hand shakes a lever) also while the rendering puts energy into the handle over them (the
      work of the force commanded one round trip earlier on the handle's motion, over what
      passes between them: at least INJECTION of it, and that much more than it ever took in:
      its energy account, capped at what one spring can store) or the handle barely moves: a
      hand shaking the lever against a rendering that absorbs what the hand puts in, or letting
      go of one it stretched, is not an oscillation of the loop. Below VOLUNTARY_HZ two such
      half-cycles suffice at over half the force limit: a full-force limit cycle fades within
      0.2 s of its onset at every pace.
    - saturation: the command sent at the force limit both ways for more than `saturated_s`
      within `saturation_window_s` (a bang-bang limit cycle; one way only is a hand pushing;
      a ringing that dies down leaves the limit sooner).
    - buzz: the 10-100 Hz rms over `window_s` above `force_fraction` of the limit for `hold_s`
      while the handle barely moves (an irregular chatter the cycles rule does not see).
    """

    BAND_HZ = (2.0, 100.0)
    BUZZ_HZ = (10.0, 100.0)
    """The buzz rule's band: chatter, above what a released device's own ringing is."""
    CYCLES = 3
    DECAY = 0.8
    INJECTION = 0.2
    PACE = 2.5
    """Successive half-cycles' durations within this ratio of one another: a steady pace."""
    VOLUNTARY_HZ = 6.0
    """Below this a hand can shake a lever on purpose: there the rule also asks that the
    rendering feed the oscillation. Above it, a sustained regular swing is the loop's."""

    def __init__(
        self,
        axes: int,
        max_force: float,
        travel: float,
        rate_hz: float,
        force_fraction: float = 0.1,
        motion_fraction: float = 0.1,
        hold_s: float = 0.5,
        window_s: float = 0.1,
        round_trip_ticks: int = 0,
        saturated_s: float = 0.2,
        saturation_window_s: float = 0.4,
    ) -> None:
        low, high = self.BAND_HZ
        high = min(high, 0.45 * rate_hz)
        self.band_hz = (low, high)
        self._band: list[SosFilter] = [bandpass(low, high, rate_hz) for _ in range(axes)]
        self._band_motion: list[SosFilter] = [bandpass(low, high, rate_hz) for _ in range(axes)]
        buzz_low, _ = self.BUZZ_HZ
        self._force: list[SosFilter] = [bandpass(buzz_low, high, rate_hz) for _ in range(axes)]
        self._motion: list[SosFilter] = [bandpass(buzz_low, high, rate_hz) for _ in range(axes)]
        self._force_ms = [0.0] * axes
        self._motion_ms = [0.0] * axes
        self._alpha = min(1.0, 1.0 / (window_s * rate_hz))
        self.max_force = max_force
        self.force_limit = (force_fraction * max_force) ** 2
        self.motion_limit = (motion_fraction * travel) ** 2
        self._band_ms = [0.0] * axes
        self.hold_s = hold_s
        self.force_fraction = force_fraction
        self.swing = force_fraction * max_force
        self.hysteresis = 0.02 * max_force
        self.longest_half_s = 0.5 / low
        self.shortest_half_s = 0.5 / high
        self.still = (0.02 * travel) ** 2
        """Below this mean square band motion the handle is still (the injection is moot)."""
        self._for = 0.0
        self._time = 0.0
        # Per axis: the open half-cycle's sign, start, extreme, work done and work passed, and
        # the last closed ones: (amplitude, duration, work done, work passed).
        self._sign = [0] * axes
        self._start = [0.0] * axes
        self._extreme = [0.0] * axes
        self._work = [0.0] * axes
        self._passed = [0.0] * axes
        self._halves: list[deque[tuple[float, float, float, float]]] = [
            deque(maxlen=self.CYCLES - 1) for _ in range(axes)
        ]
        self._commands = [deque([0.0] * (round_trip_ticks + 1)) for _ in range(axes)]
        self._last_x: list[float | None] = [None] * axes
        self._account = [0.0] * axes
        """Per axis, the energy the rendering took from the handle less what it gave, capped
        at `stored` (the passivity controller's account, without its damping credit)."""
        self.stored = 0.5 * max_force * travel
        """The most one spring holding the force limit within the travel stores: what a hand
        can leave in a rendering and get back."""
        ticks = max(1, round(saturation_window_s * rate_hz))
        self._saturation: list[deque[int]] = [deque([0] * ticks, maxlen=ticks) for _ in range(axes)]
        self._plus = [0] * axes
        self._minus = [0] * axes
        self._saturated_ticks = saturated_s * rate_hz
        self.top = 0.999 * max_force
        self.worst_rms = 0.0
        """Largest smoothed band rms of the command seen, device units (for the summary)."""

    @property
    def current_rms(self) -> float:
        """The largest smoothed band rms of the command now, device units (a live view)."""
        return math.sqrt(max(self._force_ms))

    @property
    def held_s(self) -> float:
        """How long the buzz condition has held so far (a fault past hold_s)."""
        return self._for

    def check(
        self,
        commands: tuple[float, ...],
        positions: tuple[float, ...],
        dt_s: float,
        sent: tuple[float, ...] | None = None,
    ) -> str | None:
        """A fault message once an oscillation is sustained, else None. `commands` are what
        the rendering asks this tick (before the limiter: its swings' peaks as they are),
        `sent` what the device was sent (after it; the same if None), `positions` this tick's
        readings."""
        a = self._alpha
        self._time += dt_s
        buzzing = False
        trouble = None
        sent = commands if sent is None else sent
        for i, (wanted, u, x) in enumerate(zip(commands, sent, positions, strict=True)):
            wanted = wanted if math.isfinite(wanted) else 0.0
            u = u if math.isfinite(u) else 0.0
            x_ok = math.isfinite(x)
            band = self._band[i].step(wanted)
            swing = self._band_motion[i].step(x if x_ok else 0.0)
            self._band_ms[i] += a * (swing * swing - self._band_ms[i])
            f = self._force[i].step(wanted)
            m = self._motion[i].step(x if x_ok else 0.0)
            self._force_ms[i] += a * (f * f - self._force_ms[i])
            self._motion_ms[i] += a * (m * m - self._motion_ms[i])
            self.worst_rms = max(self.worst_rms, math.sqrt(self._force_ms[i]))
            if self._force_ms[i] > self.force_limit and self._motion_ms[i] < self.motion_limit:
                buzzing = True
            # The work of the force that acts on the handle now (commanded a round trip ago).
            past = self._commands[i]
            last = self._last_x[i]
            moved = 0.0 if last is None or not x_ok else x - last
            if x_ok:
                self._last_x[i] = x
            work = past[0] * moved
            self._account[i] = min(self.stored, self._account[i] - work)
            past.popleft()
            past.append(u)
            trouble = trouble or self._cycles(i, band, work) or self._saturated(i, u)
        self._for = self._for + dt_s if buzzing else 0.0
        if trouble is None and self._for > self.hold_s:
            rms = max(math.sqrt(v) for v in self._force_ms)
            trouble = (
                f"oscillation: the command's {self.BUZZ_HZ[0]:g}-{self.band_hz[1]:g} Hz content "
                f"held {rms:.3g} rms (over {self.force_fraction:.0%} of the force limit) for "
                f"{self._for:.2f} s while the handle barely moved: a limit cycle"
            )
        return trouble

    def _cycles(self, i: int, f: float, work: float) -> str | None:
        sign = self._sign[i]
        self._work[i] += work
        self._passed[i] += abs(work)
        if sign == 0:
            if abs(f) > self.hysteresis:
                self._open(i, 1 if f > 0 else -1)
            return None
        self._extreme[i] = max(self._extreme[i], sign * f)
        duration = self._time - self._start[i]
        if duration > self.longest_half_s:
            # Slower than the band: no oscillation; the chain starts again.
            self._halves[i].clear()
            self._open(i, sign)
            return None
        if sign * f < -self.hysteresis:  # crossed over: the half-cycle is complete
            self._halves[i].append((self._extreme[i], duration, self._work[i], self._passed[i]))
            self._open(i, -sign)
            return None
        # The open half-cycle judged at its peak, with those before it: no need to wait for
        # its end (a full-force cycle must fade within a period).
        halves = self._halves[i]
        if not halves:
            return None
        amplitude = self._extreme[i]
        # Slower than a hand's pace and at over half the limit, two half-cycles (then the
        # rendering must be seen feeding them, below): three would take longer than a
        # full-force limit cycle may last.
        slow = halves[-1][1] > 0.5 / self.VOLUNTARY_HZ
        needed = 1 if slow and amplitude >= 0.5 * self.max_force else self.CYCLES - 1
        if len(halves) < needed:
            return None
        recent = list(halves)[-needed:]
        swings = [h[0] for h in recent] + [amplitude]
        if min(swings) < self.swing:
            return None
        if any(b < self.DECAY * a for a, b in itertools.pairwise(swings)):
            return None
        times = [h[1] for h in recent]
        if min(times) < self.shortest_half_s or max(times) > self.PACE * min(times):
            return None
        if duration < 0.5 * min(times):  # not yet at this half-cycle's peak
            return None
        frequency = 0.5 / (sum(times) / len(times))
        if frequency < self.VOLUNTARY_HZ and self._band_ms[i] > self.still:
            # As slow as a hand can shake a lever: an oscillation of the loop only where the
            # rendering feeds it. (At these frequencies the work is sound even if the device's
            # true delay is not the one told: the phase it costs is small.)
            done = sum(h[2] for h in recent) + self._work[i]
            passed = sum(h[3] for h in recent) + self._passed[i]
            if done < self.INJECTION * passed:
                return None  # the rendering takes in what moves it: a hand, not the loop
            if self._account[i] > -self.INJECTION * passed:
                # It gives back what a hand stored in it (let go of a stretched coupling, the
                # handle swings home): over all it has not put out INJECTION of what passed
                # more than it took in (a loop's cycle from rest has, by the test above).
                return None
        return (
            f"oscillation: axis {i} swung {len(swings)} half-cycles in a row at {frequency:.3g} "
            f"Hz, each over {self.force_fraction:.0%} of the force limit (the last "
            f"{amplitude:.3g}) and none dying down: a limit cycle"
        )

    def _open(self, i: int, sign: int) -> None:
        self._sign[i] = sign
        self._start[i] = self._time
        self._extreme[i] = 0.0
        self._work[i] = self._passed[i] = 0.0

    def _saturated(self, i: int, u: float) -> str | None:
        now = 1 if u >= self.top else -1 if u <= -self.top else 0
        window = self._saturation[i]
        gone = window[0]
        window.append(now)
        self._plus[i] += (now == 1) - (gone == 1)
        self._minus[i] += (now == -1) - (gone == -1)
        plus, minus = self._plus[i], self._minus[i]
        if plus and minus and plus + minus > self._saturated_ticks:
            return (
                f"oscillation: axis {i} was at its force limit both ways for "
                f"{(plus + minus) / len(window) * 100:.0f} % of the last "
                f"{len(window)} ticks: a limit cycle at full force"
            )
        return None
