"""The haptic loop in simulated time: rendering, safety, recording, on the virtual devices."""

from __future__ import annotations

import itertools
import json
import math
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carfeel.cli import main
from carfeel.io.presets import load_shift
from carfeel.realtime.clock import SimulatedClock
from carfeel.realtime.devices.virtual import virtual_joystick
from carfeel.realtime.filters import butterworth, butterworth_sections
from carfeel.realtime.hands import ShiftHand
from carfeel.realtime.loop import LoopConfig, run_loop
from carfeel.realtime.rendering import Gains, ShiftRenderer, default_scaling, velocity_sections
from carfeel.realtime.safety import ForceLimiter, SafetyLimits
from carfeel.realtime.session import RealtimeRun, run_realtime
from carfeel.realtime.stability import size
from carfeel.simulation.result import Result
from tests.test_hpattern import drive, engaged


def test_the_display_filter_matches_scipy():
    from scipy.signal import sosfilt

    rng = np.random.default_rng(1)
    x = rng.normal(0.0, 10.0, 5000) + 78.5 * (np.arange(5000) > 1000)
    filt = butterworth(20.0, 1000.0)
    ours = np.array([filt.step(float(v)) for v in x])
    sections = butterworth_sections(20.0, 1000.0)
    sos = np.array([[b0, b1, b2, 1.0, a1, a2] for b0, b1, b2, a1, a2 in sections])
    # The same arithmetic in the same order: equal to rounding.
    assert np.max(np.abs(ours - sosfilt(sos, x))) < 1e-9


LIMITS = SafetyLimits(max_force=10.0, max_slew_per_s=2000.0)


@settings(max_examples=200, deadline=None)
@given(
    commands=st.lists(
        st.tuples(
            st.floats(allow_nan=True, allow_infinity=True),
            st.floats(allow_nan=True, allow_infinity=True),
        ),
        min_size=1,
        max_size=200,
    ),
    dt=st.sampled_from([1e-4, 1e-3, 2e-3]),
)
def test_the_limiter_never_exceeds_the_force_or_the_slew(commands, dt):
    limiter = ForceLimiter(LIMITS, 2)
    last: tuple[float, ...] = (0.0, 0.0)
    for command in commands:
        out = limiter.limit(command, dt)
        for value, before in zip(out, last, strict=True):
            assert math.isfinite(value)
            assert abs(value) <= LIMITS.max_force
            assert abs(value - before) <= LIMITS.max_slew_per_s * dt * (1 + 1e-12)
        last = out


def stages_per_engagement(stages, events) -> list[list[str]]:
    """The stages the lever went through on its way into each gear, in order, without repeats."""
    out: list[list[str]] = []
    path: list[str] = []
    for stage, event in zip(stages, events, strict=True):
        if not path or path[-1] != stage:
            path.append(stage)
        if str(event).startswith("engage"):
            out.append([s for s in path if s != "neutral"][-5:])
            path = []
    return out


@pytest.mark.parametrize("mode", ["admittance", "impedance"])
@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_hpattern_on_the_virtual_device_matches_the_offline_run(mode, tmp_path):
    """Same sequence, same gears, and each engagement through the same stages in the same
    order as offline (synchronization, the gate opening, the teeth, the stop), with the hand
    holding the device through a 2 ms each-way delay."""
    sequence = ("N", "1", "2", "3", "2", "N")
    offline = drive(sequence, speed_kmh=30.0)
    record = tmp_path / "online.csv"
    online = run_realtime(
        RealtimeRun(model="hpattern", mode=mode, clock="simulated", sequence=sequence,
                    record=record)
    )  # fmt: skip
    assert online.summary.gears == engaged(offline) == ["1", "2", "3", "2"]
    assert online.summary.faults == []
    rec = Result.from_csv(record)
    live = np.isfinite(np.asarray(rec["force_x_N"], dtype=float))
    ours = stages_per_engagement(rec["stage"][live], rec["event"][live])
    theirs = stages_per_engagement(offline["stage"], offline["event"])
    assert ours == theirs
    assert all("synchronization" in path for path in ours)


@pytest.mark.parametrize("mode", ["admittance", "impedance"])
def test_the_6r_lockout_the_physics_synchronizer_and_pulling_out_on_a_device(mode):
    """The cases the defaults never reach: the six-speed layout with reverse behind its lockout,
    the cone physics deciding when the gate opens, and the lever pulled out of each gear back
    to neutral, on the virtual shifter at the default delay."""
    sequence = ("N", "5", "6", "N", "R", "N")
    offline = drive(sequence, layout="6r", physics=True, speed_kmh=0.0)
    online = run_realtime(
        RealtimeRun(model="hpattern", mode=mode, clock="simulated", sequence=sequence,
                    preset="6r", synchronizer="physics", speed_kmh=0.0,
                    device="virtual:shifter")
    )  # fmt: skip
    assert online.summary.faults == []
    assert online.summary.gears == engaged(offline) == ["5", "6", "R"]


def test_the_plateau_and_the_filtered_force_as_the_paper_measured(tmp_path):
    """Admittance as the paper: the hand's force comes from the servo's effort. The paper's DSP
    rendered with no transport delay; the ring is rendered as a wall that stiffens with the
    push (issue 30), so with none and with 2 ms each way the synchronization plateau read
    through the 20 Hz low-pass settles near the driver's F_max: the last third of it within
    5 % (measured 1.7 % and 2.3 % under it: the wall's stretch still grows a little while the
    hand's muscle pushes against it, eq. 10; on the servo alone it was 5.8 % and 14.8 %, the
    handle sinking into it while the push builds, so the check fails without the wall). Both
    on the device identified afresh."""
    push = load_shift().params.driver.push_force_N
    for delay_ms, tolerance in ((0.0, 0.05), (2.0, 0.05)):
        record = tmp_path / f"adm{delay_ms:g}.csv"
        run_realtime(RealtimeRun(model="shift", mode="admittance", clock="simulated",
                                 record=record, device_delay_ms=delay_ms,
                                 identify="full"))  # fmt: skip
        result = Result.from_csv(record)
        sync = np.flatnonzero(result["stage"] == "synchronization")
        assert len(sync) > 250
        late = sync[2 * len(sync) // 3 :]
        assert np.median(result["force_filtered_N"][late]) == pytest.approx(push, rel=tolerance)
    # The filtered force is smoother than the raw estimate (the reason the paper filtered it).
    raw, smooth = result["force_N"][sync], result["force_filtered_N"][sync]
    assert np.std(np.diff(smooth)) < 0.5 * np.std(np.diff(raw))


def test_the_virtual_coupling_settles_in_gear_without_sustained_oscillation():
    """Energy check on the handle's true motion (not the noisy readings): once the lever is in
    gear and the hand has let go, the handle's kinetic energy dies down and stays down."""
    device = virtual_joystick(hand_for(virtual_joystick()))
    summary = shift_loop(device, 3.5)
    assert summary.gears == ["1"] and summary.faults == []
    times = np.array([t for t, _, _ in device.log])
    x = np.array([p[0] for _, p, _ in device.log])
    speed = np.abs(np.diff(x)) / np.diff(times)
    mass = device.plant.mass
    energy = 0.5 * mass * speed**2
    late, last = times[1:] > 2.5, times[1:] > 3.0
    # The potentiometer's noise (50 um, 78 um steps) through the coupling keeps the handle
    # trembling by about 0.1 mm at 20 mm/s: some 20 uJ at the most. A limit cycle at the stop
    # (an unstable coupling) shakes it by millimetres at hundreds of mm/s: 10 mJ and more.
    # Under 0.2 mJ, and not growing, is a tremor, not an oscillation.
    assert energy[late].max() < 2e-4
    assert energy[last].mean() <= 2.0 * energy[late & ~last].mean() + 1e-12


def sized_renderer(device, rate_hz=1000.0, cls=ShiftRenderer):
    """The shift on a device, with the coupling sized for it as a session sizes it."""
    gear = load_shift().params
    scaling = default_scaling(100.0, 0.045, device.info)
    gains = Gains.sized(size(device.info, rate_hz, velocity_sections(rate_hz)), scaling)
    return cls(gear.gearbox, "impedance", scaling, rate_hz, gains)


def shift_loop(device, duration_s=1.0, clock=None):
    renderer = sized_renderer(device)
    limits = SafetyLimits(max_force=10.0, max_slew_per_s=2000.0, fade_s=0.05)
    with device:
        summary = run_loop(
            renderer, device, clock or SimulatedClock(), LoopConfig(1000.0, duration_s, False),
            limits,
        )  # fmt: skip
    return summary


def hand_for(scaling_device):
    gear = load_shift().params
    scaling = default_scaling(100.0, 0.045, scaling_device.info)
    return ShiftHand(gear.driver, scaling.force_scale, scaling.position_scale)


def faded_in_time(device, fault_at_s: float, fade_s: float = 0.05) -> None:
    """From the fault on, the commanded force only shrinks, and is zero within the fade (one
    tick of slack) and at the end."""
    after = [max(abs(v) for v in f) for t, f in device.sent if t >= fault_at_s]
    assert after
    assert all(b <= a + 1e-12 for a, b in itertools.pairwise(after))
    late = [max(abs(v) for v in f) for t, f in device.sent if t >= fault_at_s + fade_s + 1e-3]
    assert all(v == 0.0 for v in late)
    assert device.sent[-1][1] == (0.0, 0.0)


def test_a_stall_fades_the_force_to_zero():
    clock = SimulatedClock()
    clock.stall(at_ns=int(0.5e9), for_ns=int(0.03e9))  # a 30 ms stall at 0.5 s
    device = virtual_joystick(hand_for(virtual_joystick()))
    summary = shift_loop(device, 2.0, clock)
    assert any(f.startswith("stall") for f in summary.faults)
    assert summary.stopped == "fault"
    assert summary.overruns >= 1
    faded_in_time(device, 0.53)


def test_a_nan_reading_fades_the_force_to_zero():
    device = virtual_joystick(hand_for(virtual_joystick()), nan_at_s=0.4)
    summary = shift_loop(device, 2.0)
    assert any("nan" in f for f in summary.faults)
    assert summary.stopped == "fault"
    faded_in_time(device, 0.4)


def test_a_lost_device_stops_the_run():
    device = virtual_joystick(hand_for(virtual_joystick()), fail_at_s=0.6)
    summary = shift_loop(device, 2.0)
    assert any(f.startswith("device lost") for f in summary.faults)
    assert summary.stopped == "fault"
    assert summary.periods < 700


def test_a_stop_request_ramps_the_force_down_within_the_slew():
    """Stopped while the hand pushes the lever against the ring (several N commanded): the
    force comes down at the slew limit, tick by tick, before the loop returns; it does not
    jump to zero (the final zero of the loop's `finally` would hide a jump)."""
    device = virtual_joystick(hand_for(virtual_joystick()))
    renderer = sized_renderer(device)
    ticks = [0]

    def stop() -> bool:
        ticks[0] += 1
        return ticks[0] > 300

    with device:
        summary = run_loop(renderer, device, SimulatedClock(), LoopConfig(1000.0, 5.0, False),
                           LIMITS, should_stop=stop)  # fmt: skip
    assert summary.stopped == "stopped"
    at_stop = device.sent[299][1][0]
    assert abs(at_stop) > 2.0  # a real force to take away (2 N per tick at this slew)
    ramp = [f[0] for _, f in device.sent[299:]]
    step = LIMITS.max_slew_per_s * 1e-3
    assert all(abs(b - a) <= step * (1 + 1e-9) for a, b in itertools.pairwise(ramp))
    assert len([f for f in ramp if f != 0.0]) >= 2
    assert ramp[-1] == 0.0


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
@pytest.mark.posix_only  # SIGKILL
def test_the_recording_is_readable_after_a_kill(tmp_path):
    """Killed mid-run: the recording so far is readable as NAME.part.csv, and what the user
    had at NAME.csv before is untouched."""
    record = tmp_path / "killed.csv"
    record.write_text("precious\n")
    part = tmp_path / "killed.part.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "carfeel.cli", "run", "--clock", "simulated", "--duration",
         "600", "--record", str(record)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            if part.exists() and part.stat().st_size > 200_000:
                break
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    result = Result.from_csv(part, drop_partial_last_line=True)
    assert len(result) >= 500
    assert np.all(np.diff(result.time_s) > 0)
    meta = json.loads(part.with_suffix(".json").read_text())
    assert meta["model"] == "hpattern" and meta["force_scale"] > 0
    assert record.read_text() == "precious\n"


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
@pytest.mark.posix_only  # SIGINT sent to a child
def test_sigint_stops_a_real_time_run_cleanly(tmp_path):
    """Ctrl-C in a wall-clock run: force first, the recording kept, exit 130. On these shared
    cores a run can meet a 20+ ms stall before the signal and end on its watchdog (exit 3, the
    safety chain doing its job, not what this test is about): such a run is tried again, at
    most three times, and any other outcome fails at once."""
    for attempt in range(3):
        record = tmp_path / f"sig{attempt}.csv"
        proc = subprocess.Popen(
            [sys.executable, "-m", "carfeel.cli", "run", "--model", "shift", "--duration", "60",
             "--record", str(record)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert proc.stdout is not None
        proc.stdout.readline()  # the start line: the handlers are in place once the loop runs
        deadline = time.monotonic() + 30.0
        part = tmp_path / f"sig{attempt}.part.csv"  # the recording while the run goes
        while not part.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        stalled = proc.returncode == 3 and "stall:" in out + err and "SIGINT" not in out
        if not stalled:
            break
    assert proc.returncode == 130, out + err  # the shell's 128 + SIGINT
    assert "stopped by SIGINT" in out
    meta = json.loads(record.with_suffix(".json").read_text())
    assert meta["summary"]["stopped"] == "SIGINT"
    assert 0 < meta["summary"]["periods"] < 60_000


def test_a_recording_replays_through_the_loop(tmp_path):
    """Replaying a run's handle positions through the same model gives the same commands."""
    record, again = tmp_path / "rec.csv", tmp_path / "again.csv"
    run_realtime(RealtimeRun(model="shift", clock="simulated", record=record, duration_s=1.5,
                             calibrate=False))  # fmt: skip
    replayed = run_realtime(
        RealtimeRun(model="shift", device=f"replay:{record}", clock="simulated",
                    calibrate=False, duration_s=1.5, record=again)
    )  # fmt: skip
    assert replayed.summary.faults == []
    first, second = Result.from_csv(record), Result.from_csv(again)
    # All of it: a replay that stops early is not a replay.
    assert replayed.summary.periods == 1500
    n = min(len(first), len(second))
    assert n >= 1500
    # The model sees the same readings at the same ticks: the same forces, to CSV rounding.
    assert np.allclose(first["command_0"][:n], second["command_0"][:n], atol=1e-6)
    assert list(first["stage"][:n]) == list(second["stage"][:n])


def test_scales_follow_the_device_and_are_recorded(tmp_path):
    """90 % of the device's force for the model's 100 N (or 10 Nm); all its travel."""
    record = tmp_path / "s.csv"
    result = run_realtime(RealtimeRun(model="steering", clock="simulated", record=record,
                                      duration_s=2.0))  # fmt: skip
    assert result.scaling.force_scale == pytest.approx(0.9 * 4.0 / 10.0)  # the 4 Nm wheel
    meta = json.loads(record.with_suffix(".json").read_text())
    assert meta["force_scale"] == pytest.approx(0.36)
    assert meta["summary"]["periods"] == 2000
    shift = run_realtime(RealtimeRun(model="shift", clock="simulated", duration_s=0.5))
    assert shift.scaling.force_scale == pytest.approx(0.9 * 10.0 / 100.0)  # the 10 N joystick
    assert shift.scaling.position_scale == pytest.approx(0.04 / 0.045)


def test_scales_come_from_a_real_device_s_limits(monkeypatch):
    """An evdev device of 3 N and 0.1 m (through the recorded fake): the scales follow it."""
    from tests.fakes import fake_evdev

    monkeypatch.setitem(sys.modules, "evdev", fake_evdev.FakeEvdev([fake_evdev.joystick()]))
    from carfeel.realtime import session

    device = session.open_device("evdev:/dev/input/event5", kind="joystick", max_force=3.0,
                                 travel=0.1)  # fmt: skip
    scaling = default_scaling(100.0, 0.045, device.info)
    assert scaling.force_scale == pytest.approx(0.027)
    assert scaling.position_scale == pytest.approx(0.1 / 0.045)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--model", "steering", "--mode", "admittance"], "use --mode impedance"),
        (["--device", "joystick9"], "expected virtual[:KIND], evdev:PATH"),
        (["--device", "virtual:wheel"], "needs one of virtual:joystick, virtual:shifter"),
        (["--model", "steering", "--device", "virtual:shifter"], "virtual:wheel, virtual:dd"),
        (["--device", "sdl:0", "--hand", "none"], "needs a virtual device"),
        (["--device-delay-ms", "100"], "allowed 0 <= value <= 50"),
        (["--device-report-hz", "20"], "allowed 100 <= value <= 10000"),
        (["--device-damping", "2"], "describe a real device"),
        # a real device's declared dynamics beyond any device (1e300 broke the sizing's algebra)
        (
            ["--device", "evdev:/dev/input/event5", "--device-damping", "1e300"],
            "allowed 0 < value <= 1000",
        ),
        (
            ["--device", "evdev:/dev/input/event5", "--device-mass", "1e300"],
            "allowed 0.0001 < value <= 50",
        ),
        (["--release-angle-deg", "0"], "allowed 0 < value <= 180"),
        (["--device", "replay:/nonexistent.csv"], "no such recording"),
        (["--rate-hz", "50000"], "allowed 250 <= value <= 10000 Hz"),
        (["--rate-hz", "40"], "allowed 250 <= value <= 10000 Hz"),
        (["--speed-kmh", "nan"], "allowed 0 <= value <= 250 km/h"),
        (["--clock", "simulated", "--sequence", "N,9"], "no gear 9 in layout 5r"),
        (["--device-max-force", "3"], "describe a real device"),
        (["--device", "sdl:x"], "expected a joystick index"),
        (["--clock", "simulated", "--device", "sdl:0"], "needs a virtual or replay device"),
    ],
)
def test_bad_run_requests_exit_2(capsys, args, message):
    assert main(["run", *args]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_model_substeps_run_inside_each_tick(tmp_path, monkeypatch):
    """1 kHz loop, 10 kHz model: every tick steps the model 10 times by a tenth of the tick
    (they add up to the tick, none is skipped or doubled), recoupled to the held handle between
    sub-steps (the coupling's force changes as the knob moves); the same gears as at 1 kHz but
    not the same run; and the 10 kHz ceiling is enforced. (The test before only asked that the
    two runs differ: any change passed it.)"""
    from carfeel.models.gearshift import hpattern as model

    steps: list[tuple[float, float]] = []
    real = model.step

    def spy(state, inputs, pattern, dt_s):
        steps.append((dt_s, inputs.force_x_N))
        return real(state, inputs, pattern, dt_s)

    monkeypatch.setattr(model, "step", spy)  # the module the renderer steps through
    runs = []
    for substeps in (1, 10):
        steps.clear()
        record = tmp_path / f"sub{substeps}.csv"
        result = run_realtime(
            RealtimeRun(model="hpattern", mode="impedance", clock="simulated",
                        substeps=substeps, sequence=("N", "1", "2", "N"), record=record)
        )  # fmt: skip
        assert result.summary.gears == ["1", "2"]
        table = Result.from_csv(record)
        runs.append(table)
        ticks = int(np.sum(~np.isnan(table["x_m"])))  # the model's ticks (not the end's ramp)
        assert len(steps) == substeps * ticks
        assert all(h == pytest.approx(1e-3 / substeps, rel=1e-12) for h, _ in steps)
        if substeps == 10:
            per_tick = [steps[i : i + 10] for i in range(0, len(steps), 10)]
            recoupled = sum(len({f for _, f in tick}) > 1 for tick in per_tick)
            # The force follows the knob within a tick wherever the knob moves: 1,612 of 7,020
            # ticks of this sequence (it rests in the others); held, it would be none.
            assert recoupled > 0.1 * ticks
    one, ten = runs
    n = min(len(one), len(ten))
    assert not np.array_equal(one["x_m"][:n], ten["x_m"][:n])
    assert main(["run", "--substeps", "20"]) == 2


class InvertedMotor:
    """A virtual joystick whose X motor pushes against its commands (a miswired device)."""

    def __init__(self, device):
        self.device, self.info = device, device.info

    def __enter__(self):
        self.device.__enter__()
        return self

    def __exit__(self, *exc):
        self.device.__exit__(*exc)

    def read(self, time_s):
        return self.device.read(time_s)

    def command(self, forces, time_s):
        self.device.command((-forces[0], *forces[1:]), time_s)


def test_calibration_finds_an_inverted_motor_and_the_run_works():
    device = virtual_joystick(hand_for(virtual_joystick()))
    wrong = InvertedMotor(device)
    renderer = sized_renderer(device)
    # The hand waits out the calibration and the ramp-in, as in a real session.
    device.hand.start_s = 1.3  # type: ignore[union-attr]
    with wrong:
        summary = run_loop(renderer, wrong, SimulatedClock(), LoopConfig(1000.0, 3.0, True),
                           LIMITS)  # fmt: skip
    assert any("axis 0 moved against its command" in n for n in summary.notes)
    assert summary.faults == []
    assert summary.gears == ["1"]


def test_calibration_pulses_respect_the_limiter():
    device = virtual_joystick()
    renderer = sized_renderer(device, 10_000.0)
    limits = SafetyLimits(max_force=10.0, max_slew_per_s=2000.0)
    with device:
        run_loop(renderer, device, SimulatedClock(), LoopConfig(10_000.0, 0.01, True), limits)
    steps = [abs(b[1][0] - a[1][0]) for a, b in itertools.pairwise(device.sent)]
    assert max(steps) <= 2000.0 * 1e-4 * (1 + 1e-9)
    # The pulses (2 x (10 + 100) ms before the loop) stay at a fifth of the limit.
    calibration = [abs(f[0]) for t, f in device.sent if t < 0.2199]
    assert len(calibration) > 2000
    assert max(calibration) <= 0.2 * 10.0 + 1e-12


def test_a_nan_force_from_the_model_is_a_fault():
    result = run_realtime(RealtimeRun(model="shift", clock="simulated", duration_s=2.0,
                                      preset=None, calibrate=False))  # fmt: skip
    assert result.summary.faults == []

    class Broken(ShiftRenderer):
        def tick(self, sample, dt_s):
            commands, row = super().tick(sample, dt_s)
            return ((math.nan, commands[1]) if sample.time_s > 0.5 else commands), row

    device = virtual_joystick(hand_for(virtual_joystick()))
    renderer = sized_renderer(device, cls=Broken)
    with device:
        summary = run_loop(renderer, device, SimulatedClock(), LoopConfig(1000.0, 2.0, False),
                           LIMITS)  # fmt: skip
    assert len(summary.faults) == 1 and "non-finite" in summary.faults[0]
    assert summary.stopped == "fault"
    faded_in_time(device, 0.5)


@settings(max_examples=100, deadline=None)
@given(
    commands=st.lists(st.floats(-50.0, 50.0), min_size=1, max_size=100),
    fade_at=st.integers(0, 100),
)
def test_the_limiter_holds_its_slew_through_a_fade(commands, fade_at):
    """The fade lowers the ceiling at max_force / fade_s, no faster than the slew allows."""
    limits = SafetyLimits(max_force=10.0, max_slew_per_s=10.0 / 0.05, fade_s=0.05)
    limiter = ForceLimiter(limits, 1)
    last, dt = 0.0, 1e-3
    for k, command in enumerate(commands):
        scale = 1.0 if k < fade_at else max(0.0, 1.0 - (k - fade_at + 1) * dt / limits.fade_s)
        (out,) = limiter.limit((command,), dt, scale)
        assert abs(out) <= limits.max_force * scale + 1e-12
        assert abs(out - last) <= limits.max_slew_per_s * dt * (1 + 1e-9)
        last = out
