"""Generate PROTOCOL.md's tables and spec/messages.py's classes from the registry; check them.

``python -m spec doc --check`` exits 1 when the document or the message classes and the
registry disagree; ``--write`` rewrites the generated blocks in place (atomically).
"""

from __future__ import annotations

import re
from pathlib import Path

from spec.errors import ERROR_MEANINGS, ErrorCode
from spec.files import write_atomically
from spec.params import CLASS_OF
from spec.registry import BY_ID, COMMANDS, PROFILES, CommandId, CommandSpec, ParamSpec
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


def differences(path: Path = PROTOCOL_MD, messages: Path | None = None) -> list[str]:
    """Names of the generated blocks that differ from the registry (``"messages"``: the
    classes of spec/messages.py, or of ``messages``)."""
    text = path.read_text(encoding="utf-8")
    names = [m["name"] for m in _BLOCK.finditer(text) if m["body"] != generated(m["name"])]
    source = (messages or MESSAGES_PY).read_text(encoding="utf-8")
    if render_messages(source) != source:
        names.append("messages")
    return names


def write(path: Path = PROTOCOL_MD, messages: Path | None = None) -> bool:
    """Rewrite the generated blocks of PROTOCOL.md and spec/messages.py; True when a file
    changed."""
    changed = False
    for target, rendering in ((path, render), (messages or MESSAGES_PY, render_messages)):
        text = target.read_text(encoding="utf-8")
        new = rendering(text)
        if new != text:
            write_atomically(target, new)
            changed = True
    return changed


# --- the message classes of spec/messages.py ---------------------------------------------------

MESSAGES_PY = Path(__file__).with_name("messages.py")
_GENERATED = re.compile(
    r"(# --- generated from spec/registry.py [^\n]*\n)(?P<body>.*?)"
    r"(# --- end of generated code ---)",
    re.S,
)
#: Words of CommandId names kept in capitals in class names (READ_IO -> ReadIORequest).
_ACRONYMS = frozenset({"IO"})
#: Names the message base classes use: no field may take one.
_RESERVED = frozenset(
    {"command", "table", "side", "what", "allow_extra", "decode", "encode", "as_dict", "reply_type"}
)


def class_name(command: CommandId) -> str:
    """The stem of a command's message classes: ``ROBOT_STATUS`` -> ``RobotStatus``."""
    return "".join(w if w in _ACRONYMS else w.capitalize() for w in command.name.split("_"))


def _field(p: ParamSpec) -> str:
    kind = CLASS_OF[p.type].__name__
    if p.name in _RESERVED or not p.name.isidentifier():
        raise ValueError(f"parameter name {p.name!r} cannot be a message field")
    if p.repeated:
        line = f"    {p.name}: tuple[{kind}, ...] = ()"
    elif p.optional:
        line = f"    {p.name}: {kind} | None = None"
    else:
        line = f"    {p.name}: {kind}"
    return f"{line}  # {p.unit}" if p.unit else line


def _message_class(c: CommandSpec, side: str) -> list[str]:
    stem = class_name(c.id)
    base = f'Request["{stem}Reply"]' if side == "request" else "Reply"
    table = c.params if side == "request" else c.reply
    return [
        "",
        "",
        "@dataclass(frozen=True, slots=True)",
        f"class {stem}{side.capitalize()}({base}):",
        f'    """{c.name} (0x{int(c.id):04X}, {c.service}) {side}."""',
        "",
        f"    command: ClassVar[CommandId] = CommandId.{c.id.name}",
        *(_field(p) for p in table),
    ]


def messages_code() -> str:
    """The generated part of spec/messages.py: two classes per command and their tables."""
    lines: list[str] = []
    for c in COMMANDS:
        lines += _message_class(c, "request") + _message_class(c, "reply")
    for side, table, base in (
        ("request", "REQUESTS", "Request[Any]"),
        ("reply", "REPLIES", "Reply"),
    ):
        lines += ["", "", f"#: Each command's {side} class, by command ID."]
        lines.append(f"{table}: dict[int, type[{base}]] = {{")
        suffix = side.capitalize()
        lines += [f"    CommandId.{c.id.name}: {class_name(c.id)}{suffix}," for c in COMMANDS]
        lines.append("}")
    return "\n".join(lines) + "\n\n\n"


def render_messages(source: str) -> str:
    """``source`` (spec/messages.py) with its generated part made from the current registry."""
    if _GENERATED.search(source) is None:
        raise ValueError("spec/messages.py has lost its generated-code markers")
    return _GENERATED.sub(lambda m: m[1] + messages_code() + m[3], source)
