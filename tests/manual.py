"""The user's manual as the tests read it: the README and the documentation's pages (the
README points to the pages; what they promise is tested wherever it is written)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def manual_text() -> str:
    """README.md, then every page under docs/ (sorted), one text."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return "\n\n".join(p.read_text(encoding="utf-8") for p in pages)


def page(relative: str) -> str:
    """One page of the documentation (`how-to/python.md`)."""
    return (ROOT / "docs" / relative).read_text(encoding="utf-8")
