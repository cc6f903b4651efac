"""Real-time scheduling of the timing threads (spec/realtime.py) and its fallbacks."""

from __future__ import annotations

import os
import sys
import threading

import pytest

from spec import realtime
from spec.realtime import promote_current_thread, shorten_switch_interval


def _in_thread(priority: int) -> str:
    """Promote a throwaway thread (never the test runner's own)."""
    out: list[str] = []
    t = threading.Thread(target=lambda: out.append(promote_current_thread(priority)))
    t.start()
    t.join()
    return out[0]


def test_promotion_says_what_it_got() -> None:
    got = _in_thread(10)
    assert got == "SCHED_FIFO 10" or got.startswith(("nice ", "normal ("))
    assert _in_thread(0) == "normal (real-time priority disabled)"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread nice is Linux's")
def test_fallback_to_nice_then_to_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*args: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    got = _in_thread(50)
    # root may lower its nice value, others may not: either way no exception
    assert got.startswith(("nice ", "normal (")) and "Operation not permitted" in got
    monkeypatch.setattr(os, "setpriority", refuse)
    assert _in_thread(50) == "normal (Operation not permitted)"


def test_switch_interval_is_only_ever_shortened() -> None:
    before = sys.getswitchinterval()
    try:
        sys.setswitchinterval(0.005)
        assert shorten_switch_interval(0.001) == 0.001 == sys.getswitchinterval()
        assert shorten_switch_interval(0.002) == 0.001  # never raised again
        assert realtime.REALTIME_SWITCH_INTERVAL_S < 0.004  # below one robot cycle
    finally:
        sys.setswitchinterval(before)
