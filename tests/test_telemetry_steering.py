"""Steering from the game's state (issue 29): the tyre's lag on the game's Ay."""

from __future__ import annotations

import math

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
