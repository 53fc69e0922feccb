"""Presets: TOML files in SI units, loaded and validated once at the boundary.

Read within limits (`carfeel.io.tomlread`), each value checked against the parameter schema
(`carfeel.schema`: type, range, unit), then the kind's cross-checks (`carfeel.io.preset_checks`).

A preset names its parameters exactly as the parameter dataclasses do; the unit is the name's
suffix (`mass_kg`, `stiffness_N_m`). Every key is required unless its field has a default, no
other key is allowed, and each value must lie in its physical range. All problems are reported
together in one PresetError, each naming the parameter, the value, the unit and the range.
"""

from __future__ import annotations

import dataclasses
import numbers
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, Generic, TypeVar

from carfeel.errors import PresetError
from carfeel.io.preset_checks import (
    STEERING_STEP_S,
    check_hpattern,
    check_shift,
    check_steering,
)
from carfeel.io.tomlread import check_toml_limits, load_toml, read_limited
from carfeel.models.gearshift.hpattern import HPatternParams
from carfeel.schema import expected_value, number_problem, optional_of, type_hints
from carfeel.simulation.hpattern import HPatternSetup
from carfeel.simulation.prnd import PrndSetup
from carfeel.simulation.sequential import SequentialSetup
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import SteeringCar

__all__ = [
    "DEFAULT_PRESETS",
    "MAX_NAME_CHARS",
    "MAX_SOURCE_CHARS",
    "PRESET_KINDS",
    "STEERING_STEP_S",
    "HPatternPreset",
    "Preset",
    "available",
    "build",
    "check_hpattern",
    "check_shift",
    "check_steering",
    "check_toml_limits",
    "from_toml",
    "load",
    "load_hpattern",
    "load_prnd",
    "load_sequential",
    "load_shift",
    "load_steering",
    "load_toml",
    "parse",
    "read_limited",
    "resolve",
    "shift_from_toml",
    "to_toml",
]

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


MAX_NAME_CHARS = 1000
"""A preset's name (and engagement) is a label: bounded, and the same bound the FMU carries (a
hostile name of a few hundred characters must still be data an FMU can hold, issue 24)."""
MAX_SOURCE_CHARS = 64 * 1024
MAX_PROBLEMS = 40
"""Problems listed in one error (a file of 100k unknown keys gives a readable message)."""


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
