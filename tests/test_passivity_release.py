"""The passivity controller and a hand that lets go of a stretched spring.

A hand that pushes a sized spring to near the device's force stores F^2 / 2K in it (0.25 J on the
shifter); let go, the spring gives it back. That energy came from the hand, so it is not the
rendering's generation: the controller must not cut the force for good (a handle left dead off
its rest) - and a rendering that does generate must still be cut. Simulated time, virtual
devices."""

from __future__ import annotations

import math

import pytest

from carfeel.realtime.clock import SimulatedClock
from carfeel.realtime.devices.base import DeviceSample
from carfeel.realtime.devices.virtual import PLANTS, virtual_device
from carfeel.realtime.loop import LoopConfig, run_loop
from carfeel.realtime.rendering import Reading, velocity_sections
from carfeel.realtime.safety import RECOVERY_S, PassivityController, SafetyLimits
from carfeel.realtime.stability import size


class Hold:
    """A spring and damper holding both axes at zero (device units), on the renderers' own
    reading (the velocity through their filter, which the sizing counts with)."""

    axes = 2
    columns: tuple[str, ...] = ("x",)
    substeps = 1
    effect = 0.0

    def __init__(self, stiffness: float, damping: float) -> None:
        self.k, self.b = stiffness, damping
        self.gears: list[str] = []
        self.rx, self.ry = Reading(1000.0), Reading(1000.0)

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        x, vx = self.rx.step(sample.positions[0], dt_s)
        y, vy = self.ry.step(sample.positions[1], dt_s)
        return (-self.k * x - self.b * vx, -self.k * y - self.b * vy), (x,)


class PushThenLetGo:
    """Pushes the first axis with `force` (device units) from `start_s` (once the safety
    chain's ramp-in has given the rendering all of the force), built up over RAMP_S as a
    muscle does, until `until_s`, then lets go in one tick."""

    RAMP_S = 0.2

    def __init__(self, force: float, start_s: float, until_s: float) -> None:
        self.force, self.start_s, self.until_s = force, start_s, until_s

    def forces(self, time_s, positions, velocities):
        if not self.start_s <= time_s < self.until_s:
            return (0.0, 0.0)
        return (self.force * min(1.0, (time_s - self.start_s) / self.RAMP_S), 0.0)


@pytest.mark.parametrize("kind", ["shifter", "joystick"])
def test_a_spring_let_go_at_full_stretch_comes_back_to_rest(kind):
    """Pushed to 90 % of the device's force (held for 0.5 s), then let go in one tick: the spring
    brings the handle back to its rest (within 1 % of the travel: a handle left where the
    controller cut the force stands mm off), and the force is not cut for good."""
    info = virtual_device(kind).info
    sizing = size(info, 1000.0, velocity_sections(1000.0))
    push = 0.9 * info.max_force
    limits = SafetyLimits(max_force=info.max_force, max_slew_per_s=2000.0, fade_s=0.05)
    hand = PushThenLetGo(push, limits.ramp_s, limits.ramp_s + 0.7)
    device = virtual_device(kind, hand)
    renderer = Hold(sizing.stiffness, sizing.damping)
    stored = push**2 / (2.0 * sizing.stiffness)
    assert stored > 0.05 * info.max_force * info.travel  # more than the controller's old ceiling
    config = LoopConfig(1000.0, limits.ramp_s + 2.5, calibrate=False)
    with device:
        summary = run_loop(renderer, device, SimulatedClock(), config, limits)
    assert summary.stopped == "duration" and not summary.faults
    x_end = device.true_positions[0]
    # At rest within what the device's Coulomb friction holds against the spring (twice its
    # dead band F_c / K: 0.4 mm on the shifter, 0.7 on the joystick); a handle the controller
    # left dead stood 41.9 mm off on the shifter.
    dead_band = PLANTS[kind][0].coulomb / sizing.stiffness
    assert abs(x_end) < 2.0 * dead_band, f"the handle stands {x_end * 1e3:.2f} mm off its rest"
    # The energy came from the hand: the controller does not act (a few ticks at most). With
    # the old ceiling (5 % of F * travel, under F^2 / 2K) it cut the force for 16-26 ms even
    # with the recovery, for good without it.
    assert summary.passivity_acted_s < 0.005


def test_a_cut_force_comes_back_over_the_recovery_time():
    """A rendering that put out 10 J more than it took in has its force cut; the handle then
    at rest does no work, and the force comes back, not never: the deficit decays toward the
    deadband with RECOVERY_S, so the force is back once it is under the band again, after
    RECOVERY_S * ln(deficit / band), and whole (98 %) four time constants later. Not sooner:
    the deficit is remembered whole (no floor), so a limit cycle the controller cut does not
    come straight back (the stability matrix's too-stiff loop stays at half its amplitude)."""
    pc = PassivityController(1, damping=0.0, deadband=0.001, ceiling=0.05)
    dt = 0.001
    pc.apply((10.0,), (0.0,), dt)
    pc.applied((10.0,))
    pc.apply((10.0,), (1.0,), dt)  # the rendering pushed the handle 1 m along: 10 J out
    pc.applied((10.0,))
    deficit = -pc.energy[0] - pc.deadband
    assert deficit == pytest.approx(10.0, rel=0.01)
    back_s = RECOVERY_S * math.log(deficit / pc.band)
    elapsed = 0.0

    def scale_at(time_s: float) -> float:
        nonlocal elapsed
        out = 0.0
        while elapsed < time_s - 1e-9:
            (out,) = pc.apply((10.0,), (1.0,), dt)  # the handle still: no work either way
            pc.applied((out,))
            elapsed += dt
        return out / 10.0

    assert scale_at(0.9 * back_s) == 0.0
    assert scale_at(1.1 * (back_s + 4.0 * RECOVERY_S)) > 0.98
