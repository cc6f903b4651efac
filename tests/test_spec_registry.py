"""The registry, the requirements and PROTOCOL.md agree with each other."""

from __future__ import annotations

import re

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spec import doc, wire
from spec.errors import ERROR_MEANINGS, ErrorCode, ParameterError
from spec.params import (
    CLASS_OF,
    FloatArray,
    Image,
    IntArray,
    Joints,
    Location,
    Matrix,
    Transform,
    type_of,
)
from spec.registry import (
    COMMANDS,
    CommandId,
    CommandSpec,
    check_params,
    check_params_reference,
    commands_for,
)
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


_SAMPLES: tuple[object, ...] = (
    0,
    True,
    1.5,
    "s",
    b"b",
    ErrorCode.BUSY,  # an IntEnum: not of INT's exact class, still an INT
    FloatArray([1.0]),
    IntArray([1]),
    Joints([0.0] * 6),
    Location(0, 0, 0, 0, 0, 0),
    Transform(),
    Matrix(1, 1, [0.0]),
    Image(1, 1, b"x"),
)


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from(COMMANDS),
    st.booleans(),
    st.lists(st.sampled_from(_SAMPLES), max_size=5),
    st.booleans(),
)
def test_fast_parameter_check_agrees_with_the_reference(
    command: CommandSpec, reply: bool, values: list[object], allow_extra: bool
) -> None:
    specs = command.reply if reply else command.params
    if values and values[0] is True:  # often exactly the declared classes
        values = [CLASS_SAMPLE[s.type] for s in specs]
    elif values and values[0] == "s":  # or a prefix of them (optional ones left off)
        values = [CLASS_SAMPLE[s.type] for s in specs][: len(values) % (len(specs) + 1)]
    outcomes: list[str | None] = []
    for check in (check_params, check_params_reference):
        try:
            check(specs, tuple(values), "x", allow_extra=allow_extra)  # type: ignore[arg-type]
            outcomes.append(None)
        except ParameterError as exc:
            outcomes.append(str(exc))
    assert outcomes[0] == outcomes[1]


CLASS_SAMPLE = {type_of(v): v for v in _SAMPLES if type(v) in CLASS_OF.values()}  # type: ignore[arg-type]


@pytest.mark.parametrize("service", ["robot", "sensor"])
def test_every_command_is_in_exactly_one_profile(service: str) -> None:
    from spec.registry import commands_for, profiles_for

    listed = [c for p in profiles_for(service) for c in p.commands]
    assert sorted(listed) == sorted(int(c.id) for c in commands_for(service))
    assert profiles_for(service)[0].name == "core"
