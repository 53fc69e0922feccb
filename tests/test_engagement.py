"""One gear engagement, neutral to first, with the default preset and the eq. (10) driver."""

from __future__ import annotations

import dataclasses
import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carfeel.analysis.shift_features import shift_features
from carfeel.models.gearshift import engagement
from carfeel.models.gearshift.engagement import EngagementInputs, Stage
from carfeel.simulation.runner import run
from carfeel.simulation.shift import simulate_shift
from tests.conftest import default_params, shift_run

PUSH_ORDER = (
    "neutral",
    "synchronization",
    "gate_open",
    "engagement",
    "free_travel",
    "stop",
    "in_gear",
)


def features(seed=0, substeps=1):
    params = default_params()
    return shift_features(shift_run(seed, substeps), params.gearbox.in_gear_position_m)


def test_stages_appear_in_order_and_end_in_gear():
    for seed in range(5):
        f = features(seed)
        assert f.stages == PUSH_ORDER
        assert f.final_stage == "in_gear"


def test_stages_happen_at_their_fixed_positions(params):
    result = shift_run(0)
    stages, x = result["stage"], result["position_m"]
    g = params.gearbox
    sync = stages == "synchronization"
    # The blocker ring holds the lever exactly at the synchronization position: no tolerance.
    assert np.all(x[sync] == g.synchronization_position_m)
    # The teeth are met at the teeth position: the first engagement sample lies within one step
    # of travel (at most 0.6 m/s * 1 ms = 0.6 mm) past it, and inside the teeth.
    first = int(np.flatnonzero(stages == "engagement")[0])
    assert g.teeth_position_m <= x[first] <= g.teeth_position_m + 0.6e-3
    assert np.all(x[stages == "engagement"] < g.teeth_end_position_m + 0.6e-3)
    first_stop = int(np.flatnonzero(stages == "stop")[0])
    assert g.in_gear_position_m <= x[first_stop] <= g.in_gear_position_m + 0.6e-3


def test_synchronization_plateau_force_and_hold_time(params):
    for seed in range(3):
        f = features(seed)
        # The plateau is the driver's F_max of eq. (10) once the hand is at rest; the median over
        # the hold is within 1 % (the hand settles in about 30 ms of the 300 ms).
        assert f.synchronization_force_N == pytest.approx(params.driver.push_force_N, rel=0.01)
        assert f.synchronization_peak_N <= params.driver.push_force_N * 1.001
        # The knob stays still for the synchronization time, to one 1 ms sample.
        assert f.synchronization_hold_s == pytest.approx(
            params.gearbox.synchronization_duration_s, abs=1e-3 + 1e-9
        )


def test_engagement_peak_is_below_the_synchronization_peak_and_random_across_seeds():
    peaks = [features(seed).engagement_peak_N for seed in range(8)]
    sync = features(0).synchronization_peak_N
    assert all(p < sync for p in peaks)
    # The synchronizer design guideline: at most 1/3 of the synchronization force.
    assert max(peaks) <= sync / 3
    # Different teeth positions give clearly different peaks: spread of several newtons.
    assert max(peaks) - min(peaks) > 5.0
    assert len({round(p, 6) for p in peaks}) == len(peaks)


def test_engagement_peak_is_identical_for_one_seed():
    params = default_params()
    from carfeel.simulation.shift import simulate_shift

    a = simulate_shift(params, seed=42)
    b = simulate_shift(params, seed=42)
    for name in a.names:
        assert np.array_equal(a[name], b[name]), name


def test_stop_overshoots_then_settles_at_the_in_gear_position(params):
    g = params.gearbox
    for seed in range(3):
        f = features(seed)
        # Overshoot: the knob goes past x_gear while the driver pushes into the elastic stop,
        # by more than 0.5 mm (the preset's stop takes about 1.5 mm at 45 N).
        assert f.stop_overshoot_m > 0.5e-3
        # Settled: the detent holds the knob within static friction / stiffness of x_gear.
        held = g.in_gear.static_friction_N / g.in_gear.stiffness_N_m
        assert abs(f.final_position_m - g.in_gear_position_m) <= held + 1e-9
        result = shift_run(seed)
        assert abs(result["velocity_m_s"][-1]) < 1e-3
        assert abs(result["force_N"][-1]) < 0.5  # the driver has let go


def test_force_reversal_during_synchronization_never_reaches_engagement():
    """A driver pushes into the synchro, then pulls back before the gate opens."""
    g = default_params().gearbox
    reverse_at = 0.25  # s; the ring is met at about 0.08 s and the gate opens at about 0.38 s

    def force(t):
        return 60.0 if t < reverse_at else -30.0

    result, state = run(
        engagement.step,
        engagement.initial_state(seed=3),
        g,
        duration_s=1.0,
        inputs=lambda t: EngagementInputs(force(t)),
    )
    stages = set(result["stage"].tolist())
    assert "synchronization" in stages
    assert stages.isdisjoint({"gate_open", "engagement", "free_travel", "stop", "in_gear"})
    assert state.stage in (Stage.NEUTRAL, Stage.RETURNING)
    assert state.position_m < g.synchronization_position_m


def test_force_reversal_on_the_teeth_goes_to_free_motion_not_into_gear():
    g = default_params().gearbox
    # Push with 60 N until the lever enters the teeth, then pull with 40 N at once.
    phases = {"push": True}

    def inputs(t):
        return EngagementInputs(60.0 if phases["push"] else -40.0)

    state = engagement.initial_state(seed=1)
    seen = []
    for _ in range(3000):
        state, out = engagement.step(state, inputs(0.0), g, 1e-3)
        seen.append(out.stage)
        if out.stage == "engagement":
            phases["push"] = False
    assert "engagement" in seen
    after = seen[seen.index("engagement") :]
    assert "returning" in after
    assert not {"free_travel", "stop", "in_gear"} & set(after)
    assert state.position_m < g.teeth_position_m


def test_one_ms_steps_and_tenth_ms_substeps_agree(params):
    """Convergence: the same shift at 1 kHz and at 10 kHz (sampled at 1 kHz) agree."""
    coarse, fine = shift_run(0, 1), shift_run(0, 10)
    fc, ff = features(0, 1), features(0, 10)
    assert _same_stages(coarse["stage"], fine["stage"])
    # Position, sample by sample: the runs drift apart in time by up to 3 ms (see _same_stages)
    # while the knob moves at up to 0.5 m/s, so up to 1.5 mm apart during the fast travel; the
    # RMS over the run stays under 0.3 mm, and where the knob rests they agree within the band
    # the in-gear stage's static friction holds it in (6 N / 30 kN/m = 0.2 mm): with the stop
    # ringing at its physical damping, each run sticks at its own point of that band.
    diff = coarse["position_m"] - fine["position_m"]
    assert np.max(np.abs(diff)) < 1.5e-3
    assert np.sqrt(np.mean(diff**2)) < 0.3e-3
    g = params.gearbox
    assert abs(diff[-1]) < g.in_gear.static_friction_N / g.in_gear.stiffness_N_m
    assert fc.synchronization_hold_s == pytest.approx(ff.synchronization_hold_s, abs=1e-3)
    # Peaks are sampled 10x more finely and the hand/lever impact resolves better: within 10 %.
    assert fc.engagement_peak_N == pytest.approx(ff.engagement_peak_N, rel=0.1)
    assert fc.stop_peak_N == pytest.approx(ff.stop_peak_N, rel=0.1)
    assert fc.stop_overshoot_m == pytest.approx(ff.stop_overshoot_m, abs=0.1e-3)


def _same_stages(a, b):
    """Same stage sequence, each transition within 5 samples (5 ms) of the other run's.

    The hand sees the knob one step late, a 1 ms lag in the loop at 1 kHz and 0.1 ms at 10 kHz;
    it delays each stage by about a millisecond and the delays add up over the push.
    """
    changes_a = [i for i in range(1, len(a)) if a[i] != a[i - 1]]
    changes_b = [i for i in range(1, len(b)) if b[i] != b[i - 1]]
    return len(changes_a) == len(changes_b) and all(
        abs(i - j) <= 5 for i, j in zip(changes_a, changes_b, strict=True)
    )


def test_no_nan_anywhere_in_a_shift_with_pull_out():
    result = shift_run(5, pull_out=True)
    for name in result.names:
        values = result[name]
        if values.dtype.kind == "f":
            assert np.all(np.isfinite(values)), name
    assert result["stage"][-1] == "neutral"
    assert "returning" in set(result["stage"].tolist())


S = Stage
# Every transition the stage machine may make in one step. Two-hop entries are the cases where a
# force guard fires before the motion and a position guard after it, within the same step.
ALLOWED = {
    (S.NEUTRAL, S.SYNCHRONIZATION),
    (S.SYNCHRONIZATION, S.GATE_OPEN),
    (S.SYNCHRONIZATION, S.ENGAGEMENT),  # gate opens, and the same (long) step reaches the teeth
    (S.SYNCHRONIZATION, S.NEUTRAL),  # the push dropped: the ring lets go
    (S.GATE_OPEN, S.ENGAGEMENT),
    (S.GATE_OPEN, S.RETURNING),
    (S.ENGAGEMENT, S.FREE_TRAVEL),
    (S.ENGAGEMENT, S.RETURNING),
    (S.ENGAGEMENT, S.NEUTRAL),  # reversal, and the same (long) step backs behind the ring
    (S.FREE_TRAVEL, S.STOP),
    (S.FREE_TRAVEL, S.RETURNING),
    (S.STOP, S.IN_GEAR),
    (S.STOP, S.RETURNING),
    (S.IN_GEAR, S.RETURNING),
    (S.RETURNING, S.NEUTRAL),
    (S.RETURNING, S.GATE_OPEN),
    (S.RETURNING, S.ENGAGEMENT),
    (S.RETURNING, S.FREE_TRAVEL),
}
IN_MESH_OR_TEETH = {S.ENGAGEMENT, S.FREE_TRAVEL, S.STOP, S.IN_GEAR}

# What a hand does to a lever, as segments (kind, size 0..1, length 0..1): pushes, pulls, lets go,
# and dithers, long enough to reach every stage (a synchronization takes 0.3 s of pushing).
KINDS = ("push", "pull", "let_go", "dither")


def segment(kind: str, size: float, length: float) -> tuple[float, float]:
    """(force N, duration s) of one segment of a hand's force history."""
    if kind == "push":
        return 20.0 + 180.0 * size, 0.01 + 0.5 * length
    if kind == "pull":
        return -10.0 - 190.0 * size, 0.005 + 0.2 * length
    if kind == "let_go":
        return 0.0, 0.01 + 0.3 * length
    return -10.0 + 20.0 * size, 0.001 + 0.05 * length


def follow_stage_graph(seed, segments, dt, seen):
    """Run a force history through the engagement model and check, at every step: finite,
    only allowed transitions, the teeth reached only through an opened synchro gate, and a
    sleeve pushed again past the ring going on where it is. Adds each transition to `seen`."""
    g = default_params().gearbox
    state = engagement.initial_state(seed)
    synchronized = False  # the gate opened since the lever last was in neutral
    for kind, size, length in segments:
        force, duration = segment(kind, size, length)
        for _ in range(max(1, round(duration / dt))):
            new, out = engagement.step(state, EngagementInputs(force), g, dt)
            assert math.isfinite(out.position_m) and math.isfinite(out.velocity_m_s)
            assert math.isfinite(out.reaction_N)
            old_stage, new_stage = state.stage, new.stage
            if new_stage is not old_stage:
                pair = (old_stage, new_stage)
                assert pair in ALLOWED, pair
                seen.add(pair)
                if old_stage is S.SYNCHRONIZATION and new_stage in (S.GATE_OPEN, S.ENGAGEMENT):
                    synchronized = True
                if new_stage is S.NEUTRAL:
                    synchronized = False
                if new_stage in IN_MESH_OR_TEETH:
                    assert synchronized, pair  # never into the teeth or mesh unsynchronized
                x = state.position_m
                if pair == (S.RETURNING, S.FREE_TRAVEL):
                    assert x >= g.teeth_end_position_m
                if pair == (S.RETURNING, S.ENGAGEMENT):
                    assert g.teeth_position_m <= x < g.teeth_end_position_m
                if pair == (S.RETURNING, S.GATE_OPEN):
                    assert g.synchronization_position_m < x < g.teeth_position_m
            if new_stage is S.SYNCHRONIZATION:
                # Blocked at the ring: at rest there, entered only from neutral.
                assert new.velocity_m_s == 0.0
                assert new.position_m == g.synchronization_position_m
                assert old_stage in (S.NEUTRAL, S.SYNCHRONIZATION)
            state = new


histories = st.lists(
    st.tuples(st.sampled_from(KINDS), st.floats(0.0, 1.0), st.floats(0.0, 1.0)),
    min_size=1,
    max_size=14,
)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**63), segments=histories, dt=st.sampled_from([1e-3, 5e-4, 1e-2]))
def test_any_force_history_follows_the_stage_graph(seed, segments, dt):
    """Under any force history: finite, only allowed transitions, and never into mesh unsynced
    (the checks in `follow_stage_graph`)."""
    follow_stage_graph(seed, segments, dt, set())


def test_the_force_histories_reach_every_transition_of_the_stage_graph():
    """The same checks over 240 random hand histories (pushes, pulls, letting go, dithering;
    1 ms, 0.5 ms and, for the two-hop transitions, 10 ms steps) and one made by hand: every
    allowed transition occurs, so the checks above have run on each of them (before issue 10,
    the property test's histories made 2 of its 17)."""
    rng = random.Random(10)
    seen: set[tuple[Stage, Stage]] = set()
    for example in range(240):
        segments = [
            (rng.choice(KINDS), rng.random(), rng.random()) for _ in range(rng.randint(3, 14))
        ]
        dt = (1e-3, 5e-4, 1e-2)[example % 3]
        follow_stage_graph(example, segments, dt, seen)
    # A two-hop transition random histories rarely make: 20 N into the teeth, a light pull held
    # past the reversal time, then a hard one that in one 10 ms step takes the lever behind the
    # ring.
    # (Seed 11, u = 0.32: its chamfers meet 0.6 mm into the teeth;
    # seed 0 made it while the chamfers met at the teeth, before issue 30.)
    follow_stage_graph(11, [("push", 0.0, 0.8), ("pull", 0.0, 0.0), ("pull", 1.0, 0.1)], 1e-2, seen)
    # Out of gear and pushed back in: since a pull out of gear must be held (issue 30), random
    # histories rarely make these. 74 N into gear, a pull of 124 or 162 N for 30 ms (out of gear
    # into the teeth or the gate), then 20 N forward again.
    for pull in (0.6, 0.8):
        follow_stage_graph(0, [("push", 0.3, 1.0), ("pull", pull, 0.1), ("push", 0.0, 0.2)],
                           1e-3, seen)  # fmt: skip
    assert seen == ALLOWED, sorted((a.value, b.value) for a, b in ALLOWED - seen)


def stage_region(stage: Stage, g) -> tuple[float, float]:
    """Positions (m) where a stage is active, for starting the energy test inside it."""
    return {
        S.NEUTRAL: (-0.01, g.synchronization_position_m - 1e-4),
        S.GATE_OPEN: (g.synchronization_position_m, g.teeth_position_m - 1e-4),
        S.ENGAGEMENT: (g.teeth_position_m, g.teeth_end_position_m - 1e-4),
        S.FREE_TRAVEL: (g.teeth_end_position_m, g.in_gear_position_m - 1e-4),
        # Beyond the settle distance, or the stop hands over to in_gear at once.
        S.STOP: (g.in_gear_position_m + g.settle_distance_m, g.in_gear_position_m + 0.005),
        S.IN_GEAR: (g.in_gear_position_m - g.detent_release_m + 1e-4, g.in_gear_position_m + 0.003),
        S.RETURNING: (g.synchronization_position_m + 1e-4, g.in_gear_position_m),
    }[stage]


FREE_STAGES = [s for s in Stage if s is not Stage.SYNCHRONIZATION]


@pytest.mark.parametrize("stage", FREE_STAGES, ids=lambda s: s.value)
@settings(max_examples=40, deadline=None)
@given(where=st.floats(0.0, 1.0), v=st.floats(-0.5, 0.5))
def test_passive_stage_never_gains_energy_without_driver_force(stage, where, v):
    """With no driver force, the energy of the active stage never grows while it is active."""
    g = default_params().gearbox
    low, high = stage_region(stage, g)
    low, high = low + 1e-3, high - 1e-3  # 1 mm inside: one 1 ms step moves at most 0.5 mm
    x = low + where * (high - low)
    # In the teeth, the chamfers still to turn the gear over the first 2 mm (heavier lever).
    state = engagement.EngagementState(stage, x, v, 0.0, 0.0, 7.0, 1, low + 1e-3)
    steps_inside = 0
    energy = engagement.energy_J(state, g)
    for _ in range(300):
        new, _ = engagement.step(state, EngagementInputs(0.0), g, 1e-3)
        if new.stage is not stage:
            break
        # Kinetic, the stage's spring and the detents' potential (conservative profiles).
        new_energy = engagement.energy_J(new, g)
        # Only rounding may add (the detents' potential is 0 at their seats, so it can be < 0).
        assert new_energy <= energy + 1e-12 * abs(energy) + 1e-15
        energy, state = new_energy, new
        steps_inside += 1
    assert steps_inside >= 1  # the example exercised the stage, not only its exit


@given(
    stages=st.sampled_from(sorted(ALLOWED, key=lambda pair: (pair[0].value, pair[1].value))),
    x=st.floats(-0.01, 0.05),
    v=st.floats(-2.0, 2.0),
)
def test_a_transition_never_adds_energy_when_the_lever_can_pay_for_it(stages, x, v):
    """Kinetic energy pays for any spring energy the new stage holds at the switch."""
    old, new = stages
    g = default_params().gearbox
    m_old, spring_old = engagement._mass_and_spring(g, old, x)
    m_new, spring_new = engagement._mass_and_spring(g, new, x)
    v_new = engagement._hand_over(v, x, old, new, g)
    before = 0.5 * m_old * v * v + spring_old
    after = 0.5 * m_new * v_new * v_new + spring_new
    if 0.5 * m_new * engagement.hand_over_velocity(v, m_old, m_new) ** 2 >= (
        spring_new - spring_old
    ):
        assert after <= before * (1 + 1e-12) + 1e-12
    else:  # it cannot pay: it stops there, the shortfall bounded by the new spring's energy
        assert v_new == 0.0
        assert after - before <= spring_new


@given(
    m_old=st.floats(0.05, 20.0),
    m_new=st.floats(0.05, 20.0),
    v=st.floats(-3.0, 3.0),
)
def test_a_change_of_mass_at_a_transition_never_adds_kinetic_energy(m_old, m_new, v):
    v_new = engagement.hand_over_velocity(v, m_old, m_new)
    assert 0.5 * m_new * v_new**2 <= 0.5 * m_old * v**2 * (1 + 1e-12)
    assert v_new * v >= 0.0  # no reversal


# ---------------------------------------------------------------- issue 10


def push(state, force_N, steps, g, dt=1e-3):
    """Step the engagement `steps` times with a constant knob force; the stages seen."""
    seen = []
    for _ in range(steps):
        state, out = engagement.step(state, EngagementInputs(force_N), g, dt)
        seen.append(out.stage)
    return state, seen


def test_no_synchronization_plateau_past_the_ring_after_a_grip_rebound_in_the_teeth():
    """The reproduction of issue 10: V0 = 0.1 m/s, seed 3, stepped at 0.1 ms. The hand rebounds
    off the teeth (a brief pull of about 10 N); before, the lever went to `returning` and a new
    0.3 s synchronization started at 23.5 mm."""
    params = default_params()
    slow = dataclasses.replace(
        params, driver=dataclasses.replace(params.driver, push_velocity_m_s=0.1)
    )
    result = simulate_shift(slow, seed=3, duration_s=2.0, dt_s=1e-4)
    stages, x = result["stage"], result["position_m"]
    sync = stages == "synchronization"
    assert np.all(x[sync] == params.gearbox.synchronization_position_m)
    assert np.count_nonzero(np.diff(sync.astype(int)) == 1) == 1  # one synchronization
    assert stages[-1] == "in_gear"


def test_a_pull_in_the_teeth_and_a_new_push_go_on_in_the_teeth_not_at_a_new_ring():
    """A pull held past the reversal time takes the lever out of the teeth's stage; pushed again
    while it is still past the ring, it goes on there: the ring cannot block again."""
    g = default_params().gearbox
    state = engagement.initial_state(seed=1)._replace(
        stage=Stage.ENGAGEMENT, position_m=0.025, velocity_m_s=0.0
    )
    seen = ["engagement"]
    while seen[-1] == "engagement":
        state, seen = push(state, -25.0, 1, g)
    assert seen == ["returning"]
    assert state.position_m > g.teeth_position_m
    state, pushed = push(state, 60.0, 1500, g)
    assert "synchronization" not in pushed
    # Into gear, still pushed against the stop (60 N compresses it by about 2 mm).
    assert state.stage in (Stage.STOP, Stage.IN_GEAR)
    assert state.position_m > g.in_gear_position_m


def test_a_brief_pull_in_the_teeth_is_not_a_reversal():
    """Shorter than the reversal time (20 ms in the preset), a pull that does not move the
    sleeve out of the teeth leaves their stage alone (before, one negative sample did)."""
    g = default_params().gearbox
    state = engagement.initial_state(seed=1)._replace(
        stage=Stage.ENGAGEMENT, position_m=0.025, velocity_m_s=0.0
    )
    state, seen = push(state, -20.0, int(0.8 * g.reversal_time_s / 1e-3), g)
    assert set(seen) == {"engagement"}


# Released anywhere from neutral to just short of the ring (15 mm).
@pytest.mark.parametrize("x0_mm", [-10.0, 1.0, 5.0, 10.0, 14.0, 14.99])
def test_a_lever_released_between_neutral_and_the_ring_returns_to_neutral(x0_mm):
    """Issue 10: the spring and the detent beat the friction everywhere before the ring.

    Within 0.5 s (measured: 0.08-0.31 s, the slowest from 15 mm), the lever is back within the
    band the neutral stage's static friction can hold it in against the centring spring and the
    detent's seat (1.5 N / 1.65 kN/m = 0.9 mm)."""
    g = default_params().gearbox
    state = engagement.initial_state()._replace(position_m=x0_mm * 1e-3)
    state, seen = push(state, 0.0, 500, g)
    seat_stiffness = g.neutral.stiffness_N_m + 4.0 * g.neutral_detent.seat_force_N / (
        g.neutral_detent.width_m
    )
    assert set(seen) == {"neutral"}
    assert abs(state.position_m) <= g.neutral.static_friction_N / seat_stiffness
    assert state.velocity_m_s == 0.0


def test_the_detents_are_conservative_profiles_with_a_crest():
    """A potential: its force is minus its slope; the neutral one pushes back before its crest
    and helps past it; the gear's pulls the lever in over its last millimetres (the suck-in)."""
    g = default_params().gearbox
    xs = np.linspace(-0.01, 0.05, 6001)
    energy = np.array([engagement.detent_energy_J(x, g) for x in xs])
    force = np.array([engagement.detent_force_N(x, g) for x in xs])
    # F = -dU/dx, to the finite difference's error (the profiles' curvature times 10 um).
    assert np.allclose(force[1:-1], -np.gradient(energy, xs)[1:-1], atol=0.05)
    crest = g.neutral_detent.width_m
    before, after = (xs > 0.002) & (xs < crest - 0.001), (xs > crest + 0.001) & (xs < crest + 0.004)
    assert np.all(force[before] < 0.0) and np.all(force[after] > 0.0)
    x_gear = g.in_gear_position_m
    suck = (xs > x_gear - g.gear_detent.width_m + 0.0005) & (xs < x_gear - 0.0005)
    assert np.all(force[suck] > 0.0)


def test_a_lever_let_go_during_synchronization_leaves_the_ring():
    """Issue 10: pushed for 0.15 s into the ring, then let go: before, it stayed blocked at the
    ring with its progress forever. Now the struts push it back to neutral, where the fixed
    synchronizer's progress decays over desynchronization_time_s."""
    g = default_params().gearbox
    state, seen = push(engagement.initial_state(), 60.0, 150, g)
    assert seen[-1] == "synchronization"
    progress = state.synchronization_progress
    assert progress > 0.1
    state, seen = push(state, 0.0, 100, g)
    assert seen[0] == "neutral"  # at once: the ring holds only under axial load
    assert state.position_m < g.synchronization_position_m - 0.005
    # 99 of the 100 steps in neutral (the first one leaves the ring).
    decayed = max(0.0, progress - 0.099 / g.desynchronization_time_s)
    assert state.synchronization_progress == pytest.approx(decayed, abs=1e-9)
    state, _ = push(state, 0.0, int(g.desynchronization_time_s / 1e-3), g)
    assert state.synchronization_progress == 0.0


def test_a_push_below_the_struts_force_does_not_load_the_ring():
    g = default_params().gearbox
    state = engagement.initial_state()._replace(
        stage=Stage.SYNCHRONIZATION, position_m=g.synchronization_position_m
    )
    state, seen = push(state, 0.9 * g.hold_force_N, 50, g)
    assert seen[0] == "neutral" and "synchronization" not in seen[1:]


def peaks_of(params, seeds=range(10)):
    return np.array(
        [
            shift_features(
                simulate_shift(params, seed=s), params.gearbox.in_gear_position_m
            ).engagement_peak_N
            for s in seeds
        ]
    )


def with_driver_speed(params, v0):
    return dataclasses.replace(
        params, driver=dataclasses.replace(params.driver, push_velocity_m_s=v0)
    )


def with_gear_inertia(params, inertia):
    g = params.gearbox
    chamfer = dataclasses.replace(g.chamfer, gear_inertia_kg_m2=inertia)
    return dataclasses.replace(params, gearbox=dataclasses.replace(g, chamfer=chamfer))


def test_the_engagement_peak_grows_with_the_shift_speed():
    """Lovas et al.: the chamfers pick up the gear in a plastic impact, so the peak grows with
    the sleeve's speed. Mean over 10 seeds at V0 = 0.25, 0.5, 1.0 m/s (measured: 17.6, 33.8
    and 48.8 N); each step at least 5 N up, and the seeds that meet a chamfer grow each."""
    params = default_params()
    means = [peaks_of(with_driver_speed(params, v0)).mean() for v0 in (0.25, 0.5, 1.0)]
    assert means[1] > means[0] + 5.0 and means[2] > means[1] + 5.0
    slow, fast = peaks_of(with_driver_speed(params, 0.25)), peaks_of(with_driver_speed(params, 1.0))
    assert np.all(fast > slow)


def test_the_engagement_peak_grows_with_the_gears_reflected_inertia():
    """First gear (0.153 kg m^2 at an output-shaft synchronizer) against fifth (0.01 * 0.897^2):
    the same seeds, the same driver; the peak is higher for every seed that meets a chamfer,
    and the same (teeth friction only) for those whose teeth meet gap to gap."""
    params = default_params()
    first = peaks_of(params)
    fifth = peaks_of(with_gear_inertia(params, 0.01 * 0.897**2))
    contact = first - fifth > 1e-9
    assert contact.sum() >= 5
    assert np.mean(first[contact] - fifth[contact]) > 3.0
    assert np.allclose(first[~contact], fifth[~contact])


def test_the_engagement_peak_varies_with_the_seed_and_sometimes_there_is_no_contact():
    """The relative angle of the teeth is random: the peak differs per seed, and with the
    preset's 20 % chance of no contact some of 20 seeds meet no chamfer (their peak is the
    teeth's friction only: the same as without any gear inertia)."""
    params = default_params()
    seeds = range(20)
    peaks = peaks_of(params, seeds)
    bare = peaks_of(with_gear_inertia(params, 0.0), seeds)
    assert len({round(p, 6) for p in peaks}) == len(peaks)
    no_contact = np.isclose(peaks, bare)
    assert 1 <= no_contact.sum() <= 10
    assert np.all(peaks < features(0).synchronization_peak_N)


def test_the_stop_rings_with_its_physical_damping_at_1_khz():
    """Issue 10: backward Euler at 1 kHz rang the preset's stop (30 kN/m, 40 N*s/m, 1.2 kg:
    zeta 0.105) with an effective 0.18. Free ringing, no friction and no detent, from 2 mm:
    the damping ratio from the logarithmic decrement over 3 periods is within 3 % of the
    physical one (the midpoint rule's error is (w*h)^2/12 = 0.2 %, the 1 ms sampling of the
    maxima of a 25 Hz ringing adds up to about 1 %)."""
    g = default_params().gearbox
    stop = dataclasses.replace(g.stop, static_friction_N=0.0, sliding_friction_N=0.0)
    quiet = dataclasses.replace(g.gear_detent, seat_force_N=0.0, far_force_N=0.0)
    g = dataclasses.replace(
        g, stop=stop, gear_detent=quiet, settle_velocity_m_s=1e-9, detent_release_m=0.01
    )
    state = engagement.initial_state()._replace(
        stage=Stage.STOP, position_m=g.in_gear_position_m + 0.002
    )
    xs = []
    for _ in range(200):
        state, _ = engagement.step(state, EngagementInputs(0.0), g, 1e-3)
        xs.append(state.position_m - g.in_gear_position_m)
    tops = [i for i in range(1, len(xs) - 1) if xs[i - 1] < xs[i] >= xs[i + 1] and xs[i] > 0]
    decrement = math.log(xs[tops[0]] / xs[tops[3]]) / 3
    zeta = decrement / math.sqrt(4 * math.pi**2 + decrement**2)
    physical = stop.damping_N_s_m / (2 * math.sqrt(stop.stiffness_N_m * stop.mass_kg))
    assert zeta == pytest.approx(physical, rel=0.03)


def test_a_compliant_linkage_lets_the_knob_in_by_force_over_stiffness_at_the_ring():
    """Issue 10: a cable linkage gives against the blocked ring (SAE 932996): at 78.5 N and
    50 kN/m the knob rests 1.57 mm past the ring, still, while the ring blocks; the paper's
    preset keeps it rigid (0: the knob exactly at x_sync)."""
    g = dataclasses.replace(
        default_params().gearbox, linkage_stiffness_N_m=50_000.0, linkage_damping_N_s_m=100.0
    )
    state = engagement.initial_state()._replace(
        stage=Stage.SYNCHRONIZATION, position_m=g.synchronization_position_m
    )
    state, seen = push(state, 78.5, 200, g)
    assert set(seen) == {"synchronization"}
    assert state.position_m == pytest.approx(
        g.synchronization_position_m + 78.5 / 50_000.0, abs=1e-7
    )
    assert abs(state.velocity_m_s) < 1e-6
    state, seen = push(state, 0.0, 100, g)
    assert seen[0] == "neutral" and state.position_m < g.synchronization_position_m
    assert default_params().gearbox.linkage_stiffness_N_m == 0.0


def test_the_linkage_efficiency_makes_the_gear_heavier_to_index():
    """m_eq = J * tan^2 / (r^2 * i^2 * efficiency): the knob drives the sleeve through losses."""
    g = default_params().gearbox
    lossy = dataclasses.replace(g, chamfer=dataclasses.replace(g.chamfer, linkage_efficiency=0.7))
    ideal = dataclasses.replace(g, chamfer=dataclasses.replace(g.chamfer, linkage_efficiency=1.0))
    mass_lossy, drag_lossy = engagement.chamfer_load(lossy, None, None)
    mass_ideal, drag_ideal = engagement.chamfer_load(ideal, None, None)
    c = g.chamfer
    per = math.tan(c.angle_rad) / (c.radius_m * c.lever_ratio)
    assert mass_ideal == pytest.approx(c.gear_inertia_kg_m2 * per**2)
    assert mass_lossy == pytest.approx(mass_ideal / 0.7)
    assert drag_lossy == pytest.approx(drag_ideal / 0.7)


@pytest.mark.parametrize("push_N", [15.0, 20.0, 40.0, 78.5, 150.0])
def test_the_fixed_synchronizers_time_falls_with_the_push(push_N):
    # Issue 30: with synchronization_force_N set, the cone's rate is proportional to the axial
    # load (the push less hold_force_N, 7.2 N here): 300 ms at 78.5 N, (78.5 - 7.2) / (F - 7.2)
    # times that at F. Measured: 2734, 1669, 652, 300, 150 ms at 15, 20, 40, 78.5, 150 N.
    # Within 2 steps of 1 ms: the step that meets the ring and the step the gate opens on.
    g = dataclasses.replace(default_params().gearbox, synchronization_force_N=78.5)
    expected_s = g.synchronization_duration_s * (78.5 - g.hold_force_N) / (push_N - g.hold_force_N)
    state = engagement.initial_state(0)
    blocked = 0
    for _ in range(5000):
        state, _ = engagement.step(state, EngagementInputs(push_N), g, 1e-3)
        blocked += state.stage is Stage.SYNCHRONIZATION
        if state.stage is Stage.GATE_OPEN:
            break
    assert state.stage is Stage.GATE_OPEN
    assert blocked * 1e-3 == pytest.approx(expected_s, abs=2e-3)
    # The paper's timer (the preset's 0) takes 300 ms whatever the push.
    paper = default_params().gearbox
    state, blocked = engagement.initial_state(0), 0
    while state.stage is not Stage.GATE_OPEN:
        state, _ = engagement.step(state, EngagementInputs(push_N), paper, 1e-3)
        blocked += state.stage is Stage.SYNCHRONIZATION
    assert blocked == 300


def test_a_synchronization_force_below_what_holds_the_ring_is_refused():
    # (F_ref - hold) divides the rate: at or below the 7.2 N the struts push back with, a preset
    # would synchronize backward or never; the check names the parameter and the bound.
    from carfeel.io.presets import check_shift

    base = default_params()
    bad = dataclasses.replace(base.gearbox, synchronization_force_N=5.0)
    problems = check_shift(dataclasses.replace(base, gearbox=bad))
    assert any("gearbox.synchronization_force_N = 5 N must exceed" in p for p in problems)
    assert not check_shift(base)
