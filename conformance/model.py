"""Cases, outcomes and the case registry of the conformance harness.

A case is a function ``fn(ctx) -> str | None`` registered with :func:`case` under a stable
dotted ID (never a position). It names the requirement IDs it checks, a level, tags, profiles,
a time budget (seconds, before ``--timeout-scale``) and whether it moves the robot or switches
an output (``motion=True``: only with ``--allow-motion``). A case reports a broken rule by
raising :class:`Fail` with what it expected and what it got; the runner maps that to an outcome
by the case's level (MUST -> fail, SHOULD -> non-strict, INFO -> informational).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from conformance.context import Context


class Outcome(StrEnum):
    """Verdict of one case."""

    PASS = "pass"
    FAIL = "fail"  # a MUST rule is broken
    NON_STRICT = "non-strict"  # a SHOULD rule is broken
    INFORMATIONAL = "informational"  # an observation, no verdict
    NOT_APPLICABLE = "not-applicable"  # capability not offered (negotiation or capability file)
    BLOCKED = "blocked"  # a precondition failed before the case's own rule could be tried
    SKIPPED = "skipped"  # not run: motion not allowed, budget too small, endpoint gone
    ERROR = "error"  # endpoint unreachable or harness fault; never a fail
    TIMEOUT = "timeout"  # the endpoint did not answer within the case's time


LEVELS = ("MUST", "SHOULD", "INFO")
SERVICES = ("robot", "sensor", "any", "sync")
PROFILES = ("smoke", "core", "full", "robustness")


class CaseSignal(Exception):
    """Base of the exceptions a case raises to end with a given outcome."""


class Fail(CaseSignal):
    """The endpoint broke the rule the case checks."""

    def __init__(
        self, message: str, expected: object = None, actual: object = None, *, requirement: str = ""
    ) -> None:
        super().__init__(message)
        self.message = message
        self.expected = expected
        self.actual = actual
        self.requirement = requirement


class NotApplicable(CaseSignal):
    """The endpoint does not offer the capability the case needs."""


class Blocked(CaseSignal):
    """A precondition of the case failed (a request it needs before the one it judges), so
    the case's own rule was never tried: not a verdict on that rule. The precondition's own
    rule is judged by its own case."""

    def __init__(self, precondition: str, why: str) -> None:
        super().__init__(f"blocked: precondition {precondition} failed ({why})")
        self.precondition = precondition
        self.why = why


class Skip(CaseSignal):
    """The case cannot run here (motion not allowed, budget too small...)."""


class Informational(CaseSignal):
    """The case ends with an observation and no verdict."""


class EndpointTimeout(CaseSignal):
    """The endpoint did not answer in time."""


class EndpointGone(CaseSignal):
    """The endpoint refused or reset the connection where the case needed it open."""


CaseFn = Callable[["Context"], "str | None"]


@dataclass(frozen=True)
class Case:
    """One registered conformance case."""

    id: str
    fn: CaseFn
    requirements: tuple[str, ...]
    level: str
    tags: tuple[str, ...]
    profiles: tuple[str, ...]
    budget: float  # s, before --timeout-scale
    motion: bool
    service: str  # "robot", "sensor", "any" (both TCP services) or "sync" (UDP)
    commands: tuple[int, ...]  # command IDs the endpoint must advertise, else not applicable
    title: str
    order: int = 50  # lower runs first; cases that need a fresh endpoint state run early
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    @property
    def section(self) -> str:
        return self.id.split(".", 1)[0]

    def applies_to(self, service: str) -> bool:
        if self.service == "any":
            return service in ("robot", "sensor")
        return self.service == service


_REGISTRY: dict[str, Case] = {}


def case(
    id: str,
    *,
    requirements: Iterable[str],
    level: str = "MUST",
    tags: Iterable[str] = (),
    profiles: Iterable[str] = ("core", "full"),
    budget: float = 5.0,
    motion: bool = False,
    service: str = "any",
    commands: Iterable[int] = (),
    order: int = 50,
    title: str = "",
) -> Callable[[CaseFn], CaseFn]:
    """Register a case function under a stable dotted ``id``."""

    def register(fn: CaseFn) -> CaseFn:
        doc = (fn.__doc__ or "").strip().splitlines()
        add_case(
            Case(
                id=id,
                fn=fn,
                requirements=tuple(requirements),
                level=level,
                tags=tuple(tags),
                profiles=tuple(profiles),
                budget=budget,
                motion=motion,
                service=service,
                commands=tuple(int(c) for c in commands),
                title=title or (doc[0] if doc else id),
                order=order,
            )
        )
        return fn

    return register


def add_case(c: Case) -> None:
    """Register a case object (also used for cases generated from the registry or vectors)."""
    if c.id in _REGISTRY:
        raise ValueError(f"case {c.id} registered twice")
    if c.level not in LEVELS:
        raise ValueError(f"case {c.id}: level must be one of {LEVELS}, got {c.level}")
    if c.service not in SERVICES:
        raise ValueError(f"case {c.id}: service must be one of {SERVICES}, got {c.service}")
    if not c.requirements:
        raise ValueError(f"case {c.id} names no requirement")
    unknown = set(c.profiles) - set(PROFILES)
    if unknown:
        raise ValueError(f"case {c.id}: unknown profiles {sorted(unknown)}")
    _REGISTRY[c.id] = c


def all_cases() -> list[Case]:
    """Every registered case, in run order (``order``, then registration order)."""
    from conformance import cases  # noqa: F401  (registers the cases on import)

    indexed = list(enumerate(_REGISTRY.values()))
    indexed.sort(key=lambda item: (item[1].order, item[0]))
    return [c for _, c in indexed]


@dataclass
class WireEntry:
    """One send or receive: time offset from the case start (s), direction, bytes, note."""

    t: float
    direction: str  # "->" sent to the endpoint, "<-" received, "--" an event (connect, close)
    conn: int
    data: bytes
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "t": round(self.t, 6),
            "dir": self.direction,
            "conn": self.conn,
            "hex": self.data.hex(),
            "note": self.note,
        }

    def render(self, max_bytes: int = 64) -> str:
        shown = self.data[:max_bytes].hex(" ")
        more = f" ... (+{len(self.data) - max_bytes} bytes)" if len(self.data) > max_bytes else ""
        note = f"  [{self.note}]" if self.note else ""
        return f"{self.t * 1000:9.3f} ms  #{self.conn} {self.direction} {shown}{more}{note}"


@dataclass
class CaseResult:
    """What happened when one case ran."""

    case: Case
    outcome: Outcome
    message: str = ""
    expected: object = None
    actual: object = None
    duration: float = 0.0  # s
    wire: list[WireEntry] = field(default_factory=list)
    wire_truncated: int = 0  # entries left out of the log to keep it small
    details: dict[str, Any] = field(default_factory=dict)
    known_failure: bool = False  # listed in --expect and failed as expected
    unexpected_pass: bool = False  # listed in --expect but passed

    @property
    def is_problem(self) -> bool:
        return self.outcome in (Outcome.FAIL, Outcome.NON_STRICT, Outcome.ERROR, Outcome.TIMEOUT)
