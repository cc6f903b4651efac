"""One meaning per name, one place per declaration (issue 33 item 3): the VAL3 location type,
its identity, the float64 array alias, ``--token-file`` and the clock kinds."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES: tuple[str, ...] = ("spec", "kinematics", "sync", "robotsocket", "sensorsocket")
PACKAGES += ("conformance", "cell", "bench", "welding")
# being refactored by other changes (issue 28/33): they follow when those land
REFACTORED = ("welding/console/", "spec/server.py", "robotsocket/rtprocess.py")


def _modules() -> Iterator[tuple[str, ast.Module]]:
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            name = str(path.relative_to(ROOT))
            if not name.startswith(REFACTORED):
                yield name, ast.parse(path.read_text())


def _module_assignments(tree: ast.Module) -> Iterator[tuple[str, ast.expr]]:
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target = node.targets[0]
            if isinstance(target, ast.Name):
                yield target.id, node.value
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.value:
            yield node.target.id, node.value


def _declared(where: str, value: str) -> list[str]:
    return [
        f"{name}:{target}"
        for name, tree in _modules()
        for target, expr in _module_assignments(tree)
        if ast.unparse(expr) == value
    ]


#: Six floats that are not a location: a per-joint value, a calibration plan's pose parameters.
NOT_LOCATIONS = {"kinematics/dynamics.py:Six", "welding/calibration.py:PlanPose"}


def test_one_location_type() -> None:
    found = _declared("Loc", "tuple[float, float, float, float, float, float]")
    assert sorted(set(found) - NOT_LOCATIONS) == ["spec/params.py:Loc"]


def test_one_identity_location() -> None:
    assert _declared("IDENTITY_LOC", "(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)") == [
        "spec/params.py:IDENTITY_LOC"
    ]


def test_one_float64_array_alias() -> None:
    found = _declared("", "npt.NDArray[np.float64]") + _declared("", "NDArray[np.float64]")
    assert found == ["kinematics/types.py:FloatArray"]


def test_one_token_file_declaration() -> None:
    found = [
        name
        for name, tree in _modules()
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == "add_argument"
        and any(isinstance(a, ast.Constant) and a.value == "--token-file" for a in node.args)
    ]
    assert found == ["spec/cliargs.py"]


def test_clock_kinds_come_from_one_place() -> None:
    """No command lists the kinds itself, no module checks them against its own tuple."""
    literal = {("sim", "real"), ("real", "sim")}
    found = [
        f"{name}:{node.lineno}"
        for name, tree in _modules()
        for node in ast.walk(tree)
        if isinstance(node, ast.Tuple)
        and all(isinstance(e, ast.Constant) for e in node.elts)
        and tuple(e.value for e in node.elts if isinstance(e, ast.Constant)) in literal
        and name != "spec/clocks.py"
    ]
    assert found == []
