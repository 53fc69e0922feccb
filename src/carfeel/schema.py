"""The parameter schema: every preset field's unit, allowed range and description, in one place.

Each consumer reads a field's metadata from here and from nowhere else: the preset loader
(`carfeel.io.presets`) checks each value it reads, the sweep (`carfeel.sweep.spec`) each value a
spec sets, varies or draws, the FMU export gives each parameter variable its unit, range and
description, the panel's tunables take their bounds, and the docs site renders its preset
reference from `fields`.

- **Unit**: the suffix of the field's name (`mass_kg` is kg, `stiffness_N_m` is N/m; `UNITS`).
- **Range**: `RANGES`, by the field's name, or by "table.name" where the same name needs another
  range in another table (`vehicle.mass_kg` is a car's, `mass_kg` a lever's).
- **Description**: the field's attribute docstring in its parameter dataclass (the string on the
  line after the field), so that it stays beside the code that uses it.

A leaf module: it imports nothing of carfeel, and walks whatever parameter dataclass it is given.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import itertools
import math
import re
import textwrap
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, NamedTuple

__all__ = [
    "RANGES",
    "UNITS",
    "Field",
    "Range",
    "describe_range",
    "expected_value",
    "field_docs",
    "fields",
    "number_problem",
    "optional_of",
    "range_key",
    "range_of",
    "type_hints",
    "unit_of",
]


class Range(NamedTuple):
    """The values a parameter may take: low .. high, each end included or not. A tuple
    (low, high, low_included, high_included) for the code that unpacks it."""

    low: float
    high: float
    low_included: bool = True
    high_included: bool = True

    def contains(self, value: float) -> bool:
        """Whether `value` is allowed (never a NaN or an infinity)."""
        if not math.isfinite(value):
            return False
        above = value >= self.low if self.low_included else value > self.low
        below = value <= self.high if self.high_included else value < self.high
        return above and below

    def text(self, unit: str = "") -> str:
        """As the messages and the reference show it: `0 < value <= 0.2 m`."""
        low = "<=" if self.low_included else "<"
        high = "<=" if self.high_included else "<"
        text = f"{self.low:g} {low} value {high} {self.high:g}"
        return f"{text} {unit}" if unit else text


INF = math.inf


def _r(low: float, high: float, low_in: bool = True, high_in: bool = True) -> Range:
    return Range(low, high, low_in, high_in)


RANGES: dict[str, Range] = {
    # the gearshift: each stage's mechanics (models.mechanics.StageMechanics)
    "vehicle.mass_kg": _r(50.0, 1e5),
    "mass_kg": _r(0.0, 100.0, False),
    "stiffness_N_m": _r(0.0, 1e7),
    "damping_N_s_m": _r(0.0, 1e5),
    "static_friction_N": _r(0.0, 1e3),
    "sliding_friction_N": _r(0.0, 1e3),
    # the gearshift: the engagement's positions and stages
    "synchronization_position_m": _r(0.0, 0.2, False),
    "teeth_position_m": _r(0.0, 0.2, False),
    "teeth_end_position_m": _r(0.0, 0.2, False),
    "in_gear_position_m": _r(0.0, 0.2, False),
    "detent_release_m": _r(0.0, 0.05, False),
    "synchronization_duration_s": _r(0.0, 10.0, False),
    "tooth_force_spread_N": _r(0.0, 1e3),
    "ring_release_force_N": _r(0.0, 1e3),
    "desynchronization_time_s": _r(0.0, 100.0, False),
    "reversal_force_N": _r(0.0, 1e3),
    "reversal_time_s": _r(0.0, 1.0),
    "linkage_stiffness_N_m": _r(0.0, 1e7),
    "linkage_damping_N_s_m": _r(0.0, 1e4),
    "stop_travel_m": _r(0.0, 0.1),
    "synchronization_force_N": _r(0.0, 1e4),
    "neutral_detent.width_m": _r(0.0, 0.1, False),
    "gear_detent.width_m": _r(0.0, 0.1, False),
    "seat_force_N": _r(0.0, 1e3),
    "far_force_N": _r(0.0, 1e3),
    "far_width_m": _r(0.0, 0.1),
    "gear_inertia_kg_m2": _r(0.0, 10.0),
    "chamfer.drag_torque_Nm": _r(0.0, 1e3),
    "angle_rad": _r(0.0, 1.4, False),
    "radius_m": _r(0.0, 0.5, False),
    "linkage_efficiency": _r(0.0, 1.0, False),
    "travel_m": _r(0.0, 0.05),
    "no_contact_fraction": _r(0.0, 1.0, True, False),
    "stick_velocity_m_s": _r(0.0, 0.1, False),
    "settle_velocity_m_s": _r(0.0, 1.0, False),
    "settle_distance_m": _r(0.0, 0.05, False),
    # the gearshift: the scripted hand
    "push_force_N": _r(0.0, 1e3, False),
    "push_velocity_m_s": _r(0.0, 10.0, False),
    "hand_mass_kg": _r(0.0, 20.0, False),
    "hand_stiffness_N_m": _r(0.0, 1e5, False),
    "hand_damping_N_s_m": _r(0.0, 1e3),
    "release_time_s": _r(0.0, 1.0, False),
    "activation_time_s": _r(0.0, 1.0, False),
    "release_position_m": _r(0.0, 0.2, False),
    "hold_s": _r(0.0, 60.0),
    "pull_force_N": _r(0.0, 1e3, False),
    "pull_velocity_m_s": _r(0.0, 10.0, False),
    "neutral_position_m": _r(0.0, 0.2),
    # steering: vehicle
    "yaw_inertia_kg_m2": _r(1.0, 1e6),
    "wheelbase_m": _r(0.5, 10.0),
    "cg_to_front_axle_m": _r(0.0, 10.0, False, False),
    "front_cornering_stiffness_N_rad": _r(1e3, 1e7),
    "rear_cornering_stiffness_N_rad": _r(1e3, 1e7),
    "steering_ratio": _r(1.0, 50.0),
    "width_m": _r(0.5, 5.0),
    "steering_lock_rad": _r(0.0, 30.0, False),
    "kinematic_speed_m_s": _r(0.1, 10.0),
    # steering: torque law (K1..K9)
    "k1_Nm_s2_m": _r(0.0, 100.0, False),
    "k2": _r(0.0, 100.0),
    "k3": _r(0.0, 5.0, False),
    "k4_1_Nm": _r(0.0, 1e3, False),
    "k5_s_m_Nm": _r(0.0, 1e3),
    "k6_rad_s": _r(0.0, 100.0, False),
    "k7_Nm": _r(0.0, 100.0),
    "k8_rad_s": _r(0.0, 100.0, False),
    "k9_Nm_s_rad": _r(0.0, 100.0),
    "k10_Nm": _r(0.0, 100.0),  # the friction with memory's level (0: off)
    "k11_rad": _r(0.0, 10.0, False),  # its presliding angle
    # hpattern: layout
    "planes_y_m": _r(-0.2, 0.2),
    "centre_plane": _r(0.0, 20.0),
    "slot_width_m": _r(0.0, 0.05, False),
    "corridor_width_m": _r(0.0, 0.1, False),
    "reverse_lockout_N": _r(0.0, 500.0),
    "plane": _r(0.0, 20.0),
    "direction": _r(-1.0, 1.0),
    "ratio": _r(-20.0, 20.0),
    "gear": _r(-8.0, 24.0),  # a truck's table: the game's gear number
    "handle_position": _r(0.0, 31.0),  # ETS2's 32 hshifter slots
    "range_plane": _r(0.0, 20.0),
    "high_centre_plane": _r(0.0, 20.0),
    "range_detent_N": _r(0.0, 200.0),
    # hpattern: select axis, walls
    "select.mass_kg": _r(0.0, 100.0, False),
    "centring_stiffness_N_m": _r(0.0, 1e5),
    "detent_stiffness_N_m": _r(0.0, 1e5),
    "detent_width_m": _r(0.0, 0.05, False),
    "slot_stiffness_N_m": _r(0.0, 1e6, False),
    "slot_damping_N_s_m": _r(0.0, 1e3),
    "lockout_stiffness_N_m": _r(0.0, 1e6, False),
    "walls.stiffness_N_m": _r(0.0, 1e6, False),
    "walls.damping_N_s_m": _r(0.0, 1e3),
    # hpattern: synchronizer
    "input_inertia_kg_m2": _r(0.0, 1.0, False),
    "cone_friction": _r(0.0, 1.0, False),
    "cone_radius_m": _r(0.0, 0.2, False),
    "cone_half_angle_rad": _r(0.0, 0.8, False),
    "lever_ratio": _r(0.0, 50.0, False),
    "blocking_margin": _r(-1.0, 10.0),
    "cone_scale": _r(0.0, 10.0, False),
    "clutch_capacity_Nm": _r(0.0, 5000.0),
    "clutch_open_above": _r(0.0, 1.0, False),
    "drag_torque_Nm": _r(0.0, 100.0),
    "speed_tolerance_rad_s": _r(0.0, 100.0, False),
    "grind_force_N": _r(0.0, 1e3),
    "grind_amplitude_N": _r(0.0, 100.0),
    "dog_teeth": _r(1.0, 500.0),
    "final_drive_ratio": _r(0.0, 20.0, False),
    "wheel_radius_m": _r(0.1, 1.0),
    # hpattern: feel (latch, click)
    "latch_position_m": _r(0.0, 0.1, False),
    "latch_width_m": _r(0.0, 0.02, False),
    "latch_force_N": _r(0.0, 100.0),
    "click_amplitude_N": _r(0.0, 50.0),
    "click_frequency_hz": _r(1.0, 1000.0),
    "click_decay_s": _r(1e-4, 1.0),
    "click_speed_m_s": _r(0.0, 10.0),
    # hpattern: driver
    "select_force_N": _r(0.0, 500.0, False),
    "select_stiffness_N_m": _r(0.0, 1e6, False),
    "select_damping_N_s_m": _r(0.0, 1e4),
    "select_tolerance_m": _r(0.0, 0.02, False),
    # sequential lever ([lever]) and PRND selector ([selector]); their offline drivers
    "forward_gears": _r(1.0, 12.0),
    "up_direction": _r(-1.0, 1.0),  # +1 or -1: the lever's own check
    "centring_N_m": _r(0.0, 1e5),
    "centring_preload_N": _r(0.0, 200.0),
    "click_m": _r(0.0, 0.1, False),
    "click_width_m": _r(0.0, 0.05, False),
    "click_N": _r(0.0, 500.0),
    "end_m": _r(0.0, 0.2, False),
    "rearm_m": _r(0.0, 0.1, False),
    "lock_m": _r(0.0, 0.1, False),
    "drum_N": _r(0.0, 500.0),
    "dog_N": _r(0.0, 500.0),
    "dog_width_m": _r(0.0, 0.05),
    "wall_N_m": _r(0.0, 1e6, False),
    "wall_N_s_m": _r(0.0, 1e3),
    "friction_velocity_m_s": _r(0.0, 1.0, False),
    "pitch_m": _r(0.0, 0.2, False),
    "detent_N": _r(0.0, 500.0),
    "register_m": _r(0.0, 0.1, False),
    "reverse_lock_speed_m_s": _r(0.0, 100.0),
    "hand_N": _r(0.0, 1e3, False),
    "rest_s": _r(0.0, 60.0),
    # steering: physical model, tyres (tables [tyres], [steering_system]; optional)
    "friction_coefficient": _r(0.05, 2.0),
    "load_sensitivity": _r(0.0, 0.5),
    "pneumatic_trail_m": _r(0.0, 0.1),
    "relaxation_length_m": _r(0.05, 2.0),
    "cg_height_m": _r(0.1, 2.0),
    "track_m": _r(0.5, 3.0),
    "front_roll_share": _r(0.0, 1.0),
    "patch_radius_m": _r(0.0, 0.3),
    "wind_up_stiffness_Nm_rad": _r(1.0, 1e6),
    # steering: physical model, steering system (hand-wheel units)
    "hand_wheel_inertia_kg_m2": _r(1e-3, 1.0),
    "rack_inertia_kg_m2": _r(1e-3, 2.0),
    "torsion_bar_stiffness_Nm_rad": _r(1.0, 1e4),
    "compensation_damping_Nm_s_rad": _r(0.0, 20.0),
    "mechanical_trail_m": _r(-0.05, 0.1),
    "kingpin_inclination_rad": _r(0.0, 0.5),
    "kingpin_offset_m": _r(0.0, 0.3),
    "column_friction_Nm": _r(0.0, 10.0),
    "rack_friction_Nm": _r(0.0, 20.0),
    "friction_stiffness_Nm_rad": _r(1.0, 1e4),
    "presliding_damping_Nm_s_rad": _r(0.0, 20.0),
    "rack_damping_Nm_s_rad": _r(0.0, 10.0),
    "assist_deadband_Nm": _r(0.0, 10.0),
    "assist_gain_standstill_1_Nm": _r(0.0, 20.0),
    "assist_gain_high_speed_1_Nm": _r(0.0, 20.0),
    "assist_fade_speed_m_s": _r(0.1, 100.0),
    "max_assist_Nm": _r(0.0, 200.0),
    "eps_damping_Nm_s_rad": _r(0.0, 10.0),
    "eps_damping_high_speed_Nm_s_rad": _r(0.0, 10.0),
    "eps_damping_rise_Nm_s3_rad_m2": _r(0.0, 0.01),
    "active_return_Nm_rad": _r(0.0, 100.0),
    "active_return_max_Nm": _r(0.0, 20.0),
    "active_return_fade_speed_m_s": _r(0.1, 100.0),
    "stop_stiffness_Nm_rad": _r(10.0, 1e5),
    "stop_damping_Nm_s_rad": _r(0.0, 100.0),
    # steering: path driver
    "preview_time_s": _r(0.0, 10.0, False),
    "min_preview_m": _r(0.0, 100.0, False),
    "lag_s": _r(0.02, 2.0),
    "max_rate_rad_s": _r(0.0, 100.0, False),
}
"""The allowed range of each parameter, by its name or by "table.name" (see `range_key`).
Physical bounds, wide enough for every car and device carfeel knows: a value outside is a typo
or a unit mistake, never a design choice. Cross-field checks (the stages' order along the slot,
a wall's passivity at 1 kHz) are the loader's (`carfeel.io.presets.check_*`)."""

UNITS: tuple[tuple[str, str], ...] = (
    ("_Nm_s3_rad_m2", "Nm*s/rad per (m/s)^2"),
    ("_Nm_s2_m", "Nm/(m/s^2)"),
    ("_Nm_s_rad", "Nm*s/rad"),
    ("_Nm_rad", "Nm/rad"),
    ("_kg_m2", "kg*m^2"),
    ("_s_m_Nm", "s/(m*Nm)"),
    ("_rad_s", "rad/s"),
    ("_N_rad", "N/rad"),
    ("_1_Nm", "1/Nm"),
    ("_N_s_m", "N*s/m"),
    ("_m_s2", "m/s^2"),
    ("_Nm", "Nm"),
    ("_rad", "rad"),
    ("_N_m", "N/m"),
    ("_m_s", "m/s"),
    ("_hz", "Hz"),
    ("_kg", "kg"),
    ("_N", "N"),
    ("_m", "m"),
    ("_s", "s"),
)
"""A name's suffix and the unit it means, longest suffix first (the first that ends the name
wins: `_N_s_m` before `_m`)."""


def unit_of(name: str) -> str:
    """The unit of a parameter (or a signal) by its name's suffix; "" for a pure number."""
    for suffix, unit in UNITS:
        if name.endswith(suffix):
            return unit
    return ""


def range_key(path: str) -> str:
    """The RANGES key of a parameter's dotted path (`gearbox.stop.mass_kg`, `layout.gears[2]
    .ratio`): "table.name" if that is listed, else "name"."""
    parts = re.sub(r"\[\d*\]", "", path).split(".")
    qualified = ".".join(parts[-2:])
    return qualified if qualified in RANGES else parts[-1]


def range_of(path: str) -> Range | None:
    """The allowed range of the parameter at a dotted path; None for one with no range (a
    true/false or a name)."""
    return RANGES.get(range_key(path))


def describe_range(key: str) -> str:
    """A RANGES key's range as text, with the unit: `0 < value <= 100 kg`."""
    return RANGES[key].text(unit_of(key.split(".")[-1]))


def optional_of(kind: Any) -> Any:
    """X for `X | None` (an optional table), else `kind`."""
    args = typing.get_args(kind)
    if type(None) in args and len(args) == 2:
        return args[0] if args[1] is type(None) else args[1]
    return kind


_HINTS: dict[type[Any], dict[str, Any]] = {}
_DOCS: dict[type[Any], dict[str, str]] = {}


def type_hints(cls: type[Any]) -> dict[str, Any]:
    """The fields' types of a parameter dataclass (typing.get_type_hints is slow: kept)."""
    hints = _HINTS.get(cls)
    if hints is None:
        hints = _HINTS[cls] = typing.get_type_hints(cls)
    return hints


def field_docs(cls: type[Any]) -> dict[str, str]:
    """The attribute docstrings of a dataclass (the string after a field), by field name."""
    docs = _DOCS.get(cls)
    if docs is None:
        docs = _DOCS[cls] = _read_field_docs(cls)
    return docs


def _read_field_docs(cls: type[Any]) -> dict[str, str]:
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    except (OSError, TypeError, SyntaxError):  # pragma: no cover - no source installed
        return {}
    docs: dict[str, str] = {}
    body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
    for node, after in itertools.pairwise(body):
        if (
            isinstance(node, ast.AnnAssign)
            and isinstance(node.target, ast.Name)
            and isinstance(after, ast.Expr)
            and isinstance(after.value, ast.Constant)
            and isinstance(after.value.value, str)
        ):
            docs[node.target.id] = " ".join(after.value.value.split())
    return docs


@dataclass(frozen=True, slots=True)
class Field:
    """One leaf parameter of a preset kind, as the schema describes it."""

    path: str
    """Its key path in the preset: `gearbox.stop.stiffness_N_m`; `layout.gears[].ratio` for a
    field of an array of tables."""
    kind: Any
    """Its Python type: float, int, bool, str, or a tuple of one of them (a list)."""
    unit: str
    range: Range | None
    doc: str
    """Its description: the attribute docstring in `owner`."""
    owner: type[Any]
    """The parameter dataclass it is a field of."""
    default: Any = dataclasses.MISSING
    """Its value when a preset leaves it out (MISSING: required)."""

    @property
    def name(self) -> str:
        return self.path.rsplit(".", 1)[-1]

    @property
    def required(self) -> bool:
        return self.default is dataclasses.MISSING

    def range_text(self) -> str:
        """The allowed range with the unit, or "" where the field has none."""
        return self.range.text(self.unit) if self.range is not None else ""


def fields(cls: type[Any], prefix: str = "") -> Iterator[Field]:
    """Every leaf field of the parameter dataclass `cls`, its tables (optional ones too) and
    its arrays of tables (as `path[].name`), in declaration order."""
    hints = type_hints(cls)
    docs = field_docs(cls)
    for field in dataclasses.fields(cls):
        hint = optional_of(hints[field.name])
        path = f"{prefix}{field.name}"
        args = typing.get_args(hint)
        if dataclasses.is_dataclass(hint):
            yield from fields(typing.cast(type[Any], hint), f"{path}.")
        elif typing.get_origin(hint) is tuple and args and dataclasses.is_dataclass(args[0]):
            yield from fields(typing.cast(type[Any], args[0]), f"{path}[].")
        else:
            yield Field(
                path, hint, unit_of(field.name), range_of(path), docs.get(field.name, ""), cls,
                field.default,
            )  # fmt: skip


def expected_value(path: str, kind: Any) -> str:
    """What a value at `path` must be, for a message: `a number with 0 < value <= 100 kg`."""
    if kind is bool:
        return "true or false"
    if kind is str:
        return "a string"
    allowed = range_of(path)
    if allowed is None:
        return "a number"
    return f"a number with {allowed.text(unit_of(path.rsplit('.', 1)[-1]))}"


def number_problem(path: str, kind: Any, value: Any, whole_floats: bool = False) -> str | None:
    """What is wrong with `value` for the parameter at `path` of type `kind` (bool, int or
    float), or None: its type, then its range. `whole_floats`: 3.0 is a whole number (a sweep's
    values are drawn as floats); else a whole number must be written as one. The one check
    behind the preset loader and the sweep's spec."""
    if kind is bool:
        return None if isinstance(value, bool) else f"{path} = {value!r}: expected true or false"
    allowed = range_of(path)
    unit = unit_of(path.rsplit(".", 1)[-1])
    expected = expected_value(path, kind)
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{path} = {value!r}: expected {expected}"
    whole = isinstance(value, int) or (whole_floats and float(value).is_integer())
    if kind is int and not whole:
        return f"{path} = {value!r}: expected a whole number, {expected}"
    if isinstance(value, int) and abs(value) > 10**15:  # beyond every range (and a float's)
        said = f"{path} = a {len(str(abs(value)))}-digit number"
        if allowed is not None:
            return f"{said} is out of range: allowed {allowed.text(unit)}"
        return f"{said}: expected {expected}"
    number = float(value)
    if allowed is not None and not allowed.contains(number):
        shown = " ".join(part for part in (f"{number:g}", unit) if part)
        return f"{path} = {shown} is out of range: allowed {allowed.text(unit)}"
    return None
