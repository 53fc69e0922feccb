"""The mkdocs hook that writes the generated reference pages at build time.

- `reference/cli.md`: every command of `carfeel.cli.build_parser()` with its usage, description,
  arguments and options (help, default, choices), walked from the parsers themselves, so a new
  option is documented by the next build.
- `reference/presets.md`: every field of every preset kind, walked from the parameter dataclasses
  the loader builds, as the parameter schema (`carfeel.schema`) describes them: its unit (the
  name's suffix), its allowed range, its description (the field's docstring), and the value in
  each shipped TOML file.

Nothing is written into `docs/`: the pages exist only in the build (`File.generated`).
"""

from __future__ import annotations

import argparse
import dataclasses
import html
import math
import re
import typing
from collections.abc import Iterator
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files

CLI_PAGE = "reference/cli.md"
PRESETS_PAGE = "reference/presets.md"


# --- Markdown helpers ----------------------------------------------------------------------------


def _text(value: str) -> str:
    """Plain text safe in Markdown and in a table cell: HTML escaped, emphasis and pipes
    neutralised outside `code spans` (which are kept: the help texts use them)."""
    parts = re.split(r"(`[^`]*`)", value)
    out = []
    for part in parts:
        if part.startswith("`") and part.endswith("`") and len(part) > 1:
            out.append("<code>" + html.escape(part[1:-1]) + "</code>")
        else:
            escaped = html.escape(part)
            escaped = re.sub(r"([\\*_\[\]])", r"\\\1", escaped)
            out.append(escaped)
    return "".join(out).replace("|", "&#124;").replace("\n", " ")


def _code(value: str) -> str:
    return "<code>" + html.escape(value).replace("|", "&#124;") + "</code>"


def _slug(words: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", words.lower()).strip("-")


# --- the command line ----------------------------------------------------------------------------


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _subcommand_help(parser: argparse.ArgumentParser) -> dict[str, str]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return {a.dest: a.help or "" for a in action._choices_actions}
    return {}


def walk_commands(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ("carfeel",)
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """(command path, parser) of the root and every sub-command, depth first."""
    yield path, parser
    for name, sub in _subcommands(parser).items():
        yield from walk_commands(sub, (*path, name))


def _help(parser: argparse.ArgumentParser, action: argparse.Action) -> str:
    if not action.help or action.help == argparse.SUPPRESS:
        return ""
    formatter = parser._get_formatter()
    return formatter._expand_help(action)  # the help as --help prints it (%(default)s filled)


def _default(action: argparse.Action) -> str:
    if action.required or isinstance(action, argparse._HelpAction | argparse._VersionAction):
        return ""
    if action.default in (None, argparse.SUPPRESS) or action.nargs == 0:
        return ""
    if isinstance(action.default, list | tuple):
        return " ".join(str(v) for v in action.default)
    return str(action.default)


def _signature(action: argparse.Action) -> str:
    if not action.option_strings:
        return str(action.metavar or action.dest)
    if action.nargs == 0:
        return ", ".join(action.option_strings)
    metavar = action.metavar or (
        "{" + ",".join(map(str, action.choices)) + "}" if action.choices else action.dest.upper()
    )
    if isinstance(metavar, tuple):
        metavar = " ".join(metavar)
    return ", ".join(f"{option} {metavar}" for option in action.option_strings)


def render_cli(parser: argparse.ArgumentParser) -> str:
    """The command-line reference page of `parser` (carfeel's root parser)."""
    lines = [
        "# Command line",
        "",
        "Generated at build time from `carfeel.cli.build_parser()`: every command and option that",
        "`carfeel --help` and each command's `--help` show. Exit codes: 0 done; 2 bad input",
        "(nothing ran, no file written over); 3 a real-time run stopped by a safety fault; 130 or",
        "143 a run stopped by Ctrl-C or SIGTERM after the force was taken away; 141 when the",
        "output was closed early (`carfeel ... | head`).",
        "",
    ]
    commands = list(walk_commands(parser))
    lines += ["| command | what it does |", "|---|---|"]
    for path, _ in commands[1:]:
        parent = dict(commands)[path[:-1]]
        summary = _subcommand_help(parent).get(path[-1], "")
        anchor = _slug(" ".join(path))
        lines.append(f"| [{_code(' '.join(path))}](#{anchor}) | {_text(summary)} |")
    lines.append("")
    for path, sub in commands:
        name = " ".join(path)
        level = "#" * min(len(path) + 1, 4)
        lines += [f"{level} {name} {{#{_slug(name)}}}", ""]
        usage = sub.format_usage().removeprefix("usage: ").strip()
        lines += ["```text", usage, "```", ""]
        if sub.description:
            lines += [_text(" ".join(sub.description.split())), ""]
        positionals = [
            a
            for a in sub._actions
            if not a.option_strings and not isinstance(a, argparse._SubParsersAction)
        ]
        options = [a for a in sub._actions if a.option_strings]
        children = _subcommand_help(sub)
        if children:
            lines += ["| sub-command | what it does |", "|---|---|"]
            for child, text in children.items():
                lines.append(f"| [{_code(f'{name} {child}')}](#{_slug(f'{name} {child}')}) "
                             f"| {_text(text)} |")  # fmt: skip
            lines.append("")
        if positionals:
            lines += ["| argument | meaning |", "|---|---|"]
            for action in positionals:
                lines.append(f"| {_code(_signature(action))} | {_text(_help(sub, action))} |")
            lines.append("")
        if options:
            lines += ["| option | meaning | default | choices |", "|---|---|---|---|"]
            for action in options:
                choices = ", ".join(map(str, action.choices)) if action.choices else ""
                default = _default(action)
                lines.append(
                    f"| {_code(_signature(action))} | {_text(_help(sub, action))} | "
                    f"{_code(default) if default else ''} | {_text(choices)} |"
                )
            lines.append("")
        if sub.epilog:
            lines += ["```text", sub.epilog.strip("\n"), "```", ""]
    return "\n".join(lines) + "\n"


# --- the presets ---------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class FieldRow:
    path: str
    """The key's path in the preset: table.sub.name; `layout.gears[].ratio` for arrays of tables."""
    kind: str
    unit: str
    allowed: str
    doc: str
    values: dict[str, str]
    """The value in each shipped preset of the kind, by preset name."""


def _shown(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(_shown(v) for v in value) + "]"
    return str(value)


def _kind(hint: Any) -> str:
    if typing.get_origin(hint) is tuple:
        return f"list of {_kind(typing.get_args(hint)[0])}"
    return {float: "number", int: "whole number", bool: "true/false", str: "text"}.get(
        hint, str(hint)
    )


_ABSENT = object()


def _value_at(instance: Any, path: str) -> Any:
    """The value at a schema path in a preset's parameters: a tuple across an array of tables
    (`layout.gears[].ratio`); _ABSENT under a table the preset leaves out."""
    value = instance
    parts = path.split(".")
    for i, part in enumerate(parts):
        if value is None:
            return _ABSENT
        if part.endswith("[]"):
            rest = ".".join(parts[i + 1 :])
            return tuple(_value_at(item, rest) for item in getattr(value, part[:-2]))
        value = getattr(value, part)
    return value


def walk_fields(cls: type, instances: dict[str, Any]) -> Iterator[FieldRow]:
    """Every leaf field of the parameter dataclass `cls` as `carfeel.schema` describes it (unit,
    range, description), with the value in each of `instances` (shipped presets, by name)."""
    from carfeel import schema

    for field in schema.fields(cls):
        values = {name: _value_at(params, field.path) for name, params in instances.items()}
        doc = field.doc
        if not field.required:  # a key a preset may leave out
            doc = f"{doc} Optional (default {_shown(field.default)}).".strip()
        yield FieldRow(
            field.path,
            _kind(field.kind),
            field.unit,
            field.range_text(),
            doc,
            {n: _shown(v) for n, v in values.items() if v is not _ABSENT},
        )


def preset_kinds() -> Iterator[tuple[str, type, dict[str, Any], tuple[str, ...]]]:
    """(kind, parameter dataclass, shipped instances by name, top-level string keys)."""
    from carfeel.io import presets
    from carfeel.simulation.hpattern import HPatternSetup
    from carfeel.simulation.shift import ShiftParams
    from carfeel.simulation.steering import SteeringCar

    shift = {n: presets.load_shift(n).params for n in presets.available("shift")}
    steering = {n: presets.load_steering(n).params for n in presets.available("steering")}
    hpattern = {n: presets.load_hpattern(n).setup for n in presets.available("hpattern")}
    yield "shift", ShiftParams, shift, ("name", "source")
    yield "steering", SteeringCar, steering, ("name", "source")
    yield "hpattern", HPatternSetup, hpattern, ("name", "source", "engagement")
    from carfeel.simulation.sequential import SequentialSetup

    sequential = {n: presets.load_sequential(n).params for n in presets.available("sequential")}
    yield "sequential", SequentialSetup, sequential, ("name", "source")
    from carfeel.simulation.prnd import PrndSetup

    prnd = {n: presets.load_prnd(n).params for n in presets.available("prnd")}
    yield "prnd", PrndSetup, prnd, ("name", "source")


_KIND_TEXT = {
    "shift": "One engagement (neutral to a gear) and the driver's hand that pushes it: "
    "`carfeel simulate shift --preset`, `carfeel run --model shift`, `carfeel fit shift` "
    "writes one.",
    "steering": "A car: its single-track vehicle, the paper's torque law K1..K9, the path "
    "driver, and the optional `[tyres]` and `[steering_system]` tables of the physical model "
    "(`--steering-model physical` needs both). `carfeel fit steering` writes one.",
    "hpattern": "An H-pattern gearbox: the layout of its slots, the select axis, the walls, the "
    "synchronizer, the feel and the scripted driver; `engagement` names the shift preset every "
    "slot engages with (a shipped name or a path relative to this file).",
    "sequential": "A sequential (rally/race) lever: the `[lever]` (its springs, click, drum, "
    "dog bump, walls and locks) and the offline `[driver]`: `carfeel simulate sequential "
    "--preset`.",
    "prnd": "An automatic's selector: the `[selector]` (its positions, detents, end stops and "
    "shift lock) and the offline `[driver]`: `carfeel simulate prnd --preset`.",
}


def render_presets() -> str:
    """The preset reference page: every field of every kind."""
    lines = [
        "# Preset fields",
        "",
        "Generated at build time from the parameter dataclasses that `carfeel.io.presets` builds",
        "and from the shipped TOML files. A preset is a TOML file in SI units: every key below is",
        "required unless marked optional, no other key is allowed, and each number must lie in",
        "its range (a value out of",
        "range is refused with the key, the value, the unit and the range: exit code 2). The unit",
        "is the suffix of the key's name (`mass_kg`, `stiffness_N_m`). Besides the ranges, each",
        "kind has cross-checks over several fields (the stages' order along the slot, the axles",
        "of the car, the steering system's modes at a 1 ms step, the walls' passivity at 1 kHz):",
        "they are in `check_shift`, `check_steering` and `check_hpattern` of",
        "[carfeel.io.presets](api/presets.md). `carfeel presets` lists the shipped presets;",
        "start a preset of your own from a copy of one of them.",
        "",
    ]
    for kind, cls, shipped, strings in preset_kinds():
        names = list(shipped)
        lines += [f"## {kind} {{#{kind}}}", "", _text(_KIND_TEXT[kind]), ""]
        lines += [
            "Top-level keys: " + ", ".join(_code(s) for s in strings) + " (text; `source` says "
            "where the numbers come from). Shipped: " + ", ".join(_code(n) for n in names) + ".",
            "",
        ]
        header = "| key | unit | allowed | " + " | ".join(_code(n) for n in names) + " | meaning |"
        lines += [header, "|" + "---|" * (len(names) + 4)]
        for row in walk_fields(cls, shipped):
            unit = row.unit or ("-" if row.kind == "number" else row.kind)
            cells = [_code(row.path), _text(unit), _text(row.allowed or "any")]
            cells += [_text(row.values.get(n, "")) for n in names]
            cells.append(_text(row.doc))
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines) + "\n"


# --- mkdocs -------------------------------------------------------------------------------------


def on_files(files: Files, config: MkDocsConfig) -> Files:
    """Add the generated pages to the build."""
    from carfeel.cli import build_parser

    for uri, content in ((CLI_PAGE, render_cli(build_parser())), (PRESETS_PAGE, render_presets())):
        existing = files.get_file_from_path(uri)
        if existing is not None:
            files.remove(existing)
        files.append(File.generated(config, uri, content=content))
    return files
