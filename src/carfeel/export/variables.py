"""The FMUs' variables: `Variable` and `ModelSpec`, the parameters of a preset's tables (unit,
range and description from `carfeel.schema`), the units' FMI spellings, and the checks of what an
FMU carries (the preset's name, the FMI version). The lowest of the export's modules.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from carfeel.errors import CarfeelError, InputError
from carfeel.io.presets import MAX_NAME_CHARS as PRESET_NAME_CHARS
from carfeel.schema import Range, field_docs, range_of, unit_of

FMI_VERSIONS = (2, 3)
INTEGER_MAX = {2: 2**31 - 1, 3: 2**63 - 1}
"""The largest value of an FMI integer variable: FMI 2's Integer (32 bits), FMI 3's Int64."""


def signed_seed(seed: int) -> int:
    """carfeel's seed (0 .. 2^64-1) as the FMU's signed seed parameter (two's complement)."""
    return seed - 2**64 if seed >= 2**63 else seed


MODEL_STEP_S = 1e-3
"""The FMUs' default model step (the 1 kHz loop's); the parameter model_step_s changes it."""


class ExportError(CarfeelError):
    """An FMU cannot be built here: a missing compiler or extra, an unsupported platform."""


MAX_NAME_CHARS = PRESET_NAME_CHARS
"""The longest preset name an FMU carries (in its model name, its description and a C string:
a name is a label, and a longer one is refused before anything is written)."""


def _refused_character(char: str) -> bool:
    """What XML 1.0 cannot hold (C0 controls but tab, newline and return; U+FFFE, U+FFFF; lone
    surrogates), and DEL and the C1 controls, which XML holds but a terminal that prints the
    name may obey (0x9B starts an escape sequence)."""
    code = ord(char)
    if code < 0x20:
        return char not in "\t\n\r"
    return 0x7F <= code <= 0x9F or 0xD800 <= code <= 0xDFFF or code in (0xFFFE, 0xFFFF)


def checked_name(name: str) -> str:
    """A preset's name as an FMU may carry it; InputError naming the character or the limit.

    The name is data wherever it goes: an attribute of modelDescription.xml (ElementTree
    escapes it), escaped HTML in the documentation, an escaped C string literal (`c_string`)."""
    if len(name) > MAX_NAME_CHARS:
        raise InputError(
            f"the preset's name is {len(name)} characters long; an FMU takes at most "
            f"{MAX_NAME_CHARS}: shorten `name` in the preset file"
        )
    bad = next((c for c in name if _refused_character(c)), None)
    if bad is not None:
        raise InputError(
            f"the preset's name holds the control character U+{ord(bad):04X} at position "
            f"{name.index(bad)}, which an FMU's modelDescription.xml cannot carry (or a terminal "
            "would obey): remove it from `name` in the preset file"
        )
    return name


def check_fmi_version(fmi_version: int) -> None:
    """ExportError unless `fmi_version` is one of FMI_VERSIONS."""
    if fmi_version not in FMI_VERSIONS:
        raise ExportError(f"FMI version {fmi_version}: choose 2 or 3")


@dataclass(frozen=True, slots=True)
class Variable:
    """One FMU variable: its name, role, the C member of struct cf_model it lives in."""

    name: str
    causality: str
    """parameter, input or output."""
    variability: str
    """fixed, tunable (parameters), continuous (reals) or discrete (integers)."""
    kind: str
    """real, integer or an enumeration type's name (stored as an integer)."""
    c_member: str
    description: str
    start: float | int | None = None
    unit: str = ""
    low: float = -math.inf
    high: float = math.inf
    low_inclusive: bool = True
    high_inclusive: bool = True
    fmi3_integer: str = "Int64"
    """The FMI 3 type of an integer variable (Int32 or Int64); enumerations are Int64."""

    @property
    def is_real(self) -> bool:
        return self.kind == "real"


@dataclass(frozen=True, slots=True)
class ModelSpec:
    """Everything an export of one model with one preset needs."""

    model: str
    identifier: str
    title: str
    description: str
    preset: str
    source_file: str
    """The model's C file (its header has the same stem)."""
    ports: tuple[str, ...]
    """The C ports it steps (file stems: a .c and a .h each)."""
    variables: tuple[Variable, ...]
    defaults: tuple[tuple[str, float | int], ...]
    """Every member of struct cf_model the preset gives a value (parameters used or not)."""
    enumerations: tuple[tuple[str, tuple[tuple[str, str], ...]], ...]
    """(type name, ((item, description), ...)): item values 0, 1, ..."""


def value_reference(index: int) -> int:
    """Variables are numbered 1..n in order (FMI 3's time is 0)."""
    return index + 1


FMI_UNITS: dict[str, tuple[str, dict[str, int]]] = {
    "N": ("N", {"kg": 1, "m": 1, "s": -2}),
    "m": ("m", {"m": 1}),
    "s": ("s", {"s": 1}),
    "kg": ("kg", {"kg": 1}),
    "rad": ("rad", {"rad": 1}),
    "m/s": ("m/s", {"m": 1, "s": -1}),
    "m/s^2": ("m/s2", {"m": 1, "s": -2}),
    "N/m": ("N/m", {"kg": 1, "s": -2}),
    "N*s/m": ("N.s/m", {"kg": 1, "s": -1}),
    "Nm": ("N.m", {"kg": 1, "m": 2, "s": -2}),
    "kg*m^2": ("kg.m2", {"kg": 1, "m": 2}),
    "N/rad": ("N/rad", {"kg": 1, "m": 1, "s": -2, "rad": -1}),
    "rad/s": ("rad/s", {"rad": 1, "s": -1}),
    "Nm/rad": ("N.m/rad", {"kg": 1, "m": 2, "s": -2, "rad": -1}),
    "Nm*s/rad": ("N.m.s/rad", {"kg": 1, "m": 2, "s": -1, "rad": -1}),
    "Nm*s/rad per (m/s)^2": ("N.m.s3/(rad.m2)", {"kg": 1, "s": 1, "rad": -1}),
    "Nm/(m/s^2)": ("N.m.s2/m", {"kg": 1, "m": 1}),
    "1/Nm": ("1/(N.m)", {"kg": -1, "m": -2, "s": 2}),
    "s/(m*Nm)": ("s/(m.N.m)", {"kg": -1, "m": -3, "s": 3}),
    "Hz": ("Hz", {"s": -1}),
}
"""carfeel's unit -> the FMU's unit (Modelica's SI spelling, as Modelica tools parse it) and its
base units."""


def fmi_unit(unit: str) -> str:
    return FMI_UNITS[unit][0] if unit else ""


def flatten(value: Any, prefix: str = "") -> Iterator[tuple[str, Any, type, str]]:
    """(dotted path, value, owning dataclass, field name) of every leaf field, in field order."""
    for field in dataclasses.fields(value):
        item = getattr(value, field.name)
        path = f"{prefix}{field.name}"
        if dataclasses.is_dataclass(item):
            yield from flatten(item, f"{path}.")
        else:
            yield path, item, type(value), field.name


def flat_values(params: Any) -> list[float]:
    """A parameter dataclass as the flat list of doubles its C struct is (tests, benchmarks)."""
    return [float(value) for _, value, _, _ in flatten(params)]


def preset_values(prefix: str, params: Any) -> list[tuple[str, float | int]]:
    """(member of struct cf_model, value) of every field of `params`, the member `prefix.path`."""
    return [(f"{prefix}.{path}", float(value)) for path, value, _, _ in flatten(params)]


def _parameter(table: str, path: str, value: float, doc: str, c_member: str) -> Variable:
    name = f"{table}.{path}"
    leaf = path.split(".")[-1]
    unit = unit_of(leaf)
    low, high, low_in, high_in = range_of(name) or Range(-math.inf, math.inf)
    text = doc or f"{leaf.replace('_', ' ')}"
    # The preset's name is in the model's description, once: not in every variable's.
    described = f"{text} [{unit or '-'}; the preset's [{table}] {path}]"
    return Variable(
        name, "parameter", "tunable", "real", c_member, described, float(value), unit,
        low, high, low_in, high_in,
    )  # fmt: skip


def table_parameters(
    table: str,
    params: Any,
    used: Sequence[str] | None = None,
    c_struct: str | None = None,
) -> Iterator[Variable]:
    """The FMU parameters of one preset table (`used`: only those fields), named table.field;
    `c_struct` is the member of struct cf_model holding it (default: the table's name)."""
    docs: dict[type, dict[str, str]] = {}
    for path, value, owner, field in flatten(params):
        if used is not None and path not in used:
            continue
        if owner not in docs:
            docs[owner] = field_docs(owner)
        member = f"{c_struct or table}.{path}"
        doc = docs[owner].get(field, "")
        yield _parameter(table, path, value, doc, member)


def model_step(max_step_s: float, why: str) -> Variable:
    return Variable(
        "model_step_s", "parameter", "fixed", "real", "model_step_s",
        "The model's own step, s: each communication step is a whole number of model steps "
        f"with the inputs held over it (any other communication step is refused); {why}",
        MODEL_STEP_S, "s", 0.0, max_step_s, False, True,
    )  # fmt: skip
