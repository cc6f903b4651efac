"""The two robot cycle loops: simulated (advanced explicitly) and real time (a 4 ms thread).

Both drive the same tick function with the cycle index k; the sample time is t_k = k * T_r.
:class:`SimLoop` never advances by itself: the owner calls :meth:`SimLoop.advance` (it counts
cycles; the sensor's :class:`sensorsocket.sensor.SimClock` is a settable clock in seconds).
:class:`RealTimeLoop` ticks on absolute deadlines start + k * T_r from ``time.monotonic_ns``
and waits on an :class:`threading.Event` with a timeout (so ``stop`` wakes it at once), not
on short sleeps; late ticks are run back to back so k stays on the time axis. It records the
lateness of every tick (tick jitter) and runs with real-time scheduling where permitted
(:mod:`spec.realtime`, docs/REALTIME.md).
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable

from spec.realtime import (
    DEFAULT_RT_PRIORITY,
    REALTIME_SWITCH_INTERVAL_S,
    promote_current_thread,
    shorten_switch_interval,
)

log = logging.getLogger(__name__)

Tick = Callable[[int], None]


class SimLoop:
    """Deterministic cycle loop: ``advance(n)`` runs n ticks, as fast as the CPU allows."""

    simulated = True

    def __init__(self, period: float, tick: Tick | None = None) -> None:
        if not period > 0:
            raise ValueError(f"period must be > 0 s, got {period}")
        self.period = period
        self.cycle = 0
        self.tick = tick

    def now(self) -> float:
        """Time of the latest cycle in seconds (k * period)."""
        return self.cycle * self.period

    def advance(self, n: int = 1) -> None:
        """Run ``n`` cycles."""
        for _ in range(n):
            self.cycle += 1
            if self.tick is not None:
                self.tick(self.cycle)


class RealTimeLoop:
    """A thread calling ``tick(k)`` at start + k * period on the monotonic clock.

    ``now()`` is seconds since start, continuous. ``jitter()`` summarises how late the ticks
    started (s). A tick that overruns makes the next ones late; they run at once to catch up,
    so every k is ticked exactly once and in order, however late (time is a stamp: the tick
    computes the sample for t_k = k * period whenever it runs).

    Isolation (docs/REALTIME.md): the thread asks for ``SCHED_FIFO`` at ``rt_priority``
    (0: stay a normal thread), falling back to a better nice value or nothing, and
    :meth:`start` lowers the process's GIL switch interval to ``switch_interval_s`` (None:
    leave it). ``scheduling`` says what the thread got. ``clock_ns`` and ``sleep_ns``
    (return True to stop) replace the monotonic clock and the wait in tests.

    Idle cost: while ``idle()`` is true (a robot at rest whose readers compute due cycles
    themselves, :meth:`RobotEmulator.catch_up`) the thread sleeps up to ``idle_wait_s`` or
    until :meth:`wake`, then runs the cycles it slept through back to back (they are stamps
    of their grid times; their lateness is not recorded) and goes on.
    """

    simulated = False

    def __init__(
        self,
        period: float,
        tick: Tick,
        history: int = 10000,
        *,
        rt_priority: int = DEFAULT_RT_PRIORITY,
        switch_interval_s: float | None = REALTIME_SWITCH_INTERVAL_S,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        sleep_ns: Callable[[int], bool] | None = None,
        idle: Callable[[], bool] | None = None,
        idle_wait_s: float = 0.1,
    ) -> None:
        if not period > 0:
            raise ValueError(f"period must be > 0 s, got {period}")
        self.period = period
        self.tick = tick
        self.cycle = 0
        self.rt_priority = rt_priority
        self.switch_interval_s = switch_interval_s
        self.scheduling = "not started"
        self._clock_ns = clock_ns
        self._period_ns = round(period * 1e9)
        self._start_ns = clock_ns()
        self._stop = threading.Event()
        self._wake = threading.Event()  # set by stop() and wake()
        self._sleep_ns = sleep_ns or self._wait_ns
        self._idle = idle
        self._idle_wait_ns = round(idle_wait_s * 1e9)
        self._thread: threading.Thread | None = None
        self._lateness: deque[float] = deque(maxlen=history)
        self.overruns = 0
        self.errors = 0

    def now(self) -> float:
        return (self._clock_ns() - self._start_ns) / 1e9

    @property
    def start_ns(self) -> int:
        """The clock's zero on ``clock_ns`` (set again by :meth:`start`)."""
        return self._start_ns

    def start(self) -> RealTimeLoop:
        if self.switch_interval_s is not None:
            shorten_switch_interval(self.switch_interval_s)
        self._start_ns = self._clock_ns()
        self._thread = threading.Thread(target=self.run, name="robot-clock", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def wake(self) -> None:
        """End an idle wait now (something will move)."""
        self._wake.set()

    def _wait_ns(self, ns: int) -> bool:
        """Wait ``ns`` or until woken; True when the loop must stop."""
        if self._wake.wait(ns / 1e9):
            self._wake.clear()
        return self._stop.is_set()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def run(self) -> None:
        """The loop (the thread's target; tests call it directly with a fake clock)."""
        self.scheduling = promote_current_thread(self.rt_priority)
        log.info(
            "real-time clock started: period %.1f ms, scheduling %s, GIL switch interval %.2f ms",
            self.period * 1e3,
            self.scheduling,
            sys.getswitchinterval() * 1e3,
        )
        clock_ns = self._clock_ns
        period_ns = self._period_ns
        lateness = self._lateness
        idle = self._idle
        while not self._stop.is_set():
            if idle is not None and idle():
                if self._sleep_ns(self._idle_wait_ns):
                    break
                # the cycles slept through, at once and unrecorded (a reader may have run
                # them already: the tick skips those)
                due = (clock_ns() - self._start_ns) // period_ns
                while self.cycle < due:
                    self.cycle += 1
                    self._run_tick(self.cycle)
                continue
            k = self.cycle + 1
            deadline = self._start_ns + k * period_ns
            wait = deadline - clock_ns()
            stopped = False
            while wait > 0:  # a wake() may end the wait early: wait for the deadline again
                if self._sleep_ns(wait):
                    stopped = True
                    break
                wait = deadline - clock_ns()
            if stopped:
                break
            late = clock_ns() - deadline
            lateness.append(max(late, 0) / 1e9)
            if late > period_ns:
                self.overruns += 1
            self.cycle = k
            self._run_tick(k)
        log.info("real-time clock stopped after %d cycles", self.cycle)

    def _run_tick(self, k: int) -> None:
        try:
            self.tick(k)
        except Exception:
            # A failing tick must not stop the robot clock silently; log and go on.
            self.errors += 1
            log.exception("robot clock tick %d failed", k)

    def jitter(self) -> dict[str, float]:
        """Tick lateness in seconds over the recent history: p50, p99, max, mean; count."""
        return lateness_summary(self._lateness)


def lateness_summary(lateness: Iterable[float]) -> dict[str, float]:
    """p50, p99, max and mean of lateness samples (s), and their count."""
    samples = sorted(lateness)
    if not samples:
        return {"count": 0, "p50": 0.0, "p99": 0.0, "max": 0.0, "mean": 0.0}
    n = len(samples)
    return {
        "count": float(n),
        "p50": samples[n // 2],
        "p99": samples[min(n - 1, int(0.99 * n))],
        "max": samples[-1],
        "mean": sum(samples) / n,
    }
