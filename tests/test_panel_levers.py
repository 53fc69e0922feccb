"""The levers in the live panel: `sequential` and `prnd` sessions started, drawn, saved and
refused as `carfeel run`'s (Starlette's TestClient; the loop in a real process, simulated time)."""

from __future__ import annotations

import dataclasses
import json
from typing import Any

import pytest

pytest.importorskip("starlette", reason="the panel needs carfeel[panel]")
pytest.importorskip("httpx2", reason="Starlette's TestClient needs httpx2 (carfeel[test])")

from carfeel.io.presets import load_prnd, load_sequential
from tests.test_panel import client_for, post, wait_for

# What the default scripts (run_options.DEFAULT_SEQUENCES) register, shift by shift, as
# tests/test_levers_device.py holds them for `carfeel run`: the locked pushes register nothing.
TUNED = {  # a tunable, its preset value and the new one; every tunable of the model
    "sequential": ("lever.click_N", (25.0, 15.0), ("lever.click_N", "lever.centring_N_m",
                   "lever.drum_N", "lever.damping_N_s_m", "lever.wall_N_m")),
    "prnd": ("selector.detent_N", (15.0, 10.0), ("selector.detent_N", "selector.damping_N_s_m",
             "selector.wall_N_m")),
}  # fmt: skip
EXPECTED = {
    "sequential": ["1", "2", "1", "N", "R", "N", "1"],
    "prnd": ["R", "N", "D", "N", "R", "P"],
}


@pytest.mark.slow  # a whole script in simulated time, over 2 s
@pytest.mark.parametrize(
    ("model", "device"), [("sequential", "virtual:shifter"), ("prnd", "virtual:joystick")]
)
def test_the_panel_runs_a_lever_with_its_script_and_saves_its_preset(tmp_path, model, device):
    with client_for(tmp_path) as client:
        options = client.get("/api/options").json()
        assert model in options["models"]
        assert {t["path"] for t in options["tunables"][model]} == set(TUNED[model][2])
        assert options["default_sequences"][model]  # the page fills the hand's script with it
        start = post(client, "/api/session", {
            "model": model, "device": device, "clock": "simulated", "duration_s": 60,
            "force": True,
        })  # fmt: skip
        assert start.status_code == 200, start.text
        # The stream carries the lever's position and the registered gear.
        gears: list[str] = []
        with client.websocket_connect("/api/stream") as ws:
            ws.send_json({"columns": ["time_s", "gear", "position_m"], "every": 1})
            for _ in range(2000):
                message = ws.receive_json()
                if message["type"] != "frame" or "columns" not in message:
                    continue
                for gear in message["columns"].get("gear", []):
                    if gear and (not gears or gears[-1] != gear):
                        gears.append(gear)
                if len(gears) > 2:
                    break
        assert len(gears) > 2, gears
        ended = wait_for(client, lambda s: s["state"] == "ended", timeout_s=300, what="the end")
        assert ended["engaged"] == EXPECTED[model], ended["engaged"]
        assert ended["summary"]["gears"] == EXPECTED[model]
        assert not ended["faults"], ended["faults"]
        # The view's marks: the lever's ends and detents along + x, from its preset.
        marks = ended["lever"]
        positions = [m["position_m"] for m in marks]
        assert positions == sorted(positions)
        names = [m["name"] for m in marks]
        if model == "prnd":
            lever = load_prnd().params.selector
            assert names == ["end", *lever.positions, "end"]
            assert positions[1:-1] == pytest.approx(
                [lever.centre_m(i) for i in range(len(lever.positions))]
            )
        else:
            seq = load_sequential().params.lever
            assert sorted(names) == ["down", "end", "end", "rest", "up"]
            assert positions == pytest.approx(
                [-seq.end_m, -seq.click_m, 0.0, seq.click_m, seq.end_m]
            )
            up = next(m for m in marks if m["name"] == "up")
            assert up["position_m"] == pytest.approx(seq.up_direction * seq.click_m)
        # Saved as a preset the loader takes back, equal to the one the session ran.
        saved = post(client, "/api/presets", {"name": f"my-{model}"})
        assert saved.status_code == 200, saved.text
        path = tmp_path / "presets" / model / f"my-{model}.toml"
        loader = load_sequential if model == "sequential" else load_prnd
        assert loader(str(path)).params == loader().params
        assert f"saved:my-{model}" in client.get("/api/options").json()["presets"][model]


@pytest.mark.parametrize(
    ("body", "words"),
    [
        ({"model": "sequential", "sequence": "up,sideways"}, "sideways"),
        ({"model": "prnd", "sequence": "R,X"}, "X"),
        ({"model": "prnd", "sequence": "R," * 15_000}, "at most 20000 characters"),
        ({"model": "prnd", "sequence": 7}, "positions such as R,N,D,P"),
    ],
)
def test_a_lever_script_the_preset_cannot_make_is_refused_with_the_reason(
    tmp_path, body: dict[str, Any], words: str
):
    with client_for(tmp_path) as client:
        answer = post(client, "/api/session", {**body, "device": "virtual:joystick",
                                               "force": True})  # fmt: skip
        assert answer.status_code == 400, answer.text
        assert words in answer.json()["error"], json.dumps(answer.json())
        assert client.get("/api/session").json() == {"state": "idle"}


@pytest.mark.slow  # a session in simulated time, over 2 s
@pytest.mark.parametrize("model", ["sequential", "prnd"])
def test_a_lever_is_tuned_at_rest_within_the_devices_force_and_saved_so(tmp_path, model):
    path, (old, new), _ = TUNED[model]
    first = {"sequential": "up", "prnd": "R"}[model]
    with client_for(tmp_path) as client:
        start = post(client, "/api/session", {
            "model": model, "device": "virtual:joystick", "clock": "simulated",
            "duration_s": 3600, "sequence": first, "force": True,
        })  # fmt: skip
        assert start.status_code == 200, start.text
        wait_for(client, lambda s: s.get("engaged"), what="the first shift")
        # Beyond what the device renders at its limit: refused with the figures.
        loud = post(client, "/api/tune", {"values": {path: 400.0}})
        assert (
            loud.status_code == 400
            and "the device renders at its force limit" in (loud.json()["error"])
        ), loud.text
        # Out of the preset's range: refused with the range.
        assert "out of range" in post(client, "/api/tune", {"values": {path: -1}}).json()["error"]
        tune = post(client, "/api/tune", {"values": {path: new}})
        assert tune.status_code == 200, tune.text
        assert tune.json()["changes"][path] == {"old": old, "new": new}
        assert tune.json()["waits_for"].startswith("the lever at rest")
        tuned = wait_for(client, lambda s: any(e["event"] == "tuned" for e in s["events"]),
                         what="the tuning applied at rest")  # fmt: skip
        assert not tuned["faults"]
        assert client.get("/api/tune").json()["tunables"]
        values = {t["path"]: t["value"] for t in client.get("/api/tune").json()["tunables"]}
        assert values[path] == new
        saved = post(client, "/api/presets", {"name": "tuned"})
        assert saved.status_code == 200, saved.text
        file = str(tmp_path / "presets" / model / "tuned.toml")
        lever: Any = (
            load_sequential(file).params.lever
            if model == "sequential"
            else load_prnd(file).params.selector
        )
        assert getattr(lever, path.split(".")[1]) == new
        assert client.post("/api/session/stop").status_code == 200
        ended = wait_for(client, lambda s: s["state"] == "ended", what="the end")
        assert ended["engaged"] == [{"sequential": "1", "prnd": "R"}[model]]
        assert not ended["faults"]


def test_a_lever_tuning_waits_for_the_lever_at_rest_in_a_position_then_ramps():
    from carfeel.panel.tuning import RAMP_S, Ramp
    from carfeel.realtime.levers import LeverRenderer, SequentialLever
    from carfeel.realtime.rendering import Gains, Scaling

    params = load_sequential().params.lever
    lever = SequentialLever(params)
    renderer = LeverRenderer(lever, Scaling(1.0, 1.0), 1000.0, Gains(0, 0, 1e4, 60, 0, 0))
    target = dataclasses.replace(params, click_N=15.0)
    ramp = Ramp(renderer, "sequential", ("retune", (("click_N", 25.0, 15.0),), target, None,
                                          {"lever.click_N": (25.0, 15.0)}), 1000.0)  # fmt: skip
    lever.state = lever.state._replace(x_m=0.015)  # pushed toward a shift: not now
    assert not ramp.step() and lever.params.click_N == 25.0
    lever.state = lever.state._replace(x_m=0.0, v_m_s=0.0)
    blended = []
    while not ramp.step():
        blended.append(lever.params.click_N)
    assert len(blended) == round(RAMP_S * 1000) - 1
    assert blended == sorted(blended, reverse=True) and 15.0 < blended[-1] < blended[0] < 25.0
    assert lever.params == target
