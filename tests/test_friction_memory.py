"""The law's friction with memory (K10, K11: a Dahl element, issue 25): what it does, that it is
off by default (the shipped presets' runs unchanged bit for bit), and its C port and FMU."""

from __future__ import annotations

import dataclasses
import math
import shutil

import numpy as np
import pytest

from carfeel.io.presets import load_steering
from carfeel.models.steering import torque
from carfeel.models.steering.torque import (
    TorqueInputs,
    TorqueState,
    friction_memory_series,
    friction_memory_step,
    torque_terms,
)
from carfeel.simulation import manoeuvres
from carfeel.simulation.steering import simulate_steering

needs_cc = pytest.mark.skipif(
    shutil.which("cc") is None and shutil.which("gcc") is None,
    reason="no C compiler (make test installs gcc)",
)


def with_memory(level=0.6, angle=0.03):
    law = load_steering("b-segment").params.torque
    return dataclasses.replace(law, k10_Nm=level, k11_rad=angle)


def _bits(values: object) -> bytes:
    return np.ascontiguousarray(values, dtype="<f8").tobytes()


def test_the_memory_builds_over_its_angle_after_a_reversal_and_holds_while_the_wheel_is_held():
    law = with_memory(angle=0.03)
    # From full memory one way, turning the other way by K11 rad: 63 % of the way back to the
    # new sign's level, 1 - 2/e; by 5 K11, within 1.4 % of it.
    z = friction_memory_step(-1.0, 0.5, 0.03 / 0.5, law)
    assert z == pytest.approx(1.0 - 2.0 / math.e, rel=1e-12)
    assert friction_memory_step(-1.0, 0.5, 5 * 0.03 / 0.5, law) == pytest.approx(
        1.0 - 2.0 * math.exp(-5.0), rel=1e-12
    )
    # Held (rate 0): it stays where it was, the feel of a wheel held off centre.
    assert friction_memory_step(0.37, 0.0, 10.0, law) == 0.37
    # Rate-independent (a hysteresis, not a damping): the same angle at 0.1 or 10 rad/s gives the
    # same memory; exact for a held rate, so one 10 ms step is ten 1 ms steps.
    slow = friction_memory_step(0.2, -0.1, 0.2, law)
    fast = friction_memory_step(0.2, -10.0, 0.002, law)
    assert slow == pytest.approx(fast, rel=1e-12)
    ten = friction_memory_series([-0.1] * 10, [0.02] * 10, law, z=0.2)[-1]
    assert ten == pytest.approx(slow, rel=1e-12)
    # Bounded by the level whatever the steering (passive: |z| <= 1).
    rng = np.random.default_rng(3)
    zs = friction_memory_series(rng.normal(0, 3.0, 5000).tolist(), [1e-3] * 5000, law)
    assert max(abs(v) for v in zs) <= 1.0


def test_the_law_with_memory_makes_a_loop_torque_against_angle_the_paper_law_cannot():
    """A slow sine (0.2 rad at 0.02 Hz): at the centre, 0.2 rad past each reversal (ten K11),
    the torque differs between the two directions by the paper friction's 2 K7 atan(rate/K8)
    and 2 K10 of memory; a wheel held there keeps the memory's K10 (the paper law has 0)."""
    law = with_memory(level=0.5, angle=0.02)
    t = np.arange(0.0, 100.0, 1e-3)
    angle = 0.2 * np.sin(2 * np.pi * 0.02 * t)
    rate = 0.2 * 2 * np.pi * 0.02 * np.cos(2 * np.pi * 0.02 * t)
    state, rows = TorqueState(), []
    for r in rate:
        state, out = torque.step(state, TorqueInputs(0.0, float(r), 0.0), law, 1e-3)
        rows.append(out.torque_friction_Nm)
    friction = np.array(rows)
    centre = np.flatnonzero((np.abs(angle) < 2e-3) & (t > 10.0))  # past the first reversal
    left, right = centre[rate[centre] > 0], centre[rate[centre] < 0]
    width = friction[left].mean() - friction[right].mean()
    paper = 2 * law.k7_Nm * float(np.mean(np.arctan(np.abs(rate[centre]) / law.k8_rad_s)))
    # z is within exp(-10) of +-1 there: 1e-4 relative covers it and the rate's spread.
    assert width == pytest.approx(paper + 2 * law.k10_Nm, rel=1e-3)
    held = friction_memory_step(float(state.friction_memory), 0.0, 5.0, law)
    assert law.k10_Nm * held == pytest.approx(law.k10_Nm * state.friction_memory)


def test_off_by_default_the_shipped_presets_run_as_before_bit_for_bit():
    """K10 = 0 in every shipped preset: torque(...) is torque_terms(...) and a simulated run's
    columns are the memoryless law's on its own rate and Ay, to the bit."""
    from carfeel.io.presets import available

    for name in available("steering"):
        law = load_steering(name).params.torque
        assert law.k10_Nm == 0.0, name
    car = load_steering("b-segment").params
    run = simulate_steering(car, manoeuvres.build("iso7401-sine", car.vehicle))
    rows = zip(run["speed_m_s"].tolist(), run["steering_rate_rad_s"].tolist(),
               run["lateral_accel_m_s2"].tolist(), strict=True)  # fmt: skip
    terms = np.array([torque_terms(v, r, a, car.torque) for v, r, a in rows])
    for column, name in ((0, "torque_Nm"), (3, "torque_friction_Nm")):
        assert _bits(run[name]) == _bits(terms[:, column]), name
    out = torque.torque(TorqueInputs(12.0, 0.3, 2.0), car.torque, friction_memory=0.8)
    assert out == torque.TorqueOutputs(*torque_terms(12.0, 0.3, 2.0, car.torque))


def test_a_run_with_memory_adds_k10_z_to_the_friction_and_the_torque():
    base = load_steering("b-segment").params
    car = dataclasses.replace(base, torque=with_memory(level=0.4, angle=0.05))
    plain = simulate_steering(base, manoeuvres.build("weave", base.vehicle))
    held = simulate_steering(car, manoeuvres.build("weave", car.vehicle))
    z = np.asarray(friction_memory_series(plain["steering_rate_rad_s"].tolist(),
                                          [1e-3] * len(plain), car.torque))  # fmt: skip
    assert held["torque_Nm"] == pytest.approx(plain["torque_Nm"] + 0.4 * z, abs=1e-12)
    assert held["torque_friction_Nm"] == pytest.approx(
        plain["torque_friction_Nm"] + 0.4 * z, abs=1e-12
    )
    assert np.abs(z).max() > 0.99  # the weave turns far beyond K11 each way


@needs_cc
@pytest.mark.linux_only  # the C port built by gcc as on Linux x86-64 (a .so)
@pytest.mark.needs_tools
def test_the_c_port_of_the_memory_is_bit_for_bit(tmp_path):
    import ctypes

    from carfeel.export import fmu

    library = ctypes.CDLL(str(fmu.build_port_library(tmp_path)))
    law = with_memory(level=0.6, angle=0.017)
    rng = np.random.default_rng(7)
    rate = np.concatenate([rng.normal(0, 2.0, 3000), [0.0, -0.0, 5e-324, -1e-300, 1e6, -3.0]])
    dt = np.concatenate([rng.uniform(1e-4, 5e-3, 3000), [1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 0.0]])
    z = np.zeros(len(rate))
    flat = np.asarray(fmu.flat_values(law), dtype="<f8")
    pointer = ctypes.POINTER(ctypes.c_double)
    library.cf_friction_memory_run(
        rate.ctypes.data_as(pointer), dt.ctypes.data_as(pointer), ctypes.c_size_t(len(rate)),
        flat.ctypes.data_as(pointer), z.ctypes.data_as(pointer),
    )  # fmt: skip
    assert _bits(z) == _bits(friction_memory_series(rate.tolist(), dt.tolist(), law))


@needs_cc
@pytest.mark.linux_only  # bit for bit: the gcc build's claim (elsewhere: FMPy's CMake)
@pytest.mark.needs_tools
def test_the_steering_fmu_carries_the_memory_as_carfeel_runs_it(tmp_path):
    """The FMU's parameters torque.k10_Nm and torque.k11_rad, set at start, give carfeel's own
    run with that law bit for bit (inputs as tests/test_fmu_export gives them)."""
    fmpy = pytest.importorskip("fmpy", reason="the fmu extra: pip install 'carfeel[fmu]'")
    from carfeel.cli import main

    path = tmp_path / "steering.fmu"
    assert main(["export", "fmu", "steering", "--out", str(path)]) == 0
    base = load_steering("b-segment").params
    car = dataclasses.replace(base, torque=with_memory(level=0.45, angle=0.025))
    recorded = simulate_steering(car, manoeuvres.build("weave", car.vehicle))
    n = 6000
    names = ("speed_m_s", "lateral_accel_m_s2", "steering_angle_rad", "steering_rate_rad_s")
    signal = np.zeros(n, dtype=[("time", "<f8")] + [(name, "<f8") for name in names])
    signal["time"] = np.arange(n) * 1e-3
    for name in names:
        signal[name] = recorded[name][:n]
    result = fmpy.simulate_fmu(
        str(path), stop_time=n * 1e-3, output_interval=1e-3, input=signal,
        start_values={"torque.k10_Nm": 0.45, "torque.k11_rad": 0.025},
    )  # fmt: skip
    for name in ("torque_Nm", "torque_friction_Nm"):
        assert _bits(result[name][1:]) == _bits(recorded[name][:n]), name
    assert np.ptp(recorded["torque_friction_Nm"] - simulate_steering(
        base, manoeuvres.build("weave", base.vehicle))["torque_friction_Nm"]) > 0.8  # fmt: skip
