"""Telemetry into the renderers: a wrapper the session puts around the H-pattern or steering
renderer. Each tick it polls the `VehicleSource` and, blended by its weight with the renderer's
own values (the passive fallback), sets what the model takes from the game:
  steering  speed and Ay (tau0's Ay is the game's, or speed x yaw rate if the game has no Ay,
            lagged as the front tyres pass it to the rim: `TyreLag`);
            with no telemetry tau0 fades to zero and the wheel keeps its friction, damping, stop;
            the physical model (`takes_lateral_accel` False) takes the speed only: its Ay is
            its own tyres' (DESIGN.md, issue 13 in the loop);
  hpattern  vehicle speed, engine speed and the clutch pedal for the synchronizer (a shift
            without the clutch balks and grinds, a rev-matched one goes through); with no
            telemetry the clutch counts as pressed and the speeds go back to the run's.
It adds the engine's vibration to the renderer's `effect` (the additive vibrations the
oscillation guard looks past) and drives the gear output from the H-pattern's state.
"""

from __future__ import annotations

import math
from typing import Any

from carfeel.contracts import DeviceSample
from carfeel.telemetry.cues import LeverCues, bite_coupling, cue_weight, octave_below
from carfeel.telemetry.gearout import GearDriver
from carfeel.telemetry.source import VehicleSource
from carfeel.telemetry.state import VehicleState

DEFAULT_CYLINDERS = 4
LIMITER_HZ = 12.0
"""The rev limiter's cut felt as an on-off pulse at 12 Hz (a fuel cut's typical rate)."""
LIMITER_FRACTION = 0.97
RELAXATION_LENGTH_M = 0.45
"""The front tyres' lateral relaxation length (the d-segment preset's, a 17-inch tyre): the
rolling distance over which their force follows a change of slip."""
RELAXATION_MIN_SPEED_M_S = 0.45
"""Below it the lag's time constant stays at its 1 s (relaxation length over this speed): a
standing tyre builds no force from the game's sample noise, but the lag does not freeze."""


class TyreLag:
    """The game's Ay as the front tyres pass it to the rim: a first-order lag of time constant
    relaxation length / speed (about 15 ms at 30 m/s, 1 s at a walking pace). A game's Ay at
    the launch is the chassis's (clutch judder at 20-30 Hz, +-1 m/s^2 frame to frame on
    iRacing's .ibt) and held for a frame at 60 Hz: neither reaches the rim through a rolling
    tyre, and the steering law would render both as a torque the oscillation guard stops."""

    def __init__(self, relaxation_length_m: float = RELAXATION_LENGTH_M) -> None:
        self.relaxation_length_m = relaxation_length_m
        self.value = 0.0

    def step(self, target: float, speed_m_s: float, dt_s: float) -> float:
        """The lagged value after `dt_s` rolling at `speed_m_s` towards `target` (its unit)."""
        speed = max(abs(speed_m_s), RELAXATION_MIN_SPEED_M_S)
        self.value += min(1.0, speed * dt_s / self.relaxation_length_m) * (target - self.value)
        return self.value

    def reset(self) -> None:
        self.value = 0.0


class EngineVibration:
    """The engine's firing frequency, rpm / 60 * cylinders / 2 (four-stroke), as a sine on the
    first axis: scaled by load (0.3 + 0.7 * throttle), kept below a quarter of the loop rate
    (an octave down at a time) so that it cannot alias; plus the rev limiter's pulse."""

    def __init__(self, rate_hz: float, amplitude: float, limiter_amplitude: float) -> None:
        self.ceiling_hz = rate_hz / 4.0
        self.amplitude, self.limiter_amplitude = amplitude, limiter_amplitude
        self.phase = 0.0
        self.limiter_phase = 0.0
        self.frequency_hz = 0.0

    def step(self, state: VehicleState, weight: float, dt_s: float) -> float:
        rpm = state.engine_speed_rpm
        if weight <= 0.0 or not rpm > 0.0:
            self.frequency_hz = 0.0
            return 0.0
        f = octave_below(rpm / 60.0 * (state.cylinders or DEFAULT_CYLINDERS) / 2.0, self.ceiling_hz)
        self.frequency_hz = f
        self.phase = (self.phase + 2.0 * math.pi * f * dt_s) % (2.0 * math.pi)
        throttle = state.throttle if 0.0 <= state.throttle <= 1.0 else 0.5
        out = self.amplitude * (0.3 + 0.7 * throttle) * math.sin(self.phase)
        if rpm >= LIMITER_FRACTION * state.engine_max_rpm:  # False when the max is NaN
            self.limiter_phase = (self.limiter_phase + LIMITER_HZ * dt_s) % 1.0
            out += self.limiter_amplitude * (1.0 if self.limiter_phase < 0.5 else -1.0)
        return weight * out


GAME_TORQUE_SAMPLE_HZ = 360.0
"""iRacing's SteeringWheelTorque_ST: six samples a 60 Hz frame (the only game that sends any)."""


class GameTorque:
    """The game's own force-feedback torque as the steering law's tau0 (`--game-torque SHARE`:
    0 the law's alone, 1 the game's instead), in model N*m and the law's sign (positive
    resisting a left turn): -torque / scale x the model's torque at the device's full force,
    the fraction held within +-1 as the game's own force feedback clips. The scale is the car
    profile's torque scale, else the game's (iRacing's SteeringWheelMaxForceNm). Where the game
    sends samples within its frame (oldest first, the last the frame's value) they are played
    at their rate from the frame's arrival, linearly between them: the game's 360 Hz detail,
    one frame (13.9 ms) late, instead of a 60 Hz staircase. Only tau0 is blended: the law's
    friction, damping and stop stay, and the loop's limiter and slew limit the sum as every
    rendering. The oscillation guard hears the game's torque whole from a live game (it is in
    a loop through the game: the game's wheel is the device); from a file image (`exogenous`)
    nothing of the device reaches it, so it is a recorded input the guard looks past as past
    the vibrations: on the .ibt the recorded driver's 4-6 Hz corrections would read as a
    limit cycle of a held wheel."""

    def __init__(
        self, share: float, full_model_Nm: float, torque_scale_Nm: float, exogenous: bool
    ) -> None:
        self.share, self.full_model_Nm = share, full_model_Nm
        self.torque_scale_Nm = torque_scale_Nm
        self.exogenous = exogenous
        self.ticks = 0
        """Ticks the game's torque was there to blend."""

    def value(self, state: VehicleState, age_s: float) -> float:
        """Model N*m (NaN where the game sends no torque or no scale is known); `age_s` the
        loop's time since the frame came."""
        samples = state.wheel_torque_samples_Nm
        if samples:
            at = min(max(age_s, 0.0) * GAME_TORQUE_SAMPLE_HZ, len(samples) - 1.0)
            i = int(at)
            raw = samples[i] if i + 1 >= len(samples) else (
                samples[i] + (at - i) * (samples[i + 1] - samples[i])
            )  # fmt: skip
        else:
            raw = state.wheel_torque_Nm
        scale = self.torque_scale_Nm
        if not scale > 0.0:  # NaN: no profile gives one
            scale = state.wheel_torque_max_Nm
        fraction = -raw / scale if scale > 0.0 else math.nan
        if not math.isfinite(fraction):
            return math.nan
        self.ticks += 1
        return max(-1.0, min(1.0, fraction)) * self.full_model_Nm


class _Pedal:
    __slots__ = ("clutch_pedal", "throttle")

    def __init__(self) -> None:
        self.clutch_pedal = 1.0
        self.throttle = 0.0
        """The game's throttle 0..1 (a truck's split waits while it is on, clutch out)."""


def steering_needs(state: VehicleState) -> bool:
    ay_or_yaw = not (math.isnan(state.lateral_accel_m_s2) and math.isnan(state.yaw_rate_rad_s))
    return not math.isnan(state.speed_m_s) and ay_or_yaw


def speed_needs(state: VehicleState) -> bool:
    """The physical steering model takes the game's speed only."""
    return not math.isnan(state.speed_m_s)


def hpattern_needs(state: VehicleState) -> bool:
    return not (math.isnan(state.speed_m_s) or math.isnan(state.engine_speed_rpm))


class Wrapping:
    """A renderer around `inner`: its gears and its model steps per tick are the inner's."""

    inner: Any

    @property
    def gears(self) -> list[str]:
        gears: list[str] = self.inner.gears
        return gears

    @property
    def substeps(self) -> int:
        return int(self.inner.substeps)

    @substeps.setter
    def substeps(self, value: int) -> None:
        self.inner.substeps = value


class TelemetryDriven(Wrapping):
    """A renderer driven by telemetry (see the module); the `Renderer` protocol, passed through."""

    EXTRA = (
        "telemetry_weight", "game_speed_m_s", "game_lateral_accel_m_s2", "game_engine_speed_rpm",
        "game_gear", "game_clutch_pedal", "engine_vibration", "model_speed_m_s",
        "model_engine_speed_rad_s", "model_clutch_pedal", "game_lateral_accel_lagged_m_s2",
        "game_torque_model_Nm", "cue_wall_N", "cue_refusing", "cue_grind_N",
    )  # fmt: skip

    def __init__(
        self,
        inner: Any,
        source: VehicleSource,
        model: str,
        vibration: EngineVibration | None = None,
        gear_driver: GearDriver | None = None,
        game_torque: GameTorque | None = None,
        cues: LeverCues | None = None,
    ) -> None:
        self.inner, self.source, self.model = inner, source, model
        self.axes: int = inner.axes
        self.columns: tuple[str, ...] = (*inner.columns, *self.EXTRA)
        self.vibration, self.gear_driver = vibration, gear_driver
        self.effect = 0.0
        self.fallback_speed = float(inner.speed)
        self.fallback_engine = float(getattr(inner, "engine", 0.0))
        self.hand = getattr(inner, "clutch", None)
        self.pedal = _Pedal()
        self.tyre_lag = TyreLag()
        self.game_torque = game_torque if hasattr(inner, "game_torque_Nm") else None
        self._game_torque_Nm = math.nan
        self.cues = cues

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        state, w = self.source.update(sample.time_s)
        inner = self.inner
        speed = state.speed_m_s if w > 0.0 else self.fallback_speed
        inner.speed = w * speed + (1.0 - w) * self.fallback_speed
        if self.model == "steering" and getattr(inner, "takes_lateral_accel", True):
            ay = state.lateral_accel_m_s2
            if math.isnan(ay):
                ay = state.speed_m_s * state.yaw_rate_rad_s
            if w > 0.0:
                inner.lateral_accel_m_s2 = w * self.tyre_lag.step(ay, state.speed_m_s, dt_s)
            else:  # faded out: the lag starts afresh when the game comes back
                self.tyre_lag.reset()
                inner.lateral_accel_m_s2 = 0.0
            if self.game_torque is not None:
                g = self.game_torque.value(state, self.source.age_s) if w > 0.0 else math.nan
                self._game_torque_Nm = g
                # Where the game sends none, tau0 stays the law's (of the game's Ay).
                inner.game_torque_Nm = None if math.isnan(g) else w * g
                inner.game_torque_share = self.game_torque.share
        game_effect = 0.0
        if self.game_torque is not None and self.game_torque.exogenous and inner.game_torque_Nm:
            # The game's part of the device command (the renderer's sign: command = -torque).
            game_effect = -self.game_torque.share * inner.game_torque_Nm * inner.scaling.force_scale
        else:
            engine = state.engine_speed_rpm * math.pi / 30.0 if w > 0.0 else self.fallback_engine
            inner.engine = w * engine + (1.0 - w) * self.fallback_engine
            hand_pedal = float(getattr(self.hand, "clutch_pedal", 1.0))
            game_pedal = state.clutch_pedal if 0.0 <= state.clutch_pedal <= 1.0 else hand_pedal
            self.pedal.clutch_pedal = w * game_pedal + (1.0 - w) * 1.0
            throttle = state.throttle if 0.0 <= state.throttle <= 1.0 else 0.0
            self.pedal.throttle = w * throttle
            inner.clutch = self.pedal
            if self.cues is not None:
                self.cues.update(state, w, str(inner.state.gear), dt_s)
                inner.cues = self.cues
        commands, row = inner.tick(sample, dt_s)
        # Cues are off in a replay or while paused; on the lever the engine comes through the
        # clutch (its bite point).
        cw = cue_weight(w, state)
        if self.model != "steering":
            cw *= bite_coupling(state.clutch_pedal, self.cues.p) if self.cues else 1.0
        vibration = self.vibration.step(state, cw, dt_s) if self.vibration is not None else 0.0
        grind = 0.0
        if self.cues is not None:
            grind = self.cues.grind(dt_s) * inner.scaling.force_scale
            vibration += grind
        self.effect = inner.effect + vibration + game_effect
        if vibration:
            commands = (commands[0] + vibration, *commands[1:])
        if self.gear_driver is not None:
            self.gear_driver.update(inner.state)
        extra = (w, state.speed_m_s, state.lateral_accel_m_s2, state.engine_speed_rpm,
                 state.gear, state.clutch_pedal, vibration, inner.speed,
                 getattr(inner, "engine", math.nan), self.pedal.clutch_pedal,
                 self.tyre_lag.value, self._game_torque_Nm,
                 self.cues.wall_N if self.cues else 0.0,
                 int(bool(self.cues.refused)) if self.cues else 0, grind)  # fmt: skip
        return commands, (*row, *extra)

    def commanded(self, now_ns: int) -> None:
        """The loop sent this tick's commands at `now_ns` (the wall clock's): the newest
        packet's packet-to-force latency (`VehicleSource.commanded`)."""
        self.source.commanded(now_ns)

    def close(self) -> None:
        """Release the gear output's buttons and the socket (stop, fault or exit)."""
        c = self.cues
        if c is not None and (c.refusals or c.mismatch_s):
            held = f"; pushed out of a gear the game did not take {c.holds} times" if c.hold else ""
            self.source.events.append(
                f"cues: the gate refused a gear {c.refusals} times (clutch out, revs apart); "
                f"the lever and the game disagreed on the gear for {c.mismatch_s:.2f} s{held}"
            )
        g = self.game_torque
        if g is not None and not g.ticks:
            self.source.events.append(
                "--game-torque: the game sent no force-feedback torque (or no torque scale: "
                "give the car's torque_scale_Nm in --car-presets); tau0 was the law's alone"
            )
        try:
            if self.gear_driver is not None:
                self.gear_driver.release()
                self.gear_driver.output.close()
        finally:
            self.source.close()
