"""Real-time scheduling of the threads that keep time (docs/REALTIME.md).

The robot's 4 ms clock, the trigger sender and the sensor's trigger listener must not wait
behind request handlers or other processes. :func:`promote_current_thread` asks the kernel for
``SCHED_FIFO`` at a given priority for the calling thread; where that is not permitted (no
``CAP_SYS_NICE``, no RT budget, not Linux) it falls back to the lowest nice value it may
set, and where even that fails it leaves the thread alone. It never raises: the caller logs
what it got. :func:`shorten_switch_interval` bounds how long a runnable real-time thread
waits for the GIL behind a busy Python thread (CPython hands the GIL over after the switch
interval, 5 ms by default: longer than a robot cycle).
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator

__all__ = [
    "DEFAULT_RT_PRIORITY",
    "REALTIME_SWITCH_INTERVAL_S",
    "promote_current_thread",
    "realtime_threads",
    "shorten_switch_interval",
]

DEFAULT_RT_PRIORITY = 50
"""SCHED_FIFO priority of the timing threads: above the default kernel threads' 0, below the
kernel's own real-time work (watchdogs, threaded IRQs at 50 run first by FIFO order)."""

REALTIME_SWITCH_INTERVAL_S = 0.0005
"""GIL switch interval while a real-time loop runs: a tick waits at most about this long for
a Python thread holding the GIL (measured in docs/REALTIME.md)."""


def promote_current_thread(priority: int = DEFAULT_RT_PRIORITY) -> str:
    """Give the calling thread real-time scheduling; returns what it got, for the log:
    ``"SCHED_FIFO 50"``, ``"nice -10"`` or ``"normal (reason)"``."""
    return _promote(threading.get_native_id(), priority)


@contextlib.contextmanager
def realtime_threads(priority: int) -> Iterator[str]:
    """Every thread of this process real-time while inside (as :func:`promote_current_thread`;
    threads they start inherit it) and the GIL switch interval short; all back as they were
    after. For a process whose threads are all on one real-time path (a tracker and the
    servers it talks through): a thread holding the GIL is then not preempted by other
    processes either. Yields what the calling thread got."""
    saved: dict[int, tuple[int, int, int]] = {}
    for tid in _own_threads():
        with contextlib.suppress(OSError, AttributeError):
            param = os.sched_getparam(tid).sched_priority
            saved[tid] = (os.sched_getscheduler(tid), param, os.getpriority(os.PRIO_PROCESS, tid))
    got = {tid: _promote(tid, priority) for tid in _own_threads()}
    interval = sys.getswitchinterval()
    shorten_switch_interval()
    try:
        yield got.get(threading.get_native_id(), "")
    finally:
        sys.setswitchinterval(interval)
        for tid in _own_threads():  # threads started meanwhile go back to normal too
            policy, param, nice = saved.get(tid, (getattr(os, "SCHED_OTHER", 0), 0, 0))
            with contextlib.suppress(OSError, AttributeError):  # gone, or not Linux
                os.sched_setscheduler(tid, policy, os.sched_param(param))
                os.setpriority(os.PRIO_PROCESS, tid, nice)


def _own_threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [threading.get_native_id()]


def _promote(tid: int, priority: int) -> str:
    if priority < 1:
        return "normal (real-time priority disabled)"
    setsched = getattr(os, "sched_setscheduler", None)
    fifo = getattr(os, "SCHED_FIFO", None)
    reason = "sched_setscheduler not available"
    if setsched is not None and fifo is not None and sys.platform.startswith("linux"):
        try:
            top = os.sched_get_priority_max(fifo)
            prio = min(priority, top)
            # On Linux a thread id is a valid pid for the scheduler calls: this thread only.
            setsched(tid, fifo, os.sched_param(prio))
            return f"SCHED_FIFO {prio}"
        except OSError as exc:
            reason = exc.strerror or str(exc)
    setprio = getattr(os, "setpriority", None)
    if setprio is not None and sys.platform.startswith("linux"):
        # Linux nice values are per thread; elsewhere they are per process (not touched).
        for nice in (-10, -5, -1):
            try:
                setprio(os.PRIO_PROCESS, tid, nice)
                return f"nice {nice} ({reason})"
            except OSError:
                continue
    return f"normal ({reason})"


def shorten_switch_interval(seconds: float = REALTIME_SWITCH_INTERVAL_S) -> float:
    """Lower the process's GIL switch interval to ``seconds`` if it is longer; returns the
    interval in force. Never raises it (another component may have chosen a shorter one)."""
    current = sys.getswitchinterval()
    if seconds < current:
        sys.setswitchinterval(seconds)
        return seconds
    return current
