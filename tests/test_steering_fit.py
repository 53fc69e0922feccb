"""Fitting K1..K9 to logs: round trips with known parameters, noise, offsets, outliers, gaps."""

from __future__ import annotations

import dataclasses
import functools
import math
import re

import numpy as np
import pytest

from carfeel.errors import InputError
from carfeel.identification.steering_fit import fit_steering, read_log
from carfeel.io.presets import load_steering
from carfeel.simulation import manoeuvres
from carfeel.simulation.result import Result
from carfeel.simulation.steering import simulate_steering

TRUE = dict(
    k1_Nm_s2_m=1.9, k2=0.25, k3=1.0, k4_1_Nm=0.5, k5_s_m_Nm=0.2, k6_rad_s=0.7, k7_Nm=0.6,
    k8_rad_s=0.08, k9_Nm_s_rad=0.12,
)  # fmt: skip
# Sensor noise (1 sigma) and errors as an instrumented car would have them: a measurement
# steering wheel (torque 0.05 Nm, encoder angle 0.02 deg, its rate 0.05 deg/s), a GPS/IMU speed
# (0.05 m/s, about 0.2 km/h) and an IMU's lateral acceleration (0.05 m/s^2, 5 mg).
NOISE = {"speed": 0.05, "angle_deg": 0.02, "torque": 0.05, "ay": 0.05, "rate_deg_s": 0.05}
ANGLE_OFFSET_DEG, TORQUE_BIAS_NM, RATE_DIVIDER = 0.3, 0.05, 5  # 1 kHz model -> 200 Hz logs


@functools.cache
def car():
    base = load_steering().params
    return base, dataclasses.replace(base, torque=dataclasses.replace(base.torque, **TRUE))


@functools.cache
def clean_runs(names=("weave", "steer-cycle", "iso4138", "iso7401-step", "iso3888")):
    _, truth = car()
    runs = []
    for name in names:
        full = simulate_steering(truth, manoeuvres.build(name, truth.vehicle))
        for segment in dict.fromkeys(full["segment"].tolist()):  # ISO 4138: left, right
            keep = full["segment"] == segment
            runs.append((f"{name}-{segment}", Result(full.time_s[keep], {
                k: v[keep] for k, v in full.signals.items()})))  # fmt: skip
    return tuple(runs)


def measured(runs, seed=0, with_ay=True, spikes=0, gap=False, rate=False, delay_s=0.0):
    """The runs as a logger would give them: 200 Hz, noise on every channel, an angle offset, a
    torque bias; with `rate` a logged rate channel; with `delay_s` the torque logged late."""
    rng = np.random.default_rng(seed)
    logs = []
    for name, r in runs:
        idx = np.arange(0, len(r), RATE_DIVIDER)
        if gap:
            idx = np.concatenate([idx[: len(idx) // 3], idx[len(idx) // 3 + 40 :]])
        n = idx.size
        late = np.interp(r.time_s[idx] - delay_s, r.time_s, r["torque_Nm"])
        torque = late + TORQUE_BIAS_NM + rng.normal(0, NOISE["torque"], n)
        if spikes:
            torque[rng.choice(n, spikes, replace=False)] += rng.choice([-8.0, 8.0], spikes)
        signals = {
            "speed_m_s": r["speed_m_s"][idx] + rng.normal(0, NOISE["speed"], n),
            "steering_angle_rad": r["steering_angle_rad"][idx]
            + np.radians(ANGLE_OFFSET_DEG + rng.normal(0, NOISE["angle_deg"], n)),
            "steering_torque_Nm": torque,
        }
        if rate:
            signals["steering_rate_rad_s"] = r["steering_rate_rad_s"][idx] + np.radians(
                rng.normal(0, NOISE["rate_deg_s"], n)
            )
        if with_ay:
            signals["lateral_accel_m_s2"] = r["lateral_accel_m_s2"][idx] + rng.normal(
                0, NOISE["ay"], n
            )
        logs.append(read_log(Result(r.time_s[idx], signals), name))
    return logs


def by_name(fit):
    return {e.name: e for e in fit.estimates}


@functools.cache
def excitation_runs():
    """clean_runs and what pins the tyre spin's speed term K5 and the damping K9: a parking
    cycle at 6 km/h beside the one at standstill, and an ISO 7401 frequency sweep at 60 km/h."""
    _, truth = car()
    extra = []
    for name, kmh in (("steer-cycle", 6.0), ("iso7401-sweep", None)):
        full = simulate_steering(truth, manoeuvres.build(name, truth.vehicle, kmh))
        extra.append((f"{name}-{kmh or 60:g}kmh", Result(full.time_s, {
            k: v for k, v in full.signals.items() if k != "segment"})))  # fmt: skip
    return (*clean_runs(), *extra)


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_noise_on_every_channel_leaves_each_k_within_3_percent_and_2_sigmas():
    """The issue's acceptance: noise on torque, angle, rate, speed and Ay (levels above), an
    angle offset and a torque bias. Before the regressors were conditioned, 0.05 m/s of speed
    noise alone moved K5 by -19 % and K4 by -3.7 %, Ay noise K2 by -6 %. Measured over 4 seeds
    with the new fit: every K within 1.3 %, the scatter matching the reported sigmas."""
    base, _ = car()
    fit = fit_steering(measured(excitation_runs(), rate=True), base)
    got = by_name(fit)
    within = 0
    for name, truth in TRUE.items():
        assert got[name].status == "fitted", name
        assert got[name].value == pytest.approx(truth, rel=0.03), name
        within += abs(got[name].value - truth) <= 2 * got[name].sigma
    assert within >= 8
    assert fit.torque_offset_Nm == pytest.approx(TORQUE_BIAS_NM, abs=0.02)
    # The residual is the sensors' noise: 0.05 Nm of torque and what is left of 0.05 m/s^2 of
    # Ay times K1 after its 4 Hz low-pass (about 0.02 Nm); allow 30 % for the rest.
    assert fit.rms_error_Nm < 1.3 * np.hypot(NOISE["torque"], 0.02)
    assert fit.r2 > 0.99
    assert fit.warnings == ()


def test_a_rate_derived_from_a_noisy_angle_still_recovers_the_parameters():
    base, _ = car()
    got = by_name(fit_steering(measured(clean_runs()), base))
    # The derived rate's noise (about 0.2 deg/s from 0.02 deg over 81 ms) blurs the rate near
    # zero, where the friction's sharp scale K8 and the tyre spin's speed term K5 are seen: 30 %
    # for those two (measured +23 % on K5), 10 % for the others.
    for name, truth in TRUE.items():
        tolerance = 0.3 if name in ("k5_s_m_Nm", "k8_rad_s") else 0.1
        assert got[name].value == pytest.approx(truth, rel=tolerance), name


def test_outliers_and_gaps_do_not_drag_the_fit():
    base, _ = car()
    clean = by_name(fit_steering(measured(clean_runs()), base))
    dirty = by_name(fit_steering(measured(clean_runs(), spikes=20, gap=True), base))
    # 20 spikes of 8 Nm per log and a 0.2 s dropout: the soft_l1 loss keeps K1 within 3 % of
    # the clean fit's, the friction within 10 %.
    assert dirty["k1_Nm_s2_m"].value == pytest.approx(clean["k1_Nm_s2_m"].value, rel=0.03)
    assert dirty["k7_Nm"].value == pytest.approx(clean["k7_Nm"].value, rel=0.1)


def test_what_the_logs_cannot_identify_is_kept_only_where_the_data_accept_the_base():
    """A weave alone: no parking (the tyre spin K4..K6), Ay under 3 m/s^2 (the saturation K2,
    K3). Whatever is kept from the base says so with the test that let it (the data fit as well
    with it held there: likelihood ratio p > 0.05) and has no sigma; whatever the test refused
    is fitted, with its sigma and a note saying the base's value fits worse. The tyre spin is
    kept here (p 0.99: at 100 km/h the weave cannot tell it), the saturation is not (the
    base's, kept unasked, biased K1 by 9 % at 47 sigma on a real weave)."""
    from carfeel.identification.steering_fit import LOWER, UPPER

    base, _ = car()
    weave_only = [run for run in clean_runs() if run[0].startswith("weave")]
    fit = fit_steering(measured(weave_only), base)
    got = by_name(fit)
    for name in ("k4_1_Nm", "k5_s_m_Nm", "k6_rad_s"):
        assert got[name].status == "kept", name
        assert got[name].value == getattr(base.torque, name) != TRUE[name], name
        assert math.isnan(got[name].sigma)
        assert "almost no parking" in got[name].note and "likelihood ratio p = " in got[name].note
    assert any("k4_1_Nm, k5_s_m_Nm, k6_rad_s not identifiable" in w for w in fit.warnings)
    tested = {name for t in fit.keep_tests for name in t.held}
    for e in fit.estimates:
        if e.status == "kept":
            assert e.name in tested and "fit is as good" in e.note, e.name
        elif e.name in tested:  # refused by the test: fitted, with its interval
            assert "fits significantly worse" in e.note and e.sigma > 0, e.name
        if e.status == "fitted":  # written at a bound only with the reason
            i = list(by_name(fit)).index(e.name)
            assert e.value not in (LOWER[i], UPPER[i]) or "at its bound" in e.note, e.name
    assert got["k2"].status == "fitted" and got["k2"].sigma > 0
    # The preset predicts its logs no worse than the free fit (the kept values cost nothing).
    assert fit.rms_error_Nm <= 1.01 * fit.free_fit["rms_error_Nm"]


def test_without_measured_ay_the_car_model_supplies_it_and_can_be_fitted():
    base, truth = car()
    logs = measured(clean_runs(), with_ay=False)
    fit = fit_steering(logs, base, fit_vehicle=True)
    got = by_name(fit)
    # Ay from the steady-state car where the logs had the transient one: K1 within 15 %, the
    # understeer gradient within 15 % (the transient runs' lag and the angle offset).
    assert got["k1_Nm_s2_m"].value == pytest.approx(TRUE["k1_Nm_s2_m"], rel=0.15)
    k_us = truth.vehicle.understeer_gradient_rad_s2_m
    assert got["understeer_gradient_rad_s2_m"].value == pytest.approx(k_us, rel=0.15)
    assert fit.car.vehicle.understeer_gradient_rad_s2_m == pytest.approx(
        got["understeer_gradient_rad_s2_m"].value, rel=1e-9
    )


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda s: s.pop("steering_torque_Nm"), "missing column(s) steering_torque_Nm"),
        (lambda s: s.update(steering_angle_rad=np.degrees(s["steering_angle_rad"])),
         "looks like degrees"),
        (lambda s: s.update(speed_m_s=s["speed_m_s"] + 30.0 * 3.6), "looks like km/h"),
        (lambda s: s.update(steering_torque_Nm=np.full_like(s["speed_m_s"], np.nan)),
         "more than half of the rows hold NaN"),
    ],
)  # fmt: skip
def test_malformed_logs_are_named(edit, message):
    _, r = next(run for run in clean_runs() if run[0].startswith("steer-cycle"))
    signals = {
        "speed_m_s": r["speed_m_s"].copy(),
        "steering_angle_rad": r["steering_angle_rad"].copy(),
        "steering_torque_Nm": r["torque_Nm"].copy(),
    }
    edit(signals)
    with pytest.raises(InputError, match=re.escape(message)):
        read_log(Result(r.time_s, signals), "log.csv")


def test_time_going_backwards_is_named():
    _, r = clean_runs()[0]
    time = r.time_s.copy()
    time[100] = time[99]
    signals = {"speed_m_s": r["speed_m_s"], "steering_angle_rad": r["steering_angle_rad"],
               "steering_torque_Nm": r["torque_Nm"]}  # fmt: skip
    with pytest.raises(InputError, match="line 102: time_s does not increase"):
        read_log(Result(time, signals), "log.csv")


def write_logs(folder, logs_from=("weave", "steer-cycle", "iso4138-left", "iso3888")):
    """Measured-style CSV logs of the true car (200 Hz, noise, offsets) in `folder`."""
    paths = []
    chosen = [run for run in clean_runs() if any(run[0].startswith(n) for n in logs_from)]
    for log in measured(chosen, seed=3):
        path = folder / f"{log.name}.csv"
        Result(log.time_s, {
            "speed_m_s": log.speed_m_s, "steering_angle_rad": log.angle_rad,
            "steering_torque_Nm": log.torque_Nm, "lateral_accel_m_s2": log.lateral_accel_m_s2,
        }).to_csv(path)  # fmt: skip
        paths.append(str(path))
    return paths


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_fit_and_validate_from_the_command_line(tmp_path, capsys):
    import json

    from carfeel.cli import main
    from carfeel.io.presets import load_steering as load

    paths = write_logs(tmp_path)
    preset, fit_report, check = tmp_path / "mine.toml", tmp_path / "fit", tmp_path / "check"
    assert main(["fit", "steering", *paths, "--out", str(preset), "--report", str(fit_report),
                 "--json"]) == 0  # fmt: skip
    figures = json.loads(capsys.readouterr().out)
    assert figures["r2"] > 0.99 and figures["rms_error"] < 0.2
    # The correlations of the fitted parameters: a symmetric matrix with a unit diagonal.
    names, matrix = figures["correlation"]["parameters"], np.array(figures["correlation"]["matrix"])
    assert "k1_Nm_s2_m" in names and matrix.shape == (len(names), len(names))
    assert np.allclose(np.diag(matrix), 1.0, atol=1e-3) and np.allclose(matrix, matrix.T)
    fitted = load(str(preset)).params.torque
    assert fitted.k1_Nm_s2_m == pytest.approx(TRUE["k1_Nm_s2_m"], rel=0.1)
    assert (fit_report / "index.html").is_file()
    assert len(list(fit_report.glob("*.png"))) == len(paths)
    # The written preset runs, and validates against the logs it came from.
    assert main(["simulate", "steering", "--manoeuvre", "weave", "--preset", str(preset),
                 "--out", str(tmp_path / "w.csv")]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["validate", "--preset", str(preset), *paths, "--report", str(check),
                 "--json"]) == 0  # fmt: skip
    checked = json.loads(capsys.readouterr().out)
    comparison = checked.pop("comparison")
    # The headline has no offset removed: the logs' 0.05 Nm bias is an error of the preset's.
    assert all(v["r2"] > 0.99 for v in checked.values())
    assert all(v["r2_offset_removed"] >= v["r2"] for v in checked.values())
    # Beside the black boxes on each log's last 30 %: the law of the logs' own car wins.
    assert comparison["model"]["all"]["r2"] > comparison["lagged ridge"]["all"]["r2"]
    assert comparison["model"]["all"]["r2"] > comparison["linear"]["all"]["r2"]
    page = (check / "index.html").read_text()
    assert "torque gradient at 0 g (Nm/g)" in page and "measured" in page
    assert page.count("<tr>") == page.count("</tr>")  # issue 11: rows were left open
    # Only the metrics a log gives are rows; the rest are named once, with the reason.
    assert "<td>n/a</td><td>n/a</td>" not in page
    assert "Feel metrics not given for this log" in page and "this run is not one" in page
    fit_page = (fit_report / "index.html").read_text()
    assert "<th>what it is</th>" in fit_page and "K4, tyre spin at standstill" in fit_page


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_malformed_logs_exit_2_from_the_command_line(tmp_path, capsys):
    from carfeel.cli import main

    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,speed_m_s\n0,1\n")
    assert main(["fit", "steering", str(bad), "--out", str(tmp_path / "p.toml")]) == 2
    assert "missing column(s) steering_angle_rad" in capsys.readouterr().err
    assert main(["validate", "--preset", "b-segment", str(tmp_path / "none.csv"),
                 "--report", str(tmp_path / "r")]) == 2  # fmt: skip
    assert "no such file" in capsys.readouterr().err
    broken = tmp_path / "broken.toml"
    broken.write_text("not toml [")
    assert (
        main(["validate", "--preset", str(broken), str(bad), "--report", str(tmp_path / "r")]) == 2
    )
    err = capsys.readouterr().err
    assert err.count("not valid TOML") == 1 and not (tmp_path / "r").exists()
    european = tmp_path / "semicolons.csv"
    european.write_text("time_s;speed_m_s;steering_angle_rad;steering_torque_Nm\n0;1,5;0;0\n")
    assert main(["fit", "steering", str(european), "--out", str(tmp_path / "p.toml")]) == 2
    assert "carfeel reads comma-separated CSV" in capsys.readouterr().err
    paths = write_logs(tmp_path, logs_from=("weave", "iso4138-left"))
    assert main(["fit", "steering", *paths, "--out", str(tmp_path / "p.toml")]) == 0
    summary = capsys.readouterr().out
    # weave + ISO 4138: no parking, so K4..K6 are kept (and what else the two cannot place)
    assert "of 11 parameters" in summary and "kept from the base" in summary


def weave_signals(degrees=False, km_h=False, flip_torque=False):
    """The true car's weave as a log with measured Ay, optionally in the wrong units/sign."""
    _, r = next(run for run in clean_runs() if run[0].startswith("weave"))
    angle = r["steering_angle_rad"]
    return r.time_s, {
        "speed_m_s": r["speed_m_s"] * (3.6 if km_h else 1.0),
        "steering_angle_rad": np.degrees(angle) if degrees else angle,
        "steering_torque_Nm": r["torque_Nm"] * (-1.0 if flip_torque else 1.0),
        "lateral_accel_m_s2": r["lateral_accel_m_s2"],
    }


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        # The weave's 12 degrees are a plausible angle in radians too: only Ay gives it away.
        ({"degrees": True}, "looks like degrees"),
        ({"flip_torque": True}, "flip the sign of steering_torque_Nm"),
    ],
)
def test_units_and_signs_that_fit_well_but_wrongly_are_refused(kwargs, message):
    base, _ = car()
    time, signals = weave_signals(**kwargs)
    log = read_log(Result(time, signals), "weave.csv")
    with pytest.raises(InputError, match=re.escape(message)):
        fit_steering([log], base)


def test_km_h_read_as_m_s_is_warned_about():
    # At 100 km/h understeer makes the measured Ay 0.53x the steady state from a speed read 3.6x
    # too high: within what another car could give, so a warning, not a refusal. The warnings
    # come from the checks before the fit (`_check_units`, which `fit_steering` returns them
    # from): checked there, without a fit that costs seconds and adds nothing.
    from carfeel.identification.steering_checks import check_units as _check_units

    base, _ = car()
    time, signals = weave_signals(km_h=True)
    warnings = _check_units([read_log(Result(time, signals), "weave.csv")], base.vehicle)
    assert any("if it is in km/h, divide it by 3.6" in w for w in warnings)
    assert any("the measured Ay is 0.527 times" in w for w in warnings)


def test_an_angle_in_degrees_without_ay_is_refused_before_the_fit():
    """Issue 11: a weave in degrees without an Ay column fitted to r2 0.9986 and wrote a preset
    from angles of 11.7 "rad", beyond the car's 9.4 rad lock. Refused by name now, before any
    fitting; and inside the lock (half the weave: 5.8 "rad"), the Ay the car would need at that
    angle (5.7 g) gives it away."""
    base, _ = car()
    time, signals = weave_signals(degrees=True)
    del signals["lateral_accel_m_s2"]
    log = read_log(Result(time, signals), "weave.csv")
    with pytest.raises(
        InputError,
        match=r"weave\.csv: steering_angle_rad reaches 11\.\d+, beyond "
        r"the base car's lock of 9\.425 rad \(540 deg\): that looks like degrees",
    ):
        fit_steering([log], base)
    signals["steering_angle_rad"] = 0.5 * signals["steering_angle_rad"]
    log = read_log(Result(time, signals), "weave.csv")
    with pytest.raises(
        InputError,
        match=r"without a lateral_accel_m_s2 column Ay comes from the "
        r"base car.*reaches 5\.\d+ g.*steering_angle_rad looks like degrees",
    ):
        fit_steering([log], base)


def test_logs_in_radians_without_ay_pass_the_unit_checks():
    """The refusals above do not catch good logs: every test manoeuvre (parking to the lock, the
    lane change at 0.76 g) without its Ay column, with the noise and offsets of `measured`."""
    from carfeel.identification.steering_checks import check_units as _check_units

    base, _ = car()
    for seed in (0, 1):
        _check_units(measured(excitation_runs(), seed=seed, with_ay=False), base.vehicle)


def test_fit_vehicle_with_a_measured_ay_names_the_fix():
    base, _ = car()
    time, signals = weave_signals()
    log = read_log(Result(time, signals), "weave.csv")
    with pytest.raises(InputError, match=r"every log has lateral_accel_m_s2.*without --fit-veh"):
        fit_steering([log], base, fit_vehicle=True)


def test_a_torque_channel_that_logged_nothing_is_named():
    """Issue 11: all-zero torque was reported as the opposite sign of Ay."""
    time, signals = weave_signals()
    signals["steering_torque_Nm"] = np.zeros_like(time)
    with pytest.raises(InputError, match="steering_torque_Nm is 0 Nm in every row: the channel "
                       "logged nothing"):  # fmt: skip
        read_log(Result(time, signals), "zero.csv")
    from carfeel.identification.steering_checks import check_units as _check_units

    # Zero only where the car corners (a channel that drops out): not a sign flip either.
    base, _ = car()
    time, signals = weave_signals()
    corner = np.abs(signals["lateral_accel_m_s2"]) > 1.0
    signals["steering_torque_Nm"] = np.where(corner, 0.0, signals["steering_torque_Nm"])
    with pytest.raises(InputError, match=r"exactly 0 in \d+% of the steady cornering"):
        _check_units([read_log(Result(time, signals), "drop.csv")], base.vehicle)


def test_time_in_milliseconds_is_named():
    time, signals = weave_signals()
    with pytest.raises(InputError, match="If time_s is in milliseconds, divide it by 1000"):
        read_log(Result(time * 1000.0, signals), "log.csv")


def test_carfeels_own_torque_column_is_accepted():
    time, signals = weave_signals()
    signals["torque_Nm"] = signals.pop("steering_torque_Nm")
    log = read_log(Result(time, signals), "weave.csv")
    assert np.array_equal(log.torque_Nm, signals["torque_Nm"])


def test_a_parameter_the_data_cannot_see_is_kept_from_the_base_and_marked():
    """Parking at a standstill, no Ay column: the base car's Ay is 0 throughout, so K1..K3
    multiply zero and nothing in the data moves them: held at the base's values the fit is
    exactly as good (p about 1). (With a measured Ay, its noise at rest would be the
    regressor: the classic errors in variables, which take K1 to 0 on noise alone.)"""
    base, _ = car()
    parking = [run for run in clean_runs() if run[0].startswith("steer-cycle")]
    fit = fit_steering(measured(parking, with_ay=False), base)
    for name in ("k1_Nm_s2_m", "k2", "k3"):
        kept = by_name(fit)[name]
        assert kept.status == "kept" and kept.value == getattr(base.torque, name), name
        assert "held at the base's value the fit is as good" in kept.note, name
    assert by_name(fit)["k4_1_Nm"].status == "fitted"
    assert any(w.startswith("k1_Nm_s2_m") and "not identifiable" in w for w in fit.warnings)


def test_an_ay_channel_that_logged_nothing_is_refused():
    """A weave at 100 km/h with Ay 0 in every row: a channel that logged nothing (the fit
    made a spring of the friction's memory to explain the aligning torque)."""
    time, signals = weave_signals()
    signals["lateral_accel_m_s2"] = np.zeros_like(time)
    message = r"lateral_accel_m_s2 is 0 m/s\^2 in every row while the car drives: the channel"
    with pytest.raises(InputError, match=message + r" logged nothing.*leave the column out"):
        read_log(Result(time, signals), "no-ay.csv")


def test_one_log_in_degrees_among_good_ones_is_refused_by_name():
    base, _ = car()
    time, signals = weave_signals(degrees=True)
    logs = [*measured(clean_runs()), read_log(Result(time, signals), "weave-in-degrees.csv")]
    with pytest.raises(InputError, match=r"weave-in-degrees\.csv: .*looks like degrees"):
        fit_steering(logs, base)


def test_a_steady_circle_one_way_is_not_taken_for_a_flipped_sign():
    """A log at nearly constant Ay: a slope of torque on Ay would be noise there (and refused
    4 seeds in 20); the sign test sees +4 Nm with +3 m/s^2 on every seed."""
    from carfeel.identification.steering_checks import check_units as _check_units

    base, _ = car()
    name, r = next(run for run in clean_runs() if run[0] == "iso4138-left")
    keep = (r.time_s > 26.6) & (r.time_s < 30.4)
    circle = ((name, Result(r.time_s[keep], {k: v[keep] for k, v in r.signals.items()})),)
    for seed in range(20):
        for with_ay in (True, False):
            _check_units(measured(circle, seed=seed, with_ay=with_ay), base.vehicle)
    flipped = measured(circle, seed=0)[0]
    flipped = dataclasses.replace(flipped, torque_Nm=-flipped.torque_Nm)
    with pytest.raises(InputError, match="flip the sign"):
        _check_units([flipped], base.vehicle)


def test_json_has_null_for_a_kept_parameters_sigma(tmp_path, capsys):
    import json

    from carfeel.cli import main

    paths = write_logs(tmp_path, logs_from=("weave",))  # a weave at speed: no parking for K4..K6
    assert main(["fit", "steering", *paths, "--out", str(tmp_path / "p.toml"), "--json"]) == 0
    printed = capsys.readouterr().out
    fitted = json.loads(printed, parse_constant=lambda token: pytest.fail(f"{token} in JSON"))
    assert fitted["parameters"]["k4_1_Nm"]["sigma"] is None
    assert fitted["parameters"]["k4_1_Nm"]["status"] == "kept"
    assert fitted["parameters"]["k1_Nm_s2_m"]["status"] == "fitted"
    assert fitted["parameters"]["k1_Nm_s2_m"]["sigma"] > 0.0
    assert fitted["sigmas_conditional_on_kept"] is True
    assert any(t["kept"] for t in fitted["keep_tests"])


def straight_drive(seconds=40.0, seed=4):
    """Driving straight at 20 m/s, no Ay column: the wheel within the angle sensor's noise, the
    torque its own noise about a 0.05 Nm bias. Nothing in it moves any term of the law."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 0.005)
    return Result(t, {
        "speed_m_s": 20.0 + rng.normal(0, 0.05, t.size),
        "steering_angle_rad": np.radians(rng.normal(0, 0.02, t.size)),
        "steering_torque_Nm": 0.05 + rng.normal(0, 0.05, t.size),
    })  # fmt: skip


def test_a_log_that_identifies_nothing_writes_no_preset(tmp_path, capsys):
    """A straight drive, on two noise seeds. Seed 5: every term held at the base's values fits
    as well as free (the free fit explains nothing but noise either), so the preset would be the
    base's: none is written, and the message quotes the base's r2 as the base's (issue 25: it
    read as the fit's). Seed 4: the keep test refuses the base's K1 (2.4) against the 0.29 +-
    0.28 the angle sensor's noise gives, so one parameter is "fitted"; the law then removes
    0.07 % of the torque's variance, and the test of the law against none refuses it (before
    it, a preset with K1 0.29 was written: exit 0)."""
    from carfeel.cli import main

    seen = set()
    for seed in (4, 5):
        path = tmp_path / f"straight-{seed}.csv"
        straight_drive(seed=seed).to_csv(path)
        out = tmp_path / f"p-{seed}.toml"
        assert main(["fit", "steering", str(path), "--out", str(out)]) == 2, seed
        err = capsys.readouterr().err
        assert "Traceback" not in err and not out.exists()
        if "none of the law's parameters" in err:
            seen.add("base")
            assert re.search(r"the base preset b-segment's law explains r2 -?\d\.\d+ of them",
                             err), err  # fmt: skip
            assert "the free fit's" in err and "not significantly better" in err
        else:
            seen.add("no law")
            assert "the logs identify no steering feel" in err, err
            assert re.search(
                r"the fitted law \(r2 -?\d\.\d+; every parameter free, r2 "
                r"-?\d\.\d+\) removes -?\d\.\d+% of the torque's variance",
                err,
            ), err
    assert seen == {"base", "no law"}  # both refusals met (which seed gives which: docstring)


def test_the_analytic_jacobian_matches_finite_differences():
    """Every column, the friction memory's K10 and K11 (its own sensitivity recurrence) too."""
    from carfeel.identification.steering_fit import PAPER_LAW, Regressors

    rng = np.random.default_rng(4)
    n = 400
    speed, rate = rng.uniform(0, 40, n), rng.normal(0, 1.0, n)
    ay = rng.normal(0, 4.0, n)
    starts = np.zeros(n, dtype=bool)
    starts[[0, 200]] = True  # two stretches: the memory starts from rest in each
    r = Regressors(speed, rate, ay, np.where(starts, 0.0, np.abs(rate) * 0.01), starts)
    x = np.array([*TRUE.values(), 0.4, 0.03])
    analytic = PAPER_LAW.jacobian(x, r)
    for j in range(len(x)):
        h = 1e-6 * max(abs(x[j]), 1e-3)
        up, down = x.copy(), x.copy()
        up[j] += h
        down[j] -= h
        numeric = PAPER_LAW.torque(up, r) - PAPER_LAW.torque(down, r)
        numeric /= 2 * h
        # Central differences are good to about h^2 and 1e-10 / h of rounding: 1e-5 of the scale.
        assert np.allclose(analytic[:, j], numeric, rtol=1e-5, atol=1e-6 * np.abs(numeric).max())


def test_a_log_with_a_gap_shifts_each_channel_by_its_own_spline():
    """A log with a dropout is not uniformly sampled: its regressors are shifted through cubic
    splines, one per log and channel. They were cached by id() of a fresh slice, which the next
    channel's slice reused: the rate and Ay were shifted as the speed (a fit on gapped logs gave
    r2 -0.4 and K4 14 for 0.5, differing from run to run)."""
    from scipy.interpolate import CubicSpline

    from carfeel.identification.steering_fit import _data

    logs = measured(clean_runs(), gap=True)
    assert all(np.ptp(np.diff(log.time_s)) > 0.1 for log in logs)  # splines, not Catmull-Rom
    data = _data(logs, [log.lateral_accel_m_s2 for log in logs], None)
    for delay in (0.013, 0.021, 0.034):  # as a fit's steps do
        shifted = data.regressors(delay)
        for log, part in zip(logs, data.parts, strict=True):
            t = log.time_s - log.time_s[0]
            for got, values in ((shifted.speed, log.speed_m_s), (shifted.rate, log.rate_rad_s),
                                (shifted.ay, log.lateral_accel_m_s2)):  # fmt: skip
                expected = CubicSpline(t, values)(np.clip(t - delay, 0.0, t[-1]))
                assert np.allclose(got[part], expected, rtol=0,
                                   atol=1e-9 * np.abs(values).max()), (log.name, delay)  # fmt: skip


def test_a_torque_logged_late_is_found_and_corrected():
    base, _ = car()
    chosen = [r for r in clean_runs() if r[0].startswith(("weave", "steer-cycle", "iso3888",
                                                          "iso7401"))]  # fmt: skip
    fit = fit_steering(measured(chosen, rate=True, delay_s=0.04), base)
    # 40 ms, as a CAN message queued behind others; found within 5 ms (a sample is 5 ms).
    assert fit.torque_delay_s == pytest.approx(0.04, abs=0.005)
    assert by_name(fit)["k1_Nm_s2_m"].value == pytest.approx(TRUE["k1_Nm_s2_m"], rel=0.03)


def another_car(rear_scale=0.85, **torque):
    """A base that is not the true car: a softer rear axle (less understeer) and other K's."""
    base, _ = car()
    vehicle = dataclasses.replace(
        base.vehicle,
        rear_cornering_stiffness_N_rad=base.vehicle.rear_cornering_stiffness_N_rad * rear_scale,
    )
    law = dataclasses.replace(base.torque, k1_Nm_s2_m=3.0, k7_Nm=1.0, k9_Nm_s_rad=0.3, **torque)
    return dataclasses.replace(base, vehicle=vehicle, torque=law)


def test_fit_vehicle_from_another_base_finds_the_true_understeer():
    _, truth = car()
    other = another_car()
    k_us = truth.vehicle.understeer_gradient_rad_s2_m
    assert other.vehicle.understeer_gradient_rad_s2_m < 0.8 * k_us  # a start away from it
    chosen = [r for r in clean_runs() if r[0] != "iso4138-right"]  # the left turn suffices
    fit = fit_steering(measured(chosen, with_ay=False, rate=True), other, fit_vehicle=True)
    got = by_name(fit)
    # Ay from the transient car (not its steady state), so the phase of the lane change and the
    # step steer does not land in K7..K9; what is left is the angle offset of 0.3 deg (an Ay
    # offset growing with V^2 that the per-log torque offset absorbs only in part): 5 % on
    # K_us and K1, 10 % on the friction and damping.
    assert got["understeer_gradient_rad_s2_m"].value == pytest.approx(k_us, rel=0.05)
    assert got["k1_Nm_s2_m"].value == pytest.approx(TRUE["k1_Nm_s2_m"], rel=0.05)
    for name in ("k7_Nm", "k9_Nm_s_rad"):
        assert got[name].value == pytest.approx(TRUE[name], rel=0.1), name


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_base_another_car_from_the_command_line(tmp_path, capsys):
    import json

    from carfeel.cli import main
    from carfeel.io.presets import load_steering as load
    from carfeel.io.presets import to_toml

    other = another_car(rear_scale=0.9)
    base_path = tmp_path / "other-car.toml"
    base_path.write_text(to_toml("other-car", "a test car", {
        "vehicle": other.vehicle, "torque": other.torque, "driver": other.driver}))  # fmt: skip
    paths = write_logs(tmp_path, logs_from=("weave", "iso4138-left"))  # no parking
    out = tmp_path / "mine.toml"
    assert main(["fit", "steering", *paths, "--base", str(base_path), "--out", str(out),
                 "--json"]) == 0  # fmt: skip
    printed = json.loads(capsys.readouterr().out)
    written = load(str(out)).params
    # The fitted K's are the logs' car, not the base's; the tyre spin (no parking) is the base's
    # where the test accepts it, else the logs' own with the warning that it is extrapolated at
    # a standstill (here the base's K9 = 0.3 and K7 = 1.0 cannot stand in for the truth's
    # damping, so the logs' speeds place a spin term); the car (ratio, wheelbase, K_us) is the
    # base's.
    assert written.torque.k1_Nm_s2_m == pytest.approx(TRUE["k1_Nm_s2_m"], rel=0.05)
    for name in ("k4_1_Nm", "k5_s_m_Nm", "k6_rad_s"):
        entry = printed["parameters"][name]
        if entry["status"] == "kept":
            assert getattr(written.torque, name) == getattr(other.torque, name)
        else:
            assert any(f"{name}" in w and "extrapolated" in w for w in printed["warnings"])
    assert written.vehicle == other.vehicle


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_drift_and_cross_validation_from_the_command_line(tmp_path, capsys):
    """A torque offset wandering by +-0.4 Nm over a minute (road crown, a sensor's drift): fitted
    with --drift on the first 70 % of each log, validated on the rest, both figures side by side."""
    import json

    from carfeel.cli import main

    chosen = [r for r in clean_runs() if r[0].startswith(("weave", "steer-cycle", "iso3888"))]
    paths = []
    for log in measured(chosen, seed=9, rate=True):
        wander = 0.4 * np.sin(2 * np.pi * (log.time_s - log.time_s[0]) / 60.0)
        path = tmp_path / f"{log.name}.csv"
        Result(log.time_s, {
            "speed_m_s": log.speed_m_s, "steering_angle_rad": log.angle_rad,
            "steering_rate_rad_s": log.rate_rad_s, "steering_torque_Nm": log.torque_Nm + wander,
            "lateral_accel_m_s2": log.lateral_accel_m_s2,
        }).to_csv(path)  # fmt: skip
        paths.append(str(path))
    out, report_dir = tmp_path / "p.toml", tmp_path / "report"
    assert main(["fit", "steering", *paths, "--out", str(out), "--drift", "10", "--holdout",
                 "0.3", "--report", str(report_dir), "--json"]) == 0  # fmt: skip
    printed = json.loads(capsys.readouterr().out)
    assert printed["parameters"]["k1_Nm_s2_m"]["value"] == pytest.approx(1.9, rel=0.03)
    fitted, held = printed["cross_validation"]["fit"], printed["cross_validation"]["held_out"]
    assert len(fitted) == len(held) == len(paths)
    # Generalization: the held-out parts' rms, their own drifting offset removed, within 2.5x of
    # the fitted parts' (measured 1.4x on the weave and the lane change; 2.1x on the steer cycle,
    # whose held-out end has the wheel leave lock at 5 rad/s, a phase its fitted part holds
    # once). Not r2: the lane change's last 2 s hold little torque to explain. The headline
    # predicts the held-out part with the offset its fit part ended with: a wandering offset is
    # no one's to predict, so it is larger (0.17 Nm against 0.06 on the weave).
    for a, b in zip(fitted.values(), held.values(), strict=True):
        assert b["rms_error_offset_removed_Nm"] < 2.5 * a["rms_error_Nm"]
        assert b["rms_error_offset_removed_Nm"] <= b["rms_error_Nm"]
    page = (report_dir / "index.html").read_text()
    assert "Cross-validation" in page and "Parameter correlations" in page
    assert "held-out rms" in page
    # validate on the whole logs, with the logs' own drifting offset removed and reported.
    assert main(["validate", "--preset", str(out), *paths, "--drift", "10", "--report",
                 str(tmp_path / "v"), "--json"]) == 0  # fmt: skip
    checked = json.loads(capsys.readouterr().out)
    checked.pop("comparison")
    for name, figures in checked.items():
        assert figures["rms_error_offset_removed_Nm"] <= figures["rms_error_Nm"]
        if "weave" in name:  # longer than 1.5 knots: a drifting offset
            assert figures["offset_range_Nm"] > 0.1, name


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_reported_sigmas_match_the_errors_over_repeated_noisy_fits():
    """Four noise draws of the acceptance logs: the scatter of each estimate against the sigma
    the fit reports (a block sandwich). With 4 draws a sample spread is good to about 40 %, so
    the check pools the parameters: the mean of (spread / sigma)^2 within 0.3..3, and 80 % of
    the 36 errors within 2 reported sigmas (95 % expected of honest Gaussian sigmas; the margin
    is for the biases left, under a sigma: measured 0.9 of them)."""
    base, _ = car()
    values, sigmas = [], []
    for seed in range(20, 24):
        fit = fit_steering(measured(excitation_runs(), seed=seed, rate=True), base)
        values.append([by_name(fit)[n].value for n in TRUE])
        sigmas.append([by_name(fit)[n].sigma for n in TRUE])
    v, s = np.array(values), np.array(sigmas)
    truth = np.array(list(TRUE.values()))
    ratio = np.mean((np.std(v, axis=0, ddof=1) / np.median(s, axis=0)) ** 2)
    assert 0.3 < ratio < 3.0
    assert np.mean(np.abs(v - truth) <= 2 * s) >= 0.8


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_validate_gives_the_models_own_understeer_gradient_not_the_logs(tmp_path):
    """The law is driven with the log's angle and Ay, so an understeer gradient taken from them
    is the log's (it was, in the model column): the model's is its car's. A D-segment log
    against its own preset: the measured one agrees with the car's within 5 % (the steady
    states of a linear car); a B-segment log against the D-segment preset: the model column
    still gives the D-segment's 2.31 deg/g, the log's is 1.10 (with the D's geometry)."""
    from carfeel.identification.workflows import steering_sections

    d = load_steering("d-segment").params
    k_us = d.vehicle.understeer_gradient_deg_per_g
    for source, near in (("d-segment", True), ("b-segment", False)):
        car = load_steering(source).params
        run = simulate_steering(car, manoeuvres.build("iso4138", car.vehicle, None))
        sections, _ = steering_sections(d, [read_log(run, source)], tmp_path)
        row = next(r for r in sections[0].table if r[0].startswith("understeer gradient"))
        measured, model = float(row[1]), float(row[2])
        assert model == pytest.approx(k_us, rel=1e-3)
        assert (abs(measured / k_us - 1.0) < 0.05) == near, (source, measured, k_us)
        assert any("not one from this log" in line for line in sections[0].paragraphs)


# ---------------------------------------------------------------- issue 25: a fit to trust


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_a_law_shape_the_preset_lacks_is_fitted_not_replaced_by_the_base():
    """The Golf-like car (torque = 3.0 Nm x (Ay / 1.375 + 0.202 tanh(rate / 0.05)): linear
    aligning, a friction step, no tyre spin) through the five ISO manoeuvres with noise. The old
    rule kept K2..K9 from the base (the vanishing tyre spin's K4 "within one sigma of its bound"
    became the base's large one): K1 4.04 for 2.18, rms 1.56 Nm against 0.071 for the true law
    (measured on the code before the test). K1 must be within 8 % and the rms within 1.3 times
    the true law's at the same (conditioned) inputs, each log with its best constant offset."""
    from tests import steering_logs as logs_of

    base = logs_of.base_car()
    runs = logs_of.golf_runs()
    logs = logs_of.as_logs(logs_of.noisy(runs, seed=0), runs)
    fit = fit_steering(logs, base)
    assert fit.car.torque.k1_Nm_s2_m == pytest.approx(logs_of.GOLF_K1, rel=0.08)
    residuals = []
    for log in logs:
        error = log.torque_Nm - logs_of.golf_torque(log.rate_rad_s, log.lateral_accel_m_s2)
        residuals.append(error - error.mean())
    true_rms = float(np.sqrt(np.mean(np.concatenate(residuals) ** 2)))
    assert fit.rms_error_Nm < 1.3 * true_rms
    assert fit.rms_error_Nm <= 1.01 * fit.free_fit["rms_error_Nm"]
    # The linear aligning is the data's: K2 at its bound 0, said so.
    k2 = by_name(fit)["k2"]
    assert k2.status == "fitted" and k2.value < 1e-6 and "at its bound 0" in k2.note


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_every_fault_of_a_real_cars_sensors_leaves_the_law_within_its_sigmas():
    """Issue 25, point 2: the angle at a 0.1 deg resolution after 0.02 deg of noise and a 0.5
    deg offset, speed, Ay and torque noise and offsets, the torque logged 20 ms late, no rate
    column, through smooth manoeuvres (tests/steering_logs.smooth_runs). Before: K8 +36 % at 7.7
    sigma from the quantization alone, the delay found as 11.7 ms (12.7 on these logs) and K9
    -24 %. Measured (6 seeds, benchmarks/bench_fit_bias.py): every K within 3 %, K1..K3 within
    1.1 %, the delay within 0.2 ms. The test: seed 0 within 10 % (K1..K3 3 %) and 2 ms; over 3
    seeds the scatter of each K against its median sigma, pooled over K1..K9 (a spread from 3
    draws is good to 50 %): the mean of (scatter / sigma)^2 within 0.5^2..2^2."""
    from tests import steering_logs as logs_of

    base = logs_of.base_car()
    runs = logs_of.smooth_runs()
    values, sigmas = [], []
    for seed in range(3):
        fit = fit_steering(logs_of.as_logs(logs_of.faulty(runs, seed), runs), base)
        got = by_name(fit)
        if seed == 0:
            for name, truth in TRUE.items():
                tolerance = 0.03 if name in ("k1_Nm_s2_m", "k2", "k3") else 0.10
                assert got[name].status == "fitted", name
                assert got[name].value == pytest.approx(truth, rel=tolerance), name
            assert fit.torque_delay_s == pytest.approx(0.020, abs=0.002)
        values.append([got[n].value for n in TRUE])
        sigmas.append([got[n].sigma for n in TRUE])
    v, s = np.array(values), np.array(sigmas)
    ratio = np.mean((np.std(v, axis=0, ddof=1) / np.median(s, axis=0)) ** 2)
    assert 0.25 < ratio < 4.0


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_a_rate_derived_from_a_quantized_angle_keeps_the_friction_unbiased():
    """The quantization alone (0.1 deg, 0.02 deg of noise before it), nothing else: a fixed
    81 ms Savitzky-Golay derivative took K8 16 % high (5.6 sigma) and K7 3.3 %; the adaptive
    one keeps both within 3 %."""
    from tests import steering_logs as logs_of

    zero = {k: 0.0 for k in logs_of.FAULTS}
    quantized = {**zero, "angle_resolution_deg": 0.1, "angle_noise_deg": 0.02,
                 "torque_noise_Nm": 0.05}  # fmt: skip
    runs = logs_of.smooth_runs()
    fit = fit_steering(logs_of.as_logs(logs_of.faulty(runs, 1, faults=quantized), runs),
                       logs_of.base_car(), estimate_delay=False)  # fmt: skip
    for name in ("k7_Nm", "k8_rad_s"):
        assert by_name(fit)[name].value == pytest.approx(TRUE[name], rel=0.03), name


def test_a_kept_value_is_the_tests_and_the_report_says_the_sigmas_are_conditional(tmp_path, capsys):
    """The weave alone keeps the tyre spin (no parking): the JSON and the summary give the test,
    the free fit's figures and that the other sigmas are conditional on what is kept."""
    import json

    from carfeel.cli import main

    paths = write_logs(tmp_path, logs_from=("weave",))
    report = tmp_path / "report"
    assert main(["fit", "steering", *paths, "--out", str(tmp_path / "p.toml"), "--report",
                 str(report), "--json"]) == 0  # fmt: skip
    printed = json.loads(capsys.readouterr().out)
    assert printed["sigmas_conditional_on_kept"] is True
    kept = [t for t in printed["keep_tests"] if t["kept"]]
    assert kept and all(t["p_value"] > 0.01 for t in kept)
    assert {"k4_1_Nm", "k5_s_m_Nm", "k6_rad_s"} <= set(kept[-1]["held"])
    assert printed["free_fit"]["rms_error_Nm"] <= printed["rms_error"] * 1.0001
    page = (report / "index.html").read_text()
    assert "conditional on the values kept" in page and "free fit" in page
