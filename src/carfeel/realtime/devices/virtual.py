"""Virtual devices: a 2-DOF force-feedback joystick and a force-feedback wheel, as plants.

They are what CI and a user without hardware run against, and what the tests drive in simulated
time. A simulated hand holds the handle (or the rim) and pushes on it as a person would, so the
coupled system (hand, device, loop, model) is exercised as a real one.

Per axis (a joystick's or a shifter's knob in m and N, a wheel's rim in rad and Nm):
    m * a = F_motor(t - delay) + F_hand - b * v - F_coulomb - F_stop(x)
    m = handle mass + motor inertia * transmission ratio          (reflected at the handle)
    the motor saturates at max_force; end stops are stiff springs beyond +-travel;
    Coulomb friction sticks (implicitly, as in the models) below its level;
    positions are sampled at the report rate, delayed, read with Gaussian noise and an ADC
    of `adc_bits` over the range: a reading is `delay` old and held between reports.
The delay acts both ways (commands and readings), as USB, a driver and a device's firmware do.

The catalogue (`PLANTS`, `--device virtual:KIND`): `joystick` (the paper's Wingman-class
2-DOF joystick), `wheel` (a belt-driven 4 Nm wheel), `dd-wheel` (a direct-drive wheel) and
`shifter` (an active H-shifter at the knob). Each number says where it comes from.

What carfeel is *told* about a device (its `info`: mass, damping, delays, report rate) and what
the device *is* (the plant it integrates) can differ, as they do for every real device:
`virtual:KIND:KEY=VALUE[,KEY=VALUE...]` (`parse_virtual`) changes the true plant only, with
`mass` (the moving inertia at the handle, kg or kg m^2), `damping`, `friction` (Coulomb, N or
Nm), `delay_ms` (each way), `report_hz`, `report_phase` (when in a tick the reports are taken,
0..1 of a report period; by default drawn from the seed), `grip` (a spring to the handle's
start, N/m or Nm/rad: a stiff hand clamped on it) and `grip_damping` (its damper); a value
ending in `x` is relative to the
catalogue's (`virtual:dd-wheel:mass=0.5x,delay_ms=6`). The device still tells the catalogue's
figures.

Commands are held for `hold_s` only: a device not commanded again lets its force go to zero,
like the finite-length effects of the evdev and SDL2 backends. `fail_at_s` makes the device
vanish (DeviceLost) and `nan_at_s` makes it read NaN, for the watchdog's tests.
"""

from __future__ import annotations

import math
import random
from collections import deque
from dataclasses import dataclass, replace
from types import TracebackType
from typing import Protocol

from carfeel.realtime.devices.base import DeviceInfo, DeviceLost, DeviceSample

SUBSTEP_S = 1e-4
"""The plants are integrated at 10 kHz between the loop's ticks."""


class Hand(Protocol):
    """A simulated hand on the device: its forces (device units) given the device's motion."""

    def forces(
        self, time_s: float, positions: tuple[float, ...], velocities: tuple[float, ...]
    ) -> tuple[float, ...]: ...


@dataclass(frozen=True, slots=True)
class PlantParams:
    """One axis of a device, in its own units (m and N, or rad and Nm)."""

    handle_mass: float
    """kg (or kg m^2 for a wheel rim)."""
    motor_inertia: float
    """Motor rotor inertia, kg m^2."""
    transmission_ratio: float
    """Reflected inertia per motor inertia: (capstan ratio / lever arm)^2 for the joystick
    (1/m^2), the belt ratio squared for a wheel."""
    damping: float
    """Physical damping of the axis, N*s/m (or Nm*s/rad)."""
    max_force: float
    travel: float
    stop_stiffness: float
    noise: float
    """Standard deviation of the position reading (potentiometer noise)."""
    adc_bits: int
    """Resolution of the reading over the whole range (-travel .. +travel)."""
    delay_s: float
    """Transport delay each way: commands reach the motor, and readings reach the loop, this
    late (USB, driver, firmware)."""
    coulomb: float = 0.0
    """Coulomb friction of the axis (bearings, gears, belt), N or Nm."""
    report_hz: float = 1000.0
    """Position reports per second; readings are held in between."""
    grip: float = 0.0
    """A spring from the handle to where it started, N/m (or Nm/rad): a stiff hand clamped on
    it, or a device's own centring spring. Not in the catalogue's plants (0)."""
    grip_damping: float = 0.0
    """The grip's damping, N*s/m (or Nm*s/rad): a hand's tissue damps what it holds."""
    report_phase: float | None = None
    """When in the loop's tick the reports are taken, a share of a report period: a device's
    clock is its own. None: drawn from the device's seed."""

    @property
    def mass(self) -> float:
        """Mass (or inertia) the motor and the hand move, reflected at the handle."""
        return self.handle_mass + self.motor_inertia * self.transmission_ratio


# A 2-DOF joystick like the paper's Wingman Force Feedback: about 10 N at the knob, +-40 mm.
# Force and travel from the paper (10 N class, a hand-sized throw); mass, damping and friction
# are assumptions of the right order for a capstan-driven gimbal (not published); a 10-bit
# potentiometer ADC as in joysticks of its age.
WINGMAN = PlantParams(
    handle_mass=0.08,
    motor_inertia=2e-6,
    transmission_ratio=1e4,  # a 10:1 capstan on a 0.1 m lever: (10 / 0.1)^2 1/m^2
    damping=3.0,
    max_force=10.0,
    travel=0.04,
    stop_stiffness=5000.0,
    noise=5e-5,
    adc_bits=10,
    delay_s=0.002,
    coulomb=0.15,
)

# A belt-driven force-feedback wheel of the sim-racing kind (Thrustmaster T300 class): 4 Nm
# peak, +-450 deg (the makers' figures); rim and pulley inertia, belt damping and friction are
# assumptions; a 16-bit encoder over the range.
BELT_WHEEL = PlantParams(
    handle_mass=0.04,
    motor_inertia=1e-5,
    transmission_ratio=100.0,  # a 10:1 belt
    damping=0.05,
    max_force=4.0,
    travel=math.radians(450.0),
    stop_stiffness=200.0,
    noise=0.0,
    adc_bits=16,
    delay_s=0.002,
    coulomb=0.03,
)

# A direct-drive wheel (Simucube 2 Sport / Fanatec DD1 class): 15 Nm (their 8-20 Nm range),
# a 0.05 kg m^2 rim and rotor (a 300 mm rim of about 1.2 kg plus the rotor), little damping and
# friction (no gears or belt: assumptions), a 22-bit encoder per turn (the makers' figure),
# +-900 deg of software travel, a stiff stop.
DD_WHEEL = PlantParams(
    handle_mass=0.045,
    motor_inertia=0.005,
    transmission_ratio=1.0,
    damping=0.01,
    max_force=15.0,
    travel=math.radians(900.0),
    stop_stiffness=1000.0,
    noise=0.0,
    adc_bits=24,  # 22 bits per turn over +-2.5 turns
    delay_s=0.002,
    coulomb=0.005,
)

# An active H-shifter (the force-feedback shifters sim-racers build or buy): 2 DOF at the knob,
# 30 N per axis, +-50 mm; knob, lever and two motors reflected at the knob about 0.25 kg; gear
# and bearing damping and friction assumed; 12-bit position sensing.
SHIFTER = PlantParams(
    handle_mass=0.15,
    motor_inertia=1e-5,
    transmission_ratio=1e4,
    damping=6.0,
    max_force=30.0,
    travel=0.05,
    stop_stiffness=20000.0,
    noise=2e-5,
    adc_bits=12,
    delay_s=0.002,
    coulomb=0.3,
)

PLANTS: dict[str, tuple[PlantParams, int, str]] = {
    "joystick": (WINGMAN, 2, "joystick"),
    "wheel": (BELT_WHEEL, 1, "wheel"),
    "dd-wheel": (DD_WHEEL, 1, "wheel"),
    "shifter": (SHIFTER, 2, "joystick"),
}
"""--device virtual:KIND -> (plant, axes, device kind)."""


class VirtualDevice:
    """A device simulated as a plant per axis, held by a simulated hand."""

    def __init__(
        self,
        plant: PlantParams,
        axes: int,
        hand: Hand | None = None,
        *,
        kind: str = "joystick",
        name: str = "virtual joystick",
        update_hz: float = 1000.0,
        hold_s: float = 0.1,
        seed: int = 0,
        fail_at_s: float | None = None,
        nan_at_s: float | None = None,
        told: PlantParams | None = None,
        ident: str = "",
        log_limit: int | None = None,
        # None: keep the whole log (tests); 0: none (sessions).
    ) -> None:
        self.plant = plant
        """The plant integrated: what the device is."""
        self.told = told = plant if told is None else told
        """The plant `info` describes: what the device tells carfeel (its catalogue entry)."""
        self.hand = hand
        self.info = DeviceInfo(
            name, kind, axes, told.max_force, told.travel, update_hz, measures_force=False,
            mass=told.mass, damping=told.damping, command_delay_s=told.delay_s,
            reading_delay_s=told.delay_s, report_hz=told.report_hz,
            resolution=2.0 * told.travel / (1 << told.adc_bits), noise=told.noise,
            ident=ident or name,
        )  # fmt: skip
        self.hold_s = hold_s
        self.fail_at_s = fail_at_s
        self.nan_at_s = nan_at_s
        self._rng = random.Random(seed)
        self._time = 0.0
        self._steps = 0
        """Sub-steps integrated: the time is counted in them (a sum of 0.1 ms steps drifts by
        roundings, and a report at a tick's edge then came a tick late)."""
        self._x = [0.0] * axes
        self._v = [0.0] * axes
        self._queue: deque[tuple[float, tuple[float, ...]]] = deque()
        self._applied: tuple[float, ...] = (0.0,) * axes
        self._applied_at = -math.inf
        self._reports: deque[tuple[float, tuple[float, ...]]] = deque([(0.0, (0.0,) * axes)])
        phase = plant.report_phase
        self._next_report = (self._rng.random() if phase is None else phase) / plant.report_hz
        self.open = False
        self.keep_log = log_limit != 0
        """Whether `log` and `sent` are kept: a session's device keeps neither, so that its
        memory does not grow with the session."""
        self.log: list[tuple[float, tuple[float, ...], tuple[float, ...]]] = []
        """(time, true positions, motor forces) of every read, for tests."""
        self.sent: list[tuple[float, tuple[float, ...]]] = []
        """(time, forces) of every command, for tests."""

    def __enter__(self) -> VirtualDevice:
        self.open = True
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self._queue.clear()
        self._applied = (0.0,) * self.info.axes
        self.open = False

    @property
    def true_positions(self) -> tuple[float, ...]:
        return tuple(self._x)

    @property
    def motor_forces(self) -> tuple[float, ...]:
        """The forces the motors apply now (after delay, saturation and the hold)."""
        if self._time - self._applied_at > self.hold_s:
            return (0.0,) * self.info.axes
        top = self.plant.max_force
        return tuple(min(top, max(-top, f)) for f in self._applied)

    def _advance(self, time_s: float) -> None:
        p = self.plant
        mass = p.mass
        report_period = 1.0 / p.report_hz
        # The implicit Coulomb friction's largest velocity change in one sub-step.
        grip = SUBSTEP_S * p.coulomb / mass / (1.0 + SUBSTEP_S * p.damping / mass)
        while self._time + 0.5 * SUBSTEP_S < time_s:
            now = self._time
            if now + 0.5 * SUBSTEP_S >= self._next_report:
                # A report carries one sample of the sensor, noise and all, held until the
                # next (a reading between reports repeats it).
                self._reports.append((now, self._sample()))
                self._next_report += report_period
                while (
                    len(self._reports) > 1
                    and self._reports[1][0] + p.delay_s <= now - 0.5 * SUBSTEP_S
                ):
                    self._reports.popleft()
            while self._queue and self._queue[0][0] + p.delay_s <= now + 0.5 * SUBSTEP_S:
                sent, forces = self._queue.popleft()
                self._applied, self._applied_at = forces, sent + p.delay_s
            motor = self.motor_forces
            hand = (
                self.hand.forces(now, tuple(self._x), tuple(self._v))
                if self.hand is not None
                else (0.0,) * self.info.axes
            )
            for i in range(self.info.axes):
                x, v = self._x[i], self._v[i]
                stop = p.grip * x + p.grip_damping * v
                if x > p.travel:
                    stop += p.stop_stiffness * (x - p.travel)
                elif x < -p.travel:
                    stop += p.stop_stiffness * (x + p.travel)
                # Semi-implicit in the damping (stable for any damping at this step).
                v = (v + SUBSTEP_S * (motor[i] + hand[i] - stop) / mass) / (
                    1.0 + SUBSTEP_S * p.damping / mass
                )
                # Coulomb friction, implicit: it stops the axis within the step, or slows it.
                v = 0.0 if abs(v) <= grip else v - math.copysign(grip, v)
                self._v[i] = v
                self._x[i] = x + SUBSTEP_S * v
            self._steps += 1
            self._time = self._steps * SUBSTEP_S
        if self._time + 0.5 * SUBSTEP_S >= self._next_report:
            # A report due now is taken now: a reading with no delay sees the sensor as it is
            # (else every reading would be a tick older than the delay says).
            self._reports.append((self._time, self._sample()))
            self._next_report += report_period

    def _sample(self) -> tuple[float, ...]:
        """The sensor now: the true positions with noise, through the ADC."""
        p = self.plant
        lsb = 2.0 * p.travel / (1 << p.adc_bits)
        rng = self._rng
        return tuple(
            round((x + (rng.gauss(0.0, p.noise) if p.noise > 0.0 else 0.0)) / lsb) * lsb
            for x in self._x
        )

    def read(self, time_s: float) -> DeviceSample:
        if self.fail_at_s is not None and time_s >= self.fail_at_s:
            raise DeviceLost(f"{self.info.name} stopped answering at t = {time_s:.3f} s")
        self._advance(time_s)
        p = self.plant
        seen = self._reports[0][1]
        for when, positions in self._reports:  # the newest report old enough to have arrived
            if when + p.delay_s > time_s + 0.5 * SUBSTEP_S:
                break
            seen = positions
        readings = list(seen)
        if self.nan_at_s is not None and time_s >= self.nan_at_s:
            readings[0] = math.nan
        if self.keep_log:
            self.log.append((time_s, tuple(self._x), self.motor_forces))
        return DeviceSample(time_s, tuple(readings), None)

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        if self.fail_at_s is not None and time_s >= self.fail_at_s:
            raise DeviceLost(f"{self.info.name} stopped answering at t = {time_s:.3f} s")
        self._queue.append((time_s, tuple(forces)))
        if self.keep_log:
            self.sent.append((time_s, tuple(forces)))


TRUE_KEYS = {
    "mass": ("kg at a knob, kg*m^2 at a rim", 1e-4, 50.0),
    "damping": ("N*s/m or Nm*s/rad", 0.0, 1000.0),
    "friction": ("N or Nm of Coulomb friction", 0.0, 100.0),
    "delay_ms": ("ms each way", 0.0, 50.0),
    "report_hz": ("reports per second", 100.0, 10_000.0),
    "grip": ("N/m or Nm/rad of a spring to the start", 0.0, 1e5),
    "grip_damping": ("N*s/m or Nm*s/rad of the grip's damper", 0.0, 1000.0),
    "report_phase": ("of a report period", 0.0, 1.0),
}
"""The keys of `virtual:KIND:KEY=VALUE,...`: (unit, least, largest) of the absolute value."""


def parse_virtual(argument: str) -> tuple[str, dict[str, tuple[float, bool]]]:
    """`KIND[:KEY=VALUE,...]` -> (KIND, {key: (value, relative)}); `relative` when the value
    ends in `x` (a factor of the catalogue's). Bad keys and values raise ValueError with the
    allowed ones."""
    kind, _, rest = argument.partition(":")
    changes: dict[str, tuple[float, bool]] = {}
    for item in filter(None, rest.split(",")):
        key, equals, text = item.partition("=")
        key = key.strip()
        if key not in TRUE_KEYS or not equals:
            raise ValueError(
                f"{item!r}: expected KEY=VALUE with KEY one of {', '.join(TRUE_KEYS)} "
                "(a value ending in x is a factor of the catalogue's: mass=0.5x)"
            )
        if key in changes:
            raise ValueError(f"{key} is given twice")
        text = text.strip()
        relative = text.endswith("x")
        try:
            value = float(text[:-1] if relative else text)
        except ValueError:
            value = math.nan
        unit, low, high = TRUE_KEYS[key]
        if relative:
            if not (math.isfinite(value) and 0.0 <= value <= 100.0):
                raise ValueError(f"{key}={text}: a factor must be 0 <= value <= 100 (then x)")
        elif not (math.isfinite(value) and low <= value <= high):
            raise ValueError(f"{key}={text}: allowed {low:g} <= value <= {high:g} ({unit})")
        changes[key] = (value, relative)
    return kind, changes


def true_plant(plant: PlantParams, changes: dict[str, tuple[float, bool]]) -> PlantParams:
    """The catalogue's plant with the true values of `parse_virtual`'s changes."""

    def value(key: str, told: float) -> float:
        number, relative = changes[key]
        result = number * told if relative else number
        unit, low, high = TRUE_KEYS[key]
        if not low <= result <= high:
            raise ValueError(
                f"{key}={number:g}x is {result:g}: allowed {low:g} <= value <= {high:g} ({unit})"
            )
        return result

    if "mass" in changes:
        # Handle and motor scaled together: the same plant, heavier or lighter.
        factor = value("mass", plant.mass) / plant.mass
        plant = replace(
            plant, handle_mass=plant.handle_mass * factor,
            motor_inertia=plant.motor_inertia * factor,
        )  # fmt: skip
    if "damping" in changes:
        plant = replace(plant, damping=value("damping", plant.damping))
    if "friction" in changes:
        plant = replace(plant, coulomb=value("friction", plant.coulomb))
    if "delay_ms" in changes:
        plant = replace(plant, delay_s=value("delay_ms", plant.delay_s * 1e3) / 1e3)
    if "report_hz" in changes:
        plant = replace(plant, report_hz=value("report_hz", plant.report_hz))
    if "grip_damping" in changes:
        if changes["grip_damping"][1]:
            raise ValueError(
                "grip_damping: the catalogue's plants have none; give N*s/m or Nm*s/rad"
            )
        plant = replace(plant, grip_damping=value("grip_damping", 0.0))
    if "report_phase" in changes:
        if changes["report_phase"][1]:
            raise ValueError("report_phase: a share of a report period, 0..1 (no x)")
        plant = replace(plant, report_phase=value("report_phase", 0.0))
    if "grip" in changes:
        if changes["grip"][1]:
            raise ValueError("grip: the catalogue's plants have none; give N/m or Nm/rad")
        plant = replace(plant, grip=value("grip", 0.0))
    return plant


def virtual_device(
    kind: str,
    hand: Hand | None = None,
    delay_s: float | None = None,
    report_hz: float | None = None,
    true: dict[str, tuple[float, bool]] | None = None,
    **options: object,
) -> VirtualDevice:
    """A device of the catalogue, optionally with another delay (each way) or report rate
    (told and true alike), and a true plant unlike what it tells (`parse_virtual`'s changes)."""
    plant, axes, device_kind = PLANTS[kind]
    if delay_s is not None:
        plant = replace(plant, delay_s=delay_s)
    if report_hz is not None:
        plant = replace(plant, report_hz=report_hz)
    name = f"virtual {kind}"
    ident = f"virtual:{kind}:delay={plant.delay_s * 1e3:g}ms,report={plant.report_hz:g}Hz"
    if true:
        ident += "," + ",".join(
            f"{k}={v:g}{'x' if r else ''}" for k, (v, r) in sorted(true.items())
        )
    return VirtualDevice(
        true_plant(plant, true or {}), axes, hand, kind=device_kind, name=name, told=plant,
        ident=ident, **options,  # type: ignore[arg-type]
    )  # fmt: skip


def virtual_joystick(hand: Hand | None = None, **options: object) -> VirtualDevice:
    """The paper's 2-DOF joystick (about 10 N per axis, +-40 mm at the knob)."""
    return virtual_device("joystick", hand, **options)  # type: ignore[arg-type]


def virtual_wheel(hand: Hand | None = None, **options: object) -> VirtualDevice:
    """A belt-driven force-feedback wheel (4 Nm, +-450 deg)."""
    return virtual_device("wheel", hand, **options)  # type: ignore[arg-type]
