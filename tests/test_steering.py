"""Steering wheel torque (paper eqs. 1, 4-7), the single-track car, manoeuvres and feel metrics."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carfeel.analysis.steering_feel import feel_of, steering_feel
from carfeel.io.presets import load_steering
from carfeel.models.steering.torque import SteeringTorqueParams, torque_terms
from carfeel.models.vehicle import single_track
from carfeel.models.vehicle.single_track import (
    VehicleInputs,
    VehicleParams,
    steady_state_lateral_accel,
)
from carfeel.simulation import manoeuvres
from carfeel.simulation.runner import run
from carfeel.simulation.steering import ImposedInputs, SteeringCar, imposed_step, simulate_steering

G = 9.80665


@functools.cache
def car() -> SteeringCar:
    return load_steering("b-segment").params


@functools.cache
def simulated(name: str, speed_kmh: float | None = None):
    c = car()
    return simulate_steering(c, manoeuvres.build(name, c.vehicle, speed_kmh))


def law() -> SteeringTorqueParams:
    return car().torque


# ---------------------------------------------------------------- the torque law


@given(
    speed=st.floats(0.0, 60.0),
    rate=st.floats(-20.0, 20.0),
    ay=st.floats(-12.0, 12.0),
)
def test_torque_is_odd_in_rate_and_lateral_acceleration(speed, rate, ay):
    plus = torque_terms(speed, rate, ay, law())
    minus = torque_terms(speed, -rate, -ay, law())
    for a, b in zip(plus, minus, strict=True):
        assert a == pytest.approx(-b, abs=1e-12)


def test_every_term_resists_the_driver():
    total, aligning, spin, friction, damping = torque_terms(10.0, 0.5, 2.0, law())
    assert aligning > 0 and spin > 0 and friction > 0 and damping > 0
    assert total == pytest.approx(aligning + spin + friction + damping)


@given(v1=st.floats(0.0, 50.0), dv=st.floats(0.1, 20.0), rate=st.floats(0.01, 10.0))
def test_tire_spin_share_falls_with_speed(v1, dv, rate):
    slow = torque_terms(v1, rate, 0.0, law())[2]
    fast = torque_terms(v1 + dv, rate, 0.0, law())[2]
    assert 0.0 < fast < slow


def test_aligning_torque_is_linear_near_zero_and_saturates():
    p = law()
    for ay in (1e-4, 1e-3, 1e-2):
        # K2*|Ay|^K3 is below 6e-4 here: linear within 0.1 %.
        assert torque_terms(0.0, 0.0, ay, p)[1] == pytest.approx(p.k1_Nm_s2_m * ay, rel=1e-3)
    ays = np.linspace(0.01, 12.0, 200)
    tau0 = torque_terms(0.0, 0.0, ays, p, atan=np.arctan)[1]
    assert np.all(np.diff(tau0 / ays) < 0)  # the secant gain falls: it saturates
    assert tau0[-1] < 0.5 * p.k1_Nm_s2_m * ays[-1]


def test_array_and_scalar_evaluation_agree():
    rng = np.random.default_rng(3)
    speed, rate, ay = rng.uniform(0, 40, 50), rng.uniform(-5, 5, 50), rng.uniform(-8, 8, 50)
    arrays = torque_terms(speed, rate, ay, law(), atan=np.arctan)
    for i in range(50):
        scalars = torque_terms(float(speed[i]), float(rate[i]), float(ay[i]), law())
        for a, s in zip(arrays, scalars, strict=True):
            assert a[i] == pytest.approx(s, rel=1e-12, abs=1e-15)


def test_at_standstill_the_torque_does_not_depend_on_the_wheel_angle():
    c = car()
    rate = 1.3
    torques = []
    for angle in (-6.0, -1.0, 0.0, 2.5, 9.0):
        state = single_track.initial_state()
        _, out = imposed_step(state, ImposedInputs(0.0, angle, rate), c, 1e-3)
        assert out.lateral_accel_m_s2 == 0.0
        torques.append(out.torque_Nm)
    assert max(torques) == min(torques)


# ---------------------------------------------------------------- the vehicle


def neutral(vehicle: VehicleParams) -> VehicleParams:
    """The same car with the rear stiffness set for neutral steer (a*C_r = b*C_f)."""
    rear = (
        vehicle.cg_to_front_axle_m
        * vehicle.front_cornering_stiffness_N_rad
        / (vehicle.cg_to_rear_axle_m)
    )
    return dataclasses.replace(vehicle, rear_cornering_stiffness_N_rad=rear)


def settle(vehicle: VehicleParams, speed: float, wheel_angle: float, seconds: float = 8.0):
    state = single_track.initial_state()
    for _ in range(int(seconds / 1e-3)):
        state, out = single_track.step(state, VehicleInputs(speed, wheel_angle), vehicle, 1e-3)
    return out


def test_the_understeer_gradient_is_the_settled_cars_steer_beyond_ackermann():
    """K_us against the transient model's own steady state (not its formula, which this test
    once re-implemented): settled at a wheel angle, the front wheels turn L/R + K_us * Ay, so
    (delta - L Ay / V^2) / Ay is K_us at every speed. The trapezoidal step is exact at steady
    state: 1e-6. A neutral-steering car has no characteristic speed."""
    v = car().vehicle
    for speed in (12.0, 27.8, 40.0):
        out = settle(v, speed, 0.3)
        ay = out.lateral_accel_m_s2
        beyond_ackermann = 0.3 / v.steering_ratio - v.wheelbase_m * ay / speed**2
        assert beyond_ackermann / ay == pytest.approx(v.understeer_gradient_rad_s2_m, rel=1e-6)
    assert neutral(v).characteristic_speed_m_s == math.inf


def test_neutral_steer_gives_v2_delta_over_l():
    v = neutral(car().vehicle)
    speed, wheel = 20.0, 0.5
    expected = speed**2 * (wheel / v.steering_ratio) / v.wheelbase_m
    assert steady_state_lateral_accel(speed, wheel, v) == pytest.approx(expected, rel=1e-9)
    # The transient model settles to it (trapezoidal rule: exact at steady state).
    assert settle(v, speed, wheel).lateral_accel_m_s2 == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("speed", [5.0, 15.0, 27.8, 40.0])
def test_transient_model_settles_to_the_steady_state(speed):
    v = car().vehicle
    out = settle(v, speed, 0.3)
    assert out.lateral_accel_m_s2 == pytest.approx(
        steady_state_lateral_accel(speed, 0.3, v), rel=1e-6
    )
    assert out.yaw_rate_rad_s == pytest.approx(out.lateral_accel_m_s2 / speed, rel=1e-6)


def test_yaw_gain_at_the_characteristic_speed_is_half_the_neutral_one():
    v = car().vehicle
    speed = v.characteristic_speed_m_s
    r = settle(v, speed, 0.2).yaw_rate_rad_s
    neutral_gain = speed / v.wheelbase_m * 0.2 / v.steering_ratio
    assert r == pytest.approx(neutral_gain / 2, rel=1e-6)


def test_steady_state_initial_state_is_a_fixed_point():
    v = car().vehicle
    state = single_track.steady_state(20.0, 0.4, v)
    new, out = single_track.step(state, VehicleInputs(20.0, 0.4), v, 1e-3)
    assert out.lateral_accel_m_s2 == pytest.approx(state.lateral_accel_m_s2, rel=1e-9)
    assert new.sideslip_rad == pytest.approx(state.sideslip_rad, rel=1e-9)
    assert new.yaw_rate_rad_s == pytest.approx(state.yaw_rate_rad_s, rel=1e-9)


def test_low_speed_circle_needs_the_ackermann_angle():
    """At 1.5 m/s on a 20 m circle the wheel angle is the Ackermann one within 1 %.

    Ay is 0.11 m/s^2 there, so the understeer adds K_us * Ay = 0.36 mrad to L/R = 123 mrad: 0.3 %.
    """
    c = car()
    radius, speed = 20.0, 1.5
    path = manoeuvres._circle(radius, 1.0, 3 * 2 * math.pi * radius)
    segment = manoeuvres.Segment("circle", 40.0, lambda t: speed, path=path)
    result = simulate_steering(c, manoeuvres.Manoeuvre("circle", "", (segment,)))
    held = result["steering_angle_rad"][result.time_s > 20.0]
    ackermann = c.vehicle.steering_ratio * math.atan(c.vehicle.wheelbase_m / radius)
    assert np.mean(held) == pytest.approx(ackermann, rel=0.01)
    assert np.ptp(held) < 0.01 * ackermann


def test_kinematic_fallback_at_walking_speed():
    """At walking speed the car rolls without slip: the rear axle turns about the point L /
    tan(delta) beside it, so the centre of gravity circles at sqrt(b^2 + (L / tan delta)^2) and
    the yaw rate is V over that radius: geometry, checked on the path the model drives (a full
    circle, fitted), not on its own formula. 1e-6: the position integrates exactly on a circle
    up to the 1 ms step's chord."""
    c = car()
    v = c.vehicle
    speed, wheel = 0.5, 8.0
    result, _ = run(imposed_step, single_track.initial_state(), c, duration_s=62.0,
                    inputs=lambda t: ImposedInputs(speed, wheel, 0.0))  # fmt: skip
    x, y = result["x_m"], result["y_m"]
    d, e, f = np.linalg.lstsq(np.column_stack([x, y, np.ones_like(x)]), -(x**2 + y**2),
                              rcond=None)[0]  # fmt: skip
    radius = math.sqrt(d * d / 4 + e * e / 4 - f)
    delta = wheel / v.steering_ratio
    expected = math.hypot(v.cg_to_rear_axle_m, v.wheelbase_m / math.tan(delta))
    assert radius == pytest.approx(expected, rel=1e-6)
    assert result["yaw_rate_rad_s"][-1] == pytest.approx(speed / expected, rel=1e-6)


# ---------------------------------------------------------------- manoeuvres


def test_iso3888_lanes_follow_the_standard_from_the_car_width():
    b = car().vehicle.width_m
    lane1, lane3, lane5 = manoeuvres.lane_change_lanes(b)
    assert (lane1.x_start_m, lane1.x_end_m) == (0.0, 15.0)
    assert lane3.x_start_m - lane1.x_end_m == 30.0
    assert lane3.x_end_m - lane3.x_start_m == 25.0
    assert lane5.x_start_m - lane3.x_end_m == 25.0
    assert lane5.x_end_m - lane5.x_start_m == 15.0
    assert lane1.width_m == pytest.approx(1.1 * b + 0.25)
    assert lane3.width_m == pytest.approx(1.2 * b + 0.25)
    assert lane5.width_m == pytest.approx(1.3 * b + 0.25)
    # Lane 3's near boundary 3.5 m from lane 1's centre line; lanes 1 and 5 share a boundary.
    assert lane3.y_centre_m - lane3.width_m / 2 == pytest.approx(3.5)
    assert lane5.y_centre_m - lane5.width_m / 2 == pytest.approx(-lane1.width_m / 2)


@pytest.mark.parametrize("speed_kmh", [60.0, 80.0])
def test_the_driver_keeps_the_car_inside_the_iso3888_lanes(speed_kmh):
    c = car()
    m = manoeuvres.build("iso3888", c.vehicle, speed_kmh)
    result = simulated("iso3888", speed_kmh)
    x, y = result["x_m"], result["y_m"]
    for lane in m.lanes:
        inside = (x >= lane.x_start_m) & (x <= lane.x_end_m)
        assert inside.sum() > 100
        # The car's width must fit: its centre stays within half the spare lane width.
        spare = (lane.width_m - c.vehicle.width_m) / 2
        assert np.max(np.abs(y[inside] - lane.y_centre_m)) <= spare


def test_iso4138_steps_ay_by_half_a_metre_per_second_squared_both_ways():
    result = simulated("iso4138")
    assert list(dict.fromkeys(result["segment"].tolist())) == ["left", "right"]
    speed = manoeuvres.iso4138_speed_profile(40.0, (0.5, 1.0, 1.5), 2.0, 3.0)[0]
    steps = [speed(t) ** 2 / 40.0 for t in (1.0, 4.9, 7.5, 9.9, 12.5, 14.9)]
    assert steps == pytest.approx([0.5, 0.5, 1.0, 1.0, 1.5, 1.5])
    for label, sign in (("left", 1.0), ("right", -1.0)):
        part = result["segment"] == label
        ay = result["lateral_accel_m_s2"][part] * sign
        assert np.all(ay > 0)
        # Steady holds: Ay = V^2/R within 2 % once settled, the car on the 40 m circle.
        v = result["speed_m_s"][part]
        hold = np.abs(np.gradient(v)) < 1e-9
        assert np.mean(np.abs(ay[hold] - v[hold] ** 2 / 40.0) / (v[hold] ** 2 / 40.0)) < 0.02
    assert np.max(np.abs(result["cross_track_m"])) < 0.05


def test_iso7401_step_reaches_4_m_s2_in_steady_state():
    result = simulated("iso7401-step")
    assert result["speed_m_s"][0] == pytest.approx(60 / 3.6)
    assert result["lateral_accel_m_s2"][-1] == pytest.approx(4.0, rel=1e-3)
    angle = result["steering_angle_rad"]
    rising = result.time_s[(angle > 0.1 * angle[-1]) & (angle < 0.9 * angle[-1])]
    assert rising[-1] - rising[0] <= 0.15  # the standard's rise time


def test_steer_cycle_goes_lock_to_lock_at_standstill():
    c = car()
    result = simulated("steer-cycle")
    angle = result["steering_angle_rad"]
    assert np.max(angle) == pytest.approx(c.vehicle.steering_lock_rad, rel=1e-4)
    assert np.min(angle) == pytest.approx(-c.vehicle.steering_lock_rad, rel=1e-4)
    assert np.all(result["lateral_accel_m_s2"] == 0.0)
    # Parking torque is the tire spin plus friction and damping, at most a few Nm.
    assert 3.0 < np.max(np.abs(result["torque_Nm"])) < 8.0


def test_weave_is_0_2_hz_and_about_0_2_g():
    result = simulated("weave")
    ay = result["lateral_accel_m_s2"]
    late = result.time_s > 10.0
    # Amplitude set from the steady-state gain; at 0.2 Hz the car's dynamic gain is within 5 %.
    assert np.max(np.abs(ay[late])) / G == pytest.approx(0.2, rel=0.05)
    # Frequency: the spectrum of the steering angle peaks at 0.2 Hz (25 s: 0.04 Hz bins).
    angle = result["steering_angle_rad"]
    spectrum = np.abs(np.fft.rfft(angle))
    freqs = np.fft.rfftfreq(len(angle), 1e-3)
    assert freqs[np.argmax(spectrum)] == pytest.approx(0.2, abs=0.04)


@pytest.mark.parametrize(
    ("name", "speed", "message"),
    [
        ("iso9999", None, "unknown manoeuvre"),
        ("weave", -5.0, "allowed 0 <= value <= 250 km/h"),
        ("weave", 5.0, "needs at least 10 km/h"),
        ("iso4138", 50.0, "drop --speed-kmh"),
        ("weave", float("nan"), "allowed 0 <= value"),
    ],
)
def test_bad_manoeuvre_requests_are_named(name, speed, message):
    from carfeel.errors import InputError

    with pytest.raises(InputError, match=message):
        manoeuvres.build(name, car().vehicle, speed)


# ---------------------------------------------------------------- feel metrics


def synthetic_weave(gradient, hysteresis, sensitivity, understeer_deg_per_g, speed=27.0):
    """A weave with known feel: T = gradient*Ay_g + hysteresis*sign(dAy/dt)."""
    t = np.arange(0.0, 25.0, 1e-3)
    ay_g = 0.25 * np.sin(2 * np.pi * 0.2 * t)
    torque = gradient * ay_g + hysteresis * np.sign(np.cos(2 * np.pi * 0.2 * t))
    ratio, wheelbase = 16.0, 2.5
    ay = ay_g * G
    # Steering through the understeer relation, delta = L*Ay/V^2 + K_us*Ay.
    k_us = math.radians(understeer_deg_per_g) / G
    angle = ratio * (wheelbase * ay / speed**2 + k_us * ay)
    return t, np.full_like(t, speed), angle, ay, torque, ratio, wheelbase


def test_metrics_recover_known_values_from_a_synthetic_weave():
    t, v, angle, ay, torque, ratio, wheelbase = synthetic_weave(24.0, 0.8, None, 2.0)
    feel = steering_feel(t, v, angle, ay, torque, steering_ratio=ratio, wheelbase_m=wheelbase)
    assert feel.torque_gradient_Nm_per_g == pytest.approx(24.0, rel=1e-6)
    assert feel.hysteresis_Nm == pytest.approx(0.8, rel=1e-6)
    assert feel.deadband_g == pytest.approx(0.8 / 24.0, rel=1e-6)
    assert feel.torque_at_0_1g_Nm == pytest.approx(2.4, rel=1e-6)
    assert feel.understeer_gradient_deg_per_g == pytest.approx(2.0, rel=1e-6)
    gain_g_per_rad = 1 / G / (ratio * (wheelbase / 27.0**2 + math.radians(2.0) / G))
    assert feel.sensitivity_g_per_100deg == pytest.approx(
        gain_g_per_rad * math.radians(100.0), rel=1e-6
    )
    assert feel.notes == ()


def test_metrics_hold_up_on_a_noisy_lagging_log():
    """Ay lags the steering by 20 deg and every channel carries sensor noise, as a measured log.

    The branch split low-passes Ay (1.5 Hz, zero phase), so noise of 0.05 m/s^2 (0.005 g) and
    0.05 Nm leaves the loop's branches intact: gradient, hysteresis and deadband within 3 %, the
    torque at 0.1 g within 2 %. The sensitivity is fitted per branch at the centre, where a
    lagging Ay crosses zero with slope gain / cos(lag): that within 3 % (one fit through both
    branches would read gain * cos(lag) instead, biased by the loop's width).
    """
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 25.0, 1e-3)
    w = 2 * np.pi * 0.2
    lag = np.radians(20.0)
    angle = np.radians(12.0) * np.sin(w * t)
    ay_g = 0.25 * np.sin(w * t - lag)
    torque = 22.0 * ay_g + 1.0 * np.sign(np.cos(w * t - lag))
    ay = ay_g * G + rng.normal(0.0, 0.05, t.size)
    torque = torque + rng.normal(0.0, 0.05, t.size)
    feel = steering_feel(t, np.full_like(t, 27.0), angle, ay, torque)
    assert feel.torque_gradient_Nm_per_g == pytest.approx(22.0, rel=0.03)
    assert feel.hysteresis_Nm == pytest.approx(1.0, rel=0.03)
    assert feel.deadband_g == pytest.approx(1.0 / 22.0, rel=0.03)
    assert feel.torque_at_0_1g_Nm == pytest.approx(2.2, rel=0.02)
    in_phase = 0.25 / 12.0 * 100.0
    assert feel.sensitivity_g_per_100deg == pytest.approx(in_phase / math.cos(lag), rel=0.03)


def test_understeer_gradient_is_refused_for_a_transient_run():
    c = car()
    result = simulated("iso7401-sweep")
    feel = feel_of(result, c.vehicle.steering_ratio, c.vehicle.wheelbase_m)
    assert math.isnan(feel.understeer_gradient_deg_per_g)
    assert any("quasi-steady" in note for note in feel.notes)


def test_iso4138_gives_the_understeer_gradient_of_the_car():
    c = car()
    result = simulated("iso4138")
    feel = feel_of(result, c.vehicle.steering_ratio, c.vehicle.wheelbase_m)
    # The steady holds between speed steps: within 3 % (the driver's pursuit error on the circle
    # and the last transients of each step).
    assert feel.understeer_gradient_deg_per_g == pytest.approx(
        c.vehicle.understeer_gradient_deg_per_g, rel=0.03
    )


def test_metrics_say_what_a_run_cannot_give():
    result = simulated("steer-cycle")
    feel = feel_of(result, None, None)
    assert math.isnan(feel.torque_gradient_Nm_per_g)
    assert any("understeer gradient needs" in note for note in feel.notes)


def test_weave_metrics_of_the_default_car_match_its_parameters():
    c = car()
    result = simulated("weave")
    feel = feel_of(result, c.vehicle.steering_ratio, c.vehicle.wheelbase_m)
    # Understeer gradient of the linear car: the 0.2 Hz weave is quasi-static to within 2 %.
    assert feel.understeer_gradient_deg_per_g == pytest.approx(
        c.vehicle.understeer_gradient_deg_per_g, rel=0.02
    )
    # On-centre gradient: K1 * g = 23.5 Nm/g at 0 g, lowered by the car's lag between wheel and
    # Ay (the rate terms add in quadrature): within 10 %. And, measured, inside the 20-30 Nm/g
    # of measured cars the preset's source claims (the claim once asserted on K1 itself).
    assert feel.torque_gradient_Nm_per_g == pytest.approx(c.torque.k1_Nm_s2_m * G, rel=0.1)
    assert 20.0 <= feel.torque_gradient_Nm_per_g <= 30.0
    # Sensitivity: the steady-state gain at 100 km/h (1.74 g/100 deg), the 0.2 Hz dynamics
    # within 5 %.
    steady = steady_state_lateral_accel(100 / 3.6, math.radians(100.0), c.vehicle) / G
    assert feel.sensitivity_g_per_100deg == pytest.approx(steady, rel=0.05)
    # Torque at 0.1 g: tau0 at 0.981 m/s^2 (2.09 Nm with the preset's saturation), the friction
    # and damping averaging out over the two branches: within 5 %.
    tau0 = torque_terms(0.0, 0.0, 0.1 * G, c.torque)[1]
    assert feel.torque_at_0_1g_Nm == pytest.approx(tau0, rel=0.05)
    assert feel.hysteresis_Nm > 0.5  # the friction term (K7) makes a visible loop


@settings(max_examples=20, deadline=None)
@given(amplitude=st.floats(0.05, 0.5))
def test_imposed_run_is_odd_in_the_steering_input(amplitude):
    c = car()

    def inputs(sign):
        return lambda t: ImposedInputs(
            20.0, sign * amplitude * math.sin(3 * t), sign * 3 * amplitude * math.cos(3 * t)
        )

    plus, _ = run(imposed_step, single_track.initial_state(), c, duration_s=1.0, inputs=inputs(1))
    minus, _ = run(imposed_step, single_track.initial_state(), c, duration_s=1.0, inputs=inputs(-1))
    for name in ("torque_Nm", "lateral_accel_m_s2", "yaw_rate_rad_s", "y_m"):
        assert np.allclose(plus[name], -minus[name], atol=1e-12), name
