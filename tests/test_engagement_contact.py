"""Issue 30: the chamfers' contact is a position (Lovas et al. 2006), drawn with the tooth angle."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest

from carfeel.models.gearshift import engagement
from carfeel.models.gearshift.engagement import EngagementInputs, Stage
from carfeel.sweep.batch import ShiftBatch
from tests.conftest import default_params

DT_S = 0.001


def _into_the_teeth(seed: int, push_N: float = 78.5):
    """Push until the lever leaves the teeth; returns the states of every step."""
    gearbox = default_params().gearbox
    state = engagement.initial_state(seed)
    states = [state]
    while state.stage is not Stage.FREE_TRAVEL and len(states) < 3000:
        state, _ = engagement.step(state, EngagementInputs(push_N), gearbox, DT_S)
        states.append(state)
    return states, gearbox


def test_the_chamfers_meet_where_the_angle_says_and_the_impact_happens_there():
    # Before: the chamfers always met at x_teeth and the draw set only how long they acted.
    contacts = []
    for seed in range(40):
        states, g = _into_the_teeth(seed)
        teeth = [s for s in states if s.stage is Stage.ENGAGEMENT]
        first = teeth[0]
        if first.index_end_m == 0.0:  # gap to gap: no chamfer, no impact
            assert first.contact_m == 0.0
            continue
        c = g.chamfer
        assert first.index_end_m == g.teeth_position_m + c.travel_m  # the chamfers' end
        assert g.teeth_position_m <= first.contact_m < first.index_end_m
        contacts.append(first.contact_m)
        # The plastic impact (momentum kept with the gear's mass added) on the step that
        # reaches the contact, not before: the speed falls by m / (m + m_gear) there.
        mass = g.engagement.mass_kg
        share = mass / (mass + engagement.chamfer_load(g, None, None)[0])
        pairs = list(itertools.pairwise(states))
        hit = next(i for i, (_, b) in enumerate(pairs) if b.position_m >= first.contact_m)
        before, after = pairs[hit]
        assert before.position_m < first.contact_m
        # Within 10 %: the step's own acceleration (78.5 N at most, 1 ms) moves the speed
        # by under 0.07 m/s against the impact's 60 % drop of about 0.3 m/s.
        assert after.velocity_m_s == pytest.approx(before.velocity_m_s * share, rel=0.1)
    # The faces meet all over the chamfer: the drawn contacts span most of its 4 mm.
    g = default_params().gearbox
    span = (max(contacts) - min(contacts)) / g.chamfer.travel_m
    assert len(contacts) >= 25 and span > 0.8, (len(contacts), span)


def _peaks(speed_m_s: float, push_N: float) -> np.ndarray:
    base = default_params()
    driver = dataclasses.replace(base.driver, push_velocity_m_s=speed_m_s, push_force_N=push_N)
    p = dataclasses.replace(base, driver=driver)
    run = ShiftBatch([p] * 10, list(range(10))).run(1.2)
    peaks = np.array([f.engagement_peak_N for f in run.features])
    assert np.isfinite(peaks).all()
    return peaks


@pytest.mark.parametrize("speed_m_s", [0.25, 0.5, 1.0, 2.0])
def test_the_peak_varies_from_seed_to_seed_at_every_shift_speed(speed_m_s):
    # The peak's spread across 10 seeds at the preset's 78.5 N. Measured (issue 30): CV 0.27,
    # 0.18, 0.17, 0.15 at 0.25, 0.5, 1, 2 m/s. The issue asks for 0.2 at every speed, which this
    # model does not reach (DESIGN.md, issue 30): the knob's peak is the hand's answer to the
    # impact's speed, which where the faces meet hardly changes. Asserted: over 0.12 (9 equal
    # peaks and one gap-to-gap seed at 0.5 of them would give 0.15; 0.12 leaves room for
    # the contact peaks' own spread to go either way).
    peaks = _peaks(speed_m_s, 78.5)
    cv = peaks.std() / peaks.mean()
    assert cv > 0.12, (cv, peaks)


@pytest.mark.parametrize("speed_m_s", [1.0, 2.0])
def test_a_brisk_hard_push_no_longer_gives_the_same_peak_on_every_contact(speed_m_s):
    # The case, 120 N: before, the 9 seeds that met the chamfers gave 65.6-66.6 N at
    # 1 m/s (the contact always at x_teeth, the hand's force there the same); now 56-65 N at
    # 1 m/s and 78-85 N at 2 m/s. More than 5 N apart (1.0 N before at 1 m/s).
    peaks = _peaks(speed_m_s, 120.0)
    met = peaks[peaks > 0.8 * np.median(peaks)]  # the gap-to-gap seed is far below
    assert len(met) >= 8
    assert met.max() - met.min() > 5.0, met
