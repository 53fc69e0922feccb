"""A sweep's cases (a parameter set and a seed, numbered from 0) made as they are asked for, and
one case's parameters: its values set into the preset by key path, then the preset's checks."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from typing import Any

from carfeel.io import presets
from carfeel.sweep.definition import Case, SweepSpec, Value
from carfeel.sweep.draws import numbered_sets
from carfeel.sweep.paths import SEGMENT, value_problem


def iter_cases(spec: SweepSpec, start: int = 0, stop: int | None = None) -> Iterator[Case]:
    """The cases start..stop-1 of the sweep (parameter set x seed, numbered from 0; all of
    them by default), made as they are asked for (a sweep of 10^7 cases never holds them; a
    task of a worker makes its own)."""
    stop = spec.n_cases if stop is None else stop
    if not 0 <= start <= stop <= spec.n_cases:
        raise ValueError(f"cases {start}..{stop} of a sweep of {spec.n_cases}")
    n_seeds = len(spec.seeds)
    if start == stop:
        return
    for index, items in numbered_sets(spec, start // n_seeds, (stop - 1) // n_seeds + 1):
        for k in range(max(start - index * n_seeds, 0), min(stop - index * n_seeds, n_seeds)):
            yield Case(index * n_seeds + k, index, spec.seeds[k], items)


def cases(spec: SweepSpec) -> list[Case]:
    """Every case as a list (small sweeps, tests)."""
    return list(iter_cases(spec))


def apply(base: Any, values: Mapping[str, Value]) -> Any:
    """`base` with each key path (not `run.`) set to its value: one `dataclasses.replace` per
    table changed, with all of its changes (a path at a time replaced each table on the way
    once per path: half of a batched shift's time went to checking and applying its case)."""
    tree: dict[str, Any] = {}
    for path, value in values.items():
        if path.startswith("run."):
            continue
        node = tree
        *tables, leaf = path.split(".")
        for part in tables:
            node = node.setdefault(part, {})
        node[leaf] = value
    return _apply(base, tree) if tree else base


def _apply(obj: Any, tree: Mapping[str, Any]) -> Any:
    changes: dict[str, Any] = {}
    for part, change in tree.items():
        match = SEGMENT.fullmatch(part)
        assert match is not None  # checked by field_type
        name, index = match.group(1), match.group(2)
        current = changes.get(name, getattr(obj, name))
        if index is not None:
            items = list(current)
            i = int(index)
            items[i] = _apply(items[i], change) if isinstance(change, dict) else change
            changes[name] = tuple(items)
        elif isinstance(change, dict):
            changes[name] = _apply(current, change)
        else:
            kind = type(current)
            changes[name] = (
                kind(change) if kind in (int, float) and not isinstance(change, bool) else change
            )
    return dataclasses.replace(obj, **changes)


def case_problems(model: str, base: Any, values: Mapping[str, Value]) -> list[str]:
    """The preset validation of one case: each value's type and range, then the preset's
    cross-parameter checks on the changed parameters."""
    return checked_case(model, base, values)[1]


def checked_case(model: str, base: Any, values: Mapping[str, Value]) -> tuple[Any, list[str]]:
    """(the case's parameters, or None, and its problems) after the preset validation."""
    problems = [
        p for path, v in values.items() if (p := value_problem(model, base, path, v, kinds=True))
    ]
    if problems:
        return None, problems
    params = apply(base, values)
    if model == "shift":
        problems = presets.check_shift(params)
    elif model == "steering":
        problems = presets.check_steering(params)
    else:
        problems = presets.check_shift(params.shift) + presets.check_hpattern(
            params.setup, params.shift
        )
    return (None if problems else params), problems
