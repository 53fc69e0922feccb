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


@pytest.fixture(autouse=True)
def _fresh_sizing():
    """Each test sizes afresh: a sizing cached by an earlier test would hide what this one
    exercises (mutation testing found every mutant of the sizing surviving through the cache)."""
    ps.size_physical.cache_clear()
    yield
    ps.size_physical.cache_clear()


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


@pytest.mark.parametrize(("substeps", "position_scale"), [(1, 1.0), (2, 1.0), (1, 0.8)])
def test_the_loop_the_sizing_analyses_is_the_loop_the_renderer_runs(substeps, position_scale):
    """Small motions of the device (a tenth of a milliradian: the frictions stay stuck, the
    tyres linear): the renderer's commands are the sizing's linear environment's, fed the same
    readings and velocities, within 0.1 % (what is left is the model's nonlinearity at that
    amplitude). A change to either side (coupling, damping, sub-steps, scales) breaks this."""
    info, sizing, scaling = device()
    scaling = Scaling(scaling.force_scale, position_scale)  # the wheels use 1; the code any
    sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, sizing, substeps, (SPEED,))
    assert isinstance(sized, PhysicalSizing)
    renderer = PhysicalSteeringRenderer(CAR, SPEED, scaling, 1000.0, sized, info)
    if substeps != 1:  # one model step a tick unless told
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
    assert renderer.effect == 0.0  # it adds no vibration on purpose (the guard hears it all)


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
    travel (a spring, and a damper against going further out); none on the dd-wheel (900 deg:
    the car's own lock, through the coupling, is within it). The command carries it."""
    info, _, scaling, sized = sized_for("wheel")
    assert sized.wall_stiffness > 0.0 and sized.wall_damping > 0.0
    dd = sized_for("dd-wheel")[3]
    assert dd.wall_stiffness == dd.wall_damping == 0.0
    fs = scaling.force_scale
    soft = dataclasses.replace(sized, wall_stiffness=0.5, wall_damping=0.01)  # any wall counts
    for wall in (sized, soft):
        rows = []
        for depth, rate in ((-0.01, 0.0), (0.02, 0.0), (0.05, 0.0), (0.05, 0.3), (0.05, -0.3)):
            renderer = PhysicalSteeringRenderer(CAR, SPEED, scaling, 1000.0, wall, info)
            for k in range(300):  # the rim turning at `rate` (through the velocity filter)
                angle = 0.95 * info.travel + depth + rate * (k - 299) * 1e-3
                commands, row = renderer.tick(DeviceSample(k * 1e-3, (angle,), None), 1e-3)
            named_row = named(renderer, row)
            total = named_row["torque_Nm"] + named_row["rendering_damping_Nm"]
            assert commands[0] == pytest.approx(-(total + named_row["rendering_wall_Nm"]) * fs)
            rows.append(named_row["rendering_wall_Nm"])
        assert rows[0] == 0.0
        assert rows[2] > rows[1] > 0.0  # it resists the turn further out
        assert rows[2] == pytest.approx(wall.wall_stiffness * 0.05 / fs)
        outward = wall.wall_stiffness * 0.05 + wall.wall_damping * 0.3
        assert rows[3] == pytest.approx(outward / fs, rel=1e-4)  # outward: damped
        assert rows[4] == pytest.approx(rows[2])  # coming back in: the spring only


def test_a_wall_in_the_sizings_environment_is_a_spring_and_damper_to_the_centre():
    import numpy as np

    n = len(ps.KEPT)
    environment = ps.coupled_environment(np.zeros((n, n)), np.zeros(n), 0.0, 0.0, 1.35, 1.0,
                                         0.0, 1, (3.0, 0.5))  # fmt: skip
    assert environment(None, 0.2, -0.4)[1] == pytest.approx(-3.0 * 0.2 - 0.5 * -0.4)


def test_the_schedule_is_linear_between_its_speeds_and_held_beyond():
    table = ((0.0, 0.1), (10.0, 0.3), (30.0, 0.2))
    assert ps.scheduled(table, -1.0) == 0.1
    assert ps.scheduled(table, 0.05) == pytest.approx(0.101)
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
    # Its rim's dampers (torsion bar's, the column friction's while it sticks, the coupling's)
    # need more than the floor: the damper rule binds, c*h/J = 0.5.
    s = CAR.system
    c = s.compensation_damping_Nm_s_rad + s.presliding_damping_Nm_s_rad + sizing.damping / 1.35
    assert c * 1e-3 / 0.5 > ps.MIN_RIM_SHARE * rim
    assert ps.rendered_params(CAR, info, scaling, sizing).system.hand_wheel_inertia_kg_m2 == (
        pytest.approx(c * 1e-3 / 0.5)
    )
    # Without the column's damper, the floor binds.
    bare = dataclasses.replace(CAR, system=dataclasses.replace(s, presliding_damping_Nm_s_rad=0.0))
    assert ps.rendered_params(bare, info, scaling, sizing).system.hand_wheel_inertia_kg_m2 == (
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
    c = (
        model.compensation_damping_Nm_s_rad
        + model.presliding_damping_Nm_s_rad
        + fast[1].damping / 1.35
    )
    j = model.hand_wheel_inertia_kg_m2
    assert j > ps.MIN_RIM_SHARE * rim
    assert max(math.sqrt(k / j) * 1e-3, c * 1e-3 / j) == pytest.approx(0.5)
    stiff = dataclasses.replace(fast[1], stiffness=4000.0, damping=0.0)  # the spring binds
    j = ps.rendered_params(CAR, fast[0], fast[2], stiff).system.hand_wheel_inertia_kg_m2
    k = CAR.system.torsion_bar_stiffness_Nm_rad + CAR.system.friction_stiffness_Nm_rad + 4000 / 1.35
    assert math.sqrt(k / j) * 1e-3 == pytest.approx(0.5)
    # The fast device with an angle scale of 2 (device rad per model rad): its coupling's
    # damper is twice as stiff in model units, and so is the rim it needs.
    wide = ps.rendered_params(CAR, fast[0], Scaling(1.35, 2.0), fast[1]).system
    c = (
        wide.compensation_damping_Nm_s_rad
        + wide.presliding_damping_Nm_s_rad
        + fast[1].damping * 2.0 / 1.35
    )
    assert c * 1e-3 / wide.hand_wheel_inertia_kg_m2 == pytest.approx(0.5)
    k = wide.torsion_bar_stiffness_Nm_rad + wide.friction_stiffness_Nm_rad + 4000 * 2.0 / 1.35
    spring = ps.rendered_params(CAR, fast[0], Scaling(1.35, 2.0), stiff).system
    assert math.sqrt(k / spring.hand_wheel_inertia_kg_m2) * 1e-3 == pytest.approx(0.5)
    # Sized with two model steps a tick, the rule is the half step's: the floor again.
    info0, sizing0, scaling0 = fast
    halved = ps.size_physical(info0, 1000.0, SECTIONS, CAR, scaling0, sizing0, 2, (SPEED,))
    assert isinstance(halved, PhysicalSizing)
    assert halved.rim_inertia_kg_m2 == pytest.approx(ps.MIN_RIM_SHARE * rim)
    # In model units the device's inertia is m * ps^2 / fs (an angle scale of 2 quadruples it).
    scaled = ps.rendered_params(CAR, light, Scaling(1.35, 0.5), sizing)
    assert scaled.system.hand_wheel_inertia_kg_m2 == pytest.approx(rim - 0.01 * 0.25 / 1.35)


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
        assert 0.9 * s.max_assist_Nm < boost(top) < s.max_assist_Nm  # just below the limit
        assert ps.assist_peak_torque(CAR, speed, 2.0) == 2.0
    assert ps.assist_peak_torque(CAR, 0.0, 0.5) == 0.0  # below the deadband: nothing to find
    manual = dataclasses.replace(CAR, system=dataclasses.replace(
        s, assist_gain_standstill_1_Nm=0.0, assist_gain_high_speed_1_Nm=0.0))  # fmt: skip
    assert ps.assist_peak_torque(manual, 0.0, 10.0) == 0.0  # no assist, nothing to linearize


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
    found = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, starved, 1, (20.0,))
    assert isinstance(found, str) and "not damped at 72 km/h" in found
    assert f"a coupling of {5 * sizing.stiffness:.3g} Nm/rad" in found  # the stiffest tried


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
    wide = Scaling(scaling.force_scale, 2.0)  # device rad per model rad: the coupling is stiffer
    assert ps.felt_share(CAR, sized, wide, SPEED) == pytest.approx(2 * k / (2 * k + car))
    centreless = dataclasses.replace(CAR, system=dataclasses.replace(
        CAR.system, kingpin_offset_m=0.0, active_return_Nm_rad=0.0))  # fmt: skip
    assert ps.car_stiffness(centreless, 0.0) == 0.0  # parked, nothing returns the rim


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
    near = np.array([1.02 * light, 1.02 * light.conjugate()])  # within 5 %: the same mode
    assert ps.least_rim_damping(matrix, 1000.0, near) == pytest.approx(0.5, abs=1e-6)
    # A growing loop pole is never mistaken for its mirror image among the clamped ones.
    grow = -light
    matrix[0:2, 0:2] = [[np.exp(grow * 1e-3).real, -np.exp(grow * 1e-3).imag],
                        [np.exp(grow * 1e-3).imag, np.exp(grow * 1e-3).real]]  # fmt: skip
    assert ps.least_rim_damping(matrix, 1000.0, np.array([light, light.conjugate()])) < 0.0
    # Slow modes count (a 0.1 Hz one lightly damped), the free rest (z = 1) and pure delays
    # (z = 0) do not, whatever their order; with nothing else the loop is damped (1).
    slow = np.exp(pole(0.02, 0.1) * 1e-3)
    blocks = np.zeros((4, 4))
    blocks[0, 0] = 1.0
    blocks[2:4, 2:4] = [[slow.real, -slow.imag], [slow.imag, slow.real]]
    assert ps.least_rim_damping(blocks, 1000.0, np.array([])) == pytest.approx(0.02, abs=1e-4)
    assert ps.least_rim_damping(np.diag([1.0, 0.0]), 1000.0, np.array([])) == 1.0
    # The free rest met first does not end the search: a growing real pole after it counts.
    assert ps.least_rim_damping(np.diag([1.0, 1.5]), 1000.0, np.array([])) == pytest.approx(-1.0)


def test_the_clamped_rim_leaves_out_only_the_cars_own_modes():
    """At walking pace the car has a lightly damped lateral mode of its own (its tyres' lag:
    3.6 Hz, zeta under 0.05) that the rim hardly takes part in: the rim-clamped model has it
    too, as damped, so it is left out of the rendering's goal (here, the frictions sliding and
    the assist at its steepest, what is left is 0.12). On centre a 2.8 Hz mode is as lightly
    damped but the rim takes part in it (held still, the rim leaves it at zeta 0.09): counted."""
    sliding = ps._sliding(CAR)
    torque = ps.assist_peak_torque(sliding, 1.0, 11.0)
    a, _ = ps.linearize(sliding, 1.0, ps.operating_state(sliding, torque), 1e-3)
    clamped = ps.clamped_modes(a, 1000.0)
    assert least_damping_ratio(a, 1000.0) < 0.05
    assert ps.least_rim_damping(a, 1000.0, clamped) > 0.1
    assert any(abs(abs(s) / (2 * math.pi) - 3.6) < 0.3 for s in clamped)
    assert all(s.real < 0.0 for s in clamped)  # poles in s, stable: the log of z over the tick
    assert len(clamped) <= a.shape[0] - 2  # the rim's angle and rate are held
    centre, _ = ps.linearize(sliding, 1.0, ps.operating_state(sliding, 0.0), 1e-3)
    on_centre = ps.least_rim_damping(centre, 1000.0, ps.clamped_modes(centre, 1000.0))
    assert on_centre == pytest.approx(least_damping_ratio(centre, 1000.0)) and on_centre < 0.05


def test_the_operating_point_holds_the_twist_with_the_frictions_relaxed():
    """The hand holding the torsion bar's torque at the operating point: nothing moves in the
    first step (the column's stick element relaxed at its anchor, not pulling the rim)."""
    state = ps.operating_state(CAR, 3.0)
    _, out = physical.step(state, PhysicalInputs(0.0, 0.0, 0.0, 3.0, 0.0), CAR, 1e-3)
    assert out.steering_rate_rad_s == pytest.approx(0.0, abs=1e-9)
    assert out.torsion_bar_torque_Nm == pytest.approx(3.0)


def test_a_short_loop_with_the_physical_renderer():
    """The renderer in the loop (simulated time, the dd-wheel untouched): no fault, no gears,
    no vibration effect; the command is the rendering's."""
    from carfeel.realtime.clock import SimulatedClock
    from carfeel.realtime.loop import LoopConfig, run_loop
    from carfeel.realtime.safety import SafetyLimits

    dd = virtual_device("dd-wheel", delay_s=0.004)
    info, sizing, scaling = dd.info, size(dd.info, 1000.0, SECTIONS), Scaling(1.35, 1.0)
    sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, (SPEED,))
    assert isinstance(sized, PhysicalSizing)
    renderer = PhysicalSteeringRenderer(CAR, SPEED, scaling, 1000.0, sized, info)
    dd._x[0] = 0.2
    with dd:
        summary = run_loop(renderer, dd, SimulatedClock(), LoopConfig(1000.0, 0.5),
                           SafetyLimits(15.0, 3000.0))  # fmt: skip
    assert summary.faults == [] and summary.gears == []
    assert renderer.effect == 0.0
    assert summary.peak_command > 0.1  # the rim off centre: the model pulls it back


def test_with_sub_steps_the_terms_are_the_mean_over_the_tick_and_sum_to_the_torque():
    """Two model steps a tick: each recorded term is the mean of the two steps' (they still
    sum to the torque rendered, the mean coupling torque), with the rim moving so that the two
    steps differ."""
    info, _, scaling, sized = sized_for(substeps=2)
    renderer = PhysicalSteeringRenderer(CAR, SPEED, scaling, 1000.0, sized, info)
    renderer.substeps = 2
    torques = set()
    for k in range(200):
        angle = 0.2 * math.sin(2 * math.pi * 1.5 * k * 1e-3)
        commands, row = renderer.tick(DeviceSample(k * 1e-3, (angle,), None), 1e-3)
        r = named(renderer, row)
        terms = [r[name] for name in ps.TERMS]
        assert sum(terms) == pytest.approx(r["torque_Nm"], abs=1e-12 + 1e-12 * sum(map(abs, terms)))
        assert commands[0] == pytest.approx(
            -(r["torque_Nm"] + r["rendering_damping_Nm"] + r["rendering_wall_Nm"]) * 1.35
        )
        torques.add(round(r["torque_Nm"], 6))
    assert len(torques) > 100


@pytest.mark.parametrize("position_scale", [1.0, 0.8])
def test_the_sizing_reports_the_loop_the_renderer_runs(position_scale):
    """What the sizing reports (its least damping ratio, per speed) is the loop built from the
    renderer's own gains (coupling, damping schedule) on the sizing's linearizations, and every
    goal it had to meet is no more than the car's own damping there (or the floor)."""
    from carfeel.realtime import stability

    info, sizing, scaling = device()
    scaling = Scaling(scaling.force_scale, position_scale)
    speeds = (0.0, SPEED)
    sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, speeds)
    assert isinstance(sized, PhysicalSizing) and sized.share in ps.COUPLING_SHARES
    renderer = PhysicalSteeringRenderer(CAR, SPEED, scaling, 1000.0, sized, info)
    sizer = ps._Sizer(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, speeds)
    axis = stability.AxisLoop.of(info, 1000.0, SECTIONS)
    for (_, added), zeta, cases in zip(sized.schedule, sized.zeta, sizer.cases, strict=True):
        found = []
        for case in cases:
            env = ps.coupled_environment(case.a, case.b, renderer.stiffness, renderer.damping,
                                         scaling.force_scale, position_scale, added, 1)  # fmt: skip
            matrix = stability.closed_loop(axis, env, len(ps.KEPT))
            found.append(ps.least_rim_damping(matrix, 1000.0, case.clamped))
            assert case.goal <= max(ps.ZETA_FLOOR, case.released)
            assert found[-1] >= case.goal - 1e-9
        assert min(found) == pytest.approx(zeta)


def test_the_assist_is_linearized_up_to_the_devices_torque():
    """At speed the assist saturates far out (16 Nm of bar torque at 100 km/h): the loaded
    linearization sits at the most the device renders, its torque limit in model units; with
    a small deadband it is found below 1 Nm too."""
    info, sizing, scaling = device()
    sizer = ps._Sizer(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, (SPEED,))
    assert max(case.torque for case in sizer.cases[0]) == pytest.approx(
        info.max_force / scaling.force_scale
    )
    light = dataclasses.replace(CAR, system=dataclasses.replace(CAR.system, assist_deadband_Nm=0.2))
    tiny = Scaling(20.0, 1.0)  # 0.75 Nm of model torque at the device's limit
    sizer = ps._Sizer(info, 1000.0, SECTIONS, light, tiny, sizing, 1, (SPEED,))
    assert max(case.torque for case in sizer.cases[0]) == pytest.approx(15.0 / 20.0)


def test_the_scheduled_damping_is_the_least_that_meets_the_goals():
    """None where none is needed (the belt wheel parked on a car whose frictions have no
    damper while they stick: the car released is barely damped there, and so is the goal);
    some on the car as shipped (its released wheel is damped, the goal with it); where some is
    (the dd-wheel at 100 km/h), a little less misses a goal (the bisection's resolution, a
    512th of the room)."""
    info, sizing, scaling = device("wheel")
    bare = dataclasses.replace(
        CAR, system=dataclasses.replace(CAR.system, presliding_damping_Nm_s_rad=0.0)
    )
    parked = ps.size_physical(info, 1000.0, SECTIONS, bare, scaling, sizing, 1, (0.0,))
    assert isinstance(parked, PhysicalSizing)
    assert parked.schedule[0][1] == 0.0
    wheel = sized_for("wheel", speeds=(0.0,))[3]
    assert wheel.schedule[0][1] > 0.0 and min(wheel.goal) > parked.goal[0]
    info, sizing, scaling = device()
    sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, (SPEED,))
    assert isinstance(sized, PhysicalSizing)
    added = sized.schedule[0][1]
    room = sizing.damping_cap - sized.share * sizing.damping
    assert 0.0 < added <= room
    sizer = ps._Sizer(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, (SPEED,))
    assert sizer.least(sized.share, sizer.cases[0], added)[0] >= 0.0
    assert sizer.least(sized.share, sizer.cases[0], added - room / 400)[0] < 0.0


def test_with_telemetry_the_belt_wheel_renders_up_to_the_speed_its_cap_allows():
    """Sized for every speed (telemetry), the belt wheel at 4 ms renders up to 252 km/h with its
    whole spring budget: the car's EPS damping, rising with the square of the speed, damps the
    released wheel's weave there, and the scheduled damping stays within the cap (the noise caps
    it at 0.65 Nm*s/rad); its wall is sized over the speeds it reaches. With the damping the
    presets had before (2.4 Nm*s/rad, constant at speed) only a quarter of the budget got there,
    with nearly all of the cap."""
    info, sizing, scaling = device("wheel")
    sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, ps.SPEEDS_M_S)
    assert isinstance(sized, PhysicalSizing)
    assert sized.top_speed_m_s == pytest.approx(ps.SPEEDS_M_S[-1])
    assert sized.share == 1.0
    room = sizing.damping_cap - sized.coupling_damping
    assert all(0.0 <= b <= room + 1e-12 for _, b in sized.schedule)
    assert sized.wall_stiffness > 0.0
    flat = dataclasses.replace(
        CAR.system, eps_damping_high_speed_Nm_s_rad=2.4, eps_damping_rise_Nm_s3_rad_m2=0.0
    )
    old = ps.size_physical(
        info, 1000.0, SECTIONS, dataclasses.replace(CAR, system=flat), scaling, sizing, 1,
        ps.SPEEDS_M_S,
    )  # fmt: skip
    assert isinstance(old, PhysicalSizing)
    assert old.share < 1.0
    assert old.schedule[-1][1] > 0.9 * (sizing.damping_cap - old.coupling_damping)


def test_a_wall_too_stiff_for_the_device_is_halved_until_it_holds():
    """The wall starts at the device's budget; given one five times too stiff it halves it
    until the loop pressed into it keeps the floor (and not further); given one no halving
    rescues, none."""
    info, sizing, scaling = device("wheel")
    sizer = ps._Sizer(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, (SPEED,))
    sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, sizing, 1, (SPEED,))
    assert isinstance(sized, PhysicalSizing)
    schedule = list(sized.schedule)
    share = sized.share
    sizer.sizing = dataclasses.replace(sizing, stiffness=5 * sizing.stiffness,
                                       damping=5 * sizing.damping)  # fmt: skip
    stiffness, damping = sizer.wall(share, schedule)
    assert 0.0 < stiffness < 5 * sizing.stiffness
    assert damping / stiffness == pytest.approx(sizing.damping / sizing.stiffness)
    held = sizer.least(share, sizer.cases[0], schedule[0][1], (stiffness, damping))[1]
    twice = sizer.least(share, sizer.cases[0], schedule[0][1], (2 * stiffness, 2 * damping))[1]
    assert held >= ps.ZETA_FLOOR > twice
    sizer.sizing = dataclasses.replace(sizing, stiffness=1e6 * sizing.stiffness,
                                       damping=1e6 * sizing.damping)  # fmt: skip
    assert sizer.wall(share, schedule) == (0.0, 0.0)


def test_the_scheduled_damping_never_exceeds_the_cap_even_where_a_little_more_would_do():
    """The dd-wheel at 4 ms needs 0.130 Nm*s/rad at 100 km/h beside its full-budget coupling;
    with a cap that leaves 0.12 for it, that coupling is not offered (a softer one is), rather
    than damping beyond the cap."""
    info, sizing, scaling = device()
    tight = dataclasses.replace(sizing, damping_cap=sizing.damping + 0.12)
    sized = ps.size_physical(info, 1000.0, SECTIONS, CAR, scaling, tight, 1, (SPEED,))
    assert isinstance(sized, PhysicalSizing)
    assert sized.schedule[0][1] <= tight.damping_cap - sized.coupling_damping + 1e-12
    assert sized.share < 1.0
