"""Rendering the models on a device: scaling, admittance and impedance (virtual coupling).

Admittance (the paper's scheme): the device measures force and displays motion. Consumer devices
take force commands only, so the position servo runs here, as the paper's DSP ran it: the servo
pulls the handle toward the model's position, and its effort is the estimate of the hand's force
(the paper estimated it from the motor currents):
    F_servo = K_s * (x_model * ps - x_device) - B_s * v_device      (device units)
    F_hand  ~ -F_servo / fs                                          (model units)
Impedance with a virtual coupling (the way for force-commanded wheels and joysticks): a spring
and damper join the handle to the model's lever; the model feels the coupling force as the
driver's, the device renders its reaction:
    F_c = K_c * (x_device / ps - x_model) + B_c * (v_device / ps - v_model)   (model units)
    command = -F_c * fs
Passivity (Colgate & Schenkel, sampled at T): the coupling, seen at the handle, is a spring
K_c * fs / ps with damping B_c * fs / ps; K*T/2 + B must stay below the damping that dissipates
(the device's own and the lever's). With the virtual joystick's 3 N*s/m and the defaults
(K_c = 30 kN/m, B_c = 5 N*s/m on the lever, fs = 0.09, ps = 0.89) the handle sees K*T/2 + B =
2.0 N*s/m; `coupling_bound` computes it. The admittance servo (1 kN/m, 1.5 N*s/m at the handle:
K*T/2 + B = 2.0 N*s/m) is soft on purpose: a stiffer servo lets a handle nobody holds ring (an
admittance display is unstable against a free handle), and its effort is the force estimate,
so its stiffness only sets how far the handle lags the lever under force (7 mm at 7 N).
Scaling: fs (device force per model force) and ps (device travel per model travel) default to
the largest that fit the device: the paper's joystick gave about 10 N against a 100 N lever,
fs = 0.1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from carfeel.models.gearshift import engagement, hpattern
from carfeel.models.gearshift.engagement import EngagementParams
from carfeel.models.gearshift.hpattern import HPatternInputs, HPatternParams
from carfeel.models.steering.torque import torque_terms
from carfeel.models.vehicle import single_track
from carfeel.models.vehicle.single_track import VehicleInputs
from carfeel.realtime.devices.base import DeviceInfo, DeviceSample
from carfeel.realtime.filters import SosFilter, butterworth
from carfeel.simulation.steering import SteeringCar

MODES = ("admittance", "impedance")
DISPLAY_CUTOFF_HZ = 20.0
VELOCITY_CUTOFF_HZ = 50.0


@dataclass(frozen=True, slots=True)
class Scaling:
    force_scale: float
    """Device force (N or Nm) per model force."""
    position_scale: float
    """Device travel (m or rad) per model travel."""


@dataclass(frozen=True, slots=True)
class Gains:
    """Servo (admittance, device units) and coupling (impedance, model units) gains."""

    servo_stiffness: float = 1000.0
    servo_damping: float = 1.5
    coupling_stiffness: float = 30000.0
    coupling_damping: float = 5.0
    hold_stiffness: float = 1000.0
    """Device units: holds an axis the model does not use (the paper held y at zero)."""
    hold_damping: float = 0.5


def default_scaling(model_force: float, model_travel: float, info: DeviceInfo) -> Scaling:
    """The largest scales that fit the device: 90 % of its force, all of its travel."""
    return Scaling(0.9 * info.max_force / model_force, info.travel / model_travel)


def coupling_bound(gains: Gains, scaling: Scaling, rate_hz: float) -> float:
    """K*T/2 + B of the coupling seen at the handle, device units (compare to its damping)."""
    ratio = scaling.force_scale / scaling.position_scale
    return gains.coupling_stiffness * ratio / (2.0 * rate_hz) + gains.coupling_damping * ratio


class Reading:
    """A device axis as the renderers use it: the reading itself, and its velocity (the
    difference of readings through a 50 Hz low-pass). The position is not filtered: a filter's
    lag inside the coupling's loop costs more stability than the sensor's noise costs tremor."""

    __slots__ = ("_last", "_velocity")

    def __init__(self, rate_hz: float) -> None:
        self._velocity: SosFilter = butterworth(min(VELOCITY_CUTOFF_HZ, 0.4 * rate_hz), rate_hz)
        self._last: float | None = None

    def step(self, raw: float, dt: float) -> tuple[float, float]:
        velocity = self._velocity.step(0.0 if self._last is None else (raw - self._last) / dt)
        self._last = raw
        return raw, velocity


class Renderer(Protocol):
    axes: int
    columns: tuple[str, ...]
    gears: list[str]
    substeps: int

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        """Device commands for this tick, and the values to record (in `columns` order)."""
        ...


class ShiftRenderer:
    """The 1-DOF engagement on the first axis of a joystick; the second held at zero."""

    axes: int = 2
    columns: tuple[str, ...] = (
        "x_device", "y_device", "position_m", "velocity_m_s", "force_N", "force_filtered_N",
        "stage",
    )  # fmt: skip

    def __init__(
        self,
        gearbox: EngagementParams,
        mode: str,
        scaling: Scaling,
        rate_hz: float,
        gains: Gains | None = None,
        seed: int = 0,
    ) -> None:
        self.gearbox, self.mode, self.scaling = gearbox, mode, scaling
        self.g = gains or Gains()
        self.state = engagement.initial_state(seed)
        self.display = butterworth(DISPLAY_CUTOFF_HZ, rate_hz)
        self.rx, self.ry = Reading(rate_hz), Reading(rate_hz)
        self.gears: list[str] = []
        self.substeps = 1
        """Model steps per tick (the loop at 1 kHz, the model up to 10 kHz)."""

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        fs, ps = self.scaling.force_scale, self.scaling.position_scale
        g = self.g
        x_dev, vx_dev = self.rx.step(sample.positions[0], dt_s)
        y_dev, vy_dev = self.ry.step(sample.positions[1], dt_s)
        lever = self.state
        h = dt_s / self.substeps
        if self.mode == "admittance":
            servo = g.servo_stiffness * (lever.position_m * ps - x_dev) - g.servo_damping * vx_dev
            hand = -servo / fs
            for _ in range(self.substeps):  # the estimate is held over the tick
                self.state, out = engagement.step(
                    self.state, engagement.EngagementInputs(hand), self.gearbox, h
                )
            command_x = g.servo_stiffness * (out.position_m * ps - x_dev) - g.servo_damping * vx_dev
        else:
            hand = g.coupling_stiffness * (x_dev / ps - lever.position_m) + g.coupling_damping * (
                vx_dev / ps - lever.velocity_m_s
            )
            coupling = hand
            for _ in range(self.substeps):  # the handle is held, the lever moves
                self.state, out = engagement.step(
                    self.state, engagement.EngagementInputs(coupling), self.gearbox, h
                )
                coupling = g.coupling_stiffness * (x_dev / ps - out.position_m) + (
                    g.coupling_damping * (vx_dev / ps - out.velocity_m_s)
                )
            command_x = -coupling * fs
        command_y = -g.hold_stiffness * y_dev - g.hold_damping * vy_dev
        if out.stage == "in_gear" and (not self.gears or self.gears[-1] != "1"):
            self.gears.append("1")
        row = (
            x_dev,
            y_dev,
            out.position_m,
            out.velocity_m_s,
            hand,
            self.display.step(hand),
            out.stage,
        )
        return (command_x, command_y), row


class HPatternRenderer:
    """The 2-DOF H-pattern on a joystick: x engage, y select."""

    axes: int = 2
    columns: tuple[str, ...] = (
        "x_device", "y_device", "x_m", "y_m", "force_x_N", "force_y_N", "force_x_filtered_N",
        "region", "gear", "event", "stage",
    )  # fmt: skip

    def __init__(
        self,
        pattern: HPatternParams,
        mode: str,
        scaling: Scaling,
        rate_hz: float,
        gains: Gains | None = None,
        seed: int = 0,
        vehicle_speed_m_s: float = 0.0,
        engine_speed_rad_s: float = 0.0,
        clutch: object = None,
    ) -> None:
        self.pattern, self.mode, self.scaling = pattern, mode, scaling
        self.g = gains or Gains()
        self.state = hpattern.initial_state(pattern, seed, engine_speed_rad_s)
        self.display = butterworth(DISPLAY_CUTOFF_HZ, rate_hz)
        self.rx, self.ry = Reading(rate_hz), Reading(rate_hz)
        self.speed = vehicle_speed_m_s
        self.engine = engine_speed_rad_s
        self.clutch = clutch
        """An object with a `clutch_pedal` attribute (the virtual hand), or None (pressed)."""
        self.gears: list[str] = []
        self.substeps = 1
        """Model steps per tick (the loop at 1 kHz, the model up to 10 kHz)."""

    def _model_xy(self) -> tuple[float, float, float, float]:
        s = self.state
        d = s.direction
        return d * s.lever.position_m, s.y_m, d * s.lever.velocity_m_s, s.vy_m_s

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        fs, ps = self.scaling.force_scale, self.scaling.position_scale
        g = self.g
        x_dev, vx_dev = self.rx.step(sample.positions[0], dt_s)
        y_dev, vy_dev = self.ry.step(sample.positions[1], dt_s)
        devices, v_dev = (x_dev, y_dev), (vx_dev, vy_dev)
        model = self._model_xy()
        hands = []
        for axis in (0, 1):
            if self.mode == "admittance":
                servo = g.servo_stiffness * (model[axis] * ps - devices[axis]) - (
                    g.servo_damping * v_dev[axis]
                )
                hands.append(-servo / fs)
            else:
                hands.append(
                    g.coupling_stiffness * (devices[axis] / ps - model[axis])
                    + g.coupling_damping * (v_dev[axis] / ps - model[axis + 2])
                )
        pedal = float(getattr(self.clutch, "clutch_pedal", 1.0))
        h = dt_s / self.substeps
        forces: tuple[float, ...] = (hands[0], hands[1])
        event = ""
        for _ in range(self.substeps):
            inputs = HPatternInputs(forces[0], forces[1], pedal, self.speed, self.engine)
            self.state, out = hpattern.step(self.state, inputs, self.pattern, h)
            if out.event.startswith("engage"):  # whichever sub-step it happens in
                self.gears.append(out.gear)
                event = out.event
            elif out.event:
                event = out.event
            if self.mode == "impedance":  # the handle is held, the knob moves
                m = self._model_xy()
                forces = tuple(
                    g.coupling_stiffness * (devices[a] / ps - m[a])
                    + g.coupling_damping * (v_dev[a] / ps - m[a + 2])
                    for a in (0, 1)
                )
        after = self._model_xy()
        commands = []
        for axis in (0, 1):
            if self.mode == "admittance":
                commands.append(
                    g.servo_stiffness * (after[axis] * ps - devices[axis])
                    - g.servo_damping * v_dev[axis]
                )
            else:
                coupling = g.coupling_stiffness * (devices[axis] / ps - after[axis]) + (
                    g.coupling_damping * (v_dev[axis] / ps - after[axis + 2])
                )
                commands.append(-coupling * fs)
        # The click and the grinding are rendered on top, as the gearbox's vibrations.
        commands[0] += (out.click_N + out.grind_N) * math.copysign(1.0, out.x_m or 1.0) * fs
        row = (
            devices[0], devices[1], out.x_m, out.y_m, hands[0], hands[1],
            self.display.step(hands[0]), out.region, out.gear, event, out.stage,
        )  # fmt: skip
        return (commands[0], commands[1]), row


class SteeringRenderer:
    """The steering wheel torque on a force-feedback wheel (direct torque, impedance)."""

    axes: int = 1
    columns: tuple[str, ...] = (
        "angle_device_rad", "steering_angle_rad", "steering_rate_rad_s", "lateral_accel_m_s2",
        "torque_Nm", "torque_filtered_Nm",
    )  # fmt: skip

    def __init__(
        self, car: SteeringCar, speed_m_s: float, scaling: Scaling, rate_hz: float
    ) -> None:
        self.car, self.speed, self.scaling = car, speed_m_s, scaling
        self.vehicle = single_track.initial_state()
        self.reading = Reading(rate_hz)
        self.display = butterworth(DISPLAY_CUTOFF_HZ, rate_hz)
        self.gears: list[str] = []
        self.substeps = 1
        """Model steps per tick (the loop at 1 kHz, the model up to 10 kHz)."""

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        ps, fs = self.scaling.position_scale, self.scaling.force_scale
        position, velocity = self.reading.step(sample.positions[0], dt_s)
        angle, rate = position / ps, velocity / ps
        for _ in range(self.substeps):
            self.vehicle, out = single_track.step(
                self.vehicle, VehicleInputs(self.speed, angle), self.car.vehicle,
                dt_s / self.substeps,
            )  # fmt: skip
        torque = torque_terms(self.speed, rate, out.lateral_accel_m_s2, self.car.torque)[0]
        row = (
            sample.positions[0],
            angle,
            rate,
            out.lateral_accel_m_s2,
            torque,
            self.display.step(torque),
        )
        return (-torque * fs,), row
