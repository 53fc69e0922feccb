"""carfeel.schema is the one description of every preset field (unit, range, description), and
the loader, the sweep, the FMU, the panel and the reference all take it from there."""

from __future__ import annotations

import dataclasses
import math
from importlib import resources

import pytest

from carfeel import schema
from carfeel.errors import PresetError
from carfeel.export.variables import fmi_unit
from carfeel.io import presets
from carfeel.panel.tuning import TUNABLES
from carfeel.simulation.hpattern import HPatternSetup
from carfeel.simulation.prnd import PrndSetup
from carfeel.simulation.sequential import SequentialSetup
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import SteeringCar
from carfeel.sweep import spec

KINDS = {
    "shift": ShiftParams,
    "steering": SteeringCar,
    "hpattern": HPatternSetup,
    "sequential": SequentialSetup,
    "prnd": PrndSetup,
}


def all_fields() -> list[schema.Field]:
    return [f for cls in KINDS.values() for f in schema.fields(cls)]


def test_the_schema_walks_every_kind_the_loader_knows():
    assert set(KINDS) == set(presets.PRESET_KINDS)
    paths = {f.path for f in all_fields()}
    # a nested table, an optional table and an array of tables are all walked
    assert "gearbox.stop.stiffness_N_m" in paths
    assert "tyres.pneumatic_trail_m" in paths
    assert "layout.gears[].ratio" in paths


def test_every_number_has_a_range_and_every_field_a_description():
    """A number without a range would be read unchecked (a NaN, a unit mistake); a field
    without a description leaves a blank in the reference and in the FMU's variables."""
    unranged = [f.path for f in all_fields() if f.kind in (int, float) and f.range is None]
    undocumented = [f"{f.owner.__name__}.{f.name}" for f in all_fields() if not f.doc]
    assert unranged == []
    assert undocumented == []


def test_every_table_is_described_too():
    seen: set[type] = set()

    def tables(cls: type) -> list[str]:
        if cls in seen:
            return []
        seen.add(cls)
        missing = []
        docs = schema.field_docs(cls)
        for field in dataclasses.fields(cls):
            if not docs.get(field.name):
                missing.append(f"{cls.__name__}.{field.name}")
        for f in schema.fields(cls):
            if f.owner is not cls:
                missing += tables(f.owner)
        return missing

    assert [m for cls in KINDS.values() for m in tables(cls)] == []


def test_every_range_is_used_and_every_unit_has_an_fmi_spelling():
    """A range no field takes is a stale entry (a renamed field read unchecked); a unit the FMU
    cannot spell would fail an export."""
    used = {schema.range_key(f.path) for f in all_fields() if f.range is not None}
    assert set(schema.RANGES) - used == set()
    for f in all_fields():
        if f.unit:
            assert fmi_unit(f.unit), f.path


def test_a_unit_is_the_longest_suffix_of_the_name():
    assert schema.unit_of("hand_damping_N_s_m") == "N*s/m"
    assert schema.unit_of("stiffness_N_m") == "N/m"
    assert schema.unit_of("k1_Nm_s2_m") == "Nm/(m/s^2)"
    assert schema.unit_of("lateral_accel_m_s2") == "m/s^2"
    assert schema.unit_of("click_frequency_hz") == "Hz"
    assert schema.unit_of("cone_friction") == ""


def test_a_qualified_range_wins_over_the_name_alone():
    assert schema.range_of("vehicle.mass_kg") == schema.RANGES["vehicle.mass_kg"]
    assert schema.range_of("gearbox.stop.mass_kg") == schema.RANGES["mass_kg"]
    assert schema.range_of("layout.gears[3].ratio") == schema.RANGES["ratio"]
    assert schema.range_of("driver.pull_out") is None


@pytest.mark.parametrize(
    ("allowed", "value", "inside"),
    [
        (schema.Range(0.0, 1.0, False, True), 0.0, False),
        (schema.Range(0.0, 1.0, False, True), 1.0, True),
        (schema.Range(0.0, 1.0, True, False), 0.0, True),
        (schema.Range(0.0, 1.0, True, False), 1.0, False),
        (schema.Range(-math.inf, math.inf), math.inf, False),
        (schema.Range(-math.inf, math.inf), math.nan, False),
    ],
)
def test_a_range_keeps_its_ends_and_refuses_what_is_not_finite(allowed, value, inside):
    assert allowed.contains(value) is inside


BAD = [  # (path, type, the value as the sweep has it, the same value as TOML writes it)
    ("gearbox.stop.stiffness_N_m", float, -1.0, "-1.0"),
    ("gearbox.stop.stiffness_N_m", float, math.nan, "nan"),
    ("gearbox.stop.stiffness_N_m", float, "stiff", '"stiff"'),
    ("driver.hold_s", float, 10**400, "1" + "0" * 400),
    ("driver.pull_out", bool, 1, "1"),
]


@pytest.mark.parametrize(("path", "kind", "value", "toml"), BAD)
def test_the_loader_and_the_sweep_give_one_answer(path, kind, value, toml):
    """One validator: the sweep's spec and the preset loader say the same of the same value."""
    said = schema.number_problem(path, kind, value)
    assert said is not None and said.startswith(path)
    base = presets.load_shift().params
    assert spec.value_problem("shift", base, path, value) == said
    # the loader, on the shipped preset with that one value changed
    table, _, name = path.rpartition(".")
    shipped = resources.files("carfeel.presets").joinpath("shift/paper-first-gear.toml")
    lines = shipped.read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.split("#")[0].strip() == f"[{table}]")
    at = next(i for i in range(start, len(lines)) if lines[i].split("=")[0].strip() == name)
    lines[at] = f"{name} = {toml}"
    with pytest.raises(PresetError) as caught:
        presets.from_toml("shift", "edited.toml", "\n".join(lines))
    assert said in str(caught.value)


def test_a_sweep_takes_a_whole_float_where_a_preset_wants_a_whole_number():
    assert schema.number_problem("layout.gears[0].gear", int, 3.0) is not None
    assert schema.number_problem("layout.gears[0].gear", int, 3.0, whole_floats=True) is None
    assert "whole number" in str(schema.number_problem("layout.gears[0].gear", int, 3.5, True))


def test_every_tunable_of_the_panel_has_its_bounds_from_the_schema():
    for tunable in TUNABLES:
        allowed = schema.range_of(tunable.path)
        assert allowed is not None, tunable.path
        assert tunable.bounds == allowed
        assert tunable.unit == schema.unit_of(tunable.path.rsplit(".", 1)[-1])
