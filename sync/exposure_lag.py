"""A reading's exposure lag against the sensor's usual one (SY-3.8), pure.

A sensor starts an exposure a short, steady time after a trigger arrives (its trigger poll and
start jitter: 0..0.5 ms for the paper's sensor); ΔT includes the mean of that [section VI].
A trigger that arrives while the chip is still busy with the previous frame (a robot whose
trigger thread got the CPU late sends overdue triggers back to back) is exposed only when
that frame ends, up to one acquisition time (3.5 ms) later: placed at t_i^T + ΔT, that
reading is early by as much (0.9 mm at 250 mm/s). The sensor's own stamps say by how much,
on its clock alone (no clock synchronisation): the lag from trigger arrival to exposure start
against the median of the recent readings' lags. A reading later than that by more than
``threshold_s`` is placed at t_i^T + ΔT + its extra lag: the data is late, not wrong.
Readings within the threshold keep t_i^T + ΔT exactly (extra lag 0.0), so ΔT means what it
meant before and nothing changes where no reading is late.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field

__all__ = ["DEFAULT_LAG_THRESHOLD_S", "ExposureLag"]

DEFAULT_LAG_THRESHOLD_S = 0.5e-3
"""Extra lag (s) beyond which a reading counts as exposed late: twice the spread around the
median of the paper's sensor (poll 0.25 ms + start jitter 0.25 ms), so a reading on time is
never moved."""


@dataclass
class ExposureLag:
    """The running reference of a sensor's trigger-to-exposure lag, and each reading's extra.

    Args:
        threshold_s: a reading whose lag exceeds the reference by more than this is late.
        window: readings the reference (their median lag) is taken over.
        min_readings: readings needed before any is judged (before that: extra 0.0).
        max_lag_s: a lag outside [0, max_lag_s] (stamps not ordered as SY-2.6 says, or later
            than a sensor may answer, SY-2.4) or not finite is not believed: that reading is
            not moved and does not enter the reference.
    """

    threshold_s: float = DEFAULT_LAG_THRESHOLD_S
    window: int = 64
    min_readings: int = 8
    max_lag_s: float = 0.1
    _order: deque[float] = field(default_factory=deque, init=False, repr=False)
    _sorted: list[float] = field(default_factory=list, init=False, repr=False)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.threshold_s) and self.threshold_s >= 0.0):
            raise ValueError("threshold_s must be finite and >= 0")
        if self.window < 1 or not 1 <= self.min_readings <= self.window:
            raise ValueError("need window >= 1 and 1 <= min_readings <= window")
        if not (math.isfinite(self.max_lag_s) and self.max_lag_s > 0.0):
            raise ValueError("max_lag_s must be positive")

    def reference(self) -> float:
        """Median lag (s) of the readings in the window; NaN before ``min_readings``."""
        s = self._sorted
        n = len(s)
        if n < self.min_readings:
            return math.nan
        mid = n // 2
        return s[mid] if n % 2 else 0.5 * (s[mid - 1] + s[mid])

    def extra(self, t_arrival: float, t_exposure_start: float) -> float:
        """The extra lag (s) of one reading, from its sensor-clock stamps: its lag minus the
        reference when that exceeds ``threshold_s``, else 0.0. The reading then joins the
        window (late readings too: the median ignores a few)."""
        lag = t_exposure_start - t_arrival
        if not 0.0 <= lag <= self.max_lag_s:  # NaN fails too
            return 0.0
        ref = self.reference()
        extra = lag - ref if lag - ref > self.threshold_s else 0.0  # NaN ref: 0.0
        if len(self._order) == self.window:
            old = self._order.popleft()
            del self._sorted[bisect.bisect_left(self._sorted, old)]
        self._order.append(lag)
        bisect.insort(self._sorted, lag)
        return extra
