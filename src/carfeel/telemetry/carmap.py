"""The car a game names -> its profile (layout, feel presets, torque scale), from TOML:

    [cars."mercedesamggt4"]       # iRacing's CarPath
    game = "iracing"
    name = "Mercedes-AMG GT4"
    layout = "sequential"         # h, sequential or truck
    hpattern = "6r"
    steering = "d-segment"
    torque_scale_Nm = 20.0

carfeel ships one (`carfeel/presets/cars/cars.toml`, common cars of each game); `--car-presets
FILE` adds the user's, whose entries replace the shipped ones car by car (a file of just
`hpattern = "5r"` lines, the older form, still reads). Read once, before the loop: a shared-memory
game names its car at open; for a UDP game the first packet that names it is waited for (at
most `WAIT_S`, only when `--car-presets` is given); a car in neither keeps the run's presets.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from carfeel.errors import InputError

WAIT_S = 2.0
LAYOUTS = ("h", "sequential", "truck")
TEXT_KEYS = ("game", "name", "layout", "hpattern", "steering")
SHIPPED = "carfeel car map"
LIVERY = re.compile(r"\s*#\S.*\Z", re.DOTALL)
"""An entry's number and what follows it, at the end of a car's name ("Oreca 07 #22 Jota")."""


@dataclass(frozen=True, slots=True)
class CarProfile:
    car: str
    source: str
    """Where the profile came from: the shipped car map or the user's file."""
    game: str = ""
    name: str = ""
    layout: str = ""
    presets: dict[str, str] = field(default_factory=dict)
    """Model -> preset (hpattern, steering)."""
    torque_scale_Nm: float = math.nan

    def describe(self, model: str) -> str:
        what = ", ".join(x for x in (self.game, self.name, self.layout) if x)
        preset = self.presets.get(model)
        chosen = f"{model} preset {preset}" if preset else f"no {model} preset (the run's kept)"
        scale = (
            f", torque scale {self.torque_scale_Nm:g} Nm"
            if math.isfinite(self.torque_scale_Nm)
            else ""
        )
        return f"car {self.car}: profile from the {self.source} ({what}): {chosen}{scale}"


def _parse(label: str, text: str) -> dict[str, dict[str, Any]]:
    from carfeel.io.tomlread import load_toml

    data = load_toml(label, text, InputError)
    cars = data.get("cars", {})
    if not isinstance(cars, dict) or not all(isinstance(v, dict) for v in cars.values()):
        raise InputError(f'{label}: expected [cars."NAME"] tables of model = "preset" strings')
    for car, entry in cars.items():
        for key, value in entry.items():
            if key == "torque_scale_Nm":
                ok = isinstance(value, int | float) and not isinstance(value, bool)
                ok = ok and math.isfinite(value) and 0 < value <= 1000
                want = "a number of N*m, 0 < value <= 1000"
            elif key == "layout":
                ok, want = value in LAYOUTS, f"one of {', '.join(LAYOUTS)}"
            else:
                ok, want = isinstance(value, str), 'a string (model = "preset")'
            if not ok:
                raise InputError(f'{label}: [cars."{car}"] {key} = {value!r}: expected {want}')
    return {str(k): dict(v) for k, v in cars.items()}


def load_car_map(path: Path) -> dict[str, dict[str, Any]]:
    """The file's [cars] tables, read within the presets' limits (size, nesting)."""
    from carfeel.io.tomlread import read_limited

    label = f"--car-presets {path}"
    try:
        text = read_limited(path, "--car-presets", InputError)
    except FileNotFoundError:
        raise InputError(f"{label}: no such file") from None
    return _parse(label, text)


def shipped_car_map() -> dict[str, dict[str, Any]]:
    text = resources.files("carfeel.presets").joinpath("cars", "cars.toml").read_text("utf-8")
    return _parse(SHIPPED, text)


def _profile(car: str, entry: dict[str, Any], source: str) -> CarProfile:
    presets = {k: str(v) for k, v in entry.items() if k not in (*TEXT_KEYS[:3], "torque_scale_Nm")}
    return CarProfile(
        car, source, str(entry.get("game", "")), str(entry.get("name", "")),
        str(entry.get("layout", "")), presets, float(entry.get("torque_scale_Nm", math.nan)),
    )  # fmt: skip


def profile_for_car(path: Path | None, receiver: Any, wait_s: float = WAIT_S) -> CarProfile | None:
    """The profile of the car the receiver names (the user's file first, then the shipped
    map), or None: no car named, or one in neither."""
    user = load_car_map(path) if path is not None else {}
    if path is not None:  # a UDP game names its car in a packet: wait for it
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline and not receiver.latest.car:
            receiver.poll()
            time.sleep(0.005)
    car = receiver.latest.car
    if not car:
        return None
    key = match_car(car, user)
    if key is not None:
        return _profile(car, user[key], f"car map {path}")
    shipped = shipped_car_map()
    key = match_car(car, shipped)
    if key is not None:
        return _profile(car, shipped[key], SHIPPED)
    return None


def match_car(car: str, cars: dict[str, dict[str, Any]]) -> str | None:
    """The key of `cars` for the name a game gives: the name itself, else the name without its
    entry's number and livery (rFactor 2 / Le Mans Ultimate name an entry, "Oreca 07 #22
    Jota": the car is "Oreca 07"); None when neither is there."""
    if car in cars:
        return car
    base = LIVERY.sub("", car)
    return base if base != car and base in cars else None


def preset_for_car(path: Path, receiver: Any, model: str, wait_s: float = WAIT_S) -> str | None:
    """The preset the file gives `model` for the car the first packets name, or None."""
    cars = load_car_map(path)
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline and not receiver.latest.car:
        receiver.poll()
        time.sleep(0.005)
    key = match_car(receiver.latest.car, cars)
    value = cars[key].get(model) if key is not None else None
    return str(value) if isinstance(value, str) else None
