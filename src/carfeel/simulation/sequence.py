"""A gear sequence as a user writes it (`N,1,2,N`): the H-pattern driver's script."""

from __future__ import annotations

from carfeel.errors import InputError

__all__ = ["parse_sequence"]


def parse_sequence(text: str) -> tuple[str, ...]:
    """The gear names of `text`, upper case, in order (`"n,1,2"` -> `("N", "1", "2")`); an
    empty name (`"N,,1"`) is an InputError. Whether the layout has each gear is the run's check."""
    gears = tuple(part.strip().upper() for part in text.split(","))
    if not gears or any(not g for g in gears):
        raise InputError(f"--sequence {text!r}: expected gear names separated by commas, N,1,2,N")
    return gears
