"""The registry, the requirements and PROTOCOL.md agree with each other."""

from __future__ import annotations

import re

from spec import doc, wire
from spec.errors import ERROR_MEANINGS, ErrorCode
from spec.registry import COMMANDS, CommandId, commands_for
from spec.requirements import PROTOCOL_MD, parse, requirements


def test_protocol_md_tables_match_the_registry() -> None:
    assert doc.differences() == [], "run: python -m spec doc --write"


def test_every_command_appears_in_protocol_md() -> None:
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    for c in COMMANDS:
        assert f"| 0x{int(c.id):04X} | {c.name} |" in text


def test_every_error_code_has_a_meaning_and_a_row() -> None:
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    for code in ErrorCode:
        assert code in ERROR_MEANINGS
        assert f"| {int(code)} | {code.name} |" in text


def test_command_ids_sit_in_their_ranges_and_names_are_unique_per_service() -> None:
    ranges = {
        "common": wire.COMMON_RANGE,
        "robot": wire.ROBOT_RANGE,
        "sensor": wire.SENSOR_RANGE,
        "sync": wire.SYNC_RANGE,
    }
    assert len({c.id for c in COMMANDS}) == len(COMMANDS) == len(CommandId)
    for c in COMMANDS:
        assert c.id in ranges[c.service], c.name
        assert all(not p.optional for p in c.params[: -sum(p.optional for p in c.params) or None])
    for service in ("robot", "sensor"):
        names = [c.name for c in commands_for(service)]
        assert len(names) == len(set(names)), service


def test_paper_commands_exist() -> None:
    robot = {c.name for c in commands_for("robot")}
    assert {"Herej", "Here", "EnablePower", "DisablePower", "JointMove", "ToolMoveJ",
            "ToolMoveL"} <= robot  # fmt: skip
    assert {"GetData", "GetImage"} <= {c.name for c in commands_for("sensor")}


def test_every_rule_line_is_a_parsed_requirement() -> None:
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    rule_lines = [line for line in text.splitlines() if re.match(r"^- \*\*\[", line)]
    reqs = requirements()
    assert len(rule_lines) == len(reqs) >= 80
    assert {r.level for r in reqs} <= {"MUST", "SHOULD", "MAY"}
    for family in ("RS", "SS", "SY"):
        assert any(r.family == family for r in reqs)
    assert all(r.section for r in reqs)


def test_requirement_ids_quoted_in_the_code_exist() -> None:
    """A ``[RS-x.y]`` quoted in spec/ must be defined in PROTOCOL.md."""
    from pathlib import Path

    known = {r.id for r in requirements()}
    for path in Path(PROTOCOL_MD).parent.glob("*.py"):
        for ref in re.findall(r"\[((?:RS|SS|SY)-\d+\.\d+)\]", path.read_text(encoding="utf-8")):
            assert ref in known, f"{path.name} quotes unknown {ref}"


def test_duplicate_requirement_is_refused() -> None:
    import pytest

    with pytest.raises(ValueError):
        parse("## 1. A\n- **[RS-1.1]** MUST x\n- **[RS-1.1]** MUST y\n")
