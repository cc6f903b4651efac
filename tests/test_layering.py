"""Imports go downward only (DESIGN.md "Layout and layering")."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# The layers, bottom first (docs/ARCHITECTURE.md). The rule: a module imports only packages
# of the layers below its own; packages of one layer do not import each other.
LAYERS: list[set[str]] = [
    {"spec"},
    {"kinematics"},
    {"sync"},
    {"robotsocket", "sensorsocket"},
    {"conformance", "cell"},
    {"welding"},
]
LAYER = {package: rank for rank, layer in enumerate(LAYERS) for package in layer}
PROJECT = set(LAYER) | {"bench"}
STDLIB_ONLY = {"spec", "conformance"}
# Two narrowings of the rule, each for a reason a user meets:
# - the harness runs against any endpoint without our servers' numpy: it imports only spec
#   eagerly (robotsocket / sensorsocket lazily, for its in-process reference servers);
# - welding reaches robot and sensor only through their clients, so it works against any
#   conforming pair: it never imports the emulated cell, except from an entry point.
EAGER_ONLY = {"conformance": {"spec"}}
NEVER = {"welding": {"cell"}}
# Entry points sit on top of everything: command lines (every __main__.py) and welding's
# --emulate modules may import any package, the emulated cell included.
ENTRY_POINTS = {"__main__.py"} | {"emulate.py", "ilc_emulate.py", "track_options.py"}


def allowed(package: str, path: Path) -> set[str]:
    """The project packages a module of ``package`` at ``path`` may import."""
    if path.name in ENTRY_POINTS:
        return set(LAYER)
    below = {p for p, rank in LAYER.items() if rank < LAYER[package]}
    return below - NEVER.get(package, set())


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
    for package in LAYER:
        for path in (ROOT / package).rglob("*.py"):
            ok = allowed(package, path)
            for module, nested in imports(path):
                if module not in PROJECT or module == package:
                    continue
                if module not in ok:
                    problems.append(f"{path.relative_to(ROOT)} imports {module}")
                elif not nested and module not in EAGER_ONLY.get(package, {module}):
                    problems.append(f"{path.relative_to(ROOT)} imports {module} eagerly")
    assert problems == []


def test_the_rule_refuses_an_upward_import() -> None:
    """The rule itself: a library module importing upward or sideways is caught."""
    assert "welding" not in allowed("robotsocket", ROOT / "robotsocket" / "service.py")
    assert "sensorsocket" not in allowed("robotsocket", ROOT / "robotsocket" / "service.py")
    assert "cell" not in allowed("welding", ROOT / "welding" / "process.py")
    assert "cell" in allowed("welding", ROOT / "welding" / "emulate.py")
    assert "cell" in allowed("sync", ROOT / "sync" / "__main__.py")


def test_codec_and_harness_use_the_standard_library_only() -> None:
    third_party = {"numpy", "matplotlib", "scipy"}
    for package in STDLIB_ONLY:
        for path in (ROOT / package).rglob("*.py"):
            used = {m for m, _ in imports(path)} & third_party
            assert not used, f"{path.relative_to(ROOT)} imports {used}"
