"""How numbers and counts read in carfeel's messages and reports (one place, so each says it the
same way): a count with its noun in the right number, a value in a sane width whatever its size
(1e+300, not three hundred digits)."""

from __future__ import annotations

import json
import math


def count(n: int, noun: str, plural: str | None = None) -> str:
    """`1 row`, `2 rows`, `0 rows` (`plural` for nouns that do not take an s)."""
    return f"{n} {noun if n == 1 else plural or noun + 's'}"


def number(value: float | None, digits: int = 4) -> str:
    """A value in `digits` significant digits (exponent form when large or small); None and NaN
    read n/a."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    return f"{value:.{digits}g}"


def shown(text: str, limit: int = 40) -> str:
    """A user's argument as a message echoes it: shortened when it is long (a 300-digit number)."""
    return text if len(text) <= limit else f"{text[: limit - 12]}...{text[-9:]}"


def finite(value: object) -> object:
    """NaN and infinities as null (JSON has no NaN), through dicts, lists and tuples."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def to_json(value: object) -> str:
    """Strict JSON (RFC 8259) of a result: what a script reading `--json` can parse."""
    return json.dumps(finite(value), allow_nan=False)
