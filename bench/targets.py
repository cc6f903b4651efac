"""The performance targets the project has set itself (issue 20), checked against one run.

Each target names the result it reads (by the start of its name, and of its baseline's name
where one figure is measured against several) and what the run must show: a bound on the value
or on the ratio to the peer of the same run. ``python -m bench.table`` prints them above the
tables, so whether a target is met is read off the run, never copied by hand. A bound on an
absolute value missed while the CPU ran below full speed (``bench.pace``) is undecided: the
run cannot tell whether the code or the machine missed it.
"""

from __future__ import annotations

import operator
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Any

from bench.pace import FULL_SPEED

_COMPARE = {"≤": operator.le, "≥": operator.ge}


@dataclass(frozen=True)
class Check:
    of: str  # "value" or "ratio"
    op: str  # "≤" or "≥"
    bound: float

    def holds(self, r: Mapping[str, Any]) -> bool:
        return bool(_COMPARE[self.op](float(r[self.of]), self.bound))


@dataclass(frozen=True)
class Target:
    goal: str
    name: str  # the result's name starts with this
    checks: tuple[Check, ...]
    baseline: str = ""  # ... and its baseline's name with this

    def find(self, results: Iterable[Mapping[str, Any]]) -> Mapping[str, Any] | None:
        for r in results:
            if str(r["name"]).startswith(self.name) and str(r["baseline_name"]).startswith(
                self.baseline
            ):
                return r
        return None


def _ratio(op: str, bound: float) -> Check:
    return Check("ratio", op, bound)


def _value(op: str, bound: float) -> Check:
    return Check("value", op, bound)


_HEREJ = "robot herej"
_ILC = "ilc real clock, sine 250 mm/s, elastic arm"
TARGETS: tuple[Target, ...] = (
    Target(
        "Herej p50 across processes ≤ pyModbusTCP's",
        f"{_HEREJ} round trip p50, client and server processes",
        (_ratio("≤", 1.0),),
    ),
    *(
        Target(
            f"Herej throughput, {n} client{'s' if n > 1 else ''}, ≥ pyModbusTCP's",
            f"{_HEREJ} throughput, {n} client(s), server process",
            (_ratio("≥", 1.0),),
        )
        for n in (1, 8, 64)
    ),
    Target(
        "GetImage across processes, frame CRC on, ≥ pyzmq REQ/REP",
        "GetImage 512x256 MONO8 (same frame re-sent), client and server processes, frame CRC on",
        (_ratio("≥", 1.0),),
    ),
    Target(
        "single-pose IK, all solutions, ≤ 50 µs and ahead of rtb ik_LM",
        "kinematics.ik single pose, all solutions",
        (_value("≤", 50.0), _ratio("≤", 1.0)),
    ),
    Target(
        "stripe ≤ 0.03 px rms, at most blur + CoG's error",
        "sensor.stripe() rms vs renderer truth",
        (_value("≤", 0.03), _ratio("≤", 1.0)),
        baseline="OpenCV",
    ),
    *(
        Target(
            f"stripe() ≥ 5,000 frames/s, {joint}", f"sensor.stripe.{joint}", (_value("≥", 5000),)
        )
        for joint in ("butt", "fillet", "lap")
    ),
    *(
        Target(
            f"detect() ≥ 3,000 frames/s, {joint}", f"sensor.detect.{joint}", (_value("≥", 3000),)
        )
        for joint in ("butt", "fillet", "lap")
    ),
    Target("ΔT estimate ≤ 1 ms", "sync.estimate_delay", (_value("≤", 1.0),)),
    *(
        t
        for hogs in (0, 2)
        for t in (
            Target(
                f"ILC, real clock, {hogs} hogs: trial 5 ≤ trial 1 / 10 (issue 31)",
                f"{_ILC}, {hogs} hogs: trial 5 error max",
                (_ratio("≤", 0.1),),
            ),
            Target(
                f"ILC table + tracking, real clock, {hogs} hogs: ≤ 0.1 mm (issue 31)",
                f"{_ILC}, {hogs} hogs: tracked with the table",
                (_value("≤", 0.1),),
            ),
        )
    ),
)


class Verdict(Enum):
    MET = "met"
    NOT_MET = "not met"
    UNDECIDED = "undecided"
    NOT_MEASURED = "not measured"


def judge(target: Target, r: Mapping[str, Any] | None) -> Verdict:
    """Whether result ``r`` meets ``target``; undecided where only an absolute bound failed
    and the CPU ran below full speed when it was measured."""
    if r is None:
        return Verdict.NOT_MEASURED
    failed = [c for c in target.checks if not c.holds(r)]
    if not failed:
        return Verdict.MET
    slow = float(r.get("machine_speed", 1.0)) < FULL_SPEED
    if slow and all(c.of == "value" for c in failed):
        return Verdict.UNDECIDED
    return Verdict.NOT_MET


def verdicts(results: list[Mapping[str, Any]]) -> list[tuple[Target, Mapping[str, Any] | None]]:
    """Each target with the result of the run that decides it (None: not measured)."""
    return [(t, t.find(results)) for t in TARGETS]
