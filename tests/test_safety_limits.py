"""The two safety values no test pinned (issue 26 point 3): the watchdog's out-of-range bound
(a reading beyond 1.1 x the device's travel is a fault, `realtime/safety.py`) and the session's
slew limit (200 x the force limit per second: full force in 5 ms, `realtime/session.py`). Each
is checked where it acts, in a default run, so that either raised or lowered 10x fails here."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import pytest

from carfeel.realtime import rendering, session
from carfeel.realtime.devices.base import DeviceSample
from carfeel.realtime.safety import SafetyLimits, Watchdog
from carfeel.realtime.session import RealtimeRun, run_realtime

FULL_FORCE_S = 0.005
"""The slew limit as built: the force limit per 5 ms (200 x max_force per second)."""
RANGE_MARGIN = 0.1
"""The watchdog's margin as built: a reading beyond 1.1 x travel is out of range."""


def _as_declared() -> dict[str, Any]:
    """The device taken as declared, where a run can choose (main's `identify`, issue 23): a
    session that identifies its device first excites it through this same safety chain, and the
    readings these tests inject at the device's own times would fault that instead of the loop."""
    fields = {f.name for f in dataclasses.fields(RealtimeRun)}
    return {"identify": "off"} if "identify" in fields else {}


# --- the watchdog's out-of-range bound ---------------------------------------------------------


@pytest.mark.parametrize("travel", [0.04, math.radians(450.0)])
def test_watchdog_faults_just_beyond_one_tenth_past_the_travel(travel: float) -> None:
    """1.09 x travel is inside, 1.11 x is a fault; either sign. A margin of 1.0 (10x) passes
    the second, one of 0.01 (a tenth) faults the first."""
    for sign in (1.0, -1.0):
        inside = Watchdog(SafetyLimits(1.0, 1.0), travel)
        inside.check((sign * 1.09 * travel,), 0.001, 1.0)
        assert not inside.faulted
        beyond = Watchdog(SafetyLimits(1.0, 1.0), travel)
        beyond.check((sign * 1.11 * travel,), 0.001, 1.0)
        assert beyond.faulted and "beyond the travel" in beyond.faults[0]


class _Offset:
    """A virtual device whose readings jump to `reading` x travel from t = 0.5 s."""

    def __init__(self, device: Any, reading: float) -> None:
        self._device, self.reading = device, reading

    def __getattr__(self, name: str) -> Any:
        return getattr(self._device, name)

    def __enter__(self) -> Any:
        self._device.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self._device.__exit__(*exc)

    def read(self, t: float) -> DeviceSample:
        sample: DeviceSample = self._device.read(t)
        if t < 0.5:
            return sample
        travel = self._device.info.travel
        return sample._replace(positions=(self.reading * travel, *sample.positions[1:]))


def _run_reading(monkeypatch: pytest.MonkeyPatch, reading: float) -> Any:
    opened = session.open_device
    monkeypatch.setattr(session, "open_device", lambda *a, **k: _Offset(opened(*a, **k), reading))
    run = RealtimeRun(model="steering", device="virtual:wheel", clock="simulated",
                      duration_s=1.0, calibrate=False, **_as_declared())  # fmt: skip
    return run_realtime(run).summary


def test_a_default_run_faults_on_a_reading_past_its_bound_not_before(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The session's SafetyLimits carry the bound into a run: a wheel read at 1.15 x its
    travel stops the run by a fault; at 1.05 x it runs to the end."""
    assert _run_reading(monkeypatch, 1.05).stopped == "duration"
    faulted = _run_reading(monkeypatch, 1.15)
    assert faulted.stopped == "fault"
    assert "beyond the travel" in faulted.faults[0]


# --- the session's slew limit ------------------------------------------------------------------


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_a_default_run_slews_at_the_force_limit_per_5_ms(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A model that asks for far beyond the limit from the first tick: the command climbs at
    the slew limit until the ramp-in's ceiling holds it, and at the end falls to zero at the
    slew limit, one step of max_force x 1 ms / 5 ms a tick. The JSON records the same limit."""
    monkeypatch.setattr(
        rendering.SteeringRenderer,
        "tick",
        lambda self, sample, dt: ((1e3,), (math.nan,) * len(self.columns)),
    )
    record = tmp_path / "slew.csv"
    # The passivity controller off: it would scale a force that spins the free wheel down.
    run = RealtimeRun(model="steering", device="virtual:wheel", clock="simulated",
                      duration_s=0.3, calibrate=False, hand="none", record=record,
                      passivity_controller=False)  # fmt: skip
    result = run_realtime(run)
    assert not result.summary.faults
    meta = json.loads(record.with_suffix(".json").read_text())
    top = meta["max_force"]
    assert meta["max_slew_per_s"] == pytest.approx(top / FULL_FORCE_S)  # written and pinned
    step = top / FULL_FORCE_S / meta["rate_hz"]  # per tick
    commands = [float(r["command_0"]) for r in _rows(record)]
    steps = [b - a for a, b in zip([0.0, *commands], commands, strict=False)]
    # Never a larger step than the limit (float rounding: 1e-9 of the force).
    assert max(abs(d) for d in steps) <= step * (1 + 1e-9)
    # At the start the ramp-in's ceiling (0.2 x max_force) and one slew step coincide.
    assert commands[0] == pytest.approx(min(step, 0.2 * top))
    # The end: from the ramp-in's ceiling at 0.3 s (0.2 + 0.8 x 0.3 = 0.44 x max_force) down to
    # zero, one slew step a tick (the last one the remainder).
    peak = max(commands)
    assert peak == pytest.approx(0.44 * top, rel=1e-3)
    fall = commands[commands.index(peak) :]
    assert fall[-1] == 0.0
    assert all(d == pytest.approx(-step) for d in steps[-len(fall) + 1 : -1])
    assert len(fall) - 1 == math.ceil(peak / step)  # 0.44 / 0.2: 3 ticks to zero


def test_a_fault_fades_the_force_over_50_ms_not_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The watchdog's fade (fade_s, 50 ms): a NaN reading at 0.25 s, the command at the ramp-in's
    ceiling then. 10 ms later it is still more than a tenth of what it was (an envelope that
    dropped at once would leave only the slew's 5 ms), and 51 ms later it is zero."""
    monkeypatch.setattr(
        rendering.SteeringRenderer,
        "tick",
        lambda self, sample, dt: ((1e3,), (math.nan,) * len(self.columns)),
    )
    opened = session.open_device
    monkeypatch.setattr(session, "open_device", lambda *a, **k: _Offset(opened(*a, **k), math.nan))
    monkeypatch.setattr(_Offset, "read", _nan_from(0.25))
    record = tmp_path / "fade.csv"
    run = RealtimeRun(model="steering", device="virtual:wheel", clock="simulated",
                      duration_s=1.0, calibrate=False, hand="none", record=record,
                      passivity_controller=False, **_as_declared())  # fmt: skip
    result = run_realtime(run)
    assert result.summary.stopped == "fault" and "read nan" in result.summary.faults[0]
    rows = _rows(record)
    times = [float(r["time_s"]) for r in rows]
    commands = [float(r["command_0"]) for r in rows]
    at = next(i for i, r in enumerate(rows) if r["fault"] == "1")
    before = commands[at - 1]
    assert before > 0.3 * 4.0  # near the ramp-in's 0.4 x max_force of the 4 Nm wheel
    after_10ms = next(c for t, c in zip(times, commands, strict=True) if t >= times[at] + 0.010)
    assert after_10ms > 0.1 * before
    assert all(c == 0.0 for t, c in zip(times, commands, strict=True) if t > times[at] + 0.051)


def _nan_from(start_s: float) -> Any:
    def read(self: _Offset, t: float) -> DeviceSample:
        sample: DeviceSample = self._device.read(t)
        if t < start_s:
            return sample
        return sample._replace(positions=(math.nan, *sample.positions[1:]))

    return read
