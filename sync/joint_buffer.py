"""The robot controller's cyclic joint buffer of (t_k^R, q_k^m) (paper section V).

The controller stores one measured joint vector per cycle (T_r = 4 ms) with its time stamp.
Old samples fall out when the buffer is full. Time is an argument: nothing here reads a clock.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "DEFAULT_CAPACITY",
    "DEFAULT_CYCLE_S",
    "JointBuffer",
    "JointBufferError",
]

DEFAULT_CYCLE_S = 0.004
"""Robot sample period T_r in seconds (section V: 4 ms)."""

DEFAULT_CAPACITY = 2500
"""10 s of history at T_r = 4 ms."""


class JointBufferError(ValueError):
    """A sample was rejected: bad shape, not finite, or not strictly newer than the last one."""


class JointBuffer:
    """Fixed-capacity ring of joint samples, oldest dropped first.

    Storage is doubled (each sample is written at ``p`` and ``p + capacity``) so the samples
    in time order are always one contiguous slice; reads never need a concatenation.

    Times are seconds on the robot clock, joints are degrees, shape ``(n_joints,)``.
    """

    def __init__(self, capacity: int = DEFAULT_CAPACITY, n_joints: int = 6) -> None:
        if capacity < 2:
            raise ValueError(f"capacity must be >= 2, got {capacity}")
        if n_joints < 1:
            raise ValueError(f"n_joints must be >= 1, got {n_joints}")
        self._capacity = capacity
        self._n_joints = n_joints
        self._times = np.empty(2 * capacity, dtype=np.float64)
        self._joints = np.empty((2 * capacity, n_joints), dtype=np.float64)
        self._start = 0  # slot of the oldest sample, in [0, capacity)
        self._count = 0
        self._latest = -math.inf  # time of the newest sample as a float (when _count > 0)

    @property
    def capacity(self) -> int:
        """Maximum number of samples kept."""
        return self._capacity

    @property
    def n_joints(self) -> int:
        """Length of one joint vector."""
        return self._n_joints

    def __len__(self) -> int:
        return self._count

    @property
    def latest_time(self) -> float | None:
        """Time of the newest sample in seconds, ``None`` when empty."""
        if self._count == 0:
            return None
        return float(self._times[self._start + self._count - 1])

    @property
    def oldest_time(self) -> float | None:
        """Time of the oldest sample still held in seconds, ``None`` when empty."""
        if self._count == 0:
            return None
        return float(self._times[self._start])

    def append(self, t: float, q: ArrayLike) -> None:
        """Store one sample: time ``t`` (s) and joints ``q`` (degrees, shape ``(n_joints,)``).

        Raises :class:`JointBufferError` when ``t`` is not finite or not strictly later than
        the newest sample, or when ``q`` has the wrong shape or a non-finite value.
        """
        t = float(t)
        qa = np.asarray(q, dtype=np.float64)
        if qa.shape != (self._n_joints,):
            raise JointBufferError(f"joints must have shape ({self._n_joints},), got {qa.shape}")
        if not math.isfinite(t):
            raise JointBufferError(f"time must be finite, got {t}")
        if not np.isfinite(qa).all():  # the method: np.all's wrapper costs more than the test
            raise JointBufferError("joints must be finite")
        if self._count and not t > self._latest:
            raise JointBufferError(
                f"time {t!r} is not after the latest sample {self.latest_time!r}"
            )
        if self._count < self._capacity:
            slot = self._start + self._count
            self._count += 1
        else:
            slot = self._start  # overwrite the oldest
            self._start = (self._start + 1) % self._capacity
        slot %= self._capacity
        self._times[slot] = t
        self._times[slot + self._capacity] = t
        self._latest = t
        self._joints[slot] = qa
        self._joints[slot + self._capacity] = qa

    def extend(self, times: ArrayLike, joints: ArrayLike) -> None:
        """Append many samples: ``times`` (N,) s, ``joints`` (N, n_joints) degrees.

        All-or-nothing: the batch is checked before anything is stored.
        """
        ta = np.asarray(times, dtype=np.float64)
        qa = np.asarray(joints, dtype=np.float64)
        if ta.ndim != 1 or qa.shape != (ta.shape[0], self._n_joints):
            raise JointBufferError(
                f"expected times (N,) and joints (N, {self._n_joints}), got {ta.shape}, {qa.shape}"
            )
        if ta.size == 0:
            return
        if not (np.all(np.isfinite(ta)) and np.all(np.isfinite(qa))):
            raise JointBufferError("times and joints must be finite")
        if ta.size > 1 and not np.all(np.diff(ta) > 0):
            raise JointBufferError("times must be strictly increasing")
        latest = self.latest_time
        if latest is not None and not ta[0] > latest:
            raise JointBufferError(f"time {ta[0]!r} is not after the latest sample {latest!r}")
        for t, q in zip(ta[-self._capacity :], qa[-self._capacity :], strict=True):
            self.append(float(t), q)

    def _view(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        s, n = self._start, self._count
        return self._times[s : s + n], self._joints[s : s + n]

    def samples(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """All held samples in time order: copies of times (N,) s and joints (N, n_joints)."""
        t, q = self._view()
        return t.copy(), q.copy()

    def since(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Samples with time >= ``t`` in time order: copies of times (N,) and joints (N, n)."""
        times, joints = self._view()
        k = int(np.searchsorted(times, t, side="left"))
        return times[k:].copy(), joints[k:].copy()

    def covering(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Samples needed to interpolate at any time >= ``t``: like :meth:`since` plus the
        last sample before ``t`` (the left end of the interval that contains ``t``)."""
        times, joints = self._view()
        k = max(int(np.searchsorted(times, t, side="right")) - 1, 0)
        return times[k:].copy(), joints[k:].copy()

    def clear(self) -> None:
        """Drop every sample (a new session starts a new time axis)."""
        self._start = 0
        self._count = 0
