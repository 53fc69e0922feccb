"""The command line end to end, in-process and as a real subprocess."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from carfeel.cli import main
from carfeel.simulation.result import Result


def test_simulate_shift_writes_csv_metadata_and_plot(tmp_path, capsys):
    out, plot = tmp_path / "s.csv", tmp_path / "s.png"
    assert main(["simulate", "shift", "--seed", "3", "--out", str(out), "--plot", str(plot)]) == 0
    printed = capsys.readouterr().out
    assert "synchronization" in printed and "engagement peak" in printed
    result = Result.from_csv(out)
    for column in ("time_s", "position_m", "velocity_m_s", "force_N", "stage"):
        assert column in result.names
    assert {"synchronization", "engagement", "stop", "in_gear"} <= set(result["stage"].tolist())
    assert np.all(np.isfinite(result["force_N"]))
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["seed"] == "3" and meta["preset"] == "paper-first-gear"


def test_pull_out_option_ends_in_neutral(tmp_path):
    out = tmp_path / "p.csv"
    assert main(["simulate", "shift", "--pull-out", "--out", str(out)]) == 0
    stages = Result.from_csv(out)["stage"]
    assert stages[-1] == "neutral" and "in_gear" in set(stages.tolist())


def test_dt_and_substeps_options(tmp_path):
    out = tmp_path / "d.csv"
    args = ["simulate", "shift", "--dt", "0.002", "--substeps", "5", "--duration", "1.0"]
    assert main([*args, "--out", str(out)]) == 0
    result = Result.from_csv(out)
    assert len(result) == 500
    assert result.time_s[1] - result.time_s[0] == pytest.approx(0.002)


def test_demo_writes_into_the_folder_it_names(tmp_path, capsys):
    folder = tmp_path / "demo"
    assert main(["demo", "--out-dir", str(folder)]) == 0
    printed = capsys.readouterr().out
    assert str(folder.resolve()) in printed
    assert (folder / "shift.csv").is_file() and (folder / "shift.png").is_file()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["simulate", "shift", "--preset", "nope", "--out", "{t}/x.csv"], "no shift preset"),
        (["simulate", "shift", "--out", "{t}/missing/x.csv"], "does not exist"),
        (["simulate", "shift", "--out", "{t}/x.txt"], "expected a .csv file name"),
        (["simulate", "shift", "--out", "{t}/x.csv", "--plot", "{t}/x.jpg"], ".png"),
        (["simulate", "shift", "--dt", "-1", "--out", "{t}/x.csv"], "finite number > 0"),
        (["simulate", "shift", "--dt", "nan", "--out", "{t}/x.csv"], "finite number > 0"),
        (
            ["simulate", "shift", "--duration", "0.01", "--dt", "0.1", "--out", "{t}/x.csv"],
            "longer than --duration",
        ),
        (["simulate", "shift", "--seed", "x", "--out", "{t}/x.csv"], "whole number"),
        (
            ["simulate", "shift", "--dt", "0.025", "--out", "{t}/x.csv"],
            "use --substeps 13 or a shorter --dt",
        ),
        (
            ["simulate", "shift", "--dt", "1e-320", "--duration", "1e-320", "--out", "{t}/x.csv"],
            "below 1e-06 s",
        ),
        (["simulate", "shift", "--out", "{t}/taken.csv"], "taken.json: it is a folder"),
        (["simulate", "shift", "--out", "{t}/a_folder.csv"], "it is a folder"),
        (["demo", "--out-dir", "{t}/file.txt/sub"], "Not a directory"),
        (["simulate", "shift"], "--out"),
        (["simulate", "steer"], "invalid choice"),
    ],
)
def test_bad_input_exits_2_with_a_message(tmp_path, capsys, args, message):
    (tmp_path / "taken.json").mkdir()
    (tmp_path / "a_folder.csv").mkdir()
    (tmp_path / "file.txt").write_text("not a folder")
    args = [a.replace("{t}", str(tmp_path)) for a in args]
    code: object
    try:
        code = main(args)
    except SystemExit as exc:  # argparse's own errors exit from inside main
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err
    assert "Traceback" not in err


def test_bad_preset_file_exits_2_without_traceback_as_a_subprocess(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "x"\nsource = "y"\n[gearbox]\n[driver]\n')
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "carfeel.cli",
            "simulate",
            "shift",
            "--preset",
            str(bad),
            "--out",
            str(tmp_path / "o.csv"),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert "gearbox.synchronization_position_m: missing" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "o.csv").exists()


def test_help_is_useful(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    text = capsys.readouterr().out
    assert "carfeel demo" in text and "simulate" in text
    with pytest.raises(SystemExit):
        main(["simulate", "shift", "--help"])
    text = capsys.readouterr().out
    for option in ("--preset", "--seed", "--duration", "--dt", "--out", "--plot", "--pull-out"):
        assert option in text


def test_presets_lists_the_shipped_ones(capsys):
    assert main(["presets", "--json"]) == 0
    assert "paper-first-gear" in json.loads(capsys.readouterr().out)["shift"]
