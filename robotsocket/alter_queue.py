"""Timed corrections (PROTOCOL.md RS-5.39 ... RS-5.46), pure: the robot's queue of future
corrections, each for a robot-clock time, and the correction it gives each 4 ms cycle.

Why robot-clock time and not arc length: every other stamp of the protocol (joint log,
triggers, seam points) is robot-clock time, so a tracker computes "the laser passes here at
t" from what it already has; the robot resolves a time without knowing the path's
parametrisation (a ToolMoveTrajectory, a blended move, a stand, a StopMove deceleration all
have a time, not all an arc length the two sides agree on); and a learned table (ILC) is a
function of time since the move's start, which the client shifts by the start it knows.

A client sends batches ahead of time (a look-ahead window, or a whole table in several
frames). The rules, one place each:

- a batch's times are finite and strictly increasing, its corrections within RS-5.33; else
  the whole batch is refused and the queue is unchanged [RS-5.40];
- an entry for a cycle already applied is late: dropped and counted, the rest of the batch
  applies [RS-5.42];
- a batch replaces the queued entries inside its own time span: a duplicate (a resend) is
  harmless, batches may arrive in any order, a later batch overrides an earlier one
  [RS-5.41];
- a batch that would make the queue longer than its capacity is refused whole [RS-5.43];
- each cycle the correction in force is the linear interpolation of the two entries around
  the cycle's time; past the last entry the last one is held (never extrapolated), before
  the first one the queue gives nothing (the immediate correction of Alter, or zero, stays
  in force) [RS-5.44].

No clock, no I/O, no lock: :class:`~robotsocket.alter.AlterState` owns one and calls
:meth:`CorrectionQueue.due` from the real-time cycle with the cycle's time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinematics.types import FloatArray
from robotsocket.interface import BusyError, OutOfRangeError

__all__ = ["MAX_BATCH", "MAX_ENTRIES", "CorrectionQueue", "QueueReport", "check_batch"]

#: [RS-5.43] Entries the queue holds: 65 s at one per 4 ms cycle, a whole weld's table.
MAX_ENTRIES = 16384
#: [RS-5.40] Entries per AlterQueue frame: 4096 x 56 bytes ≈ 230 KiB, well inside every
#: server's payload limit; a longer table travels in several frames.
MAX_BATCH = 4096


@dataclass(frozen=True)
class QueueReport:
    """What AlterQueue answers [RS-5.45]: entries of this batch accepted and dropped as late,
    then the queue's state: entries queued, the time of the last one (-1 when empty; robot
    clock, s), and the counters since AlterBegin: late entries and held cycles (cycles whose
    time was past the last entry while timed corrections were in use)."""

    accepted: int
    late: int
    depth: int
    horizon: float
    late_total: int
    held_total: int


def check_batch(
    times: FloatArray, corrections: FloatArray, limit_mm: float, limit_deg: float
) -> None:
    """OutOfRangeError unless ``times`` (N,) are finite, strictly increasing and at most
    :data:`MAX_BATCH`, and ``corrections`` (N, 6) are finite and within the RS-5.33 limits
    (``limit_mm`` translation, ``limit_deg`` rotation) [RS-5.40]."""
    n = len(times)
    if n > MAX_BATCH:
        raise OutOfRangeError(f"a batch holds at most {MAX_BATCH} entries, got {n}")
    if corrections.shape != (n, 6):
        raise OutOfRangeError(
            f"corrections must be {n} x 6 (one row per time), got "
            + " x ".join(str(d) for d in corrections.shape)
        )
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(corrections))):
        raise OutOfRangeError("times and corrections must be finite")
    if n > 1 and not np.all(np.diff(times) > 0.0):
        k = int(np.argmax(np.diff(times) <= 0.0)) + 1
        raise OutOfRangeError(f"times must increase strictly: entry {k} is not after {k - 1}")
    if n:
        size = np.linalg.norm(corrections[:, :3], axis=1)
        turn = np.linalg.norm(corrections[:, 3:], axis=1)
        if float(size.max()) > limit_mm + 1e-9:
            k = int(np.argmax(size))
            raise OutOfRangeError(
                f"entry {k}: correction translation {size[k]:.3f} mm exceeds {limit_mm} mm"
            )
        if float(turn.max()) > limit_deg + 1e-9:
            k = int(np.argmax(turn))
            raise OutOfRangeError(
                f"entry {k}: correction rotation {turn[k]:.3f} deg exceeds {limit_deg} deg"
            )


class CorrectionQueue:
    """Future corrections (robot-clock time s, correction (6,) mm and deg), sorted by time.

    ``capacity``: entries it holds at most. The entry just before the last cycle applied is
    kept (it is the left end of the interpolation), everything older is dropped.
    """

    def __init__(self, capacity: int = MAX_ENTRIES) -> None:
        self.capacity = capacity
        self._t = np.zeros(0)
        self._c = np.zeros((0, 6))
        self.applied_until = -math.inf  # time of the last cycle :meth:`due` was asked for
        self.late_total = 0
        self.held_total = 0

    @property
    def depth(self) -> int:
        return len(self._t)

    @property
    def horizon(self) -> float:
        """Time (s) of the last queued entry, -inf when empty."""
        return float(self._t[-1]) if len(self._t) else -math.inf

    def clear(self) -> None:
        """Drop every entry and the counters (AlterBegin, AlterEnd, a lost stream)."""
        self._t = np.zeros(0)
        self._c = np.zeros((0, 6))
        self.applied_until = -math.inf
        self.late_total = 0
        self.held_total = 0

    def report(self, accepted: int = 0, late: int = 0) -> QueueReport:
        horizon = self.horizon
        return QueueReport(
            accepted,
            late,
            self.depth,
            horizon if math.isfinite(horizon) else -1.0,
            self.late_total,
            self.held_total,
        )

    def insert(self, times: FloatArray, corrections: FloatArray) -> QueueReport:
        """Merge a checked batch (:func:`check_batch`): late entries dropped [RS-5.42], the
        queued entries inside the batch's span replaced [RS-5.41]; BusyError when the
        result would exceed the capacity, the queue then unchanged [RS-5.43]."""
        t = np.asarray(times, dtype=np.float64)
        c = np.asarray(corrections, dtype=np.float64).reshape(len(t), 6)
        fresh = t > self.applied_until
        late = int(len(t) - np.count_nonzero(fresh))
        t, c = t[fresh], c[fresh]
        if not len(t):
            self.late_total += late
            return self.report(0, late)
        keep = (self._t < t[0]) | (self._t > t[-1])
        depth = int(np.count_nonzero(keep)) + len(t)
        if depth > self.capacity:
            raise BusyError(
                f"correction queue full: {depth} entries would exceed its {self.capacity}"
            )
        self.late_total += late
        # the kept entries lie wholly before or after the batch: concatenating in that
        # order keeps the queue sorted
        before = keep & (self._t < t[0])
        after = keep & (self._t > t[-1])
        self._t = np.concatenate([self._t[before], t, self._t[after]])
        self._c = np.concatenate([self._c[before], c, self._c[after]])
        return self.report(len(t), late)

    def due(self, t: float) -> FloatArray | None:
        """The correction (6,) in force at the cycle of time ``t`` [RS-5.44]: interpolated
        between the entries around ``t``, the last one held past the end (a held cycle),
        None before the first entry. Entries before the left one are dropped; the cycle
        counts as applied (later entries for it or before it are late)."""
        self.applied_until = max(self.applied_until, t)
        ts = self._t
        if not len(ts) or t < ts[0]:
            return None
        i = int(np.searchsorted(ts, t, side="right")) - 1  # ts[i] <= t
        if i > 0:
            self._t, self._c = ts[i:], self._c[i:]
            ts = self._t
        if len(ts) == 1 or t >= ts[-1]:
            if t > ts[-1]:
                self.held_total += 1
            out: FloatArray = self._c[-1].copy()
            return out
        w = (t - ts[0]) / (ts[1] - ts[0])
        out = self._c[0] + w * (self._c[1] - self._c[0])
        return out
