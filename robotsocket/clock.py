"""The two robot cycle loops: simulated (advanced explicitly) and real time (a 4 ms thread).

Both drive the same tick function with the cycle index k; the sample time is t_k = k * T_r.
:class:`SimLoop` never advances by itself: the owner calls :meth:`SimLoop.advance` (it counts
cycles; the sensor's :class:`sensorsocket.sensor.SimClock` is a settable clock in seconds).
:class:`RealTimeLoop` ticks on absolute deadlines start + k * T_r from ``time.monotonic_ns``
and waits on an :class:`threading.Event` with a timeout (so ``stop`` wakes it at once), not
on short sleeps; late ticks are run back to back so k stays on the time axis. It records the
lateness of every tick (tick jitter).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable

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
    started (s). A tick that overruns makes the next ones late; they run at once to catch up.
    """

    simulated = False

    def __init__(self, period: float, tick: Tick, history: int = 10000) -> None:
        if not period > 0:
            raise ValueError(f"period must be > 0 s, got {period}")
        self.period = period
        self.tick = tick
        self.cycle = 0
        self._period_ns = round(period * 1e9)
        self._start_ns = time.monotonic_ns()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lateness: deque[float] = deque(maxlen=history)
        self.overruns = 0
        self.errors = 0

    def now(self) -> float:
        return (time.monotonic_ns() - self._start_ns) / 1e9

    def start(self) -> RealTimeLoop:
        self._start_ns = time.monotonic_ns()
        self._thread = threading.Thread(target=self._run, name="robot-clock", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _run(self) -> None:
        log.info("real-time clock started: period %.1f ms", self.period * 1e3)
        while not self._stop.is_set():
            k = self.cycle + 1
            deadline = self._start_ns + k * self._period_ns
            wait = deadline - time.monotonic_ns()
            if wait > 0 and self._stop.wait(wait / 1e9):
                break
            late = time.monotonic_ns() - deadline
            self._lateness.append(max(late, 0) / 1e9)
            if late > self._period_ns:
                self.overruns += 1
            self.cycle = k
            try:
                self.tick(k)
            except Exception:
                # A failing tick must not stop the robot clock silently; log and go on.
                self.errors += 1
                log.exception("robot clock tick %d failed", k)
        log.info("real-time clock stopped after %d cycles", self.cycle)

    def jitter(self) -> dict[str, float]:
        """Tick lateness in seconds over the recent history: p50, p99, max, mean; count."""
        samples = sorted(self._lateness)
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
