"""The clock kinds of the emulators, one closed set (issue 33): ``"sim"``, a simulated clock
that advances only when the code makes it (deterministic, as fast as the CPU allows), and
``"real"``, the wall clock with real sockets and the 4 ms real-time loop. The same code runs on
both. A :data:`ClockKind` is a ``Literal``, so ``mypy --strict`` refuses a misspelt
comparison (``clock == "reel"``) that a plain ``str`` let through."""

from __future__ import annotations

from typing import Literal, TypeGuard

__all__ = ["CLOCK_KINDS", "ClockKind", "check_clock_kind", "is_clock_kind"]

ClockKind = Literal["sim", "real"]
#: Every kind, for ``choices=`` and messages.
CLOCK_KINDS: tuple[ClockKind, ...] = ("sim", "real")


def is_clock_kind(value: object) -> TypeGuard[ClockKind]:
    return value in CLOCK_KINDS


def check_clock_kind(value: object) -> ClockKind:
    """``value`` as a :data:`ClockKind`; ValueError naming the kinds otherwise."""
    if not is_clock_kind(value):
        raise ValueError(f"clock must be 'sim' or 'real', got {value!r}")
    return value
