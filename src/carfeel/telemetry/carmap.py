"""A user's mapping from the car a format names to the presets for it (TOML):

    [cars."2372"]                 # Forza's car ordinal
    hpattern = "6r"
    [cars."ks_audi_r8_lms"]       # Assetto Corsa's car name
    steering = "b-segment"

Read once, before the loop: the first packet that names the car is waited for (at most
`WAIT_S`); a car not in the file keeps the run's preset.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from carfeel.errors import InputError

WAIT_S = 2.0


def load_car_map(path: Path) -> dict[str, dict[str, str]]:
    """The file's [cars] tables, read within the presets' limits (size, nesting)."""
    from carfeel.io.presets import load_toml, read_limited

    label = f"--car-presets {path}"
    try:
        text = read_limited(path, "--car-presets", InputError)
    except FileNotFoundError:
        raise InputError(f"{label}: no such file") from None
    data = load_toml(label, text, InputError)
    cars = data.get("cars", {})
    if not isinstance(cars, dict) or not all(
        isinstance(v, dict) and all(isinstance(x, str) for x in v.values()) for v in cars.values()
    ):
        raise InputError(
            f'--car-presets {path}: expected [cars."NAME"] tables of model = "preset" strings'
        )
    return {str(k): dict(v) for k, v in cars.items()}


def preset_for_car(path: Path, receiver: Any, model: str, wait_s: float = WAIT_S) -> str | None:
    """The preset the file gives `model` for the car the first packets name, or None."""
    cars = load_car_map(path)
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and not receiver.latest.car:
        receiver.poll()
        time.sleep(0.005)
    return cars.get(receiver.latest.car, {}).get(model)
