"""A shipped preset with one line changed at a time, and the problem the loader must name."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest

from carfeel.errors import PresetError
from carfeel.io import presets


def assert_each_edit_is_named(
    kind: str,
    shipped: str,
    edits: Sequence[tuple[str, str, str]],
    folder: Path,
    other: tuple[str, str, str],
) -> None:
    """Each (old line, new line, words the error must hold) of `edits`, made alone in the
    shipped preset, is refused with those words; `other` = (kind, name, words): a preset of
    another kind given as this one is refused with the kind named."""
    text = presets.resolve(kind, shipped)[1]
    path = folder / "bad.toml"
    for old, new, named in edits:
        assert old in text, f"{shipped} has no line {old!r}: the edit would test nothing"
        path.write_text(text.replace(old, new), encoding="utf-8")
        with pytest.raises(PresetError, match=r"bad\.toml is not valid") as info:
            presets.load(kind, str(path))
        assert named in str(info.value)
    other_kind, other_name, words = other
    path.write_text(presets.resolve(other_kind, other_name)[1], encoding="utf-8")
    with pytest.raises(PresetError, match=words):
        presets.load(kind, str(path))
