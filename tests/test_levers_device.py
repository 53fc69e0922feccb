"""The sequential lever and the PRND selector on a device (`carfeel run --model sequential|prnd`):
each shifts its script on each virtual device, also where the device is unlike what it tells;
the hand goes by what it feels; what a lever run cannot do is refused with the reason.

Simulated time, virtual devices identified at start-up (their profiles in the session's
CARFEEL_CONFIG_DIR, as a user's)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from carfeel.cli import main
from carfeel.commands import run as run_command
from carfeel.io.presets import load_sequential
from carfeel.models.gearshift import sequential as sq
from carfeel.realtime import run_options
from carfeel.realtime.levers import Controls, LeverHand, prnd_moves
from carfeel.simulation.result import Result

EXPECTED = {
    # up, up, down, down (1 to N without the lift: locked, the wall), lift-down to N and to R,
    # lift-down past R (locked), lift-up to N, up to 1.
    "sequential": ["1", "2", "1", "N", "R", "N", "1"],
    "prnd": ["R", "N", "D", "N", "R", "P"],
}


def run_lever(model: str, device: str, tmp_path, *extra: str) -> tuple[int, dict[str, Any], Any]:
    record = tmp_path / f"{model}.csv"
    code = main(["run", "--model", model, "--device", device, "--clock", "simulated",
                 "--record", str(record), *extra])  # fmt: skip
    meta = json.loads(record.with_suffix(".json").read_text()) if code == 0 else {}
    return code, meta, Result.from_csv(record) if code == 0 else None


def calm_at_the_end(meta: dict[str, Any], rec: Result) -> float:
    """The command's peak to peak over the last half second, as a share of the force limit."""
    command = np.asarray(rec["command_0"], dtype=float)
    live = np.isfinite(command) & np.isfinite(np.asarray(rec["force_N"], dtype=float))
    t = rec.time_s[live]
    last = t >= t[-1] - 0.5
    return float(np.ptp(command[live][last])) / float(meta["max_force"])


@pytest.mark.slow
@pytest.mark.parametrize("device", ["virtual:shifter", "virtual:joystick"])
@pytest.mark.parametrize("model", ["sequential", "prnd"])
def test_each_lever_shifts_its_script_on_each_virtual_device(model, device, tmp_path):
    """The default script, the hand pushing with the preset's force: every shift registers in
    order, the locked moves meet their walls without a fault, never at the force limit, and
    the command is calm at the end (under 5 % of the limit peak to peak: the ripple a hand
    would feel as buzz)."""
    code, meta, rec = run_lever(model, device, tmp_path)
    assert code == 0
    summary = meta["summary"]
    assert summary["faults"] == [] and summary["time_at_limit_s"] == 0.0
    assert summary["gears"] == EXPECTED[model]
    assert meta["model"] == model and meta["preset"] == run_options.DEFAULT_PRESETS[model]
    assert meta["sequence"] == ",".join(run_options.DEFAULT_SEQUENCES[model])
    assert calm_at_the_end(meta, rec) < 0.05
    if model == "sequential":  # the locked moves went into the walls, and no further
        depth = np.asarray(rec["wall_depth_m"], dtype=float)
        assert np.nanmax(depth) > 0.0
        lever = load_sequential().params.lever
        x = np.abs(np.asarray(rec["position_m"], dtype=float))
        locked = depth > 0.0
        assert np.nanmax(x[locked]) < lever.click_m - lever.click_width_m


@pytest.mark.slow
@pytest.mark.parametrize(
    ("model", "device"),
    [("sequential", "virtual:shifter:mass=0.6x,damping=0.5x"),
     ("sequential", "virtual:shifter:mass=1.5x,delay_ms=4"),
     ("prnd", "virtual:joystick:mass=0.7x"),
     ("prnd", "virtual:shifter:report_hz=250")],
)  # fmt: skip
def test_a_lever_on_a_device_unlike_its_declaration(model, device, tmp_path):
    """The true plant lighter and less damped, heavier and slower, or reporting at 250 Hz: the
    device is measured at start-up and the lever sized for what was measured. (The lighter,
    less damped shifter faulted at 5.7 Hz when the lever was let go from its lock wall, until
    the oscillation guard kept its energy account.)"""
    code, meta, rec = run_lever(model, device, tmp_path)
    assert code == 0
    assert meta["summary"]["faults"] == []
    assert meta["summary"]["gears"] == EXPECTED[model]
    assert calm_at_the_end(meta, rec) < 0.05


@pytest.mark.slow
def test_the_handle_leads_the_selector_by_more_than_half_a_pitch_on_the_joystick(tmp_path):
    """Why the hand goes by the registered position: on the joystick's soft coupling the handle
    stands more than half a detent's pitch ahead of the selector while the hand pushes (a hand
    that stopped once the handle reached the target's centre let go before D registered: R N R
    P was the run), and by what it feels the hand makes every shift."""
    code, meta, rec = run_lever("prnd", "virtual:joystick", tmp_path)
    assert code == 0
    lead = np.asarray(rec["x_device"], dtype=float) / meta["position_scale"] - np.asarray(
        rec["position_m"], dtype=float
    )
    pitch = 0.03  # automatic.toml's
    assert np.nanmax(np.abs(lead)) > 0.5 * pitch
    assert meta["summary"]["gears"] == EXPECTED["prnd"]


def test_the_hand_pushes_toward_its_target_until_it_feels_it():
    """Toward a target, the sense comes from the registered position along the selector's order,
    whatever the handle's reading; the push stops once the target registers, and a position the
    hand does not know (none yet) gets no push."""
    from carfeel.models.gearshift.prnd import PrndParams

    params = PrndParams()
    now = ["N"]
    hand = LeverHand(prnd_moves(params, (3,)), 25.0, 0.6, 0.4, 0.5, 2.0, Controls(),
                     registered=lambda: now[0], order=params.positions)  # fmt: skip
    far_past = (1.0, 0.0)  # the handle's reading beyond D: not what the hand goes by
    assert hand.forces(0.1, far_past, (0.0, 0.0))[0] == pytest.approx(25.0 * 0.5)
    now[0] = "D"
    assert hand.forces(0.2, far_past, (0.0, 0.0))[0] == 0.0
    now[0] = ""
    assert hand.forces(0.3, far_past, (0.0, 0.0))[0] == 0.0
    now[0] = "D"
    hand_back = LeverHand(prnd_moves(params, (0,)), 25.0, 0.6, 0.4, 0.5, 2.0, Controls(),
                          registered=lambda: now[0], order=params.positions)  # fmt: skip
    assert hand_back.forces(0.1, (-1.0, 0.0), (0.0, 0.0))[0] == pytest.approx(-25.0 * 0.5)
    assert hand.controls.button and hand.controls.brake  # P and R need them


def test_the_rally_preset_s_hand_gets_over_its_click():
    """The preset's hand must beat the click's peak with the spring there (rally-6: 50.8 N);
    a weaker hand (it was 45 N) gets over it offline only by its momentum, which a device's
    coupling takes: on both virtual devices it made no shift at all."""
    setup = load_sequential().params
    lever = setup.lever
    travel = np.linspace(0.0, lever.click_m, 2001)
    peak = max(-sq.mechanism_N(lever, s, 0.0) for s in travel)
    assert peak == pytest.approx(50.8, abs=0.1)
    assert setup.driver.hand_N > peak


@pytest.mark.parametrize(
    ("extra", "says"),
    [(["--model", "sequential", "--mode", "admittance"], "--mode impedance"),
     (["--model", "sequential", "--sequence", "up,sideways"], "'sideways' is not a move"),
     (["--model", "prnd", "--sequence", "R,X"], "'X' is not a position"),
     (["--model", "shift", "--telemetry", "carfeel:127.0.0.1:0"], "--telemetry drives"),
     (["--model", "shift", "--sequence", "up"], "--model shift has none")],
)  # fmt: skip
def test_what_a_lever_run_cannot_do_is_refused_with_the_reason(extra, says, tmp_path, capsys):
    """Exit 2, the reason named, no traceback, before the device is opened (no identification
    said), and the recording not started."""
    record = tmp_path / "r.csv"
    code = main(["run", *extra, "--clock", "simulated", "--record", str(record)])
    err = capsys.readouterr().err
    assert code == 2
    assert says in err and "Traceback" not in err
    assert "hands off" not in err  # refused before the device was opened
    assert not record.exists() and not record.with_suffix(".json").exists()


def test_the_command_line_offers_the_run_options_models_and_scripts():
    """The command line names its choices without importing the real-time package (its help
    stays quick); they are the run options' own."""
    assert run_command.MODELS == run_options.MODELS
    assert ",".join(run_options.DEFAULT_SEQUENCES["hpattern"]) == run_command.DEFAULT_SEQUENCE
    for model, text in run_command.LEVER_SEQUENCES.items():
        assert text == ",".join(run_options.DEFAULT_SEQUENCES[model])
    assert set(run_options.LEVER_MODELS) == set(run_command.LEVER_SEQUENCES)


@pytest.mark.slow
def test_the_readmes_lever_runs_do_what_they_say(tmp_path, monkeypatch):
    """The manual's `carfeel run --model sequential|prnd` lines without a game (on the simulated
    clock here: a test asserts no wall-clock figure) make their scripts' shifts (the game's
    lines need a game: `test_levers_telemetry` drives the same options from a socket)."""
    import shlex

    from tests.test_cli import readme_examples

    examples = [
        e for e in readme_examples("carfeel run --model")
        if ("sequential" in e or "prnd" in e) and "--telemetry" not in e  # a game's: elsewhere
    ]  # fmt: skip
    assert len(examples) == 2
    monkeypatch.chdir(tmp_path)
    for example in examples:
        record = tmp_path / "r.csv"
        args = [*shlex.split(example)[1:], "--clock", "simulated", "--record", str(record)]
        assert main(args) == 0, example
        meta = json.loads(record.with_suffix(".json").read_text())
        model = "sequential" if "sequential" in example else "prnd"
        assert meta["summary"]["gears"] == EXPECTED[model], example
