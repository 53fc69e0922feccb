"""Channel maps: which signal of a log is which of carfeel's channels, with its unit, scale and
offset (the TOML file `logs` describes), read and checked."""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.io import log_limits as limits
from carfeel.io.log_limits import byte_size, close, shown
from carfeel.io.log_units import CHANNELS, UNITS, si_unit

MAX_TERMS = 16
"""Most signals one map entry sums."""
MIN_RESAMPLE_HZ = 1.0
MAX_RESAMPLE_HZ = 20_000.0
"""A log is resampled to 1 Hz .. 20 kHz (the 1 kHz loop's logs and a car's buses lie within)."""


@dataclass(frozen=True)
class Term:
    """One signal of a map entry's sum."""

    signal: str
    scale: float = 1.0
    group: int | None = None


@dataclass(frozen=True)
class MapEntry:
    terms: tuple[Term, ...]
    """Summed (one term: the signal itself)."""
    unit: str | None
    scale: float
    offset: float

    @property
    def signal(self) -> str:
        return " + ".join(t.signal for t in self.terms)


@dataclass(frozen=True)
class ChannelMap:
    channels: Mapping[str, MapEntry]
    rate_hz: float | None = None


def load_map(path: Path) -> ChannelMap:
    """Read and check a channel map (`carfeel.io.logs`'s docstring)."""
    where = f"--channels {path}"
    data = _read_toml(where, path)
    unknown = sorted(set(data) - {"channels", "resample"})
    if unknown:
        raise InputError(
            f"{where}: unknown table(s) {', '.join(shown(u) for u in unknown[:5])}"
            .replace("'", "") + "; a channel map has [channels] and optionally [resample]"
        )  # fmt: skip
    table = data.get("channels")
    if not isinstance(table, dict) or not table:
        raise InputError(
            f"{where}: no [channels] table (see README, 'Log formats and channel maps')"
        )
    entries = {}
    for name, entry in table.items():
        if name not in CHANNELS:
            raise InputError(
                f"{where}: unknown channel {shown(name)}{close(name, CHANNELS)}; carfeel's "
                f"channels are {', '.join(CHANNELS)}"
            )
        entries[name] = _entry(where, name, entry)
    return ChannelMap(entries, _rate(where, data.get("resample", {})))


def _read_toml(where: str, path: Path) -> dict[str, Any]:
    """The map file's TOML, its size checked (MAX_MAP_BYTES) before it is read."""
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise InputError(f"{where}: no such file") from None
    except OSError as exc:
        raise InputError(f"{where}: cannot read it ({exc.strerror})") from None
    if size > limits.MAX_MAP_BYTES:
        raise InputError(
            f"{where}: {size:,} bytes, beyond the {byte_size(limits.MAX_MAP_BYTES)} a channel map "
            "may have (one is a few hundred bytes): is it the right file?"
        )
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except IsADirectoryError:
        raise InputError(f"{where}: a folder, not a channel map") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{where}: not valid TOML ({str(exc)[:200]})") from None
    except RecursionError:  # tables or arrays nested thousands deep
        raise InputError(
            f"{where}: not a channel map: its tables or arrays nest thousands deep (a map has "
            "[channels] with one entry per channel)"
        ) from None


def _rate(where: str, resample: object) -> float | None:
    """The [resample] table's rate_hz (Hz), None where it gives none."""
    if not isinstance(resample, dict):
        raise InputError(f"{where}: [resample] must be a table (rate_hz = 50.0)")
    if set(resample) - {"rate_hz"}:
        raise InputError(
            f"{where}: [resample] {', '.join(sorted(set(resample) - {'rate_hz'}))[:200]}: "
            "unknown key(s); it takes rate_hz"
        )
    rate = resample.get("rate_hz")
    if rate is not None and (
        isinstance(rate, bool)
        or not isinstance(rate, int | float)
        or not MIN_RESAMPLE_HZ <= rate <= MAX_RESAMPLE_HZ
    ):
        number = isinstance(rate, int | float) and not isinstance(rate, bool)
        raise InputError(
            f"{where}: [resample] rate_hz = {f'{rate:g}' if number else shown(rate)}: "
            f"expected a number of Hz, {MIN_RESAMPLE_HZ:g} <= rate_hz <= {MAX_RESAMPLE_HZ:g}"
        )
    return None if rate is None else float(rate)


def _entry(where: str, name: str, entry: object) -> MapEntry:
    """One [channels] entry: a signal name, or a table with signal (a name, or a list of names
    or {signal, scale, group} tables: their sum), unit, scale, offset and group."""
    usage = (
        f'{where}: {name} needs signal = "NAME" (or a list of names to sum), and optionally '
        "unit, scale, offset, group"
    )
    if isinstance(entry, str):
        entry = {"signal": entry}
    if not isinstance(entry, dict) or "signal" not in entry:
        raise InputError(usage)
    extra = sorted(set(entry) - {"signal", "unit", "scale", "offset", "group"})
    if extra:
        raise InputError(
            f"{where}: {name}: unknown key(s) {', '.join(extra)[:200]}; allowed: signal, unit, "
            "scale, offset, group"
        )
    group = _group(where, name, entry.get("group"))
    terms = _terms(where, name, entry["signal"], group, usage)
    unit = entry.get("unit")
    if unit is not None:
        if not isinstance(unit, str):
            raise InputError(f'{where}: {name}: unit must be text, e.g. unit = "deg"')
        if si_unit(unit) != CHANNELS[name]:
            raise InputError(
                f"{where}: {name}: unit {shown(unit)} is not a unit of {CHANNELS[name]}; known: "
                f"{', '.join(u for u, (si, _) in UNITS.items() if si == CHANNELS[name])}"
            )
    scale = _number(where, name, "scale", entry.get("scale", 1.0))
    offset = _number(where, name, "offset", entry.get("offset", 0.0), zero=True)
    return MapEntry(terms, unit, scale, offset)


def _terms(where: str, name: str, raw: object, group: int | None, usage: str) -> tuple[Term, ...]:
    """An entry's signal as the terms of its sum (one name: one term); `group` their default."""
    items = raw if isinstance(raw, list) else [raw]
    if not items or len(items) > MAX_TERMS:
        raise InputError(f"{where}: {name}: signal lists 1 to {MAX_TERMS} signals to sum")
    terms = []
    for item in items:
        if isinstance(item, str):
            item = {"signal": item}
        if not isinstance(item, dict) or not isinstance(item.get("signal"), str):
            raise InputError(usage)
        if set(item) - {"signal", "scale", "group"}:
            raise InputError(
                f"{where}: {name}: a term of the sum takes signal, scale and group only"
            )
        scale = _number(where, name, "scale", item.get("scale", 1.0))
        terms.append(Term(item["signal"], scale, _group(where, name, item.get("group", group))))
    return tuple(terms)


def _number(where: str, name: str, key: str, value: object, zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{where}: {name}: {key} must be a number")
    number = float(value)
    if not math.isfinite(number) or abs(number) > limits.MAX_RAW_VALUE:
        raise InputError(f"{where}: {name}: {key} = {number:g}: give a finite number under 1e15")
    if number == 0.0 and not zero:
        raise InputError(f"{where}: {name}: {key} must not be 0")
    return number


def _group(where: str, name: str, value: object) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 1_000_000:
        raise InputError(
            f"{where}: {name}: group must be an MDF channel group's index, 0 or more (carfeel "
            "channels FILE lists them)"
        )
    return int(value)
