"""The tables of a sweep spec read into checked values: `seeds`, `[set]` (key path = value)
and `[vary]` (key path = a grid of values or a distribution), each problem named with its fix.
What the values mean to the preset is checked in `carfeel.sweep.checks`."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from carfeel.sweep.definition import DISTRIBUTIONS, MAX_CASES, Value, Vary


def read_seeds(value: Any, problems: list[str]) -> Sequence[int]:
    """The seeds: `seeds = n` as range(n), a list as a tuple."""
    if isinstance(value, int) and not isinstance(value, bool) and value > MAX_CASES:
        problems.append(
            f"seeds = {value:.3g}: at most {MAX_CASES:.0e} cases in a sweep, seeds included; "
            "fewer seeds"
        )
        return range(1)
    if isinstance(value, int) and not isinstance(value, bool) and value >= 1:
        return range(value)  # not a tuple: 10^8 seeds were 4 GB before they were counted
    if (
        isinstance(value, list)
        and value
        and all(isinstance(s, int) and not isinstance(s, bool) for s in value)
        and len(set(value)) == len(value)
    ):
        return tuple(value)
    problems.append(
        f"seeds = {said(value)}: expected how many seeds (a whole number >= 1: seeds 0..n-1) "
        "or a list of distinct whole numbers"
    )
    return (0,)


def said(value: Any) -> str:
    """A spec's value as a message quotes it: at most 60 characters of it."""
    text = repr(value) if not isinstance(value, list | str) or len(value) < 50 else (
        f"a {type(value).__name__} of {len(value)} items"
    )  # fmt: skip
    return text if len(text) <= 60 else f"{text[:48]}...{text[-9:]}"


def _flatten(table: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    """(key path, value) of a table's leaves; a [vary] entry (values or distribution) is one."""
    out = []
    for key, value in table.items():
        path = f"{prefix}{key}"
        if isinstance(value, dict) and not ({"values", "distribution"} & set(value)):
            out.extend(_flatten(value, f"{path}."))
        else:
            out.append((path, value))
    return out


def read_assignments(table: Any, where: str, problems: list[str]) -> list[tuple[str, Value]]:
    """(key path, value) of a table like [set]: numbers or true/false."""
    if not isinstance(table, dict):
        problems.append(f"{where} = {table!r}: expected a table [{where}] of key path = value")
        return []
    out = []
    for path, value in _flatten(table):
        if isinstance(value, bool | int | float):
            out.append((path, value))
        else:
            problems.append(f"[{where}] {path} = {value!r}: expected a number or true/false")
    return out


def read_vary(table: Any, problems: list[str]) -> list[Vary]:
    """The varied parameters of [vary], in the spec's order."""
    if not isinstance(table, dict):
        problems.append(
            f"vary = {table!r}: expected a table [vary] of key path = "
            "{ values = [...] } or { distribution = ... }"
        )
        return []
    out: list[Vary] = []
    for path, entry in _flatten(table):
        hint = (
            f'"{path}" = {{ values = [a, b, c] }} or {{ distribution = "uniform", low = a, '
            "high = b }"
        )
        if not isinstance(entry, dict):
            problems.append(f"[vary] {path} = {entry!r}: expected {hint}")
            continue
        read = _grid if "values" in entry else _distribution
        varied = read(path, entry, problems)
        if varied is not None:
            out.append(varied)
    return out


def _grid(path: str, entry: Mapping[str, Any], problems: list[str]) -> Vary | None:
    """A `{ values = [...] }` entry of [vary]."""
    values = entry["values"]
    extra = set(entry) - {"values"}
    if extra:
        problems.append(f"[vary] {path}: {', '.join(sorted(extra))}: a grid takes only values")
    if (
        not isinstance(values, list)
        or not values
        or not all(isinstance(x, bool | int | float) for x in values)
    ):
        problems.append(
            f"[vary] {path}: values = {values!r}: expected a non-empty list "
            "of numbers (or true/false)"
        )
        return None
    if len(set(values)) != len(values):
        problems.append(f"[vary] {path}: values = {values!r} repeats a value")
    return Vary(path, values=tuple(values))


def _distribution(path: str, entry: Mapping[str, Any], problems: list[str]) -> Vary | None:
    """A `{ distribution = ... }` entry of [vary]."""
    name = entry.get("distribution")
    if name not in DISTRIBUTIONS:
        problems.append(
            f"[vary] {path}: distribution = {name!r}: expected one of "
            + ", ".join(f"{d} ({', '.join(a)})" for d, a in DISTRIBUTIONS.items())
        )
        return None
    names = DISTRIBUTIONS[name]
    extra = set(entry) - {"distribution", *names}
    missing = [a for a in names if a not in entry]
    if extra or missing:
        problems.append(
            f"[vary] {path}: a {name} distribution takes {', '.join(names)}"
            + (f"; unknown {', '.join(sorted(extra))}" if extra else "")
            + (f"; missing {', '.join(missing)}" if missing else "")
        )
        return None
    args = [entry[a] for a in names]
    if not all(isinstance(a, int | float) and not isinstance(a, bool) for a in args) or not all(
        math.isfinite(a) for a in args
    ):
        problems.append(
            f"[vary] {path}: {name} arguments must be finite numbers, got "
            f"{dict(zip(names, args, strict=True))}"
        )
        return None
    return Vary(path, distribution=name, args=tuple(float(a) for a in args))
