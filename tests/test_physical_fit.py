"""Fitting and validating the physical steering model (issue 13) from carfeel's own noisy logs.

The logs come from `tests/physical_logs.py`: a true car that is not the base preset, six
manoeuvres that excite the fitted parameters, 200 Hz, noise on every channel, an angle offset
and a torque bias. Tolerances say why they are that wide.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from carfeel.cli import main
from carfeel.errors import InputError
from carfeel.identification import physical_batch, physical_fit
from carfeel.identification.physical_fit import (
    NAMES,
    PARAMETERS,
    Batch,
    fit_physical,
    pieces_of,
    reference,
    runs_of,
)
from carfeel.io.presets import load_steering, to_toml
from carfeel.models.steering import physical
from carfeel.models.steering.physical import PhysicalInputs
from carfeel.simulation.result import Result
from tests.physical_logs import TRUE, base_car, clean_runs, measured, true_car


def by_name(fit):
    return {e.name: e for e in fit.estimates}


def test_the_batch_is_the_pure_step():
    """Three parameter sets on three pieces: the speed through the kinematic car's range,
    parking past the lock (the end stops), sliding at 25 m/s; one set with the motor at its
    limit and a wheel lifting (no grip). 1e-9 Nm: rounding (the pieces' torques reach 60 Nm;
    measured 2e-11)."""
    p = base_car().physical()
    lifted = dataclasses.replace(p.tyres, cg_height_m=2.0, track_m=0.5, friction_coefficient=0.8)
    limited = dataclasses.replace(p.system, max_assist_Nm=3.0, column_friction_Nm=0.5)
    sets = [p, dataclasses.replace(p, tyres=lifted), dataclasses.replace(p, system=limited)]
    n = 3000
    t = np.arange(1, n + 1) * 1e-3
    cases = [
        (np.clip(8.0 * t - 2.0, 0.0, 30.0), 3.0 * np.sin(2 * np.pi * 0.4 * t)),
        (np.zeros(n), 10.0 * np.sin(2 * np.pi * 0.2 * t)),  # the lock is 9.42 rad
        (np.full(n, 25.0), 2.0 * np.sin(2 * np.pi * 0.3 * t)),
    ]
    rates = [np.gradient(angle, 1e-3) for _, angle in cases]
    pure = np.empty((n, len(sets), len(cases)))
    pure_ay = np.empty_like(pure)
    kept = {}
    for j, params in enumerate(sets):
        for s, ((speed, angle), rate) in enumerate(zip(cases, rates, strict=True)):
            state = physical.initial_state(params)
            for k in range(n):
                inputs = PhysicalInputs(float(speed[k]), float(angle[k]), float(rate[k]), 0.0, 1.0)
                state, out = physical.step(state, inputs, params, 1e-3)
                pure[k, j, s], pure_ay[k, j, s] = out.torque_Nm, out.lateral_accel_m_s2
                if k == 1999:
                    kept[(j, s)] = state
    start = physical_batch.stack_states([physical.initial_state(p)] * len(cases))
    pieces = physical_batch.Pieces(
        np.column_stack([c[0] for c in cases]), np.column_stack([c[1] for c in cases]),
        np.column_stack(rates), start,
    )  # fmt: skip
    torque, ay, states = physical_batch.simulate(sets, pieces, 1e-3, capture=[1999])
    assert np.max(np.abs(pure)) > 50.0  # the stops were reached
    assert np.max(np.abs(torque - pure)) < 1e-9
    # The set with a lifting wheel slides: its Ay carries the reordered mu's last bits up to
    # 2e-9 m/s^2 over the 3 s (measured); the others agree to 1e-13.
    assert np.max(np.abs(ay - pure_ay)) < 1e-8
    for (j, s), state in kept.items():
        for f, name in enumerate(physical_batch.FIELDS):
            if name not in ("x_m", "y_m", "yaw_rad"):  # the batch leaves the pose out
                assert states[1999][f, j, s] == pytest.approx(getattr(state, name), abs=1e-9)


def test_swept_pieces_are_the_whole_run_for_every_parameter_set():
    """Pieces started from another parameter set's states join up, within a few sweeps, into
    the pure model's run of each set, its memory included (a stuck friction, the patches'
    wind-up): else the finite differences would miss it. 1e-3 Nm: the sweeps stop within
    SWEEP_TOL_NM (1e-4 Nm, weighted) of joining."""
    logs = measured(clean_runs(("park-0kmh", "fast-sine-80kmh")), noise=False)
    runs = runs_of(logs)
    pieces = pieces_of(runs)
    wanted: dict[int, set[int]] = {}
    for i, begin in zip(pieces.run, pieces.begin, strict=True):
        wanted.setdefault(i, set()).add(begin)
    base = base_car()
    ref = reference(base.physical(), runs, wanted)
    x = np.array([TRUE[n] for n in NAMES])
    neighbours = [(NAMES.index("rack_friction_Nm"), 0.05), (NAMES.index("friction_coefficient"),
                                                            0.05)]  # fmt: skip
    sets = [physical_fit.with_values(base, x).physical()]
    for i, h in neighbours:
        trial = x.copy()
        trial[i] += h
        sets.append(physical_fit.with_values(base, trial).physical())
    data = physical_fit._data(logs, runs, None)
    delay = 0.0123  # the torque logged late: the samples fall between grid points
    once, _, _ = Batch(runs, pieces, ref, data).run(sets, x, neighbours, delay, max_sweeps=1)
    swept, slope, change = Batch(runs, pieces, ref, data).run(sets, x, neighbours, delay,
                                                             max_sweeps=50)  # fmt: skip
    assert change <= physical_fit.SWEEP_TOL_NM
    worst_once = 0.0
    for j, params in enumerate(sets):
        exact = reference(params, runs)
        model = data.predict([t[None, :] for t in exact.torque_Nm], delay)[0]
        assert np.max(np.abs(swept.torque(j) - model)) < 1e-3
        worst_once = max(worst_once, float(np.max(np.abs(once.torque(j) - model))))
        if j == 0:  # the delay's column: the slope of the same interpolant (a central
            # difference of it over 0.1 ms, exact where no grid point lies within 0.05 ms)
            h = 5e-5
            ahead = data.predict([t[None, :] for t in exact.torque_Nm], delay - h)[0]
            behind = data.predict([t[None, :] for t in exact.torque_Nm], delay + h)[0]
            numeric = (ahead - behind) / (2 * h)
            away = np.abs(((data.time_s - delay) / physical_fit.DT_S + 0.5) % 1.0 - 0.5) > 0.06
            assert away.mean() > 0.5
            # 1e-3 Nm of torque difference over a 1 ms grid step: 1 Nm/s
            assert np.max(np.abs(slope - numeric)[away]) < 1.0
    assert worst_once > 1e-2  # started from the base's states, one sweep is not the run


@pytest.fixture(scope="module")
def acceptance_fit():
    return fit_physical(measured(clean_runs()), base_car())


def test_noise_on_every_channel_identifies_every_parameter(acceptance_fit):
    """The issue's acceptance: noise on torque, angle, rate, speed and Ay, a 0.3 deg angle
    offset and a 0.05 Nm torque bias; the truth 10-40 % from the base. Measured over six other
    noise draws (benchmarks/bench_physical_fit.py --seeds 6): every error within 1.2 % (the
    assist at speed; the rest within 0.7 %), all within 2 of the reported sigmas (0.05-0.96 %);
    this draw's within 0.25 %. Each must be within 1.5 % (over the worst draw seen; the angle
    used as logged, without its fusion with the rate, put the rack friction 1.7 % out, jumpy
    steering inputs the assist at speed 3.2 %, a fit left near the base 10-40 %) and within 3
    of its sigmas."""
    fit = acceptance_fit
    got = by_name(fit)
    for name, truth in TRUE.items():
        e = got[name]
        assert e.status == "fitted", name
        assert e.value == pytest.approx(truth, rel=0.015), name
        assert abs(e.value - truth) <= 3 * e.sigma, name
    # The torque sensor's 0.05 Nm and what is left of the angle's noise after its fusion
    # with the rate (0.017 Nm at the truth, measured): 15 % over that.
    assert fit.rms_error_Nm < 1.15 * math.hypot(0.05, 0.017)
    assert fit.r2 > 0.999
    assert fit.warnings == ()
    assert fit.batch_check_Nm < 1e-6  # the fit's batch is the pure model's run
    assert abs(fit.torque_delay_s) < 0.0025  # none was put in


def test_what_the_logs_cannot_excite_is_kept_from_the_base_and_said():
    """The weave alone: no parking, no quick steering, 0.2 g. The assist at standstill, the
    damping and mu keep the base's values (not the truth's), with the reason; nothing is left
    at a bound."""
    base = base_car()
    fit = fit_physical(measured(clean_runs(("weave",))), base)
    got = by_name(fit)
    for name in ("assist_gain_standstill_1_Nm", "eps_damping_high_speed_Nm_s_rad",
                 "friction_coefficient"):  # fmt: skip
        e = got[name]
        assert e.status == "kept", name
        assert e.value == physical_fit.value_of(base, PARAMETERS[NAMES.index(name)])
        assert e.value != TRUE[name] and math.isnan(e.sigma)
        assert e.note.startswith("kept from the base preset")
    assert got["pneumatic_trail_m"].status == "fitted"
    assert any("assist_gain_standstill_1_Nm not identifiable" in w for w in fit.warnings)
    assert any("friction_coefficient not identifiable" in w for w in fit.warnings)
    for e, p in zip(fit.estimates, PARAMETERS, strict=True):
        assert p.lower < e.value < p.upper, e.name
    written = fit.car
    assert written.tyres is not None and written.steering_system is not None
    assert base.tyres is not None and base.steering_system is not None
    assert written.tyres.friction_coefficient == base.tyres.friction_coefficient
    assert written.steering_system.torsion_bar_stiffness_Nm_rad == (
        base.steering_system.torsion_bar_stiffness_Nm_rad
    )


def write_logs(folder, names, delay_s=0.0, seed=5):
    """Measured-style CSV logs of the true car, the torque logged `delay_s` late."""
    paths = []
    for (name, run), log in zip(clean_runs(names), measured(clean_runs(names), seed),
                                strict=True):  # fmt: skip
        late = np.interp(log.time_s - delay_s, run.time_s, run["torque_Nm"])
        torque = log.torque_Nm + (late - np.interp(log.time_s, run.time_s, run["torque_Nm"]))
        assert log.lateral_accel_m_s2 is not None
        path = folder / f"{name}.csv"
        Result(log.time_s, {
            "speed_m_s": log.speed_m_s, "steering_angle_rad": log.angle_rad,
            "steering_rate_rad_s": log.rate_rad_s, "steering_torque_Nm": torque,
            "lateral_accel_m_s2": log.lateral_accel_m_s2,
        }).to_csv(path)  # fmt: skip
        paths.append(str(path))
    return paths


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_fit_and_validate_the_physical_model_from_the_command_line(tmp_path, capsys):
    """Parking, the weave and the fast sine with the torque logged 40 ms late; fitted on the
    first 70 % of each log, the offset let drift (knots 10 s apart); the preset keeps the base
    car's tables with the fitted values in them, runs, and validates against the logs."""
    paths = write_logs(tmp_path, ("park-0kmh", "weave", "fast-sine-80kmh"), delay_s=0.04)
    out, fit_report = tmp_path / "mine.toml", tmp_path / "fit"
    assert main(["fit", "steering", *paths, "--steering-model", "physical", "--out", str(out),
                 "--report", str(fit_report), "--holdout", "0.3", "--drift", "10",
                 "--json"]) == 0  # fmt: skip
    printed = json.loads(capsys.readouterr().out)
    assert printed["steering_model"] == "physical"
    # 40 ms, as a CAN message queued behind others: found within 5 ms (a sample is 5 ms).
    assert printed["torque_delay_s"] == pytest.approx(0.04, abs=0.005)
    parameters = printed["parameters"]
    assert printed["cross_validation"]["held_out"]
    written = load_steering(str(out)).params
    base = base_car()
    for p in PARAMETERS:
        assert physical_fit.value_of(written, p) == pytest.approx(parameters[p.name]["value"])
        # 70 % of three short logs, noise on every channel: within 5 % (measured: 2 %); mu from
        # the parking (the patches' sliding moment), as no run goes past 0.6 g.
        assert parameters[p.name]["status"] == "fitted", p.name
        assert parameters[p.name]["value"] == pytest.approx(TRUE[p.name], rel=0.05), p.name
    assert written.vehicle == base.vehicle and written.torque == base.torque
    assert written.tyres is not None and written.steering_system is not None
    assert base.tyres is not None and base.steering_system is not None
    assert written.tyres.relaxation_length_m == base.tyres.relaxation_length_m
    assert written.steering_system.stop_stiffness_Nm_rad == (
        base.steering_system.stop_stiffness_Nm_rad
    )
    page = (fit_report / "index.html").read_text()
    assert "Cross-validation" in page and "physical" in page
    assert main(["simulate", "steering", "--steering-model", "physical", "--preset", str(out),
                 "--manoeuvre", "weave", "--out", str(tmp_path / "w.csv")]) == 0  # fmt: skip
    capsys.readouterr()
    # validate applies no delay (as for the law): checked on the same runs logged without it
    undelayed = tmp_path / "undelayed"
    undelayed.mkdir()
    paths = write_logs(undelayed, ("park-0kmh", "weave", "fast-sine-80kmh"), seed=6)
    check = tmp_path / "check"
    assert main(["validate", "--steering-model", "physical", "--preset", str(out), *paths,
                 "--report", str(check), "--drift", "10", "--json"]) == 0  # fmt: skip
    figures = json.loads(capsys.readouterr().out)
    assert set(figures) == set(paths)
    for values in figures.values():
        assert values["r2"] > 0.99
        assert values["rms_error_offset_removed_Nm"] <= values["rms_error_Nm"]
        assert values["rms_lateral_accel_error_m_s2"] < 0.3
    page = (check / "index.html").read_text()
    # the feel metrics side by side, labelled as the law's validation labels them
    assert "torque gradient at 0 g (Nm/g)" in page and "measured" in page
    assert len(list(check.glob("*.png"))) == len(paths)


def weave_log(tmp_path, **edit):
    """The weave as a CSV log, its columns edited."""
    ((_, run),) = clean_runs(("weave",))
    signals = {
        "speed_m_s": run["speed_m_s"], "steering_angle_rad": run["steering_angle_rad"],
        "steering_rate_rad_s": run["steering_rate_rad_s"], "steering_torque_Nm": run["torque_Nm"],
        "lateral_accel_m_s2": run["lateral_accel_m_s2"],
    }  # fmt: skip
    time = run.time_s
    if "degrees" in edit:
        signals["steering_angle_rad"] = np.degrees(signals["steering_angle_rad"])
    if "flip" in edit:
        signals["steering_torque_Nm"] = -signals["steering_torque_Nm"]
    if "ms" in edit:
        time = time * 1000.0
    if "huge" in edit:
        signals["steering_torque_Nm"] = signals["steering_torque_Nm"].copy()
        signals["steering_torque_Nm"][500] = 1e300
    path = tmp_path / f"weave-{'-'.join(edit) or 'ok'}.csv"
    Result(time, signals).to_csv(path)
    return str(path)


@pytest.mark.parametrize(
    ("edit", "extra", "message"),
    [
        ({"degrees": 1}, [], "looks like degrees"),
        ({"flip": 1}, [], "flip the sign of steering_torque_Nm"),
        ({"ms": 1}, [], "If time_s is in milliseconds, divide it by 1000"),
        ({"huge": 1}, [], "beyond the 200 no car reaches"),
        ({}, ["twice"], "hold the same log"),
        ({}, ["--fit-vehicle"], "--fit-vehicle fits the paper law's understeer gradient"),
        ({}, ["paper-only-base"], "no [tyres] and [steering_system] tables"),
    ],
)  # fmt: skip
def test_bad_input_to_the_physical_fit_is_named_and_nothing_is_lost(
    tmp_path, capsys, edit, extra, message
):
    log = weave_log(tmp_path, **edit)
    args = [log]
    if "twice" in extra:
        args.append(str(tmp_path / "copy.csv"))
        (tmp_path / "copy.csv").write_bytes(Path(log).read_bytes())
    if "--fit-vehicle" in extra:
        args.append("--fit-vehicle")
    if "paper-only-base" in extra:
        car = base_car()
        base = tmp_path / "paper-only.toml"
        base.write_text(to_toml("paper-only", "a car without the physical tables", {
            "vehicle": car.vehicle, "torque": car.torque, "driver": car.driver}))  # fmt: skip
        args += ["--base", str(base)]
    out = tmp_path / "mine.toml"
    out.write_text("# the user's own preset\n")
    code = main(["fit", "steering", *args, "--steering-model", "physical", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and "Traceback" not in err
    assert out.read_text() == "# the user's own preset\n"


def test_validate_refuses_a_preset_without_the_physical_model(tmp_path, capsys):
    log = weave_log(tmp_path)
    for preset, message in (
        ("paper-first-gear", "needs a steering (car) preset"),
        (None, "no [tyres] and [steering_system] tables"),
    ):
        if preset is None:
            car = base_car()
            path = tmp_path / "paper-only.toml"
            path.write_text(to_toml("paper-only", "no physical tables", {
                "vehicle": car.vehicle, "torque": car.torque, "driver": car.driver}))  # fmt: skip
            preset = str(path)
        report = tmp_path / "report"
        code = main(["validate", "--steering-model", "physical", "--preset", preset, log,
                     "--report", str(report)])  # fmt: skip
        err = capsys.readouterr().err
        assert code == 2 and message in err, err
        assert not (report / "index.html").exists()


def test_the_fit_refuses_a_base_without_the_physical_model():
    car = base_car()
    paper_only = dataclasses.replace(car, tyres=None, steering_system=None)
    with pytest.raises(InputError, match=re.escape("no [tyres] and [steering_system] tables")):
        fit_physical(measured(clean_runs(("weave",))), paper_only)


def test_the_true_car_differs_from_the_base_in_every_fitted_parameter():
    """Else the acceptance test would pass by staying at the base."""
    base, truth = base_car(), true_car()
    for p in PARAMETERS:
        a, b = physical_fit.value_of(base, p), physical_fit.value_of(truth, p)
        assert abs(a - b) >= 0.1 * abs(b), p.name


def test_a_long_gap_starts_the_model_again_and_its_start_is_not_scored():
    """A 2 s dropout (over GAP_RESTART_S) cuts a log into two stretches, each simulated from
    the model's own start, whose first SETTLE_S is not scored; a 0.2 s one is bridged."""
    (log,) = measured(clean_runs(("fast-sine-80kmh",)), noise=False)
    t = log.time_s
    for gap_s, stretches in ((2.0, 2), (0.2, 1)):
        keep = (t < 3.0) | (t >= 3.0 + gap_s)
        cut = dataclasses.replace(
            log, time_s=t[keep], speed_m_s=log.speed_m_s[keep], angle_rad=log.angle_rad[keep],
            rate_rad_s=log.rate_rad_s[keep], torque_Nm=log.torque_Nm[keep],
            lateral_accel_m_s2=None,
        )  # fmt: skip
        runs = runs_of([cut])
        assert len(runs) == stretches
        data = physical_fit._data([cut], runs, None)
        starts = [cut.time_s[run.samples.start] for run in runs]
        scored = data.time_s
        for start in starts:
            assert not np.any((scored >= start) & (scored < start + physical_fit.SETTLE_S))
        assert len(scored) == sum(
            int(np.sum(cut.time_s[r.samples] >= s + physical_fit.SETTLE_S))
            for r, s in zip(runs, starts, strict=True)
        )


def test_without_logged_ay_the_excitation_of_mu_is_judged_on_the_base_model():
    """The limit run without its Ay column: the base model's Ay (driven by the logged angle)
    goes past 0.6 g, so mu is fitted; the weave's stays under it, so mu is kept."""
    base = base_car()
    limit = measured(clean_runs(("limit",)), noise=False, with_ay=False)
    weave = measured(clean_runs(("weave",)), noise=False, with_ay=False)
    index = NAMES.index("friction_coefficient")
    for logs, kept in ((limit, False), (weave, True)):
        runs = runs_of(logs)
        ref = reference(base.physical(), runs)
        sim = [ref.lateral_accel_m_s2[0]]
        assert (index in physical_fit.excitation(logs, sim, base)) == kept
