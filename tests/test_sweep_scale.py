"""Sweeps that scale out (issue 27): a task travels as the spec and two case numbers and its
worker makes its own cases, its rows come back by column, the last tasks shrink so that the
workers finish together, the client's memory does not grow with the cases on Dask either, and
the progress bar says the rate now, not the start-up's."""

from __future__ import annotations

import io
import itertools
import json
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from carfeel.sweep import runner, spec, tasks

LATIN_GRID = """\
model = "shift"
seeds = [3, 7, 11]
samples = 300
sampling = "latin"
sampling_seed = 5
[vary]
"driver.push_velocity_m_s" = { values = [0.2, 0.3] }
"driver.push_force_N" = { distribution = "truncnormal", mean = 80, sd = 30, low = 60, high = 100 }
"gearbox.neutral_detent.seat_force_N" = { distribution = "normal", mean = 5.0, sd = 0.5 }
"""


def test_a_task_makes_the_cases_the_whole_sweep_makes(monkeypatch):
    """Any run of cases, made by a worker from the spec alone, equals those cases of the whole
    sweep, bit for bit: across grid points, seeds and blocks of draws (77 samples a block
    here, so that runs cross them)."""
    monkeypatch.setattr("carfeel.sweep.draws.DRAW_BLOCK", 77)
    sweep = spec.from_toml(LATIN_GRID)
    every = spec.cases(sweep)
    assert len(every) == sweep.n_cases == 2 * 300 * 3
    rng = np.random.default_rng(0)
    for start, stop in [(0, 1), (0, 1800), (899, 902), (230, 231), (1799, 1800), *(
        sorted(rng.integers(0, 1801, 2)) for _ in range(40)
    )]:  # fmt: skip
        if start == stop:
            continue
        assert tasks.Task(sweep, int(start), int(stop)).cases == tuple(every[start:stop])
    with pytest.raises(ValueError, match=r"cases 5\.\.4 of 1800"):
        tasks.Task(sweep, 5, 5)
    with pytest.raises(ValueError, match=r"cases 0\.\.1800 of 1800"):
        tasks.Task(sweep, 0, 1801)


def test_a_task_travels_in_a_few_kilobytes_whatever_its_size():
    """It held its cases: 166 kB for 4096 shifts of five parameters, 40 bytes a case."""
    sweep = spec.from_toml(LATIN_GRID.replace("samples = 300", "samples = 100000"))
    small = len(pickle.dumps(tasks.Task(sweep, 0, 10)))
    large = len(pickle.dumps(tasks.Task(sweep, 0, 500_000)))
    # The spec's text and its preset's (8 kB); the case numbers take a few bytes more.
    assert large - small < 16 and large < 10_000, (small, large)


def test_a_tasks_rows_come_back_by_column_and_read_back_as_rows(tmp_path):
    sweep = spec.from_toml(LATIN_GRID.replace("samples = 300", "samples = 4"))
    chunk = tasks.run_chunk(tasks.Task(sweep, 5, 17))
    assert chunk.start == 5 and len(chunk) == 12 and chunk.stop == 17
    assert chunk.columns["case_id"] == list(range(5, 17))
    assert list(chunk.columns) == sweep.columns()
    rows = chunk.rows()
    assert rows == tasks.run_task(tasks.Task(sweep, 5, 17))
    assert tasks.Chunk.of(rows) == chunk
    fourth = chunk.every(4)
    assert fourth is not None and fourth.columns["case_id"] == [8, 12, 16]
    assert chunk.every(100) is None
    with pytest.raises(ValueError, match="consecutive"):
        tasks.Chunk.of(rows[::2])
    # The part file keeps chunks as lines of columns; one whose ids are not its own is a cut.
    part = runner.PartFile(tmp_path / "r.part.jsonl", sweep)
    part.open(keep=False)
    part.append(chunk)
    part.close()
    line = json.loads(part.path.read_text().splitlines()[1])
    assert line["start"] == 5 and line["columns"]["case_id"] == list(range(5, 17))
    bad = dict(line, start=6)
    with part.path.open("a") as handle:
        handle.write(json.dumps(bad) + "\n")
    assert sorted(part.load()) == list(range(5, 17))  # the bad line ends what is read
    done, tally = part.scan()
    assert int(done.sum()) == 12 and done[5:17].all() and sum(tally.counts.values()) == 12


def test_an_old_part_file_is_refused_with_the_way_out(tmp_path):
    """A part file of the rows-as-dicts format (issue 24's) is another format: refused, exit 2
    through SpecError, with --restart named."""
    sweep = spec.from_toml(LATIN_GRID)
    path = tmp_path / "r.part.jsonl"
    header = {"carfeel_sweep_part": 1, "spec_hash": sweep.hash, "spec": "x", "cases": 1}
    path.write_text(json.dumps(header) + '\n{"rows": [{"case_id": 0}]}\n')
    with pytest.raises(spec.SpecError, match="--restart"):
        runner.PartFile(path, sweep).scan()


@pytest.mark.parametrize("workers", [1, 2, 3, 8])
def test_tasks_cover_every_case_left_once_and_the_last_ones_shrink(workers):
    sweep = spec.from_toml('model = "shift"\nseeds = 100000\ncases_per_task = 4096\n')
    done = np.zeros(sweep.n_cases, dtype=bool)
    done[10_000:10_500] = True  # an interrupted run's finished cases
    done[70_000] = True
    todo = list(runner.iter_tasks(sweep, done, workers))
    covered = np.zeros(sweep.n_cases, dtype=int)
    for task in todo:
        covered[task.start : task.stop] += 1
    assert (covered == ~done).all()  # every case left, once
    sizes = [len(t) for t in todo]
    assert max(sizes) == 4096
    if workers == 1:  # serially: all of cases_per_task but where a finished case cuts a run
        assert sorted(sizes)[3:] == [4096] * (len(sizes) - 3)  # three runs, three ends
    else:
        # Near the end at most half of what is left a worker, not below a quarter of a task.
        tail = sizes[-6:]
        assert tail[-2] < 4096 and all(s >= 1024 for s in sizes[:-1])
        assert all(a >= b for a, b in itertools.pairwise(tail[:-1]))


def test_the_progress_bar_shows_the_rate_now(monkeypatch):
    """1000 cases in the first 100 s (the cluster starting, the first tasks), then 1000 a
    second: after two minutes the bar says about 1000 cases/s, not the 100 s average of 250."""

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    clock = [0.0]
    monkeypatch.setattr("carfeel.sweep.runner.time.monotonic", lambda: clock[0])
    screen = Terminal()
    bar = runner.Progress(500_000, 0, screen)
    for _ in range(10):
        clock[0] += 10.0
        bar.update(100)
    for _ in range(60):
        clock[0] += 1.0
        bar.update(1000)
    shown = screen.getvalue().rsplit("\r", 1)[1]
    assert "61000/500000 cases, 1000.0 cases/s" in shown and "439 s left" in shown
    assert bar.rate(clock[0]) == pytest.approx(1000.0)


CLIENT = """
import sys
sys.path.insert(0, {repo!r})
from pathlib import Path
from carfeel.sweep import results, runner, spec
from tests.test_sweep_scale import fast
n, folder = int(sys.argv[1]), Path(sys.argv[2])
sweep = spec.from_toml(f'model = "shift"\\nseeds = {{n}}\\ncases_per_task = 2000\\n')
part = runner.PartFile(folder / "r.part.jsonl", sweep)
run = runner.run_cases(sweep, part, workers=1, execute=fast, keep_rows=False)
results.write_chunks(part.chunks_in_order(), sweep, folder / "r.csv", ".csv")
assert run.count("ok") == n, run.tally
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM:')]
print(hwm[0].split()[1])
"""


def fast(task: tasks.Task) -> tasks.Chunk:
    """A task's rows without a simulation: the client's own cost, nothing else."""
    return tasks.Chunk.of([tasks._row(task.spec, case, {}, "ok", "") for case in task.cases])


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc/self/status")
@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_the_clients_memory_does_not_grow_with_the_cases_on_dask(tmp_path):
    """A client (with its LocalCluster's scheduler, in its process) of 20,000 and of 200,000
    cases, each in a child process of its own (its VmHWM as it ends): within 15 MB (Dask's
    logs of a hundred tasks, the bitmap of cases and a chunk; 2.7 KB a case would be 486 MB)."""
    pytest.importorskip("dask.distributed")
    repo = str(Path(__file__).resolve().parents[1])
    peaks = []
    for n in (20_000, 200_000):
        folder = tmp_path / str(n)
        folder.mkdir()
        done = subprocess.run(
            [sys.executable, "-c", CLIENT.format(repo=repo), str(n), str(folder)],
            capture_output=True, text=True, timeout=600, check=False,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr[-3000:]
        peaks.append(int(done.stdout.split()[-1]))
        assert sum(1 for _ in (folder / "r.csv").open()) == n + 1
    assert peaks[1] - peaks[0] < 15 * 1024, peaks


def test_parquet_is_written_from_the_chunks_as_they_come(tmp_path, monkeypatch):
    """`write_chunks` draws a row group's chunks, writes them, then draws the next: it held every
    chunk before writing (`(*chunks, None)`): a 10^6-case sweep's client peaked at 727 MB on
    --workers 2 (582 MB writing rows made without simulating, 212 MB for 10^5)."""
    pq = pytest.importorskip("pyarrow.parquet")
    from carfeel.sweep import results

    sweep = spec.from_toml('model = "shift"\nseeds = 10000\ncases_per_task = 1000\n')
    monkeypatch.setattr(results, "WRITE_BATCH", 2000)  # two chunks a row group
    drawn: list[int] = []

    def chunks():
        for start in range(0, 10_000, 1000):
            drawn.append(start)
            yield fast(tasks.Task(sweep, start, start + 1000))

    at_write: list[int] = []
    real = pq.ParquetWriter.write_table

    def write_table(self, table, *args, **kwargs):
        at_write.append(len(drawn))
        return real(self, table, *args, **kwargs)

    monkeypatch.setattr(pq.ParquetWriter, "write_table", write_table)
    results.write_chunks(chunks(), sweep, tmp_path / "r.parquet", ".parquet")
    assert at_write == [2, 4, 6, 8, 10], at_write
    back = pq.read_table(tmp_path / "r.parquet")
    assert back.num_rows == 10_000 and back.column("case_id").to_pylist() == list(range(10_000))
