"""Euro Truck Simulator 2 / American Truck Simulator through the scs-sdk-plugin's shared memory.

No real dump of the map's bytes was found: the image here is BUILT FROM THE PLUGIN'S HEADER
(`scs-telemetry-common.hpp`, revision 12: its zones start where its comments say, the fields
in its order) and filled with the values of a real decoded snapshot (tests/data/telemetry's
JSON: a Scania S, 14+2 gears, the game's 32-slot H-shifter table).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import pytest

from carfeel.errors import InputError
from carfeel.telemetry import pages
from carfeel.telemetry.receiver import open_receiver
from tests.datafiles import data_file
from tests.pagefuzz import fuzz_pages

SNAPSHOT = "ets2-scs-sdk-plugin-snapshot-scania-s.json"
MAP_BYTES = 32 * 1024
# The header's zone starts (its "START OF ... ZONE AT OFFSET" comments) and, within each, the
# fields in its order, 4 bytes each unless said: what this test writes.
ZONE2 = 40  # unsigned ints
SCS_VALUES = ["revision", "version_major", "version_minor", "game", "tel_major", "tel_minor"]
CONFIG_UI = ["gears", "gears_reverse", "retarderStepCount", "truckWheelCount", "selectorCount"]
ZONE3 = 500  # ints: restStop, gear, gearDashboard, hshifterResulting[32]
ZONE4 = 700  # floats: scale, then config_f (12 floats, wheel radii 16, ratios 24 + 8, unitMass)
ZONE5 = 1500  # bools
ZONE6 = 1640  # fvectors: config_fv (9 + 48 floats), then truck_fv
ZONE9 = 2300  # strings of 64 (shifterType 16)


def build(snapshot: dict[str, Any], revision: int = 12, game: int = 1) -> bytes:
    m = bytearray(MAP_BYTES)
    g, t = snapshot["game"], snapshot["truck"]
    tr = t["transmission"]
    struct.pack_into("<??", m, 0, g["sdkActive"], False)
    struct.pack_into("<?", m, 4, g["paused"])
    struct.pack_into("<Q", m, 8, g["timestamp"]["value"])
    struct.pack_into("<6I", m, ZONE2, revision, 1, 18, game, 1, 18)
    at = ZONE2 + 4 * len(SCS_VALUES) + 4  # after common_ui.time_abs
    counts = (tr["forwardGears"], tr["reverseGears"], t["brakes"]["retarder"]["steps"],
              len(t["wheels"]), tr["selectors"])  # fmt: skip
    struct.pack_into("<5I", m, at, *counts)
    truck_ui = at + 4 * 9  # config_ui has 9 fields
    struct.pack_into("<I", m, truck_ui, tr["slot"])
    slots = tr["slots"]
    position = truck_ui + 4 * (4 + 16)  # shifterSlot, retarderBrake, aux lights x2, substances
    struct.pack_into("<32I", m, position, *(s["handlePosition"] for s in slots))
    struct.pack_into("<32I", m, position + 128, *(s["selector"] for s in slots))
    struct.pack_into("<ii32i", m, ZONE3 + 4, tr["gear"]["selected"], tr["gear"]["displayed"],
                     *(s["gear"] for s in slots))  # fmt: skip
    config_f = ZONE4 + 4
    struct.pack_into("<f", m, config_f + 4 * 9, t["engine"]["rpm"]["max"])  # engineRpmMax
    truck_f = config_f + 4 * (12 + 16 + 24 + 8 + 1)
    c = snapshot["controls"]
    struct.pack_into("<10f", m, truck_f, t["speed"]["value"], t["engine"]["rpm"]["value"],
                     c["input"]["steering"], c["input"]["throttle"], c["input"]["brake"],
                     c["input"]["clutch"], c["game"]["steering"], c["game"]["throttle"],
                     c["game"]["brake"], c["game"]["clutch"])  # fmt: skip
    truck_b = ZONE5 + 16 * 4 + 2  # config_b: 4 x 16 wheel flags, isCargoLoaded, specialJob
    shifter_toggle = truck_b + 24 + 16  # 24 flags (parkBrake .. cruiseControl), wheelOnGround
    struct.pack_into("<??", m, shifter_toggle, *tr["selector"])
    truck_fv = ZONE6 + 4 * (9 + 48)
    a = t["acceleration"]
    struct.pack_into("<9f", m, truck_fv,
                     *(a[k][x] for k in ("linearVelocity", "angularVelocity",
                                         "linearAcceleration") for x in "XYZ"))  # fmt: skip
    ids = [t["brand"]["id"], t["brand"]["name"], t["model"]["id"], t["model"]["name"]]
    for i, text in enumerate(ids):  # truckBrandId, truckBrand, truckId, truckName
        struct.pack_into("64s", m, ZONE9 + 64 * i, text.encode())
    struct.pack_into("16s", m, ZONE9 + 64 * 14, tr["shifterType"].encode())
    return bytes(m)


@pytest.fixture
def snapshot() -> dict[str, Any]:
    loaded: dict[str, Any] = json.loads(data_file("telemetry", SNAPSHOT).read_text("utf-8"))
    return loaded


def _one(path: Path) -> Any:
    with open_receiver(f"scs:file:{path}") as r:
        got: list[Any] = []
        r.poll(got.append, now_s=0.0)
        assert r.bad == 0 and len(got) == 1
        return got[0], r


def test_the_snapshot_decodes_with_its_slot_table(tmp_path: Path, snapshot: dict[str, Any]) -> None:
    image = tmp_path / "scs.bin"
    image.write_bytes(build(snapshot))
    s, r = _one(image)
    assert r.car == "vehicle.scania.s_2016" == s.car
    assert (s.forward_gears, s.gearbox, s.truck_slot) == (14, "truck", 0)
    assert s.engine_max_rpm == 2500.0 and s.engine_speed_rpm == 550.0009765625  # float32, exact
    assert s.speed_m_s == 38.0 and s.gear == 0 and not s.paused
    expected = [(x["handlePosition"], x["selector"], x["gear"])
                for x in snapshot["truck"]["transmission"]["slots"]]  # fmt: skip
    assert list(s.slots) == expected
    # The game's table: bit 0 of the selector is the range (+6 gears), bit 1 the splitter (+1).
    table = {(p, sel): gear for p, sel, gear in s.slots}
    for position in (5, 6, 7):
        assert table[position, 1] - table[position, 0] == 6
        assert table[position, 2] - table[position, 0] == 1
    assert {gear for _, _, gear in s.slots} == set(range(-2, 15))  # 14 + 2, every one


def test_the_range_and_splitter_and_signs(tmp_path: Path, snapshot: dict[str, Any]) -> None:
    tr = snapshot["truck"]["transmission"]
    tr["selector"] = [True, False]
    tr["gear"]["selected"] = 9
    a = snapshot["truck"]["acceleration"]
    a["linearAcceleration"]["X"] = -2.0  # x right: 2 m/s^2 to the left
    a["angularVelocity"]["Y"] = 0.1  # y up, anticlockwise: turning left
    image = tmp_path / "scs.bin"
    image.write_bytes(build(snapshot))
    s, _ = _one(image)
    assert s.range_high and not s.splitter_high and s.gear == 9
    assert s.lateral_accel_m_s2 == 2.0 and s.yaw_rate_rad_s == pytest.approx(0.1)


@pytest.mark.parametrize(
    ("revision", "game", "reason"),
    [(11, 1, "revision 11"), (13, 1, "revision 13"), (12, 7, "game id 7")],
)
def test_another_plugin_revision_is_refused(
    tmp_path: Path, snapshot: dict[str, Any], revision: int, game: int, reason: str
) -> None:
    image = tmp_path / "scs.bin"
    image.write_bytes(build(snapshot, revision, game))
    with pytest.raises(InputError, match=reason):
        open_receiver(f"scs:file:{image}")


def test_the_sdk_inactive_is_no_state(tmp_path: Path, snapshot: dict[str, Any]) -> None:
    snapshot["game"]["sdkActive"] = False
    image = tmp_path / "scs.bin"
    image.write_bytes(build(snapshot))
    with open_receiver(f"scs:file:{image}") as r:
        assert r.poll(now_s=0.0) == 0 and r.ignored == 1


def test_the_reader_survives_a_fuzzed_map(snapshot: dict[str, Any]) -> None:
    def check(s: Any) -> None:
        assert -1 <= s.gear <= 24 and len(s.slots) in (0, 32)

    kept, refused = fuzz_pages(pages.SCS, build(snapshot), 3300, 29, 300, check)
    assert kept > 50 and refused > 10
