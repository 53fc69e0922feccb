"""Profiles per car (issue 29): the shipped car map, the user's over it, the summary's note."""

from __future__ import annotations

import math
import types
from pathlib import Path

import pytest

from carfeel.errors import InputError
from carfeel.io.presets import load_hpattern, load_steering
from carfeel.telemetry.carmap import match_car, profile_for_car, shipped_car_map
from carfeel.telemetry.state import VehicleState


def _receiver(car: str) -> types.SimpleNamespace:
    return types.SimpleNamespace(latest=VehicleState(car=car), poll=lambda: 0)


def test_every_shipped_profile_names_presets_that_exist() -> None:
    cars = shipped_car_map()
    assert {"mercedesamggt4", "porsche_991ii_gt3_r", "vehicle.scania.s_2016"} <= set(cars)
    games = {entry["game"] for entry in cars.values()}
    assert {"iracing", "acc", "assetto", "scs", "pcars", "rf2", "r3e"} <= games
    for entry in cars.values():
        if "hpattern" in entry:
            load_hpattern(entry["hpattern"])  # raises if the preset does not exist
        if "steering" in entry:
            load_steering(entry["steering"])


def test_the_shipped_profile_and_the_users_over_it(tmp_path: Path) -> None:
    shipped = profile_for_car(None, _receiver("mercedesamggt4"))
    assert shipped is not None and shipped.layout == "sequential"
    assert shipped.presets == {"hpattern": "6r", "steering": "d-segment"}
    assert shipped.torque_scale_Nm == 20.0
    assert "carfeel car map" in shipped.describe("hpattern")
    mine = tmp_path / "cars.toml"
    mine.write_text('[cars."mercedesamggt4"]\nhpattern = "5r"\nlayout = "h"\n')
    user = profile_for_car(mine, _receiver("mercedesamggt4"), wait_s=0.0)
    assert user is not None and user.presets == {"hpattern": "5r"} and user.layout == "h"
    assert math.isnan(user.torque_scale_Nm) and str(mine) in user.describe("hpattern")
    assert "no steering preset" in user.describe("steering")
    assert profile_for_car(mine, _receiver("unknown car"), wait_s=0.0) is None
    assert profile_for_car(None, _receiver("")) is None


@pytest.mark.parametrize(
    ("line", "reason"),
    [('layout = "diagonal"', "one of h, sequential, truck"),
     ("torque_scale_Nm = -3", "N\\*m"), ('torque_scale_Nm = "20"', "N\\*m"),
     ("hpattern = 5", "a string")],
)  # fmt: skip
def test_a_bad_entry_is_refused_with_what_is_wrong(tmp_path: Path, line: str, reason: str) -> None:
    mine = tmp_path / "cars.toml"
    mine.write_text(f'[cars."x"]\n{line}\n')
    with pytest.raises(InputError, match=reason):
        profile_for_car(mine, _receiver("x"), wait_s=0.0)


def test_an_entrys_number_and_livery_are_left_off_and_nothing_else(tmp_path: Path) -> None:
    """rFactor 2 / LMU name an entry, not a car: "Oreca 07 #22 Jota" is the shipped "Oreca 07";
    a name that merely starts like a car ("Oreca 07X", "Oreca 07 Gibson") is not it, and the
    user's key for the whole entry name comes before the car's."""
    entry = profile_for_car(None, _receiver("Oreca 07 #22 Jota"))
    assert entry is not None and entry.game == "rf2" and entry.layout == "sequential"
    assert entry.car == "Oreca 07 #22 Jota"  # the summary says what the game said
    for other in ("Oreca 07X", "Oreca 07 Gibson", "Oreca 07#", "#22 Oreca 07", "Oreca"):
        assert profile_for_car(None, _receiver(other)) is None, other
    cars = {"Oreca 07": {"steering": "d-segment"}, "Oreca 07 #22 Jota": {"steering": "b-segment"}}
    assert match_car("Oreca 07 #22 Jota", cars) == "Oreca 07 #22 Jota"
    assert match_car("Oreca 07 #38", cars) == "Oreca 07"
    assert match_car("Oreca 07  #38\nx", cars) == "Oreca 07"
    mine = tmp_path / "cars.toml"
    mine.write_text('[cars."Oreca 07"]\nsteering = "b-segment"\n')
    users = profile_for_car(mine, _receiver("Oreca 07 #22 Jota"), wait_s=0.0)
    assert users is not None and users.presets == {"steering": "b-segment"}
