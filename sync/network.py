"""A modelled one-way network for simulated time (no sockets).

Datagrams go in with a send time and come out at their arrival time, with optional loss,
duplication and extra delay (which reorders), so the emulated cell, the soak benchmark and the
tests drive the robot's synchronisation core (:class:`sync.udp.RobotSyncCore`) as a real
network would, deterministically for a seeded ``rng``.
"""

from __future__ import annotations

import heapq

import numpy as np

__all__ = ["DelayLink"]


class DelayLink:
    """A modelled one-way network for simulated time.

    ``send(t, datagram)`` queues a datagram sent at ``t`` (s); it arrives at ``t + delay()``
    unless lost. Faults (each with its own probability, drawn from ``rng``): loss,
    duplication (a second copy with its own delay) and an extra delay of ``reorder_delay_s``
    (which makes it overtake nothing but be overtaken: reordering).
    """

    def __init__(
        self,
        *,
        delay_s: float = 0.0,
        jitter_s: float = 0.0,
        rng: np.random.Generator | None = None,
        loss: float = 0.0,
        duplicate: float = 0.0,
        reorder: float = 0.0,
        reorder_delay_s: float = 0.01,
    ) -> None:
        if delay_s < 0 or jitter_s < 0 or jitter_s / 2 > delay_s + 1e-15:
            raise ValueError("need delay_s >= jitter_s / 2 >= 0")
        for name, p in (("loss", loss), ("duplicate", duplicate), ("reorder", reorder)):
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"{name} must be a probability, got {p}")
        if (jitter_s or loss or duplicate or reorder) and rng is None:
            raise ValueError("jitter and faults need an rng")
        self.delay_s = delay_s
        self.jitter_s = jitter_s
        self.rng = rng
        self.loss = loss
        self.duplicate = duplicate
        self.reorder = reorder
        self.reorder_delay_s = reorder_delay_s
        self._queue: list[tuple[float, int, bytes]] = []
        self._seq = 0
        self.counts = {"sent": 0, "lost": 0, "duplicated": 0, "delayed": 0, "delivered": 0}

    def _delay(self) -> float:
        d = self.delay_s
        if self.jitter_s and self.rng is not None:
            d += float(self.rng.uniform(-self.jitter_s / 2, self.jitter_s / 2))
        return d

    def _chance(self, p: float) -> bool:
        return p > 0.0 and self.rng is not None and float(self.rng.random()) < p

    def send(self, t: float, datagram: bytes) -> None:
        self.counts["sent"] += 1
        if self._chance(self.loss):
            self.counts["lost"] += 1
            return
        copies = 2 if self._chance(self.duplicate) else 1
        self.counts["duplicated"] += copies - 1
        for _ in range(copies):
            d = self._delay()
            if self._chance(self.reorder):
                self.counts["delayed"] += 1
                d += self.reorder_delay_s
            self._seq += 1
            heapq.heappush(self._queue, (t + d, self._seq, datagram))

    def deliver(self, until: float) -> list[tuple[float, bytes]]:
        """Datagrams arriving at or before ``until`` (s): (arrival time, bytes), in order."""
        out = []
        while self._queue and self._queue[0][0] <= until:
            t, _, data = heapq.heappop(self._queue)
            out.append((t, data))
        self.counts["delivered"] += len(out)
        return out
