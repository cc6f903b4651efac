"""The tool and frame database: named transformations in one human-readable JSON file.

Tools are flange-relative (^N_L T laser tools, ^N_S T sensor tools, any other ``kind``),
frames are base-relative work-object frames (^B_W T); each is a VAL3 location (x, y, z in mm,
rx, ry, rz in deg, R = Rx·Ry·Rz) with an optional note. The built-in tool ``flange`` and frame
``world`` are the identity and always exist. The file::

    {
      "format": "welding-tools",
      "version": 1,
      "revision": 7,
      "tools": {"laser": {"kind": "laser", "location": [0, 0, 200, 0, 0, 0], "note": ""}},
      "frames": {"table": {"location": [600, 0, -300, 0, 0, 0], "note": ""}}
    }

Concurrency: every change goes through :meth:`ToolDB.update`, which holds an exclusive lock
(``flock`` on ``<file>.lock``) while it reads, changes and atomically replaces the file, so
two processes editing at once never lose an update; ``revision`` counts the changes, and
``update(..., expect_revision=n)`` is a compare-and-swap for an editor that showed revision
n to its user (the browser console).
"""

from __future__ import annotations

import fcntl
import json
import math
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kinematics.types import IDENTITY_LOC, Loc
from spec.files import write_atomically
from welding.job import NAME_RE

__all__ = [
    "BUILTIN_FRAME",
    "BUILTIN_TOOL",
    "FORMAT_VERSION",
    "Entry",
    "Tables",
    "ToolDB",
    "ToolDBError",
]

FORMAT = "welding-tools"
FORMAT_VERSION = 1
BUILTIN_TOOL = "flange"
BUILTIN_FRAME = "world"
TOOL_KINDS = ("laser", "sensor", "tool")
#: Largest database file read (bytes): thousands of entries are far below.
MAX_BYTES = 4 * 1024 * 1024


class ToolDBError(ValueError):
    """A bad database file, a bad entry or a refused change (message says which)."""


@dataclass(frozen=True)
class Entry:
    """A named transformation: ``location`` (mm, deg); ``kind`` for tools, "frame" for frames."""

    name: str
    kind: str
    location: Loc
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"location": list(self.location), "note": self.note}
        if self.kind != "frame":
            d = {"kind": self.kind, **d}
        return d


def check_name(name: str) -> str:
    if not NAME_RE.fullmatch(name):
        raise ToolDBError(
            f"bad name {name!r}: 1-64 letters, digits, '_', '.', '-' (not starting with '.' or '-')"
        )
    return name


def check_location(values: Sequence[object], what: str) -> Loc:
    if isinstance(values, str | bytes) or len(values) != 6:
        raise ToolDBError(f"{what}: expected 6 numbers x, y, z, rx, ry, rz")
    out: list[float] = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ToolDBError(f"{what}: {v!r} is not a finite number")
        out.append(float(v))
    return (out[0], out[1], out[2], out[3], out[4], out[5])


@dataclass
class Tables:
    """The database content: ``tools`` and ``frames`` by name, and the change ``revision``."""

    tools: dict[str, Entry]
    frames: dict[str, Entry]
    revision: int = 0

    def tool(self, name: str) -> Entry:
        if name == BUILTIN_TOOL:
            return Entry(BUILTIN_TOOL, "tool", IDENTITY_LOC, "the flange itself (identity)")
        if name not in self.tools:
            raise ToolDBError(f"no tool named {name!r}")
        return self.tools[name]

    def frame(self, name: str) -> Entry:
        if name == BUILTIN_FRAME:
            return Entry(BUILTIN_FRAME, "frame", IDENTITY_LOC, "the robot base (identity)")
        if name not in self.frames:
            raise ToolDBError(f"no frame named {name!r}")
        return self.frames[name]

    def has_tool(self, name: str) -> bool:
        return name == BUILTIN_TOOL or name in self.tools

    def has_frame(self, name: str) -> bool:
        return name == BUILTIN_FRAME or name in self.frames

    def add(self, entry: Entry, *, replace: bool = False) -> None:
        check_name(entry.name)
        check_location(entry.location, entry.name)
        if entry.name in (BUILTIN_TOOL, BUILTIN_FRAME):
            raise ToolDBError(f"{entry.name!r} is built in and cannot be changed")
        if entry.kind != "frame" and entry.kind not in TOOL_KINDS:
            raise ToolDBError(f"kind must be one of {', '.join(TOOL_KINDS)} or frame")
        table = self.frames if entry.kind == "frame" else self.tools
        if entry.name in table and not replace:
            raise ToolDBError(f"{entry.name!r} exists already (edit it instead)")
        other = self.tools if entry.kind == "frame" else self.frames
        if entry.name in other:
            used_by = "tool" if other is self.tools else "frame"
            raise ToolDBError(f"{entry.name!r} is already used by a {used_by}")
        table[entry.name] = entry

    def remove(self, name: str) -> Entry:
        for table in (self.tools, self.frames):
            if name in table:
                return table.pop(name)
        raise ToolDBError(f"no tool or frame named {name!r}")

    def to_json(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "revision": self.revision,
            "tools": {n: e.to_json() for n, e in sorted(self.tools.items())},
            "frames": {n: e.to_json() for n, e in sorted(self.frames.items())},
        }

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=2) + "\n"

    @classmethod
    def from_json(cls, data: object, source: str = "<tools>") -> Tables:
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise ToolDBError(f'{source}: not a tool database ("format": "{FORMAT}" missing)')
        if data.get("version") != FORMAT_VERSION:
            raise ToolDBError(
                f"{source}: version {data.get('version')!r}; this program reads {FORMAT_VERSION}"
            )
        revision = data.get("revision", 0)
        if not isinstance(revision, int) or isinstance(revision, bool) or revision < 0:
            raise ToolDBError(f"{source}: revision must be an integer >= 0")
        tables = cls({}, {}, revision)
        for key, kind in (("tools", None), ("frames", "frame")):
            section = data.get(key, {})
            if not isinstance(section, dict):
                raise ToolDBError(f"{source}: {key!r} must be an object")
            for name, raw in section.items():
                if not isinstance(raw, dict):
                    raise ToolDBError(f"{source}: {key}.{name}: expected an object")
                unknown = set(raw) - {"kind", "location", "note"}
                if unknown:
                    raise ToolDBError(f"{source}: {key}.{name}: unknown fields {sorted(unknown)}")
                note = raw.get("note", "")
                if not isinstance(note, str):
                    raise ToolDBError(f"{source}: {key}.{name}: note must be a string")
                loc = raw.get("location")
                if not isinstance(loc, list):
                    raise ToolDBError(f"{source}: {key}.{name}: location must be a list")
                entry_kind = kind or raw.get("kind", "tool")
                if not isinstance(entry_kind, str):
                    raise ToolDBError(f"{source}: {key}.{name}: kind must be a string")
                try:
                    tables.add(Entry(name, entry_kind, check_location(loc, name), note))
                except ToolDBError as exc:
                    raise ToolDBError(f"{source}: {key}.{name}: {exc}") from None
        return tables

    @classmethod
    def loads(cls, text: str | bytes, source: str = "<tools>") -> Tables:
        try:
            data = json.loads(text)
        except (ValueError, RecursionError) as exc:
            raise ToolDBError(f"{source}: not valid JSON: {exc}") from None
        return cls.from_json(data, source)


class ToolDB:
    """The database file at ``path`` (created empty on the first change)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.lock_path = self.path.with_name(self.path.name + ".lock")

    def read(self) -> Tables:
        """The current content (an empty database when the file does not exist yet)."""
        try:
            with open(self.path, "rb") as f:
                text = f.read(MAX_BYTES + 1)
        except FileNotFoundError:
            return Tables({}, {})
        except OSError as exc:
            raise ToolDBError(f"cannot read {self.path}: {exc.strerror}") from None
        if len(text) > MAX_BYTES:
            raise ToolDBError(f"{self.path}: larger than {MAX_BYTES} bytes")
        return Tables.loads(text, str(self.path))

    @contextmanager
    def _locked(self) -> Iterator[None]:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.lock_path, "a+b") as f:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(f.fileno(), fcntl.LOCK_UN)

    def update(
        self, change: Callable[[Tables], object], *, expect_revision: int | None = None
    ) -> Tables:
        """Apply ``change`` to the content under the file lock and save it atomically with
        the revision counted up; ``expect_revision`` refuses the change when someone else
        changed the file since that revision was read. Returns the saved content."""
        with self._locked():
            tables = self.read()
            if expect_revision is not None and tables.revision != expect_revision:
                raise ToolDBError(
                    f"{self.path} changed (revision {tables.revision}, expected "
                    f"{expect_revision}): read it again"
                )
            change(tables)
            tables.revision += 1
            write_atomically(self.path, tables.dumps())
            return tables

    # --- conveniences for the command line and the job runner -----------------------------

    def add(self, entry: Entry, *, replace: bool = False) -> None:
        self.update(lambda t: t.add(entry, replace=replace))

    def edit(self, name: str, *, location: Loc | None = None, note: str | None = None) -> Entry:
        out: list[Entry] = []

        def change(t: Tables) -> None:
            old = t.frames[name] if name in t.frames else t.tool(name)
            new = Entry(
                name,
                old.kind,
                old.location if location is None else location,
                old.note if note is None else note,
            )
            t.add(new, replace=True)
            out.append(new)

        self.update(change)
        return out[0]

    def remove(self, name: str) -> Entry:
        out: list[Entry] = []
        self.update(lambda t: out.append(t.remove(name)))
        return out[0]

    def import_from(self, path: str | os.PathLike[str], *, replace: bool = False) -> int:
        """Merge the entries of another database file; returns how many were taken."""
        try:
            other = Tables.loads(Path(path).read_bytes(), str(path))
        except OSError as exc:
            raise ToolDBError(f"cannot read {path}: {exc.strerror}") from None
        entries = [*other.tools.values(), *other.frames.values()]

        def change(t: Tables) -> None:
            for e in entries:
                t.add(e, replace=replace)

        self.update(change)
        return len(entries)

    def export_to(self, path: str | os.PathLike[str]) -> None:
        write_atomically(path, self.read().dumps())
