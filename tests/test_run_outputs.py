"""`carfeel run` keeps what the user had: outputs checked first, replaced only at the end, the
device opened before anything is recorded; bad input answered before anything is announced."""

from __future__ import annotations

import json
import stat

import numpy as np
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


@pytest.mark.parametrize("device", ["sdl:0", "evdev:/dev/input/event99"])
def test_a_device_that_cannot_be_opened_leaves_the_recording_alone(precious, capsys, device):
    # No pysdl2 here (an extra), no such event device: opening fails, nothing is written.
    assert main(["run", "--device", device, "--record", str(precious)]) == 2
    err = capsys.readouterr().err
    assert "carfeel[devices]" in err or "event99" in err
    assert untouched(precious)


@pytest.mark.posix_only  # /proc/x.png as the message writes it (Windows: \proc\x.png)
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
        (50, "{", "its sidecar r.json is missing, unreadable"),  # it changed the position scale
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
        replay.with_suffix(".json").write_text(
            sidecar if isinstance(sidecar, str) else source.with_suffix(".json").read_text()
        )
    capsys.readouterr()
    code = main(["run", "--clock", "simulated", "--model", "shift", "--device", f"replay:{replay}"])
    assert code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--model", "shift", "--sequence", "N,1,N"], "--sequence is the virtual hand's script"),
        (["--model", "steering", "--sequence", "N,1,N"], "--model steering has none"),
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
@pytest.mark.posix_only  # /proc/x.png as the message writes it (Windows: \proc\x.png)
def test_a_failed_simulation_leaves_the_user_s_files(precious, capsys, command):
    """The plot cannot be written: refused before the run, nothing replaced."""
    code = main([*command, "--out", str(precious), "--plot", "/proc/x.png"])
    assert code == 2
    assert "cannot write /proc/x.png" in capsys.readouterr().err
    assert untouched(precious)


def test_a_failure_while_writing_names_the_users_file(precious, tmp_path, capsys, monkeypatch):
    """Issue 11: `cannot use /proc/.x.csv.iwlpbjgh.tmp`: the staged name, not the user's."""
    from carfeel.errors import InputError

    plot = tmp_path / "keep.png"

    def full_disk(result, path, *args, **kwargs):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr("carfeel.io.plots.plot_shift", full_disk)
    assert main(["simulate", "shift", "--out", str(precious), "--plot", str(plot)]) == 2
    err = capsys.readouterr().err
    assert f"cannot use {plot}: No space left on device" in err and ".tmp" not in err
    assert untouched(precious)

    def refused(result, path, *args, **kwargs):
        raise InputError(f"cannot write {path}: refused")

    monkeypatch.setattr("carfeel.io.plots.plot_shift", refused)
    assert main(["simulate", "shift", "--out", str(precious), "--plot", str(plot)]) == 2
    err = capsys.readouterr().err
    assert f"cannot write {plot}: refused" in err and ".tmp" not in err


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


# ---------------------------------------------------------------- report folders (fit, validate)


@pytest.fixture
def old_report(tmp_path):
    """A report the user already has: its page and a figure."""
    folder = tmp_path / "report"
    folder.mkdir()
    (folder / "index.html").write_text("old report\n")
    (folder / "steering-9.png").write_bytes(b"old figure")
    return folder


def report_untouched(folder) -> bool:
    return (
        sorted(p.name for p in folder.iterdir()) == ["index.html", "steering-9.png"]
        and (folder / "index.html").read_text() == "old report\n"
        and not [p for p in folder.parent.iterdir() if p.name.startswith(".")]
    )


def weave_logs(tmp_path, count=2):
    logs = []
    for i in range(count):
        log = tmp_path / f"weave{i}.csv"
        speed = str(90 + 10 * i)
        assert main(["simulate", "steering", "--manoeuvre", "weave", "--speed-kmh", speed,
                     "--dt", "0.005", "--out", str(log)]) == 0  # fmt: skip
        logs.append(log)
    return logs


def test_a_validation_that_fails_while_drawing_leaves_the_old_report_whole(
    old_report, tmp_path, capsys, monkeypatch
):
    """The hard case: the second figure fails after the first is written."""
    from carfeel.io import plots

    logs = weave_logs(tmp_path)
    drawn: list[object] = []
    real = plots.plot_torque_validation

    def second_fails(*args, **kwargs):
        if drawn:
            raise OSError(28, "No space left on device", str(args[4]))
        drawn.append(real(*args, **kwargs))
        return drawn[-1]

    monkeypatch.setattr(plots, "plot_torque_validation", second_fails)
    capsys.readouterr()
    code = main(["validate", "--preset", "b-segment", *map(str, logs), "--report",
                 str(old_report)])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    # The user's folder named, not the temporary one the report was staged in.
    assert f"cannot use {old_report}/steering-2.png: No space left on device" in err, err
    assert drawn  # the first figure was drawn (in the staging folder) before the failure
    assert report_untouched(old_report)


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_a_failed_fit_leaves_the_report_and_the_preset(old_report, tmp_path, capsys):
    trace = tmp_path / "shift.csv"
    assert main(["simulate", "shift", "--pull-out", "--out", str(trace)]) == 0
    lines = trace.read_text().splitlines()
    header = lines[0].split(",")
    force = header.index("force_N")
    rows = [line.split(",") for line in lines[1:]]
    for row in rows:  # the force in kgf: the fit gives a preset carfeel refuses
        row[force] = repr(float(row[force]) / 9.80665)
    kgf = tmp_path / "kgf.csv"
    kgf.write_text("\n".join([lines[0], *(",".join(r) for r in rows)]) + "\n")
    preset = tmp_path / "mine.toml"
    preset.write_text("precious\n")
    capsys.readouterr()
    code = main(["fit", "shift", str(kgf), "--out", str(preset), "--report", str(old_report)])
    assert code == 2
    err = capsys.readouterr().err
    assert "mine.toml is not written" in err and "if force_N is in kgf, multiply it" in err
    assert preset.read_text() == "precious\n"
    assert report_untouched(old_report)


def test_a_report_replaces_an_old_one_whole_and_keeps_other_files(old_report, tmp_path, capsys):
    logs = weave_logs(tmp_path, count=1)
    assert main(["validate", "--preset", "b-segment", str(logs[0]), "--report",
                 str(old_report)]) == 0  # fmt: skip
    # Only a report was there: replaced whole, the old figure gone with it.
    assert sorted(p.name for p in old_report.iterdir()) == ["index.html", "steering-1.png"]
    assert "Validation of b-segment" in (old_report / "index.html").read_text()
    mode = stat.S_IMODE(old_report.stat().st_mode)
    assert mode & 0o055 == 0o055, oct(mode)  # a folder as any other: others may enter it
    # A folder with the user's own files keeps them; the report's files are replaced in it.
    notes = old_report / "notes.txt"
    notes.write_text("mine\n")
    assert main(["validate", "--preset", "b-segment", str(logs[0]), "--report",
                 str(old_report)]) == 0  # fmt: skip
    assert notes.read_text() == "mine\n"
    assert sorted(p.name for p in old_report.iterdir()) == [
        "index.html", "notes.txt", "steering-1.png"
    ]  # fmt: skip
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


@pytest.mark.parametrize(
    ("report", "message"),
    [
        ("", "an output folder name is empty"),
        ("missing/report", "folder missing does not exist"),
        ("weave0.csv", "it exists and is not a folder"),
        pytest.param(
            "/proc/report", "folder /proc does not take new files", marks=pytest.mark.linux_only
        ),
    ],
)
def test_a_report_folder_that_cannot_be_written_is_refused_first(
    tmp_path, capsys, monkeypatch, report, message
):
    logs = weave_logs(tmp_path, count=1)
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "fit.toml"
    capsys.readouterr()
    assert main(["fit", "steering", str(logs[0]), "--out", str(out), "--report", report]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_the_outputs_stage_a_folder_and_discard_it_on_failure(tmp_path):
    from carfeel.io.outputs import Outputs

    final = tmp_path / "r"
    outputs = Outputs()
    staged = outputs.add_folder(final)
    assert staged.is_dir() and staged.parent == tmp_path and not final.exists()
    (staged / "index.html").write_text("half")

    def failed_run():
        with outputs:
            raise RuntimeError("the run failed")

    with pytest.raises(RuntimeError):
        failed_run()
    assert list(tmp_path.iterdir()) == []  # nothing left, not even the staging folder


# ---------------------------------------------------------------- the recording's columns


def documented_columns() -> dict[str, set[str]]:
    """The manual's "Recording columns": every model's, then each model's own."""
    import re

    from tests.manual import manual_text

    readme = manual_text()
    start = readme.index("**Recording columns**")
    text = readme[start : readme.index("\n\n", start)]
    common, *bullets = text.split("\n- ")

    def names(part: str) -> set[str]:
        spans = re.findall(r"`([^`]*)`", part)
        return {n for s in spans if "-" not in s for n in re.split(r",\s*", s)}

    models = {re.match(r"`--model (\w+)`", b).group(1): names(b) for b in bullets}  # type: ignore[union-attr]
    return {"": names(common), **models}


@pytest.mark.parametrize(("model", "device"), [("shift", "virtual"), ("hpattern", "virtual"),
                                               ("steering", "virtual:wheel")])  # fmt: skip
def test_the_readme_names_every_column_a_recording_has(tmp_path, model, device):
    record = tmp_path / "rec.csv"
    assert main(["run", "--clock", "simulated", "--model", model, "--device", device,
                 "--duration", "0.3", "--record", str(record)]) == 0  # fmt: skip
    header = record.read_text().splitlines()[0].split(",")
    documented = documented_columns()
    expected = documented[""] | documented[model]
    if model == "steering":
        expected -= {"command_1"}  # a wheel has one axis
    assert set(header) == expected
    assert len(header) == len(set(header))


@pytest.mark.parametrize(("signum", "code"), [("SIGINT", 130), ("SIGTERM", 143)])
@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
@pytest.mark.posix_only  # SIGINT, SIGTERM sent to a child
def test_a_signal_ends_the_recording_with_the_fade_to_zero(tmp_path, signum, code):
    """Issue 11: after SIGTERM or SIGINT the recording ended before the fade (its last command
    was 8.7 N), so the fade could not be checked from the file; and the run exited 0."""
    import signal
    import subprocess
    import sys
    import time

    from carfeel.simulation.result import Result

    record = tmp_path / "sig.csv"
    # Simulated time: a stall of this shared machine cannot end the run by a fault first.
    proc = subprocess.Popen(
        [sys.executable, "-m", "carfeel.cli", "run", "--model", "hpattern", "--clock",
         "simulated", "--duration", "3600", "--record", str(record)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    part = tmp_path / "sig.part.csv"
    deadline = time.monotonic() + 60.0
    # Past the start-up pulses and the ramp-in (2 s of simulated time): the hand is shifting.
    while time.monotonic() < deadline and (
        not part.exists() or part.read_text().count("\n") < 3000
    ):
        time.sleep(0.1)
    proc.send_signal(getattr(signal, signum))
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    assert f"stopped by {signum}" in out
    result = Result.from_csv(record)
    commands = np.column_stack([result["command_0"], result["command_1"]])
    ramp = np.flatnonzero(np.isnan(result["x_m"]))  # the rows after the model stopped
    assert len(ramp) > 0 and ramp[-1] == len(result) - 1
    before = np.abs(commands[ramp[0] - 1]).max()
    assert before > 0.0  # there was a force to take away
    assert np.all(commands[-1] == 0.0)  # the file ends at zero force
    assert np.all(np.abs(commands[ramp]).max(axis=1) <= before + 1e-9)  # falling, not jumping


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_every_command_says_what_it_wrote(tmp_path, capsys):
    """Issue 11: `fit shift --report` and `run --plot` did not say what they wrote."""
    record, plot = tmp_path / "r.csv", tmp_path / "r.png"
    assert main(["run", "--clock", "simulated", "--model", "shift", "--duration", "0.3",
                 "--record", str(record), "--plot", str(plot)]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert f"recorded {record} (+ .json)" in out and f"plotted {plot}" in out
    trace, preset, report = tmp_path / "t.csv", tmp_path / "p.toml", tmp_path / "report"
    assert main(["simulate", "shift", "--pull-out", "--out", str(trace)]) == 0
    capsys.readouterr()
    assert main(["fit", "shift", str(trace), "--out", str(preset), "--report", str(report)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {preset}" in out and f"wrote the report {report / 'index.html'}" in out
