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
import numbers
import re
import stat
import tomllib
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Generic, TypeVar

from carfeel.errors import CarfeelError, PresetError
from carfeel.models.gearshift.hpattern import WALL_DEPTH_M, HPatternParams, Layout
from carfeel.models.gearshift.synchronizer import LOCATIONS
from carfeel.schema import expected_value, number_problem, optional_of, type_hints
from carfeel.simulation.hpattern import HPatternSetup
from carfeel.simulation.prnd import PrndSetup
from carfeel.simulation.sequential import SequentialSetup
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import SteeringCar

T = TypeVar("T")
P = TypeVar("P")

PRESET_KINDS = ("shift", "steering", "hpattern", "sequential", "prnd")
DEFAULT_PRESETS = {"shift": "paper-first-gear", "steering": "b-segment", "hpattern": "5r",
                   "sequential": "rally-6", "prnd": "automatic"}  # fmt: skip


@dataclass(frozen=True, slots=True)
class Preset(Generic[P]):
    name: str
    source: str
    params: P


def available(kind: str) -> list[str]:
    """Names of the presets that ship with carfeel for one kind (e.g. "shift")."""
    folder = resources.files("carfeel.presets").joinpath(kind)
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


MAX_TOML_BYTES = 256 * 1024
"""The largest preset (or map) file read: the shipped ones are under 8 kB; 256 kB of the
worst TOML (keys alone) parses in about 0.3 s."""
MAX_TOML_NESTING = 16
"""Arrays and inline tables nested deeper than this are refused before parsing (a preset
nests 3 deep; 100k deep made tomllib overflow Python's stack)."""
MAX_KEY_PARTS = 16
"""Parts of one dotted key (a.b.c is 3): tomllib's memory grows as their square (10k parts
took 400 MB), so a longer key is refused before parsing."""
MAX_NAME_CHARS = 1000
"""A preset's name (and engagement) is a label: bounded, and the same bound the FMU carries (a
hostile name of a few hundred characters must still be data an FMU can hold, issue 24)."""
MAX_SOURCE_CHARS = 64 * 1024
MAX_PROBLEMS = 40
"""Problems listed in one error (a file of 100k unknown keys gives a readable message)."""

_TOML_TOKEN = re.compile(r'"""|' + r"'''" + r"""|["'#\[\]{}.=,\n]""")


def read_limited(path: Path, what: str, error: type[CarfeelError] = PresetError) -> str:
    """A TOML file's text, refused (not read) beyond MAX_TOML_BYTES or if it is not a regular
    file (a FIFO or /dev/zero would block or never end). FileNotFoundError passes through."""
    try:
        info = path.stat()
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise error(f"{what} {path} cannot be read: {exc}") from None
    if not stat.S_ISREG(info.st_mode):
        raise error(f"{what} {path} is not a regular file")
    if info.st_size > MAX_TOML_BYTES:
        raise error(
            f"{what} {path} is {info.st_size} bytes: at most {MAX_TOML_BYTES} are read "
            "(a preset is a few kB)"
        )
    try:
        with path.open("rb") as handle:
            data = handle.read(MAX_TOML_BYTES + 1)
    except OSError as exc:
        raise error(f"{what} {path} cannot be read: {exc}") from None
    if len(data) > MAX_TOML_BYTES:
        raise error(f"{what} {path} grew past {MAX_TOML_BYTES} bytes while read")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path} is not UTF-8 text: {exc}") from None


def check_toml_limits(label: str, text: str, error: type[CarfeelError] = PresetError) -> None:
    """Refuse, before tomllib sees it, TOML that is too large, nested too deep or has too long a
    dotted key (the limits above). A scan of the text outside its strings and comments that
    counts brackets and dots; tomllib then checks the syntax."""
    if len(text) > MAX_TOML_BYTES:
        raise error(f"{label}: {len(text)} characters; at most {MAX_TOML_BYTES} are read")
    depth = parts = 0
    find, n = _TOML_TOKEN.search, len(text)
    pos = 0
    while (match := find(text, pos)) is not None:
        token, i = match.group(), match.start()
        pos = match.end()
        if token == "#":
            end = text.find("\n", pos)
            pos = n if end < 0 else end
        elif token in ('"""', "'''", '"', "'"):
            pos = _string_end(text, pos, token)
        elif token in "[{":
            depth += 1
            parts = 0
            if depth > MAX_TOML_NESTING:
                raise error(
                    f"{label}: arrays or tables nested more than {MAX_TOML_NESTING} deep (line "
                    f"{text.count(chr(10), 0, i) + 1}); a preset nests 3 deep"
                )
        elif token in "]}":
            depth = max(0, depth - 1)
            parts = 0
        elif token == ".":
            parts += 1
            if parts >= MAX_KEY_PARTS:
                raise error(
                    f"{label}: a dotted key of more than {MAX_KEY_PARTS} parts (line "
                    f"{text.count(chr(10), 0, i) + 1})"
                )
        else:  # = , newline
            parts = 0


def _string_end(text: str, pos: int, quote: str) -> int:
    """Where the string that `quote` opened just before `pos` ends (past its closing quotes).
    Basic strings (") take backslash escapes, literal ones (') none; single-line ones end at
    the line's end at the latest (tomllib refuses them there)."""
    multiline = len(quote) == 3
    while True:
        end = text.find(quote, pos)
        stop = len(text) if multiline else text.find("\n", pos)
        stop = len(text) if stop < 0 else stop
        if end < 0 or end > stop:
            return stop
        slashes = 0
        while quote[0] == '"' and end - slashes > pos and text[end - slashes - 1] == "\\":
            slashes += 1
        if slashes % 2:  # an escaped quote
            pos = end + 1
            continue
        end += len(quote)
        extra = 0
        while multiline and extra < 2 and end < len(text) and text[end] == quote[0]:
            end += 1  # up to two quotes of the content before the closing three
            extra += 1
        return end


def load_toml(label: str, text: str, error: type[CarfeelError] = PresetError) -> dict[str, Any]:
    """TOML text as a dict within the limits above; `error` (exit code 2) for anything else."""
    check_toml_limits(label, text, error)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{label}: not valid TOML: {exc}") from None
    except (RecursionError, ValueError) as exc:  # a 5000-digit integer raises ValueError
        raise error(f"{label}: not TOML this reader takes: {str(exc)[:200]}") from None


def resolve(kind: str, name_or_path: str) -> tuple[str, str]:
    """Find a preset by shipped name or file path; return (label, TOML text)."""
    path = Path(name_or_path)
    looks_like_path = path.suffix == ".toml" or "/" in name_or_path or "\\" in name_or_path
    if looks_like_path or path.is_file():
        try:
            return str(path), read_limited(path, "preset file")
        except FileNotFoundError:
            raise PresetError(
                f"preset file {path} not found; give an existing TOML file or one of the "
                f"{kind} presets: {', '.join(available(kind))}"
            ) from None
    shipped = resources.files("carfeel.presets").joinpath(kind, f"{name_or_path}.toml")
    if len(name_or_path) > MAX_NAME_CHARS or not shipped.is_file():
        raise PresetError(
            f"no {kind} preset named {name_or_path[:MAX_NAME_CHARS]!r}; the shipped ones are: "
            f"{', '.join(available(kind))} (or give the path of a .toml file)"
        )
    return name_or_path, shipped.read_text(encoding="utf-8")


def parse(label: str, text: str) -> dict[str, Any]:
    return load_toml(f"preset {label}", text)


KIND_TABLES = {
    "shift": ("gearbox",),
    "steering": ("vehicle", "torque"),
    "hpattern": ("layout", "select", "walls"),
    "sequential": ("lever",),
    "prnd": ("selector",),
}
"""The tables that tell the kinds apart (a shift and a steering preset both have [driver])."""


def _kind_mismatch(kind: str, label: str, data: Mapping[str, Any]) -> None:
    """Say what a preset of another kind is, instead of listing every key it lacks."""
    own = KIND_TABLES[kind]
    if any(t in data for t in own):
        return
    for other, tables in KIND_TABLES.items():
        found = [t for t in tables if t in data]
        if other != kind and found:
            article = "an" if other[0] in "aeiouh" else "a"
            raise PresetError(
                f"preset {label} is {article} {other} preset (it has "
                f"{', '.join(f'[{t}]' for t in found)}), not a {kind} one: give a {kind} preset "
                f"({', '.join(available(kind))}, or a file with "
                f"{', '.join(f'[{t}]' for t in own)})"
            )


def _report(label: str, problems: list[str]) -> PresetError:
    shown = problems[:MAX_PROBLEMS]
    more = [f"... and {len(problems) - len(shown)} more"] if len(problems) > len(shown) else []
    return PresetError(f"preset {label} is not valid:\n  " + "\n  ".join([*shown, *more]))


def _text_fields(data: Mapping[str, Any], keys: tuple[str, ...], problems: list[str]) -> None:
    """`name`, `source` (and `engagement`): non-empty strings of a bounded length."""
    for key in keys:
        value = data.get(key)
        if not isinstance(value, str) or not value.strip():
            problems.append(f"{key}: missing; expected a string (where the numbers come from)")
            continue
        limit = MAX_SOURCE_CHARS if key == "source" else MAX_NAME_CHARS
        if len(value) > limit:
            problems.append(f"{key}: {len(value)} characters; at most {limit}")


_MISSING = object()


def build(cls: type[T], table: Mapping[str, Any], where: str, problems: list[str]) -> T | None:
    """Build a parameter dataclass from a TOML table, appending each problem to `problems`."""
    hints = type_hints(cls)
    fields = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    for key in table:
        if key not in fields:
            problems.append(
                f"{where}{key}: unknown parameter; {where.rstrip('.') or 'this table'} takes "
                f"{', '.join(fields)}"
            )
    values: dict[str, Any] = {}
    optional = {
        f.name
        for f in dataclasses.fields(cls)  # type: ignore[arg-type]
        if f.default is not dataclasses.MISSING
    }
    for name in fields:
        kind = optional_of(hints[name])
        full = f"{where}{name}"
        if name not in table and name in optional:
            continue
        if name not in table:
            problems.append(f"{full}: missing; expected {_expected(full, kind)}")
            continue
        value = _convert(kind, table[name], full, problems)
        if value is not _MISSING:
            values[name] = value
    if len(values) < len(fields) - len(optional & (set(fields) - set(table))):
        return None
    return cls(**values)


def _convert(kind: Any, value: Any, full: str, problems: list[str]) -> Any:
    """One TOML value as the parameter type `kind`; _MISSING (and a problem) if it is not one."""
    if dataclasses.is_dataclass(kind):
        if not isinstance(value, dict):
            problems.append(f"{full}: expected a table [{full}], got {value!r}")
            return _MISSING
        built = build(kind, value, f"{full}.", problems)  # type: ignore[arg-type]
        return _MISSING if built is None else built
    if typing.get_origin(kind) is tuple:
        item = typing.get_args(kind)[0]
        if not isinstance(value, list):
            problems.append(f"{full} = {value!r}: expected a list, {_expected(full, kind)}")
            return _MISSING
        items = [_convert(item, v, f"{full}[{i}]", problems) for i, v in enumerate(value)]
        return _MISSING if any(v is _MISSING for v in items) else tuple(items)
    if kind is str:
        if not isinstance(value, str) or not value:
            problems.append(f"{full} = {value!r}: expected a non-empty string")
            return _MISSING
        return value
    if kind in (bool, int, float):
        problem = number_problem(full, kind, value)
        if problem is not None:
            problems.append(problem)
            return _MISSING
        return float(value) if kind is float else value
    raise TypeError(f"{full}: a parameter type this loader was not taught: {kind}")


def _expected(full: str, kind: Any) -> str:
    if dataclasses.is_dataclass(kind):
        return "a table"
    if typing.get_origin(kind) is tuple:
        return "a list"
    return expected_value(full, kind)


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
    f_ref = g.synchronization_force_N
    if 0.0 < f_ref <= g.hold_force_N:
        problems.append(
            f"gearbox.synchronization_force_N = {f_ref:g} N must exceed the force that pushes the "
            f"sleeve back at the ring ({g.hold_force_N:.3g} N, gearbox.hold_force_N), or 0 for "
            "the paper's timer whatever the push"
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
    # The tyres' lag at the slowest speed the tyre model runs: the trapezoidal rule rings on
    # modes much faster than its step, so they must stay slower than a millisecond.
    lateral = (
        v.mass_kg
        * v.kinematic_speed_m_s
        / (v.front_cornering_stiffness_N_rad + v.rear_cornering_stiffness_N_rad)
    )
    yaw = (
        v.yaw_inertia_kg_m2
        * v.kinematic_speed_m_s
        / (
            v.cg_to_front_axle_m**2 * v.front_cornering_stiffness_N_rad
            + v.cg_to_rear_axle_m**2 * v.rear_cornering_stiffness_N_rad
        )
        if v.cg_to_front_axle_m < v.wheelbase_m
        else 1.0
    )
    if min(lateral, yaw) < 1e-3:
        problems.append(
            f"at vehicle.kinematic_speed_m_s = {v.kinematic_speed_m_s:g} m/s the tyres' time "
            f"constant is {min(lateral, yaw) * 1e3:.3g} ms, under the 1 ms the model steps with; "
            "raise kinematic_speed_m_s or check the mass, inertia and cornering stiffnesses"
        )
    if (car.tyres is None) != (car.steering_system is None):
        problems.append(
            "the physical steering model needs both tables [tyres] and [steering_system] (or "
            "neither: the car then runs the paper's law only)"
        )
    elif car.steering_system is not None:
        problems.extend(_check_steering_system(car.steering_system))
    return problems


STEERING_STEP_S = 1e-3
"""The step the physical steering model must be accurate at (the 1 kHz loop)."""

CHECKED_SPEED_M_S = 100.0
"""The speed (360 km/h) up to which the EPS damping's rise with speed is checked at that step."""


def _check_steering_system(s: Any) -> list[str]:
    """Its semi-implicit Euler step must resolve the stiffest and most damped modes at 1 ms."""
    problems = []
    h = STEERING_STEP_S
    stiff = s.stop_stiffness_Nm_rad + s.torsion_bar_stiffness_Nm_rad + s.friction_stiffness_Nm_rad
    for name, inertia, stiffness, damping in (
        ("rack_inertia_kg_m2", s.rack_inertia_kg_m2, stiff,
         s.compensation_damping_Nm_s_rad + s.rack_damping_Nm_s_rad + s.stop_damping_Nm_s_rad
         + max(s.eps_damping_Nm_s_rad, s.eps_damping_high_speed_Nm_s_rad)
         + s.eps_damping_rise_Nm_s3_rad_m2 * CHECKED_SPEED_M_S**2
         + s.presliding_damping_Nm_s_rad),
        ("hand_wheel_inertia_kg_m2", s.hand_wheel_inertia_kg_m2,
         s.torsion_bar_stiffness_Nm_rad + s.friction_stiffness_Nm_rad,
         s.compensation_damping_Nm_s_rad + s.presliding_damping_Nm_s_rad),
    ):  # fmt: skip
        if math.sqrt(stiffness / inertia) * h > 0.5 or damping * h / inertia > 0.5:
            problems.append(
                f"steering_system.{name} = {inertia:g} kg*m^2 is too light for its springs "
                f"({stiffness:g} Nm/rad) and dampers ({damping:g} Nm*s/rad) at 1 ms steps: "
                "w*h and c*h/J must stay under 0.5; raise the inertia or soften the springs"
            )
    return problems


_KINDS: dict[str, tuple[type[Any], tuple[str, ...], Callable[[Any], list[str]]]] = {
    "shift": (ShiftParams, ("gearbox", "driver"), check_shift),
    "steering": (
        SteeringCar,
        ("vehicle", "torque", "driver", "tyres", "steering_system"),
        check_steering,
    ),
    "sequential": (SequentialSetup, ("lever", "driver"), lambda setup: []),
    "prnd": (PrndSetup, ("selector", "driver"), lambda setup: []),
}


def load_shift(name_or_path: str = "paper-first-gear") -> Preset[ShiftParams]:
    """Load and validate a shift preset by shipped name or path."""
    preset: Preset[ShiftParams] = load("shift", name_or_path)
    return preset


def load_steering(name_or_path: str = "b-segment") -> Preset[SteeringCar]:
    """Load and validate a steering (car) preset by shipped name or path."""
    preset: Preset[SteeringCar] = load("steering", name_or_path)
    return preset


def load(kind: str, name_or_path: str) -> Any:
    """A preset of any kind by shipped name or path."""
    if kind == "hpattern":
        return load_hpattern(name_or_path)
    if kind in ("sequential", "prnd"):
        return _load_checked(kind, name_or_path)
    label, text = resolve(kind, name_or_path)
    return from_toml(kind, label, text)


def from_toml(kind: str, label: str, text: str) -> Preset[Any]:
    """Parse and validate a preset of `kind`; every problem is reported in one PresetError."""
    cls, tables_of_kind, check = _KINDS[kind]
    data = parse(label, text)
    _kind_mismatch(kind, label, data)
    problems: list[str] = []
    allowed = ("name", "source", *tables_of_kind)
    for key in data:
        if key not in allowed:
            problems.append(f"{key[:80]}: unknown key; a {kind} preset has {', '.join(allowed)}")
    _text_fields(data, ("name", "source"), problems)
    tables: dict[str, Any] = {k: data[k] for k in tables_of_kind if k in data}
    params = build(cls, tables, "", problems)
    if params is not None and not problems:
        problems.extend(check(params))
    if problems or params is None:
        raise _report(label, problems)
    return Preset(data["name"], data["source"], params)


def load_sequential(name_or_path: str = "rally-6") -> Preset[SequentialSetup]:
    """Load a sequential lever preset; the lever's own checks (raised as it is built) are
    reported with the preset's label."""
    preset: Preset[SequentialSetup] = _load_checked("sequential", name_or_path)
    return preset


def _load_checked(kind: str, name_or_path: str) -> Preset[Any]:
    """A preset whose model checks itself as it is built (a PresetError without the label),
    reported with the preset's label."""
    label, text = resolve(kind, name_or_path)
    try:
        preset: Preset[Any] = from_toml(kind, label, text)
    except PresetError as exc:
        if str(exc).startswith("preset "):
            raise
        raise _report(label, [str(exc)]) from None
    return preset


def load_prnd(name_or_path: str = "automatic") -> Preset[PrndSetup]:
    """Load a PRND selector preset (its checks reported with the preset's label)."""
    preset: Preset[PrndSetup] = _load_checked("prnd", name_or_path)
    return preset


def shift_from_toml(label: str, text: str) -> Preset[ShiftParams]:
    return from_toml("shift", label, text)


@dataclass(frozen=True, slots=True)
class HPatternPreset:
    """An H-pattern gearbox: its layout and select axis, and the shift preset of its slots."""

    name: str
    source: str
    engagement: str
    """The shift preset every slot's engagement (and the driver's hand) comes from."""
    shift: ShiftParams
    setup: HPatternSetup

    def pattern(self, physics: bool | None = None) -> HPatternParams:
        """The model's parameters; `physics` overrides the preset's synchronizer mode."""
        sync = self.setup.synchronizer
        if physics is not None and physics != sync.physics:
            sync = dataclasses.replace(sync, physics=physics)
        return HPatternParams(
            self.setup.layout,
            self.shift.gearbox,
            self.setup.select,
            self.setup.walls,
            sync,
            self.setup.feel,
        )


NOMINAL_RATE_HZ = 1000.0
"""Rate at which the walls must stay passive when a device renders them (the paper's 1 kHz)."""


def check_hpattern(setup: HPatternSetup, shift: ShiftParams) -> list[str]:
    """Problems of an H-pattern preset across parameters (each field already in range)."""
    layout, problems = setup.layout, []
    planes = layout.planes_y_m
    if not planes:
        return ["layout.planes_y_m is empty; give the y of each plane, m"]
    for a, b in itertools.pairwise(planes):
        if not b > a:
            problems.append(f"layout.planes_y_m must increase: {a:g} m then {b:g} m")
        elif b - a <= layout.slot_width_m:
            problems.append(
                f"layout: planes at {a:g} m and {b:g} m are closer than the slot width "
                f"{layout.slot_width_m:g} m: their slots overlap"
            )
    last = len(planes) - 1
    if layout.centre_plane > last:
        problems.append(
            f"layout.centre_plane = {layout.centre_plane}: the layout has planes 0..{last}"
        )
    seen: dict[tuple[int, int], str] = {}
    names: set[str] = set()
    for gear in layout.gears:
        if gear.name in names:
            problems.append(f"layout.gears: gear {gear.name!r} appears twice")
        names.add(gear.name)
        if gear.name == "N":
            problems.append("layout.gears: 'N' is neutral, not a gear name")
        if gear.direction not in (-1, 1):
            problems.append(
                f"layout.gears: gear {gear.name} has direction = {gear.direction}; "
                "allowed 1 (forward) or -1 (back)"
            )
        if gear.plane > last:
            problems.append(
                f"layout.gears: gear {gear.name} is on plane {gear.plane}, but the layout has "
                f"planes 0..{last}: no such plane"
            )
        where = (gear.plane, gear.direction)
        if where in seen:
            problems.append(
                f"layout.gears: gears {seen[where]} and {gear.name} share a slot (plane "
                f"{gear.plane}, direction {gear.direction}): slots overlap"
            )
        seen[where] = gear.name
        if gear.synchronizer not in LOCATIONS:
            problems.append(
                f"layout.gears: gear {gear.name} has synchronizer = {gear.synchronizer!r}; "
                f"allowed {', '.join(repr(x) for x in LOCATIONS)} (the shaft it sits on, or none)"
            )
        if gear.ratio == 0.0 or (gear.name == "R") != (gear.ratio < 0.0):
            problems.append(
                f"layout.gears: gear {gear.name} has ratio {gear.ratio:g}; reverse takes a "
                "negative ratio, forward gears a positive one"
            )
    if not layout.gears:
        problems.append("layout.gears is empty; give at least one [[layout.gears]]")
    if layout.reverse_lockout_N > 0.0:
        reverse = [g for g in layout.gears if g.name == "R"]
        shared = reverse and any(
            g.plane == reverse[0].plane and g.name != "R" for g in layout.gears
        )
        if not reverse or shared or reverse[0].plane not in (0, last) or last == 0:
            problems.append(
                f"layout.reverse_lockout_N = {layout.reverse_lockout_N:g} N needs reverse alone "
                "on an outer plane (as 6+R with R beyond 6); set it to 0 for this layout"
            )
    problems += _check_truck(layout) + _check_double_h(layout)
    g = shift.gearbox
    if layout.corridor_width_m / 2 + WALL_DEPTH_M >= g.synchronization_position_m:
        problems.append(
            f"layout.corridor_width_m = {layout.corridor_width_m:g} m: half of it, plus the "
            f"{WALL_DEPTH_M:g} m a wall gives, must stay short of the synchro ring at "
            f"{g.synchronization_position_m:g} m"
        )
    # The driver must be able to hold the farthest plane against the select spring (and the
    # lockout), with a fifth to spare for friction and the detents.
    if 0 <= layout.centre_plane <= last:
        centre = planes[layout.centre_plane]
        reach = max(abs(p - centre) for p in planes)
        boundary = layout.range_boundary_m() if 0 < layout.range_plane <= last else math.inf
        high = planes[min(layout.high_centre_plane, last)]
        if boundary < math.inf:  # a double-H: each half from its own neutral
            reach = max(abs(p - (centre if p < boundary else high)) for p in planes)
        needed = setup.select.centring_stiffness_N_m * reach + setup.select.static_friction_N
        lock = layout.lockout_plane if last > 0 else None
        if lock is not None:
            neighbour = lock - 1 if lock > 0 else lock + 1
            half_gap = abs(planes[lock] - planes[neighbour]) / 2
            needed += layout.reverse_lockout_N + setup.select.lockout_stiffness_N_m * half_gap
        if setup.driver.select_force_N < 1.2 * needed:
            problems.append(
                f"driver.select_force_N = {setup.driver.select_force_N:g} N cannot hold the "
                f"farthest plane: the select spring{' and the lockout' if lock is not None else ''}"
                f" need {needed:.1f} N there (with a fifth to spare: {1.2 * needed:.1f} N)"
            )
        if boundary < math.inf:
            cross = (
                layout.range_detent_N
                + setup.select.centring_stiffness_N_m * abs(boundary - centre)
                + setup.select.static_friction_N
            )
            if setup.driver.select_force_N < 1.2 * cross:
                problems.append(
                    f"driver.select_force_N = {setup.driver.select_force_N:g} N cannot cross "
                    f"the range detent: it and the select spring need {cross:.1f} N there "
                    f"(with a fifth to spare: {1.2 * cross:.1f} N)"
                )
            if not math.isclose(boundary - centre, high - boundary, abs_tol=1e-6):
                problems.append(
                    f"layout: the double-H's neutrals lie {1e3 * (boundary - centre):g} mm and "
                    f"{1e3 * (high - boundary):g} mm from the range detent; they must be equally "
                    "far (else the select spring's energy jumps as the knob crosses)"
                )
    feel = setup.feel
    first, last_latch = (
        feel.latch_position_m - feel.latch_width_m,
        feel.latch_position_m + feel.latch_width_m,
    )
    if not (layout.corridor_width_m / 2 < first and last_latch < g.synchronization_position_m):
        problems.append(
            f"feel.latch_position_m = {feel.latch_position_m:g} m +- latch_width_m = "
            f"{feel.latch_width_m:g} m must lie in the slot before the synchro ring: between "
            f"{layout.corridor_width_m / 2:g} m and {g.synchronization_position_m:g} m"
        )
    spacing = min((b - a for a, b in itertools.pairwise(planes)), default=math.inf)
    if setup.select.detent_width_m >= spacing / 2:
        problems.append(
            f"select.detent_width_m = {setup.select.detent_width_m:g} m must be under half the "
            f"plane spacing ({spacing / 2:g} m)"
        )
    # Sampled-wall passivity (Colgate & Schenkel): K*T/2 + B < b, b the lever's own damping.
    period = 1.0 / NOMINAL_RATE_HZ
    lever_damping = min(
        [getattr(g, s).damping_N_s_m for s in ("neutral", "gate_open", "engagement",
                                                "free_travel", "returning")]
        + [setup.select.damping_N_s_m]
    )  # fmt: skip
    for label, k, b in (
        ("walls", setup.walls.stiffness_N_m, setup.walls.damping_N_s_m),
        ("select.slot", setup.select.slot_stiffness_N_m, setup.select.slot_damping_N_s_m),
    ):
        need = k * period / 2 + b
        if need >= lever_damping:
            problems.append(
                f"{label}: stiffness {k:g} N/m and damping {b:g} N*s/m need a lever damping "
                f"above K*T/2 + B = {need:g} N*s/m at {NOMINAL_RATE_HZ:g} Hz to stay passive "
                f"when rendered, but the lever's least damping is {lever_damping:g} N*s/m"
            )
    return problems


def _check_truck(layout: Layout) -> list[str]:
    """A range/splitter table: every row on a slot of the layout, each slot's combination once,
    the signs of its gear and ratio the slot's, one handle position per slot."""
    problems: list[str] = []
    slots = {g.name: g for g in layout.gears}
    seen: set[tuple[str, bool, bool]] = set()
    handles: dict[str, int] = {}
    for row in layout.truck:
        where = f"layout.truck: slot {row.slot!r} (range {'high' if row.range_high else 'low'}, "
        where += f"splitter {'high' if row.splitter_high else 'low'})"
        slot = slots.get(row.slot)
        if slot is None:
            problems.append(f"{where}: no such slot; the layout has {', '.join(slots)}")
            continue
        key = (row.slot, row.range_high, row.splitter_high)
        if key in seen:
            problems.append(f"{where} appears twice")
        seen.add(key)
        if (
            row.gear == 0
            or row.ratio == 0.0
            or (row.gear < 0) != (slot.ratio < 0.0)
            or (row.ratio < 0.0) != (slot.ratio < 0.0)
        ):
            problems.append(
                f"{where}: gear {row.gear}, ratio {row.ratio:g}: a reverse slot takes a "
                "negative gear and ratio, a forward slot positive ones"
            )
        if handles.setdefault(row.slot, row.handle_position) != row.handle_position:
            problems.append(
                f"{where}: handle_position {row.handle_position}, but another row of the slot "
                f"has {handles[row.slot]}: one handle position per slot"
            )
    missing = [name for name in slots if layout.truck and name not in handles]
    if missing:
        problems.append(f"layout.truck: no row for slot {', '.join(missing)}: the lever could "
                        "not engage it in any range")  # fmt: skip
    return problems


def _check_double_h(layout: Layout) -> list[str]:
    """A double-H: the high half's first plane, its neutral in it, the low neutral below it."""
    last = len(layout.planes_y_m) - 1
    if layout.range_plane == 0:
        if layout.range_detent_N > 0.0 or layout.high_centre_plane:
            return ["layout.range_detent_N and high_centre_plane need layout.range_plane (the "
                    "first plane of a double-H's high half)"]  # fmt: skip
        return []
    if not 0 < layout.range_plane <= last:
        return [f"layout.range_plane = {layout.range_plane}: a double-H's high half starts on "
                f"plane 1..{last}"]  # fmt: skip
    problems = []
    if not layout.range_plane <= layout.high_centre_plane <= last:
        problems.append(
            f"layout.high_centre_plane = {layout.high_centre_plane}: the high half's neutral "
            f"is one of its planes, {layout.range_plane}..{last}"
        )
    if layout.centre_plane >= layout.range_plane:
        problems.append(
            f"layout.centre_plane = {layout.centre_plane}: the low half's neutral is one of "
            f"its planes, 0..{layout.range_plane - 1}"
        )
    return problems


def load_hpattern(name_or_path: str = "5r") -> HPatternPreset:
    """Load and validate an H-pattern (layout) preset by shipped name or path."""
    label, text = resolve("hpattern", name_or_path)
    data = parse(label, text)
    _kind_mismatch("hpattern", label, data)
    problems: list[str] = []
    allowed = ("name", "source", "engagement", "layout", "select", "walls", "synchronizer",
               "feel", "driver")  # fmt: skip
    for key in data:
        if key not in allowed:
            problems.append(f"{key[:80]}: unknown key; an hpattern preset has {', '.join(allowed)}")
    _text_fields(data, ("name", "source", "engagement"), problems)
    tables: dict[str, Any] = {k: data[k] for k in allowed[3:] if k in data}
    setup = build(HPatternSetup, tables, "", problems)
    if problems or setup is None:
        raise _report(label, problems)
    reference = data["engagement"]
    if (reference.endswith(".toml") or "/" in reference) and not Path(reference).is_absolute():
        base = Path(label).parent if Path(label).suffix == ".toml" else Path(".")
        reference = str(base / reference)
    shift = load_shift(reference)
    problems = check_hpattern(setup, shift.params)
    if problems:
        raise _report(label, problems)
    return HPatternPreset(data["name"], data["source"], data["engagement"], shift.params, setup)


def to_toml(
    name: str, source: str, tables: Mapping[str, Any], extra: Mapping[str, str] | None = None
) -> str:
    """A preset's TOML text, written by tomli-w (so a name, source or path holding backslashes,
    quotes or newlines is escaped as TOML wants): `name`, `source`, the string keys of `extra`,
    then one table per dataclass of `tables` (nested dataclasses as sub-tables, tuples of them
    as arrays of tables). Loading it back with the matching loader gives the same parameters
    and the same strings (the source less its leading and trailing newlines)."""
    import tomli_w

    document: dict[str, Any] = {"name": name, "source": source.strip("\n")}
    document.update(extra or {})
    texts = [v for v in document.values() if isinstance(v, str)]
    for key, value in tables.items():
        document[key] = _toml_table(value)
    # Multi-line strings read best, but a TOML reader turns their CR LF into LF: a text with a
    # CR is written on one line, its newlines escaped, so that it comes back as it was.
    multiline = not any("\r" in t for t in texts)
    return tomli_w.dumps(document, multiline_strings=multiline)


def _toml_value(value: Any) -> Any:
    if isinstance(value, bool | str):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):  # float, and numpy scalars a fit may leave behind
        return float(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _toml_table(value)
    if isinstance(value, tuple | list):
        return [_toml_value(v) for v in value]
    raise TypeError(f"no TOML form for {value!r}")


def _toml_table(value: Any) -> dict[str, Any]:
    return {f.name: _toml_value(getattr(value, f.name)) for f in dataclasses.fields(value)}
