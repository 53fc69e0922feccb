"""The steering law at a negative speed (a car reversing, or a game that signs its speed): the
tire-spin term falls with |Vx| either way (eq. 5 with the speed's magnitude), so the torque at -v
is the torque at +v; no term blows up where K4 + K5 * Vx would pass zero (issue 26 point 9: only
the C port's edge-value test, skipped without a compiler, drove it)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carfeel.io.presets import load_steering
from carfeel.models.steering.torque import TorqueInputs, torque, torque_terms

LAW = load_steering("b-segment").params.torque


@settings(max_examples=300, deadline=None)
@given(
    speed=st.floats(0.0, 80.0),
    rate=st.floats(-20.0, 20.0),
    ay=st.floats(-15.0, 15.0),
)
def test_the_law_at_minus_v_is_the_law_at_v(speed: float, rate: float, ay: float) -> None:
    assert torque_terms(-speed, rate, ay, LAW) == torque_terms(speed, rate, ay, LAW)


def test_where_k4_plus_k5_vx_would_vanish_the_tire_spin_stays_bounded() -> None:
    """At Vx = -K4/K5 a law without the magnitude divides by zero; beyond it the tire spin
    would turn against the rate. With it, the term is the one at +K4/K5: bounded by
    pi/2 / K4, resisting the rate."""
    v = LAW.k4_1_Nm / LAW.k5_s_m_Nm
    for rate in (-5.0, 0.3, 5.0):
        reverse = torque(TorqueInputs(-v, rate, 0.0), LAW)
        forward = torque(TorqueInputs(v, rate, 0.0), LAW)
        assert reverse == forward
        assert math.isfinite(reverse.torque_tire_spin_Nm)
        assert abs(reverse.torque_tire_spin_Nm) <= math.pi / 2 / LAW.k4_1_Nm
        assert math.copysign(1.0, reverse.torque_tire_spin_Nm) == math.copysign(1.0, rate)
        far = torque(TorqueInputs(-3 * v, rate, 0.0), LAW)  # past the pole, reversing fast
        assert math.copysign(1.0, far.torque_tire_spin_Nm) == math.copysign(1.0, rate)


def test_the_batch_law_agrees_at_negative_speeds() -> None:
    """The numpy evaluation (fits, sweeps) gives the scalar law's terms, to the bit."""
    speed = np.linspace(-60.0, 60.0, 241)
    rate = np.sin(speed)
    ay = np.cos(speed) * 8.0
    batch = torque_terms(speed, rate, ay, LAW, atan=np.arctan)
    for i in range(len(speed)):
        scalar = torque_terms(float(speed[i]), float(rate[i]), float(ay[i]), LAW)
        assert tuple(float(b[i]) for b in batch) == pytest.approx(scalar, rel=1e-15, abs=0)
