"""The physical steering model (issue 13): the acceptance points, in simulated time.

The acceptance tests run both shipped cars with physical tables (B- and D-segment); tolerances
say why they are that wide.
"""

from __future__ import annotations

import json
import math
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from carfeel.analysis.steering_feel import steering_feel
from carfeel.io.presets import load_steering
from carfeel.models.steering import physical
from carfeel.models.steering.physical import SLIDING_GRIP, PhysicalInputs, PhysicalParams
from carfeel.models.vehicle.tyres import brush
from carfeel.simulation import manoeuvres
from carfeel.simulation.result import Result
from carfeel.simulation.runner import run
from carfeel.simulation.steering import PHYSICAL_TERMS, physical_start, simulate_steering

G = 9.80665
CARS = ("b-segment", "d-segment")


@cache
def params(car: str = "b-segment") -> PhysicalParams:
    return load_steering(car).params.physical()


def release(
    speed_kmh: float, angle_deg: float, after_s: float, car: str = "b-segment"
) -> tuple[Result, int]:
    """Steer to `angle_deg` (0.5 s half-cosine), hold 1 s, let go; the run and the release index."""
    return release_with(params(car), speed_kmh, angle_deg, after_s)


def release_with(
    p: PhysicalParams, speed_kmh: float, angle_deg: float, after_s: float
) -> tuple[Result, int]:
    """`release` on the model `p`."""
    v, a0, ramp, hold = speed_kmh / 3.6, math.radians(angle_deg), 0.5, 1.0

    def inputs(t: float) -> PhysicalInputs:
        if t < ramp:
            rate = a0 * 0.5 * math.pi / ramp * math.sin(math.pi * t / ramp)
            return PhysicalInputs(v, a0 * 0.5 * (1 - math.cos(math.pi * t / ramp)), rate, 0.0, 1.0)
        if t < ramp + hold:
            return PhysicalInputs(v, a0, 0.0, 0.0, 1.0)
        return PhysicalInputs(v, 0.0, 0.0, 0.0, 0.0)

    result, _ = run(
        physical.step, physical_start(p, v, 0.0), p, duration_s=ramp + hold + after_s,
        inputs=inputs,
    )  # fmt: skip
    return result, round((ramp + hold) / 1e-3)


def test_brush_trail_collapses_so_the_aligning_moment_peaks_first():
    slips = np.linspace(1e-4, 0.3, 600)
    fy, mz = zip(*(brush(float(s), 3000.0, 40e3, 1.0, 0.035)[:2] for s in slips), strict=True)
    assert mz[0] / fy[0] == pytest.approx(0.035, rel=1e-3)  # trail t0 at zero slip
    # Analytic: Mz peaks at a quarter of the sliding slip 3 mu Fz / C, Fy saturates at it.
    assert slips[int(np.argmax(mz))] == pytest.approx(0.25 * 3 * 3000 / 40e3, abs=1e-3)
    assert max(fy) == pytest.approx(3000.0) and mz[-1] == 0.0


def test_terms_sum_to_the_torque():
    result, _ = release(100.0, 90.0, 1.0)
    total = sum(result[name] for name in PHYSICAL_TERMS)
    assert np.max(np.abs(total - result["torque_Nm"])) < 1e-9


@cache
def limit_run(name: str) -> Result:
    car = load_steering(name).params
    # Only the left circle, 1 s ramps and 1 s holds: the car's modes settle within 0.3 s.
    m = manoeuvres.iso4138(
        car.vehicle, max_lateral_accel_m_s2=11.0, ramp_s=1.0, hold_s=1.0, sides=("left",)
    )
    return simulate_steering(car, m, model="physical")


def ramp_means(result: Result, name: str) -> np.ndarray:
    """A signal's mean over the middle of each 1 s speed ramp (from 0.5 up to 11 m/s^2), where
    the driver steers in: the friction has one sign there (in the holds it flips as the driver
    eases off, and 2 Nm of its band would hide the cue)."""
    values = result[name]
    return np.array([values[k * 2000 + 600 : k * 2000 + 1000].mean() for k in range(1, 22)])


@pytest.mark.parametrize("car", CARS)
def test_iso4138_to_the_limit_ay_saturates_and_the_wheel_goes_light_first(car):
    result = limit_run(car)
    ay = ramp_means(result, "lateral_accel_m_s2") / G
    torque = ramp_means(result, "torque_Nm")
    assert 0.8 <= ay.max() <= 1.0  # the acceptance range
    # While Ay still rises (up to its peak; past it the driver winds on toward the lock and the
    # EPS damping adds torque), the torque peaks first and then falls: at least 0.05 g more Ay
    # (a tenth of the 0.4 g between the trail's and the force's peaks) with 0.2 Nm less torque
    # (the damping of the driver's faster steering near the limit adds up to 0.5 Nm; the cue
    # must stand above that).
    rising = int(np.argmax(ay)) + 1
    peak = int(np.argmax(torque[:rising]))
    later = slice(peak + 1, rising)
    assert np.any((torque[later] < torque[peak] - 0.2) & (ay[later] > ay[peak] + 0.05))
    assert result["front_grip_used"].max() > SLIDING_GRIP


@pytest.mark.parametrize("name", CARS)
def test_iso4138_understeer_gradient_at_low_ay_is_the_linear_cars(name):
    result = limit_run(name)
    car = load_steering(name).params.vehicle
    ay = ramp_means(result, "lateral_accel_m_s2")[:4]  # 1 .. 2.5 m/s^2
    wheels = ramp_means(result, "front_wheel_angle_rad")[:4]
    gradient = np.polyfit(ay, wheels, 1)[0]  # L/R is constant on the circle
    # 10 %: the brush's cubic term adds about 3 % at 0.25 g, the ramps leave a little lag.
    assert gradient == pytest.approx(car.understeer_gradient_rad_s2_m, rel=0.1)


@pytest.mark.parametrize("car", CARS)
def test_release_at_100_kmh_returns_overshoots_and_settles(car):
    result, i0 = release(100.0, 90.0, 4.0, car)
    angle = np.degrees(result["steering_angle_rad"][i0:])
    overshoot = -angle.min() / 90.0
    # Production cars overshoot the centre by about 10-50 % of the release angle when released
    # at speed (see DESIGN.md, issue 13: our stated range, not a measured figure of ours).
    assert 0.1 <= overshoot <= 0.5
    last = angle[-1000:]
    assert np.ptp(last) < 0.5 and abs(last.mean()) < 5.0  # settled, within the friction's band


@pytest.mark.parametrize("car", CARS)
def test_release_at_10_kmh_jacking_returns_it_partly(car):
    result, i0 = release(10.0, 270.0, 4.0, car)
    angle = np.degrees(result["steering_angle_rad"])
    assert 0.1 * 270.0 < angle[-1] < 0.8 * 270.0  # partly: neither stuck nor centred
    # The kingpin's jacking torque is the largest returning torque at that speed.
    sl = slice(i0, i0 + 2000)
    assert result["torque_jacking_Nm"][sl].mean() > result["torque_aligning_Nm"][sl].mean()


@pytest.mark.parametrize("car", CARS)
def test_parking_torque_in_the_assisted_range_and_growing_with_wind_up(car):
    rate = math.radians(90.0)
    p = params(car)
    result, _ = run(
        physical.step, physical.initial_state(p), p, duration_s=2.5,
        inputs=lambda t: PhysicalInputs(0.0, rate * t, rate, 0.0, 1.0),
    )  # fmt: skip
    angle = np.degrees(result["steering_angle_rad"])
    torque = result["torque_Nm"]
    at = {deg: torque[np.searchsorted(angle, deg)] for deg in (20, 45, 70, 180)}
    assert at[20] < at[45] < at[70] - 0.5  # wind-up: the patches twist before they slide
    # Assisted cars at parking: 2.5-6 Nm at the rim (DESIGN.md, issue 13).
    assert 2.5 <= at[180] <= 6.0
    # The patches slide at the dry-park moment: (2/3) mu Fz r at the kingpins, over the ratio.
    assert result["torque_park_Nm"][-1] == pytest.approx(
        p.park_moment_Nm / p.vehicle.steering_ratio
    )


@pytest.mark.parametrize("car_name", CARS)
@pytest.mark.parametrize("name", ["iso3888", "weave"])
def test_on_centre_torque_gradient_in_the_published_range(name, car_name):
    car = load_steering(car_name).params
    m = manoeuvres.build(name, car.vehicle, 80.0 if name == "iso3888" else None)
    r = simulate_steering(car, m, model="physical")
    feel = steering_feel(
        r.time_s, r["speed_m_s"], r["steering_angle_rad"], r["lateral_accel_m_s2"],
        r["torque_Nm"], steering_ratio=car.vehicle.steering_ratio,
        wheelbase_m=car.vehicle.wheelbase_m,
    )  # fmt: skip
    assert 15.0 <= feel.torque_gradient_Nm_per_g <= 30.0


@pytest.mark.parametrize("name", CARS)
def test_lane_change_at_250_kmh_slides_instead_of_4_g(name):
    car = load_steering(name).params
    r = simulate_steering(car, manoeuvres.build("iso3888", car.vehicle, 250.0), model="physical")
    assert np.abs(r["lateral_accel_m_s2"]).max() < 1.05 * G  # mu = 1 and load sensitivity
    grip = np.maximum(r["front_grip_used"], r["rear_grip_used"])
    assert grip.max() > SLIDING_GRIP


def energy_J(state: physical.PhysicalState, p: PhysicalParams) -> float:
    """Kinetic and spring energy of the steering system at standstill (assist off), J."""
    s, sr = p.system, p.vehicle.steering_ratio
    kf = s.friction_stiffness_Nm_rad
    lam = s.kingpin_inclination_rad
    delta = state.pinion_angle_rad / sr
    return (
        0.5 * s.hand_wheel_inertia_kg_m2 * state.hand_rate_rad_s**2
        + 0.5 * s.rack_inertia_kg_m2 * state.pinion_rate_rad_s**2
        + 0.5
        * s.torsion_bar_stiffness_Nm_rad
        * (state.hand_angle_rad - state.pinion_angle_rad) ** 2
        + 0.5 * kf * (state.hand_angle_rad - state.column_anchor_rad) ** 2
        + 0.5 * kf * (state.pinion_angle_rad - state.rack_anchor_rad) ** 2
        + 0.5 * p.tyres.wind_up_stiffness_Nm_rad * (delta - state.park_anchor_rad) ** 2
        + p.front_load_N
        * s.kingpin_offset_m
        * math.sin(lam)
        * math.cos(lam)
        * (1 - math.cos(delta))
    )


def test_released_at_standstill_without_assist_the_system_is_passive():
    """With the motor off (the assist is the only source), a twisted, released steering system
    at standstill never gains energy: springs, stick elements, dampers and jacking only."""
    import dataclasses

    p = params()
    off = dataclasses.replace(
        p.system, assist_gain_standstill_1_Nm=0.0, assist_gain_high_speed_1_Nm=0.0,
        active_return_Nm_rad=0.0,
    )  # fmt: skip
    p = dataclasses.replace(p, system=off)
    state = physical.initial_state(p)._replace(hand_angle_rad=1.0, column_anchor_rad=1.0)
    energies = [energy_J(state, p)]
    for _ in range(1000):
        state, _ = physical.step(state, PhysicalInputs(0.0, 0.0, 0.0, 0.0, 0.0), p, 1e-3)
        energies.append(energy_J(state, p))
    e = np.array(energies)
    # Semi-implicit Euler keeps a shadow energy within h*w/2 of the true one (the torsion bar's
    # relative mode, w = 72 rad/s: 4 %); 5 % bounds that, far below a real gain of energy.
    assert np.all(e[1:] <= e[0] * 1.05)
    assert e[-1] < 0.5 * e[0]  # and the dampers and frictions take it away


def _least_released_damping(p: PhysicalParams) -> float:
    """The least damping ratio of the model hands off, its frictions stuck, over the speeds
    the loop sizes for, on centre and at the torsion-bar torque where the assist's gain is
    largest; the car's own modes the rim does not take part in left out (as the sizing does)."""
    from carfeel.realtime import physical_steering as ps

    zetas = []
    for speed in ps.SPEEDS_M_S:
        for torque in (0.0, ps.assist_peak_torque(p, speed, 20.0)):
            own, _ = ps.linearize(p, speed, ps.operating_state(p, torque), 1e-3)
            zetas.append(ps.least_rim_damping(own, 1000.0, ps.clamped_modes(own, 1000.0)))
    return min(zetas)


@pytest.mark.parametrize("car", CARS)
def test_the_released_wheel_is_damped_at_every_speed_while_its_frictions_stick(car):
    """A released wheel that does not move enough to slide its frictions still settles: at
    standstill the rim and rack swing on the stick springs (7.5 Hz), where only the stick
    elements' pre-sliding damper dissipates; with the assist at its steepest the motor's gain
    takes damping away. 0.1 is a well-damped mechanical mode (a tenth of critical; both cars
    have at least 0.13). Without the damper the same check finds a growing mode."""
    import dataclasses

    p = params(car)
    assert _least_released_damping(p) >= 0.1
    bare = dataclasses.replace(p.system, presliding_damping_Nm_s_rad=0.0)
    assert _least_released_damping(dataclasses.replace(p, system=bare)) < 0.0


@pytest.mark.parametrize("car", CARS)
def test_released_at_250_kmh_the_wheel_settles(car):
    """Let go from 30 deg at 250 km/h (about 0.6 g, inside the tyres' limit), the wheel's weave
    with the car dies out: the EPS damping keeps rising with speed. With the damping the
    presets had before, 2.4 Nm*s/rad from about 70 km/h up with no rise, the same release
    limit-cycles (88 and 24 deg peak to peak on the B and D cars, measured), which this test's
    own check catches. 1 deg peak to peak over the last 2 s: settled, the friction's band is a
    fraction of that."""
    import dataclasses

    def last_swing(p: PhysicalParams) -> float:
        result, i0 = release_with(p, 250.0, 30.0, 8.0)
        return float(np.ptp(np.degrees(result["steering_angle_rad"][i0:])[-2000:]))

    p = params(car)
    assert last_swing(p) < 1.0
    held = dataclasses.replace(p.system, eps_damping_high_speed_Nm_s_rad=2.4,
                               eps_damping_rise_Nm_s3_rad_m2=0.0)  # fmt: skip
    assert last_swing(dataclasses.replace(p, system=held)) > 10.0


def test_a_wheel_nudged_at_standstill_settles_within_a_few_swings():
    """Hands off at standstill, the rim nudged within its friction band (a tenth of a degree:
    nothing slides): its swing falls below a tenth of the nudge after 0.3 s (measured: under
    1 % with the frictions' damper; 48 % without it, the model's 7.5 Hz at zeta 0.011)."""
    p = params()
    nudge = math.radians(0.1)
    state = physical.initial_state(p)._replace(hand_angle_rad=nudge)
    angles = []
    for _ in range(600):
        state, out = physical.step(state, PhysicalInputs(0.0, 0.0, 0.0, 0.0, 0.0), p, 1e-3)
        angles.append(out.steering_angle_rad)
    swing = np.abs(np.array(angles) - angles[-1])
    assert abs(state.column_anchor_rad) == 0.0 and abs(state.rack_anchor_rad) == 0.0  # stuck
    assert swing[300:].max() < 0.1 * nudge


def _b_segment_text() -> str:
    from importlib import resources

    return resources.files("carfeel.presets").joinpath("steering", "b-segment.toml").read_text()


def test_the_physical_tables_are_optional_but_come_together():
    from carfeel.errors import PresetError
    from carfeel.io.presets import from_toml

    text = _b_segment_text()
    paper_only = text[: text.index("[tyres]")]
    car = from_toml("steering", "paper-only", paper_only).params
    assert not car.has_physical and car.tyres is None
    half = text[: text.index("[steering_system]")]
    with pytest.raises(PresetError, match=r"both tables \[tyres\] and \[steering_system\]"):
        from_toml("steering", "half", half)


def test_a_rack_too_light_for_1_ms_steps_is_rejected():
    from carfeel.errors import PresetError
    from carfeel.io.presets import from_toml

    text = _b_segment_text().replace("rack_inertia_kg_m2 = 0.06", "rack_inertia_kg_m2 = 0.005")
    with pytest.raises(PresetError, match=r"rack_inertia_kg_m2 = 0.005 kg\*m\^2 is too light"):
        from_toml("steering", "light", text)


def test_cli_simulates_the_physical_model_and_reports_the_sliding_car(tmp_path, capsys):
    from carfeel.cli import main

    out = tmp_path / "dlc.csv"
    args = ["simulate", "steering", "--manoeuvre", "iso3888", "--speed-kmh", "250"]
    assert main([*args, "--steering-model", "physical", "--out", str(out)]) == 0
    result = Result.from_csv(out)
    assert "torque_assist_Nm" in result.names
    assert np.abs(result["lateral_accel_m_s2"]).max() < 1.05 * G
    assert "the car slides" in capsys.readouterr().out


@pytest.mark.parametrize(("road", "mu"), [("wet", 0.7), ("snow", 0.3)])
def test_the_road_sets_the_limit(road, mu):
    car = load_steering("b-segment").params
    r = simulate_steering(
        car, manoeuvres.build("iso3888", car.vehicle, 120.0), model="physical", road=road
    )
    # The lane change at 120 km/h asks for more than mu g: the car slides at the road's limit
    # (within 5 %: load sensitivity takes a little, the relaxation's transients add a little).
    peak = np.abs(r["lateral_accel_m_s2"]).max() / G
    assert 0.8 * mu < peak < 1.05 * mu
    assert np.maximum(r["front_grip_used"], r["rear_grip_used"]).max() > SLIDING_GRIP


def test_a_presets_own_mu_is_kept_unless_a_road_is_given(tmp_path, capsys):
    """A preset's tyres.friction_coefficient is its tyres' (a fitted mu among them): without
    --road the run keeps it; --road puts the tyres on that road instead. The lane change at
    120 km/h with mu 0.5 slides at about 0.5 g (the shipped car, mu 1.0, near 1 g)."""
    from carfeel.cli import main

    shipped = Path(__file__).parents[1] / "src/carfeel/presets/steering/b-segment.toml"
    text = shipped.read_text()
    assert "friction_coefficient = 1.0" in text
    slippery = tmp_path / "mu05.toml"
    slippery.write_text(text.replace("friction_coefficient = 1.0", "friction_coefficient = 0.5"))
    peaks = {}
    for name, extra in (("own", []), ("dry", ["--road", "dry"])):
        out = tmp_path / f"{name}.csv"
        args = [
            "simulate",
            "steering",
            "--steering-model",
            "physical",
            "--preset",
            str(slippery),
            "--manoeuvre",
            "iso3888",
            "--speed-kmh",
            "120",
            "--out",
            str(out),
        ]
        assert main([*args, *extra]) == 0  # fmt: skip
        result = Result.from_csv(out)
        peaks[name] = float(np.abs(result["lateral_accel_m_s2"]).max()) / G
        meta = json.loads(out.with_suffix(".json").read_text())
        assert float(meta["friction_coefficient"]) == (0.5 if name == "own" else 1.0)
    assert 0.4 < peaks["own"] < 0.525, peaks
    assert peaks["dry"] > 0.85, peaks
    capsys.readouterr()
    refused = ["simulate", "steering", "--manoeuvre", "iso3888", "--road", "snow", "--out",
               str(tmp_path / "x.csv")]  # fmt: skip
    assert main(refused) == 2
    assert "give --steering-model physical too" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()
