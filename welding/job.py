"""Welding jobs (paper section III-C): the model, the XML format, loading and saving.

A job is an ordered list of named items, processed in the job's ``order`` (item names,
repeats allowed) or, without one, in document order:

- :class:`Path`: a welding trajectory, a start location then linear (:class:`Line`) and
  circular (:class:`Arc`, through a middle location) segments, with its process parameters
  (velocity, laser on/off and power, process gas on/off with pre- and post-flow, crossjet),
  optionally ``tracked`` (the seam tracker corrects it during the weld);
- :class:`Via`: an in-between (joint-interpolated) move to a location;
- :class:`Stitch`: a spot weld at a location for a duration;
- :class:`Pause`: the robot waits.

Every location names the tool (^N_L T, ^N_S T, ...) and the frame (^B_W T) it is expressed
in; the names refer to the tool and frame database (:mod:`welding.tools`).

The XML format is published as ``welding/job.xsd`` and in the README. Loading reports every
problem it finds, each with its line and column (:class:`JobError`); saving writes the file
atomically and is canonical: ``dumps(loads(dumps(job))) == dumps(job)`` and
``loads(dumps(job)) == job`` (floats as their shortest exact decimal).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path as FilePath
from xml.sax.saxutils import escape as escape_text
from xml.sax.saxutils import quoteattr

from spec.files import write_atomically
from welding.xmlsafe import MAX_BYTES, Element, XmlRefused, parse

__all__ = [
    "FORMAT_VERSION",
    "Arc",
    "Item",
    "Job",
    "JobError",
    "Line",
    "Location",
    "Path",
    "Pause",
    "Problem",
    "Segment",
    "Stitch",
    "Via",
    "dumps",
    "load",
    "loads",
    "named_location",
    "save",
]

#: Version of the job file format written by :func:`dumps`.
FORMAT_VERSION = 1
NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}")
#: Limits of the process parameters (mm/s, W, s, %): wide, but they catch a slipped digit.
MAX_VELOCITY = 2000.0
MAX_POWER = 100_000.0
MAX_SECONDS = 3600.0
COORDS = ("x", "y", "z", "rx", "ry", "rz")


@dataclass(frozen=True)
class Location:
    """A VAL3 location (mm, deg) of ``tool`` in ``frame`` (names in the tool database)."""

    x: float
    y: float
    z: float
    rx: float
    ry: float
    rz: float
    tool: str
    frame: str

    @property
    def values(self) -> tuple[float, float, float, float, float, float]:
        return (self.x, self.y, self.z, self.rx, self.ry, self.rz)


@dataclass(frozen=True)
class Line:
    """A linear segment to ``to``."""

    to: Location


@dataclass(frozen=True)
class Arc:
    """A circular segment through ``mid`` to ``to`` (from the end of the previous one)."""

    mid: Location
    to: Location


Segment = Line | Arc


@dataclass(frozen=True)
class Path:
    """A welding path: ``start`` then ``segments``; velocity mm/s, power W, flows s."""

    name: str
    start: Location
    segments: tuple[Segment, ...]
    velocity: float
    laser: bool = True
    power: float = 0.0
    gas: bool = True
    crossjet: bool = True
    preflow: float = 0.0
    postflow: float = 0.0
    #: seam tracking (method 2): the sensor measures the seam ahead of the laser and the
    #: path is corrected every cycle (lines only; corners rounded, see welding.tracking)
    tracked: bool = False

    def locations(self) -> Iterator[Location]:
        yield self.start
        for seg in self.segments:
            if isinstance(seg, Arc):
                yield seg.mid
            yield seg.to


@dataclass(frozen=True)
class Via:
    """An in-between move (joint interpolated) at ``speed`` % of the joint speed."""

    name: str
    at: Location
    speed: float = 10.0


@dataclass(frozen=True)
class Stitch:
    """A spot weld at ``at``: laser on for ``duration`` s at ``power`` W."""

    name: str
    at: Location
    duration: float
    power: float = 0.0
    gas: bool = True
    crossjet: bool = True
    preflow: float = 0.0
    postflow: float = 0.0
    speed: float = 10.0


@dataclass(frozen=True)
class Pause:
    """The robot waits ``duration`` s."""

    name: str
    duration: float


Item = Path | Via | Stitch | Pause


@dataclass(frozen=True)
class Job:
    """A named job: ``items`` in document order, processed in ``order`` (names) if given."""

    name: str
    items: tuple[Item, ...]
    order: tuple[str, ...] | None = None
    description: str = ""

    def item(self, name: str) -> Item:
        for it in self.items:
            if it.name == name:
                return it
        raise KeyError(name)

    def sequence(self) -> list[Item]:
        """The items in processing order."""
        if self.order is None:
            return list(self.items)
        return [self.item(n) for n in self.order]

    def locations(self) -> Iterator[Location]:
        for it in self.items:
            if isinstance(it, Path):
                yield from it.locations()
            elif isinstance(it, Via | Stitch):
                yield it.at

    def tools(self) -> set[str]:
        return {loc.tool for loc in self.locations()}

    def frames(self) -> set[str]:
        return {loc.frame for loc in self.locations()}


def named_location(job: Job, name: str) -> Location:
    """Where the item ``name`` is (a via's or stitch's location, a path's start); KeyError
    with a message naming the job's locations when there is none of that name."""
    try:
        item = job.item(name)
    except KeyError:
        names = ", ".join(i.name for i in job.items if not isinstance(i, Pause))
        raise KeyError(f"no location named {name!r}; the job has {names}") from None
    if isinstance(item, Pause):
        raise KeyError(f"{name!r} is a pause, not a location")
    return item.start if isinstance(item, Path) else item.at


# --- problems ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Problem:
    """One problem: where it is in the XML (line, column), where it is in the job as an
    operator names it (``where``: "item 2 (via 'approach')", "item 1 (path 'seam'), segment
    3 (line)") and the attribute (``field``, "" when the element as a whole is wrong)."""

    line: int
    column: int
    message: str
    where: str = ""
    field: str = ""

    @property
    def text(self) -> str:
        """The problem as an operator reads it: the place in the job, then what is wrong."""
        return f"{self.where}: {self.message}" if self.where else self.message

    def __str__(self) -> str:
        return f"{self.line}:{self.column}: {self.text}"


class JobError(ValueError):
    """A job file with problems: ``problems`` lists every one with its line and column."""

    def __init__(self, problems: Iterable[Problem], source: str = "<job>") -> None:
        self.problems = sorted(problems, key=lambda p: (p.line, p.column))
        self.source = source
        super().__init__("\n".join(f"{source}:{p}" for p in self.problems))


# --- reading -------------------------------------------------------------------------------

#: Attributes each element takes: (required, optional). The schema (job.xsd) says the same;
#: tests/test_welding_job.py checks that the two agree.
LOCATION_ATTRS = ("tool", "frame", *COORDS)
SCHEMA: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "job": (("name", "version"), ("order",)),
    "description": ((), ()),
    "path": (
        ("name", "velocity"),
        ("laser", "power", "gas", "crossjet", "preflow", "postflow", "tracked"),
    ),
    "start": (LOCATION_ATTRS, ()),
    "line": (LOCATION_ATTRS, ()),
    "arc": ((), ()),
    "mid": (LOCATION_ATTRS, ()),
    "end": (LOCATION_ATTRS, ()),
    "via": (("name", *LOCATION_ATTRS), ("speed",)),
    "stitch": (
        ("name", "duration", *LOCATION_ATTRS),
        ("power", "gas", "crossjet", "preflow", "postflow", "speed"),
    ),
    "pause": (("name", "duration"), ()),
}
ITEM_TAGS = ("path", "via", "stitch", "pause")


class _Reader:
    def __init__(self) -> None:
        self.problems: list[Problem] = []
        self._where: dict[int, str] = {}  # id(element) -> its place in the job

    def at(self, el: Element, where: str) -> None:
        """Name ``el``'s place in the job for the problems found on it."""
        self._where[id(el)] = where

    def error(self, el: Element, message: str, field: str = "") -> None:
        where = self._where.get(id(el), "")
        self.problems.append(Problem(el.line, el.column, message, where, field))

    def check_element(self, el: Element, *, text: bool = False) -> bool:
        """Unknown/missing attributes and stray text; False when a required one is missing."""
        required, optional = SCHEMA[el.tag]
        for name in el.attrs:
            if name not in required and name not in optional:
                self.error(el, f"<{el.tag}>: unknown attribute {name!r}", name)
        ok = True
        for name in required:
            if name not in el.attrs:
                self.error(el, f"<{el.tag}>: missing attribute {name!r}", name)
                ok = False
        if not text and el.text.strip():
            self.error(el, f"<{el.tag}>: text is not allowed here")
        return ok

    def number(
        self, el: Element, name: str, default: float, lo: float, hi: float, *, open_lo: bool = False
    ) -> float:
        raw = el.attrs.get(name)
        if raw is None:
            return default
        try:
            value = float(raw.strip())
        except ValueError:
            self.error(el, f"<{el.tag}> {name}={raw!r}: not a number", name)
            return default
        if not math.isfinite(value):
            self.error(el, f"<{el.tag}> {name}={raw!r}: must be finite", name)
            return default
        if value < lo or value > hi or (open_lo and value == lo):
            bound = f"> {lo:g}" if open_lo else f">= {lo:g}"
            self.error(el, f"<{el.tag}> {name}={raw}: must be {bound} and <= {hi:g}", name)
            return default
        return value

    def flag(self, el: Element, name: str, default: bool) -> bool:
        raw = el.attrs.get(name)
        if raw is None:
            return default
        if raw not in ("on", "off"):
            self.error(el, f"<{el.tag}> {name}={raw!r}: expected 'on' or 'off'", name)
            return default
        return raw == "on"

    def name(self, el: Element, attr: str = "name") -> str:
        raw = el.attrs.get(attr, "")
        if not NAME_RE.fullmatch(raw):
            self.error(
                el,
                f"<{el.tag}> {attr}={raw!r}: names are 1-64 letters, digits, '_', '.', '-' "
                "(not starting with '.' or '-')",
                attr,
            )
        return raw

    def location(self, el: Element) -> Location:
        c = [self.number(el, k, 0.0, -1e6, 1e6) for k in COORDS]
        return Location(
            c[0], c[1], c[2], c[3], c[4], c[5], self.name(el, "tool"), self.name(el, "frame")
        )

    def no_children(self, el: Element) -> None:
        for child in el.children:
            self.error(child, f"<{child.tag}> is not allowed inside <{el.tag}>")

    # --- items ---

    def item(self, el: Element) -> Item | None:
        if not self.check_element(el):
            self.no_children(el)
            return None
        if el.tag == "path":
            return self.path(el)
        self.no_children(el)
        name = self.name(el)
        if el.tag == "via":
            speed = self.number(el, "speed", 10.0, 0.0, 100.0, open_lo=True)
            return Via(name, self.location(el), speed)
        if el.tag == "stitch":
            return Stitch(
                name,
                self.location(el),
                duration=self.number(el, "duration", 0.0, 0.0, MAX_SECONDS, open_lo=True),
                power=self.number(el, "power", 0.0, 0.0, MAX_POWER),
                gas=self.flag(el, "gas", True),
                crossjet=self.flag(el, "crossjet", True),
                preflow=self.number(el, "preflow", 0.0, 0.0, MAX_SECONDS),
                postflow=self.number(el, "postflow", 0.0, 0.0, MAX_SECONDS),
                speed=self.number(el, "speed", 10.0, 0.0, 100.0, open_lo=True),
            )
        return Pause(name, self.number(el, "duration", 0.0, 0.0, MAX_SECONDS))

    def path(self, el: Element) -> Path | None:
        start: Location | None = None
        segments: list[Segment] = []
        # elements present but broken have their own problem: not "needs a <start>" again
        had_start = had_segment = False
        where = self._where.get(id(el), "")
        for child in el.children:
            if child.tag not in ("start", "line", "arc"):
                self.error(child, f"<{child.tag}> is not allowed inside <path>")
                continue
            if child.tag == "start":
                self.at(child, f"{where}, start")
                if had_start or had_segment:
                    self.error(child, "<path>: <start> must come once, first")
                had_start = True
                if self.check_element(child):
                    start = self.location(child)
                self.no_children(child)
                continue
            had_segment = True
            self.at(child, f"{where}, segment {len(segments) + 1} ({child.tag})")
            if child.tag == "line":
                if self.check_element(child):
                    segments.append(Line(self.location(child)))
                self.no_children(child)
            else:
                arc = self.arc(child)
                if arc is not None:
                    segments.append(arc)
        if not had_start:
            self.error(el, "<path>: needs a <start> location")
        if not had_segment:
            self.error(el, "<path>: needs at least one <line> or <arc> segment")
        path = Path(
            self.name(el),
            start or Location(0, 0, 0, 0, 0, 0, "", ""),
            tuple(segments),
            velocity=self.number(el, "velocity", 1.0, 0.0, MAX_VELOCITY, open_lo=True),
            laser=self.flag(el, "laser", True),
            power=self.number(el, "power", 0.0, 0.0, MAX_POWER),
            gas=self.flag(el, "gas", True),
            crossjet=self.flag(el, "crossjet", True),
            preflow=self.number(el, "preflow", 0.0, 0.0, MAX_SECONDS),
            postflow=self.number(el, "postflow", 0.0, 0.0, MAX_SECONDS),
            tracked=self.flag(el, "tracked", False),
        )
        return path if start is not None and segments else None

    def arc(self, el: Element) -> Arc | None:
        self.check_element(el)
        found: dict[str, Location] = {}
        for child in el.children:
            self.at(child, f"{self._where.get(id(el), '')} {child.tag}")
            if child.tag not in ("mid", "end") or child.tag in found:
                self.error(
                    child, f"<{child.tag}> is not allowed here: <arc> takes <mid> then <end>"
                )
                continue
            if child.tag == "end" and "mid" not in found:
                self.error(child, "<arc>: <mid> must come before <end>")
            if self.check_element(child):
                found[child.tag] = self.location(child)
            self.no_children(child)
        if "mid" not in found or "end" not in found:
            self.error(el, "<arc>: needs a <mid> and an <end> location")
            return None
        return Arc(found["mid"], found["end"])

    def job(self, root: Element) -> Job | None:
        if root.tag != "job":
            self.error(root, f"the root element must be <job>, not <{root.tag}>")
            return None
        self.at(root, "job")
        self.check_element(root)
        version = root.attrs.get("version")
        if version is not None and version != str(FORMAT_VERSION):
            self.error(
                root, f"<job> version={version!r}: this program reads version {FORMAT_VERSION}"
            )
            return None
        name = self.name(root)
        description = ""
        items: list[Item] = []
        seen: dict[str, Element] = {}
        for i, child in enumerate(root.children):
            if child.tag == "description":
                if i != 0:
                    self.error(child, "<description> must be the first element of <job>")
                self.check_element(child, text=True)
                self.no_children(child)
                description = child.text
                continue
            if child.tag not in ITEM_TAGS:
                self.error(child, f"<{child.tag}> is not allowed inside <job>")
                continue
            number = sum(c.tag in ITEM_TAGS for c in root.children[: i + 1])
            self.at(child, f"item {number} ({child.tag} {child.attrs.get('name', '')!r})")
            item = self.item(child)
            item_name = child.attrs.get("name", "")
            if item_name in seen:
                first = seen[item_name]
                self.error(child, f"item name {item_name!r} already used at line {first.line}")
            seen[item_name] = child
            if item is not None:
                items.append(item)
        order: tuple[str, ...] | None = None
        if "order" in root.attrs:
            order = tuple(root.attrs["order"].split())
            if not order:
                self.error(root, "<job> order: empty; leave it out to use document order")
            for n in order:
                if n not in seen:
                    self.error(root, f"<job> order: no item named {n!r}")
        if not items and not self.problems:
            self.error(root, "<job>: no items")
        return Job(name, tuple(items), order, description)


ToolCheck = Callable[[str], bool]


def loads(
    data: bytes | str,
    *,
    source: str = "<job>",
    has_tool: ToolCheck | None = None,
    has_frame: ToolCheck | None = None,
) -> Job:
    """Parse a job; :class:`JobError` lists every problem. With ``has_tool``/``has_frame``
    (e.g. from :class:`welding.tools.ToolDB`) every location's tool and frame must exist."""
    raw = data.encode("utf-8") if isinstance(data, str) else data
    try:
        root = parse(raw)
    except XmlRefused as exc:
        raise JobError([Problem(exc.line, exc.column, exc.message)], source) from None
    reader = _Reader()
    job = reader.job(root)
    if job is not None and (has_tool is not None or has_frame is not None):
        _check_names(root, reader, has_tool, has_frame)
    if reader.problems or job is None:
        raise JobError(reader.problems, source)
    return job


def _check_names(
    el: Element, reader: _Reader, has_tool: ToolCheck | None, has_frame: ToolCheck | None
) -> None:
    if "tool" in el.attrs and has_tool is not None and not has_tool(el.attrs["tool"]):
        reader.error(
            el, f"<{el.tag}> tool={el.attrs['tool']!r}: no such tool in the database", "tool"
        )
    if "frame" in el.attrs and has_frame is not None and not has_frame(el.attrs["frame"]):
        reader.error(
            el, f"<{el.tag}> frame={el.attrs['frame']!r}: no such frame in the database", "frame"
        )
    for child in el.children:
        _check_names(child, reader, has_tool, has_frame)


def load(
    path: str | os.PathLike[str],
    *,
    has_tool: ToolCheck | None = None,
    has_frame: ToolCheck | None = None,
) -> Job:
    """Read and parse a job file (see :func:`loads`); OSError when it cannot be read."""
    p = FilePath(path)
    with open(p, "rb") as f:
        data = f.read(MAX_BYTES + 1)  # one byte over is enough for the reader to refuse it
    return loads(data, source=str(p), has_tool=has_tool, has_frame=has_frame)


# --- writing -------------------------------------------------------------------------------


def _num(v: float) -> str:
    # repr is the shortest decimal that reads back to the same float
    text = repr(float(v))
    return text[:-2] if text.endswith(".0") else text


def _flag(v: bool) -> str:
    return "on" if v else "off"


def _attrs(pairs: Iterable[tuple[str, str]]) -> str:
    return "".join(f" {k}={quoteattr(v)}" for k, v in pairs)


def _loc_attrs(loc: Location) -> list[tuple[str, str]]:
    return [("tool", loc.tool), ("frame", loc.frame)] + [
        (k, _num(v)) for k, v in zip(COORDS, loc.values, strict=True)
    ]


def _item_xml(item: Item) -> list[str]:
    if isinstance(item, Pause):
        return [f"  <pause{_attrs([('name', item.name), ('duration', _num(item.duration))])}/>"]
    if isinstance(item, Via):
        a = [("name", item.name), *_loc_attrs(item.at), ("speed", _num(item.speed))]
        return [f"  <via{_attrs(a)}/>"]
    if isinstance(item, Stitch):
        a = [
            ("name", item.name),
            ("duration", _num(item.duration)),
            *_loc_attrs(item.at),
            ("power", _num(item.power)),
            ("gas", _flag(item.gas)),
            ("crossjet", _flag(item.crossjet)),
            ("preflow", _num(item.preflow)),
            ("postflow", _num(item.postflow)),
            ("speed", _num(item.speed)),
        ]
        return [f"  <stitch{_attrs(a)}/>"]
    a = [
        ("name", item.name),
        ("velocity", _num(item.velocity)),
        ("laser", _flag(item.laser)),
        ("power", _num(item.power)),
        ("gas", _flag(item.gas)),
        ("crossjet", _flag(item.crossjet)),
        ("preflow", _num(item.preflow)),
        ("postflow", _num(item.postflow)),
        ("tracked", _flag(item.tracked)),
    ]
    lines = [f"  <path{_attrs(a)}>", f"    <start{_attrs(_loc_attrs(item.start))}/>"]
    for seg in item.segments:
        if isinstance(seg, Line):
            lines.append(f"    <line{_attrs(_loc_attrs(seg.to))}/>")
        else:
            lines.append("    <arc>")
            lines.append(f"      <mid{_attrs(_loc_attrs(seg.mid))}/>")
            lines.append(f"      <end{_attrs(_loc_attrs(seg.to))}/>")
            lines.append("    </arc>")
    lines.append("  </path>")
    return lines


def dumps(job: Job) -> str:
    """The job as canonical XML text (UTF-8, two-space indent, attributes in fixed order)."""
    a = [("name", job.name), ("version", str(FORMAT_VERSION))]
    if job.order is not None:
        a.append(("order", " ".join(job.order)))
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', f"<job{_attrs(a)}>"]
    if job.description:
        lines.append(f"  <description>{escape_text(job.description)}</description>")
    for item in job.items:
        lines.extend(_item_xml(item))
    lines.append("</job>")
    return "\n".join(lines) + "\n"


def save(job: Job, path: str | os.PathLike[str]) -> None:
    """Write ``job`` to ``path`` atomically (a reader sees the old file or the new one)."""
    write_atomically(path, dumps(job))
