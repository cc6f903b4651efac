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

import os
import sys
import threading

__all__ = [
    "DEFAULT_RT_PRIORITY",
    "REALTIME_SWITCH_INTERVAL_S",
    "promote_current_thread",
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
    if priority < 1:
        return "normal (real-time priority disabled)"
    setsched = getattr(os, "sched_setscheduler", None)
    fifo = getattr(os, "SCHED_FIFO", None)
    tid = threading.get_native_id()
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
