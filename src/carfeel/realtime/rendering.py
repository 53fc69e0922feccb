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
Sizing: the coupling, the servo and the hold of an unused axis are sized from the device (its
rate, delays both ways, report rate, mass, damping and noise: `stability.size`), never fixed:
a coupling that is stiff enough on one device limit-cycles on another with a few ms of USB
delay. At the handle the coupling is K_c * fs / ps, and that is what the sizing bounds.
Scaling: fs (device force per model force) and ps (device travel per model travel) default to
the largest that fit the device: the paper's joystick gave about 10 N against a 100 N lever,
fs = 0.1.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any, Protocol

from carfeel.models.drivers.shift import ShiftDriverParams
from carfeel.models.gearshift import engagement, hpattern
from carfeel.models.gearshift.engagement import EngagementParams, Stage
from carfeel.models.gearshift.hpattern import HPatternInputs, HPatternParams
from carfeel.models.vehicle import single_track
from carfeel.models.vehicle.single_track import VehicleInputs
from carfeel.realtime.devices.base import DeviceInfo, DeviceSample
from carfeel.realtime.filters import SosFilter, butterworth, butterworth_sections
from carfeel.realtime.stability import RingWall, Sizing
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

    servo_stiffness: float
    servo_damping: float
    coupling_stiffness: float
    coupling_damping: float
    hold_stiffness: float
    """Device units: holds an axis the model does not use (the paper held y at zero)."""
    hold_damping: float

    @classmethod
    def sized(cls, sizing: Sizing, scaling: Scaling) -> Gains:
        """The stiffest coupling, servo and hold the device renders hands-off (at the handle,
        device units: K and B of `sizing`; the coupling in model units through the scales)."""
        to_model = scaling.position_scale / scaling.force_scale
        k, b = sizing.stiffness, sizing.damping
        return cls(k, b, k * to_model, b * to_model, k, b)


WALL_FADE_S = 0.05
"""Time constant (s) over which the ring wall's force beyond the coupling's hands over to it
once the ring stops blocking (the gate opens): the lever takes the push it held, no step. With
the wall's feed-forward the wall holds nearly all of the push at the block's end (the coupling,
barely stretched, almost none); over 10 ms the model's lever lost its drive before the handle
could stretch the coupling, and the handle then rushed after it: on the 14-speed truck at the
virtual shifter three 12 Hz swings over a tenth of the limit, which the guard ended. Over 50 ms
the lever is pushed on while the coupling takes over (the worst 2-100 Hz swing 3.2 N rms,
against 3.5 N on the wall's springs alone with the 10 ms fade)."""


class RingHold:
    """The ring wall in a renderer (device units): while the ring blocks, the wall's force on
    the stretch past the blocked position; once it lets go, what the wall held beyond the
    coupling's spring (stiffness `coupling`, device units), fading over WALL_FADE_S.

    The wall takes over from the coupling without a step back: at the block's first tick the
    handle may already stand past the lever by the coupling's stretch (a hand that pushed
    against a cue or a gate wall), and the wall, stiffer than the coupling, would kick it
    back by the difference of their forces at that stretch; a kick that pushes the hand out
    puts energy into it (a bounce, and the passivity controller's chatter after it). So the
    wall's zero moves by `offset`, the stretch at which the wall's spring holds what the
    coupling held: its spring's force and, while the handle moves on into the ring, its
    damper's (`damped`). The damper's share would otherwise vanish as the handle stops and
    have to be rebuilt by stretch (in admittance, where the servo damps the handle's own
    velocity, nearly all of the push at the ring's arrival); the wall's damper then acts on
    the arrival on top of it, as the ring's impact, against the motion only.

    Then the feed-forward (`RingWall.integrals`): on ticks whose velocity reading is forward
    beyond the reading's noise (`RingWall.pushing_on`: the handle pushing on into the wall),
    the wall's zero moves back by the stretch over the piece's time constant, so the push the
    wall holds comes to stand nearer the blocked position instead of on the spring's stretch
    (the ring's reaction fed forward). It never moves otherwise, so it is no integrator that
    pulls the handle back against the muscle; the pieces are sized stable with it acting on
    every tick (DESIGN.md)."""

    __slots__ = ("blocking", "coupling", "held", "offset", "wall")

    def __init__(self, wall: RingWall, coupling: float) -> None:
        self.wall, self.coupling = wall, coupling
        self.held = 0.0
        self.offset = 0.0
        """Device units: how far past the blocked position the wall's zero stands (behind it
        when negative: the feed-forward)."""
        self.blocking = False

    def block(self, stretch: float, velocity: float, dt_s: float, damped: float = 0.0) -> float:
        """The wall's force while the ring blocks (pushing back: the command is its negative);
        `damped`: the force the coupling's (or servo's) damper held this tick (device units,
        toward the gate; only its forward part counts)."""
        if not self.blocking:
            self.blocking = True
            coupled = self.coupling * stretch + max(0.0, damped)  # what the coupling held
            self.offset = stretch - self.wall.stretch_for(coupled) if coupled > 0.0 else 0.0
        s = stretch - self.offset
        self.held = self.wall.force(s, 0.0) - self.coupling * stretch
        force = self.wall.force(s, velocity)
        if (
            velocity > self.wall.pushing_on
            and stretch > 0.0
            and s < self.wall.stretches[-1]  # beyond it the device cannot render the wall
            and self.wall.integrals
        ):
            tau = self.wall.integrals[self.wall.piece(s)]
            if tau > 0.0:
                self.offset -= stretch * dt_s / tau
        return force

    def fade(self, dt_s: float) -> float:
        """Out of the block: the held force, fading."""
        self.blocking = False
        if self.held:
            self.held *= math.exp(-dt_s / WALL_FADE_S)
        return self.held


def default_scaling(model_force: float, model_travel: float, info: DeviceInfo) -> Scaling:
    """The largest scales that fit the device: 90 % of its force, all of its travel."""
    return Scaling(0.9 * info.max_force / model_force, info.travel / model_travel)


def ring_wall(
    info: DeviceInfo,
    rate_hz: float,
    scaling: Scaling,
    driver: ShiftDriverParams,
    feed_forward: bool = True,
) -> RingWall:
    """The synchronizer ring's wall on this device for the preset's hand (the paper's eq. (10)
    muscle: a push F brings F / V0 of damping at the knob, and the hand's mass), in device
    units through the scales, with its feed-forward unless told not to
    (`stability.size_ring_wall`)."""
    from carfeel.realtime import stability

    fs, ps = scaling.force_scale, scaling.position_scale
    return stability.size_ring_wall(
        info,
        rate_hz,
        velocity_sections(rate_hz),
        hand_damping_per_N=1.0 / (driver.push_velocity_m_s * ps),
        hand=(
            driver.hand_mass_kg * fs / ps,
            driver.hand_stiffness_N_m * fs / ps,
            driver.hand_damping_N_s_m * fs / ps,
        ),
        feed_forward=feed_forward,
    )


def velocity_sections(rate_hz: float) -> tuple[tuple[float, float, float, float, float], ...]:
    """The velocity filter every renderer uses (for the sizing, which must see its lag)."""
    return butterworth_sections(min(VELOCITY_CUTOFF_HZ, 0.4 * rate_hz), rate_hz)


class Reading:
    """A device axis as the renderers use it: the reading itself, and its velocity (the
    difference of readings through a 50 Hz low-pass). The position is not filtered: a filter's
    lag inside the coupling's loop costs more stability than the sensor's noise costs tremor."""

    __slots__ = ("_last", "_velocity")

    def __init__(self, rate_hz: float) -> None:
        self._velocity: SosFilter = SosFilter(velocity_sections(rate_hz))
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
    effect: float
    """A vibration the model adds on purpose (device units, first axis) to this tick's command."""

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
        gains: Gains,
        seed: int = 0,
        wall: RingWall | None = None,
    ) -> None:
        self.gearbox, self.mode, self.scaling = gearbox, mode, scaling
        self.g = gains
        self.ring = None if wall is None else RingHold(wall, gains.servo_stiffness)
        """The ring while it blocks (None: the coupling or servo holds it, as any stage)."""
        self.effect = 0.0
        self.state = engagement.initial_state(seed)
        self.display = butterworth(DISPLAY_CUTOFF_HZ, rate_hz)
        self.rx, self.ry = Reading(rate_hz), Reading(rate_hz)
        self.gears: list[str] = []
        self.substeps = 1
        """Model steps per tick (the loop at 1 kHz, the model up to 10 kHz)."""

    def retune(self, gearbox: EngagementParams) -> None:
        """New gearbox parameters from the next tick on (call between ticks, with validated
        parameters; a live panel calls it in neutral, blending old into new over a ramp)."""
        self.gearbox = gearbox

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        fs, ps = self.scaling.force_scale, self.scaling.position_scale
        g = self.g
        x_dev, vx_dev = self.rx.step(sample.positions[0], dt_s)
        y_dev, vy_dev = self.ry.step(sample.positions[1], dt_s)
        lever = self.state
        h = dt_s / self.substeps
        ring = self.ring
        if ring is not None and lever.stage is Stage.SYNCHRONIZATION:
            # The ring blocks: the same wall in either mode (the lever stands still, so the
            # servo and the coupling are both a spring to where it stands).
            lever_v = 0.0 if self.mode == "admittance" else lever.velocity_m_s * ps
            damped = g.servo_damping * (vx_dev - lever_v)  # the servo damps the handle's own
            push = ring.block(x_dev - lever.position_m * ps, vx_dev, dt_s, damped)
            hand = push / fs
            for _ in range(self.substeps):
                self.state, out = engagement.step(
                    self.state, engagement.EngagementInputs(hand), self.gearbox, h
                )
            command_x = -push
        elif self.mode == "admittance":
            held = 0.0 if ring is None else ring.fade(dt_s)
            servo = g.servo_stiffness * (lever.position_m * ps - x_dev) - g.servo_damping * vx_dev
            hand = (held - servo) / fs
            for _ in range(self.substeps):  # the estimate is held over the tick
                self.state, out = engagement.step(
                    self.state, engagement.EngagementInputs(hand), self.gearbox, h
                )
            command_x = (
                g.servo_stiffness * (out.position_m * ps - x_dev) - g.servo_damping * vx_dev - held
            )
        else:
            held = 0.0 if ring is None else ring.fade(dt_s) / fs
            hand = (
                g.coupling_stiffness * (x_dev / ps - lever.position_m)
                + g.coupling_damping * (vx_dev / ps - lever.velocity_m_s)
                + held
            )
            coupling = hand
            for _ in range(self.substeps):  # the handle is held, the lever moves
                self.state, out = engagement.step(
                    self.state, engagement.EngagementInputs(coupling), self.gearbox, h
                )
                coupling = g.coupling_stiffness * (x_dev / ps - out.position_m) + (
                    g.coupling_damping * (vx_dev / ps - out.velocity_m_s) + held
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
        gains: Gains,
        seed: int = 0,
        vehicle_speed_m_s: float = 0.0,
        engine_speed_rad_s: float = 0.0,
        clutch: object = None,
        wall: RingWall | None = None,
    ) -> None:
        self.pattern, self.mode, self.scaling = pattern, mode, scaling
        self.g = gains
        self.ring = None if wall is None else RingHold(wall, gains.servo_stiffness)
        """The ring on x while it blocks (None: the coupling or servo holds it)."""
        self.effect = 0.0
        """The vibrations (click, grinding) added to this tick's command on the first axis:
        the oscillation guard looks past them."""
        self.state = hpattern.initial_state(pattern, seed, engine_speed_rad_s)
        self.display = butterworth(DISPLAY_CUTOFF_HZ, rate_hz)
        self.rx, self.ry = Reading(rate_hz), Reading(rate_hz)
        self.speed = vehicle_speed_m_s
        self.engine = engine_speed_rad_s
        self.clutch = clutch
        """An object with a `clutch_pedal` attribute (the virtual hand), or None (pressed)."""
        self.knob = clutch
        """The knob's switches (a truck's range and splitter: `range_high`, `splitter_high` of
        the virtual hand; low without), kept when telemetry takes over the pedal."""
        self.cues: Any = None
        """The game's cues on the knob (telemetry/cues.py `LeverCues`): called each sub-step
        with the model's state, (x, y) N added to the hand's; None: no cues."""
        self.gears: list[str] = []
        self.substeps = 1
        """Model steps per tick (the loop at 1 kHz, the model up to 10 kHz)."""

    def retune(self, pattern: HPatternParams) -> None:
        """New gearbox parameters from the next tick on (call between ticks, with validated
        parameters; a live panel calls it in neutral, blending old into new over a ramp)."""
        self.pattern = pattern

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
        ring, d = self.ring, self.state.direction
        blocked = ring is not None and self.state.lever.stage is Stage.SYNCHRONIZATION
        push = held = 0.0  # device units along the slot (toward the gear)
        if ring is not None:
            if blocked:  # the ring blocks x: its wall, in either mode (see ShiftRenderer)
                lever_v = 0.0 if self.mode == "admittance" else model[2] * ps
                damped = g.servo_damping * d * (vx_dev - lever_v)
                push = ring.block(d * (x_dev - model[0] * ps), d * vx_dev, dt_s, damped)
            else:
                held = ring.fade(dt_s)
        hands = []
        for axis in (0, 1):
            if axis == 0 and blocked:
                hands.append(d * push / fs)
            elif self.mode == "admittance":
                servo = g.servo_stiffness * (model[axis] * ps - devices[axis]) - (
                    g.servo_damping * v_dev[axis]
                )
                hands.append(-servo / fs + (d * held / fs if axis == 0 else 0.0))
            else:
                hands.append(
                    g.coupling_stiffness * (devices[axis] / ps - model[axis])
                    + g.coupling_damping * (v_dev[axis] / ps - model[axis + 2])
                    + (d * held / fs if axis == 0 else 0.0)
                )
        pedal = float(getattr(self.clutch, "clutch_pedal", 1.0))
        # A truck's range switch and splitter on the knob (the virtual hand's; low otherwise),
        # and the game's throttle where telemetry gives it (a split waits under torque).
        knob = (bool(getattr(self.knob, "range_high", False)),
                bool(getattr(self.knob, "splitter_high", False)),
                float(getattr(self.clutch, "throttle", 0.0)))  # fmt: skip
        h = dt_s / self.substeps
        forces: tuple[float, ...] = (hands[0], hands[1])
        event = ""
        for _ in range(self.substeps):
            cx, cy = self.cues(self.state) if self.cues is not None else (0.0, 0.0)
            inputs = HPatternInputs(
                forces[0] + cx, forces[1] + cy, pedal, self.speed, self.engine, *knob
            )
            self.state, out = hpattern.step(self.state, inputs, self.pattern, h)
            if out.event.startswith("engage"):  # whichever sub-step it happens in
                self.gears.append(out.gear)
                event = out.event
            elif out.event:
                event = out.event
            if self.mode == "impedance":  # the handle is held, the knob moves
                m = self._model_xy()
                forces = tuple(
                    hands[0]
                    if a == 0 and blocked
                    else g.coupling_stiffness * (devices[a] / ps - m[a])
                    + g.coupling_damping * (v_dev[a] / ps - m[a + 2])
                    + (d * held / fs if a == 0 else 0.0)
                    for a in (0, 1)
                )
        after = self._model_xy()
        commands = []
        for axis in (0, 1):
            if axis == 0 and blocked:
                commands.append(-d * push)
            elif self.mode == "admittance":
                commands.append(
                    g.servo_stiffness * (after[axis] * ps - devices[axis])
                    - g.servo_damping * v_dev[axis]
                    - (d * held if axis == 0 else 0.0)
                )
            else:
                coupling = g.coupling_stiffness * (devices[axis] / ps - after[axis]) + (
                    g.coupling_damping * (v_dev[axis] / ps - after[axis + 2])
                )
                commands.append(-coupling * fs - (d * held if axis == 0 else 0.0))
        # The click and the grinding are rendered on top, as the gearbox's vibrations.
        self.effect = (out.click_N + out.grind_N) * math.copysign(1.0, out.x_m or 1.0) * fs
        commands[0] += self.effect
        row = (
            devices[0], devices[1], out.x_m, out.y_m, hands[0], hands[1],
            self.display.step(hands[0]), out.region, out.gear, event, out.stage,
        )  # fmt: skip
        return (commands[0], commands[1]), row


ALIGNING = ("front-axle", "steady-state")
"""Where the aligning torque's Ay comes from: the front axle's force (default), or the paper's
steady-state Ay of the wheel angle."""


@dataclass(frozen=True, slots=True)
class SteeringRendering:
    """How the steering law is put on a wheel (choices of rendering, not of the car)."""

    aligning: str = "front-axle"
    """"front-axle": tau0 from F_f * L / (m * b), which leads Ay as the tyres' moment does;
    "steady-state": the paper's Ay (a pure spring in the wheel angle). The transient Ay of the
    car lags the angle and turns tau0 into negative damping: it is not offered."""
    stick_angle_rad: float = 0.01
    """Rim angle over which the friction builds up to its level (the Dahl element's spring)."""
    zeta_released: float = 0.3
    """Damping ratio the speed-scheduled damping gives the released wheel, delay included."""
    friction_share: float = 0.3
    """Share of the device's stiffness budget the friction's stick spring may take."""
    tire_spin_share: float = 0.3
    """Share of the device's velocity-gain cap the tire-spin term's slope may take."""


class SteeringRenderer:
    """The steering wheel torque on a force-feedback wheel (direct torque, impedance).

    The paper's terms, made renderable on a device with delay (device units unless said):
      tau0  K1*Ay'/(1 + K2|Ay'|^K3), Ay' the front axle's (or the paper's steady-state) Ay;
      tau1  the tire-spin term with its slope at zero rate capped (a share of the velocity cap);
      tau2  friction of level K7*pi/2 as a position-based stick element (elasto-plastic, after
            Dahl and Hayward & Armstrong 2000): a spring of bounded stiffness to an anchor that
            slides once the spring holds the friction level. No velocity in it, so it neither
            buzzes on a noisy, delayed velocity nor gains energy (each slip dissipates);
      tau3  K9*rate, plus speed-scheduled damping (as EPS damping is) sized so the released
            wheel on this device, with its delays, keeps zeta_released;
      stop  a passive wall at the car's lock (inside the device's own travel).
    Every velocity gain stays under the device's cap and every spring within its budget
    (`stability.size`).
    """

    axes: int = 1
    columns: tuple[str, ...] = (
        "angle_device_rad", "steering_angle_rad", "steering_rate_rad_s", "lateral_accel_m_s2",
        "torque_Nm", "torque_filtered_Nm", "torque_aligning_Nm", "torque_tire_spin_Nm",
        "torque_friction_Nm", "torque_damping_Nm", "torque_stop_Nm",
    )  # fmt: skip

    def __init__(
        self,
        car: SteeringCar,
        speed_m_s: float,
        scaling: Scaling,
        rate_hz: float,
        sizing: Sizing,
        info: DeviceInfo,
        rendering: SteeringRendering | None = None,
    ) -> None:
        self.car, self.speed, self.scaling = car, speed_m_s, scaling
        self.rendering = r = rendering or SteeringRendering()
        if r.aligning not in ALIGNING:
            raise ValueError(f"aligning {r.aligning!r}: choose one of {', '.join(ALIGNING)}")
        self.sizing = sizing
        self.vehicle = single_track.initial_state()
        self.reading = Reading(rate_hz)
        self.display = butterworth(DISPLAY_CUTOFF_HZ, rate_hz)
        self.gears: list[str] = []
        self.substeps = 1
        """Model steps per tick (the loop at 1 kHz, the model up to 10 kHz)."""
        self.effect = 0.0
        self.lateral_accel_m_s2: float | None = None
        """The game's Ay for tau0 (telemetry, already faded by its weight); None: the car's."""
        self.game_torque_Nm: float | None = None
        """The game's own FFB torque (model N*m, this law's sign, faded; telemetry/driving.py),
        blended into tau0 by `game_torque_share`; None: tau0 is the law's alone."""
        self.game_torque_share = 0.0
        fs, ps = scaling.force_scale, scaling.position_scale
        k = car.torque
        friction_level = fs * k.k7_Nm * math.pi / 2.0
        self.friction_stiffness = min(
            friction_level / (r.stick_angle_rad * ps), r.friction_share * sizing.stiffness
        )
        """Device units (Nm/rad): the stick element's spring."""
        self.friction_slip = friction_level / self.friction_stiffness if friction_level else 0.0
        self._anchor: float | None = None
        self.stop_angle = min(car.vehicle.steering_lock_rad * ps, 0.95 * info.travel)
        """Device rad: where the rendered lock starts."""
        self.stop_stiffness = sizing.stiffness
        self.stop_damping = sizing.damping
        self.schedule = damping_schedule(
            car, scaling, rate_hz, sizing, info, r, self.tire_spin_rate, self.friction_stiffness
        )
        """(speed m/s, added damping at the device Nm*s/rad), rising speeds."""
        self._scheduled_for = math.nan
        self._spin_rate = self._added = 0.0

    def retune(self, car: SteeringCar, schedule: tuple[tuple[float, float], ...]) -> None:
        """New car parameters from the next tick on (call between ticks), with the damping
        `schedule` sized for them (a renderer built with `car` has it); the friction's stick
        spring follows K7. A live panel blends old into new over a ramp."""
        self.car, self.schedule = car, schedule
        fs, ps = self.scaling.force_scale, self.scaling.position_scale
        level = fs * car.torque.k7_Nm * math.pi / 2.0
        r = self.rendering
        self.friction_stiffness = min(
            level / (r.stick_angle_rad * ps), r.friction_share * self.sizing.stiffness
        )
        self.friction_slip = level / self.friction_stiffness if level else 0.0
        self._scheduled_for = math.nan

    def tire_spin_rate(self, speed_m_s: float) -> float:
        """K6, raised where needed so the tire spin's slope at zero rate fits its cap, rad/s."""
        k = self.car.torque
        amplitude = self.scaling.force_scale / (k.k4_1_Nm + k.k5_s_m_Nm * abs(speed_m_s))
        cap = self.rendering.tire_spin_share * self.sizing.damping_cap
        return max(k.k6_rad_s, amplitude / cap / self.scaling.position_scale)

    def added_damping(self, speed_m_s: float) -> float:
        """The speed-scheduled damping at the device, Nm*s/rad (linear between the table's)."""
        table = self.schedule
        if speed_m_s <= table[0][0]:
            return table[0][1]
        for (v0, b0), (v1, b1) in itertools.pairwise(table):
            if speed_m_s <= v1:
                return b0 + (b1 - b0) * (speed_m_s - v0) / (v1 - v0)
        return table[-1][1]

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        ps, fs = self.scaling.position_scale, self.scaling.force_scale
        k = self.car.torque
        vehicle = self.car.vehicle
        speed = self.speed
        position, velocity = self.reading.step(sample.positions[0], dt_s)
        angle, rate = position / ps, velocity / ps
        for _ in range(self.substeps):
            self.vehicle, out = single_track.step(
                self.vehicle, VehicleInputs(speed, angle), vehicle, dt_s / self.substeps
            )
        if self.lateral_accel_m_s2 is not None:
            ay = self.lateral_accel_m_s2
        elif self.rendering.aligning == "front-axle":
            ay = single_track.aligning_lateral_accel(self.vehicle, speed, vehicle)
        else:
            ay = single_track.steady_state_lateral_accel(speed, angle, vehicle)
        aligning = k.k1_Nm_s2_m * ay / (1.0 + k.k2 * abs(ay) ** k.k3)
        if self.game_torque_Nm is not None:
            aligning += self.game_torque_share * (self.game_torque_Nm - aligning)
        if speed != self._scheduled_for:  # the schedule's values only change with the speed
            self._scheduled_for = speed
            self._spin_rate = self.tire_spin_rate(speed)
            self._added = self.added_damping(speed)
        tire_spin = math.atan(rate / self._spin_rate) / (k.k4_1_Nm + k.k5_s_m_Nm * abs(speed))
        # Friction: the anchor slides when the stick spring holds the friction level.
        anchor = position if self._anchor is None else self._anchor
        if position - anchor > self.friction_slip:
            anchor = position - self.friction_slip
        elif anchor - position > self.friction_slip:
            anchor = position + self.friction_slip
        self._anchor = anchor
        friction = self.friction_stiffness * (position - anchor) / fs
        damping = k.k9_Nm_s_rad * rate + self._added * velocity / fs
        over = abs(position) - self.stop_angle
        stop = 0.0
        if over > 0.0:
            outward = max(0.0, math.copysign(1.0, position) * velocity)
            stop = (
                math.copysign(self.stop_stiffness * over + self.stop_damping * outward, position)
                / fs
            )
        torque = aligning + tire_spin + friction + damping + stop
        row = (
            sample.positions[0], angle, rate, out.lateral_accel_m_s2, torque,
            self.display.step(torque), aligning, tire_spin, friction, damping, stop,
        )  # fmt: skip
        return (-torque * fs,), row


SCHEDULE_SPEEDS_M_S = tuple(5.0 * i for i in range(15))
"""0 .. 70 m/s (252 km/h): where the steering's added damping is sized."""


def damping_schedule(
    car: SteeringCar,
    scaling: Scaling,
    rate_hz: float,
    sizing: Sizing,
    info: DeviceInfo,
    rendering: SteeringRendering,
    tire_spin_rate: Any,
    friction_stiffness: float,
) -> tuple[tuple[float, float], ...]:
    """Per speed, the least added damping (device units, within the velocity cap less what the
    law's own terms take) that gives the released wheel zeta_released on every plant of the
    device's uncertainty set, or the cap. Small swings stay inside the friction's stick spring,
    so it counts as a spring here."""
    from carfeel.realtime import stability

    plants = stability.plant_set(info, rate_hz, velocity_sections(rate_hz))
    table = []
    for speed in SCHEDULE_SPEEDS_M_S:
        law = steering_environment(
            car, scaling, speed, rendering, 1.0 / rate_hz, tire_spin_rate(speed)
        )
        size = 3 if law.stateful else 0
        own = law(None, 0.0, 1.0)[1]  # the law's own velocity gain, device units (negative)
        room = max(0.0, sizing.damping_cap + own)

        def ok(b: float, law: SteeringEnvironment = law, size: int = size) -> bool:
            def environment(state: object, y: float, v: float) -> tuple[object, float]:
                state, u = law(state, y, v)
                return state, u - b * v - friction_stiffness * y

            return stability.least_over(plants, environment, size) >= rendering.zeta_released

        if ok(0.0):
            added = 0.0
        elif not ok(room):
            added = room
        else:
            low, high = 0.0, room
            for _ in range(30):
                middle = 0.5 * (low + high)
                low, high = (low, middle) if ok(middle) else (middle, high)
            added = high
        table.append((speed, added))
    return tuple(table)


class SteeringEnvironment:
    """A linear environment (see `steering_environment`) and whether it has the car's state."""

    def __init__(self, function: Any, stateful: bool) -> None:
        self.function, self.stateful = function, stateful

    def __call__(self, state: Any, y: float, v: float) -> tuple[Any, float]:
        result: tuple[Any, float] = self.function(state, y, v)
        return result


def steering_environment(
    car: SteeringCar,
    scaling: Scaling,
    speed_m_s: float,
    rendering: SteeringRendering,
    period_s: float,
    tire_spin_rate_rad_s: float,
) -> SteeringEnvironment:
    """The steering law linearized on centre, as the sizing's environment: (state, y, v) ->
    (state, command), device units; the car's (sideslip, yaw rate, last wheel angle) its state.
    The friction element is left out (it only dissipates once it slips)."""
    fs, ps = scaling.force_scale, scaling.position_scale
    k, vehicle = car.torque, car.vehicle
    spin = (1.0 / (k.k4_1_Nm + k.k5_s_m_Nm * speed_m_s)) / tire_spin_rate_rad_s
    gain = k.k9_Nm_s_rad + spin
    transient = speed_m_s >= vehicle.kinematic_speed_m_s and rendering.aligning == "front-axle"

    def environment(state: Any, y: float, v: float) -> tuple[Any, float]:
        angle, rate = y / ps, v / ps
        if transient:
            beta, r, last = (0.0, 0.0, 0.0) if state is None else state
            now = single_track.VehicleState(beta, r, 0.0, 0.0, 0.0, 0.0, last)
            after, _ = single_track.step(now, VehicleInputs(speed_m_s, angle), vehicle, period_s)
            ay = single_track.aligning_lateral_accel(after, speed_m_s, vehicle)
            state = (after.sideslip_rad, after.yaw_rate_rad_s, after.front_wheel_angle_rad)
        else:
            ay = single_track.steady_state_lateral_accel(speed_m_s, angle, vehicle)
        return state, -fs * (k.k1_Nm_s2_m * ay + gain * rate)

    return SteeringEnvironment(environment, transient)
