"""One exit-code table for every command line (issue 33): the docs list it, the tools use it."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from spec.exitcodes import ExitCode

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("spec", "kinematics", "sync", "robotsocket", "sensorsocket", "conformance", "cell")
PACKAGES += ("bench", "welding")


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


def _literal_exit_statuses(tree: ast.AST) -> list[int]:
    """Lines that return or exit with a bare non-zero integer instead of an ExitCode."""
    lines = []
    for node in ast.walk(tree):
        value: ast.expr | None = None
        if isinstance(node, ast.Return):
            value = node.value
        elif isinstance(node, ast.Call) and ast.unparse(node.func) in ("sys.exit", "exit"):
            value = node.args[0] if node.args else None
        if isinstance(value, ast.Constant) and type(value.value) is int and value.value != 0:
            lines.append(node.lineno)
    return lines


def test_command_lines_name_their_exit_codes() -> None:
    modules = _command_line_modules()
    assert len(modules) > 10  # the scan finds the tools
    literal = {
        str(path.relative_to(ROOT)): lines
        for path in modules
        if (lines := _literal_exit_statuses(ast.parse(path.read_text())))
    }
    assert literal == {}, "use spec.exitcodes.ExitCode, not a number"


def test_the_scan_finds_a_bare_number() -> None:
    assert _literal_exit_statuses(ast.parse("def f():\n    return 3\n")) == [2]
    assert _literal_exit_statuses(ast.parse("import sys\nsys.exit(2)\n")) == [2]
    assert _literal_exit_statuses(ast.parse("def f():\n    return ExitCode.USAGE\n")) == []
