"""The panel's session request is hostile input too: any JSON body is a run or an InputError
(the API's 400), never another exception; and its telemetry listens beyond loopback only when
the panel itself was started for the network (issue 24 point 5, issue 26)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("starlette", reason="the panel needs carfeel[panel]")

from carfeel.errors import CarfeelError, InputError
from carfeel.panel.config import PanelConfig
from carfeel.panel.state import Panel

FIELDS = ("model", "preset", "device", "mode", "speed_kmh", "hand", "clock", "sequence",
          "duration_s", "seed", "telemetry", "synchronizer", "rate_hz", "force", "aligning",
          "device_delay_ms", "calibrate", "steering_model", "road")  # fmt: skip
SOURCES = ("forza:127.0.0.1:0", "forza:0.0.0.0:5301", "forza:0.0.0.0:5301,from=any",
           "carfeel:127.0.0.1:0,from=10.0.0.0/8", "gt7:1", "forza:127.0.0.1:99999",
           "forza:127.0.0.1:0,to=x", "outsim@zz:1", "assetto:127.0.0.1:0", "")  # fmt: skip
"""Telemetry sources to try: no free text, which would be looked up as a host name."""

JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner,
                                                                  max_size=4),
    max_leaves=8,
)  # fmt: skip


def _value(name: str) -> st.SearchStrategy[Any]:
    if name == "telemetry":
        return st.sampled_from(SOURCES) | st.integers() | st.none()
    if name == "model":
        return st.sampled_from(("shift", "hpattern", "steering")) | JSON
    if name == "force":
        return st.just(True) | JSON
    return JSON


BODY = st.fixed_dictionaries({}, optional={name: _value(name) for name in FIELDS} | {"extra": JSON})


@pytest.fixture(scope="module")
def panel(tmp_path_factory: pytest.TempPathFactory) -> Panel:
    return Panel(PanelConfig(folder=tmp_path_factory.mktemp("panel")))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(body=BODY)
def test_any_session_body_is_a_run_or_an_input_error(panel: Panel, body: dict[str, Any]) -> None:
    try:
        run = panel.run_of(body)
    except CarfeelError:
        return  # the API answers 400 with the message
    assert isinstance(run, dict) and run["model"] in ("shift", "hpattern", "steering")


def _body(telemetry: str) -> dict[str, Any]:
    return {"model": "steering", "device": "virtual:wheel", "force": True, "telemetry": telemetry}


def test_a_local_panel_never_listens_beyond_loopback(tmp_path: Path) -> None:
    local = Panel(PanelConfig(folder=tmp_path))
    assert local.run_of(_body("forza:127.0.0.1:5301"))["telemetry"] == "forza:127.0.0.1:5301"
    for source in ("forza:0.0.0.0:5301,from=any", "forza:0.0.0.0:5301,from=192.168.1.0/24"):
        with pytest.raises(InputError, match="started for this machine only"):
            local.run_of(_body(source))


def test_a_network_panel_listens_beyond_loopback_for_whom_it_names(tmp_path: Path) -> None:
    network = Panel(PanelConfig(folder=tmp_path, hosts=()))  # `carfeel panel --host 0.0.0.0`
    source = "forza:0.0.0.0:5301,from=192.168.1.0/24"
    assert network.run_of(_body(source))["telemetry"] == source
    with pytest.raises(InputError, match="--accept-from"):
        network.run_of(_body("forza:0.0.0.0:5301"))  # whom to take from, still required


FINITE_JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**300), 10**300) | st.floats()
    | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner,
                                                                  max_size=3),
    max_leaves=6,
)  # fmt: skip
"""JSON values; integers within a float's range (a longer one: the test below)."""


def _tuning_session(model: str) -> Any:
    from carfeel.io.presets import load_hpattern, load_shift
    from carfeel.panel import tuning

    preset = load_shift().params if model == "shift" else load_hpattern()
    return tuning.Session(model, preset, None, {})


@pytest.mark.parametrize("model", ["shift", "hpattern"])
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_any_tuning_is_a_proposal_or_an_input_error(model: str, data: st.DataObject) -> None:
    """A tuning's values (the panel's POST /api/tune, its WebSocket's JSON) of any shape: a
    proposal, or an InputError naming what is wrong."""
    from carfeel.panel import tuning

    session = _tuning_session(model)
    now = tuning.values_of(model, session.preset)
    paths = sorted(now)
    keys = data.draw(st.lists(st.sampled_from(paths) | st.text(max_size=10), max_size=4))
    values: dict[str, Any] = {}
    for k in keys:  # near today's value, where a change is often accepted; anything else
        near = data.draw(st.floats(0.8, 1.2)) * now.get(k, 1.0)
        values[k] = data.draw(FINITE_JSON | st.just(near))
    try:
        proposal = tuning.propose(session, values)
    except CarfeelError:
        return
    assert set(proposal.changes) == set(values)
    assert all(proposal.changes[k][1] == pytest.approx(v) for k, v in values.items())


def test_a_401_digit_tuning_integer_is_an_input_error() -> None:
    from carfeel.panel import tuning

    path = sorted(t.path for t in tuning.tunables_for("shift"))[0]
    with pytest.raises(InputError, match="out of range"):
        tuning.propose(_tuning_session("shift"), {path: 10**400})
