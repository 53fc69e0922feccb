"""A self-contained validation report: one HTML page beside its PNG figures."""

from __future__ import annotations

import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from carfeel import text
from carfeel.errors import InputError


@dataclass
class Section:
    heading: str
    paragraphs: list[str] = field(default_factory=list)
    table: list[list[str]] = field(default_factory=list)
    """Rows of cells; the first row is the header."""
    figures: list[Path] = field(default_factory=list)


def prepare(folder: Path) -> Path:
    """Make `folder` to write a report straight into. The commands stage theirs instead
    (`carfeel.io.outputs.Outputs.add_folder`: a failed run leaves an older report whole)."""
    if folder.exists() and not folder.is_dir():
        raise InputError(f"--report {folder} exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def number(value: float | None, digits: int = 4) -> str:
    """A table cell's value: `digits` significant digits, n/a for None and NaN."""
    return text.number(value, digits)


def write(folder: Path, title: str, sections: Sequence[Section]) -> Path:
    """Write `index.html` in `folder` (figures are referred to by their names beside it)."""
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;"
        "padding:3px 8px;text-align:right}td:first-child{text-align:left}"
        "th{background:#eee}img{max-width:100%}</style>",
        f"</head><body><h1>{html.escape(title)}</h1>",
    ]
    for section in sections:
        parts.append(f"<h2>{html.escape(section.heading)}</h2>")
        parts += [f"<p>{html.escape(p)}</p>" for p in section.paragraphs]
        if section.table:
            head, *rows = section.table
            cells = "".join(f"<th>{html.escape(c)}</th>" for c in head)
            parts.append(f"<table><tr>{cells}</tr>")
            for row in rows:
                cells = "".join(f"<td>{html.escape(c)}</td>" for c in row)
                parts.append(f"<tr>{cells}</tr>")
            parts.append("</table>")
        parts += [
            f"<p><img src='{html.escape(f.name)}' alt='{html.escape(f.stem)}'></p>"
            for f in section.figures
        ]
    parts.append("</body></html>")
    target = folder / "index.html"
    target.write_text("\n".join(parts), encoding="utf-8")
    return target
