"""RaceRoom shared memory ($R3E, Sector3's r3e-api `r3e.h`, version 3.4).

No real dump of the map was found: the image here is BUILT FROM THE HEADER (`r3e.h`,
`#pragma pack(1)`): the field list below is the header's, in its order (runs of 4-byte fields
merged), and the offsets are summed from it here, not taken from carfeel's constants.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path
from typing import Any

import pytest

from carfeel.errors import InputError
from carfeel.telemetry import pages
from carfeel.telemetry.receiver import open_receiver
from tests.pagefuzz import fuzz_pages

SIZES = {"i": 4, "f": 4, "d": 8, "s": 1}
DRIVER_INFO = 64 + 10 * 4 + 6 * 4  # name[64], 10 int32 (car_number..engine_type), 6 floats
PLAYER = 4 + 4 + 8 + 11 * 24 + 9 * 8 + 16 * 8 + 7 * 8 + 3 * 8  # r3e_playerdata
DRIVER_DATA = DRIVER_INFO + 4 * (5 + 3 + 3 + 1 + 9 + 2 + 3 + 5 + 1 + 4 + 2 + 2 + 1 + 3 + 3 + 3)
FIELDS = [
    ("version_major", "i", 1), ("version_minor", "i", 1), ("all_drivers_offset", "i", 1),
    ("driver_data_size", "i", 1), ("game_mode", "i", 1), ("game_paused", "i", 1),
    ("game_in_menus", "i", 1), ("game_in_replay", "i", 1), ("game_using_vr", "i", 1),
    ("game_unused1", "i", 1),
    ("player_ids", "i", 2), ("game_simulation_time", "d", 1), ("player_vec3s", "d", 12),
    ("player_rest", "d", 3 * 7 + 9 + 16 + 7 + 3),
    ("track_layout_names", "s", 128), ("event", "i", 3 + 3 + 6 + 4 + 1 + 5 + 1 + 2 + 1 + 2),
    ("pit", "i", 5 + 12 + 1 + 2 + 2 + 2), ("flags", "i", 14),
    ("scoring", "i", 4 + 5 + 1 + 3 + 2 + 2 + 3 + 4 + 4 + 4 + 5 + 9 + 3 + 3),
    ("vehicle_info_name", "s", 64), ("vehicle_info_rest", "i", 16), ("player_name", "s", 64),
    ("control_type", "i", 1), ("car_speed", "f", 1), ("engine_rps", "f", 1),
    ("max_engine_rps", "f", 1), ("upshift_rps", "f", 1), ("gear", "i", 1), ("num_gears", "i", 1),
    ("car_cg_location", "f", 3), ("car_orientation", "f", 3), ("local_acceleration", "f", 3),
    ("mass_fuel_energy_temps", "f", 12), ("throttle", "f", 1), ("throttle_raw", "f", 1),
    ("brake", "f", 1), ("brake_raw", "f", 1), ("clutch", "f", 1), ("clutch_raw", "f", 1),
    ("steer_input_raw", "f", 1), ("steer_lock_degrees", "i", 1),
    ("steer_wheel_range_degrees", "i", 1),
    ("vehicle_rest", "i", 5 + 4 + 1 + 5 + 1 + 2 + 1 + 1 + 1 + 1 + 1),
    ("tires", "i", 1 + 7 * 4 + 24 + 4 + 16 + 4), ("electronics", "i", 4 + 4 + 4),
    ("car_damage", "f", 6), ("num_cars", "i", 1), ("all_drivers_data_1", "s", 128 * DRIVER_DATA),
]  # fmt: skip


def _offsets() -> tuple[dict[str, int], int]:
    at, out = 0, {}
    for name, code, count in FIELDS:
        out[name] = at
        at += SIZES[code] * count
    return out, at


OFFSET, MAP_BYTES = _offsets()
# Inside r3e_playerdata (at player_ids): the ids, the time, then the vec3 doubles in order.
PLAYER_AT = OFFSET["player_ids"]
TICKS_AT = PLAYER_AT + 4
LOCAL_ANGULAR_VELOCITY_AT = PLAYER_AT + 16 + 9 * 24


def build(major: int = 3, minor: int = 4, ticks: int = 100, **values: Any) -> bytes:
    m = bytearray(MAP_BYTES)
    base: dict[str, Any] = {
        "version_major": major, "version_minor": minor,
        "all_drivers_offset": OFFSET["num_cars"], "driver_data_size": DRIVER_DATA,
        "game_mode": 3, "car_speed": 45.0, "engine_rps": 700.0, "max_engine_rps": 900.0,
        "gear": 4, "num_gears": 6, "local_acceleration": (10.0, 0.0, -1.0), "throttle": 0.7,
        "clutch": 0.0, "steer_input_raw": -0.5, "steer_wheel_range_degrees": 360,
        "vehicle_info_name": b"BMW M4 GT3\x00", "num_cars": 1,
    }  # fmt: skip
    base.update(values)
    codes = {n: c for n, c, _ in FIELDS}
    for name, value in base.items():
        if isinstance(value, bytes):
            m[OFFSET[name] : OFFSET[name] + len(value)] = value
        elif isinstance(value, tuple):
            struct.pack_into(f"<{len(value)}{codes[name]}", m, OFFSET[name], *value)
        else:
            struct.pack_into(f"<{codes[name]}", m, OFFSET[name], value)
    struct.pack_into("<i", m, TICKS_AT, ticks)
    struct.pack_into("<3d", m, LOCAL_ANGULAR_VELOCITY_AT, 0.0, -0.25, 0.0)
    return bytes(m)


def test_the_header_offsets_are_the_readers() -> None:
    # The sums from the header's field list land where carfeel reads.
    assert (PLAYER, DRIVER_INFO, PLAYER_AT) == (560, 128, 40)
    assert OFFSET["car_speed"] == pages.R3E_DRIVE_AT + 4
    assert OFFSET["steer_wheel_range_degrees"] + 4 == pages.R3E_READ_BYTES
    assert (OFFSET["vehicle_info_name"], OFFSET["num_cars"]) == (
        pages.R3E_NAME_AT,
        pages.R3E_ALL_DRIVERS_AT,
    )
    assert MAP_BYTES == pages.R3E_MAP_BYTES


def test_a_left_turn_built_from_the_header_decodes(tmp_path: Path) -> None:
    image = tmp_path / "r3e.bin"
    image.write_bytes(build() + build(game_in_replay=1) + build(game_paused=1) + build(gear=-1))
    with open_receiver(f"r3e:file:{image}") as r:
        got: list[Any] = []
        for i in range(6):
            r.poll(got.append, now_s=i / 60.0)
        assert r.bad == 0 and r.car == "BMW M4 GT3"
    assert len(got) == 4
    s = got[0]
    assert (s.speed_m_s, s.gear, s.forward_gears) == (45.0, 4, 6)
    assert s.engine_speed_rpm == pytest.approx(700.0 * 60.0 / (2.0 * math.pi))
    assert s.engine_max_rpm == pytest.approx(900.0 * 60.0 / (2.0 * math.pi))
    assert s.lateral_accel_m_s2 == 10.0  # +X is left in r3e's axes
    assert s.yaw_rate_rad_s == pytest.approx(0.25)
    assert s.steering_angle_rad == pytest.approx(math.radians(90.0))  # half of 360, left
    assert s.throttle == pytest.approx(0.7) and not s.replay and not s.paused
    assert got[1].replay and got[2].paused and got[3].gear == -1


@pytest.mark.parametrize(("major", "minor"), [(2, 4), (3, 3), (3, 5), (0, 0)])
def test_another_version_is_refused(tmp_path: Path, major: int, minor: int) -> None:
    image = tmp_path / "r3e.bin"
    image.write_bytes(build(major=major, minor=minor))
    with pytest.raises(InputError, match=f"version {major}.{minor}.*3.4"):
        open_receiver(f"r3e:file:{image}")


def test_a_moved_driver_array_is_refused(tmp_path: Path) -> None:
    image = tmp_path / "r3e.bin"
    image.write_bytes(build(all_drivers_offset=OFFSET["num_cars"] + 4))
    with pytest.raises(InputError, match="all_drivers_offset"):
        open_receiver(f"r3e:file:{image}")


def test_another_games_image_and_truncation_are_refused(tmp_path: Path) -> None:
    from tests.test_telemetry_ams2 import build as ams2_build

    image = tmp_path / "r3e.bin"
    for data in (ams2_build(), build()[:-1], b""):
        image.write_bytes(data)
        with pytest.raises(InputError):
            open_receiver(f"r3e:file:{image}")


@pytest.mark.parametrize("field", ["car_speed", "engine_rps", "steer_input_raw"])
def test_nan_is_counted_bad(tmp_path: Path, field: str) -> None:
    image = tmp_path / "r3e.bin"
    values: dict[str, Any] = {field: math.nan}
    image.write_bytes(build(**values))
    with open_receiver(f"r3e:file:{image}") as r:
        got: list[Any] = []
        r.poll(got.append, now_s=0.0)
        assert r.bad == 1 and got == []


def test_the_menus_are_no_state() -> None:
    assert pages.PagesReader(pages.R3E, (build(game_in_menus=1),), True).read(0.0) == [None]


def test_the_reader_survives_a_fuzzed_map() -> None:
    kept, refused = fuzz_pages(pages.R3E, build(), pages.R3E_READ_BYTES, 4, 200)
    assert kept > 20 and refused > 5
