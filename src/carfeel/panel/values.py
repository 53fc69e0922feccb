"""The API's values: a request's names, paths and numbers checked and quoted in its errors; the
answers as strict JSON."""

from __future__ import annotations

import re
import sys
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

from starlette.responses import JSONResponse

from carfeel.errors import InputError
from carfeel.text import finite, shown

NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,79}")
"""A file name of the panel's folder; always `fullmatch` (`$` matches before a final newline)."""


def said(value: object) -> str:
    """A request's value as an error message quotes it: its repr, shortened when long (a name
    of 60 kB is not copied back into the answer)."""
    if isinstance(value, str) and len(value) > 200:
        value = value[:100] + value[-50:]  # the repr of 60 kB need not be built to shorten it
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 128:
        return f"(a whole number of {value.bit_length()} bits)"
    if isinstance(value, list | dict) and len(value) > 20:
        return f"(a {type(value).__name__} of {len(value)} items)"
    return shown(repr(value), 60)


def safe_name(name: object, what: str) -> str:
    """A file name for the panel's folder: letters, digits, '.', '_', '-'; no way out of it."""
    if not isinstance(name, str) or not NAME.fullmatch(name) or ".." in name:
        raise InputError(
            f"{what} name {said(name)}: use 1-80 letters, digits, '.', '_' or '-' (starting "
            "with a letter or digit; no '/', no '..', no line break: files stay in the panel's "
            "folder)"
        )
    return name


def inside(folder: Path, name: str) -> Path:
    """`folder/name`, refused when it resolves outside `folder` (a link, a '..')."""
    path = (folder / name).resolve()
    if not path.is_relative_to(folder.resolve()):
        raise InputError(f"{said(name)} would leave the panel's folder {folder}")
    return path


def number_of(key: str, value: object) -> float:
    """A request's number as a float; InputError (not an OverflowError) for a whole number
    beyond any float, a string or a boolean."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{key} {said(value)}: expected a number")
    try:
        return float(value)
    except OverflowError:
        raise InputError(f"{key} {said(value)}: a number beyond {sys.float_info.max:.3g}") from None


def jsonable(value: Any) -> Any:
    """Dataclasses, tuples and NaN as strict JSON values."""
    if is_dataclass(value) and not isinstance(value, type):
        value = asdict(value)
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return finite(value)


def error_response(status: int, message: str) -> JSONResponse:
    """An error as the API answers it: {"error": message} with its HTTP status."""
    return JSONResponse({"error": message}, status_code=status)
