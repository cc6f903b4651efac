"""The requirement registry, read from PROTOCOL.md (the single source of the rules).

Each rule is one line ``- **[ID]** LEVEL sentence`` under a numbered section heading.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cache
from pathlib import Path

PROTOCOL_MD = Path(__file__).with_name("PROTOCOL.md")

_RULE = re.compile(
    r"^- \*\*\[(?P<id>(?:RS|SS|SY)-\d+\.\d+)\]\*\* (?P<level>MUST|SHOULD|MAY) (?P<text>.+)$"
)
_SECTION = re.compile(r"^#{2,3} (?P<number>\d+(?:\.\d+)?)\.? (?P<title>.+)$")


@dataclass(frozen=True, slots=True)
class Requirement:
    id: str
    level: str  # "MUST", "SHOULD" or "MAY"
    text: str
    section: str  # e.g. "3 Frames"

    @property
    def family(self) -> str:
        return self.id.split("-")[0]


def parse(text: str) -> tuple[Requirement, ...]:
    """Every rule line of a PROTOCOL.md text; raise ValueError on a duplicate ID."""
    section = ""
    rules: list[Requirement] = []
    seen: set[str] = set()
    for line in text.splitlines():
        heading = _SECTION.match(line)
        if heading:
            section = f"{heading['number']} {heading['title']}"
            continue
        rule = _RULE.match(line)
        if rule:
            if rule["id"] in seen:
                raise ValueError(f"requirement {rule['id']} defined twice")
            seen.add(rule["id"])
            rules.append(Requirement(rule["id"], rule["level"], rule["text"], section))
    return tuple(rules)


@cache
def requirements() -> tuple[Requirement, ...]:
    """The requirements of the installed PROTOCOL.md."""
    return parse(PROTOCOL_MD.read_text(encoding="utf-8"))


def by_id() -> dict[str, Requirement]:
    return {r.id: r for r in requirements()}
