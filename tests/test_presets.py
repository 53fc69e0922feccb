"""Presets are validated once, at the boundary, with messages that say what to fix."""

from __future__ import annotations

import re
from importlib import resources

import pytest

from carfeel.errors import PresetError
from carfeel.io import presets
from carfeel.simulation.shift import ShiftParams

DEFAULT = resources.files("carfeel.presets").joinpath("shift", "paper-first-gear.toml").read_text()


def load_text(text: str) -> presets.Preset[ShiftParams]:
    return presets.shift_from_toml("test.toml", text)


def edit(key: str, line: str, table: str = "") -> str:
    """The default preset with the first `key = ...` line (after `[table]`) replaced by `line`."""
    start = DEFAULT.index(f"[{table}]") if table else 0
    match = re.compile(rf"^{re.escape(key)} = .*$", re.M).search(DEFAULT, start)
    assert match, key
    return DEFAULT[: match.start()] + line + DEFAULT[match.end() :]


def error_for(text: str) -> str:
    with pytest.raises(PresetError) as info:
        load_text(text)
    return str(info.value)


def test_every_shipped_preset_loads():
    for kind in presets.PRESET_KINDS:
        names = presets.available(kind)
        assert names
        for name in names:
            assert presets.load(kind, name).name == name


def test_negative_mass_names_parameter_value_unit_and_range():
    message = error_for(edit("mass_kg", "mass_kg = -1.0", "gearbox.neutral"))
    assert "gearbox.neutral.mass_kg = -1 kg is out of range" in message
    assert "0 < value <= 100 kg" in message


def test_sliding_friction_above_static_is_rejected():
    message = error_for(edit("sliding_friction_N", "sliding_friction_N = 50.0", "gearbox.stop"))
    assert "gearbox.stop.sliding_friction_N = 50 N exceeds gearbox.stop.static_friction_N" in (
        message
    )
    assert "0 <= sliding <= static" in message


def test_synchronization_beyond_the_stop_is_rejected():
    message = error_for(
        edit("synchronization_position_m", "synchronization_position_m = 0.05", "gearbox")
    )
    assert "gearbox.synchronization_position_m = 0.05 m must lie before" in message


def test_unknown_key_is_rejected_and_the_known_ones_listed():
    message = error_for(edit("mass_kg", "mass_kg = 1.2\nspring = 3.0", "gearbox.stop"))
    assert "gearbox.stop.spring: unknown parameter" in message
    assert "stiffness_N_m" in message


def test_missing_value_is_rejected_with_its_range():
    message = error_for(edit("hold_s", "", "driver"))
    assert "driver.hold_s: missing; expected a number with 0 <= value <= 60 s" in message


def test_wrong_type_and_non_finite_values_are_rejected():
    assert "expected a number" in error_for(edit("hold_s", 'hold_s = "long"', "driver"))
    assert "expected true or false" in error_for(edit("pull_out", "pull_out = 1", "driver"))
    assert "out of range" in error_for(edit("hold_s", "hold_s = nan", "driver"))
    assert "out of range" in error_for(edit("hold_s", "hold_s = inf", "driver"))
    assert "out of range" in error_for(edit("hold_s", "hold_s = 1" + "0" * 400, "driver"))


def test_a_settle_distance_the_stop_friction_can_defeat_is_rejected():
    message = error_for(edit("settle_distance_m", "settle_distance_m = 1e-5", "gearbox"))
    assert "gearbox.settle_distance_m = 1e-05 m must exceed" in message


def test_all_problems_are_reported_together():
    text = edit("mass_kg", "mass_kg = -1.0", "gearbox.neutral")
    text = text.replace("[driver]\n", "[driver]\ncolour = 1\n")
    message = error_for(text)
    assert "mass_kg" in message and "colour" in message


def test_tooth_force_above_the_drivers_force_is_rejected():
    message = error_for(edit("tooth_force_spread_N", "tooth_force_spread_N = 900.0", "gearbox"))
    assert "must stay below driver.push_force_N = 78.5 N" in message


def test_malformed_toml_and_missing_files():
    assert "not valid TOML" in error_for("name = \n")
    with pytest.raises(PresetError, match="not found"):
        presets.load_shift("/nonexistent/preset.toml")
    with pytest.raises(PresetError, match=r"no shift preset named 'nope'.*paper-first-gear"):
        presets.load_shift("nope")


def test_a_preset_file_on_disk_loads(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(DEFAULT.replace('name = "paper-first-gear"', 'name = "mine"'))
    assert presets.load_shift(str(path)).name == "mine"


def test_presets_written_as_toml_load_back_the_same(tmp_path):
    import dataclasses

    shift = presets.load_shift()
    text = presets.to_toml(shift.name, shift.source, {"gearbox": shift.params.gearbox,
                                                      "driver": shift.params.driver})  # fmt: skip
    assert presets.shift_from_toml("written", text).params == shift.params
    layout = presets.load_hpattern()
    tables = {f.name: getattr(layout.setup, f.name) for f in dataclasses.fields(layout.setup)}
    path = tmp_path / "layout.toml"
    path.write_text(presets.to_toml(layout.name, layout.source, tables,
                                    {"engagement": layout.engagement}))  # fmt: skip
    assert presets.load_hpattern(str(path)).setup == layout.setup


def test_numpy_scalars_from_a_fit_are_written_as_plain_toml_numbers():
    import dataclasses

    import numpy as np

    shift = presets.load_shift()
    gearbox = dataclasses.replace(shift.params.gearbox, in_gear_position_m=np.float64(0.0431))
    text = presets.to_toml("fitted", "a fit", {"gearbox": gearbox, "driver": shift.params.driver})
    assert "np.float64" not in text
    loaded = presets.shift_from_toml("fitted", text).params.gearbox
    assert loaded.in_gear_position_m == 0.0431 and type(loaded.in_gear_position_m) is float


def test_the_shipped_presets_name_only_files_the_repository_has():
    """Issue 11: paper-first-gear's comment named shared/seed/EQUATIONS.md, which a user of the
    repository (or of the installed package) does not have. Any file a shipped preset names, in
    its comments or its source text, exists in the repository."""
    from pathlib import Path

    repository = Path(__file__).resolve().parents[1]
    pattern = re.compile(r"[\w./-]+\.(?:md|csv|toml|py|txt|pdf|json|png|html|dbc|mf4)\b")
    named = set()
    for kind in presets.PRESET_KINDS:
        for name in presets.available(kind):
            text = resources.files("carfeel.presets").joinpath(kind, f"{name}.toml").read_text()
            named |= set(pattern.findall(text))
    assert named, "the test sees no file names at all: check the pattern"
    missing = sorted(n for n in named if not (repository / n).exists())
    assert missing == []
