"""Simulations streamed to their outputs (issue 27): the samples go to the CSV, the summaries and
the plot a block at a time, so a run's memory does not grow with its length (`simulate hpattern`
of 1,000 s peaked at 1.1 GB; the CSV's strings doubled it at the end).

What must hold: the streamed outputs equal the run held in memory bit for bit, whatever the
blocks; the summaries kept as the samples come equal the ones of the whole run (the old code
is the reference); the plot of a long run keeps its peaks; a failed run leaves the user's files;
and a run ten or a hundred times longer peaks at the same memory.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from typing import Any

import numpy as np
import pytest

from carfeel.analysis.hpattern_features import EngagementStream
from carfeel.analysis.shift_features import ShiftFeatureStream, shift_features
from carfeel.cli import main
from carfeel.errors import CarfeelError
from carfeel.io import plots
from carfeel.io.presets import load_hpattern, load_steering
from carfeel.models.drivers.hpattern import Script
from carfeel.runs import HPatternRunConfig, run_hpattern
from carfeel.simulation import manoeuvres, runner, stream
from carfeel.simulation.hpattern import HPatternRun, simulate_hpattern
from carfeel.simulation.result import Result
from carfeel.simulation.sequence import parse_sequence
from carfeel.simulation.shift import initial_state, simulate_force_profile, step
from carfeel.simulation.steering import simulate_steering
from tests.conftest import default_params, shift_run
from tests.memory import carfeel_peak


def blocks_of(result: Result, sizes: list[int]) -> list[Result]:
    """`result` cut into consecutive blocks of the given sizes (cycled), the last shorter."""
    out, start, k = [], 0, 0
    while start < len(result):
        stop = min(start + sizes[k % len(sizes)], len(result))
        out.append(result.take(np.arange(start, stop)))
        start, k = stop, k + 1
    return out


def same(a: Result, b: Result) -> None:
    """Bit for bit: the times, each signal's values and dtype."""
    assert a.time_s.tobytes() == b.time_s.tobytes()
    assert a.names == b.names
    for name in a.signals:
        assert a[name].dtype == b[name].dtype, name
        if a[name].dtype.kind == "f":
            assert a[name].tobytes() == b[name].tobytes(), name
        else:
            assert np.array_equal(a[name], b[name]), name


def hpattern_run(sequence: str = "N,1,2,3,2,N", physics: bool = True, seed: int = 2) -> Result:
    preset = load_hpattern("5r")
    script = Script(
        parse_sequence(sequence), preset.setup.layout, preset.shift.driver, preset.setup.driver,
        1.0, 0, 0,
    )  # fmt: skip
    run = HPatternRun(preset.pattern(physics), script, 30 / 3.6, 800 * 2 * math.pi / 60, 1e-3)
    return simulate_hpattern(run, seed=seed, max_duration_s=3.0 * len(script.sequence) + 5)


@pytest.mark.parametrize("block", [1, 7, 4096])
def test_a_streamed_run_is_the_run_held_in_memory(block):
    """The runner's blocks (of 1, 7 and 4096 samples) put together are `run`'s Result, and
    each block is a stretch of it."""
    params = default_params()
    whole, _ = runner.run(step, initial_state(3), params, duration_s=0.9, substeps=2)
    kept = stream.Collector()
    _, n = runner.stream(
        step, initial_state(3), params, kept, duration_s=0.9, substeps=2, block_samples=block
    )
    assert n == len(whole) == 900
    assert all(len(b) == block for b in kept.blocks[:-1])
    same(kept.result(), whole)


def test_an_early_stop_ends_the_last_block_there():
    """A run that stops early (the H-pattern's driver done) hands on its last, short block."""
    params = default_params()
    kept = stream.Collector()
    _, n = runner.stream(
        step, initial_state(0), params, kept, duration_s=5.0, block_samples=256,
        stop_when=lambda state: state.lever.stage.name == "IN_GEAR",
    )  # fmt: skip
    result = kept.result()
    assert n == len(result) < 5000
    assert result["stage"][-1] == "in_gear" and not (result["stage"][:-1] == "in_gear").any()


def test_the_csv_written_as_the_run_goes_is_the_csv_of_the_whole_run(tmp_path):
    """Byte for byte what `Result.to_csv` writes of the whole run (both steering models and a
    manoeuvre of two segments: the segment column and the time running on)."""
    car = load_steering().params
    for model in ("paper", "physical"):
        whole = simulate_steering(car, manoeuvres.build("iso4138", car.vehicle), model=model,
                                  dt_s=5e-3)  # fmt: skip
        assert set(whole["segment"]) == {"left", "right"}
        whole.to_csv(tmp_path / "whole.csv")
        with stream.CsvWriter(tmp_path / "streamed.csv") as csv:
            for block in blocks_of(whole, [1000, 3, 4096]):
                csv.write(block)
        assert (tmp_path / "streamed.csv").read_bytes() == (tmp_path / "whole.csv").read_bytes()
        assert csv.samples == len(whole)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["streamed.csv", "whole.csv"]


def test_a_failed_run_leaves_the_file_that_was_there(tmp_path):
    target = tmp_path / "run.csv"
    target.write_text("precious\n")

    def fails_half_way() -> None:
        with stream.CsvWriter(target) as csv:
            csv.write(shift_run(0))
            raise RuntimeError("the run failed half way")

    with pytest.raises(RuntimeError):
        fails_half_way()
    assert target.read_text() == "precious\n"
    assert [p.name for p in tmp_path.iterdir()] == ["run.csv"]  # no temporary left
    with pytest.raises(ValueError, match="no sample"), stream.CsvWriter(target):
        pass
    assert target.read_text() == "precious\n"


def test_the_csv_is_staged_beside_its_target_as_name_part_csv(tmp_path):
    """As `Outputs` stages a file written as it goes: while the run goes its samples are in
    run.part.csv (readable if the run is killed), the user's run.csv untouched; renamed over
    it on success. A path `Outputs` already staged (stage=False) is written as it is."""
    target = tmp_path / "run.csv"
    target.write_text("precious\n")
    with stream.CsvWriter(target) as csv:
        csv.write(shift_run(0))
        csv._handle.flush()  # what a killed run leaves on disk
        part = tmp_path / "run.part.csv"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv", "run.part.csv"]
        assert part.read_text().startswith("time_s,") and target.read_text() == "precious\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]
    assert target.read_text().startswith("time_s,")
    staged = tmp_path / "out.part.csv"
    with stream.CsvWriter(staged, stage=False) as csv:
        csv.write(shift_run(0))
        assert sorted(p.name for p in tmp_path.iterdir()) == ["out.part.csv", "run.csv"]
    assert staged.read_bytes() == target.read_bytes()


def test_simulate_stages_its_csv_once_as_out_part_csv(tmp_path, monkeypatch):
    """The command's --out is staged by `Outputs` (OUT.part.csv), and the CSV writer writes that
    file itself: no OUT.part.part.csv, no hidden temporary, during the run or after it."""
    seen: list[list[str]] = []
    real = stream.CsvWriter.write

    def write(self, block):
        real(self, block)
        seen.append(sorted(p.name for p in tmp_path.iterdir()))

    monkeypatch.setattr(stream.CsvWriter, "write", write)
    out = tmp_path / "run.csv"
    assert main(["simulate", "shift", "--out", str(out)]) == 0
    assert seen and all(names == ["run.part.csv", "run.part.json"] or names == ["run.part.csv"]
                        for names in seen), seen  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv", "run.json"]


def test_a_non_finite_sample_stops_the_run_at_once_naming_it_and_its_time(tmp_path):
    """The check runs on each block as it comes: the run ends within a block of the NaN, its
    CSV is never written."""
    params = default_params()
    seen = stream.Collector()

    calls = []

    def broken(state, inputs, p, dt):  # a model that goes wrong at 1.5 s
        calls.append(dt)
        new, out = step(state, inputs, p, dt)
        return new, (out._replace(force_N=math.nan) if len(calls) >= 1500 else out)

    target = tmp_path / "run.csv"

    def run() -> None:
        with stream.CsvWriter(target) as csv:
            sink = stream.Tee(stream.FiniteCheck("shift"), csv, seen)
            runner.stream(broken, initial_state(0), params, sink, duration_s=100.0,
                          block_samples=512)  # fmt: skip

    with pytest.raises(CarfeelError, match=r"non-finite force_N at 1\.5 s"):
        run()
    assert sum(len(b) for b in seen.blocks) < 1500  # stopped at its first bad block
    assert not target.exists() and not list(tmp_path.iterdir())


def features_equal(a, b) -> None:
    for name, value in dataclasses.asdict(a).items():
        other = getattr(b, name)
        if isinstance(value, float) and math.isnan(value):
            assert math.isnan(other), name
        else:
            assert value == other, name


def old_shift_features(result: Result, in_gear_position_m: float) -> dict[str, Any]:
    """The features as they were computed before issue 27, on the whole run: the reference."""
    stages, x, force = result["stage"], result["position_m"], result["force_N"]
    dt = float(result.time_s[1] - result.time_s[0])
    nan = float("nan")
    sync, engagement, stop = (stages == s for s in ("synchronization", "engagement", "stop"))
    peak_at = (
        int(np.flatnonzero(engagement)[np.argmax(force[engagement])]) if engagement.any() else -1
    )
    seen: dict[str, int] = {}
    for i, name in enumerate(stages.tolist()):
        seen.setdefault(name, i)
    return {
        "stages": tuple(sorted(seen, key=seen.__getitem__)),
        "synchronization_position_m": float(x[sync][0]) if sync.any() else nan,
        "synchronization_force_N": float(np.median(force[sync])) if sync.any() else nan,
        "synchronization_peak_N": float(force[sync].max()) if sync.any() else nan,
        "synchronization_hold_s": float(sync.sum() * dt),
        "engagement_position_m": float(x[engagement][0]) if engagement.any() else nan,
        "engagement_peak_N": float(force[engagement].max()) if engagement.any() else nan,
        "engagement_peak_position_m": float(x[peak_at]) if engagement.any() else nan,
        "stop_peak_N": float(force[stop].max()) if stop.any() else nan,
        "stop_overshoot_m": float(x[stop].max() - in_gear_position_m) if stop.any() else nan,
        "final_stage": str(stages[-1]),
        "final_position_m": float(x[-1]),
    }


@pytest.mark.parametrize("sizes", [[4096], [1], [7, 300, 2], [64]])
def test_shift_features_kept_as_the_samples_come_equal_those_of_the_whole_run(sizes):
    """Pushes in (seeds 0-5), in and back out (stages entered twice), a knob force replayed
    that never reaches the stop: every figure equal to the old computation, bit for bit,
    whatever the blocks."""
    params = default_params()
    gearbox = params.gearbox
    runs = [shift_run(seed) for seed in range(6)] + [shift_run(1, pull_out=True)]
    runs.append(simulate_force_profile(gearbox, [0.0, 0.4, 1.0], [0.0, 10.0, 10.0],
                                       duration_s=1.0))  # fmt: skip
    for run in runs:
        streamed = ShiftFeatureStream(gearbox.in_gear_position_m)
        for block in blocks_of(run, sizes):
            streamed.write(block)
        reference = old_shift_features(run, gearbox.in_gear_position_m)
        features_equal(type(streamed.features())(**reference), streamed.features())
        features_equal(shift_features(run, gearbox.in_gear_position_m), streamed.features())
        at_stop = np.flatnonzero(run["stage"] == "stop")
        expected = float(run.time_s[at_stop[0]]) if at_stop.size else math.nan
        assert streamed.time_to_stop_s == expected or (
            math.isnan(expected) and math.isnan(streamed.time_to_stop_s)
        )
    assert "stop" not in streamed.features().stages  # the replayed force: a run without one


def old_engagements(result: Result) -> list[tuple[str, float, float, float, float, float]]:
    """Each engagement's figures as `engagements_of` and the sweep's `hpattern_metrics`
    computed them before issue 27, from the whole run: the reference."""
    dt = float(result.time_s[1] - result.time_s[0])
    stages, events, force = result["stage"], result["event"], np.abs(result["force_x_N"])
    engaged = [i for i, e in enumerate(events) if e.startswith("engage")]
    out, start = [], 0
    for k, i in enumerate(engaged):
        window = slice(start, i + 1)
        sync, teeth = stages[window] == "synchronization", stages[window] == "engagement"
        after = slice(i, engaged[k + 1] if k + 1 < len(engaged) else len(stages))
        at_stop = stages[after] == "stop"
        out.append((
            events[i].split()[1],
            float(result.time_s[i]),
            float(sync.sum() * dt),
            float(np.median(force[window][sync])) if sync.any() else math.nan,
            float(force[window][teeth].max()) if teeth.any() else math.nan,
            float(force[after][at_stop].max()) if at_stop.any() else math.nan,
        ))  # fmt: skip
        start = i + 1
    return out


@pytest.mark.parametrize("sizes", [[4096], [1, 2, 3], [97], [500, 1]])
def test_engagement_figures_kept_as_the_samples_come_equal_those_of_the_whole_run(sizes):
    """The fixed and the physics synchronizer, a gear engaged twice through neutral: each
    engagement's synchronization, plateau, tooth and stop peaks, bit for bit."""
    for run in (hpattern_run(), hpattern_run("N,1,N,1,2,1,N", physics=False, seed=5)):
        figures = EngagementStream()
        for block in blocks_of(run, sizes):
            figures.write(block)
        got = [dataclasses.astuple(e) for e in figures.figures()]
        expected = old_engagements(run)
        assert len(got) == len(expected) >= 4
        for g, e in zip(got, expected, strict=True):
            assert g[:3] == e[:3]
            for a, b in zip(g[3:], e[3:], strict=True):
                assert a == b or (math.isnan(a) and math.isnan(b))
        assert figures.final_gear == run["gear"][-1]
        assert figures.peak_grind_N == float(np.abs(run["grind_N"]).max())
        assert figures.final_time_s == run.time_s[-1]


def test_the_envelope_keeps_every_sample_of_a_short_run_and_the_peaks_of_a_long_one():
    run = hpattern_run()
    full = stream.Envelope(1, "force_x_N")
    full.write(run)
    same(full.result(), run)
    assert full.note() == ""
    for every in (3, 50, 1000):
        kept_by_blocks = []
        for sizes in ([4096], [13, 1, 700]):
            env = stream.Envelope(every, "force_x_N", ("x_m", "force_x_N", "stage"))
            for block in blocks_of(run, sizes):
                env.write(block)
            kept_by_blocks.append(env.result())
        same(*kept_by_blocks)  # the same samples whatever the blocks
        kept = kept_by_blocks[0]
        assert kept.names == ["time_s", "x_m", "force_x_N", "stage"]
        assert len(kept) <= 2 * math.ceil(len(run) / every)
        assert np.all(np.diff(kept.time_s) > 0)  # in time order
        force = run["force_x_N"]
        for b in range(0, len(run), every):  # each bucket's least and greatest force are kept
            bucket = force[b : b + every]
            inside = (kept.time_s >= run.time_s[b]) & (
                kept.time_s <= run.time_s[b + len(bucket) - 1]
            )
            assert kept["force_x_N"][inside].max() == bucket.max()
            assert kept["force_x_N"][inside].min() == bucket.min()


def test_a_long_hpattern_run_is_plotted_from_its_envelope_with_its_peaks(tmp_path, monkeypatch):
    """With the plot's bound at 2000 samples, a run of 11 s (10819 samples, 10816 before issue
    30's engagement changes; up to 38 s, the sequence's longest, were sized for: buckets of
    38) is drawn from at most 2000 of them: the
    title says how, the force's colour scale still reaches the run's
    peak, and the loops are the engagements' own samples at full rate."""
    monkeypatch.setattr(stream, "PLOT_SAMPLES", 2000)
    drawn: dict[str, Any] = {}

    def keep(result, layout, path, title, loops):
        drawn.update(result=result, title=title, loops=loops)
        return path

    monkeypatch.setattr(plots, "plot_hpattern", keep)
    config = HPatternRunConfig(parse_sequence("N,1,2,3,4,5,4,3,2,1,N"))
    run_hpattern(config, tmp_path / "hp.csv", tmp_path / "hp.png")
    whole = Result.from_csv(tmp_path / "hp.csv")
    shown = drawn["result"]
    assert len(whole) == 10819 and len(shown) <= 2 * math.ceil(10819 / 38)
    assert "10819 samples drawn as the extremes of every 38" in drawn["title"]
    magnitude = np.hypot(whole["force_x_N"], whole["force_y_N"])
    assert np.hypot(shown["force_x_N"], shown["force_y_N"]).max() == pytest.approx(
        magnitude.max(),
        rel=1e-9,  # the CSV's 10 digits
    )
    loops = drawn["loops"]
    assert [loop.label for loop in loops.loops][:3] == ["N \u2192 1", "1 \u2192 2", "2 \u2192 3"]
    assert loops.count == len(loops.loops) == 9 and not loops.more


def test_an_engagement_loop_is_the_push_that_ends_in_it():
    """A gear engaged again through neutral (N,1,N,1): its loop began with the previous push's
    hold at the stop (41 mm) and drew a straight line back to neutral; it starts at neutral
    now, labelled from where the knob came: neutral."""
    run = hpattern_run("N,1,N,1,2,1,N", physics=False, seed=5)
    for sizes in ([4096], [5, 900]):
        loops = plots.EngagementLoops()
        for block in blocks_of(run, sizes):
            loops.write(block)
        assert [loop.label for loop in loops.loops] == [
            "N \u2192 1", "N \u2192 1", "1 \u2192 2", "2 \u2192 1"
        ]  # fmt: skip
        for loop in loops.loops:
            along = load_hpattern("5r").setup.layout.gear(loop.gear).direction * loop.x_m
            assert abs(along[0]) < 5e-3  # starts in the neutral corridor, not at the stop
            assert along.max() > 0.04  # reaches the stop
            # the push and its stop: 400 samples after the engage event, the push before it
            assert 400 < len(along) < 1000


def test_the_plot_draws_at_most_its_loops_and_says_how_many_there_were():
    run = hpattern_run("N,1,2,1,2,1,2,N", physics=False)
    loops = plots.EngagementLoops(max_loops=3)
    loops.write(run)
    assert len(loops.loops) == 3 and loops.count == 6 and loops.more


LONG_SEQUENCE = "N," + ",".join(["1,2,3,4,5,4,3,2,1,N"] * 9)


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc/self/status")
@pytest.mark.parametrize(
    ("command", "short", "long"),
    [
        (["simulate", "shift", "--duration"], ["3"], ["300"]),
        (["simulate", "hpattern", "--sequence"], ["N,1"], [LONG_SEQUENCE]),
        (["simulate", "steering", "--manoeuvre", "iso7401-step", "--dt"], ["0.005"], ["0.0001"]),
    ],
)
@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_a_run_fifty_times_longer_peaks_at_the_same_memory(tmp_path, command, short, long):
    """Each run in a child process of its own, its peak resident memory (VmHWM) as it exits.
    Before: 0.43 / 1.06 / 1.35 KB a sample held, 130 MB more for the shift's 300 s, 98 MB
    for the 93 s H-pattern, 67 MB for the steering's 50,000 samples. Now the long run's peak
    is within 12 MB of the short one's (the allocator's pools, a block, and the steering's four
    columns that its feel metrics read: 2 MB)."""
    peaks = {}
    for name, extra in (("short", short), ("long", long)):
        out = tmp_path / f"{name}.csv"
        done, peaks[name] = carfeel_peak([*command, *extra, "--out", str(out)])
        assert done.returncode == 0, done.stderr
        peaks[name + "_rows"] = sum(1 for _ in out.open()) - 1
    assert peaks["long_rows"] >= 50 * peaks["short_rows"], peaks
    assert peaks["long"] - peaks["short"] < 12 * 1024, peaks


def test_simulate_writes_nothing_when_the_run_fails(tmp_path, capsys, monkeypatch):
    """A run that goes wrong half way (a NaN from the model) exits 2 with the message; the
    user's CSV and its metadata stay as they were, no staged file is left."""
    from carfeel.models.gearshift import engagement

    out = tmp_path / "run.csv"
    out.write_text("precious\n")
    out.with_suffix(".json").write_text("{}\n")
    real = engagement.step
    calls = []

    def broken(state, inputs, params, dt):  # wrong from the 500th step (1 ms each) on
        calls.append(dt)
        new, result = real(state, inputs, params, dt)
        return new, (result._replace(position_m=math.inf) if len(calls) >= 500 else result)

    monkeypatch.setattr("carfeel.simulation.shift.engagement.step", broken)
    assert main(["simulate", "shift", "--out", str(out), "--plot", str(tmp_path / "p.png")]) == 2
    assert "non-finite position_m at 0.5" in capsys.readouterr().err
    assert out.read_text() == "precious\n" and out.with_suffix(".json").read_text() == "{}\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv", "run.json"]


def test_the_in_memory_api_is_unchanged_in_results(tmp_path):
    """`simulate_*` still return the whole run; a CSV written by the command reads back as it."""
    assert main(["simulate", "shift", "--seed", "3", "--out", str(tmp_path / "s.csv")]) == 0
    back = Result.from_csv(tmp_path / "s.csv")
    run = shift_run(3)
    assert back.names == run.names and len(back) == len(run)
    assert np.allclose(back["force_N"], run["force_N"], rtol=1e-9, atol=0)  # 10 digits
    assert (back["stage"] == run["stage"]).all()
