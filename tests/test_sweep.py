"""`carfeel sweep`: specs validated like presets, rows identical serially and on Dask, resume
after an interruption, results with their metadata, plots and the sensitivity ranking."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from carfeel.cli import main
from carfeel.sweep import results, runner, sensitivity, spec, tasks

SMALL = """\
model = "shift"
seeds = 2
cases_per_task = 2
[vary]
"gearbox.chamfer.gear_inertia_kg_m2" = { values = [0.1, 0.25] }
"driver.push_velocity_m_s" = { values = [0.2, 0.35] }
"""
"""8 cases in 4 tasks: cheap, and enough tasks for two workers to share."""


def _write(folder: Path, text: str, name: str = "spec.toml") -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text), encoding="utf-8")
    return path


def _same_rows(a: list[dict[str, object]], b: list[dict[str, object]]) -> bool:
    def same(x: object, y: object) -> bool:
        if isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y):
            return True
        return x == y and type(x) is type(y)

    return len(a) == len(b) and all(
        r.keys() == s.keys() and all(same(r[k], s[k]) for k in r) for r, s in zip(a, b, strict=True)
    )


# ---------------------------------------------------------------------------- the spec


BAD_SPECS = {
    "unknown key": ('model = "shift"\nsamplez = 3\n', ["samplez", "unknown key", "samples"]),
    "unknown parameter": (
        'model = "shift"\n[vary]\n"gearbox.chamfer.inertia" = { values = [0.1] }\n',
        ["gearbox.chamfer.inertia", "unknown parameter", "gear_inertia_kg_m2"],
    ),
    "bad distribution": (
        'model = "shift"\nsamples = 4\n[vary]\n'
        '"driver.push_force_N" = { distribution = "gauss", mean = 80, sd = 5 }\n',
        ["driver.push_force_N", "'gauss'", "truncnormal (mean, sd, low, high)"],
    ),
    "missing distribution argument": (
        'model = "shift"\nsamples = 4\n[vary]\n'
        '"driver.push_force_N" = { distribution = "uniform", low = 60 }\n',
        ["driver.push_force_N", "missing high"],
    ),
    "out-of-range grid value": (
        'model = "shift"\n[vary]\n"gearbox.chamfer.linkage_efficiency" = { values = [0.8, 1.3] }\n',
        ["gearbox.chamfer.linkage_efficiency = 1.3", "out of range", "0 < value <= 1"],
    ),
    "out-of-range bound": (
        'model = "shift"\nsamples = 4\n[vary]\n'
        '"gearbox.stop.damping_N_s_m" = { distribution = "uniform", low = -5, high = 50 }\n',
        ["gearbox.stop.damping_N_s_m", "low is a bound", "-5", "0 <= value <= 100000 N*s/m"],
    ),
    "missing preset file": (
        'model = "shift"\npreset = "nowhere/box.toml"\n',
        ["nowhere/box.toml", "not found", "paper-first-gear"],
    ),
    "a fixed value the preset refuses": (
        'model = "shift"\n[set]\n"driver.push_force_N" = 10.0\n',
        ["[set] makes the preset invalid", "must stay below driver.push_force_N = 10 N"],
    ),
    "distribution without samples": (
        'model = "shift"\n[vary]\n'
        '"driver.push_force_N" = { distribution = "normal", mean = 80, sd = 5 }\n',
        ["samples = None", "number of draws"],
    ),
    "a run setting in [run] and [vary]": (
        'model = "steering"\n[run]\nmanoeuvre = "iso7401-step"\nspeed_kmh = 100\n[vary]\n'
        '"run.speed_kmh" = { values = [60, 80] }\n',
        ["run.speed_kmh: given in [run] and in [set] or [vary]"],
    ),
    # What a case would only find when it runs.
    "a gear the layout does not have": (
        'model = "hpattern"\n[run]\nsequence = "N,1,7"\n',
        ["[run] sequence: no gear 7 in the preset's layout"],
    ),
    "a speed the manoeuvre does not take": (
        'model = "steering"\n[run]\nmanoeuvre = "steer-cycle"\n[vary]\n'
        '"run.speed_kmh" = { values = [0, 50] }\n',
        ["manoeuvre = 'steer-cycle' at run.speed_kmh = 50", "10 km/h"],
    ),
    # Parameters the run's model does not read (their rows would all be equal).
    "the physical model's tyres on the paper's law": (
        'model = "steering"\n[run]\nmanoeuvre = "iso7401-step"\n[vary]\n'
        '"tyres.pneumatic_trail_m" = { values = [0.03, 0.05] }\n',
        [
            "tyres.pneumatic_trail_m",
            "only the physical steering model",
            'steering_model = "physical"',
        ],
    ),
    "the paper law's gain on the physical model": (
        'model = "steering"\n[run]\nmanoeuvre = "iso7401-step"\nsteering_model = "physical"\n'
        '[vary]\n"torque.k1_Nm_s2_m" = { values = [2.0, 3.0] }\n',
        ["torque.k1_Nm_s2_m", "the paper's torque law reads it"],
    ),
    "a road for the paper's law": (
        'model = "steering"\n[run]\nmanoeuvre = "iso7401-step"\nroad = "snow"\n',
        ["[run] road", 'add steering_model = "physical"'],
    ),
    "a road and a mu": (
        'model = "steering"\n[run]\nmanoeuvre = "iso7401-step"\nsteering_model = "physical"\n'
        'road = "wet"\n[vary]\n"tyres.friction_coefficient" = { values = [0.3, 1.0] }\n',
        ["tyres.friction_coefficient and [run] road", "give one"],
    ),
    "a cone friction with the fixed synchronizer": (
        'model = "hpattern"\n[run]\nsequence = "N,1,2"\nsynchronizer = "fixed"\n[vary]\n'
        '"synchronizer.cone_friction" = { values = [0.08, 0.12] }\n',
        ["synchronizer.cone_friction", "only the physics synchronizer", 'synchronizer = "physics"'],
    ),
}


@pytest.mark.parametrize("name", list(BAD_SPECS))
def test_a_bad_spec_exits_2_naming_the_key_and_leaves_the_results_untouched(name, tmp_path, capsys):
    text, expected = BAD_SPECS[name]
    path = _write(tmp_path, text)
    out = tmp_path / "r.csv"
    out.write_text("the results of last week\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["sweep", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    for piece in expected:
        assert piece in err, (piece, err)
    assert "Traceback" not in err
    assert out.read_text() == "the results of last week\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_missing_spec_file_exits_2(tmp_path, capsys):
    assert main(["sweep", str(tmp_path / "no.toml"), "--out", str(tmp_path / "r.csv")]) == 2
    assert "no.toml not found" in capsys.readouterr().err


def test_the_cases_are_the_grid_times_the_draws_times_the_seeds():
    sweep = spec.from_toml(
        'model = "shift"\nseeds = [3, 7]\nsamples = 5\nsampling = "latin"\n[vary]\n'
        '"driver.push_velocity_m_s" = { values = [0.2, 0.3, 0.4] }\n'
        '"driver.push_force_N" = { distribution = "truncnormal", mean = 80, sd = 30, '
        "low = 60, high = 100 }\n"
    )
    cases = spec.cases(sweep)
    assert len(cases) == sweep.n_cases == 3 * 5 * 2
    assert [c.seed for c in cases[:4]] == [3, 7, 3, 7]
    forces = [dict(c.values)["driver.push_force_N"] for c in cases]
    assert all(60.0 <= f <= 100.0 for f in forces)
    # The same draws at every grid point; a Latin hypercube puts one draw in each fifth.
    assert forces[:10] == forces[10:20] == forces[20:]
    quantiles = sorted(forces[::2][:5])
    assert len({int((f - 60) / 8.0) for f in quantiles}) >= 4
    assert spec.from_toml(sweep.text).hash == sweep.hash
    assert spec.from_toml(sweep.text.replace("mean = 80", "mean = 81")).hash != sweep.hash


def test_a_draw_the_preset_refuses_is_an_invalid_row_naming_it():
    sweep = spec.from_toml(
        'model = "shift"\nsamples = 12\nsampling_seed = 4\n[vary]\n'
        '"gearbox.engagement.sliding_friction_N" = { distribution = "normal", mean = 11.5, '
        "sd = 1.0 }\n"
    )
    rows = tasks.run_task(tasks.Task(sweep, 0, sweep.n_cases))
    invalid = [r for r in rows if r["status"] == "invalid"]
    ok = [r for r in rows if r["status"] == "ok"]
    assert invalid and ok  # mean 11.5, sd 1: about 30 % of the draws exceed the static 12 N
    for r in invalid:
        assert r["gearbox.engagement.sliding_friction_N"] > 12.0
        assert "sliding_friction_N" in r["problem"] and "static_friction_N = 12 N" in r["problem"]
        assert r["engagement_peak_N"] is None
    assert all(r["gearbox.engagement.sliding_friction_N"] <= 12.0 for r in ok)
    assert all(isinstance(r["engagement_peak_N"], float) for r in ok)


def test_the_batch_and_the_pure_engine_give_the_same_rows(monkeypatch):
    monkeypatch.setattr(tasks, "BATCH_MIN_LANES", 1)  # batch even 8 lanes
    sweep = spec.from_toml(SMALL)
    batch = tasks.run_task(tasks.Task(sweep, 0, sweep.n_cases))
    pure = tasks.run_task(tasks.Task(dataclasses.replace(sweep, engine="pure"), 0, sweep.n_cases))
    assert _same_rows(batch, pure)
    assert all(r["status"] == "ok" and r["balked"] is False for r in batch)
    # The metrics move as the physics says: a heavier gear to index, a higher engagement peak.
    light = [
        r["engagement_peak_N"] for r in batch if r["gearbox.chamfer.gear_inertia_kg_m2"] == 0.1
    ]
    heavy = [r["engagement_peak_N"] for r in batch if r["gearbox.chamfer.gear_inertia_kg_m2"] > 0.1]
    assert np.mean(heavy) > np.mean(light)


# ---------------------------------------------------------------------------- Dask


MONTE_CARLO = """\
model = "shift"
seeds = 4
samples = 32
sampling = "latin"
cases_per_task = 64
[vary]
"gearbox.chamfer.gear_inertia_kg_m2" = { distribution = "uniform", low = 0.05, high = 0.3 }
"driver.push_force_N" = { distribution = "truncnormal", mean = 80, sd = 10, low = 60, high = 100 }
"""
"""128 shifts in two tasks of 64 lanes: the vectorized batch on each worker."""


@pytest.mark.slow  # over 2 s: make test (and CI) runs it, make check does not
def test_rows_are_identical_serially_and_on_a_two_worker_local_cluster():
    distributed = pytest.importorskip("dask.distributed")
    sweep = spec.from_toml(MONTE_CARLO)
    assert sweep.engine == "batch" and tasks.BATCH_MIN_LANES <= 64
    serial = runner.run_cases(sweep)
    cluster = distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    )
    try:
        on_dask = runner.run_cases(sweep, scheduler=cluster.scheduler_address)
    finally:
        cluster.close()
    assert on_dask.where.startswith("the cluster at tcp://")
    assert _same_rows(serial.rows, on_dask.rows)
    assert [r["case_id"] for r in on_dask.rows] == list(range(128))
    assert all(r["status"] == "ok" for r in serial.rows)


def probe(task: tasks.Task) -> list[dict[str, object]]:
    """A task that also says where it ran: its worker's threads and BLAS setting."""
    from distributed import get_worker

    worker = get_worker()
    rows = tasks.run_task(task)
    for row in rows:
        row["threads"] = worker.state.nthreads
        row["omp"] = os.environ.get("OMP_NUM_THREADS")
        row["openblas"] = os.environ.get("OPENBLAS_NUM_THREADS")
        row["worker"] = worker.address
    return rows


def test_a_script_without_a_main_guard_runs_on_single_threaded_workers(tmp_path):
    pytest.importorskip("dask.distributed")
    repo = Path(__file__).resolve().parents[1]
    spec_path = _write(tmp_path, SMALL)
    script = tmp_path / "unguarded.py"
    script.write_text(
        "import json, sys\n"
        "from pathlib import Path\n"
        f"sys.path.insert(0, {str(repo)!r})\n"
        "from carfeel.sweep import runner, spec\n"
        "from tests.test_sweep import probe\n"
        f"run = runner.run_cases(spec.load(Path({str(spec_path)!r})), workers=2, execute=probe)\n"
        "print(json.dumps(run.rows))\n"
    )
    done = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=600, cwd=tmp_path
    )
    # Without carfeel's care each spawned worker would run this script again, and fail to
    # start a cluster of its own while it is bootstrapping.
    assert done.returncode == 0, done.stderr[-3000:]
    rows = json.loads(done.stdout.strip().splitlines()[-1])
    assert {r.pop("threads") for r in rows} == {1}
    assert {r.pop("omp") for r in rows} == {"1"}
    assert {r.pop("openblas") for r in rows} == {"1"}
    assert len({r.pop("worker") for r in rows}) == 2  # 4 tasks over 2 workers: both got some
    serial = runner.run_cases(spec.load(spec_path))
    assert _same_rows(rows, json.loads(json.dumps(serial.rows)))


def test_the_local_cluster_refuses_clients_without_its_credentials():
    """--workers N starts its cluster with TLS and credentials made for the run: a client
    without them (another local user's `Client(address).run(os.getuid)`, the review's attack)
    cannot connect to the scheduler nor to a worker, in plain TCP, with TLS but no
    certificate, or with another temporary certificate of its own."""
    distributed = pytest.importorskip("dask.distributed")
    import ssl

    from distributed.security import Security

    with runner.dask_client(1, None) as (client, _, where, _note):
        assert where == "LocalCluster of 1 workers"
        scheduler = client.scheduler.address
        workers = list(client.scheduler_info()["workers"])
        assert scheduler.startswith("tls://127.0.0.1:") and workers
        assert all(w.startswith("tls://127.0.0.1:") for w in workers)
        assert set(client.run(os.getpid)) == set(workers)  # the run's own client gets in
        for address in (scheduler, *workers):
            host, port = address.removeprefix("tls://").rsplit(":", 1)
            # TLS without a client certificate: refused at the handshake (or closed unread).
            context = ssl.create_default_context()
            context.check_hostname = False
            context.verify_mode = ssl.CERT_NONE
            try:
                with (
                    socket.create_connection((host, int(port)), timeout=10) as raw,
                    context.wrap_socket(raw) as tls,
                ):
                    tls.sendall(b"\x00" * 64)
                    got = repr(tls.recv(1))
            except (ssl.SSLError, OSError):
                got = "refused"
            assert got in ("refused", "b''"), (address, got)
        for attempt in ({"address": scheduler.replace("tls://", "tcp://")},
                        {"address": scheduler, "security": Security.temporary()}):  # fmt: skip
            # Connecting is refused (a client cannot be made, so it runs nothing).
            with pytest.raises((OSError, TimeoutError, distributed.comm.CommClosedError)):
                distributed.Client(timeout="5s", **attempt)


# ---------------------------------------------------------------------------- resume


class Interrupt:
    """A task runner that is interrupted (Ctrl-C) when it starts its task number `at`."""

    real = staticmethod(tasks.run_chunk)

    def __init__(self, at: int | None) -> None:
        self.at = at
        self.ran: list[int] = []

    def __call__(self, task: tasks.Task) -> tasks.Chunk:
        if self.at is not None and len(self.ran) // len(task) >= self.at:
            raise KeyboardInterrupt
        self.ran.extend(range(task.start, task.stop))
        return self.real(task)


def test_an_interrupted_sweep_resumes_without_redoing_finished_cases(tmp_path, monkeypatch, capsys):
    path = _write(tmp_path, SMALL)
    out = tmp_path / "r.csv"
    out.write_text("old results\n")
    first = Interrupt(at=3)
    monkeypatch.setattr(tasks, "run_chunk", first)
    assert main(["sweep", str(path), "--out", str(out)]) == 130
    assert "run the same command again to resume" in capsys.readouterr().err
    assert out.read_text() == "old results\n"  # nothing written over
    part = runner.part_path(out)
    assert part.is_file() and first.ran == [0, 1, 2, 3, 4, 5]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".r.")]  # no staged files

    second = Interrupt(at=None)
    monkeypatch.setattr(tasks, "run_chunk", second)
    assert main(["sweep", str(path), "--out", str(out)]) == 0
    assert "6 kept from the interrupted run" in capsys.readouterr().out
    assert second.ran == [6, 7]  # only what was not finished
    assert not part.exists()
    resumed, meta = results.read(out)
    monkeypatch.undo()
    fresh = runner.run_cases(spec.load(path))
    assert resumed == results.columns_of(fresh.rows, fresh.spec)[0]
    assert meta["carfeel_spec_hash"] == fresh.spec.hash


def test_a_part_file_cut_by_a_kill_keeps_the_rows_before_the_cut(tmp_path):
    sweep = spec.from_toml(SMALL)
    part = runner.PartFile(tmp_path / "r.part.jsonl", sweep)
    part.open(keep=False)
    rows = tasks.run_task(tasks.Task(sweep, 0, 2))
    part.append(rows)
    part.close()
    with part.path.open("a") as handle:
        handle.write('{"start": 2, "columns": {"case_id": [2, 3], "sam')  # killed mid-line
    kept = part.load()
    assert sorted(kept) == [0, 1] and _same_rows([kept[0], kept[1]], rows)


def test_a_part_file_of_another_spec_is_refused_unless_restarted(tmp_path, monkeypatch, capsys):
    path = _write(tmp_path, SMALL)
    out = tmp_path / "r.parquet"
    monkeypatch.setattr(tasks, "run_chunk", Interrupt(at=1))
    assert main(["sweep", str(path), "--out", str(out)]) == 130
    monkeypatch.undo()
    capsys.readouterr()
    path.write_text(SMALL.replace("0.25", "0.3"))  # the spec changed
    assert main(["sweep", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "another sweep spec" in err and "--restart" in err
    assert not out.exists()
    counted = Interrupt(at=None)
    monkeypatch.setattr(tasks, "run_chunk", counted)
    assert main(["sweep", str(path), "--out", str(out), "--restart"]) == 0
    assert counted.ran == list(range(8))


# ---------------------------------------------------------------------------- results, plots


def test_parquet_results_keep_the_spec_and_version_and_plot(tmp_path, capsys):
    pytest.importorskip("pyarrow")
    text = SMALL.replace("[vary]", 'metrics = ["engagement_peak_N", "balked"]\n[vary]')
    path = _write(tmp_path, text)
    out, plots = tmp_path / "r.parquet", tmp_path / "plots"
    assert main(["sweep", str(path), "--out", str(out), "--plot", str(plots)]) == 0
    printed = capsys.readouterr().out
    assert "8 ok, 0 refused" in printed and "engine batch" in printed
    columns, meta = results.read(out)
    assert meta["carfeel_spec"] == text and meta["carfeel_model"] == "shift"
    from carfeel import __version__

    assert meta["carfeel_version"] == __version__
    assert columns["case_id"] == list(range(8))
    assert set(columns) >= {"gearbox.chamfer.gear_inertia_kg_m2", "engagement_peak_N", "balked"}
    assert columns["balked"] == [False] * 8
    for name in ("distributions.png", "sensitivity.png", "metric-engagement_peak_N.png"):
        assert (plots / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    page = (plots / "index.html").read_text()
    assert "PRCC" in page and "engagement_peak_N" in page
    # And again from the file, into another folder.
    again = tmp_path / "again"
    assert main(["sweep", "plot", str(out), "--out", str(again)]) == 0
    assert (again / "index.html").is_file() and (again / "distributions.png").is_file()


def test_csv_results_with_their_sidecar_read_back_as_written(tmp_path):
    path = _write(tmp_path, SMALL)
    out = tmp_path / "r.csv"
    assert main(["sweep", str(path), "--out", str(out)]) == 0
    columns, _ = results.read(out)
    assert json.loads(out.with_suffix(".json").read_text())["carfeel_spec"] == SMALL
    fresh = runner.run_cases(spec.load(path))
    assert columns == results.columns_of(fresh.rows, fresh.spec)[0]


def test_hpattern_and_steering_sweeps_run_their_pure_models(tmp_path):
    hp = spec.from_toml(
        'model = "hpattern"\nmetrics = ["shift1_1_synchronization_time_s", '
        '"shift2_2_synchronization_time_s", "balked", "total_time_s"]\n'
        '[run]\nsequence = "N,1,2"\nsynchronizer = "physics"\n'
        '[vary]\n"run.speed_kmh" = { values = [10.0, 40.0] }\n'
    )
    rows = runner.run_cases(hp).rows
    assert [r["status"] for r in rows] == ["ok", "ok"]
    slow, fast = rows
    assert not slow["balked"] and not fast["balked"]
    # Into first gear from a faster car: more speed difference for the cone to cancel.
    assert fast["shift1_1_synchronization_time_s"] > slow["shift1_1_synchronization_time_s"]
    steer = spec.from_toml(
        'model = "steering"\nmetrics = ["torque_gradient_Nm_per_g", "peak_torque_Nm"]\n'
        '[run]\nmanoeuvre = "weave"\n[vary]\n"torque.k1_Nm_s2_m" = { values = [2.0, 3.0] }\n'
    )
    low, high = runner.run_cases(steer).rows
    assert low["status"] == high["status"] == "ok"
    assert high["torque_gradient_Nm_per_g"] > low["torque_gradient_Nm_per_g"] > 0.0


def test_the_sensitivity_ranks_the_parameter_that_moves_a_metric_first():
    rng = np.random.default_rng(0)
    a, b, c = rng.uniform(0, 1, 200), rng.uniform(0, 1, 200), rng.uniform(0, 1, 200)
    y = np.exp(3 * a) + 0.5 * b + 0.05 * rng.normal(size=200)  # monotone, not linear, in a
    ranked = sensitivity.indices({"a": a, "b": b, "c": c}, y)
    assert [i.parameter for i in ranked] == ["a", "b", "c"]
    assert ranked[0].prcc > 0.95 and ranked[1].prcc > 0.5 and abs(ranked[2].prcc) < 0.2
    assert ranked[0].spearman > 0.8
    # A parameter drawn with another that dominates: rho hides it, PRCC finds it.
    strong, weak = rng.uniform(0, 1, 300), rng.uniform(0, 1, 300)
    z = 10 * strong + weak
    both = {i.parameter: i for i in sensitivity.indices({"s": strong, "w": weak}, z)}
    assert both["w"].prcc > 0.9 > 0.3 > both["w"].spearman


def test_progress_shows_on_a_terminal_only(tmp_path):
    class Tty:
        def __init__(self, tty: bool) -> None:
            self.tty, self.text = tty, ""

        def isatty(self) -> bool:
            return self.tty

        def write(self, text: str) -> None:
            self.text += text

        def flush(self) -> None:
            pass

    sweep = spec.from_toml(SMALL)
    quiet, shown = Tty(False), Tty(True)
    runner.run_cases(sweep, progress=quiet)  # type: ignore[arg-type]
    runner.run_cases(sweep, progress=shown)  # type: ignore[arg-type]
    assert quiet.text == ""
    assert "8/8 cases" in shown.text and "#" * 30 in shown.text


def test_the_draws_follow_their_distributions_and_the_ranks_handle_ties():
    from scipy import stats

    u = np.linspace(0.0005, 0.9995, 41)
    cases = [
        (spec.Vary("x", distribution="normal", args=(5.0, 2.0)), stats.norm(5.0, 2.0)),
        (spec.Vary("x", distribution="uniform", args=(1.0, 3.0)), stats.uniform(1.0, 2.0)),
        (
            spec.Vary("x", distribution="truncnormal", args=(80.0, 10.0, 60.0, 100.0)),
            stats.truncnorm(-2.0, 2.0, loc=80.0, scale=10.0),
        ),
        (  # the bounds far in the upper tail, where a naive CDF loses its digits
            spec.Vary("x", distribution="truncnormal", args=(0.0, 1.0, 4.0, 6.0)),
            stats.truncnorm(4.0, 6.0),
        ),
    ]
    for vary, reference in cases:
        # scipy.stats as the independent reference; 1e-9 of the spread covers ndtri's rounding.
        assert np.allclose(vary.sample(u), reference.ppf(u), rtol=0.0, atol=1e-9)
    values = np.array([3.0, 1.0, 2.0, 2.0, 5.0, 1.0, 1.0])
    assert np.array_equal(sensitivity._ranks(values), stats.rankdata(values))


def test_a_failed_sweep_leaves_no_plot_folder_behind(tmp_path, monkeypatch, capsys):
    """The plot folder is made, whole, only once every case has run: a run that fails (here a
    scheduler that cannot be reached, as the runner reports it) leaves nothing new."""
    from carfeel.errors import InputError
    from carfeel.sweep import runner

    def unreachable(*args, **kwargs):
        raise InputError("cannot reach the Dask scheduler tcp://127.0.0.1:1")

    monkeypatch.setattr(runner, "run_cases", unreachable)
    path = _write(tmp_path, SMALL)
    before = sorted(p.name for p in tmp_path.iterdir())
    plots = tmp_path / "newplots"
    assert main(["sweep", str(path), "--out", str(tmp_path / "r.csv"), "--plot", str(plots)]) == 2
    assert "cannot reach the Dask scheduler" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_run_that_ends_in_the_synchronization_has_no_synchronization_time():
    """Cut at 0.2 s the ring (0.3 s) still holds the lever: the time is where the run stopped,
    not a measured synchronization, so it is NaN (and the shift balked); the full run's is the
    preset's 0.3 s. Both engines."""
    text = (
        'model = "shift"\n[run]\nduration_s = DURATION\n[vary]\n'
        '"driver.push_force_N" = { values = [80] }\n'
    )
    for engine in ("batch", "pure"):
        short, full = (
            tasks.run_task(tasks.Task(dataclasses.replace(sweep, engine=engine), 0, 1))[0]
            for sweep in (spec.from_toml(text.replace("DURATION", d)) for d in ("0.2", "1.2"))
        )  # fmt: skip
        assert math.isnan(short["synchronization_time_s"]) and short["balked"] is True
        assert full["synchronization_time_s"] == pytest.approx(0.3, abs=0.01)
