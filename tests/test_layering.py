"""Imports go downward only (DESIGN.md "Layout and layering")."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# What each package may import from the project; everything else is above it.
ALLOWED = {
    "spec": set(),
    "kinematics": set(),
    "sync": {"spec", "kinematics"},
    "robotsocket": {"spec", "kinematics", "sync"},
    "sensorsocket": {"spec", "kinematics", "sync"},
    "conformance": {"spec", "robotsocket", "sensorsocket"},  # the last two only lazily
    "cell": {"spec", "kinematics", "sync", "robotsocket", "sensorsocket"},
    "welding": {"spec", "kinematics", "sync", "robotsocket", "sensorsocket"},
}
PROJECT = set(ALLOWED) | {"bench"}
STDLIB_ONLY = {"spec", "conformance"}
# Command-line entry points sit on top of everything and may start the emulated cell.
ENTRY_POINT_EXTRA = {"sync": {"cell", "robotsocket", "sensorsocket"}}
# welding reaches robot and sensor only through the clients; only its --emulate paths
# (emulate.py, imported lazily) build the emulated cell, and the options of `welding track`
# (track_options.py, on every parser) take the cell's timing options.
EMULATE_MODULES = {"welding": (("emulate.py", "track_options.py"), {"cell"})}


def imports(path: Path) -> list[tuple[str, bool]]:
    """(top-level module, imported inside a function) for every import in a file."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out: list[tuple[str, bool]] = []

    def visit(node: ast.AST, nested: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = nested or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef)
            if isinstance(child, ast.Import):
                out.extend((a.name.split(".")[0], inner) for a in child.names)
            elif isinstance(child, ast.ImportFrom) and child.module and not child.level:
                out.append((child.module.split(".")[0], inner))
            visit(child, inner)

    visit(tree, False)
    return out


def test_packages_import_only_downward() -> None:
    problems = []
    for package, allowed in ALLOWED.items():
        for path in (ROOT / package).rglob("*.py"):
            extra = ENTRY_POINT_EXTRA.get(package, set()) if path.name == "__main__.py" else set()
            if package in EMULATE_MODULES and path.name in EMULATE_MODULES[package][0]:
                extra = EMULATE_MODULES[package][1]
            for module, nested in imports(path):
                if module not in PROJECT or module == package:
                    continue
                if module not in allowed | extra:
                    problems.append(f"{path.relative_to(ROOT)} imports {module}")
                elif package == "conformance" and module != "spec" and not nested:
                    problems.append(f"{path.relative_to(ROOT)} imports {module} eagerly")
    assert problems == []


def test_codec_and_harness_use_the_standard_library_only() -> None:
    third_party = {"numpy", "matplotlib", "scipy"}
    for package in STDLIB_ONLY:
        for path in (ROOT / package).rglob("*.py"):
            used = {m for m, _ in imports(path)} & third_party
            assert not used, f"{path.relative_to(ROOT)} imports {used}"
