"""The physical steering renderer and its sizing, piece by piece (fast: no loop runs). The loop
itself, on the plants, is tests/test_physical_loop.py."""

from __future__ import annotations

import dataclasses
import math
from typing import cast

import numpy as np
import pytest

from carfeel.io.presets import load_steering
from carfeel.models.steering import physical
from carfeel.models.steering.physical import PhysicalInputs
from carfeel.realtime import physical_steering as ps
from carfeel.realtime.devices.base import DeviceSample
from carfeel.realtime.devices.virtual import virtual_device
from carfeel.realtime.physical_steering import PhysicalSizing, PhysicalSteeringRenderer
from carfeel.realtime.rendering import Reading, Scaling, velocity_sections
from carfeel.realtime.stability import least_damping_ratio, size

CAR = load_steering("b-segment").params.physical()
SECTIONS = velocity_sections(1000.0)
SPEED = 100.0 / 3.6


def device(kind: str = "dd-wheel", delay_s: float = 0.004):
    info = virtual_device(kind, delay_s=delay_s).info
    return info, size(info, 1000.0, SECTIONS), Scaling(0.9 * info.max_force / 10.0, 1.0)


def named(renderer: PhysicalSteeringRenderer, row: tuple[object, ...]) -> dict[str, float]:
    """A recorded row by column (every value of this renderer's rows is a float)."""
    return {name: cast(float, value) for name, value in zip(renderer.columns, row, strict=True)}


def sized_for(kind: str = "dd-wheel", substeps: int = 1, speeds=(SPEED,)):
    info, sizing, scaling = device(kind)
    sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, sizing, substeps, speeds)
    assert isinstance(sized, PhysicalSizing)
    return info, sizing, scaling, sized


@pytest.mark.parametrize("substeps", [1, 2])
def test_the_loop_the_sizing_analyses_is_the_loop_the_renderer_runs(substeps):
    """Small motions of the device (a tenth of a milliradian: the frictions stay stuck, the
    tyres linear): the renderer's commands are the sizing's linear environment's, fed the same
    readings and velocities, within 0.1 % (what is left is the model's nonlinearity at that
    amplitude). A change to either side (coupling, damping, sub-steps, scales) breaks this."""
    info, sizing, scaling, sized = sized_for(substeps=substeps)
    renderer = PhysicalSteeringRenderer(CAR, SPEED, scaling, 1000.0, sized, info)
    renderer.substeps = substeps
    model = ps.rendered_params(CAR, info, scaling, sizing, 1e-3 / substeps)
    assert model.system.hand_wheel_inertia_kg_m2 == sized.rim_inertia_kg_m2
    a, b = ps.linearize(model, SPEED, ps.operating_state(model, 0.0), 1e-3 / substeps)
    fs, ps_ = scaling.force_scale, scaling.position_scale
    environment = ps.coupled_environment(
        a, b, sized.coupling_stiffness * ps_ / fs, sized.coupling_damping * ps_ / fs, fs, ps_,
        sized.schedule[0][1], substeps,
    )  # fmt: skip
    reading = Reading(1000.0)
    state = None
    ours, theirs = [], []
    for k in range(600):
        y = 1e-4 * math.sin(2 * math.pi * 3.0 * k * 1e-3) + 5e-5 * math.sin(0.05 * k)
        commands, _ = renderer.tick(DeviceSample(k * 1e-3, (y,), None), 1e-3)
        _, v = reading.step(y, 1e-3)
        state, u = environment(state, y, v)
        ours.append(commands[0])
        theirs.append(u)
    ours_a, theirs_a = np.array(ours), np.array(theirs)
    assert np.max(np.abs(ours_a)) > 1e-3  # a command to compare
    assert np.max(np.abs(ours_a - theirs_a)) < 1e-3 * np.max(np.abs(ours_a))


def test_the_linearization_is_the_models_step():
    """A x + B tau against `physical.step` from a perturbed state: within 1e-4 of the response
    (the brush tyre's second-order term at a slip of 1e-5 rad, C*alpha / (3 mu Fz) ~ 5e-5)."""
    model = CAR
    around = ps.operating_state(model, 0.0)
    a, b = ps.linearize(model, SPEED, around, 1e-3)
    rng = np.random.default_rng(1)
    dx = 1e-5 * rng.standard_normal(len(ps.KEPT))
    full = list(around)
    for j, i in enumerate(ps.KEPT):
        full[i] += dx[j]
    torque = 0.01
    new, _ = physical.step(physical.PhysicalState(*full),
                           PhysicalInputs(SPEED, 0.0, 0.0, torque, 0.0), model, 1e-3)  # fmt: skip
    response = np.array([new[i] for i in ps.KEPT])
    predicted = a @ dx + b * torque
    assert np.max(np.abs(response - predicted)) < 1e-4 * np.max(np.abs(predicted))
    assert np.max(np.abs(predicted)) > 0.0


def test_the_first_tick_starts_the_model_where_the_device_is():
    """After the calibration pulses the rim is off centre: the model starts there (the car in
    steady cornering at that angle), so the coupling is not stretched at the first tick."""
    info, _sizing, scaling, sized = sized_for()
    renderer = PhysicalSteeringRenderer(CAR, SPEED, scaling, 1000.0, sized, info)
    angle = math.radians(4.0)
    _, row = renderer.tick(DeviceSample(0.0, (angle,), None), 1e-3)
    columns = named(renderer, row)
    assert abs(columns["coupling_stretch_rad"]) < 1e-6
    assert columns["steering_angle_rad"] == pytest.approx(angle, abs=1e-6)
    assert columns["lateral_accel_m_s2"] > 0.5  # cornering to the left, as the rim says


def test_the_wall_inside_the_travel_pushes_back_and_only_beyond_it():
    """The belt wheel turns 450 deg, the car's lock is at 540: a passive wall at 95 % of the
    travel, sized with what the coupling leaves of the budget; none on the dd-wheel (900 deg:
    the car's own lock, through the coupling, is within it)."""
    info, _sizing, scaling, sized = sized_for("wheel")
    assert sized.wall_stiffness > 0.0
    dd = sized_for("dd-wheel")[3]
    assert dd.wall_stiffness == 0.0
    walls = []
    for depth in (-0.01, 0.02, 0.05):
        renderer = PhysicalSteeringRenderer(CAR, SPEED, scaling, 1000.0, sized, info)
        angle = 0.95 * info.travel + depth
        for k in range(3):  # at rest there: no velocity
            _, row = renderer.tick(DeviceSample(k * 1e-3, (angle,), None), 1e-3)
        walls.append(named(renderer, row)["rendering_wall_Nm"])
    assert walls[0] == 0.0
    assert walls[2] > walls[1] > 0.0  # it resists the turn further out (the command's sign)
    assert walls[2] == pytest.approx(sized.wall_stiffness * 0.05 / scaling.force_scale)


def test_the_schedule_is_linear_between_its_speeds_and_held_beyond():
    table = ((0.0, 0.1), (10.0, 0.3), (30.0, 0.2))
    assert ps.scheduled(table, -1.0) == 0.1
    assert ps.scheduled(table, 5.0) == pytest.approx(0.2)
    assert ps.scheduled(table, 10.0) == pytest.approx(0.3)
    assert ps.scheduled(table, 20.0) == pytest.approx(0.25)
    assert ps.scheduled(table, 99.0) == 0.2


def test_the_scheduled_damping_follows_the_models_speed():
    """With telemetry the speed moves: the damping rendered is the schedule's at each speed."""
    info, _sizing, scaling, sized = sized_for("wheel", speeds=(0.0, 20.0, 30.0))
    renderer = PhysicalSteeringRenderer(CAR, 0.0, scaling, 1000.0, sized, info)
    ticks = iter(range(10_000))
    for speed in (0.0, 25.0, 30.0):
        renderer.speed = speed
        for _ in range(100):  # a steady turn of the rim: its velocity through the filter
            k = next(ticks)
            _, row = renderer.tick(DeviceSample(k * 1e-3, (0.01 * k * 1e-3,), None), 1e-3)
        added = named(renderer, row)["rendering_damping_Nm"]
        expected = ps.scheduled(sized.schedule, speed) * 0.01 / scaling.force_scale
        assert added == pytest.approx(expected, rel=1e-6)  # the filter has settled
        assert (speed == 0.0) or added > 0.0


def test_the_models_rim_keeps_what_the_device_does_not_have():
    """The user holds the device's rim: the model's rim keeps the car's inertia less the
    device's (in model units), at least a fifth of the car's, and at least what the 1 ms step
    needs for the stiffest coupling the device holds (w*h and c*h/J at most 0.5)."""
    info, sizing, scaling = device("dd-wheel", 0.004)  # 0.05 kg m^2 at 1.35 Nm per model Nm
    rim = CAR.system.hand_wheel_inertia_kg_m2
    assert ps.rendered_params(CAR, info, scaling, sizing).system.hand_wheel_inertia_kg_m2 == (
        pytest.approx(ps.MIN_RIM_SHARE * rim)
    )
    light = dataclasses.replace(info, mass=0.01)
    kept = ps.rendered_params(CAR, light, scaling, sizing).system.hand_wheel_inertia_kg_m2
    assert kept == pytest.approx(rim - 0.01 / 1.35)
    fast = device("dd-wheel", 0.0)  # 686 Nm/rad and 4.1 Nm*s/rad at the device
    model = ps.rendered_params(CAR, fast[0], fast[2], fast[1]).system
    k = (
        model.torsion_bar_stiffness_Nm_rad
        + model.friction_stiffness_Nm_rad
        + fast[1].stiffness / 1.35
    )
    c = model.compensation_damping_Nm_s_rad + fast[1].damping / 1.35
    j = model.hand_wheel_inertia_kg_m2
    assert j > ps.MIN_RIM_SHARE * rim
    assert max(math.sqrt(k / j) * 1e-3, c * 1e-3 / j) == pytest.approx(0.5)


def test_the_assist_is_linearized_where_its_gain_is_largest():
    """The boost grows as (T - deadband)^2 up to the motor's limit: its slope is largest just
    below the limit, which is where the sizing linearizes it (or at the device's torque)."""
    assert CAR.system.active_return_Nm_rad > 0.0  # on centre it gives nothing: not in the boost
    s = CAR.system
    for speed in (0.0, 5.0, 30.0):
        top = ps.assist_peak_torque(CAR, speed, 100.0)
        assert top > s.assist_deadband_Nm

        def boost(torque: float, speed: float = speed) -> float:
            """The model's own boost with the torsion bar twisted to `torque` (the rack on
            centre: no active return)."""
            state = ps.operating_state(CAR, torque)
            inputs = PhysicalInputs(speed, 0.0, 0.0, 0.0, 0.0)
            return -physical.step(state, inputs, CAR, 1e-3)[1].torque_assist_Nm

        slope = (boost(top + 1e-4) - boost(top - 1e-4)) / 2e-4
        assert slope > (boost(top - 0.5) - boost(top - 0.5 - 2e-4)) / 2e-4
        assert boost(top) < s.max_assist_Nm
        assert ps.assist_peak_torque(CAR, speed, 2.0) == 2.0
    assert ps.assist_peak_torque(CAR, 0.0, 0.5) == 0.0  # below the deadband: nothing to find


def test_a_stiffer_device_gets_a_stiffer_coupling_and_every_goal_is_met():
    """Less delay, stiffer coupling; and what the sizing reports holds: the least damping
    ratio at each speed is at least its goal, never below the floor."""
    stiff = []
    for delay in (0.0, 0.002, 0.004):
        info, sizing, scaling = device("dd-wheel", delay)
        sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, (0.0, SPEED))
        assert isinstance(sized, PhysicalSizing)
        assert all(z >= g - 1e-9 for z, g in zip(sized.zeta, sized.goal, strict=True))
        assert min(sized.goal) >= ps.ZETA_FLOOR
        stiff.append(sized.coupling_stiffness)
    assert stiff[0] > stiff[1] > stiff[2]


def test_where_no_coupling_is_damped_the_reason_is_given():
    """A device that cannot even hold the model still (no damping room at all under its cap:
    here a cap of zero) gets no sizing but the reason, naming the speed."""
    info, sizing, scaling = device("dd-wheel", 0.004)
    # A budget whose coupling damper takes the whole cap and a cap too small for anything.
    starved = dataclasses.replace(sizing, damping=0.0, damping_cap=0.0,
                                  stiffness=5 * sizing.stiffness)  # fmt: skip
    found = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, starved, 1, (0.0,))
    assert isinstance(found, str) and "not damped at 0 km/h" in found


def test_the_sliding_model_has_no_friction_springs():
    sliding = ps._sliding(CAR)
    assert sliding.system.column_friction_Nm == sliding.system.rack_friction_Nm == 0.0
    assert sliding.park_moment_Nm == 0.0
    assert sliding.system.torsion_bar_stiffness_Nm_rad == CAR.system.torsion_bar_stiffness_Nm_rad


def test_the_felt_share_is_the_coupling_in_series_with_the_car():
    _, _, scaling, sized = sized_for()
    k = sized.coupling_stiffness / scaling.force_scale
    car = ps.car_stiffness(CAR, SPEED)
    assert 10.0 < car < 30.0  # Nm/rad at the rim on centre at 100 km/h (DESIGN: 17.5)
    assert ps.felt_share(CAR, sized, scaling, SPEED) == pytest.approx(k / (k + car))


def test_only_poles_the_clamped_rim_shares_are_left_out():
    """`least_rim_damping` leaves a pole out only within 5 % of one of the clamped model's:
    nothing clamped, it is the plain least damping ratio; a lightly damped pole clamped is
    left out, the same pole 10 % away is not."""
    a, _ = ps.linearize(CAR, SPEED, ps.operating_state(CAR, 0.0), 1e-3)
    assert ps.least_rim_damping(a, 1000.0, np.array([])) == pytest.approx(
        least_damping_ratio(a, 1000.0)
    )

    def pole(zeta: float, hz: float) -> complex:
        w = 2 * math.pi * hz
        return complex(-zeta * w, w * math.sqrt(1 - zeta * zeta))

    light, firm = pole(0.02, 3.6), pole(0.5, 10.0)
    zs = [np.exp(s * 1e-3) for s in (light, firm)]
    matrix = np.zeros((4, 4))
    for i, z in enumerate(zs):  # real 2x2 blocks with the poles z and its conjugate
        matrix[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = [[z.real, -z.imag], [z.imag, z.real]]
    assert ps.least_rim_damping(matrix, 1000.0, np.array([])) == pytest.approx(0.02, abs=1e-6)
    assert ps.least_rim_damping(matrix, 1000.0, np.array([light, light.conjugate()])) == (
        pytest.approx(0.5, abs=1e-6)
    )
    assert ps.least_rim_damping(matrix, 1000.0, np.array([1.1 * light])) == pytest.approx(
        0.02, abs=1e-6
    )
