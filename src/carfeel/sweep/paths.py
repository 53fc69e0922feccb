"""Key paths into a model's preset parameters (`gearbox.stop.stiffness_N_m`,
`layout.gears[2].ratio`, an H-pattern's engagement under `shift.`) and run settings
(`run.speed_kmh`): the field a path names, and what is wrong with a value there (its type and
range: `carfeel.schema.number_problem`, the preset loader's own check)."""

from __future__ import annotations

import dataclasses
import math
import re
import typing
from typing import Any

from carfeel import schema
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import SteeringCar
from carfeel.sweep.base import HPatternCase
from carfeel.sweep.definition import Value
from carfeel.sweep.settings import RUN_KEYS, RUN_RANGES


def _root_type(model: str) -> type[Any]:
    return {"shift": ShiftParams, "steering": SteeringCar, "hpattern": HPatternCase}[model]


SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[([0-9]{1,6})\])?")
"""One segment of a key path: a field name, or a list's field with its index (`gears[2]`).
Always `fullmatch`: `$` would match before a trailing newline."""


def field_type(model: str, base: Any, path: str) -> tuple[Any, Any]:
    """(type, value in the preset) of the field at a key path; SpecError-free: raises KeyError
    with the reason."""
    if path.startswith("run."):
        name = path[4:]
        if name not in RUN_RANGES or name not in RUN_KEYS[model]:
            varied = [f"run.{k}" for k in RUN_RANGES if k in RUN_KEYS[model]]
            raise KeyError(
                f"the {model} sweep varies these run settings: {', '.join(varied) or 'none'}"
            )
        return float, None
    kind: Any = _root_type(model)
    value = base
    walked: list[str] = []
    for part in path.split("."):
        match = SEGMENT.fullmatch(part)
        if match is None:
            raise KeyError(f"{part!r} is not a field name")
        name, index = match.group(1), match.group(2)
        kind = schema.optional_of(kind)
        if not dataclasses.is_dataclass(kind):
            raise KeyError(f"{'.'.join(walked)} is a value, not a table")
        hints = schema.type_hints(typing.cast(type, kind))
        if name not in hints:
            where = ".".join(walked) or "the preset"
            fields = ", ".join(hints)
            raise KeyError(f"{where} has no {name!r}; it has {fields}")
        kind = hints[name]
        value = getattr(value, name) if value is not None else None
        walked.append(part)
        if value is None and index is None and schema.optional_of(kind) is not kind:
            raise KeyError(f"the preset has no [{'.'.join(walked)}] table")
        if index is not None:
            if typing.get_origin(kind) is not tuple:
                raise KeyError(f"{name} is not a list; drop [{index}]")
            kind = typing.get_args(kind)[0]
            assert value is not None  # a tuple field of the preset
            if int(index) >= len(value):
                raise KeyError(f"{name} has {len(value)} entries (0..{len(value) - 1})")
            value = value[int(index)]
    kind = schema.optional_of(kind)
    if dataclasses.is_dataclass(kind) or typing.get_origin(kind) is tuple or kind is str:
        raise KeyError("it is a table, a list or a name; address a number inside it")
    return kind, value


_KINDS: dict[tuple[str, int, str], tuple[Any, Any]] = {}


def _kind(model: str, base: Any, path: str) -> Any:
    """`field_type`'s type, kept per preset and path (the entry holds its preset: an id is
    never another preset's while it is kept)."""
    key = (model, id(base), path)
    entry = _KINDS.get(key)
    if entry is None or entry[0] is not base:
        if len(_KINDS) > 4096:
            _KINDS.clear()
        entry = _KINDS[key] = (base, field_type(model, base, path)[0])
    return entry[1]


def _range_text(path: str) -> str:
    if path.startswith("run."):
        low, high = RUN_RANGES[path[4:]]
        return f"{low:g} <= value <= {high:g}"
    allowed = schema.range_of(path)
    return allowed.text(schema.unit_of(path.split(".")[-1])) if allowed else "any number"


def value_problem(
    model: str, base: Any, path: str, value: Value, kinds: bool = False
) -> str | None:
    """What is wrong with `value` at `path` (its type, its range), or None. `kinds`: the
    field's type looked up once per preset and path (a sweep's cases all ask the same)."""
    try:
        kind = _kind(model, base, path) if kinds else field_type(model, base, path)[0]
    except KeyError as exc:
        return f"{path}: unknown parameter: {exc.args[0]}"
    if not path.startswith("run."):
        return schema.number_problem(path, kind, value, whole_floats=True)
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{path} = {value!r}: expected a number with {_range_text(path)}"
    low, high = RUN_RANGES[path[4:]]
    if not (math.isfinite(float(value)) and low <= float(value) <= high):
        return f"{path} = {float(value):g} is out of range: allowed {_range_text(path)}"
    return None
