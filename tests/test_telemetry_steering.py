"""Steering from the game's state (issue 29): the tyre's lag on the game's Ay."""

from __future__ import annotations

import math

import pytest

from carfeel.telemetry.driving import RELAXATION_LENGTH_M, TyreLag


def test_the_lag_follows_the_relaxation_length_over_the_speed() -> None:
    dt = 1e-3
    for speed in (10.0, 30.0, 45.0):
        lag = TyreLag()
        tau = RELAXATION_LENGTH_M / speed
        steps = round(tau / dt)
        for _ in range(steps):
            value = lag.step(1.0, speed, dt)
        # A first-order lag is at 1 - 1/e after its time constant; the 1 kHz Euler steps and
        # the time constant rounded to whole ms put it within 0.04 of that.
        assert abs(value - (1.0 - math.exp(-1.0))) < 0.04, (speed, value)


def test_a_launch_judder_does_not_reach_the_rim() -> None:
    """+-1 m/s^2 frame to frame (30 Hz), held at 60 Hz as iRacing's frames are, at 0.1 m/s:
    the lag's 1 s time constant at that pace leaves a ripple of a frame over 1 s (1.7% peak to
    peak; under 2% with what is left of the start's bias after 1 s); at 40 m/s the lag passes
    the chassis's Ay within 0.1 s."""
    lag = TyreLag()
    dt = 1e-3
    out = []
    for i in range(2000):
        frame = math.floor(i * dt * 60.0)
        out.append(lag.step(1.0 if frame % 2 else -1.0, 0.1, dt))
    assert max(abs(v) for v in out[1000:]) < 0.02
    fast = TyreLag()
    last = [fast.step(1.0, 40.0, dt) for _ in range(100)][-1]
    assert last > 0.99  # 11 ms at 40 m/s: passed within 0.1 s


def test_a_standing_tyre_still_relaxes_and_reset_clears() -> None:
    lag = TyreLag()
    for _ in range(5000):  # 5 s at standstill: the 1 s floor lets it get there
        lag.step(2.0, 0.0, 1e-3)
    assert abs(lag.value - 2.0) < 0.02
    lag.reset()
    assert lag.value == 0.0
    assert TyreLag().step(3.0, 1e6, 1e-3) == 3.0  # never past the target


# --- the game's own force-feedback torque (--game-torque) -----------------------------------


def _torque(samples: tuple[float, ...] = (), torque: float = math.nan, game_max: float = 10.0):
    from carfeel.telemetry.state import VehicleState

    return VehicleState(
        speed_m_s=20.0, wheel_torque_Nm=torque, wheel_torque_samples_Nm=samples,
        wheel_torque_max_Nm=game_max,
    )  # fmt: skip


def test_the_games_samples_play_at_their_rate_scaled_by_the_cars_torque() -> None:
    from carfeel.telemetry.driving import GAME_TORQUE_SAMPLE_HZ, GameTorque

    g = GameTorque(1.0, 5.0, math.nan, exogenous=True)  # the game's own scale (10 N*m)
    state = _torque((0.0, 1.0, 2.0, 3.0, 4.0, 5.0), 5.0)
    assert g.value(state, 0.0) == 0.0  # the frame's oldest sample on its arrival
    # Halfway between samples 1 and 2: 1.5 N*m of 10 at the game's full force; the law's sign
    # is the game's negated (the game: positive to the left; the law: resisting a left turn).
    assert g.value(state, 1.5 / GAME_TORQUE_SAMPLE_HZ) == pytest.approx(-0.15 * 5.0, rel=1e-12)
    assert g.value(state, 1.0) == pytest.approx(-0.5 * 5.0)  # after the last: held
    assert g.ticks == 3
    profile = GameTorque(1.0, 5.0, 20.0, exogenous=False)  # the car profile's scale first
    assert profile.value(_torque(torque=4.0), 0.0) == pytest.approx(-0.2 * 5.0)
    assert profile.value(_torque(torque=-400.0), 0.0) == 5.0  # clipped as the game's FFB does
    none = GameTorque(1.0, 5.0, math.nan, exogenous=False)
    assert math.isnan(none.value(_torque(), 0.0))  # the game sends no torque
    assert math.isnan(none.value(_torque(torque=3.0, game_max=math.nan), 0.0))  # nor a scale
    assert none.ticks == 0


def test_a_wheel_torque_out_of_any_cars_range_is_not_plausible() -> None:
    from carfeel.telemetry.state import plausible

    assert plausible(_torque((1.0, -2.0), 3.0))
    assert not plausible(_torque(torque=math.inf))
    assert not plausible(_torque((1.0, 1e6), 3.0))
    assert plausible(_torque())  # NaN: not sent


class _Inner:
    """A steering renderer's face to TelemetryDriven: its tau0 blend as SteeringRenderer's."""

    axes = 1
    columns = ("torque_aligning_Nm",)
    takes_lateral_accel = True

    def __init__(self) -> None:
        from carfeel.realtime.rendering import Scaling

        self.speed, self.effect = 10.0, 0.0
        self.gears: list[str] = []
        self.scaling = Scaling(0.5, 1.0)
        self.lateral_accel_m_s2: float | None = None
        self.game_torque_Nm: float | None = None
        self.game_torque_share = 0.0

    def tick(self, sample: object, dt_s: float) -> tuple[tuple[float, ...], tuple[object, ...]]:
        aligning = 2.0 * (self.lateral_accel_m_s2 or 0.0)
        if self.game_torque_Nm is not None:
            aligning += self.game_torque_share * (self.game_torque_Nm - aligning)
        return (-aligning * self.scaling.force_scale,), (aligning,)


class _Source:
    def __init__(self, state: object) -> None:
        self.state, self.age_s = state, 0.0
        self.events: list[str] = []

    def update(self, t_s: float) -> tuple[object, float]:
        return self.state, 1.0


def test_the_guard_looks_past_a_recorded_torque_but_hears_a_live_games() -> None:
    from carfeel.contracts import DeviceSample
    from carfeel.telemetry.driving import GameTorque, TelemetryDriven
    from carfeel.telemetry.state import VehicleState

    state = VehicleState(speed_m_s=20.0, lateral_accel_m_s2=1.0, wheel_torque_Nm=-4.0,
                         wheel_torque_max_Nm=10.0)  # fmt: skip
    sample = DeviceSample(0.0, (0.0,), (0.0,))
    effects = {}
    for exogenous in (True, False):
        driven = TelemetryDriven(
            _Inner(), _Source(state), "steering",  # type: ignore[arg-type]
            game_torque=GameTorque(0.5, 5.0, math.nan, exogenous),
        )  # fmt: skip
        commands, row = driven.tick(sample, 1e-3)
        # The game's 4 of 10 N*m resists (+2 model N*m); half of it with half the law's.
        law = 2.0 * driven.tyre_lag.value
        aligning = float(row[0])  # type: ignore[arg-type]
        assert aligning == pytest.approx(0.5 * law + 0.5 * 2.0)
        assert commands[0] == pytest.approx(-0.5 * aligning)  # force scale 0.5, the law's sign
        effects[exogenous] = driven.effect
    assert effects[True] == pytest.approx(-0.5 * 2.0 * 0.5)  # the game's part of the command
    assert effects[False] == 0.0  # live: in the loop through the game, heard whole
