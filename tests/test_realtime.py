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
from carfeel.realtime.rendering import ShiftRenderer, default_scaling
from carfeel.realtime.safety import ForceLimiter, SafetyLimits
from carfeel.realtime.session import RealtimeRun, run_realtime
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


@pytest.mark.parametrize("mode", ["admittance", "impedance"])
def test_the_hpattern_on_the_virtual_device_matches_the_offline_run(mode):
    """Same sequence, same gears, every engagement through its synchronization."""
    sequence = ("N", "1", "2", "3", "2", "N")
    offline = drive(sequence, speed_kmh=30.0)
    online = run_realtime(
        RealtimeRun(model="hpattern", mode=mode, clock="simulated", sequence=sequence)
    )
    assert online.summary.gears == engaged(offline) == ["1", "2", "3", "2"]
    assert online.summary.faults == []
    assert online.summary.overruns == 0  # simulated time: every period exact


def test_the_plateau_and_the_filtered_force_as_the_paper_measured(tmp_path):
    """Admittance as the paper: the hand's force comes from the servo's effort; through the
    20 Hz low-pass the synchronization plateau reads the driver's F_max (within 10 %: the
    virtual potentiometer's noise and the servo's own dynamics)."""
    record = tmp_path / "adm.csv"
    run_realtime(RealtimeRun(model="shift", mode="admittance", clock="simulated", record=record))
    result = Result.from_csv(record)
    sync = result["stage"] == "synchronization"
    assert sync.sum() > 250
    plateau = np.median(result["force_filtered_N"][sync])
    assert plateau == pytest.approx(load_shift().params.driver.push_force_N, rel=0.1)
    # The filtered force is smoother than the raw estimate (the reason the paper filtered it):
    # the potentiometer's noise through the servo's stiffness makes sample-to-sample jumps of
    # about 1 N; the 20 Hz low-pass takes away more than half of them.
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


def shift_loop(device, duration_s=1.0, clock=None):
    gear = load_shift().params
    scaling = default_scaling(100.0, 0.045, device.info)
    renderer = ShiftRenderer(gear.gearbox, "impedance", scaling, 1000.0)
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


def test_a_stop_request_zeroes_the_force_first():
    device = virtual_joystick(hand_for(virtual_joystick()))
    gear = load_shift().params
    scaling = default_scaling(100.0, 0.045, device.info)
    renderer = ShiftRenderer(gear.gearbox, "impedance", scaling, 1000.0)
    ticks = [0]

    def stop() -> bool:
        ticks[0] += 1
        return ticks[0] > 300

    with device:
        summary = run_loop(renderer, device, SimulatedClock(), LoopConfig(1000.0, 5.0, False),
                           LIMITS, should_stop=stop)  # fmt: skip
        last_command = device._queue[-1][1]
    assert summary.stopped == "stopped"
    assert last_command == (0.0, 0.0)


def test_the_recording_is_readable_after_a_kill(tmp_path):
    record = tmp_path / "killed.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "carfeel.cli", "run", "--clock", "simulated", "--duration",
         "600", "--record", str(record)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            if record.exists() and record.stat().st_size > 200_000:
                break
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    result = Result.from_csv(record, drop_partial_last_line=True)
    assert len(result) >= 500
    assert np.all(np.diff(result.time_s) > 0)
    meta = json.loads(record.with_suffix(".json").read_text())
    assert meta["model"] == "hpattern" and meta["force_scale"] > 0


def test_sigint_stops_a_real_time_run_cleanly():
    proc = subprocess.Popen(
        [sys.executable, "-m", "carfeel.cli", "run", "--model", "shift", "--duration", "60",
         "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    time.sleep(1.5)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    summary = json.loads(out)
    assert summary["stopped"] == "stopped"
    assert 0 < summary["periods"] < 60_000


def test_a_recording_replays_through_the_loop(tmp_path):
    record = tmp_path / "rec.csv"
    run_realtime(RealtimeRun(model="shift", clock="simulated", record=record, duration_s=1.5))
    replayed = run_realtime(
        RealtimeRun(model="shift", device=f"replay:{record}", clock="simulated",
                    calibrate=False, duration_s=1.0)
    )  # fmt: skip
    assert replayed.summary.faults == []
    assert replayed.summary.periods == 1000


def test_scales_are_recorded_with_the_run(tmp_path):
    record = tmp_path / "s.csv"
    result = run_realtime(RealtimeRun(model="steering", clock="simulated", record=record,
                                      duration_s=2.0))  # fmt: skip
    meta = json.loads(record.with_suffix(".json").read_text())
    assert meta["force_scale"] == pytest.approx(result.scaling.force_scale)
    assert meta["summary"]["periods"] == 2000


def test_devices_with_nothing_attached_says_so(capsys):
    assert main(["devices"]) == 0
    text = capsys.readouterr().out
    assert "evdev" in text and "SDL2" in text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--model", "steering", "--mode", "admittance"], "use --mode impedance"),
        (["--device", "joystick9"], "expected virtual, evdev:PATH"),
        (["--device", "replay:/nonexistent.csv"], "no such recording"),
        (["--rate-hz", "50000"], "allowed 10 <= value <= 10000 Hz"),
        (["--device", "sdl:x"], "expected a joystick index"),
        (["--clock", "simulated", "--device", "sdl:0"], "needs a virtual or replay device"),
    ],
)
def test_bad_run_requests_exit_2(capsys, args, message):
    assert main(["run", *args]) == 2
    assert message in capsys.readouterr().err


def test_model_substeps_run_inside_each_tick():
    """1 kHz loop, 10 kHz model: the same gears; and the 10 kHz ceiling is enforced."""
    result = run_realtime(
        RealtimeRun(model="hpattern", mode="impedance", clock="simulated", substeps=10,
                    sequence=("N", "1", "2", "N"))
    )  # fmt: skip
    assert result.summary.gears == ["1", "2"]
    assert main(["run", "--substeps", "20"]) == 2
