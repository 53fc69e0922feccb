"""carfeel.models imports nothing else of carfeel, and nothing heavy: it runs in the 1 kHz loop."""

from __future__ import annotations

import ast
from pathlib import Path

import carfeel.models

MODELS = Path(carfeel.models.__file__).parent
HEAVY = {"numpy", "scipy", "matplotlib", "pandas"}


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
        elif isinstance(node, ast.ImportFrom):
            raise AssertionError(f"{path}: relative import; use absolute carfeel.models imports")
    return names


def test_models_import_only_models_and_the_standard_library():
    files = sorted(MODELS.rglob("*.py"))
    assert len(files) >= 5
    for path in files:
        for name in imported_modules(path):
            top = name.split(".")[0]
            if top == "carfeel":
                assert name.startswith("carfeel.models"), f"{path.name} imports {name}"
            assert top not in HEAVY, f"{path.name} imports {name}: keep the step plain Python"
