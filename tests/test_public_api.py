"""The public API (issue 28): the names `import carfeel` offers are pinned here, each works as the
docs show it, and each gives what the command line gives for the same run."""

from __future__ import annotations

import inspect
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import carfeel
from carfeel.errors import InputError

PUBLIC = {
    "__version__",
    "CarfeelError",
    "InputError",
    "MANOEUVRES",
    "Preset",
    "PresetError",
    "RealtimeResult",
    "RealtimeRun",
    "Result",
    "export_fmu",
    "fit_physical",
    "fit_shift",
    "fit_steering",
    "load_hpattern_preset",
    "load_shift_preset",
    "load_steering_preset",
    "preset_names",
    "run_device",
    "run_sweep",
    "shift_features",
    "simulate_hpattern",
    "simulate_shift",
    "simulate_steering",
    "steering_feel",
    "validate_steering",
}


def test_the_exported_names_are_pinned():
    """Adding or removing a public name is a decision: change this list with it (and the
    changelog)."""
    assert set(carfeel.__all__) == PUBLIC
    assert set(carfeel._EXPORTS) == PUBLIC - {"__version__"}  # each name says where it lives
    assert set(dir(carfeel)) >= PUBLIC


def test_every_exported_name_resolves_and_says_what_it_is():
    for name in sorted(PUBLIC - {"__version__"}):
        value = getattr(carfeel, name)
        if inspect.isfunction(value) or inspect.isclass(value):
            assert (value.__doc__ or "").strip(), f"carfeel.{name} has no docstring"
    with pytest.raises(AttributeError, match="no attribute 'simulate_shfit'"):
        carfeel.simulate_shfit  # noqa: B018  (a typo is an AttributeError naming it)


def test_import_carfeel_stays_light():
    """The exports are lazy: a script that only asks the version pays for no numpy."""
    code = "import sys, carfeel; carfeel.__version__; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_simulate_shift_is_the_simulation_of_the_preset():
    from carfeel.io.presets import load_shift
    from carfeel.simulation.shift import simulate_shift

    by_api = carfeel.simulate_shift("paper-first-gear", seed=3, duration_s=0.8)
    direct = simulate_shift(load_shift("paper-first-gear").params, seed=3, duration_s=0.8)
    assert by_api.names == direct.names
    for name in direct.names:
        assert np.array_equal(by_api[name], direct[name]), name
    # the loaded preset and its parameters are the same preset as its name
    preset = carfeel.load_shift_preset("paper-first-gear")
    again = carfeel.simulate_shift(preset.params, seed=3, duration_s=0.8)
    assert np.array_equal(again["force_N"], by_api["force_N"])
    features = carfeel.shift_features(by_api, preset)
    # the paper's first gear, stage by stage, and its plateau at the hand's force there
    assert features.stages == ("neutral", "synchronization", "gate_open", "engagement",
                               "free_travel", "stop", "in_gear")  # fmt: skip
    sync = by_api["stage"] == "synchronization"
    assert features.synchronization_force_N == pytest.approx(
        float(np.median(by_api["force_N"][sync]))
    )


def test_simulate_steering_equals_the_command_line(tmp_path: Path):
    from carfeel.cli import main
    from carfeel.simulation.result import Result

    csv = tmp_path / "step.csv"
    assert main(["simulate", "steering", "--manoeuvre", "iso7401-step", "--speed-kmh", "80",
                 "--out", str(csv)]) == 0  # fmt: skip
    by_cli = Result.from_csv(csv)
    by_api = carfeel.simulate_steering("b-segment", "iso7401-step", speed_kmh=80.0)
    # the CSV holds 9 significant digits (repr would be exact; the file is for people too)
    for name in ("time_s", "steering_angle_rad", "torque_Nm", "lateral_accel_m_s2"):
        assert np.allclose(by_api[name], by_cli[name], rtol=1e-8, atol=1e-12), name
    from carfeel.analysis.steering_feel import feel_of

    feel = carfeel.steering_feel(by_api, "b-segment")
    car = carfeel.load_steering_preset("b-segment").params.vehicle
    of_cli = feel_of(by_cli, car.steering_ratio, car.wheelbase_m)
    # a step is no weave: only the understeer gradient is defined, and it is the CLI's
    # (within 1e-4: the CSV keeps 9 digits and the gradient is a fit over the run)
    assert feel.understeer_gradient_deg_per_g == pytest.approx(
        of_cli.understeer_gradient_deg_per_g, rel=1e-4
    )


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: carfeel.simulate_steering(manoeuvre="iso9999"), "unknown manoeuvre"),
        (lambda: carfeel.simulate_steering(road="wet"), "model='physical'"),
        (lambda: carfeel.simulate_steering(model="physical", road="ice"), "dry, wet, snow"),
        (lambda: carfeel.simulate_steering(model="magic"), "paper, physical"),
        (lambda: carfeel.simulate_shift(dt_s=0.01), "substeps"),
        (lambda: carfeel.simulate_shift("no-such-preset"), "no-such-preset"),
    ],
)
def test_bad_input_is_an_input_error_that_says_what_to_fix(call, message):
    with pytest.raises((InputError, carfeel.PresetError), match=message):
        call()


def test_preset_names_lists_what_ships():
    assert "paper-first-gear" in carfeel.preset_names("shift")
    assert "b-segment" in carfeel.preset_names("steering")


def test_simulate_hpattern_is_the_command_lines_run(tmp_path: Path):
    from carfeel.cli import main
    from carfeel.simulation.result import Result

    csv = tmp_path / "hp.csv"
    assert main(["simulate", "hpattern", "--sequence", "N,1,2,N", "--speed-kmh", "40",
                 "--out", str(csv)]) == 0  # fmt: skip
    by_cli = Result.from_csv(csv)
    by_api = carfeel.simulate_hpattern("5r", "N,1,2,N", speed_kmh=40.0)
    assert len(by_api) == len(by_cli)
    for name in ("x_m", "y_m", "force_x_N", "force_y_N"):
        assert np.allclose(by_api[name], by_cli[name], rtol=1e-8, atol=1e-12), name
    assert list(by_api["gear"]) == list(by_cli["gear"])
    assert carfeel.simulate_hpattern(sequence=["N", "1"]).names == by_api.names
    with pytest.raises(InputError, match="no gear 7 in layout"):
        carfeel.simulate_hpattern("5r", "N,7")


def test_a_result_as_a_data_frame():
    result = carfeel.simulate_shift(duration_s=0.05)
    frame = result.to_pandas()
    assert list(frame.columns) == result.names[1:] and frame.index.name == "time_s"
    assert np.array_equal(frame["force_N"].to_numpy(), result["force_N"])
    assert np.array_equal(frame.index.to_numpy(), result.time_s)
    assert frame.attrs["seed"] == "0"
    frame.loc[frame.index[0], "force_N"] = 1e9  # a copy: the run is not changed through it
    assert result["force_N"][0] != 1e9


def test_run_sweep_from_python(tmp_path: Path):
    spec = tmp_path / "spec.toml"
    spec.write_text(
        'model = "shift"\npreset = "paper-first-gear"\nseeds = [0, 1]\n'
        'metrics = ["synchronization_force_N"]\n'
        '[vary]\n"driver.push_force_N" = { values = [60.0, 80.0] }\n',
        encoding="utf-8",
    )
    summary = carfeel.run_sweep(spec, tmp_path / "out.csv")
    assert summary.run.count("ok") == 4
    assert (tmp_path / "out.csv").read_text().count("\n") == 5  # a header and 4 cases


def test_the_python_pages_example_runs_as_written(tmp_path: Path, monkeypatch, capsys):
    """docs/how-to/python.md: its first block runs as a user would paste it, and prints what
    its comments say (the paper's plateau; no safety fault)."""
    from tests.manual import page

    code = page("how-to/python.md").split("```python\n", 1)[1].split("\n```", 1)[0]
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "docs/how-to/python.md", "exec"), {})
    printed = capsys.readouterr().out.split()
    assert float(printed[0]) == pytest.approx(78.3, abs=0.05) and printed[1] == "[]"


EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_fit_and_validate_steering_equal_the_command_line(tmp_path: Path):
    """The API's fit is the CLI's fit: the same preset bytes from the same logs (examples/, a
    rig's 200 Hz logs with noise, an offset and a lag), and validate_steering scores them."""
    from carfeel.cli import main

    logs = [EXAMPLES / "logs" / n for n in ("weave.csv", "lanechange.csv", "park.csv")]
    (tmp_path / "cli").mkdir()
    (tmp_path / "api").mkdir()  # one file name in two folders: the preset is named after it
    cli = tmp_path / "cli" / "mycar.toml"
    assert main(["fit", "steering", *map(str, logs), "--out", str(cli)]) == 0
    fit = carfeel.fit_steering(logs, tmp_path / "api" / "mycar.toml")
    assert (tmp_path / "api" / "mycar.toml").read_bytes() == cli.read_bytes()
    assert 0.99 < fit.r2 <= 1.0  # the examples' own law under rig noise: nearly all explained
    checked = carfeel.validate_steering(cli, logs[:1], tmp_path / "check")
    assert (tmp_path / "check" / "index.html").is_file() and checked
    with pytest.raises(InputError):  # a log that is not there: the CLI's message, no fit written
        carfeel.fit_steering([tmp_path / "missing.csv"], tmp_path / "none.toml")
    assert not (tmp_path / "none.toml").exists()


@pytest.mark.slow
@pytest.mark.needs_tools  # a C compiler (gcc on Linux x86-64, else cmake's)
def test_export_fmu_from_python_equals_the_command_line(tmp_path: Path):
    from carfeel.cli import main

    assert main(["export", "fmu", "shift", "--out", str(tmp_path / "cli.fmu")]) == 0
    files = carfeel.export_fmu("shift", tmp_path / "api.fmu")
    assert "modelDescription.xml" in files
    import zipfile

    with zipfile.ZipFile(tmp_path / "cli.fmu") as a, zipfile.ZipFile(tmp_path / "api.fmu") as b:
        assert a.read("modelDescription.xml") == b.read("modelDescription.xml")


@pytest.mark.slow  # two shift fits, about 11 s here
def test_fit_shift_equals_the_command_line(tmp_path: Path):
    from carfeel.cli import main

    trace = EXAMPLES / "logs" / "first-gear.csv"
    (tmp_path / "cli").mkdir()
    (tmp_path / "api").mkdir()
    cli = tmp_path / "cli" / "box.toml"
    assert main(["fit", "shift", str(trace), "--out", str(cli)]) == 0
    figures = carfeel.fit_shift([trace], tmp_path / "api" / "box.toml")
    assert (tmp_path / "api" / "box.toml").read_bytes() == cli.read_bytes()
    assert figures["r2"] >= 0.8  # the bar a written preset must pass (below it: refused)
