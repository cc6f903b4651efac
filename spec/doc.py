"""Generate PROTOCOL.md's command and error tables from the registry, and check them.

``python -m spec doc --check`` exits 1 when the document and the registry disagree;
``--write`` rewrites the generated blocks in place (atomically).
"""

from __future__ import annotations

import re
from pathlib import Path

from spec.errors import ERROR_MEANINGS, ErrorCode
from spec.files import write_atomically
from spec.registry import BY_ID, COMMANDS, PROFILES, CommandSpec, ParamSpec
from spec.requirements import PROTOCOL_MD

_BLOCK = re.compile(r"(<!-- registry:(?P<name>\w+) -->\n)(?P<body>.*?)(<!-- /registry -->)", re.S)


def _params(specs: tuple[ParamSpec, ...]) -> str:
    if not specs:
        return "—"
    parts = []
    for p in specs:
        unit = f" [{p.unit}]" if p.unit else ""
        opt = " *opt*" if p.optional else ""
        parts.append(f"`{p.name}` {p.type.name}{unit}{opt}")
    return "<br>".join(parts)


def _rules(c: CommandSpec) -> str:
    flags = [f for f, on in (("control", c.needs_control), ("motion", c.moves)) if on]
    return ", ".join(flags) or "—"


def command_table(service: str) -> str:
    rows = [
        "| ID | name | parameters | reply | rules | what it does |",
        "|---|---|---|---|---|---|",
    ]
    for c in COMMANDS:
        if c.service != service:
            continue
        rows.append(
            f"| 0x{int(c.id):04X} | {c.name} | {_params(c.params)} | {_params(c.reply)} "
            f"| {_rules(c)} | {c.summary} |"
        )
    return "\n".join(rows) + "\n"


def error_table() -> str:
    rows = ["| code | name | meaning |", "|---:|---|---|"]
    for code in ErrorCode:
        rows.append(f"| {int(code)} | {code.name} | {ERROR_MEANINGS[code]} |")
    return "\n".join(rows) + "\n"


def profile_table() -> str:
    rows = ["| service | profile | commands | what it covers |", "|---|---|---|---|"]
    for p in PROFILES:
        names = ", ".join(BY_ID[c].name for c in p.commands)
        rows.append(f"| {p.service} | {p.name} | {names} | {p.summary} |")
    return "\n".join(rows) + "\n"


def generated(name: str) -> str:
    if name == "errors":
        return error_table()
    if name == "profiles":
        return profile_table()
    return command_table(name)


def render(text: str) -> str:
    """``text`` with every generated block replaced by the registry's current tables."""
    return _BLOCK.sub(lambda m: m[1] + generated(m["name"]) + m[4], text)


def differences(path: Path = PROTOCOL_MD) -> list[str]:
    """Names of the generated blocks that differ from the registry."""
    text = path.read_text(encoding="utf-8")
    return [m["name"] for m in _BLOCK.finditer(text) if m["body"] != generated(m["name"])]


def write(path: Path = PROTOCOL_MD) -> bool:
    """Rewrite the generated blocks; True when the file changed."""
    text = path.read_text(encoding="utf-8")
    new = render(text)
    if new == text:
        return False
    write_atomically(path, new)
    return True
