"""Presets: TOML files in SI units, loaded and validated once at the boundary.

A preset names its parameters exactly as the parameter dataclasses do; the unit is the name's
suffix (`mass_kg`, `stiffness_N_m`). Every key is required, no other key is allowed, and each value
must lie in its physical range. All problems are reported together in one PresetError, each naming
the parameter, the value, the unit and the allowed range.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import tomllib
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Generic, TypeVar

from carfeel.errors import PresetError
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import SteeringCar

T = TypeVar("T")
P = TypeVar("P")

INF = math.inf

# Allowed range of each parameter, by its name, or by "table.name" where the same name needs another
# range in another table: (low, high, low included, high included).
RANGES: dict[str, tuple[float, float, bool, bool]] = {
    "vehicle.mass_kg": (0.0, 1e5, False, True),
    "mass_kg": (0.0, 100.0, False, True),
    "stiffness_N_m": (0.0, 1e7, True, True),
    "damping_N_s_m": (0.0, 1e5, True, True),
    "static_friction_N": (0.0, 1e3, True, True),
    "sliding_friction_N": (0.0, 1e3, True, True),
    "synchronization_position_m": (0.0, 0.2, False, True),
    "teeth_position_m": (0.0, 0.2, False, True),
    "teeth_end_position_m": (0.0, 0.2, False, True),
    "in_gear_position_m": (0.0, 0.2, False, True),
    "detent_release_m": (0.0, 0.05, False, True),
    "synchronization_duration_s": (0.0, 10.0, False, True),
    "tooth_force_spread_N": (0.0, 1e3, True, True),
    "stick_velocity_m_s": (0.0, 0.1, False, True),
    "settle_velocity_m_s": (0.0, 1.0, False, True),
    "settle_distance_m": (0.0, 0.05, False, True),
    "push_force_N": (0.0, 1e3, False, True),
    "push_velocity_m_s": (0.0, 10.0, False, True),
    "hand_mass_kg": (0.0, 20.0, False, True),
    "hand_stiffness_N_m": (0.0, 1e5, False, True),
    "hand_damping_N_s_m": (0.0, 1e3, True, True),
    "release_time_s": (0.0, 1.0, False, True),
    "activation_time_s": (0.0, 1.0, False, True),
    "release_position_m": (0.0, 0.2, False, True),
    "hold_s": (0.0, 60.0, True, True),
    "pull_force_N": (0.0, 1e3, False, True),
    "pull_velocity_m_s": (0.0, 10.0, False, True),
    "neutral_position_m": (0.0, 0.2, True, True),
    # steering: vehicle
    "yaw_inertia_kg_m2": (0.0, 1e6, False, True),
    "wheelbase_m": (0.5, 10.0, True, True),
    "cg_to_front_axle_m": (0.0, 10.0, False, False),
    "front_cornering_stiffness_N_rad": (0.0, 1e7, False, True),
    "rear_cornering_stiffness_N_rad": (0.0, 1e7, False, True),
    "steering_ratio": (1.0, 50.0, True, True),
    "width_m": (0.5, 5.0, True, True),
    "steering_lock_rad": (0.0, 30.0, False, True),
    "kinematic_speed_m_s": (0.0, 10.0, False, True),
    # steering: torque law (K1..K9)
    "k1_Nm_s2_m": (0.0, 100.0, False, True),
    "k2": (0.0, 100.0, True, True),
    "k3": (0.0, 5.0, False, True),
    "k4_1_Nm": (0.0, 1e3, False, True),
    "k5_s_m_Nm": (0.0, 1e3, True, True),
    "k6_rad_s": (0.0, 100.0, False, True),
    "k7_Nm": (0.0, 100.0, True, True),
    "k8_rad_s": (0.0, 100.0, False, True),
    "k9_Nm_s_rad": (0.0, 100.0, True, True),
    # steering: path driver
    "preview_time_s": (0.0, 10.0, False, True),
    "min_preview_m": (0.0, 100.0, False, True),
    "lag_s": (0.0, 2.0, False, True),
    "max_rate_rad_s": (0.0, 100.0, False, True),
}

# Unit of a parameter from the suffix of its name, longest suffix first.
_UNITS = [
    ("_Nm_s2_m", "Nm/(m/s^2)"),
    ("_Nm_s_rad", "Nm*s/rad"),
    ("_s_m_Nm", "s/(m*Nm)"),
    ("_kg_m2", "kg*m^2"),
    ("_N_rad", "N/rad"),
    ("_rad_s", "rad/s"),
    ("_1_Nm", "1/Nm"),
    ("_N_s_m", "N*s/m"),
    ("_Nm", "Nm"),
    ("_rad", "rad"),
    ("_N_m", "N/m"),
    ("_m_s", "m/s"),
    ("_kg", "kg"),
    ("_N", "N"),
    ("_m", "m"),
    ("_s", "s"),
]

PRESET_KINDS = ("shift", "steering")
DEFAULT_PRESETS = {"shift": "paper-first-gear", "steering": "b-segment"}


def unit_of(name: str) -> str:
    for suffix, unit in _UNITS:
        if name.endswith(suffix):
            return unit
    return ""


def range_key(full: str) -> str:
    """The RANGES key of a parameter's dotted path: "table.name" if listed, else "name"."""
    parts = full.split(".")
    qualified = ".".join(parts[-2:])
    return qualified if qualified in RANGES else parts[-1]


def describe_range(key: str) -> str:
    low, high, low_in, high_in = RANGES[key]
    name = key.split(".")[-1]
    unit = unit_of(name)
    return f"{low:g} {'<=' if low_in else '<'} value {'<=' if high_in else '<'} {high:g} {unit}"


@dataclass(frozen=True, slots=True)
class Preset(Generic[P]):
    name: str
    source: str
    params: P


def available(kind: str) -> list[str]:
    """Names of the presets that ship with carfeel for one kind (e.g. "shift")."""
    folder = resources.files("carfeel.presets").joinpath(kind)
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def resolve(kind: str, name_or_path: str) -> tuple[str, str]:
    """Find a preset by shipped name or file path; return (label, TOML text)."""
    path = Path(name_or_path)
    looks_like_path = path.suffix == ".toml" or "/" in name_or_path or "\\" in name_or_path
    if looks_like_path or path.is_file():
        try:
            return str(path), path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise PresetError(
                f"preset file {path} not found; give an existing TOML file or one of the "
                f"{kind} presets: {', '.join(available(kind))}"
            ) from None
        except (OSError, UnicodeDecodeError) as exc:
            raise PresetError(f"preset file {path} cannot be read: {exc}") from None
    shipped = resources.files("carfeel.presets").joinpath(kind, f"{name_or_path}.toml")
    if not shipped.is_file():
        raise PresetError(
            f"no {kind} preset named {name_or_path!r}; the shipped ones are: "
            f"{', '.join(available(kind))} (or give the path of a .toml file)"
        )
    return name_or_path, shipped.read_text(encoding="utf-8")


def parse(label: str, text: str) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise PresetError(f"preset {label}: not valid TOML: {exc}") from None


def build(cls: type[T], table: Mapping[str, Any], where: str, problems: list[str]) -> T | None:
    """Build a parameter dataclass from a TOML table, appending each problem to `problems`."""
    hints = typing.get_type_hints(cls)
    fields = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    for key in table:
        if key not in fields:
            problems.append(
                f"{where}{key}: unknown parameter; {where.rstrip('.') or 'this table'} takes "
                f"{', '.join(fields)}"
            )
    values: dict[str, Any] = {}
    for name in fields:
        kind = hints[name]
        full = f"{where}{name}"
        if name not in table:
            expected = "a table" if dataclasses.is_dataclass(kind) else _expected(full, kind)
            problems.append(f"{full}: missing; expected {expected}")
            continue
        value = table[name]
        if dataclasses.is_dataclass(kind):
            if not isinstance(value, dict):
                problems.append(f"{full}: expected a table [{full}], got {value!r}")
                continue
            values[name] = build(kind, value, f"{full}.", problems)  # type: ignore[arg-type]
        elif kind is bool:
            if not isinstance(value, bool):
                problems.append(f"{full} = {value!r}: expected true or false")
            values[name] = value
        elif kind is float:
            if isinstance(value, bool) or not isinstance(value, int | float):
                problems.append(f"{full} = {value!r}: expected a number, {_expected(full, kind)}")
                continue
            try:
                value = float(value)
            except OverflowError:
                value = math.inf
            if not _in_range(range_key(full), value):
                problems.append(
                    f"{full} = {value:g} {unit_of(name)} is out of range: "
                    f"allowed {describe_range(range_key(full))}"
                )
            values[name] = value
        else:  # pragma: no cover - a parameter type this loader was not taught
            raise TypeError(f"{cls.__name__}.{name}: unsupported type {kind}")
    if len(values) < len(fields) or any(v is None for v in values.values()):
        return None
    return cls(**values)


def _expected(full: str, kind: Any) -> str:
    if kind is bool:
        return "true or false"
    key = range_key(full)
    return f"a number with {describe_range(key)}" if key in RANGES else "a number"


def _in_range(name: str, value: float) -> bool:
    low, high, low_in, high_in = RANGES[name]
    if not math.isfinite(value):
        return False
    above = value >= low if low_in else value > low
    below = value <= high if high_in else value < high
    return above and below


def check_shift(params: ShiftParams) -> list[str]:
    """Problems a shift preset can have across parameters (each field already in range)."""
    g, d = params.gearbox, params.driver
    problems = []
    order = [
        ("gearbox.synchronization_position_m", g.synchronization_position_m),
        ("gearbox.teeth_position_m", g.teeth_position_m),
        ("gearbox.teeth_end_position_m", g.teeth_end_position_m),
        ("gearbox.in_gear_position_m", g.in_gear_position_m),
    ]
    for (name_a, a), (name_b, b) in itertools.pairwise(order):
        if not a < b:
            problems.append(
                f"{name_a} = {a:g} m must lie before {name_b} = {b:g} m: along the slot the "
                "synchro ring comes first, then the teeth, then the stop"
            )
    for stage in (
        "neutral",
        "gate_open",
        "engagement",
        "free_travel",
        "stop",
        "in_gear",
        "returning",
    ):
        mech = getattr(g, stage)
        if mech.sliding_friction_N > mech.static_friction_N:
            problems.append(
                f"gearbox.{stage}.sliding_friction_N = {mech.sliding_friction_N:g} N exceeds "
                f"gearbox.{stage}.static_friction_N = {mech.static_friction_N:g} N: allowed "
                "0 <= sliding <= static"
            )
    for stage in ("stop", "in_gear"):
        if getattr(g, stage).stiffness_N_m <= 0.0:
            problems.append(
                f"gearbox.{stage}.stiffness_N_m = 0 N/m: the {stage} stage is a spring around the "
                "in-gear position; allowed 0 < value <= 1e+07 N/m"
            )
    if g.in_gear.stiffness_N_m > g.stop.stiffness_N_m:
        problems.append(
            f"gearbox.in_gear.stiffness_N_m = {g.in_gear.stiffness_N_m:g} N/m exceeds "
            f"gearbox.stop.stiffness_N_m = {g.stop.stiffness_N_m:g} N/m: the lever settles from "
            "the stop into the detent, which may be softer but not stiffer"
        )
    held = g.stop.static_friction_N / g.stop.stiffness_N_m if g.stop.stiffness_N_m > 0 else 0.0
    if g.settle_distance_m <= held:
        problems.append(
            f"gearbox.settle_distance_m = {g.settle_distance_m:g} m must exceed the distance the "
            f"stop's static friction can hold the lever off x_gear ({held:.3g} m = "
            "gearbox.stop.static_friction_N / gearbox.stop.stiffness_N_m), or the lever may "
            "never count as settled in gear"
        )
    room = g.in_gear_position_m - g.teeth_end_position_m
    if g.detent_release_m >= room:
        problems.append(
            f"gearbox.detent_release_m = {g.detent_release_m:g} m must be shorter than the travel "
            f"from the teeth to the gear ({room:g} m)"
        )
    tooth_max = g.engagement.static_friction_N + g.tooth_force_spread_N
    if tooth_max >= d.push_force_N:
        problems.append(
            "gearbox.engagement.static_friction_N + gearbox.tooth_force_spread_N = "
            f"{tooth_max:g} N "
            f"must stay below driver.push_force_N = {d.push_force_N:g} N, or a driver could stall "
            "on the teeth; the tooth peak is lower than the synchronization force (about 1/3 of it "
            "by a synchronizer design guideline)"
        )
    if g.neutral.static_friction_N >= d.push_force_N:
        problems.append(
            f"gearbox.neutral.static_friction_N = {g.neutral.static_friction_N:g} N must stay "
            f"below driver.push_force_N = {d.push_force_N:g} N, or the lever never leaves neutral"
        )
    if not g.teeth_end_position_m < d.release_position_m <= g.in_gear_position_m:
        problems.append(
            f"driver.release_position_m = {d.release_position_m:g} m: allowed "
            f"{g.teeth_end_position_m:g} < value <= {g.in_gear_position_m:g} m (past the teeth, "
            "at most the in-gear position)"
        )
    if d.neutral_position_m >= g.synchronization_position_m:
        problems.append(
            f"driver.neutral_position_m = {d.neutral_position_m:g} m: allowed "
            f"0 <= value < {g.synchronization_position_m:g} m (before the synchro ring)"
        )
    return problems


def check_steering(car: SteeringCar) -> list[str]:
    """Problems a steering preset can have across parameters (each field already in range)."""
    v = car.vehicle
    problems = []
    if v.cg_to_front_axle_m >= v.wheelbase_m:
        problems.append(
            f"vehicle.cg_to_front_axle_m = {v.cg_to_front_axle_m:g} m must be shorter than "
            f"vehicle.wheelbase_m = {v.wheelbase_m:g} m (the centre of gravity lies between the "
            "axles)"
        )
    elif v.understeer_gradient_rad_s2_m < 0.0:
        problems.append(
            f"the vehicle oversteers (understeer gradient {v.understeer_gradient_deg_per_g:.2f} "
            "deg/g): a linear oversteering car is unstable above its critical speed; raise "
            "vehicle.rear_cornering_stiffness_N_rad or move the centre of gravity forward"
        )
    return problems


_KINDS: dict[str, tuple[type[Any], tuple[str, ...], Callable[[Any], list[str]]]] = {
    "shift": (ShiftParams, ("gearbox", "driver"), check_shift),
    "steering": (SteeringCar, ("vehicle", "torque", "driver"), check_steering),
}


def load_shift(name_or_path: str = "paper-first-gear") -> Preset[ShiftParams]:
    """Load and validate a shift preset by shipped name or path."""
    preset: Preset[ShiftParams] = load("shift", name_or_path)
    return preset


def load_steering(name_or_path: str = "b-segment") -> Preset[SteeringCar]:
    """Load and validate a steering (car) preset by shipped name or path."""
    preset: Preset[SteeringCar] = load("steering", name_or_path)
    return preset


def load(kind: str, name_or_path: str) -> Preset[Any]:
    label, text = resolve(kind, name_or_path)
    return from_toml(kind, label, text)


def from_toml(kind: str, label: str, text: str) -> Preset[Any]:
    """Parse and validate a preset of `kind`; every problem is reported in one PresetError."""
    cls, tables_of_kind, check = _KINDS[kind]
    data = parse(label, text)
    problems: list[str] = []
    allowed = ("name", "source", *tables_of_kind)
    for key in data:
        if key not in allowed:
            problems.append(f"{key}: unknown key; a {kind} preset has {', '.join(allowed)}")
    for key in ("name", "source"):
        if not isinstance(data.get(key), str) or not data[key].strip():
            problems.append(f"{key}: missing; expected a string (where the numbers come from)")
    tables: dict[str, Any] = {k: data[k] for k in tables_of_kind if k in data}
    params = build(cls, tables, "", problems)
    if params is not None and not problems:
        problems.extend(check(params))
    if problems or params is None:
        raise PresetError(f"preset {label} is not valid:\n  " + "\n  ".join(problems))
    return Preset(data["name"], data["source"], params)


def shift_from_toml(label: str, text: str) -> Preset[ShiftParams]:
    return from_toml("shift", label, text)
