"""What a session may be: the choices the page offers (GET /api/options) and a request's session
checked against them, as `carfeel run` checks its own, into RealtimeRun's keyword arguments."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.models.rng import MAX_SEED
from carfeel.panel import tuning
from carfeel.panel.config import KINDS
from carfeel.panel.recordings import recording_file, replay_problem
from carfeel.panel.values import inside, number_of, safe_name, said

VIRTUAL_CHANGES = re.compile(r"[A-Za-z_]+=[0-9.eE+-]+x?(,[A-Za-z_]+=[0-9.eE+-]+x?)*")
"""`virtual:KIND:KEY=VALUE,...`'s changes to the true plant: names and numbers, nothing else."""
MAX_TEXT_CHARS = 200
"""The longest text field of a session's request (a device, a mode, a telemetry source)."""
MAX_SEQUENCE_CHARS = 20_000
"""The longest virtual hand's script (a long H-pattern session's gears run to a few thousand)."""
PANEL_MODELS = ("shift", "hpattern", "sequential", "prnd", "steering")
"""The models the panel starts: all of `carfeel run`'s."""


SCRIPTS = {
    "hpattern": "gears such as N,1,2,N",
    "sequential": "moves such as up,up,down,lift-down",
    "prnd": "positions such as R,N,D,P",
}
"""What a session's `sequence` holds, per model that has a virtual hand's script."""


def options(preset_folder: Path, real: list[str], replays: list[str]) -> dict[str, Any]:
    """What the page offers (`real`: the devices detected; `replays`: the recordings')."""
    from carfeel.io.presets import available
    from carfeel.realtime.devices.virtual import PLANTS
    from carfeel.realtime.hands import HANDS
    from carfeel.realtime.rendering import MODES
    from carfeel.realtime.run_options import DEFAULT_SEQUENCES
    from carfeel.realtime.session import DEFAULT_PRESETS
    from carfeel.simulation.steering import ROAD_FRICTION, STEERING_MODELS

    presets = {
        kind: [*available(kind), *(f"saved:{p.stem}" for p in
                                   sorted((preset_folder / kind).glob("*.toml")))]
        for kind in KINDS
    }  # fmt: skip
    return {
        "models": list(PANEL_MODELS),
        "modes": list(MODES),
        "default_presets": DEFAULT_PRESETS,
        "default_sequences": {m: ",".join(s) for m, s in DEFAULT_SEQUENCES.items()},
        "presets": presets,
        "devices": {
            "joystick": [f"virtual:{k}" for k, v in PLANTS.items() if v[2] == "joystick"],
            "wheel": [f"virtual:{k}" for k, v in PLANTS.items() if v[2] == "wheel"],
            "real": real,
            "replays": replays,
        },
        "hands": list(HANDS),
        "clocks": ["wall", "simulated"],
        "telemetry_formats": _telemetry_formats(),
        "steering_models": list(STEERING_MODELS),
        "roads": list(ROAD_FRICTION),
        "tunables": {
            m: [t.as_dict() for t in tuning.tunables_for(m)]
            for m in (*PANEL_MODELS, tuning.PHYSICAL)
        },
    }


def device_of(spec: str, recording_folder: Path, detect: Callable[[], list[str]]) -> str:
    """The device a request names, if the panel may open it: a virtual one, one detected on
    this machine, or replay:NAME of a recording in the panel's folder (as its path)."""
    from carfeel.realtime.devices.virtual import PLANTS

    virtual = ["virtual", *(f"virtual:{k}" for k in PLANTS)]
    if spec in virtual:
        return spec
    kind, _, changes = spec.removeprefix("virtual:").partition(":")
    if spec.startswith("virtual:") and kind in PLANTS and VIRTUAL_CHANGES.fullmatch(changes):
        return spec  # a virtual plant unlike its catalogue's: numbers the session checks
    if spec.startswith("replay:"):
        name = spec[len("replay:") :]
        path = recording_file(recording_folder, name if name.endswith(".csv") else f"{name}.csv")
        problem = replay_problem(path)
        if problem is not None:
            raise InputError(f"device {said(spec)}: {problem}")
        return f"replay:{path}"
    detected = detect()
    if spec in detected:
        return spec
    raise InputError(
        f"device {said(spec)}: the panel opens the virtual devices "
        f"({', '.join(virtual[1:])}), the devices this machine has "
        f"({', '.join(detected) or 'none detected: carfeel devices says why'}) and "
        f"replay:NAME of a recording in {recording_folder}"
    )


def preset_spec(model: str, preset: object, preset_folder: Path) -> str | None:
    """The preset a request names: a shipped one, or saved:NAME as its path (None: none)."""
    if preset in (None, ""):
        return None
    if not isinstance(preset, str):
        raise InputError(f"preset {said(preset)}: expected a preset name")
    if preset.startswith("saved:"):
        name = safe_name(preset[6:], "preset")
        path = inside(preset_folder / KINDS[model], f"{name}.toml")
        if not path.is_file():
            raise InputError(f"no saved {model} preset {name!r} in {preset_folder / model}")
        return str(path)
    from carfeel.io.presets import available

    if preset not in available(model):
        raise InputError(
            f"preset {said(preset)}: the shipped {model} presets are "
            f"{', '.join(available(model))} (or saved:NAME for one saved from the panel)"
        )
    return preset


def run_of(
    body: dict[str, Any],
    *,
    preset_folder: Path,
    recording_folder: Path,
    detect: Callable[[], list[str]],
    network: bool,
) -> dict[str, Any]:
    """The request's session as RealtimeRun keyword arguments, checked as `carfeel run`'s."""
    from carfeel.realtime.run_options import LEVER_MODELS, RealtimeRun, check_run
    from carfeel.simulation.sequence import parse_sequence

    allowed = {"model", "preset", "device", "mode", "speed_kmh", "hand", "clock", "sequence",
               "duration_s", "seed", "telemetry", "synchronizer", "rate_hz", "force",
               "aligning", "device_delay_ms", "calibrate", "steering_model",
               "road"}  # fmt: skip
    unknown = sorted(set(body) - allowed)
    if unknown:
        raise InputError(f"unknown field {', '.join(said(k) for k in unknown[:5])}; a "
                         f"session takes {', '.join(sorted(allowed))}")  # fmt: skip
    if body.get("force") is not True:
        raise InputError(
            'starting a session turns the force on: say so with "force": true (the page\'s '
            "Start button does)"
        )
    model = body.get("model", "hpattern")
    if not isinstance(model, str) or model not in PANEL_MODELS:
        raise InputError(f"model {said(model)}: choose one of {', '.join(PANEL_MODELS)}")
    run: dict[str, Any] = {"model": model}
    texts = ("device", "mode", "hand", "clock", "telemetry", "synchronizer", "aligning",
             "steering_model", "road")  # fmt: skip
    for key in texts:
        value = body.get(key)
        if value is None or value == "":
            continue
        if not isinstance(value, str):
            raise InputError(f"{key} {said(value)}: expected a string")
        if len(value) > MAX_TEXT_CHARS:
            raise InputError(f"{key} {said(value)}: at most {MAX_TEXT_CHARS} characters")
        run[key] = value
    if "device" in run:  # what a request may open: a whitelist, not a path
        run["device"] = device_of(run["device"], recording_folder, detect)
    for key in ("speed_kmh", "duration_s", "rate_hz", "device_delay_ms"):
        value = body.get(key)
        if value is None or value == "":
            continue
        run[key] = number_of(key, value)
    seed = body.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise InputError(f"seed {said(seed)}: expected a whole number from 0 to 2^64 - 1")
    run["seed"] = seed
    if "calibrate" in body:
        if not isinstance(body["calibrate"], bool):
            raise InputError(f"calibrate {said(body['calibrate'])}: expected true or false")
        run["calibrate"] = body["calibrate"]
    if model == "steering":
        run.setdefault("mode", "impedance")
    sequence = body.get("sequence")
    if sequence not in (None, "") and model in ("hpattern", *LEVER_MODELS):
        if isinstance(sequence, list):
            sequence = ",".join(str(s) for s in sequence)
        if not isinstance(sequence, str) or len(sequence) > MAX_SEQUENCE_CHARS:
            raise InputError(
                f"sequence {said(sequence)}: expected at most {MAX_SEQUENCE_CHARS} characters of "
                f"{SCRIPTS[model]}"
            )
        run["sequence"] = parse_sequence(sequence)
    run.setdefault("duration_s", 600.0)
    run["preset"] = preset_spec(model, body.get("preset"), preset_folder)
    try:
        check_run(RealtimeRun(**run))
    except TypeError as exc:  # pragma: no cover - the fields are filtered above
        raise InputError(str(exc)) from None
    if "telemetry" in run:  # loopback only, unless the panel itself is on the network
        from carfeel.telemetry.receiver import Source

        Source.parse(run["telemetry"], network=network)
    return run


def _telemetry_formats() -> list[str]:
    try:
        from carfeel.telemetry.formats import FORMATS
    except ImportError:  # pragma: no cover
        return []
    return sorted(FORMATS)
