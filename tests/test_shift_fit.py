"""fit_shift: a round trip through simulated engagements made noisy and resampled, robustness to
spikes and gaps, a single engagement, and malformed traces.

The truth is the shift loop (driver of eq. 10 + engagement model) with parameters unlike the
shipped preset's, stepped at 0.1 ms (substeps=10), which stands for the continuous physics of a
real gearbox: the fit simulates finely for the same reason (see FIT_STEP_S), so it recovers
physical values, not the 1 ms model's own discretization error. The measured traces are the
truth at 500 Hz, offset half a step from the model's samples, with 0.05 mm and 0.5 N of white
noise.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from typing import Any

import numpy as np
import pytest

from carfeel.errors import InputError
from carfeel.identification.shift_fit import ShiftFit, fit_shift
from carfeel.io.presets import check_shift, load_shift
from carfeel.models.drivers import shift as driver
from carfeel.models.rng import next_uniform, seed_state
from carfeel.simulation import shift
from carfeel.simulation.result import Result
from carfeel.simulation.runner import run
from carfeel.simulation.shift import ShiftParams

RATE_HZ = 500.0
POSITION_NOISE_M = 5e-5
FORCE_NOISE_N = 0.5
SEEDS = (11, 12)
ENGAGEMENTS_PER_TRACE = 3
DURATION_S = 3.2


@functools.cache
def truth() -> ShiftParams:
    base = load_shift().params
    g = base.gearbox
    gearbox = dataclasses.replace(
        g,
        synchronization_position_m=0.018,
        teeth_position_m=0.025,
        teeth_end_position_m=0.030,
        in_gear_position_m=0.043,
        synchronization_duration_s=0.25,
        stop=dataclasses.replace(g.stop, stiffness_N_m=45000.0),
        # The teeth's friction law the fit identifies (the preset's before issue 10); the
        # chamfers' indexing of the gear, which the fit does not model, is off.
        engagement=dataclasses.replace(
            g.engagement, static_friction_N=14.0, sliding_friction_N=12.0
        ),
        tooth_force_spread_N=10.0,
        chamfer=dataclasses.replace(g.chamfer, gear_inertia_kg_m2=0.0, drag_torque_Nm=0.0),
    )
    hand = dataclasses.replace(
        base.driver, push_force_N=70.0, pull_out=True, release_position_m=0.043, hold_s=0.2
    )
    params = ShiftParams(gearbox, hand)
    assert check_shift(params) == []
    return params


def push_again(pause_s: float = 0.15) -> Any:
    """The shift loop's step with a driver who pushes into gear again `pause_s` after pulling
    out: several engagements per trace, each with its own draw of the tooth force."""

    def step(state: shift.ShiftState, inputs: None, params: ShiftParams, dt_s: float) -> Any:
        hand = state.driver
        if hand.phase is driver.DriverPhase.IDLE and hand.phase_time_s >= pause_s:
            state = state._replace(driver=driver.initial_state(state.lever.position_m))
        return shift.step(state, inputs, params, dt_s)

    return step


@functools.cache
def clean(seed: int, duration_s: float = DURATION_S, repeat: bool = True) -> Result:
    """The truth at 1 kHz, stepped at 0.1 ms."""
    step = push_again() if repeat else shift.step
    result, _ = run(
        step, shift.initial_state(seed), truth(), duration_s=duration_s, dt_s=1e-3, substeps=10
    )
    return result


def measured(result: Result, seed: int, name: str | None = None) -> Result:
    """The result as a sensor logs it: resampled at 500 Hz, half a step off, with noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(result.time_s[0] + 0.5e-3, result.time_s[-1], 1.0 / RATE_HZ)
    x = np.interp(t, result.time_s, result["position_m"]) + rng.normal(0, POSITION_NOISE_M, t.size)
    f = np.interp(t, result.time_s, result["force_N"]) + rng.normal(0, FORCE_NOISE_N, t.size)
    return Result(t, {"position_m": x, "force_N": f}, {"name": name} if name else {})


def true_resistances(seed: int, count: int) -> list[float]:
    """The teeth's sliding resistance of each engagement: friction + U(0, 1) * spread, drawn
    from the seed's generator in the order the engagements happen."""
    g = truth().gearbox
    state, draws = seed_state(seed), []
    for _ in range(count):
        state, u = next_uniform(state)
        draws.append(g.engagement.sliding_friction_N + u * g.tooth_force_spread_N)
    return draws


def arrivals(result: Result) -> list[float]:
    """When the truth's lever entered synchronization."""
    stage = result["stage"]
    entered = (stage[1:] == "synchronization") & (stage[:-1] != "synchronization")
    return [float(t) for t in result.time_s[1:][entered]]


@pytest.fixture(scope="module")
def round_trip() -> ShiftFit:
    return fit_shift([measured(clean(seed), seed) for seed in SEEDS])


def test_the_truth_holds_three_engagements_per_trace():
    for seed in SEEDS:
        assert len(arrivals(clean(seed))) == ENGAGEMENTS_PER_TRACE
        assert clean(seed)["stage"].tolist().count("stop") > 0


def test_round_trip_finds_every_engagement_where_it_starts(round_trip: ShiftFit):
    found = round_trip.engagements
    assert len(found) == len(SEEDS) * ENGAGEMENTS_PER_TRACE
    for index, seed in enumerate(SEEDS):
        starts = [e.start_time_s for e in found if e.trace == index]
        # Within one sample: the arrival is the approach extrapolated to the ring.
        assert np.allclose(starts, arrivals(clean(seed)), atol=1.0 / RATE_HZ)
    # The one warning: the base's chamfers, which this truth lacks, are taken out (tested below).
    assert len(round_trip.warnings) == 1
    assert "showed the chamfers' impact" in round_trip.warnings[0]


def test_round_trip_recovers_the_positions(round_trip: ShiftFit):
    # 0.5 mm is 10 sigma of the position noise. The ring's position is the median of hundreds
    # of still samples; the teeth come from ~50 samples per passage and trade against the
    # teeth's resistance; the settled position sits up to F_st/k = 0.2 mm off x_gear (the
    # detent's friction), which the stop fit removes.
    g, t = round_trip.params.gearbox, truth().gearbox
    for name in (
        "synchronization_position_m",
        "teeth_position_m",
        "teeth_end_position_m",
        "in_gear_position_m",
    ):
        assert getattr(g, name) == pytest.approx(getattr(t, name), abs=5e-4), name
    assert g.synchronization_position_m == pytest.approx(0.018, abs=5e-5)


def test_round_trip_recovers_the_synchronization_time_and_push(round_trip: ShiftFit):
    g = round_trip.params.gearbox
    # Two samples: the opening and the arrival are each placed within a sample.
    assert g.synchronization_duration_s == pytest.approx(0.25, abs=2.0 / RATE_HZ)
    # 3 %: the plateau's second half holds the driver's F_max within 0.1 % (the hand's force
    # builds up with a 30 ms time constant), and 0.5 N of noise averages out over 60 samples.
    assert round_trip.params.driver.push_force_N == pytest.approx(70.0, rel=0.03)
    for e in round_trip.engagements:
        assert e.plateau_force_N == pytest.approx(70.0, rel=0.03)
        assert e.plateau_duration_s == pytest.approx(0.25, abs=2.0 / RATE_HZ)


def test_round_trip_recovers_the_stop(round_trip: ShiftFit):
    stop = round_trip.params.gearbox.stop
    # 25 %: the stiffness rests on ~10 ms of overshoot and the push against the stop (1-2 mm of
    # give under 40-70 N), seen through 0.05 mm of noise, and trades against x_gear and the
    # stop's friction (kept from the base).
    assert stop.stiffness_N_m == pytest.approx(45000.0, rel=0.25)
    assert 0.0 <= stop.damping_N_s_m < 200.0
    for e in round_trip.engagements:
        assert 2e-4 < e.overshoot_m < 3e-3
        assert e.stop_position_m > 0.043


def test_round_trip_recovers_each_teeth_resistance_and_their_law(round_trip: ShiftFit):
    # 1 N per engagement: the resistance trades against the teeth's position (0.1 mm of teeth
    # is about 0.5 N); the law's bounds come from 6 draws, so they scatter by about
    # spread / 6 = 1.7 N.
    fitted = [e.tooth_resistance_N for e in round_trip.engagements]
    expected = [r for seed in SEEDS for r in true_resistances(seed, ENGAGEMENTS_PER_TRACE)]
    assert np.allclose(fitted, expected, atol=1.0)
    g, t = round_trip.params.gearbox, truth().gearbox
    assert g.engagement.sliding_friction_N == pytest.approx(12.0, abs=2.5)
    assert g.tooth_force_spread_N == pytest.approx(10.0, abs=3.5)
    margin = t.engagement.static_friction_N - t.engagement.sliding_friction_N
    assert g.engagement.static_friction_N == pytest.approx(g.engagement.sliding_friction_N + margin)
    # The peaks at the knob differ from engagement to engagement, as the draws do.
    peaks = [e.tooth_peak_force_N for e in round_trip.engagements]
    assert all(math.isfinite(p) for p in peaks)
    assert np.ptp(peaks) > 3.0
    assert np.corrcoef(peaks, expected)[0, 1] > 0.8


def test_round_trip_params_pass_the_preset_checks_and_keep_the_rest(round_trip: ShiftFit):
    params, base = round_trip.params, load_shift().params
    assert check_shift(params) == []
    assert params.gearbox.neutral == base.gearbox.neutral
    assert params.gearbox.gate_open == base.gearbox.gate_open
    assert params.driver.push_velocity_m_s == base.driver.push_velocity_m_s
    assert params.driver.release_position_m == pytest.approx(params.gearbox.in_gear_position_m)


def test_round_trip_resimulation_follows_the_traces(round_trip: ShiftFit):
    figures = round_trip.figures
    # Open loop, a lever 1 ms behind its recorded force in the passage (0.4 m/s) is 0.4 mm
    # behind and drifts farther until the stop; the measured rms is 2-3 mm over 43 mm of travel.
    # Bound: 4 mm and r^2 > 0.95 (the fit itself, per stage, is at the noise: below 0.1 mm).
    assert figures["rms_error_m"] < 4e-3
    assert figures["r2"] > 0.95
    for index in range(len(SEEDS)):
        assert figures[f"trace{index}.rms_error_m"] < 4e-3
        assert figures[f"trace{index}.r2"] > 0.95
        assert figures[f"trace{index}.position_noise_m"] == pytest.approx(5e-5, rel=0.2)
        assert figures[f"trace{index}.force_noise_N"] == pytest.approx(0.5, rel=0.2)
    assert figures["passage_rms_m"] < 2 * POSITION_NOISE_M
    assert figures["stop_rms_m"] < 2 * POSITION_NOISE_M
    assert figures["gearbox.stop.stiffness_N_m"] == round_trip.params.gearbox.stop.stiffness_N_m
    assert figures["driver.push_force_N"] == round_trip.params.driver.push_force_N
    assert figures["engagements"] == 6.0


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_a_force_spike_and_gaps_still_fit():
    trace = measured(clean(SEEDS[0]), SEEDS[0])
    t, x, f = trace.time_s, trace["position_m"].copy(), trace["force_N"].copy()
    # A 150 N spike in the second engagement's passage, a 40 ms gap in its plateau and 10 ms
    # missing in the third engagement's free travel.
    second, third = arrivals(clean(SEEDS[0]))[1:]
    f[np.searchsorted(t, second + 0.26)] += 150.0
    missing = ((t > second + 0.1) & (t < second + 0.14)) | ((t > third + 0.3) & (t < third + 0.31))
    keep = ~missing
    damaged = Result(t[keep], {"position_m": x[keep], "force_N": f[keep]})
    fit = fit_shift([damaged])
    assert len(fit.engagements) == ENGAGEMENTS_PER_TRACE
    assert any("1 outlier sample" in w for w in fit.warnings)
    assert any("2 gap(s)" in w for w in fit.warnings)
    g, t_g = fit.params.gearbox, truth().gearbox
    for name in ("synchronization_position_m", "teeth_position_m", "in_gear_position_m"):
        assert getattr(g, name) == pytest.approx(getattr(t_g, name), abs=5e-4), name
    assert g.synchronization_duration_s == pytest.approx(0.25, abs=2.0 / RATE_HZ)
    assert fit.params.driver.push_force_N == pytest.approx(70.0, rel=0.03)
    assert g.stop.stiffness_N_m == pytest.approx(45000.0, rel=0.25)
    fitted = [e.tooth_resistance_N for e in fit.engagements]
    assert np.allclose(fitted, true_resistances(SEEDS[0], 3), atol=1.0)


def test_one_engagement_keeps_the_spread_and_says_why():
    single = measured(clean(5, duration_s=1.2, repeat=False), 5)
    fit = fit_shift([single])
    assert len(fit.engagements) == 1
    assert any("not identifiable from a single engagement" in w for w in fit.warnings)
    base = load_shift().params.gearbox
    g = fit.params.gearbox
    assert g.tooth_force_spread_N == base.tooth_force_spread_N
    resistance = fit.engagements[0].tooth_resistance_N
    assert resistance == pytest.approx(true_resistances(5, 1)[0], abs=1.5)
    assert g.engagement.sliding_friction_N == pytest.approx(
        resistance - 0.5 * base.tooth_force_spread_N
    )
    assert g.synchronization_position_m == pytest.approx(0.018, abs=5e-4)
    assert g.in_gear_position_m == pytest.approx(0.043, abs=5e-4)


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_a_mapping_of_arrays_is_a_trace(round_trip: ShiftFit):
    trace = measured(clean(SEEDS[0]), SEEDS[0])
    columns = {name: trace[name] for name in trace.names}
    fit = fit_shift([columns])
    assert len(fit.engagements) == ENGAGEMENTS_PER_TRACE


def _good() -> Result:
    return measured(clean(SEEDS[0]), SEEDS[0])


def _noise(n: int, sigma: float) -> np.ndarray:
    """A knob left alone: sensor noise only."""
    return np.random.default_rng(0).normal(0.0, sigma, n)


def _with(trace: Result, **signals: np.ndarray) -> Result:
    return Result(trace.time_s, {**trace.signals, **signals}, trace.metadata)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (
            lambda g: Result(g.time_s, {"position_m": g["position_m"]}),
            r"trace 2: missing column\(s\) force_N; a shift trace needs time_s",
        ),
        (
            lambda g: _with(g, force_N=np.where(np.arange(len(g)) == 700, np.nan, g["force_N"])),
            r"trace 2: force_N holds 1 NaN or infinite value\(s\), the first at sample 701 "
            r"\(t = 1.4\d* s\); drop those samples",
        ),
        (
            lambda g: Result(np.concatenate([g.time_s[:300], g.time_s[299:-1]]), g.signals),
            r"trace 2: time_s does not increase at sample 301 .*sort the samples by time",
        ),
        (
            lambda g: _with(g, position_m=_noise(len(g), 5e-5), force_N=_noise(len(g), 0.5)),
            r"trace 2: no engagement found: .*check that the trace holds a push into gear",
        ),
        (
            lambda g: Result(g.time_s[::5], {k: v[::5] for k, v in g.signals.items()}),
            r"trace 2: sampled every 10 ms; the segmentation needs at least 200 Hz",
        ),
        (
            lambda g: Result(g.time_s[:20], {k: v[:20] for k, v in g.signals.items()}),
            r"trace 2: 20 samples; a fit or a validation needs 50 at least",
        ),
        (
            # Issue 11: a negated force said "no engagement found" and nothing more.
            lambda g: _with(g, force_N=-g["force_N"]),
            r"trace 2: no engagement found: .*with the sign of force_N flipped it holds 3 "
            r"engagement\(s\).*scale = -1 in a channel map",
        ),
        (
            # A negated position fitted on to a preset carfeel refused (negative teeth).
            lambda g: _with(g, position_m=-g["position_m"], force_N=-g["force_N"]),
            r"trace 2: position_m runs to -4\d\.\d mm and only to \+\d\.?\d* mm the other way; "
            r".*\+ toward the gear.*flip its sign",
        ),
    ],
    ids=[
        "missing-column",
        "nan",
        "time-backwards",
        "no-engagement",
        "slow",
        "short",
        "negated-force",
        "negated-position",
    ],
)
def test_malformed_traces_raise_naming_the_trace(make: Any, message: str):
    good = _good()
    with pytest.raises(InputError, match=message):
        fit_shift([good, make(good)])


def test_an_error_names_the_trace_by_its_name():
    good = _good()
    named = Result(good.time_s, {"position_m": good["position_m"]}, {"name": "left-hand run"})
    # Counted from 1, as a user counts the files given (issue 11: "trace 0").
    with pytest.raises(InputError, match=r"trace 1 \(left-hand run\): missing column"):
        fit_shift([named])


def test_no_traces_is_an_error():
    with pytest.raises(InputError, match="no traces given"):
        fit_shift([])


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_fit_and_validate_shift_traces_from_the_command_line(tmp_path, capsys):
    """The CLI round trip: traces on disk -> `fit shift` -> a preset that loads -> `validate`."""
    import json

    from carfeel.cli import main

    paths = []
    for seed in SEEDS:
        path = tmp_path / f"trace-{seed}.csv"
        measured(clean(seed), seed).to_csv(path)
        paths.append(str(path))
    preset, fit_report, check = tmp_path / "mine.toml", tmp_path / "fit", tmp_path / "check"
    assert main(["fit", "shift", *paths, "--out", str(preset), "--report", str(fit_report),
                 "--json"]) == 0  # fmt: skip
    result = json.loads(capsys.readouterr().out)
    assert len(result["engagements"]) == ENGAGEMENTS_PER_TRACE * len(SEEDS)
    # Same bound as the round trip above: the stage positions are read off still plateaus.
    fitted = load_shift(str(preset)).params.gearbox
    assert fitted.synchronization_position_m == pytest.approx(0.018, abs=5e-4)
    assert (fit_report / "index.html").is_file()
    assert main(["validate", "--preset", str(preset), *paths, "--report", str(check),
                 "--json"]) == 0  # fmt: skip
    figures = json.loads(capsys.readouterr().out)
    assert set(figures) == set(paths)
    # The truth itself re-simulates these seeds to 1.8-2.1 mm rms: open loop, the knob's force
    # (which sags while the hand catches up) meets the preset's mean tooth resistance instead of
    # each engagement's own draw. 5 mm bounds the fitted preset; the shipped preset, whose
    # stages sit elsewhere, must do far worse on the same traces (measured: 11.9 and 11.3 mm
    # against 1.6 and 2.3 mm).
    assert all(v["rms_error_m"] < 0.005 for v in figures.values())
    assert len(list(check.glob("*.png"))) == len(SEEDS)
    page = (check / "index.html").read_text()
    assert f"{ENGAGEMENTS_PER_TRACE} engagements;" in page
    assert page.count("<tr>") == page.count("</tr>")
    # The fit's report: each value with its sigma and what it is; the JSON has the sigmas too.
    fit_page = (fit_report / "index.html").read_text()
    assert "<th>1 sigma</th><th>what it is</th>" in fit_page and "the end stop" in fit_page
    sigmas = result["uncertainties"]
    assert set(sigmas) == set(result["parameters"])
    assert all(sigmas[k] > 0 for k in ("gearbox.stop.stiffness_N_m", "driver.push_force_N"))
    assert main(["validate", "--preset", "paper-first-gear", *paths, "--report",
                 str(tmp_path / "shipped"), "--json"]) == 0  # fmt: skip
    shipped = json.loads(capsys.readouterr().out)
    assert all(shipped[p]["rms_error_m"] > 3 * figures[p]["rms_error_m"] for p in paths)


def test_malformed_shift_traces_exit_2_from_the_command_line(tmp_path, capsys):
    from carfeel.cli import main

    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,position_m\n0,0\n0.002,0\n")
    assert main(["fit", "shift", str(bad), "--out", str(tmp_path / "p.toml")]) == 2
    err = capsys.readouterr().err
    assert "missing column(s) force_N" in err and "Traceback" not in err
    assert not (tmp_path / "p.toml").exists()
    garbled = tmp_path / "garbled.csv"
    garbled.write_text("time_s,position_m,force_N\n0,0,1\n0.002,abc,2\n")
    assert main(["validate", "--preset", "paper-first-gear", str(garbled),
                 "--report", str(tmp_path / "r")]) == 2  # fmt: skip
    assert "garbled.csv" in capsys.readouterr().err


def test_the_plain_summary_and_strict_json(tmp_path, capsys):
    import json

    from carfeel.cli import main

    trace = tmp_path / "one.csv"
    # One engagement: the spread is kept from the base, with a warning, and the JSON must still
    # be strict (a NaN figure would print as the token NaN, which JSON does not have).
    result = clean(SEEDS[0], duration_s=1.0, repeat=False)
    measured(result, SEEDS[0]).to_csv(trace)
    out = tmp_path / "one.toml"
    assert main(["fit", "shift", str(trace), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "fitted 1 engagement:" in text and f"wrote {out}" in text
    assert "warning: one engagement: the spread of the tooth force is not identifiable" in text
    assert main(["fit", "shift", str(trace), "--out", str(out), "--json"]) == 0
    printed = capsys.readouterr().out
    # Strict JSON: no NaN or Infinity tokens, which json.loads would otherwise accept.
    fitted = json.loads(printed, parse_constant=lambda token: pytest.fail(f"{token} in JSON"))
    assert set(fitted["parameters"]) >= {"gearbox.synchronization_position_m"}
    assert not any(k.startswith("gearbox.") for k in fitted["figures"])


def test_a_report_path_that_is_a_file_stops_before_anything_is_written(tmp_path, capsys):
    from carfeel.cli import main

    trace = tmp_path / "t.csv"
    measured(clean(SEEDS[0]), SEEDS[0]).to_csv(trace)
    blocker = tmp_path / "report"
    blocker.write_text("not a folder")
    out = tmp_path / "p.toml"
    assert main(["fit", "shift", str(trace), "--out", str(out), "--report", str(blocker)]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err
    assert not out.exists()
    missing = tmp_path / "nowhere" / "p.toml"
    assert main(["fit", "shift", str(trace), "--out", str(missing)]) == 2
    assert f"folder {missing.parent} does not exist" in capsys.readouterr().err


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_positions_in_mm_and_exactly_200_hz():
    result = measured(clean(SEEDS[0]), SEEDS[0])
    with pytest.raises(InputError, match="if it is in mm, divide it by 1000"):
        fit_shift([{"time_s": result.time_s, "position_m": result["position_m"] * 1e3,
                    "force_N": result["force_N"]}])  # fmt: skip
    # Resampled to exactly 200 Hz, the slowest the docstring accepts (steps of 0.005000...01 s).
    t = np.arange(result.time_s[0], result.time_s[-1], 1.0 / 200.0)
    slow = {"time_s": t, "position_m": np.interp(t, result.time_s, result["position_m"]),
            "force_N": np.interp(t, result.time_s, result["force_N"])}  # fmt: skip
    assert len(fit_shift([slow]).engagements) == ENGAGEMENTS_PER_TRACE


def test_a_fit_carfeel_would_refuse_is_not_written(tmp_path):
    from carfeel.identification.common import write_checked_preset
    from carfeel.io.presets import to_toml

    params = load_shift().params
    bad = dataclasses.replace(params.gearbox, synchronization_position_m=0.5)
    text = to_toml("bad", "a fit gone wrong", {"gearbox": bad, "driver": params.driver})
    out = tmp_path / "bad.toml"
    with pytest.raises(InputError, match=r"so .*bad\.toml is not written"):
        write_checked_preset("shift", out, text)
    assert not out.exists()


def test_a_trace_without_an_engagement_is_still_validated(tmp_path, capsys):
    """A pull-out only (the knob starts in gear): nothing to restart at, one piece from the
    first sample."""
    from carfeel.cli import main
    from carfeel.identification.shift_fit import resimulate

    pulled = clean(SEEDS[0], repeat=False)  # one push in, held, pulled out, nothing after
    keep = pulled.time_s > arrivals(pulled)[0] + 0.6  # after the engagement's stop
    late = Result(pulled.time_s[keep], {k: v[keep] for k, v in pulled.signals.items()})
    assert late["position_m"][0] > truth().gearbox.teeth_end_position_m  # starts in gear
    path = tmp_path / "pull-only.csv"
    measured(late, SEEDS[0]).to_csv(path)
    assert resimulate(Result.from_csv(path), truth()).engagements == 0
    assert main(["validate", "--preset", "paper-first-gear", str(path),
                 "--report", str(tmp_path / "r")]) == 0  # fmt: skip
    assert "rms_error_m" in capsys.readouterr().out


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_a_truth_away_from_the_base_with_a_biased_drifting_force_is_found():
    """The teeth's sliding friction, their spread and the stop's damping of this truth are not
    the base preset's (12 N, 10 N, 40 N*s/m), so a fit that returned the base would fail; the
    force sensor reads 1.5 N high and drifts 2 N more over each trace."""
    g = truth().gearbox
    other = ShiftParams(
        dataclasses.replace(
            g, tooth_force_spread_N=6.0,
            engagement=dataclasses.replace(g.engagement, sliding_friction_N=16.0,
                                           static_friction_N=18.0),
            stop=dataclasses.replace(g.stop, damping_N_s_m=90.0),
        ),
        truth().driver,
    )  # fmt: skip
    traces = []
    for seed in SEEDS:
        result, _ = run(push_again(), shift.initial_state(seed), other, duration_s=DURATION_S,
                        dt_s=1e-3, substeps=10)  # fmt: skip
        m = measured(result, seed)
        t = m.time_s
        drift = 1.5 + 2.0 * (t - t[0]) / (t[-1] - t[0])
        traces.append(Result(t, {"position_m": m["position_m"], "force_N": m["force_N"] + drift}))
    fit = fit_shift(traces)
    got = fit.params.gearbox
    # Measured 15.95 N and 6.1 N: the bounds of a uniform law from 6 draws scatter by about
    # spread / 6 (1 N) and the drift adds up to 3.5 N to a resistance at worst: 2.5 N on each.
    assert got.engagement.sliding_friction_N == pytest.approx(16.0, abs=2.5)
    assert got.tooth_force_spread_N == pytest.approx(6.0, abs=2.5)
    # Measured 112: the damping rests on ~10 ms of overshoot per engagement; the base's 40 is
    # out of this band, as is twice the truth.
    assert 60.0 < got.stop.damping_N_s_m < 150.0
    # The bias lands in the push force (the plateau is the driver's F_max plus the bias).
    assert fit.params.driver.push_force_N == pytest.approx(70.0 + 2.5, abs=1.5)


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_the_lever_mass_from_noise_free_free_travel():
    """The free stretches' output-error fit on traces without noise recovers a lever mass that
    is not the base's (1.6 vs 1.2 kg) within 3 %; with the noise of the other tests it reads
    10-17 % high, which is why it is reported and not yet written (DESIGN, issue 12)."""
    g = truth().gearbox
    names = ("neutral", "gate_open", "engagement", "free_travel", "stop", "in_gear", "returning")
    heavy = ShiftParams(
        dataclasses.replace(g, **{n: dataclasses.replace(getattr(g, n), mass_kg=1.6)
                                  for n in names}),
        truth().driver,
    )  # fmt: skip
    result, _ = run(push_again(), shift.initial_state(11), heavy, duration_s=DURATION_S,
                    dt_s=1e-3, substeps=10)  # fmt: skip
    fit = fit_shift([Result(result.time_s, {"position_m": result["position_m"],
                                            "force_N": result["force_N"]})])  # fmt: skip
    assert fit.figures["free_mass_kg"] == pytest.approx(1.6, rel=0.03)
    assert fit.figures["free_damping_N_s_m"] == pytest.approx(15.0, rel=0.15)


# ---------------------------------------------------------------- the sigmas (issue 11)


def test_the_tooth_laws_sigmas_match_the_scatter_of_repeated_draws():
    """The uniform law's bounds from n draws (`_tooth_law`) scatter as `_tooth_law_sigmas`
    says: 20000 repeats per n, so the scatter itself is known to 0.5 %; 3 % allowed."""
    from carfeel.identification.shift_fit import _tooth_law, _tooth_law_sigmas

    gb = load_shift().params.gearbox
    rng = np.random.default_rng(1)
    for n in (2, 3, 6):
        fits = np.array([_tooth_law(list(12.0 + 10.0 * rng.random(n)), gb, [])
                         for _ in range(20000)])  # fmt: skip
        sigmas = _tooth_law_sigmas(n, 10.0)
        assert fits[:, 0].std() == pytest.approx(
            sigmas["gearbox.engagement.sliding_friction_N"], rel=0.03
        )
        assert fits[:, 1].std() == pytest.approx(sigmas["gearbox.tooth_force_spread_N"], rel=0.03)
    assert _tooth_law_sigmas(1, 10.0) == {}  # one draw: no spread, no sigma


def test_the_medians_standard_error_matches_its_scatter():
    """1.2533 s / sqrt(n) against the scatter of the median of n normal values: the large-sample
    formula, within 5 % from n = 3 on (measured: -4 % at 3, +5 % at 6, +3 % at 12); 8 % allowed
    for the 6000 repeats' own scatter (about 1 %)."""
    from carfeel.identification.shift_fit import _median_error

    rng = np.random.default_rng(4)
    for n in (3, 6, 12):
        samples = rng.normal(0.0, 2.0, (6000, n))
        reported = np.mean([_median_error(list(row)) for row in samples])
        assert reported == pytest.approx(np.median(samples, axis=1).std(), rel=0.08)
    assert math.isnan(_median_error([1.0, 2.0]))


def test_the_fits_gauss_newton_sigmas_match_the_scatter_of_repeated_fits():
    """`_covariance` on `_solve` (the shift fits' solver: forward differences, soft_l1) for a
    model with a known answer, 200 noisy repeats: the reported sigmas within -15 %..+25 % of the
    scatter (its own 5 % uncertainty; the forward difference of step 0.05 makes them about 8 %
    conservative here)."""
    from carfeel.identification.shift_fit import _covariance, _solve

    rng = np.random.default_rng(2)
    t = np.linspace(0.0, 1.0, 200)

    def model(p):
        return p[0] * (1.0 - np.exp(-t / p[1]))

    start, scale = np.array([4.0, 0.25]), np.array([1.0, 0.1])
    estimates, sigmas = [], []
    for _ in range(200):
        data = model(np.array([5.0, 0.2])) + rng.normal(0.0, 0.05, t.size)

        def residuals(z, data=data):
            return (model(start + z * scale) - data) / 0.05  # in units of the noise

        solution = _solve(residuals, np.array([-3.0, -2.0]), np.array([5.0, 5.0]), [[0], [1]],
                          [None, None], lambda r: None)  # fmt: skip
        estimates.append(start + solution.x * scale)
        sigmas.append(np.sqrt(np.diag(_covariance(solution))) * scale)
    ratio = np.mean(sigmas, axis=0) / np.std(estimates, axis=0)
    assert np.all((ratio > 0.85) & (ratio < 1.25)), ratio


# ---------------------------------------------------------------- issue 25, point 4


def quantized(result: Result, seed: int) -> Result:
    """Issue 25's sensors: the position in 0.05 mm steps (an encoder, no noise between them),
    the force with 1 N of white noise; 500 Hz, half a step off the truth's samples."""
    rng = np.random.default_rng(seed)
    t = np.arange(result.time_s[0] + 0.5e-3, result.time_s[-1], 1.0 / RATE_HZ)
    x = np.round(np.interp(t, result.time_s, result["position_m"]) / 5e-5) * 5e-5
    f = np.interp(t, result.time_s, result["force_N"]) + rng.normal(0, 1.0, t.size)
    return Result(t, {"position_m": x, "force_N": f})


@functools.cache
def chamfered_truth() -> ShiftParams:
    """The hidden preset of the tests above with the shipped preset's chamfers on: the gear's
    inertia picked up at the teeth slows the knob, and each engagement meets them or not."""
    t = truth()
    return ShiftParams(dataclasses.replace(t.gearbox, chamfer=load_shift().params.gearbox.chamfer),
                       t.driver)  # fmt: skip


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_a_quantized_position_and_1_n_of_force_noise_give_the_stages_and_honest_sigmas():
    """Issue 25: 1 N of force noise and a 0.05 mm position resolution gave r2 -0.13 (0.41 here
    with the chamfers on, 12 mm rms), the teeth -23 % at 10-24 sigma and a push force's sigma
    of 8e-15 N (a quantized plateau reads the same everywhere). Measured now: r2 0.9996, every
    stage within 0.07 mm, each within 2.0 of its sigma."""
    truth_params = chamfered_truth()
    traces = []
    for seed in SEEDS:
        result, _ = run(push_again(), shift.initial_state(seed), truth_params,
                        duration_s=DURATION_S, dt_s=1e-3, substeps=10)  # fmt: skip
        traces.append(quantized(result, seed))
    fit = fit_shift(traces)
    assert fit.figures["r2"] > 0.8
    assert all(fit.figures[f"trace{i}.r2"] > 0.8 for i in range(len(SEEDS)))
    assert fit.figures["chamfer_contacts"] >= 1  # the chamfers were seen and kept
    assert fit.params.gearbox.chamfer == truth_params.gearbox.chamfer
    g, t = fit.params.gearbox, truth_params.gearbox
    for name in ("synchronization_position_m", "teeth_position_m", "teeth_end_position_m",
                 "in_gear_position_m"):  # fmt: skip
        error = getattr(g, name) - getattr(t, name)
        sigma = fit.sigmas[f"gearbox.{name}"]
        # The acceptance's 2 mm; and honest: 4 sigma is a 1-in-16000 miss of a normal error,
        # and a sigma may not be smaller than the resolution's q / sqrt(12) / sqrt(n) can give.
        assert abs(error) < 2e-3, name
        assert sigma > 5e-6 and abs(error) < 4.0 * sigma, (name, error, sigma)
    # A plateau of quantized positions and noisy forces: the sigma is the noise's, not 8e-15 N.
    push_sigma = fit.sigmas["driver.push_force_N"]
    assert 0.02 < push_sigma < 1.0
    assert abs(fit.params.driver.push_force_N - 70.0) < 4.0 * push_sigma
    # Each trace's quality, worst first, where its model departs most.
    assert len(fit.departures) == len(SEEDS)
    assert all("r2" in d and "departing most at" in d for d in fit.departures)


@pytest.mark.slow  # over 8 s here: the full suite (make test) runs it, make check does not
def test_chamfers_the_traces_never_show_are_taken_out():
    """The round trip's truth has no chamfers, the base has them: 6 engagements gap to gap
    would happen with a probability of 0.2^6 under the base's, so the fitted preset has none
    and says why (with them, the fitted preset validated at 4.9 mm rms, r2 0.90; 1.6 mm
    without)."""
    fit = fit_shift([quantized(clean(seed), seed) for seed in SEEDS])
    assert fit.figures["chamfer_contacts"] == 0
    assert fit.params.gearbox.chamfer.gear_inertia_kg_m2 == 0.0
    assert fit.params.gearbox.chamfer.drag_torque_Nm == 0.0
    assert any("showed the chamfers' impact" in w and "6.4e-05" in w for w in fit.warnings)
    assert fit.figures["r2"] > 0.95


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_a_fit_under_the_r2_a_preset_needs_is_refused_with_why(tmp_path, capsys, monkeypatch):
    """The refusal of issue 25 point 4: a fit whose model follows its traces with r2 under
    MIN_R2 writes no preset, exits 2 and names the r2, the worst trace and where it departs.
    No hidden preset this model cannot follow gives such a fit (the round trip's r2 is
    0.9999), so the bar is raised above it here: the same code path, the same message."""
    from carfeel.cli import main
    from carfeel.identification import shift_workflows

    paths = []
    for seed in SEEDS[:1]:
        path = tmp_path / f"trace-{seed}.csv"
        measured(clean(seed), seed).to_csv(path)
        paths.append(str(path))
    monkeypatch.setattr(shift_workflows, "MIN_R2", 0.999999)
    out = tmp_path / "mine.toml"
    assert main(["fit", "shift", *paths, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert re.search(r"r2 0\.99[0-9]*, under the 0\.999999 a preset needs", err), err
    assert "mine.toml is not written" in err and "departing most at" in err
    assert "Traceback" not in err
    assert not out.exists()
