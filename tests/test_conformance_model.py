"""The case registry, selection, exit codes, reports and the command line of the harness."""

from __future__ import annotations

import json
import re
import socket
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from conformance.cli import main
from conformance.context import Options
from conformance.model import Case, CaseResult, Outcome, WireEntry, all_cases
from conformance.report import load_expectations, to_json, to_junit, to_markdown, write_atomic
from conformance.runner import RunResult, Selection, exit_code
from spec.exitcodes import ExitCode
from spec.requirements import requirements

#: MUST rules that cannot be observed at the wire in bounded time; each still has a case,
#: with level INFO and a message saying why (keep this list short).
NOT_OBSERVABLE = {"SY-3.5", "SY-2.9"}
#: Client-side rules: a server cannot break them; their cases are informational.
CLIENT_SIDE = {"RS-3.14", "RS-5.6"}


def test_every_must_requirement_has_a_case() -> None:
    named = {req for c in all_cases() for req in c.requirements}
    missing = [r.id for r in requirements() if r.level == "MUST" and r.id not in named]
    assert missing == []


def test_must_requirements_have_a_verdict_case_unless_listed() -> None:
    judged = {req for c in all_cases() if c.level == "MUST" for req in c.requirements}
    unjudged = {r.id for r in requirements() if r.level == "MUST" and r.id not in judged}
    assert unjudged == NOT_OBSERVABLE | CLIENT_SIDE


def test_every_should_requirement_has_a_case() -> None:
    named = {req for c in all_cases() for req in c.requirements}
    # RS-6.3 (message names the parameter) and RS-7.7 (bind/allow-list) are not judged.
    missing = {r.id for r in requirements() if r.level == "SHOULD" and r.id not in named}
    assert missing <= {"RS-6.3", "RS-7.7"}


def test_case_ids_are_dotted_unique_and_name_known_requirements() -> None:
    known = {r.id for r in requirements()}
    ids = [c.id for c in all_cases()]
    assert len(ids) == len(set(ids))
    for c in all_cases():
        assert re.fullmatch(r"[a-z]+(\.[A-Za-z0-9_\-]+)+", c.id), c.id
        assert set(c.requirements) <= known, (c.id, c.requirements)
        assert c.budget > 0 and c.title


def test_motion_cases_are_robot_cases_only() -> None:
    motion = [c for c in all_cases() if c.motion]
    assert motion and all(c.service == "robot" for c in motion)


def test_selection_globs_tags_and_profiles() -> None:
    cases = all_cases()
    smoke = Selection("smoke").pick(cases, "sensor")
    core = Selection("core").pick(cases, "sensor")
    assert 0 < len(smoke) < len(core)
    assert all("smoke" in c.profiles for c in smoke)
    picked = Selection(select=("framing.*",), exclude=("framing.crc.*",)).pick(cases, "robot")
    assert picked and all(
        c.id.startswith("framing.") and not c.id.startswith("framing.crc.") for c in picked
    )
    tagged = Selection("full", tags=("sync",)).pick(cases, "robot")
    assert tagged and all("sync" in c.tags for c in tagged)
    assert all(c.service == "sync" for c in Selection("full").pick(cases, "sync"))
    assert not any(c.service == "sensor" for c in Selection("full").pick(cases, "robot"))


def _case(id: str, level: str = "MUST") -> Case:
    return Case(
        id,
        lambda ctx: None,
        ("RS-3.4",),
        level,
        ("framing",),
        ("core",),
        1.0,
        False,
        "any",
        (),
        "a case",
    )


def _run(*outcomes: Outcome, reachable: bool = True) -> RunResult:
    result = RunResult("robot", "127.0.0.1:1", Options(), "core", None, reachable, "")
    for i, o in enumerate(outcomes):
        r = CaseResult(_case(f"framing.c{i}"), o, f"message {i}", expected=1, actual=2)
        r.wire = [WireEntry(0.001, "->", 1, b"\x52\x53\x01"), WireEntry(0.002, "<-", 1, b"RS")]
        if o is Outcome.ERROR:
            r.details["endpoint_error"] = True
        result.results.append(r)
    return result


@pytest.mark.parametrize(
    ("outcomes", "strict", "code"),
    [
        ((Outcome.PASS, Outcome.NOT_APPLICABLE, Outcome.SKIPPED), False, ExitCode.OK),
        ((Outcome.PASS, Outcome.FAIL, Outcome.NON_STRICT), False, ExitCode.FAILED),
        ((Outcome.PASS, Outcome.NON_STRICT), False, ExitCode.OK),
        ((Outcome.PASS, Outcome.NON_STRICT), True, ExitCode.SHOULD_FAILED),
        ((Outcome.PASS, Outcome.TIMEOUT), True, ExitCode.UNREACHABLE),
        ((Outcome.ERROR,), False, ExitCode.UNREACHABLE),
        ((), False, ExitCode.NOTHING_SELECTED),
    ],
)
def test_exit_codes(outcomes: tuple[Outcome, ...], strict: bool, code: int) -> None:
    assert exit_code(_run(*outcomes), strict) == code


def test_known_failures_do_not_fail_the_run() -> None:
    run = _run(Outcome.PASS, Outcome.FAIL)
    run.results[1].known_failure = True
    assert exit_code(run) == ExitCode.OK


def test_harness_fault_is_untrusted() -> None:
    run = _run(Outcome.PASS)
    run.harness_errors = 1
    assert exit_code(run) == ExitCode.UNTRUSTED


def test_json_report_schema() -> None:
    data = to_json(_run(Outcome.PASS, Outcome.FAIL))
    assert data["schema_version"] == 1
    assert data["tool"] == "conformance" and data["spec_version"] == "1.3"
    assert {"suite_version", "seed", "endpoint", "summary", "measurements"} <= set(data)
    failed = data["cases"][1]
    assert failed["outcome"] == "fail" and failed["requirements"] == ["RS-3.4"]
    assert failed["expected"] == 1 and failed["actual"] == 2
    assert failed["wire"][0] == {"t": 0.001, "dir": "->", "conn": 1, "hex": "525301", "note": ""}
    json.dumps(data)  # serialisable


def test_junit_distinguishes_failure_error_and_skipped() -> None:
    xml = to_junit(
        _run(
            Outcome.PASS,
            Outcome.FAIL,
            Outcome.ERROR,
            Outcome.TIMEOUT,
            Outcome.NOT_APPLICABLE,
            Outcome.NON_STRICT,
        )
    )
    root = ET.fromstring(xml)
    assert root.get("tests") == "6"
    assert root.get("failures") == "1" and root.get("errors") == "2" and root.get("skipped") == "1"
    cases = {tc.get("name"): tc for tc in root.iter("testcase")}
    assert cases["framing.c1"].find("failure") is not None
    assert cases["framing.c2"].find("error") is not None
    assert cases["framing.c1"].find("failure").text is not None  # type: ignore[union-attr]
    assert "52 53 01" in cases["framing.c1"].find("failure").text  # type: ignore[union-attr,operator]
    props = [
        p.get("value")
        for p in cases["framing.c0"].iter("property")
        if p.get("name") == "requirement"
    ]
    assert props == ["RS-3.4"]
    strict = ET.fromstring(to_junit(_run(Outcome.NON_STRICT), strict=True))
    assert strict.get("failures") == "1"


def test_markdown_lists_failures_with_bytes() -> None:
    md = to_markdown(_run(Outcome.PASS, Outcome.FAIL))
    assert "`framing.c1`" in md and "52 53 01" in md and "| fail |" in md


def test_write_atomic_leaves_no_temporary_files(tmp_path: Path) -> None:
    target = tmp_path / "r.json"
    write_atomic(target, "one")
    write_atomic(target, "two")
    assert target.read_text() == "two"
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_expectation_file_formats(tmp_path: Path) -> None:
    lines = tmp_path / "known.txt"
    lines.write_text("# known\nframing.crc.bad  # vendor bug\n\nrobot.io.unknown_name\n")
    assert load_expectations(lines) == {"framing.crc.bad", "robot.io.unknown_name"}
    js = tmp_path / "known.json"
    js.write_text('["a.b"]')
    assert load_expectations(js) == {"a.b"}


# --- command line ------------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_cli_list_and_nothing_selected(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["robot", "--list", "--select", "framing.crc.*"]) == 0
    out = capsys.readouterr().out
    assert "framing.crc.bad" in out and "RS-3.6" in out
    assert main(["robot", "--list", "--select", "no.such.case"]) == ExitCode.NOTHING_SELECTED
    assert (
        main(["robot", "127.0.0.1:1", "--select", "no.such.case", "-q"])
        == ExitCode.NOTHING_SELECTED
    )


def test_cli_usage_errors_exit_usage(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["robot", "not-an-endpoint"]) == ExitCode.USAGE
    assert main(["robot", "--timeout-scale", "0"]) == ExitCode.USAGE
    assert main(["teapot"]) == ExitCode.USAGE
    err = capsys.readouterr().err
    assert err.count("\n") >= 3 and "Traceback" not in err


def test_cli_unreachable_writes_every_report(tmp_path: Path) -> None:
    port = _free_port()
    paths = {k: tmp_path / f"r.{k}" for k in ("json", "junit", "markdown")}
    code = main(
        [
            "sensor",
            f"127.0.0.1:{port}",
            "--profile",
            "smoke",
            "-q",
            "--timeout-scale",
            "0.1",
            *(a for k, p in paths.items() for a in (f"--{k}", str(p))),
        ]
    )
    assert code == ExitCode.UNREACHABLE
    data = json.loads(paths["json"].read_text())
    assert data["reachable"] is False and data["exit_code"] == ExitCode.UNREACHABLE
    assert data["cases"] == []  # nothing ran; the reason is said once
    assert "cannot connect" in data["negotiation_error"]
    assert ET.parse(paths["junit"]).getroot() is not None
    assert "unreachable" in paths["markdown"].read_text()
