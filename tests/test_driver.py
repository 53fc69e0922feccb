"""The driver of eq. (10) and its hand."""

from __future__ import annotations

import dataclasses

import pytest

from carfeel.models.drivers import shift as driver
from tests.conftest import default_params


def hold_still(params, steps=2000, dt=1e-3, x=0.0):
    state = driver.initial_state(x)
    out = None
    for _ in range(steps):
        state, out = driver.step(state, driver.DriverInputs(x, 0.0), params, dt)
    return state, out


def test_blocked_knob_gets_f_max():
    params = default_params().driver
    _, out = hold_still(params)
    assert out.force_N == pytest.approx(params.push_force_N, rel=1e-6)


def test_eq_10_target_is_linear_in_velocity():
    params = default_params().driver
    # A knob moving with the hand at steady speed v feels F = F_max * (1 - v / V0) once the hand
    # has settled (it moves with the knob, so the grip carries the muscle force).
    for fraction in (0.0, 0.25, 0.5, 0.8):
        v = fraction * params.push_velocity_m_s
        state = driver.initial_state()
        x, out = 0.0, None
        for _ in range(3000):
            state, out = driver.step(state, driver.DriverInputs(x, v), params, 1e-3)
            x += v * 1e-3
        assert out is not None
        assert out.force_N == pytest.approx(params.push_force_N * (1 - fraction), abs=0.05)


def test_release_then_pull_out_then_hand_off():
    params = dataclasses.replace(default_params().driver, pull_out=True)
    state = driver.initial_state(params.release_position_m)
    phases = []
    x = params.release_position_m
    for _ in range(int((params.hold_s + 0.2) / 1e-3)):
        state, out = driver.step(state, driver.DriverInputs(x, 0.0), params, 1e-3)
        phases.append(out.phase)
    assert phases[0] == "release" and phases[-1] == "pull"
    assert out.force_N < -0.5 * params.pull_force_N  # pulling toward neutral
    state, out = driver.step(
        state, driver.DriverInputs(params.neutral_position_m, 0.0), params, 1e-3
    )
    assert out.phase == "idle" and out.force_N == 0.0
