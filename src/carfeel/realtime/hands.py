"""Simulated hands for the virtual devices: the scripted drivers, acting through the scales.

A hand waits `start_s` (the loop's calibration and ramp-in: a person waits for the device to be
ready), then works in the model's world (the driver laws are written for a real lever or wheel): it
sees the device's motion divided by the position scale and its force is multiplied by the
force scale before it reaches the handle, as a person's hand would be scaled down by the
paper's 1/10 joystick.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from carfeel.models.drivers import hpattern as hpattern_driver
from carfeel.models.drivers import shift as shift_driver
from carfeel.models.drivers.hpattern import Script
from carfeel.models.drivers.shift import ShiftDriverParams


class _ScriptedHand:
    """What the scripted hands share: the scales, a start delay and their own time step."""

    def __init__(self, force_scale: float, position_scale: float, start_s: float) -> None:
        self.force_scale = force_scale
        self.position_scale = position_scale
        self.start_s = start_s
        self._last = 0.0

    def _tick(self, time_s: float) -> float | None:
        """The time since the last call, or None while the hand waits to start."""
        last, self._last = self._last, time_s
        if time_s < self.start_s:
            return None
        return time_s - last if time_s > last else 1e-4


class ShiftHand(_ScriptedHand):
    """The eq. (10) driver of the 1-DOF engagement, on the first axis; the second is left free."""

    def __init__(
        self,
        params: ShiftDriverParams,
        force_scale: float,
        position_scale: float,
        start_s: float = 0.0,
    ):
        super().__init__(force_scale, position_scale, start_s)
        self.params = params
        self.state = shift_driver.initial_state()

    def forces(
        self, time_s: float, positions: tuple[float, ...], velocities: tuple[float, ...]
    ) -> tuple[float, ...]:
        dt = self._tick(time_s)
        if dt is None:  # waiting for the device to be ready
            return (0.0,) * len(positions)
        inputs = shift_driver.DriverInputs(
            positions[0] / self.position_scale, velocities[0] / self.position_scale
        )
        self.state, out = shift_driver.step(self.state, inputs, self.params, dt)
        return (out.force_N * self.force_scale,) + (0.0,) * (len(positions) - 1)


class HPatternHand(_ScriptedHand):
    """The 2-D gear-sequence driver on both axes (x engage, y select)."""

    def __init__(
        self, script: Script, force_scale: float, position_scale: float, start_s: float = 0.0
    ):
        super().__init__(force_scale, position_scale, start_s)
        self.script = script
        self.state = hpattern_driver.initial_state()
        self.phase = "pull"
        self.clutch_pedal = script.clutch_pedal
        self.range_high = self.splitter_high = False
        """A truck's range switch and splitter button, as the hand sets them."""

    def forces(
        self, time_s: float, positions: tuple[float, ...], velocities: tuple[float, ...]
    ) -> tuple[float, ...]:
        dt = self._tick(time_s)
        if dt is None:  # waiting for the device to be ready
            return (0.0,) * len(positions)
        ps = self.position_scale
        inputs = hpattern_driver.HPatternDriverInputs(
            positions[0] / ps, positions[1] / ps, velocities[0] / ps, velocities[1] / ps
        )
        self.state, out = hpattern_driver.step(self.state, inputs, self.script, dt)
        self.phase = out.phase
        self.clutch_pedal = out.clutch_pedal
        self.range_high, self.splitter_high = out.range_high, out.splitter_high
        return (out.force_x_N * self.force_scale, out.force_y_N * self.force_scale)

    @property
    def done(self) -> bool:
        return self.state.phase is hpattern_driver.Phase.DONE


class WheelHand:
    """Hands on the rim that steer a wheel angle against its torque: a stiff, damped grip.
    Before `start_s` they wait off the rim (the loop calibrates the device)."""

    def __init__(
        self,
        target: Callable[[float], float],
        stiffness_Nm_rad: float = 20.0,
        damping_Nm_s_rad: float = 1.0,
        max_torque_Nm: float = 15.0,
        position_scale: float = 1.0,
        start_s: float = 0.0,
    ):
        self.start_s = start_s
        self.target = target
        self.stiffness = stiffness_Nm_rad
        self.damping = damping_Nm_s_rad
        self.max_torque = max_torque_Nm
        self.position_scale = position_scale

    def forces(
        self, time_s: float, positions: tuple[float, ...], velocities: tuple[float, ...]
    ) -> tuple[float, ...]:
        if time_s < self.start_s:
            return (0.0,)
        aim = self.target(time_s) * self.position_scale
        torque = self.stiffness * (aim - positions[0]) - self.damping * velocities[0]
        return (max(-self.max_torque, min(self.max_torque, torque)),)


def weave_target(
    amplitude_rad: float, frequency_hz: float, start_s: float = 0.0, cycles: float = math.inf
) -> Callable[[float], float]:
    """A steering wheel angle sine from `start_s` for `cycles` cycles, then centre, rad."""
    end_s = start_s + cycles / frequency_hz

    def target(t: float) -> float:
        if t < start_s or t >= end_s:
            return 0.0
        return amplitude_rad * math.sin(2.0 * math.pi * frequency_hz * (t - start_s))

    return target


HANDS = ("script", "none", "release")
"""--hand: the scripted driver holds the device throughout; nobody touches it; or the script
runs, then the hand lets go."""


class ReleasingHand:
    """A hand that works until `let_go()` says so, then leaves the device for good (no force,
    no contact): what a released device does is then the rendering's alone."""

    def __init__(self, hand: Any, let_go: Callable[[float], bool]) -> None:
        self.hand = hand
        self.let_go = let_go
        self.released_at_s: float | None = None

    def __getattr__(self, name: str) -> Any:  # the clutch pedal and the like, from the hand
        return getattr(self.hand, name)

    def forces(
        self, time_s: float, positions: tuple[float, ...], velocities: tuple[float, ...]
    ) -> tuple[float, ...]:
        if self.released_at_s is None and self.let_go(time_s):
            self.released_at_s = time_s
        if self.released_at_s is not None:
            return (0.0,) * len(positions)
        forces: tuple[float, ...] = self.hand.forces(time_s, positions, velocities)
        return forces


def holding_wheel(angle_rad: float, start_s: float, hold_s: float) -> ReleasingHand:
    """Hands that turn the rim to `angle_rad` from `start_s` (a smooth half-second turn, as a
    person's), hold it until `hold_s` after `start_s`, then let go."""

    def target(t: float) -> float:
        phase = min(1.0, max(0.0, (t - start_s) / TURN_S))
        return angle_rad * 0.5 * (1.0 - math.cos(math.pi * phase))

    hand = WheelHand(target, 300.0, 5.0, 30.0, start_s=start_s)
    return ReleasingHand(hand, lambda t: t >= start_s + hold_s)


TURN_S = 0.5
"""How long the releasing hands take to turn the rim to its angle."""
