"""`carfeel run` keeps what the user had: outputs checked first, replaced only at the end, the
device opened before anything is recorded; bad input answered before anything is announced."""

from __future__ import annotations

import json
import stat

import pytest

from carfeel.cli import main


@pytest.fixture
def precious(tmp_path):
    """A recording the user already has, with its sidecar."""
    keep = tmp_path / "keep.csv"
    keep.write_text("precious\n")
    keep.with_suffix(".json").write_text('{"precious": true}\n')
    return keep


def untouched(keep) -> bool:
    return (
        keep.read_text() == "precious\n"
        and keep.with_suffix(".json").read_text() == '{"precious": true}\n'
        and not list(keep.parent.glob("*.part.*"))
        and not list(keep.parent.glob(".*tmp*"))
    )


def test_a_device_that_cannot_be_opened_leaves_the_recording_alone(precious, capsys):
    # No pysdl2 on these machines (an extra): opening fails, nothing is written.
    assert main(["run", "--device", "sdl:0", "--record", str(precious)]) == 2
    assert "carfeel[devices]" in capsys.readouterr().err
    assert untouched(precious)


def test_an_unwritable_plot_is_refused_before_the_run(precious, capsys):
    code = main(["run", "--clock", "simulated", "--model", "shift", "--duration", "0.5",
                 "--record", str(precious), "--plot", "/proc/x.png"])  # fmt: skip
    assert code == 2
    captured = capsys.readouterr()
    assert "cannot write /proc/x.png" in captured.err
    assert captured.out == ""  # nothing announced before the error
    assert untouched(precious)


def test_a_finished_run_replaces_the_recording_with_normal_permissions(precious, tmp_path):
    plot = tmp_path / "keep.png"
    code = main(["run", "--clock", "simulated", "--model", "shift", "--duration", "0.5",
                 "--record", str(precious), "--plot", str(plot), "--json"])  # fmt: skip
    assert code == 0
    assert precious.read_text().startswith("time_s,")
    meta = json.loads(precious.with_suffix(".json").read_text())
    assert meta["preset"] == "paper-first-gear"  # the default, named
    assert plot.stat().st_size > 1000
    for path in (precious, precious.with_suffix(".json"), plot):
        mode = stat.S_IMODE(path.stat().st_mode)
        assert mode & 0o044 == 0o044, oct(mode)  # readable by others, like any other file
    assert not list(tmp_path.glob("*.part.*"))


@pytest.mark.parametrize(
    ("rows", "sidecar", "message"),
    [
        (0, True, "0 recorded sample(s); a replay needs at least two"),
        (1, True, "1 recorded sample(s)"),
        (50, False, "its sidecar r.json is missing"),
    ],
)
def test_bad_replays_exit_2_with_the_reason(tmp_path, capsys, rows, sidecar, message):
    source = tmp_path / "src.csv"
    assert main(["run", "--clock", "simulated", "--model", "shift", "--duration", "0.3",
                 "--record", str(source)]) == 0  # fmt: skip
    lines = source.read_text().splitlines()
    replay = tmp_path / "r.csv"
    replay.write_text("\n".join(lines[: rows + 1]) + "\n")
    if sidecar:
        replay.with_suffix(".json").write_text(source.with_suffix(".json").read_text())
    capsys.readouterr()
    code = main(["run", "--clock", "simulated", "--model", "shift", "--device", f"replay:{replay}"])
    assert code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--model", "shift", "--sequence", "N,1,N"], "--sequence is the H-pattern's script"),
        (["--device-max-force", "1e9", "--device", "sdl:0"], "allowed 0 < value <= 200"),
        (["--rate-hz", "10"], "allowed 250 <= value <= 10000 Hz"),
        (["--preset", "nope"], "nope"),
    ],
)
def test_bad_requests_are_answered_before_anything_is_announced(capsys, args, message):
    assert main(["run", "--clock", "simulated", *args]) == 2
    captured = capsys.readouterr()
    assert message in captured.err
    assert captured.out == ""


def test_a_replay_refuses_a_declared_force_limit(tmp_path, capsys):
    source = tmp_path / "src.csv"
    assert main(["run", "--clock", "simulated", "--model", "shift", "--duration", "0.3",
                 "--record", str(source)]) == 0  # fmt: skip
    capsys.readouterr()
    code = main(["run", "--model", "shift", "--device", f"replay:{source}",
                 "--device-max-force", "3"])  # fmt: skip
    assert code == 2
    assert "takes the recorded device's limits" in capsys.readouterr().err


def test_a_wheel_s_peak_command_is_in_nm(capsys):
    assert main(["run", "--clock", "simulated", "--model", "steering", "--duration", "3",
                 "--json"]) == 0  # fmt: skip
    summary = json.loads(capsys.readouterr().out)
    assert summary["command_unit"] == "Nm" and 0 < summary["peak_command"] <= 4.0


@pytest.mark.parametrize(
    "command",
    [
        ["simulate", "shift"],
        ["simulate", "steering", "--manoeuvre", "weave"],
        ["simulate", "hpattern", "--sequence", "N,1,N"],
    ],
)
def test_a_failed_simulation_leaves_the_user_s_files(precious, capsys, command):
    """The plot cannot be written: refused before the run, nothing replaced."""
    code = main([*command, "--out", str(precious), "--plot", "/proc/x.png"])
    assert code == 2
    assert "cannot write /proc/x.png" in capsys.readouterr().err
    assert untouched(precious)


def test_a_simulation_replaces_its_outputs_only_when_done(precious, tmp_path, capsys):
    plot = tmp_path / "keep.png"
    assert main(["simulate", "shift", "--out", str(precious), "--plot", str(plot)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {precious} and {plot}" in out  # the user's names, not the staged ones
    assert precious.read_text().startswith("time_s,")
    assert json.loads(precious.with_suffix(".json").read_text())["seed"] == 0
    assert not list(tmp_path.glob("*.part.*")) and not list(tmp_path.glob(".*tmp*"))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--mistake", "early-clutch:0"], "K counts the gears of --sequence from 1"),
        (["--mistake", "wall:1", "--mistake", "wall:2"], "given twice"),
        (["--out", ""], "an output file name is empty"),
    ],
)
def test_bad_simulate_options_exit_2(tmp_path, capsys, args, message):
    base = ["simulate", "hpattern", "--sequence", "N,1,2,N"]
    if "--out" not in args:
        args = [*args, "--out", str(tmp_path / "x.csv")]
    assert main([*base, *args]) == 2
    assert message in capsys.readouterr().err


def test_validate_prints_its_figures_without_a_report(tmp_path, capsys, monkeypatch):
    """`validate --json` needed --report; now the figures alone, and no files left behind."""
    log = tmp_path / "weave.csv"
    assert main(["simulate", "steering", "--manoeuvre", "weave", "--out", str(log)]) == 0
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    capsys.readouterr()
    assert main(["validate", "--preset", "b-segment", str(log), "--json"]) == 0
    figures = json.loads(capsys.readouterr().out)
    assert figures  # per log, the rms and r2 of the torque
    assert sorted(p.name for p in tmp_path.iterdir()) == before
