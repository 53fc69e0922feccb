"""The implicit stick-slip integrator of equation (8)."""

from __future__ import annotations

import math

from hypothesis import given, settings
from hypothesis import strategies as st

from carfeel.models.mechanics import StageMechanics, stage_energy_J, stick_slip_step

MECH = StageMechanics(
    mass_kg=1.0,
    stiffness_N_m=0.0,
    damping_N_s_m=0.0,
    static_friction_N=10.0,
    sliding_friction_N=6.0,
)


def step(x, v, force, mech=MECH, rest=0.0, dt=1e-3):
    return stick_slip_step(
        x, v, force, mech.mass_kg, mech.damping_N_s_m, mech.stiffness_N_m, rest,
        mech.static_friction_N, mech.sliding_friction_N, 1e-3, dt,
    )  # fmt: skip


def test_sticking_in_the_velocity_band_does_not_depend_on_the_step():
    # 0.5 mm/s, inside the 1 mm/s band, pushed with 8 N against 10 N static: sticks at any step.
    for dt in (1e-3, 1e-4, 1e-5):
        x1, v1, friction = step(0.0, 0.0005, 8.0, dt=dt)
        assert (x1, v1, friction) == (0.0, 0.0, 8.0)


def test_stuck_lever_stays_exactly_still_below_breakaway():
    x, v = 0.0123456789, 0.0
    for i in range(1000):
        force = 9.99 * math.sin(i * 0.01)  # always within the 10 N static friction
        x1, v1, friction = step(x, v, force)
        assert x1 == x  # bit for bit, not approximately
        assert v1 == 0.0
        assert friction == force  # the mounting carries the whole force
        x, v = x1, v1


def test_breakaway_at_static_force_then_sliding_friction():
    # Just above the static friction the lever moves, and it feels the sliding friction.
    _x1, v1, friction = step(0.0, 0.0, 10.001)
    assert v1 > 0.0
    assert friction == 6.0
    # Acceleration (10.001 - 6) / 1 kg over 1 ms, to rounding.
    assert math.isclose(v1, (10.001 - 6.0) * 1e-3, rel_tol=1e-12)


def test_sliding_lever_sticks_when_friction_can_stop_it_within_a_step():
    # 2 mm/s against 6 N of friction on 1 kg stops within 1 ms: no sign flip, no chatter.
    x1, v1, friction = step(0.0, 0.002, 0.0)
    assert v1 == 0.0
    assert x1 == 0.0
    assert math.isclose(friction, 2.0, rel_tol=1e-12)  # m*v/h: exactly what stops it


def test_stop_time_does_not_depend_on_step_size():
    # A lever at 0.1 m/s sliding against 6 N stops after m*v/F = 16.67 ms, whatever the step.
    stop_times = []
    for dt in (1e-3, 1e-4, 1e-5):
        x, v, t = 0.0, 0.1, 0.0
        while v != 0.0:
            x, v, _ = step(x, v, 0.0, dt=dt)
            t += dt
        stop_times.append(t)
    band_time = 1.0 * 1e-3 / 6.0  # the lever sticks once inside the 1 mm/s band: 0.17 ms early
    for t, dt in zip(stop_times, (1e-3, 1e-4, 1e-5), strict=True):
        # Within one step, plus the band: the stop happens in the step where v enters the band.
        assert abs(t - 1.0 * 0.1 / 6.0) <= dt + band_time + 1e-12


mechanics = st.builds(
    StageMechanics,
    mass_kg=st.floats(0.05, 20.0),
    stiffness_N_m=st.floats(0.0, 1e6),
    damping_N_s_m=st.floats(0.0, 1e3),
    static_friction_N=st.floats(0.0, 100.0),
    sliding_friction_N=st.floats(0.0, 100.0),
)


@settings(max_examples=300, deadline=None)
@given(
    mech=mechanics,
    x=st.floats(-0.05, 0.05),
    v=st.floats(-2.0, 2.0),
    rest=st.floats(-0.05, 0.05),
    dt=st.sampled_from([1e-3, 1e-4, 2e-3]),
)
def test_no_energy_is_gained_without_applied_force(mech, x, v, rest, dt):
    """Passivity: with F = 0 the stage energy never grows, step after step (any parameters)."""
    static = max(mech.static_friction_N, mech.sliding_friction_N)
    energy = stage_energy_J(x, v, mech, rest)
    for _ in range(200):
        x, v, _ = stick_slip_step(
            x, v, 0.0, mech.mass_kg, mech.damping_N_s_m, mech.stiffness_N_m, rest, static,
            mech.sliding_friction_N, 1e-3, dt,
        )  # fmt: skip
        new_energy = stage_energy_J(x, v, mech, rest)
        # Rounding of the float arithmetic is the only allowed gain.
        assert new_energy <= energy * (1 + 1e-12) + 1e-15
        assert math.isfinite(x) and math.isfinite(v)
        energy = new_energy
