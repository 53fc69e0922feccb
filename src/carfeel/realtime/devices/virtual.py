"""Virtual devices: a 2-DOF force-feedback joystick and a force-feedback wheel, as plants.

They are what CI and a user without hardware run against, and what the tests drive in simulated
time. A simulated hand holds the handle (or the rim) and pushes on it as a person would, so the
coupled system (hand, device, loop, model) is exercised as a real one.

Joystick, per axis (the paper's Logitech Wingman, driven by a DSP):
    m * a = F_motor(t - delay) + F_hand - b * v - F_stop(x)
    m = handle mass + motor inertia * (capstan ratio / lever)^2   (reflected at the knob)
    the motor saturates at max_force_N; end stops are stiff springs beyond +-travel_m;
    positions are read through a potentiometer: Gaussian noise, then an ADC of `adc_bits`.
Wheel: the same for one rotation axis (rim inertia, motor torque limit, encoder counts, delay).

Commands are held for `hold_s` only: a device not commanded again lets its force go to zero,
like the finite-length effects of the evdev and SDL2 backends. `fail_at_s` makes the device
vanish (DeviceLost) and `nan_at_s` makes it read NaN, for the watchdog's tests.
"""

from __future__ import annotations

import math
import random
from collections import deque
from dataclasses import dataclass
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
    """Transport delay of the commands (USB and driver)."""

    @property
    def mass(self) -> float:
        """Mass (or inertia) the motor and the hand move, reflected at the handle."""
        return self.handle_mass + self.motor_inertia * self.transmission_ratio


# A 2-DOF joystick like the paper's Wingman Force Feedback: about 10 N at the knob, +-40 mm.
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
)

# A belt-driven force-feedback wheel of the sim-racing kind: 4 Nm, +-450 deg.
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
)


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
    ) -> None:
        self.plant = plant
        self.hand = hand
        self.info = DeviceInfo(
            name, kind, axes, plant.max_force, plant.travel, update_hz, measures_force=False
        )
        self.hold_s = hold_s
        self.fail_at_s = fail_at_s
        self.nan_at_s = nan_at_s
        self._rng = random.Random(seed)
        self._time = 0.0
        self._x = [0.0] * axes
        self._v = [0.0] * axes
        self._queue: deque[tuple[float, tuple[float, ...]]] = deque()
        self._applied: tuple[float, ...] = (0.0,) * axes
        self._applied_at = -math.inf
        self.open = False
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
        while self._time + 0.5 * SUBSTEP_S < time_s:
            now = self._time
            while self._queue and self._queue[0][0] + p.delay_s <= now:
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
                stop = 0.0
                if x > p.travel:
                    stop = p.stop_stiffness * (x - p.travel)
                elif x < -p.travel:
                    stop = p.stop_stiffness * (x + p.travel)
                # Semi-implicit in the damping (stable for any damping at this step).
                v = (v + SUBSTEP_S * (motor[i] + hand[i] - stop) / mass) / (
                    1.0 + SUBSTEP_S * p.damping / mass
                )
                self._v[i] = v
                self._x[i] = x + SUBSTEP_S * v
            self._time = now + SUBSTEP_S

    def read(self, time_s: float) -> DeviceSample:
        if self.fail_at_s is not None and time_s >= self.fail_at_s:
            raise DeviceLost(f"{self.info.name} stopped answering at t = {time_s:.3f} s")
        self._advance(time_s)
        p = self.plant
        lsb = 2.0 * p.travel / (1 << p.adc_bits)
        readings = []
        for x in self._x:
            noisy = x + (self._rng.gauss(0.0, p.noise) if p.noise > 0.0 else 0.0)
            readings.append(round(noisy / lsb) * lsb)
        if self.nan_at_s is not None and time_s >= self.nan_at_s:
            readings[0] = math.nan
        self.log.append((time_s, tuple(self._x), self.motor_forces))
        return DeviceSample(time_s, tuple(readings), None)

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        if self.fail_at_s is not None and time_s >= self.fail_at_s:
            raise DeviceLost(f"{self.info.name} stopped answering at t = {time_s:.3f} s")
        self._queue.append((time_s, tuple(forces)))
        self.sent.append((time_s, tuple(forces)))


def virtual_joystick(hand: Hand | None = None, **options: object) -> VirtualDevice:
    """The paper's 2-DOF joystick (about 10 N per axis, +-40 mm at the knob)."""
    return VirtualDevice(WINGMAN, 2, hand, kind="joystick", name="virtual joystick", **options)  # type: ignore[arg-type]


def virtual_wheel(hand: Hand | None = None, **options: object) -> VirtualDevice:
    """A belt-driven force-feedback wheel (4 Nm, +-450 deg)."""
    return VirtualDevice(BELT_WHEEL, 1, hand, kind="wheel", name="virtual wheel", **options)  # type: ignore[arg-type]
