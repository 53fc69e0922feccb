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
    assert meta["seed"] == 3 and meta["preset"] == "paper-first-gear"


def test_pull_out_option_ends_in_neutral(tmp_path):
    out = tmp_path / "p.csv"
    assert main(["simulate", "shift", "--pull-out", "--out", str(out)]) == 0
    stages = Result.from_csv(out)["stage"]
    assert stages[-1] == "neutral" and "in_gear" in set(stages.tolist())


def test_dt_and_substeps_options(tmp_path):
    """--dt 0.002 --substeps 5 steps the model at 0.4 ms and writes every 2 ms: the same rows,
    to the digit, as --dt 0.0004 written every fifth row, and not those of --dt 0.002 alone
    (the test before checked only the time grid: substeps ignored passed it)."""
    runs = {}
    for dt, substeps in (("0.002", "5"), ("0.0004", "1"), ("0.002", "1")):
        out = tmp_path / f"d{dt}-{substeps}.csv"
        args = ["simulate", "shift", "--dt", dt, "--substeps", substeps, "--duration", "1.0"]
        assert main([*args, "--out", str(out)]) == 0
        runs[dt, substeps] = out.read_text().splitlines()
    coarse, fine, plain = runs["0.002", "5"], runs["0.0004", "1"], runs["0.002", "1"]
    assert len(coarse) == 501 and len(fine) == 2501  # a header and 500 (2500) rows
    assert coarse[1].startswith("0.002,")
    assert coarse[1:] == fine[5::5]  # 0.0004 s steps, every fifth written
    assert coarse[1:] != plain[1:]


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_demo_writes_into_the_folder_it_names(tmp_path, capsys, monkeypatch):
    """... and its real-time part, stopped once by a stall of a busy machine, runs again."""
    from carfeel.realtime import session
    from carfeel.realtime.identify import IdentificationError

    real, calls = session.run_realtime, []

    def busy_once(run, *args, **kwargs):
        calls.append(run)
        if len(calls) == 1:
            raise IdentificationError("the identification of virtual joystick stopped: stall")
        return real(run, *args, **kwargs)

    monkeypatch.setattr(session, "run_realtime", busy_once)
    folder = tmp_path / "demo"
    assert main(["demo", "--clock", "simulated", "--out-dir", str(folder)]) == 0
    printed = capsys.readouterr().out
    assert len(calls) == 2 and "stopped: stall; once more:" in printed
    assert str(folder.resolve()) in printed
    for name in ("shift.csv", "shift.png", "hpattern.png", "hpattern-reverse.png",
                 "realtime-hpattern.csv", "realtime-hpattern.png", "steering-iso3888.png",
                 "steering-weave.png", "fit-report/index.html"):  # fmt: skip
        assert (folder / name).is_file(), name
    assert "gears engaged: 1 2 3 4 5 4 3 2 1" in printed
    # The demo's fitted preset loads, and is the preset its noisy logs came from: K1 within
    # 5 % (the logs' 0.05 m/s^2 of Ay noise and the derived rate's error; 2.34 vs 2.4 today).
    from carfeel.io.presets import load_steering

    fitted = load_steering(str(folder / "fitted-b-segment.toml")).params.torque
    assert fitted.k1_Nm_s2_m == pytest.approx(load_steering().params.torque.k1_Nm_s2_m, rel=0.05)


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
    assert message in capsys.readouterr().err


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
    """Every kind, each with the package's own files (a new kind or preset the listing forgot
    fails), and each listed name loads."""
    from importlib import resources

    from carfeel.io.presets import PRESET_KINDS, load

    assert main(["presets", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)
    assert "paper-first-gear" in listed["shift"] and "rally-6" in listed["sequential"]
    assert tuple(listed) == PRESET_KINDS
    for kind, names in listed.items():
        folder = resources.files("carfeel.presets").joinpath(kind)
        files = sorted(f.name[:-5] for f in folder.iterdir() if f.name.endswith(".toml"))
        assert sorted(names) == files, kind
        for name in names:
            load(kind, name)


STEERING_COLUMNS = (
    "time_s", "speed_m_s", "steering_angle_rad", "steering_rate_rad_s", "lateral_accel_m_s2",
    "torque_Nm", "torque_aligning_Nm", "torque_tire_spin_Nm", "torque_friction_Nm",
    "torque_damping_Nm",
)  # fmt: skip


def test_simulate_steering_writes_the_columns_and_the_plot(tmp_path, capsys):
    out, plot = tmp_path / "w.csv", tmp_path / "w.png"
    args = ["simulate", "steering", "--manoeuvre", "iso3888", "--speed-kmh", "60"]
    assert main([*args, "--out", str(out), "--plot", str(plot)]) == 0
    assert "ISO 3888-1 double lane change at 60 km/h" in capsys.readouterr().out
    result = Result.from_csv(out)
    for column in (*STEERING_COLUMNS, "x_m", "y_m", "yaw_rad"):
        assert column in result.names
    assert plot.read_bytes()[:4] == b"\x89PNG"
    # The total is the sum of its terms in every row (to CSV rounding, 10 significant digits).
    terms = sum(result[c] for c in STEERING_COLUMNS[6:])
    assert np.allclose(result["torque_Nm"], terms, rtol=1e-8, atol=1e-9)


def test_metrics_steering_json_has_the_six_keys(tmp_path, capsys):
    out = tmp_path / "weave.csv"
    assert main(["simulate", "steering", "--manoeuvre", "weave", "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["metrics", "steering", str(out), "--json"]) == 0
    values = json.loads(capsys.readouterr().out)
    keys = {
        "torque_gradient_Nm_per_g", "torque_at_0_1g_Nm", "deadband_g", "hysteresis_Nm",
        "sensitivity_g_per_100deg", "understeer_gradient_deg_per_g",
    }  # fmt: skip
    assert keys <= set(values)
    assert all(isinstance(values[k], float) for k in keys)
    assert 20.0 <= values["torque_gradient_Nm_per_g"] <= 30.0


def test_metrics_of_a_measured_style_log_without_metadata(tmp_path, capsys):
    t = np.arange(0.0, 20.0, 0.01)
    ay = 2.0 * np.sin(2 * np.pi * 0.2 * t)
    angle = ay / 9.8 * 0.1
    torque = 2.3 * ay + 0.5 * np.sign(np.cos(2 * np.pi * 0.2 * t))
    rows = ["time_s,speed_m_s,steering_angle_rad,lateral_accel_m_s2,torque_Nm"]
    rows += [f"{a},{27.0},{b},{c},{d}" for a, b, c, d in zip(t, angle, ay, torque, strict=True)]
    log = tmp_path / "log.csv"
    log.write_text("\n".join(rows) + "\n")
    assert main(["metrics", "steering", str(log)]) == 0
    text = capsys.readouterr().out
    assert "torque gradient at 0 g" in text and "22.6 Nm/g" in text  # 2.3 * 9.80665


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("time_s,speed_m_s\n0,1\n", "missing column(s) steering_angle_rad"),
        (
            "time_s,speed_m_s,steering_angle_rad,lateral_accel_m_s2,torque_Nm\n"
            "0,1,0,0,0\n0.1,1,0,nan,0\n0.2,1,0,0,0\n",
            "line 3: lateral_accel_m_s2 is not a finite",
        ),
        (
            "time_s,speed_m_s,steering_angle_rad,lateral_accel_m_s2,torque_Nm\n"
            "0,1,0,0,0\n0,1,0,0,0\n0.2,1,0,0,0\n",
            "line 3: time_s does not increase",
        ),
        (
            "time_s,time_s,speed_m_s\n0,0,1\n",
            "column(s) time_s appear more than once",
        ),
        (
            "time_s,speed_m_s,steering_angle_rad,lateral_accel_m_s2,torque_Nm\n"
            "0,1,0,0,x\n0.1,1,0,0,0\n0.2,1,0,0,0\n",
            "column torque_Nm must hold numbers",
        ),
    ],
)
def test_malformed_steering_logs_exit_2(tmp_path, capsys, content, message):
    log = tmp_path / "bad.csv"
    log.write_text(content)
    assert main(["metrics", "steering", str(log)]) == 2
    err = capsys.readouterr().err
    assert message in err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--manoeuvre", "iso9999"], "invalid choice"),
        (["--manoeuvre", "weave", "--speed-kmh", "-10"], "allowed 0 <= value <= 250 km/h"),
        (["--manoeuvre", "iso4138", "--speed-kmh", "50"], "drop --speed-kmh"),
        (["--manoeuvre", "weave", "--preset", "nope"], "no steering preset named 'nope'"),
        (["--manoeuvre", "weave", "--dt", "100"], "longer than --duration"),
        (["--manoeuvre", "iso3888", "--dt", "0.2"], "use --substeps 40"),
        (["--manoeuvre", "iso3888", "--dt", "1e-7"], "below 1e-06 s"),
        (["--manoeuvre", "iso7401-step", "--speed-kmh", "10"], "beyond the car's lock of 540"),
        (["--manoeuvre", "steer-cycle", "--speed-kmh", "250"], "a parking manoeuvre"),
    ],
)
def test_bad_steering_requests_exit_2(tmp_path, capsys, args, message):
    code: object
    try:
        code = main(["simulate", "steering", *args, "--out", str(tmp_path / "x.csv")])
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err


def test_malformed_steering_preset_exits_2(tmp_path, capsys):
    from importlib import resources

    text = resources.files("carfeel.presets").joinpath("steering", "b-segment.toml").read_text()
    bad = tmp_path / "car.toml"
    bad.write_text(text.replace("cg_to_front_axle_m = 0.984", "cg_to_front_axle_m = 3.0"))
    code = main(
        [
            "simulate",
            "steering",
            "--manoeuvre",
            "weave",
            "--preset",
            str(bad),
            "--out",
            str(tmp_path / "x.csv"),
        ]
    )
    assert code == 2
    assert "must be shorter than vehicle.wheelbase_m" in capsys.readouterr().err


def test_simulate_hpattern_writes_the_columns_and_the_plot(tmp_path, capsys):
    out, plot = tmp_path / "h.csv", tmp_path / "h.png"
    args = ["simulate", "hpattern", "--sequence", "N,1,2,3,2,N", "--seed", "2"]
    assert main([*args, "--out", str(out), "--plot", str(plot)]) == 0
    text = capsys.readouterr().out
    assert "gears engaged    1 2 3 2; now in N" in text
    result = Result.from_csv(out)
    for column in ("time_s", "x_m", "y_m", "vx_m_s", "vy_m_s", "force_x_N", "force_y_N",
                   "region", "gear"):  # fmt: skip
        assert column in result.names
    assert set(result["gear"].tolist()) == {"N", "1", "2", "3"}
    assert plot.read_bytes()[:4] == b"\x89PNG"
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["sequence"] == "N,1,2,3,2,N" and meta["synchronizer"] == "fixed"


def test_hpattern_with_the_clutch_released_reports_the_balk(tmp_path, capsys):
    out = tmp_path / "b.csv"
    code = main(["simulate", "hpattern", "--sequence", "N,1", "--clutch", "0",
                 "--synchronizer", "physics", "--out", str(out)])  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    # A sound ring balks silently (issue 10: grinding only when the blocking condition fails).
    assert "gears engaged    none" in text and "grinding" not in text


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--sequence", "N,7,N"], "no gear 7 in layout 5r"),
        (["--sequence", "N,,1"], "expected gear names separated by commas"),
        (["--sequence", "N,1", "--clutch", "1.5"], "allowed 0 (released) .. 1 (pressed)"),
        (["--sequence", "N,1", "--speed-kmh", "-3"], "allowed 0 <= value <= 250 km/h"),
        (["--sequence", "N,1", "--mistake", "sneeze:1"], "expected early-clutch:K or wall:K"),
        (["--sequence", "N,1", "--mistake", "wall:9"], "allowed 1 .. 1, the K-th gear"),
        (["--sequence", "N,1", "--layout", "9r"], "no hpattern preset named '9r'"),
        (["--sequence", "N,1", "--dt", "0.01"], "use --substeps 10"),
        (["--sequence", "N,1", "--synchronizer", "magic"], "invalid choice"),
    ],
)
def test_bad_hpattern_requests_exit_2(tmp_path, capsys, args, message):
    code: object
    try:
        code = main(["simulate", "hpattern", *args, "--out", str(tmp_path / "x.csv")])
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err


def test_invalid_layout_file_exits_2(tmp_path, capsys):
    from importlib import resources

    text = resources.files("carfeel.presets").joinpath("hpattern", "5r.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('name = "R"\nplane = 2', 'name = "R"\nplane = 5'))
    code = main(["simulate", "hpattern", "--sequence", "N,1", "--layout", str(bad),
                 "--out", str(tmp_path / "x.csv")])  # fmt: skip
    assert code == 2
    assert "gear R is on plane 5" in capsys.readouterr().err


# ---------------------------------------------------------------- issue 10


@pytest.mark.parametrize("seed", [0, 1, 4])
def test_the_summary_gives_the_engagement_peak_where_the_csv_has_it(tmp_path, capsys, seed):
    """Issue 10: the summary said "at 21.2 mm" (where the teeth are met) for every seed."""
    out = tmp_path / "s.csv"
    assert main(["simulate", "shift", "--seed", str(seed), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    result = Result.from_csv(out)
    teeth = result["stage"] == "engagement"
    peak = np.flatnonzero(teeth)[np.argmax(result["force_N"][teeth])]
    line = next(line for line in text.splitlines() if "engagement peak" in line)
    at_mm = float(line.split(" at ")[1].split(" mm")[0])
    # Printed to 0.1 mm.
    assert at_mm == pytest.approx(result["position_m"][peak] * 1e3, abs=0.051)


def write_profile(path, rows, header="time_s,force_N"):
    path.write_text(header + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")
    return path


def test_a_force_profile_drives_the_knob_open_loop(tmp_path, capsys):
    """A hand-made profile: 60 N for 0.5 s (synchronization, then into gear), then nothing. The
    knob force in the CSV is the profile's, interpolated; the run lasts as long as the profile."""
    profile = write_profile(
        tmp_path / "push.csv", [(0.0, 0.0), (0.02, 60.0), (0.5, 60.0), (0.52, 0.0), (0.8, 0.0)]
    )
    out = tmp_path / "p.csv"
    code = main(["simulate", "shift", "--force-profile", str(profile), "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    result = Result.from_csv(out)
    assert result.time_s[-1] == pytest.approx(0.8)
    expected = np.interp(result.time_s, [0.0, 0.02, 0.5, 0.52, 0.8], [0.0, 60.0, 60.0, 0.0, 0.0])
    assert np.allclose(result["force_N"], expected)
    stages = set(result["stage"].tolist())
    assert {"synchronization", "engagement", "stop"} <= stages
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["force_profile"] == str(profile)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("time,force\n0,1\n1,2\n", "no column time_s or force_N"),
        ("time_s,force_N\n0,1\n", "give at least two"),
        ("time_s,force_N\n0,1\n0.1,abc\n", "line 3: force_N = 'abc' is not a number"),
        ("time_s,force_N\n0,1\n0.2,2\n0.1,3\n", "times must increase"),
        ("time_s,force_N\n0,1\n0.1,50000\n", "give the knob force in N"),
        ("", "is empty"),
    ],
)
def test_bad_force_profiles_are_refused_with_a_message(tmp_path, capsys, content, message):
    profile = tmp_path / "bad.csv"
    profile.write_text(content)
    out = tmp_path / "o.csv"
    out.write_text("keep me")
    code = main(["simulate", "shift", "--force-profile", str(profile), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and "Traceback" not in err
    assert err.count("\n") == 1  # one message
    assert out.read_text() == "keep me"  # existing files untouched


def test_a_missing_force_profile_and_pull_out_with_a_profile_are_refused(tmp_path, capsys):
    out = tmp_path / "o.csv"
    code = main(
        ["simulate", "shift", "--force-profile", str(tmp_path / "no.csv"), "--out", str(out)]
    )
    assert code == 2 and "not found" in capsys.readouterr().err
    profile = write_profile(tmp_path / "p.csv", [(0.0, 0.0), (0.1, 10.0)])
    code = main(
        ["simulate", "shift", "--force-profile", str(profile), "--pull-out", "--out", str(out)]
    )
    assert code == 2 and "exclude each other" in capsys.readouterr().err
    assert not out.exists()


# ---------------------------------------------------------------- issue 11: every failure clear


def test_every_option_and_argument_has_a_help_text():
    """Issue 11 found `run --model`, `validate --preset` and `--report` without one: the class,
    over every command the parser assembles (a new family's options included)."""
    import argparse

    from carfeel.cli import build_parser

    missing = []

    def walk(parser, path):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, [*path, name])
            elif not action.help and not isinstance(action, argparse._HelpAction):
                missing.append(" ".join([*path, *(action.option_strings or [action.dest])]))

    walk(build_parser(), ["carfeel"])
    assert missing == []


def run_cli(args):
    try:
        return main(args)
    except SystemExit as exc:  # argparse's own refusals
        return exc.code


@pytest.mark.parametrize(
    ("args", "message"),
    [
        # A 300-digit seed was printed back in full (and aliased a 64-bit one).
        (["simulate", "shift", "--seed", "1" + "0" * 300], "got '100000000000000000000000000"),
        (["simulate", "shift", "--seed", "-1"], "from 0 to 2^64 - 1"),
        (["simulate", "hpattern", "--sequence", "N," + "9" * 300],
         "no gear 9999999999999999999999999999...999999999 in layout 5r"),
        (["simulate", "hpattern", "--sequence", "N,1", "--mistake", "wall:" + "9" * 300],
         "--mistake wall:99999999999999999999999...999999999: allowed 1 .. 1"),
    ],
)  # fmt: skip
def test_long_arguments_are_refused_and_echoed_short(tmp_path, capsys, args, message):
    assert run_cli([*args, "--out", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err) < 1000
    assert not (tmp_path / "x.csv").exists()


def test_a_preset_integer_beyond_any_float_is_named_not_a_traceback(tmp_path, capsys):
    from importlib import resources

    text = resources.files("carfeel.presets").joinpath("hpattern", "5r.toml").read_text()
    huge = text.replace("plane = 0", "plane = 1" + "0" * 400, 1)
    assert huge != text
    layout = tmp_path / "huge.toml"
    layout.write_text(huge)
    code = main(["simulate", "hpattern", "--sequence", "N,1", "--layout", str(layout), "--out",
                 str(tmp_path / "x.csv")])  # fmt: skip
    assert code == 2
    assert "layout.gears[0].plane = a 401-digit number" in capsys.readouterr().err


def test_one_row_is_one_row(tmp_path, capsys):
    log = tmp_path / "one.csv"
    log.write_text("time_s,speed_m_s,steering_angle_rad,lateral_accel_m_s2,torque_Nm\n0,1,0,0,0\n")
    assert main(["metrics", "steering", str(log)]) == 2
    assert "one.csv: 1 row; the metrics need" in capsys.readouterr().err


def test_an_empty_preset_name_says_so(tmp_path, capsys):
    log = tmp_path / "w.csv"
    assert main(["simulate", "steering", "--manoeuvre", "weave", "--dt", "0.005", "--out",
                 str(log)]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["fit", "steering", str(log), "--out", ""]) == 2
    assert "an output file name is empty" in capsys.readouterr().err  # it said "--out .:"


def test_a_closed_pipe_ends_quietly_with_sigpipe_s_code(tmp_path):
    """`carfeel ... | head -1`: the reader goes away; no "cannot use a file: Broken pipe"."""
    from pathlib import Path

    carfeel = Path(sys.executable).with_name("carfeel")
    proc = subprocess.Popen(
        [str(carfeel), "presets"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # before it writes: its first write meets a closed pipe
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141
    assert err == ""


def readme_examples(prefix: str) -> list[str]:
    """The manual's example command lines that start with `prefix` (continuations joined)."""
    from tests.manual import manual_text

    text = manual_text()
    lines = text.replace("\\\n", " ").splitlines()
    return [line.split("  #")[0].strip() for line in lines if line.startswith(prefix)]


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_readmes_hpattern_examples_do_what_they_say(tmp_path, capsys, monkeypatch):
    """Issue 11: the `--mistake early-clutch:3` example exited 2 (its sequence has two gears)
    and `--sequence ...,N,R,N` at 30 km/h never engaged reverse (no synchronizer: right, but
    the README promised it). Every such example runs, and the two claims hold."""
    import shlex

    examples = readme_examples("carfeel simulate hpattern")
    assert len(examples) >= 3
    monkeypatch.chdir(tmp_path)
    printed = {}
    for example in examples:
        args = shlex.split(example)[1:]
        capsys.readouterr()
        assert main(args) == 0, example
        printed[example] = capsys.readouterr().out
    reverse = next(text for example, text in printed.items() if ",R," in example)
    assert "gears engaged    R" in reverse
    balk = next(text for example, text in printed.items() if "early-clutch" in example)
    assert "gears engaged    1;" in balk  # into 1st, and the clutch let out before 2nd: a balk
