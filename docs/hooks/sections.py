"""The mkdocs hook that puts a section of README.md or DESIGN.md into a page at build time.

A page line `<!-- section FILE "HEADING" -->` (FILE relative to the repository's root, HEADING a
whole heading line of it, e.g. `## Sweeps and Monte Carlo`) is replaced by that section: from its
heading (left out: the page has its own title) to the next heading of the same or a higher level.
The manual stays in one place and the site shows it by topic; a heading that is gone fails the
strict build instead of leaving an empty page.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
DIRECTIVE = re.compile(r'^<!-- section (\S+) "([^"]+)" -->$', re.MULTILINE)
ALLOWED = ("README.md", "DESIGN.md")


def section(file: str, heading: str) -> str:
    """The body of `heading` in `file` (README.md or DESIGN.md), without the heading line."""
    if file not in ALLOWED:
        raise ValueError(f"section of {file!r}: only {', '.join(ALLOWED)}")
    lines = (ROOT / file).read_text(encoding="utf-8").splitlines()
    level = len(heading) - len(heading.lstrip("#"))
    try:
        start = lines.index(heading)
    except ValueError:
        raise ValueError(f"{file} has no heading {heading!r}") from None
    body, fenced = [], False
    for line in lines[start + 1 :]:
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and re.match(rf"#{{1,{level}}} ", line):
            break
        body.append(line)
    return "\n".join(body).strip("\n")


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    return DIRECTIVE.sub(lambda m: section(m.group(1), m.group(2)), markdown)
