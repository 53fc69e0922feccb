"""How numbers and counts read in carfeel's messages and reports (one place, so each says it the
same way): a count with its noun in the right number, a value in a sane width whatever its size
(1e+300, not three hundred digits)."""

from __future__ import annotations

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
