"""One exit-code table for every command line (issue 33): the docs list it, the tools use it."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from spec.exitcodes import ExitCode

ROOT = Path(__file__).resolve().parent.parent
PACKAGES: tuple[str, ...] = ("spec", "kinematics", "sync", "robotsocket", "sensorsocket")
PACKAGES += ("conformance", "cell", "bench", "welding")


def test_the_cli_reference_lists_every_exit_code_by_number_and_name() -> None:
    text = (ROOT / "docs" / "CLI.md").read_text()
    section = text.split("## Exit codes", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| (\d+) \| `(\w+)` \|", section, re.M)
    assert rows == [(str(int(code)), code.name) for code in ExitCode]


def _command_line_modules() -> list[Path]:
    found = []
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            name = path.name
            if name in (
                "__main__.py",
                "cli.py",
                "callcli.py",
                "cliargs.py",
                "table.py",
            ) or name.endswith("_cli.py"):
                found.append(path)
    return found


def _bare_numbers(value: ast.expr | None) -> bool:
    """A non-zero int literal, or one in a branch of ``a if c else b``."""
    if isinstance(value, ast.IfExp):
        return _bare_numbers(value.body) or _bare_numbers(value.orelse)
    return isinstance(value, ast.Constant) and type(value.value) is int and value.value != 0


def _literal_exit_statuses(tree: ast.AST, *, whole_module: bool = True) -> list[int]:
    """Lines that return or exit with a bare non-zero integer instead of an ExitCode, and
    module constants ``EXIT_… = <int>`` (a second table). ``whole_module=False``: only the
    returns of the command functions (``main``, ``console``, ``cmd_…``)."""
    lines = []
    scopes: list[ast.AST] = [tree]
    if not whole_module:
        scopes = [
            node
            for node in ast.walk(tree)
            if isinstance(node, ast.FunctionDef)
            and (node.name in ("main", "console") or node.name.startswith("cmd_"))
        ]
    for scope in scopes:
        for node in ast.walk(scope):
            value: ast.expr | None = None
            if isinstance(node, ast.Return):
                value = node.value
            elif isinstance(node, ast.Call) and ast.unparse(node.func) in ("sys.exit", "exit"):
                value = node.args[0] if node.args else None
            if _bare_numbers(value) and isinstance(node, ast.stmt | ast.expr):
                lines.append(node.lineno)
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
            names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            if any(n.startswith("EXIT_") for n in names) and type(node.value.value) is int:
                lines.append(node.lineno)
    return sorted(set(lines))


def test_command_lines_name_their_exit_codes() -> None:
    modules = _command_line_modules()
    assert len(modules) > 10  # the scan finds the tools
    literal = {
        str(path.relative_to(ROOT)): lines
        for path in modules
        if (lines := _literal_exit_statuses(ast.parse(path.read_text())))
    }
    assert literal == {}, "use spec.exitcodes.ExitCode, not a number"


def test_command_functions_everywhere_name_their_exit_codes() -> None:
    """[issue 33] ``welding track`` (in welding/emulate.py, no CLI file name) ended an
    out-of-tolerance weld with its own ``EXIT_OUT_OF_TOLERANCE = 3``: UNREACHABLE in the
    table. Every ``main``/``cmd_…`` of every module, and no module's own EXIT_ number."""
    literal = {
        str(path.relative_to(ROOT)): lines
        for package in PACKAGES
        for path in (ROOT / package).rglob("*.py")
        if (lines := _literal_exit_statuses(ast.parse(path.read_text()), whole_module=False))
    }
    assert literal == {}, "use spec.exitcodes.ExitCode, not a number"


def test_the_scan_finds_a_bare_number() -> None:
    assert _literal_exit_statuses(ast.parse("def f():\n    return 3\n")) == [2]
    assert _literal_exit_statuses(ast.parse("import sys\nsys.exit(2)\n")) == [2]
    assert _literal_exit_statuses(ast.parse("def f():\n    return ExitCode.USAGE\n")) == []
    assert _literal_exit_statuses(ast.parse("def f(ok):\n    return 0 if ok else 1\n")) == [2]
    assert _literal_exit_statuses(ast.parse("EXIT_BAD = 3\n")) == [1]
    tree = ast.parse("def g():\n    return 3\ndef cmd_x():\n    return 1\n")
    assert _literal_exit_statuses(tree, whole_module=False) == [4]
