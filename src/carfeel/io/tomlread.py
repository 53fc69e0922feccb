"""TOML files read within limits: a size read before the bytes, nesting and dotted keys
counted before `tomllib` parses (its stack and memory are what a hostile file aims at).

Presets, car maps, sweep specs and device profiles are all read through here; each caller names
its own error type, so the message reaches the user as that kind of bad input (exit 2).
"""

from __future__ import annotations

import re
import stat
import tomllib
from pathlib import Path
from typing import Any

from carfeel.errors import CarfeelError, PresetError

__all__ = [
    "MAX_KEY_PARTS",
    "MAX_TOML_BYTES",
    "MAX_TOML_NESTING",
    "check_toml_limits",
    "load_toml",
    "read_limited",
]

MAX_TOML_BYTES = 256 * 1024
"""The largest preset (or map) file read: the shipped ones are under 8 kB; 256 kB of the
worst TOML (keys alone) parses in about 0.3 s."""
MAX_TOML_NESTING = 16
"""Arrays and inline tables nested deeper than this are refused before parsing (a preset
nests 3 deep; 100k deep made tomllib overflow Python's stack)."""
MAX_KEY_PARTS = 16
"""Parts of one dotted key (a.b.c is 3): tomllib's memory grows as their square (10k parts
took 400 MB), so a longer key is refused before parsing."""
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
