"""A sweep's sizes are checked before anything is made, and a large sweep's memory does not grow
with its cases (issue 24): `seeds = 100000000` took 15 s and 3.96 GB before it was refused, 1e9
and 1e18 died in a MemoryError, and a 10-million-case sweep held 6.4 GB of cases before its first
ran. Now the count is refused in a fraction of a second (bench_sweep.py measures it), the cases
and the draws are made as they are needed, and the rows go to the part file as they come and
from there, in order, to the results.
"""

from __future__ import annotations

import random
import sys
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from carfeel.cli import main
from carfeel.sweep import results, runner, spec, tasks
from tests.memory import carfeel_peak

UNIFORM = '"driver.push_force_N" = { distribution = "uniform", low = 60, high = 100 }'
TOO_MANY = {
    "seeds 1e8": 'model = "shift"\nseeds = 100000000\n',
    "seeds 1e9": 'model = "shift"\nseeds = 1000000000\n',
    "seeds 1e18": 'model = "shift"\nseeds = 1000000000000000000\n',
    "samples 1e18": f'model = "shift"\nsamples = 1000000000000000000\n[vary]\n{UNIFORM}\n',
    "seeds x samples": f'model = "shift"\nseeds = 10000000\nsamples = 2\n[vary]\n{UNIFORM}\n',
    "a grid of 1.6e7": 'model = "shift"\n[vary]\n'
    + '"driver.push_force_N" = {{ values = [{}] }}\n'.format(
        ", ".join(str(60 + k * 1e-3) for k in range(4000))
    )
    + '"driver.push_velocity_m_s" = {{ values = [{}] }}\n'.format(
        ", ".join(str(0.15 + k * 1e-5) for k in range(4000))
    ),
}


@pytest.mark.skipif(sys.platform != "linux", reason="/proc/self/status")
@pytest.mark.parametrize("name", TOO_MANY)
def test_too_many_cases_are_refused_before_any_is_made(tmp_path, name):
    """In a process of its own, to read its peak memory: the limit is named, exit 2, no
    traceback, no file, and never the gigabytes of the old check."""
    path = tmp_path / "big.toml"
    path.write_text(TOO_MANY[name])
    done, peak_kb = carfeel_peak(["sweep", str(path), "--out", str(tmp_path / "r.csv")], 120)
    assert done.returncode == 2, done.stderr
    assert "at most 1e+07" in done.stderr and "Traceback" not in done.stderr
    # Python, numpy and carfeel's imports are about 40 MB here; 200 MB is the bound.
    assert peak_kb < 200 * 1024, peak_kb
    assert [p.name for p in tmp_path.iterdir()] == ["big.toml"]


def test_a_spec_file_over_a_megabyte_is_refused_unread(tmp_path, capsys):
    path = tmp_path / "huge.toml"
    path.write_text('model = "shift"\n#' + "x" * spec.MAX_SPEC_BYTES + "\n")
    assert main(["sweep", str(path), "--out", str(tmp_path / "r.csv")]) == 2
    assert f"a spec is at most {spec.MAX_SPEC_BYTES} bytes" in capsys.readouterr().err


LATIN = """model = "shift"
seeds = [3, 7]
samples = 1000
sampling = "{sampling}"
sampling_seed = 5
[vary]
"driver.push_velocity_m_s" = {{ values = [0.2, 0.3] }}
"driver.push_force_N" = {{ distribution = "truncnormal", mean = 80, sd = 30, low = 60, high = 100 }}
"gearbox.chamfer.gear_inertia_kg_m2" = {{ distribution = "uniform", low = 0.05, high = 0.3 }}
"gearbox.neutral_detent.seat_force_N" = {{ distribution = "normal", mean = 5.0, sd = 0.5 }}
"""


def all_at_once(sweep: spec.SweepSpec) -> list[dict[str, Any]]:
    """The parameter sets as carfeel drew them before issue 24: every draw at once."""
    grid = [v for v in sweep.vary if v.values]
    draws = [v for v in sweep.vary if v.distribution]
    rng = np.random.default_rng(sweep.sampling_seed)
    if sweep.sampling == "latin":
        strata = np.column_stack([rng.permutation(sweep.samples) for _ in draws])
        u = (strata + rng.random((sweep.samples, len(draws)))) / sweep.samples
    else:
        u = rng.random((sweep.samples, len(draws)))
    drawn = {v.path: v.sample(u[:, j]) for j, v in enumerate(draws)}
    sets = []
    for a in grid[0].values:
        for s in range(sweep.samples):
            values = {grid[0].path: a, **{p: float(d[s]) for p, d in drawn.items()}}
            sets.append({v.path: values[v.path] for v in sweep.vary})
    return sets


@pytest.mark.parametrize("sampling", ["random", "latin"])
def test_draws_made_block_by_block_equal_the_draws_made_at_once(monkeypatch, sampling):
    """Tolerance 0: a resumed sweep must meet the very cases it left (77: blocks that do not
    divide the samples, so that every block boundary is crossed mid-grid)."""
    monkeypatch.setattr("carfeel.sweep.draws.DRAW_BLOCK", 77)
    sweep = spec.from_toml(LATIN.format(sampling=sampling))
    assert spec.parameter_sets(sweep) == all_at_once(sweep)
    assert isinstance(sweep.seeds, tuple) and sweep.n_cases == 2 * 1000 * 2
    assert spec.from_toml('model = "shift"\nseeds = 10000000\n').seeds == range(10_000_000)


def _fast(task: tasks.Task) -> list[dict[str, Any]]:
    """Rows without a simulation (what a task returns, less the physics): the runner's own
    cost and memory, nothing else."""
    return [tasks._row(task.spec, case, {}, "ok", "") for case in task.cases]


def _peak_bytes(n_seeds: int, folder: Path) -> tuple[int, Path]:
    sweep = spec.from_toml(f'model = "shift"\nseeds = {n_seeds}\ncases_per_task = 500\n')
    part = runner.PartFile(folder / "r.part.jsonl", sweep)
    out = folder / "r.csv"
    tracemalloc.start()
    try:
        run = runner.run_cases(sweep, part, execute=_fast, keep_rows=False)
        results.write_rows(part.rows_in_order(), sweep, out, ".csv")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert run.rows == [] and run.count("ok") == n_seeds
    return peak, out


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_a_large_sweep_streams_its_rows_in_memory_that_does_not_grow(tmp_path):
    """Ten times the cases, about the same peak memory: nothing per case is held but a byte of
    the bitmap of finished cases. (Traced Python allocations; the 1.5x and 1 MB allow for the
    bitmap, the allocator's pools and one task's rows.)"""
    (tmp_path / "small").mkdir()
    (tmp_path / "large").mkdir()
    small, _ = _peak_bytes(5_000, tmp_path / "small")
    large, out = _peak_bytes(50_000, tmp_path / "large")
    assert large < 1.5 * small + 1_000_000, (small, large)
    columns, _ = results.read(out)
    assert columns["case_id"] == list(range(50_000))
    assert columns["seed"] == list(range(50_000))


def test_rows_come_out_in_order_whatever_order_the_tasks_finished_in(tmp_path):
    """On Dask tasks finish in any order, and a resumed run's tasks stop at the cases already
    done: each line of the part file is one run of consecutive cases, so its lines in the order
    of their first case are the rows in order."""
    sweep = spec.from_toml('model = "shift"\nseeds = 300\ncases_per_task = 200\n')
    part = runner.PartFile(tmp_path / "r.part.jsonl", sweep)
    part.open(keep=False)
    part.append(_fast(tasks.Task(sweep, 100, 200)))
    part.close()
    done, tally = part.scan()
    assert int(done.sum()) == 100 and tally.counts == {"ok": 100}
    todo = list(runner.iter_tasks(sweep, done))
    assert [(t.start, t.stop) for t in todo] == [(0, 100), (200, 300)]
    assert [c.case_id for c in todo[1].cases] == list(range(200, 300))
    part.open(keep=True)
    chunks = [_fast(t) for t in todo]
    random.Random(1).shuffle(chunks)
    for chunk in reversed(chunks):
        part.append(chunk)
    part.close()
    assert [r["case_id"] for r in part.rows_in_order()] == list(range(300))
    assert [r["case_id"] for r in part.rows_in_order(every=50)] == [0, 50, 100, 150, 200, 250]
    # A chunk is consecutive cases: rows that are not cannot be appended as one.
    rows = _fast(tasks.Task(sweep, 0, 300))
    part.open(keep=True)
    with pytest.raises(ValueError, match="consecutive"):
        part.append(rows[250:] + rows[:250])
    part.close()
    assert [r["case_id"] for r in part.rows_in_order()] == list(range(300))


def test_a_missing_case_is_an_error_not_a_short_file(tmp_path):
    sweep = spec.from_toml('model = "shift"\nseeds = 10\n')
    part = runner.PartFile(tmp_path / "r.part.jsonl", sweep)
    part.open(keep=False)
    part.append(_fast(tasks.Task(sweep, 0, 4)))
    part.append(_fast(tasks.Task(sweep, 5, 10)))
    part.close()
    with pytest.raises(Exception, match="case 4 is missing"):
        list(part.rows_in_order())
