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
                # carfeel.errors is a leaf (it imports nothing): a model names a bad
                # parameter with PresetError, which the command line maps to exit 2.
                ok = name.startswith("carfeel.models") or name == "carfeel.errors"
                assert ok, f"{path.name} imports {name}"
            assert top not in HEAVY, f"{path.name} imports {name}: keep the step plain Python"


PACKAGE = MODELS.parent


def carfeel_imports(path: Path, module_level_only: bool) -> set[str]:
    """The carfeel modules `path` imports (at module level, or anywhere in it)."""
    tree = ast.parse(path.read_text(), filename=str(path))
    nodes = tree.body if module_level_only else list(ast.walk(tree))
    names: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names if a.name.startswith("carfeel"))
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("carfeel"):
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return names


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    found, state = [], {}

    def visit(node: str, trail: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                found.append([*trail[trail.index(nxt) :], nxt])
            elif nxt not in state:
                visit(nxt, [*trail, nxt])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    return found


def import_graph(module_level_only: bool, within: str = "carfeel") -> dict[str, set[str]]:
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for name, path in modules.items():
        if name.startswith(within):
            targets = carfeel_imports(path, module_level_only)
            graph[name] = {t for t in targets if t in modules and t.startswith(within)} - {name}
    return graph


def test_no_import_cycle_at_module_level():
    """Issue 11: `workflows.py` and `shift_workflows.py` imported each other. No module of carfeel
    takes part in a cycle of module-level imports (the order of imports would decide what
    works)."""
    assert cycles(import_graph(module_level_only=True)) == []


def test_the_identification_workflows_do_not_import_each_other_at_all():
    """Not even lazily: the shift workflow stands on `common`, not on the steering one's."""
    graph = import_graph(module_level_only=False, within="carfeel.identification")
    assert cycles(graph) == []


def test_the_cli_only_assembles_the_command_families():
    """`cli.py` parses and dispatches: it imports the command modules, the errors and the
    version, not the models, the simulations or the workflows (each family owns its own)."""
    imported = carfeel_imports(PACKAGE / "cli.py", module_level_only=False)
    allowed = ("carfeel.commands", "carfeel.errors", "carfeel.__version__")
    assert {m for m in imported if not m.startswith(allowed) and m != "carfeel"} == set()


def package_graph() -> dict[str, set[str]]:
    """Which of carfeel's packages (carfeel.X) import which, lazily or not."""
    graph: dict[str, set[str]] = {}
    for name, targets in import_graph(module_level_only=False).items():
        top = ".".join(name.split(".")[:2])
        graph.setdefault(top, set()).update(
            ".".join(t.split(".")[:2]) for t in targets if not t.startswith(top)
        )
    return graph


def test_no_two_packages_import_each_other_even_lazily():
    """Issue 28: `telemetry` imported `realtime` (a device sample) while `realtime` imports
    `telemetry`; the type both need lives in `carfeel.contracts`. A lazy import counts: it is the
    same dependency, only later."""
    assert cycles(package_graph()) == []


def test_only_the_command_line_imports_the_commands():
    """`carfeel.commands` is the CLI over the library: the panel imported its helpers (JSON, a
    gear sequence), which made the library depend on its own command line."""
    importers = {
        package for package, targets in package_graph().items() if "carfeel.commands" in targets
    }
    assert importers <= {"carfeel.cli", "carfeel.__main__"}


def test_nothing_below_the_panel_imports_it():
    importers = {p for p, targets in package_graph().items() if "carfeel.panel" in targets}
    assert importers <= {"carfeel.cli", "carfeel.commands"}
