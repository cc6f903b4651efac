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


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread scheduling")
def test_realtime_threads_promotes_the_threads_and_puts_them_back() -> None:
    def policy(tid: int) -> tuple[int, int]:
        return os.sched_getscheduler(tid), os.getpriority(os.PRIO_PROCESS, tid)

    seen: dict[str, object] = {}

    def body() -> None:  # a throwaway thread, as above
        me = threading.get_native_id()
        seen["before"], seen["interval"] = policy(me), sys.getswitchinterval()
        with realtime.realtime_threads(20) as got:
            seen["got"], seen["inside"] = got, policy(me)
            seen["interval_inside"] = sys.getswitchinterval()
        seen["after"], seen["interval_after"] = policy(me), sys.getswitchinterval()

    t = threading.Thread(target=body)
    t.start()
    t.join()
    got = str(seen["got"])
    assert got == "SCHED_FIFO 20" or got.startswith(("nice ", "normal ("))
    if got.startswith("SCHED_FIFO"):
        assert seen["inside"] == (os.SCHED_FIFO, seen["before"][1])  # type: ignore[index]
    assert seen["interval_inside"] <= realtime.REALTIME_SWITCH_INTERVAL_S  # type: ignore[operator]
    assert (seen["after"], seen["interval_after"]) == (seen["before"], seen["interval"])
