"""Reports of a run: terminal summary, JSON (schema-versioned), JUnit XML and Markdown.

Every file is written atomically (a temporary file in the same directory, then
:func:`os.replace`), so a CI system never reads half a report. Measurements are reported apart
from verdicts.
"""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path
from typing import Any

from conformance import SUITE_VERSION, TOOL, TOOL_VERSION
from conformance.model import CaseResult, Outcome
from conformance.runner import RunResult, exit_code
from spec import wire
from spec.files import write_atomically
from spec.messages import Message

SCHEMA_VERSION = 1
ORDER = [o.value for o in Outcome]


def write_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` so readers see the old file or the whole new one."""
    write_atomically(path, text)


def counts(results: list[CaseResult]) -> dict[str, int]:
    c = Counter(r.outcome.value for r in results)
    return {o: c.get(o, 0) for o in ORDER}


def _plain(value: object) -> Any:
    """A JSON-safe form of a value from a case (wire values, tuples, NaN)."""
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else repr(value)
    if isinstance(value, bytes):
        return {"hex": value.hex()}
    if isinstance(value, Message):
        value = value.as_dict()  # a typed reply: its fields by name
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [_plain(v) for v in value]
    return repr(value)


def _endpoint(run: RunResult) -> dict[str, Any]:
    out: dict[str, Any] = {"service": run.service, "address": run.endpoint}
    if run.hello is not None:
        for key in ("version", "service", "vendor", "model", "serial", "software"):
            out[key if key != "service" else "reported_service"] = run.hello.text(key)
        out["commands"] = sorted(run.hello.commands)
        for key in ("max_payload", "max_clients", "idle_timeout", "frame_timeout"):
            out[key] = _plain(run.hello.fields.get(key))
    return out


def to_json(run: RunResult, strict: bool = False) -> dict[str, Any]:
    cases = []
    for r in run.results:
        cases.append(
            {
                "id": r.case.id,
                "title": r.case.title,
                "section": r.case.section,
                "requirements": list(r.case.requirements),
                "level": r.case.level,
                "tags": list(r.case.tags),
                "motion": r.case.motion,
                "outcome": r.outcome.value,
                "message": r.message,
                "expected": _plain(r.expected),
                "actual": _plain(r.actual),
                "duration_s": round(r.duration, 6),
                "budget_s": r.case.budget * run.options.timeout_scale,
                "known_failure": r.known_failure,
                "unexpected_pass": r.unexpected_pass,
                "details": _plain({k: v for k, v in r.details.items() if k != "traceback"}),
                "traceback": r.details.get("traceback", ""),
                "wire": [e.to_json() for e in r.wire],
                "wire_truncated": r.wire_truncated,
            }
        )
    return {
        "schema_version": SCHEMA_VERSION,
        "tool": TOOL,
        "tool_version": TOOL_VERSION,
        "spec_version": wire.VERSION,
        "suite_version": SUITE_VERSION,
        "started": run.started,
        "duration_s": round(run.duration, 6),
        "endpoint": _endpoint(run),
        "reachable": run.reachable,
        "negotiation_error": run.negotiation_error,
        "refused": run.refused,
        "liveness": run.liveness,
        "profiles": dict(zip(("claimed", "not_covered"), run.scope(), strict=True)),
        "profile": run.profile,
        "options": {
            "allow_motion": run.options.allow_motion,
            "timeout_scale": run.options.timeout_scale,
            "fuzz": run.options.fuzz,
            "seed": run.options.seed,
        },
        "seed": run.options.seed,
        "summary": counts(run.results),
        "exit_code": exit_code(run, strict),
        "measurements": _plain(run.measurements),
        "cases": cases,
    }


def to_junit(run: RunResult, strict: bool = False) -> str:
    """JUnit XML: one testsuite per section; fail -> <failure>, error/timeout -> <error>,
    not applicable/skipped -> <skipped>; requirement IDs as properties."""
    root = ET.Element("testsuites", name=f"conformance {run.service} {run.endpoint}")
    sections: dict[str, list[CaseResult]] = {}
    for r in run.results:
        sections.setdefault(r.case.section, []).append(r)
    totals = Counter[str]()
    for section, results in sections.items():
        suite = ET.SubElement(root, "testsuite", name=section)
        c = Counter[str]()
        for r in results:
            tc = ET.SubElement(
                suite,
                "testcase",
                name=r.case.id,
                classname=f"conformance.{run.service}.{section}",
                time=f"{r.duration:.6f}",
            )
            props = ET.SubElement(tc, "properties")
            for req in r.case.requirements:
                ET.SubElement(props, "property", name="requirement", value=req)
            ET.SubElement(props, "property", name="level", value=r.case.level)
            ET.SubElement(props, "property", name="outcome", value=r.outcome.value)
            text = _failure_text(r)
            failing = r.outcome is Outcome.FAIL or (strict and r.outcome is Outcome.NON_STRICT)
            if r.known_failure:
                ET.SubElement(tc, "skipped", message=f"known failure: {r.message}")
                c["skipped"] += 1
            elif failing:
                el = ET.SubElement(tc, "failure", message=r.message, type=r.outcome.value)
                el.text = text
                c["failures"] += 1
            elif r.outcome in (Outcome.ERROR, Outcome.TIMEOUT):
                el = ET.SubElement(tc, "error", message=r.message, type=r.outcome.value)
                el.text = text
                c["errors"] += 1
            elif r.outcome in (Outcome.NOT_APPLICABLE, Outcome.SKIPPED, Outcome.BLOCKED):
                ET.SubElement(tc, "skipped", message=f"{r.outcome.value}: {r.message}")
                c["skipped"] += 1
            elif r.message or r.outcome is Outcome.NON_STRICT:
                out = ET.SubElement(tc, "system-out")
                extra = text if r.outcome is Outcome.NON_STRICT else ""
                out.text = f"{r.outcome.value}: {r.message}\n{extra}"
            c["tests"] += 1
        for key in ("tests", "failures", "errors", "skipped"):
            suite.set(key, str(c[key]))
            totals[key] += c[key]
        suite.set("time", f"{sum(r.duration for r in results):.6f}")
    for key in ("tests", "failures", "errors", "skipped"):
        root.set(key, str(totals[key]))
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _failure_text(r: CaseResult, max_entries: int = 40) -> str:
    lines = [r.message]
    if r.expected is not None or r.actual is not None:
        lines.append(f"expected: {r.expected!r}")
        lines.append(f"actual:   {r.actual!r}")
    if r.wire:
        lines.append("bytes exchanged (time since case start, connection, direction):")
        lines += ["  " + e.render() for e in r.wire[-max_entries:]]
        if len(r.wire) > max_entries or r.wire_truncated:
            lines.append(
                f"  ({len(r.wire) - max_entries + r.wire_truncated} earlier entries left out)"
            )
    return "\n".join(lines)


def to_markdown(run: RunResult, strict: bool = False) -> str:
    lines = [
        f"# Conformance report: {run.service} at {run.endpoint}",
        "",
        f"- tool {TOOL} {TOOL_VERSION}, suite {SUITE_VERSION}, protocol {wire.VERSION}",
        f"- profile `{run.profile}`, seed {run.options.seed}, timeout scale"
        f" {run.options.timeout_scale:g}, motion"
        f" {'allowed' if run.options.allow_motion else 'not allowed'}",
    ]
    if run.hello is not None:
        h = run.hello
        lines.append(
            f"- endpoint: {h.text('vendor')} {h.text('model')} serial {h.text('serial')},"
            f" software {h.text('software')}, protocol {h.text('version')}"
        )
    if not run.reachable:
        lines.append(f"- **endpoint unreachable**: {run.negotiation_error}")
    if run.refused:
        lines.append(f"- **not run**: {run.refused}")
    lines.append(f"- exit code {exit_code(run, strict)}, {run.duration:.2f} s")
    lines += ["", "| outcome | count |", "|---|---:|"]
    lines += [f"| {k} | {v} |" for k, v in counts(run.results).items() if v]
    lines += [
        "",
        "| case | requirements | level | outcome | time (s) | message |",
        "|---|---|---|---|---:|---|",
    ]
    for r in run.results:
        msg = r.message.replace("|", "\\|").replace("\n", " ")
        mark = (
            " (known)" if r.known_failure else (" (unexpected pass)" if r.unexpected_pass else "")
        )
        lines.append(
            f"| `{r.case.id}` | {', '.join(r.case.requirements)} | {r.case.level} |"
            f" {r.outcome.value}{mark} | {r.duration:.3f} | {msg} |"
        )
    problems = [r for r in run.results if r.is_problem and not r.known_failure]
    if problems:
        lines += ["", "## Failures, errors and timeouts", ""]
        for r in problems:
            lines += [
                f"### `{r.case.id}` ({r.outcome.value})",
                "",
                "```",
                _failure_text(r),
                "```",
                "",
            ]
    if run.measurements:
        lines += ["", "## Measurements (not verdicts)", ""]
        for name, values in run.measurements.items():
            lines.append(f"- **{name}**: " + ", ".join(f"{k} {v}" for k, v in values.items()))
    return "\n".join(lines) + "\n"


def terminal(run: RunResult, strict: bool = False, verbose: bool = False) -> str:
    """The readable summary: per section counts, then every problem with its bytes."""
    out = [
        f"conformance {run.service} {run.endpoint}  profile {run.profile}  seed {run.options.seed}"
    ]
    if run.hello is not None:
        h = run.hello
        out.append(
            f"endpoint: {h.text('vendor')} {h.text('model')} serial {h.text('serial')}"
            f" software {h.text('software')} protocol {h.text('version')}"
        )
    if run.liveness:
        out.append(run.liveness)
    if run.scope_line():
        out.append(run.scope_line())
    if not run.reachable:
        out.append(f"ENDPOINT UNREACHABLE: {run.negotiation_error}")
    elif run.refused:
        out.append(f"NOT RUN: {run.refused}")
    elif run.negotiation_error:
        out.append(f"negotiation: {run.negotiation_error}")
    sections: dict[str, list[CaseResult]] = {}
    for r in run.results:
        sections.setdefault(r.case.section, []).append(r)
    out.append("")
    for section, results in sections.items():
        c = counts(results)
        text = ", ".join(f"{v} {k}" for k, v in c.items() if v)
        out.append(f"  {section:<12} {len(results):4d} cases: {text}")
    out.append("")
    for r in run.results:
        shown = (r.is_problem and not r.known_failure) or r.outcome is Outcome.BLOCKED
        if verbose or shown or r.unexpected_pass:
            flag = " (unexpected pass)" if r.unexpected_pass else ""
            reqs = ", ".join(r.case.requirements)
            out.append(f"{r.outcome.value.upper():<14} {r.case.id} [{reqs}]{flag}")
            if r.is_problem:
                out += ["    " + line for line in _failure_text(r, 12).splitlines()]
            elif r.message:
                out.append(f"    {r.message}")
    if run.measurements:
        out.append("measurements (not verdicts):")
        for name, values in run.measurements.items():
            out.append(f"  {name}: " + ", ".join(f"{k} {v}" for k, v in values.items()))
    total = counts(run.results)
    out.append(
        "total: "
        + ", ".join(f"{v} {k}" for k, v in total.items() if v)
        + f"  ({run.duration:.2f} s)  exit {exit_code(run, strict)}"
    )
    return "\n".join(out) + "\n"


def load_expectations(path: str | Path) -> frozenset[str]:
    """Case IDs of known failures: one per line (``#`` comments) or a JSON list."""
    text = Path(path).read_text(encoding="utf-8")
    if text.lstrip().startswith("["):
        data = json.loads(text)
        if not isinstance(data, list) or not all(isinstance(x, str) for x in data):
            raise ValueError("expected a JSON list of case IDs")
        return frozenset(data)
    ids = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            ids.append(line)
    return frozenset(ids)
