"""The fixed-step runner and the Result's CSV."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from carfeel.errors import InputError
from carfeel.simulation.result import Result
from carfeel.simulation.runner import run


class Out(NamedTuple):
    value: float
    label: str


def counter(state: int, inputs: float | None, params: float, dt_s: float) -> tuple[int, Out]:
    state += 1
    return state, Out(state * dt_s * params + (inputs or 0.0), "odd" if state % 2 else "even")


def test_runner_samples_at_dt_and_runs_substeps():
    result, final = run(counter, 0, 1.0, duration_s=0.01, dt_s=1e-3, substeps=4)
    assert final == 40  # 10 samples x 4 sub-steps
    assert np.allclose(result.time_s, np.arange(1, 11) * 1e-3)
    assert result["label"][0] == "even"  # the output of the 4th sub-step
    assert result["value"][-1] == pytest.approx(40 * 0.25e-3)


def test_runner_passes_inputs_at_each_substep_end():
    seen = []

    def inputs(t: float) -> float:
        seen.append(t)
        return 0.0

    run(counter, 0, 1.0, duration_s=2e-3, dt_s=1e-3, substeps=2, inputs=inputs)
    assert seen == pytest.approx([0.5e-3, 1e-3, 1.5e-3, 2e-3])


def test_runner_rejects_bad_steps():
    with pytest.raises(ValueError, match="dt_s must be > 0"):
        run(counter, 0, 1.0, duration_s=1.0, dt_s=0.0)
    with pytest.raises(ValueError, match="substeps"):
        run(counter, 0, 1.0, duration_s=1.0, substeps=0)
    with pytest.raises(ValueError, match="at least one dt_s"):
        run(counter, 0, 1.0, duration_s=1e-5)


def test_csv_round_trip_keeps_numbers_and_names(tmp_path):
    result, _ = run(counter, 0, 0.3, duration_s=0.05)
    path = result.to_csv(tmp_path / "r.csv")
    back = Result.from_csv(path)
    assert back.names == result.names
    assert np.allclose(back.time_s, result.time_s, rtol=1e-9)
    assert np.allclose(back["value"], result["value"], rtol=1e-9)
    assert list(back["label"]) == list(result["label"])
    assert path.read_text().splitlines()[0] == "time_s,value,label"


def test_csv_write_to_missing_folder_is_a_clear_error(tmp_path):
    result, _ = run(counter, 0, 1.0, duration_s=0.002)
    with pytest.raises(InputError, match="does not exist"):
        result.to_csv(tmp_path / "nope" / "r.csv")


def test_failed_write_keeps_the_existing_file(tmp_path, monkeypatch):
    result, _ = run(counter, 0, 1.0, duration_s=0.002)
    path = result.to_csv(tmp_path / "r.csv")
    before = path.read_text()

    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("carfeel.simulation.result.os.replace", broken)
    with pytest.raises(OSError, match="disk full"):
        result.to_csv(path)
    assert path.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["r.csv"]  # no temporary left behind


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty file"),
        ("a,b\n1,2\n", "no time_s column"),
        ("time_s,x\n0,1\n0.1\n", "line 3: 1 field, the header has 2"),
        ("time_s,x\nzero,1\n", "time_s must be numbers"),
    ],
)
def test_malformed_csv_is_named(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=message):
        Result.from_csv(path)


def test_missing_csv_is_named(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        Result.from_csv(tmp_path / "absent.csv")


def test_result_rejects_ragged_signals_and_names_unknown_ones():
    with pytest.raises(ValueError, match="has 2 samples, time has 3"):
        Result(np.zeros(3), {"x": np.zeros(2)})
    r = Result(np.zeros(2), {"x": np.zeros(2)})
    with pytest.raises(KeyError, match="the result has: time_s, x"):
        r["y"]
