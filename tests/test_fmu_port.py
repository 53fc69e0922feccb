"""The C ports of the FMUs against the Python models: the same recorded inputs, equal outputs
bit for bit (the same IEEE operations in the same order, libm for the functions, no FMA).

Every comparison is of the bytes of the doubles, so -0.0 against 0.0 or one ulp would fail it.
The C library is compiled with the FMUs' own flags (`carfeel.export.fmu.CFLAGS`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from typing import Any

import numpy as np
import pytest

from carfeel.export import fmu, port
from carfeel.io.presets import load_shift, load_steering
from carfeel.models import rng
from carfeel.models.drivers import shift as driver
from carfeel.models.gearshift import engagement as eng
from carfeel.models.gearshift.engagement import EngagementInputs, Stage
from carfeel.models.vehicle import single_track
from carfeel.simulation import manoeuvres
from carfeel.simulation.result import Result
from carfeel.simulation.steering import simulate_steering
from tests.fmu_marks import GCC_BUILD

# The C ports compiled with gcc's flags into a .so, as the FMU's gcc build does on Linux x86-64:
# elsewhere the FMU takes FMPy's CMake build, which these tests do not check.
pytestmark = GCC_BUILD


@pytest.fixture(scope="module")
def c_port(tmp_path_factory: pytest.TempPathFactory) -> port.Port:
    return port.Port(fmu.build_port_library(tmp_path_factory.mktemp("port")))


def _bits(values: object) -> bytes:
    return np.ascontiguousarray(values, dtype="<f8").tobytes()


def _python_records(states: list[eng.EngagementState]) -> np.ndarray:
    return np.concatenate([port.engagement_state(s) for s in states])


def assert_same_engagement(python_states, python_outputs, c_states, c_outputs) -> None:
    """Every state field and output of every step, bit for bit; the first mismatch named."""
    expected = _python_records(python_states)
    for name in port.ENGAGEMENT_STATE.names or ():
        same = expected[name].tobytes() == c_states[name].tobytes()
        if not same:
            k = int(np.flatnonzero(expected[name] != c_states[name])[0])
            raise AssertionError(
                f"state.{name} differs first at step {k}: Python {expected[name][k]!r}, "
                f"C {c_states[name][k]!r} (stage {python_states[k].stage.value})"
            )
    for name in ("position_m", "velocity_m_s", "force_N", "reaction_N"):
        py = [getattr(o, name) for o in python_outputs]
        assert _bits(py) == c_outputs[name].tobytes(), f"output {name} differs"
    stages = [port.STAGES.index(Stage(o.stage)) for o in python_outputs]
    assert stages == c_outputs["stage"].tolist()


def test_c_structs_have_the_dataclasses_fields_in_order():
    # The parameters cross into C as flat arrays of doubles: the order must be the dataclass's.
    headers = "".join(
        (fmu.c_source_dir() / f"{stem}.h").read_text()
        for stem in ("cf_engagement", "cf_steering", "cf_physical")
    )
    for struct, cls in fmu.C_STRUCTS.items():
        body = re.search(r"typedef struct \{([^{}]*)\} " + struct + ";", headers)
        assert body is not None, struct
        members = re.findall(r"(\w+) (\w+);", body.group(1))
        assert all(t in ("double",) or t.startswith("cf_") for t, _ in members), struct
        assert [name for _, name in members] == [f.name for f in dataclasses.fields(cls)], struct


@pytest.mark.parametrize("seed", [0, 1, 7, 2**31 - 1, -1, -(2**63), 2**64 - 1, 2**70 + 5])
def test_splitmix64_draws_match(c_port, seed):
    # Python's ints are unbounded and masked to 64 bits; C's uint64_t wraps the same way.
    python_state = rng.seed_state(seed)
    c_state = python_state
    for _ in range(1000):
        python_state, u = rng.next_uniform(python_state)
        c_state, c_u = c_port.next_uniform(c_state)
        assert c_state == python_state
        assert _bits([c_u]) == _bits([u])


def _closed_loop(params, seed: int, steps: int, dt: float):
    """The carfeel shift loop (eq. (10) driver through a hand, the engagement): the knob forces
    it recorded, and the lever's states and outputs."""
    ds, es = driver.initial_state(), eng.initial_state(seed)
    inputs, states, outputs = [], [], []
    for _ in range(steps):
        ds, dout = driver.step(
            ds, driver.DriverInputs(es.position_m, es.velocity_m_s), params.driver, dt
        )
        u = EngagementInputs(dout.force_N)
        es, out = eng.step(es, u, params.gearbox, dt)
        inputs.append(u)
        states.append(es)
        outputs.append(out)
    return inputs, states, outputs


def _variants():
    base = load_shift("paper-first-gear").params
    pull = dataclasses.replace(base, driver=dataclasses.replace(base.driver, pull_out=True))
    g = pull.gearbox
    cable = dataclasses.replace(g, linkage_stiffness_N_m=50_000.0, linkage_damping_N_s_m=20.0)
    always_chamfer = dataclasses.replace(
        g, chamfer=dataclasses.replace(g.chamfer, no_contact_fraction=0.0, travel_m=0.006)
    )
    heavy_gear = dataclasses.replace(
        g,
        chamfer=dataclasses.replace(g.chamfer, gear_inertia_kg_m2=0.6),
        tooth_force_spread_N=12.0,
    )
    return {
        "paper-first-gear": pull,
        "cable-linkage": dataclasses.replace(pull, gearbox=cable),
        "chamfers-always-meet": dataclasses.replace(pull, gearbox=always_chamfer),
        "heavy-gear": dataclasses.replace(pull, gearbox=heavy_gear),
        # Issue 30: the fixed synchronizer's time falling with the push, no gate's end.
        "timer-by-force": dataclasses.replace(
            pull,
            gearbox=dataclasses.replace(g, synchronization_force_N=60.0, stop_travel_m=0.0),
        ),
    }


@pytest.mark.parametrize("variant", list(_variants()))
@pytest.mark.parametrize("seed", [0, 3, 11])
def test_full_shift_with_pull_out_is_bit_for_bit(c_port, variant, seed):
    params = _variants()[variant]
    dt = 1e-3
    inputs, states, outputs = _closed_loop(params, seed, 2500, dt)
    visited = {s.stage for s in states}
    # The hard case: the whole shift, into gear and back out to neutral.
    assert {Stage.SYNCHRONIZATION, Stage.ENGAGEMENT, Stage.STOP, Stage.IN_GEAR} <= visited
    assert Stage.RETURNING in visited and states[-1].stage is Stage.NEUTRAL
    c_states, c_outputs = c_port.engagement_run(
        params.gearbox, eng.initial_state(seed), port.engagement_inputs(inputs), dt
    )
    assert_same_engagement(states, outputs, c_states, c_outputs)


def test_shift_at_a_fine_step_is_bit_for_bit(c_port):
    params = _variants()["paper-first-gear"]
    inputs, states, outputs = _closed_loop(params, 5, 20_000, 1e-4)
    c_states, c_outputs = c_port.engagement_run(
        params.gearbox, eng.initial_state(5), port.engagement_inputs(inputs), 1e-4
    )
    assert_same_engagement(states, outputs, c_states, c_outputs)


def _rough_inputs(seed: int, steps: int) -> list[EngagementInputs]:
    """Pushes and pulls of random size and length, with walls, a latch's friction, an outside
    synchronizer and the H-pattern's gear loads switching on and off: every branch of the step."""
    r = np.random.default_rng(seed)
    inputs = []
    force = 0.0
    gate: bool | None = None
    wall = (0.0, 0.0, 0.0)
    extra = 0.0
    load: tuple[float | None, float | None] = (None, None)
    for k in range(steps):
        if k % int(r.integers(40, 400)) == 0:
            force = float(r.choice([-60.0, -20.0, -6.0, 0.0, 3.0, 30.0, 90.0]) + r.normal(0, 4))
        if r.random() < 0.004:
            gate = [None, None, True, False][int(r.integers(4))]
        if r.random() < 0.003:
            wall = (
                (0.0, 0.0, 0.0)
                if r.random() < 0.5
                else (
                    float(r.uniform(1e3, 2e4)),
                    float(r.uniform(0, 30)),
                    float(r.normal(0.01, 0.01)),
                )
            )
        if r.random() < 0.003:
            extra = float(r.choice([0.0, 2.0, 8.0]))
        if r.random() < 0.002:
            load = (
                (None, None)
                if r.random() < 0.5
                else (float(r.uniform(0, 1)), float(r.uniform(0, 3)))
            )
        inputs.append(EngagementInputs(force + float(r.normal(0, 1.5)), *wall, gate, extra, *load))
    return inputs


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_rough_inputs_through_every_branch_are_bit_for_bit(c_port, seed):
    params = _variants()["cable-linkage"].gearbox
    if seed == 3:  # the force-scaled timer under rough pushes too (issue 30)
        params = dataclasses.replace(params, synchronization_force_N=60.0)
    inputs = _rough_inputs(seed, 30_000)
    state, states, outputs = eng.initial_state(seed), [], []
    for u in inputs:
        state, out = eng.step(state, u, params, 1e-3)
        states.append(state)
        outputs.append(out)
    assert {s.stage for s in states} == set(Stage)  # all eight stages, back and forth
    assert any(s.reversal_s > 0.0 for s in states)  # a pull held in the teeth
    c_states, c_outputs = c_port.engagement_run(
        params, eng.initial_state(seed), port.engagement_inputs(inputs), 1e-3
    )
    assert_same_engagement(states, outputs, c_states, c_outputs)


@functools.cache
def _manoeuvre(name: str) -> Result:
    car = load_steering("b-segment").params
    return simulate_steering(car, manoeuvres.build(name, car.vehicle))


STEERING_MANOEUVRES = (
    "iso4138", "iso3888", "iso7401-step", "iso7401-sine", "iso7401-sweep", "steer-cycle", "weave",
)  # fmt: skip


@pytest.mark.parametrize("name", STEERING_MANOEUVRES)
def test_steering_law_over_iso_manoeuvres_is_bit_for_bit(c_port, name):
    run = _manoeuvre(name)
    torque = load_steering("b-segment").params.torque
    terms = c_port.torque_run(
        torque, run["speed_m_s"], run["steering_rate_rad_s"], run["lateral_accel_m_s2"]
    )
    for column, name_ in enumerate(
        ("torque_Nm", "torque_aligning_Nm", "torque_tire_spin_Nm", "torque_friction_Nm",
         "torque_damping_Nm")
    ):  # fmt: skip
        assert terms[:, column].tobytes() == _bits(run[name_]), name_


def test_steering_law_at_edge_values_is_bit_for_bit(c_port):
    # Zero (and -0.0), tiny and large values, and a law whose K3 makes pow() work hard.
    from carfeel.models.steering.torque import torque_terms

    law = dataclasses.replace(load_steering("b-segment").params.torque, k3=1.37, k2=0.05)
    values = [0.0, -0.0, 5e-324, -1e-300, 1e-9, 0.3, -2.5, 9.81, -40.0, 1e6]
    grid = [(v, r, a) for v in (0.0, 1.0, 33.3, -5.0) for r in values for a in values]
    speed, rate, ay = (np.array(c) for c in zip(*grid, strict=True))
    terms = c_port.torque_run(law, speed, rate, ay)
    expected = [torque_terms(float(v), float(r), float(a), law) for v, r, a in grid]
    assert terms.tobytes() == _bits(expected)


@pytest.mark.parametrize("name", ["iso7401-step", "iso7401-sine", "steer-cycle", "weave"])
def test_single_track_car_and_its_front_axle_ay_are_bit_for_bit(c_port, name):
    # Imposed manoeuvres drive the car from the angle; steer-cycle stands still (the kinematic
    # branch), the others run the trapezoidal one.
    vehicle = load_steering("b-segment").params.vehicle
    run = _manoeuvre(name)
    speed, angle = run["speed_m_s"], run["steering_angle_rad"]
    state = single_track.initial_state()
    states, aligning = [], []
    for v, a in zip(speed, angle, strict=True):
        state, _ = single_track.step(
            state, single_track.VehicleInputs(float(v), float(a)), vehicle, 1e-3
        )
        states.append(tuple(state))
        aligning.append(single_track.aligning_lateral_accel(state, float(v), vehicle))
    c_states, c_aligning = c_port.vehicle_run(
        vehicle, single_track.initial_state(), speed, angle, 1e-3
    )
    assert np.ascontiguousarray(c_states).view("<f8").tobytes() == _bits(states)
    assert c_aligning.tobytes() == _bits(aligning)
    # The simulated run's own Ay is that car's (simulate steering, imposed steering).
    assert c_states["lateral_accel_m_s2"].tobytes() == _bits(run["lateral_accel_m_s2"])
    steady = c_port.steady_state_run(vehicle, speed, angle)
    assert steady.tobytes() == _bits(
        [single_track.steady_state_lateral_accel(float(v), float(a), vehicle)
         for v, a in zip(speed, angle, strict=True)]
    )  # fmt: skip


def test_the_port_compiles_without_a_warning(tmp_path):
    # compile_library refuses any compiler output; -Wall -Wextra are on.
    fmu.compile_library(
        fmu.find_compiler(), fmu.c_source_dir(), fmu.PORT_SOURCES, tmp_path / "x.so"
    )
    assert (tmp_path / "x.so").stat().st_size > 0


def test_flat_values_follow_the_parameter_dataclass():
    gearbox = load_shift("paper-first-gear").params.gearbox
    flat = fmu.flat_values(gearbox)
    assert flat[0] == gearbox.synchronization_position_m
    assert flat[10] == gearbox.neutral.mass_kg  # the first nested table starts after 10 numbers
    assert flat[-1] == gearbox.synchronization_force_N
    spec = fmu.shift_spec(load_shift("paper-first-gear"))
    exposed = [v.start for v in spec.variables if v.name.startswith("gearbox.")]
    assert exposed == flat  # every gearbox number is an FMU parameter, in the same order


def _physical_case(name: str) -> tuple[list[Any], float]:
    """Inputs (PhysicalInputs per 1 ms step) of a case, and the start angle."""
    from carfeel.models.steering.physical import PhysicalInputs

    if name == "weave-then-release":  # 4 s of a weave at 100 km/h, then hands off for 4 s
        run = _manoeuvre("weave")
        hold = [
            PhysicalInputs(float(v), float(a), float(r), 0.0, 1.0)
            for v, a, r in zip(
                run["speed_m_s"][:4000], run["steering_angle_rad"][:4000],
                run["steering_rate_rad_s"][:4000], strict=True,
            )
        ]  # fmt: skip
        return hold + [PhysicalInputs(27.78, 0.0, 0.0, 0.0, 0.0)] * 4000, 0.0
    if name == "parking-lock-to-lock":  # the steer cycle at standstill, into the stops
        run = _manoeuvre("steer-cycle")
        return [
            PhysicalInputs(0.0, float(a) * 1.1, float(r) * 1.1, 0.0, 1.0)
            for a, r in zip(run["steering_angle_rad"], run["steering_rate_rad_s"], strict=True)
        ], 0.0
    if name == "ramp-to-the-limit":  # 20 m/s, the rim ramped to 170 deg: the tyres saturate
        return [
            PhysicalInputs(20.0, 3.0 * min(1.0, k / 6000), 0.5 * (k < 6000), 0.0, 1.0)
            for k in range(8000)
        ], 0.0
    # a crawl through the kinematic speed with a hand's torque on a free rim
    return [
        PhysicalInputs(0.002 * k, 0.0, 0.0, 2.0 * math.sin(k / 300), 0.0) for k in range(3000)
    ], 0.4


@pytest.mark.parametrize(
    "name", ["weave-then-release", "parking-lock-to-lock", "ramp-to-the-limit", "crawl-free-rim"]
)
def test_physical_steering_model_is_bit_for_bit(c_port, name):
    from carfeel.models.steering import physical

    car = load_steering("b-segment").params
    params = car.physical()
    inputs, angle = _physical_case(name)
    state = physical.initial_state(params, steering_angle_rad=angle)
    states, outputs = [], []
    for u in inputs:
        state, out = physical.step(state, u, params, 1e-3)
        states.append(tuple(state))
        outputs.append(tuple(out))
    c_states, c_outputs = c_port.physical_run(
        params, physical.initial_state(params, steering_angle_rad=angle), inputs, 1e-3
    )
    for k, field in enumerate(c_states.dtype.names or ()):
        column = [s[k] for s in states]
        assert _bits(column) == c_states[field].tobytes(), f"state.{field}"
    for k, field in enumerate(c_outputs.dtype.names or ()):
        column = [o[k] for o in outputs]
        assert _bits(column) == c_outputs[field].tobytes(), f"output {field}"
    # The case did what it is named for.
    columns = {
        f: np.array([o[k] for o in outputs]) for k, f in enumerate(c_outputs.dtype.names or ())
    }
    if name == "weave-then-release":
        assert np.ptp(columns["steering_angle_rad"][4000:]) > 0.01  # the free rim moved
    elif name == "parking-lock-to-lock":
        assert np.max(np.abs(columns["torque_stop_Nm"])) > 0.0
        assert np.max(columns["torque_park_Nm"]) > 0.0
    elif name == "ramp-to-the-limit":
        assert np.max(columns["front_grip_used"]) == 1.0  # a sliding axle: the brush's x >= 1
    else:
        assert np.ptp(columns["steering_angle_rad"]) > 0.01
