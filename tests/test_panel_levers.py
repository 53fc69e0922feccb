"""The levers in the live panel: `sequential` and `prnd` sessions started, drawn, saved and
refused as `carfeel run`'s (Starlette's TestClient; the loop in a real process, simulated time)."""

from __future__ import annotations

import json
from typing import Any

import pytest

pytest.importorskip("starlette", reason="the panel needs carfeel[panel]")
pytest.importorskip("httpx2", reason="Starlette's TestClient needs httpx2 (carfeel[test])")

from carfeel.io.presets import load_prnd, load_sequential
from tests.test_panel import client_for, post, wait_for

# What the default scripts (run_options.DEFAULT_SEQUENCES) register, shift by shift, as
# tests/test_levers_device.py holds them for `carfeel run`: the locked pushes register nothing.
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
        assert model in options["models"] and options["tunables"][model] == []
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
