"""The synchronizer's ring on the device (issue 30): a wall that holds, sized for the device's
uncertainty with the pushing hand on it, beside the coupling alone (the rendering before it)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from carfeel.io.presets import load_shift
from carfeel.realtime import building, stability
from carfeel.realtime.clock import SimulatedClock
from carfeel.realtime.devices.virtual import virtual_device
from carfeel.realtime.hands import ReleasingHand, ShiftHand
from carfeel.realtime.loop import LoopConfig, run_loop
from carfeel.realtime.rendering import (
    Gains,
    ShiftRenderer,
    default_scaling,
    ring_wall,
    velocity_sections,
)
from carfeel.realtime.safety import SafetyLimits
from carfeel.realtime.session import RealtimeRun, run_realtime
from carfeel.simulation.result import Result
from carfeel.simulation.shift import simulate_shift

SECTIONS = velocity_sections(1000.0)


def offline_plateau_N() -> float:
    result = simulate_shift(load_shift().params)
    sync = np.asarray(result["stage"]) == "synchronization"
    return float(np.median(np.asarray(result["force_N"], dtype=float)[sync]))


def plateau(tmp_path, monkeypatch, device: str, mode: str, wall: bool):
    """(travel over the block, travel over its middle half (device m), the hand's force over
    the middle half (N), the run's summary)."""
    record = tmp_path / f"{device.replace(':', '_')}-{mode}-{wall}.csv"
    with monkeypatch.context() as patch:
        if not wall:  # the session as it was: the coupling (or servo) holds the ring
            patch.setattr(building, "ring_wall", lambda *args: None)
        result = run_realtime(
            RealtimeRun(model="shift", mode=mode, clock="simulated", record=record,
                        device=device)
        )  # fmt: skip
    rec = Result.from_csv(record)
    sync = np.flatnonzero(np.asarray(rec["stage"]) == "synchronization")
    x = np.asarray(rec["x_device"], dtype=float)[sync]
    force = np.asarray(rec["force_N"], dtype=float)[sync]
    middle = slice(len(sync) // 4, 3 * len(sync) // 4)
    return float(np.ptp(x)), float(np.ptp(x[middle])), force[middle], result.summary


@pytest.mark.parametrize("mode", ["impedance", "admittance"])
@pytest.mark.parametrize("device", ["virtual:joystick", "virtual:shifter"])
@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_ring_holds_the_knob_still_and_the_push_at_the_plateau(
    device, mode, tmp_path, monkeypatch
):
    """At the default delay (2 ms each way), the device identified afresh: over the middle half
    of the block the handle moves at most a third of what it moved on the coupling alone
    (measured 0.05-0.11 of it), and over the whole block, where the hand's arrival is, 0.3 of
    it and at most the issue's third of its 12-14 mm, 4.67 mm (measured 0.17-0.25, 2.9-4.4 mm).
    Before the wall took over the push the servo's damper held at the arrival, the shifter in
    admittance travelled 6.1-6.2 mm (0.35 of it), and before the feed-forward 7.8-7.9 mm, so
    the bound fails on either. The hand's force
    over the middle half stays within +-15 % of the offline plateau (the issue's bound;
    measured 72-81 N against 78.3 N), where on the coupling alone it is not (45-55 N at its
    10th percentile): the check fails on the old rendering, so it can fail."""
    reference = offline_plateau_N()
    whole, middle, force, summary = plateau(tmp_path, monkeypatch, device, mode, wall=True)
    old_whole, old_middle, old_force, old_summary = plateau(
        tmp_path, monkeypatch, device, mode, wall=False
    )
    assert summary.faults == [] and summary.gears == ["1"]
    assert old_summary.gears == ["1"]
    assert middle <= old_middle / 3.0
    assert whole <= min(0.3 * old_whole, 0.014 / 3.0)  # m
    # The 10th and 90th percentiles: the potentiometer's noise through the stiff wall puts
    # single-sample spikes of a few N on the estimate that a hand does not feel as the push.
    low, high = np.percentile(force, [10, 90])
    assert 0.85 * reference <= low and high <= 1.15 * reference
    assert np.percentile(old_force, 10) < 0.85 * reference


def identified_info(kind: str):
    """The device's info as an identification at start-up finds it (with its uncertainty)."""
    found = []
    original = stability.size

    def spy(info, *rest):
        found.append(info)
        return original(info, *rest)

    setattr(stability, "size", spy)  # noqa: B010 (a spy in place of the cached function)
    try:
        run_realtime(RealtimeRun(model="shift", clock="simulated", device=f"virtual:{kind}",
                                 duration_s=0.05))  # fmt: skip
    finally:
        setattr(stability, "size", original)  # noqa: B010
    return found[-1]


@pytest.mark.parametrize("kind", ["joystick", "shifter"])
def test_every_piece_of_the_wall_is_stable_inside_its_pushes(kind):
    """Each piece was sized at its two ends: the damping ratio at pushes inside it (the thirds,
    not sized) with the preset's hand on every plant of the set and the piece's feed-forward
    acting holds ZETA_MIN (within 0.03: between its ends the hand's damping moves the loop's
    poles smoothly), and hands off the first piece holds it too. Every piece has the
    feed-forward on these devices. The wall rises monotonically, continuous at its corners."""
    info = identified_info(kind)
    shift = load_shift().params
    scaling = default_scaling(100.0, shift.gearbox.in_gear_position_m + 0.005, info)
    wall = ring_wall(info, 1000.0, scaling, shift.driver)
    sized = stability.size(info, 1000.0, SECTIONS)
    base = stability.plant_set(info, 1000.0, SECTIONS)
    assert wall.integrals == (stability.RING_FEED_FORWARD_S,) * len(wall.dampings)
    assert wall.pushing_on > 0.0  # the session's wall knows the device's noise
    assert wall.pushing_on == pytest.approx(stability.reading_noise(info, 1000.0)[1])
    first = stability.zeta_of(
        base, wall.forces[1] / wall.stretches[1], wall.dampings[0], wall.integrals[0]
    )
    assert first >= stability.ZETA_MIN - 1e-6
    assert all(np.diff(wall.stretches) > 0.0) and all(np.diff(wall.forces) > 0.0)
    for x, f in zip(wall.stretches, wall.forces, strict=True):
        assert wall.force(x, 0.0) == pytest.approx(f, abs=1e-9)
    fs, ps = scaling.force_scale, scaling.position_scale
    d = shift.driver
    hand = (d.hand_mass_kg * fs / ps, d.hand_stiffness_N_m * fs / ps,
            d.hand_damping_N_s_m * fs / ps)  # fmt: skip
    stiffer = 0
    for i in range(1, len(wall.dampings)):  # the first piece holds hands off: tested above
        k = (wall.forces[i + 1] - wall.forces[i]) / (wall.stretches[i + 1] - wall.stretches[i])
        stiffer += k > 1.5 * sized.stiffness
        for third in (1.0 / 3.0, 2.0 / 3.0):
            push = wall.forces[i] + third * (wall.forces[i + 1] - wall.forces[i])
            grip = (*hand, push / (d.push_velocity_m_s * ps))
            plants = tuple(dataclasses.replace(a, hand=grip) for a in base)
            zeta = stability.zeta_of(plants, k, wall.dampings[i], wall.integrals[i])
            assert zeta >= stability.ZETA_MIN - 0.03, (i, push, zeta)
    assert stiffer >= 3  # the point of it: most pieces well beyond the coupling


def test_a_hand_on_the_handle_is_a_second_body_of_the_loop():
    """The hand's discretization: a grip so stiff it is rigid and no muscle make the hand's
    mass the device's (the damping ratio of a spring on it as on the heavier device alone,
    within 0.01: the grip's own fast mode); a muscle's damping on the hand's mass damps the
    handle through the grip (more damping than the bare device)."""
    info = identified_info("joystick")
    axis = stability.AxisLoop.of(info, 1000.0, SECTIONS)
    k = 300.0
    heavier = dataclasses.replace(axis, mass=axis.mass + 0.05)
    rigid = dataclasses.replace(axis, hand=(0.05, 2e5, 50.0, 0.0))
    assert stability.zeta_of(rigid, k, 0.5) == pytest.approx(
        stability.zeta_of(heavier, k, 0.5), abs=0.01
    )
    muscle = dataclasses.replace(axis, hand=(0.05, 2e3, 5.0, 10.0))
    assert stability.zeta_of(muscle, k, 0.5) > stability.zeta_of(heavier, k, 0.5) + 0.05


@pytest.mark.parametrize("kind", ["joystick", "shifter"])
def test_a_hand_that_lets_go_against_the_ring_leaves_a_handle_at_rest(kind):
    """The wall is sized with the hand on; let go in the middle of the block (the hardest push,
    the wall at its stiffest), the ring lets go under its hold within a part of a swing and the
    coupling (sized hands off) brings the handle to rest: no fault, and the command over the
    last 0.5 s within 5 % of the limit peak to peak (the stability matrix's rule)."""
    shift = load_shift().params
    probe = virtual_device(kind)
    scaling = default_scaling(100.0, shift.gearbox.in_gear_position_m + 0.005, probe.info)
    renderer_box: list[ShiftRenderer] = []

    def in_the_block(t: float) -> bool:
        state = renderer_box[0].state
        return state.stage.value == "synchronization" and state.stage_time_s > 0.15

    hand = ReleasingHand(
        ShiftHand(shift.driver, scaling.force_scale, scaling.position_scale, 0.1), in_the_block
    )
    device = virtual_device(kind, hand)
    info = device.info
    sizing = stability.size(info, 1000.0, SECTIONS)
    renderer = ShiftRenderer(shift.gearbox, "impedance", scaling, 1000.0,
                             Gains.sized(sizing, scaling),
                             wall=ring_wall(info, 1000.0, scaling, shift.driver))  # fmt: skip
    renderer_box.append(renderer)
    limits = SafetyLimits(max_force=info.max_force, max_slew_per_s=200.0 * info.max_force)
    with device:
        summary = run_loop(renderer, device, SimulatedClock(), LoopConfig(1000.0, 2.0, False),
                           limits)  # fmt: skip
    assert hand.released_at_s is not None and summary.faults == []
    assert renderer.state.stage.value == "neutral"
    sent = [(t, f[0]) for t, f in device.sent if t >= 1.5]
    assert sent
    commands = np.array([f for _, f in sent])
    assert np.ptp(commands) <= 0.05 * info.max_force
    assert math.isfinite(float(commands[-1]))


def shift_with(kind: str, driver, walled: bool):
    """The shift on a virtual device with the hand `driver`, the wall sized for the preset's
    hand (or none): the loop's summary."""
    shift = load_shift().params
    probe = virtual_device(kind)
    scaling = default_scaling(100.0, shift.gearbox.in_gear_position_m + 0.005, probe.info)
    hand = ShiftHand(driver, scaling.force_scale, scaling.position_scale, 0.1)
    device = virtual_device(kind, hand)
    info = device.info
    sizing = stability.size(info, 1000.0, SECTIONS)
    wall = ring_wall(info, 1000.0, scaling, shift.driver) if walled else None
    renderer = ShiftRenderer(shift.gearbox, "impedance", scaling, 1000.0,
                             Gains.sized(sizing, scaling), wall=wall)  # fmt: skip
    limits = SafetyLimits(max_force=info.max_force, max_slew_per_s=200.0 * info.max_force)
    with device:
        return run_loop(renderer, device, SimulatedClock(), LoopConfig(1000.0, 2.0, False),
                        limits)  # fmt: skip


@pytest.mark.parametrize(
    ("speed", "damping", "grip"), [(4.0, 0.25, 1.0), (1.0, 0.25, 3.0), (2.0, 0.5, 0.3)]
)
@pytest.mark.parametrize("kind", ["joystick", "shifter"])
def test_a_hand_unlike_the_one_the_wall_was_sized_for(kind, speed, damping, grip):
    """The wall is sized for the preset's hand; a driver's hand with 4x the muscle's V0 (a
    quarter of its damping per newton), a quarter of the grip's damping, a grip 3x as stiff or
    a third as stiff: no fault, and every gear the coupling alone engages (some of these hands
    do not finish the shift in 2 s on either rendering; the brisk, lightly damped one on the
    joystick does only on the wall)."""
    base = load_shift().params.driver
    driver = dataclasses.replace(
        base,
        push_velocity_m_s=speed * base.push_velocity_m_s,
        hand_damping_N_s_m=damping * base.hand_damping_N_s_m,
        hand_stiffness_N_m=grip * base.hand_stiffness_N_m,
    )
    walled = shift_with(kind, driver, walled=True)
    assert walled.faults == []
    coupled = shift_with(kind, driver, walled=False).gears
    assert walled.gears[: len(coupled)] == coupled


def hpattern_blocks(tmp_path, monkeypatch, device: str, mode: str, wall: bool):
    """Per synchronization block of N,1,2,3,2,N: the handle's x travel (device m) and the
    median x force over its middle half (N); and the run's gears and faults."""
    record = tmp_path / f"hp-{device.replace(':', '_')}-{mode}-{wall}.csv"
    with monkeypatch.context() as patch:
        if not wall:
            patch.setattr(building, "ring_wall", lambda *args: None)
        result = run_realtime(
            RealtimeRun(model="hpattern", mode=mode, clock="simulated", record=record,
                        device=device, sequence=("N", "1", "2", "3", "2", "N"))
        )  # fmt: skip
    rec = Result.from_csv(record)
    x = np.asarray(rec["x_device"], dtype=float)
    force = np.abs(np.asarray(rec["force_x_N"], dtype=float))
    index = np.flatnonzero(np.asarray(rec["stage"]) == "synchronization")
    blocks = [b for b in np.split(index, np.flatnonzero(np.diff(index) > 1) + 1) if len(b) > 50]
    travel = [float(np.ptp(x[b])) for b in blocks]
    middle = [float(np.median(force[b[len(b) // 4 : 3 * len(b) // 4]])) for b in blocks]
    return travel, middle, result.summary


@pytest.mark.parametrize(
    ("device", "mode"), [("virtual:joystick", "impedance"), ("virtual:shifter", "admittance")]
)
@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_hpattern_s_ring_holds_on_the_device(device, mode, tmp_path, monkeypatch):
    """The H-pattern's x axis on the same wall: each of the four blocks travels at most half of
    what it did on the coupling alone (measured 0.20 and 0.44 of it), the median push over its
    middle half within 15 % of the offline plateau (74-75 N against 78.3; 57-64 N before, so
    the check fails without the wall), the same gears and no fault."""
    reference = offline_plateau_N()
    travel, middle, summary = hpattern_blocks(tmp_path, monkeypatch, device, mode, wall=True)
    old_travel, old_middle, old_summary = hpattern_blocks(
        tmp_path, monkeypatch, device, mode, wall=False
    )
    assert summary.faults == [] and summary.gears == old_summary.gears == ["1", "2", "3", "2"]
    assert len(travel) == len(old_travel) == 4
    assert max(travel) <= 0.5 * min(old_travel)
    assert all(abs(m / reference - 1.0) <= 0.15 for m in middle)
    assert not all(abs(m / reference - 1.0) <= 0.15 for m in old_middle)


@pytest.mark.parametrize("kind", ["joystick", "shifter"])
def test_the_ring_takes_over_from_the_coupling_without_a_step(kind):
    """A hand that pushed against a cue wall reaches the ring with the handle already past the
    lever by the coupling's stretch. The ring's first tick holds what the coupling held (no
    kick back: the kick bounced the hand and limit-cycled the H-pattern at 31 Hz once the
    game's refusal faded), and a further push stretches the wall by its own stiffness."""
    from carfeel.realtime.rendering import RingHold

    info = identified_info(kind)
    shift = load_shift().params
    scaling = default_scaling(100.0, shift.gearbox.in_gear_position_m + 0.005, info)
    wall = ring_wall(info, 1000.0, scaling, shift.driver)
    coupling = Gains.sized(stability.size(info, 1000.0, SECTIONS), scaling).servo_stiffness
    stretch = 0.35 * info.max_force / coupling  # the coupling holding 35 %: inside a piece
    hold = RingHold(wall, coupling)
    first = hold.block(stretch, 0.0, 0.001)
    assert first == pytest.approx(coupling * stretch, rel=1e-9)  # the same force: no step
    assert wall.force(stretch, 0.0) > 1.5 * first  # the step the old wall gave (stiffer)
    more = 1e-4  # m: 0.1 mm further
    k = (hold.block(stretch + more, 0.0, 0.001) - first) / more
    piece = wall.piece(wall.stretch_for(first))
    slope = (wall.forces[piece + 1] - wall.forces[piece]) / (
        wall.stretches[piece + 1] - wall.stretches[piece]
    )
    assert k == pytest.approx(slope, rel=1e-6)  # the wall's stiffness from there on
    hold.fade(0.001)  # let go: the next block measures afresh
    assert hold.block(0.0, 0.0, 0.001) == 0.0


def test_a_handle_arriving_on_the_ring_keeps_the_push_its_damper_held():
    """A handle that reaches the ring moving was held partly by the coupling's (in admittance
    the servo's) damper: the wall's spring takes that share over, so it does not vanish as the
    handle stops (the block's travel on the shifter in admittance: 6.1-6.2 mm before, 5.1 mm
    with this take-over alone, seed 0); the wall's damper acts on the arrival on top. A
    handle moving back off the ring gets only the spring's share, as before (no kick out)."""
    from carfeel.realtime.rendering import RingHold
    from carfeel.realtime.stability import RingWall

    wall = RingWall((0.0, 0.01, 0.02), (0.0, 5.0, 12.0), (3.0, 3.0), (0.0, 0.0))  # no f-f
    coupling, stretch, v, b = 200.0, 0.002, 0.2, 10.0  # N/m, m, m/s, N*s/m
    arriving = RingHold(wall, coupling)
    first = arriving.block(stretch, v, 0.001, damped=b * v)
    spring = coupling * stretch + b * v  # 0.4 N + 2.0 N
    assert wall.force(stretch - arriving.offset, 0.0) == pytest.approx(spring, rel=1e-9)
    assert first == pytest.approx(spring + 3.0 * v, rel=1e-9)  # the wall's damper on top
    leaving = RingHold(wall, coupling)
    leaving.block(stretch, -v, 0.001, damped=-b * v)
    assert wall.force(stretch - leaving.offset, 0.0) == pytest.approx(coupling * stretch)


def test_the_feed_forward_stops_where_the_device_cannot_render_the_wall():
    """Past the wall's last piece (the device's force limit) the renderer's force is clipped,
    so a zero moving on there would wind up the push the model is given (found with the force
    still ramping in: 450 N estimated against the 5 N the joystick rendered, and at 0.1 s a
    4 Hz swing once the gate opened). The zero stands there; within the wall it moves."""
    from carfeel.realtime.rendering import RingHold
    from carfeel.realtime.stability import RingWall

    wall = RingWall((0.0, 0.01, 0.02), (0.0, 5.0, 12.0), (0.0, 0.0), (0.1, 0.1))
    beyond = RingHold(wall, 0.0)
    for _ in range(100):
        beyond.block(0.025, 0.05, 0.001)
    assert beyond.offset == 0.0
    within = RingHold(wall, 0.0)
    within.block(0.015, 0.05, 0.001)
    assert within.offset == pytest.approx(-0.015 * 0.001 / 0.1)


def test_the_feed_forward_moves_only_while_the_handle_pushes_on():
    """The wall's zero moves back by the stretch over the piece's time constant while the
    handle moves on into the wall (its velocity reading forward beyond the reading's noise),
    and never otherwise: a handle that stands, gives way or trembles at rest is not pulled
    back, a handle behind the blocked position is not chased, and a wall without a
    feed-forward keeps its zero. A hand whose push rises to 8 N ends the 0.3 s block nearer
    the blocked position than on the springs alone (the point: the push stands nearer the
    blocked position), and stays there."""
    from carfeel.realtime.rendering import RingHold
    from carfeel.realtime.stability import RingWall

    wall = RingWall((0.0, 0.01, 0.02), (0.0, 5.0, 12.0), (0.0, 0.0), (0.2, 0.2))
    hold = RingHold(wall, 0.0)
    hold.block(0.004, 0.0, 0.001)
    assert hold.offset == 0.0  # standing: no change
    hold.block(0.004, -0.05, 0.001)
    assert hold.offset == 0.0  # giving way: no change
    hold.block(-0.001, 0.05, 0.001)
    assert hold.offset == 0.0  # behind the blocked position: not chased
    hold.block(0.004, 0.05, 0.001)
    assert hold.offset == pytest.approx(-0.004 * 0.001 / 0.2)  # pushing on: moves back
    noisy = RingHold(dataclasses.replace(wall, pushing_on=0.01), 0.0)
    noisy.block(0.004, 0.0099, 0.001)
    assert noisy.offset == 0.0  # forward, but within the reading's noise: no change
    noisy.block(0.004, 0.0101, 0.001)
    assert noisy.offset < 0.0
    plain = RingHold(dataclasses.replace(wall, integrals=()), 0.0)
    plain.block(0.004, 0.05, 0.001)
    assert plain.offset == 0.0

    def settle(hold: RingHold, ticks: int) -> float:
        """Where a first-order hand (it moves on at 10 mm/s per N of surplus) pushing up to
        8 N over 0.1 s stands after `ticks` ms, past the blocked position (m)."""
        x = v = 0.0
        for i in range(ticks):
            push = min(8.0, 8.0 * i / 100)
            v = 0.01 * (push - hold.block(x, v, 0.001))
            x += v * 0.001
        return x

    springs = settle(RingHold(dataclasses.replace(wall, integrals=()), 0.0), 300)
    fed = settle(RingHold(wall, 0.0), 300)
    assert fed < 0.8 * springs  # measured 8.2 mm against 11.3 (0.73)
    # Once the handle stands the zero stands too: no creep back or on (measured 0.04 mm).
    assert settle(RingHold(wall, 0.0), 1000) == pytest.approx(fed, abs=1e-4)
