"""The on-centre feel metrics only where ISO 13674-1 measures them: in a weave."""

from __future__ import annotations

import math

import numpy as np
import pytest

from carfeel.analysis.steering_feel import is_weave, steering_feel
from carfeel.runs import SteeringRun, run_steering
from carfeel.simulation.result import Result


def feel_of_run(manoeuvre: str, tmp_path):
    path = tmp_path / f"{manoeuvre}.csv"
    run_steering(SteeringRun(manoeuvre), path)
    r = Result.from_csv(path)
    args = (r.time_s, r["speed_m_s"], r["steering_angle_rad"], r["lateral_accel_m_s2"],
            r["torque_Nm"])  # fmt: skip
    return r, steering_feel(*args, steering_ratio=16.0, wheelbase_m=2.46)


@pytest.mark.parametrize("manoeuvre", ["iso3888", "iso7401-sine", "iso7401-step"])
def test_transients_do_not_pass_for_on_centre_figures(manoeuvre, tmp_path):
    """The lane change's loop once gave 42.2 Nm/g against the weave's 22.3: now n/a, and why."""
    _, feel = feel_of_run(manoeuvre, tmp_path)
    assert math.isnan(feel.torque_gradient_Nm_per_g)
    assert math.isnan(feel.sensitivity_g_per_100deg)
    assert any("measured in a weave; this run is not one" in n for n in feel.notes)


def test_a_weave_gives_them(tmp_path):
    _, feel = feel_of_run("weave", tmp_path)
    # The car's 23.5 Nm/g law through the transient car: 22.3 (see test_steering).
    assert 18.0 < feel.torque_gradient_Nm_per_g < 26.0
    assert not any("not one" in n for n in feel.notes)


def test_a_measured_weave_with_noise_and_speed_jitter_is_still_a_weave(tmp_path):
    """Logs are not clean: 200 Hz with jitter, sensor noise, the speed wandering by 3 %."""
    r, _ = feel_of_run("weave", tmp_path)
    rng = np.random.default_rng(4)
    keep = np.sort(rng.choice(len(r.time_s), len(r.time_s) // 5, replace=False))
    t = r.time_s[keep] + rng.normal(0.0, 2e-4, len(keep))
    speed = r["speed_m_s"][keep] * (1.0 + 0.03 * np.sin(0.3 * t))
    angle = r["steering_angle_rad"][keep] + rng.normal(0.0, 0.002, len(keep))
    ok, why = is_weave(np.sort(t), speed, angle)
    assert ok, why


def test_a_drive_is_not_a_weave():
    """A minute of steering noise and wandering speed, as a road log holds."""
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 60.0, 0.01)
    angle = np.cumsum(rng.normal(0.0, 0.002, len(t)))
    speed = 20.0 + 5.0 * np.sin(0.05 * t)
    ok, why = is_weave(t, speed, angle)
    assert not ok and why
