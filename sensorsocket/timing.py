"""Trigger-to-exposure timing of the seam-tracking sensor (paper section V), simulated time.

All times are seconds on the sensor's clock. A trigger datagram arriving at ``t_arrival``
is noticed at the next poll of the 4 kHz trigger loop (``t_poll``, 0..0.25 ms later), the
acquisition starts after a further start jitter (uniform 0..0.25 ms), and the chip is read
column by column: column k of the readout window integrates light during
``[t_exposure_start + k·dt, t_exposure_start + k·dt + exposure]`` with the column period
``dt = full_frame_time / 512`` (3.5 ms / 512 ≈ 6.8 µs), so a window of n columns takes
``n·dt`` and, with the default exposure of one column period, the exposure window
``t_exposure_end - t_exposure_start`` equals the acquisition time n·dt. A column's time
(the one used for its pose) is the middle of its integration interval. Processing of the
image takes ``processing_time_s`` (simulated; a real-time caller measures it instead).

Polling: ``poll_mode="random"`` draws the poll delay uniform in [0, 1/poll_rate) for every
trigger — what the paper assumes, and what a poll loop on a clock independent of the robot's
gives over time; ``"grid"`` polls at ``phase + k/poll_rate`` on the sensor clock, which is
deterministic for a given arrival time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from kinematics.types import FloatArray


class TimingError(ValueError):
    """Invalid timing parameter or readout window."""


@dataclass(frozen=True)
class Acquisition:
    """When one triggered image was taken (seconds, sensor clock).

    ``column_times`` (n_columns,) is the mid-integration time of each read column,
    in readout order; column ``first_column + i`` has ``column_times[i]``.
    """

    t_arrival: float
    t_poll: float
    t_exposure_start: float
    t_exposure_end: float
    t_done: float
    first_column: int
    n_columns: int
    exposure_s: float
    column_period_s: float
    column_times: FloatArray = field(repr=False)

    def column_time(self, column: float) -> float:
        """Time (s) of a possibly fractional chip column inside the readout window."""
        k = column - self.first_column
        if not math.isfinite(column) or not -0.5 <= k <= self.n_columns - 0.5:
            return math.nan
        return float(self.column_times[0] + k * self.column_period_s)


class TimingModel:
    """Trigger polling, start jitter, column-wise acquisition and processing time."""

    def __init__(
        self,
        *,
        rng: np.random.Generator,
        poll_rate_hz: float = 4000.0,
        start_jitter_s: float = 0.25e-3,
        start_latency_s: float = 0.0,
        full_frame_time_s: float = 3.5e-3,
        full_frame_columns: int = 512,
        processing_time_s: float = 1.0e-3,
        poll_mode: Literal["random", "grid"] = "random",
        poll_phase_s: float | None = None,
    ) -> None:
        if not (poll_rate_hz > 0 and math.isfinite(poll_rate_hz)):
            raise TimingError("poll_rate_hz must be positive")
        for name, value in (
            ("start_jitter_s", start_jitter_s),
            ("start_latency_s", start_latency_s),
            ("processing_time_s", processing_time_s),
        ):
            if not (value >= 0 and math.isfinite(value)):
                raise TimingError(f"{name} must be >= 0")
        if not (full_frame_time_s > 0 and math.isfinite(full_frame_time_s)):
            raise TimingError("full_frame_time_s must be positive")
        if full_frame_columns < 1:
            raise TimingError("full_frame_columns must be >= 1")
        if poll_mode not in ("random", "grid"):
            raise TimingError("poll_mode must be 'random' or 'grid'")
        self.rng = rng
        self.poll_period_s = 1.0 / poll_rate_hz
        self.start_jitter_s = start_jitter_s
        self.start_latency_s = start_latency_s
        self.full_frame_time_s = full_frame_time_s
        self.full_frame_columns = full_frame_columns
        self.processing_time_s = processing_time_s
        self.poll_mode = poll_mode
        if poll_phase_s is None:
            poll_phase_s = float(rng.uniform(0.0, self.poll_period_s))
        self.poll_phase_s = poll_phase_s

    @property
    def column_period_s(self) -> float:
        """Readout time of one column (s)."""
        return self.full_frame_time_s / self.full_frame_columns

    def acquisition_time(self, n_columns: int) -> float:
        """Time to read a window of n columns (s), proportional to its width."""
        return n_columns * self.column_period_s

    def poll_time(self, t_arrival: float) -> float:
        """When the trigger loop notices a datagram that arrived at t_arrival (s)."""
        if self.poll_mode == "random":
            return t_arrival + float(self.rng.uniform(0.0, self.poll_period_s))
        k = math.ceil((t_arrival - self.poll_phase_s) / self.poll_period_s)
        return self.poll_phase_s + k * self.poll_period_s

    def schedule(
        self,
        t_arrival: float,
        *,
        first_column: int = 0,
        n_columns: int | None = None,
        exposure_s: float | None = None,
        not_before: float = -math.inf,
    ) -> Acquisition:
        """Timestamps of the acquisition triggered by a datagram arriving at t_arrival.

        ``not_before``: the sensor cannot start while a previous acquisition still runs.
        """
        if not math.isfinite(t_arrival):
            raise TimingError("t_arrival must be finite")
        n = self.full_frame_columns - first_column if n_columns is None else n_columns
        if first_column < 0 or n < 1 or first_column + n > self.full_frame_columns:
            raise TimingError(
                f"readout window {first_column}+{n} outside 0..{self.full_frame_columns}"
            )
        dt = self.column_period_s
        exposure = dt if exposure_s is None else exposure_s
        if not (exposure > 0 and math.isfinite(exposure)):
            raise TimingError("exposure_s must be positive")
        t_poll = self.poll_time(t_arrival)
        jitter = float(self.rng.uniform(0.0, self.start_jitter_s)) if self.start_jitter_s else 0.0
        t_start = max(t_poll + self.start_latency_s + jitter, not_before)
        column_times: FloatArray = t_start + np.arange(n, dtype=np.float64) * dt + exposure / 2.0
        t_end = t_start + (n - 1) * dt + exposure
        return Acquisition(
            t_arrival=t_arrival,
            t_poll=t_poll,
            t_exposure_start=t_start,
            t_exposure_end=t_end,
            t_done=t_end + self.processing_time_s,
            first_column=first_column,
            n_columns=n,
            exposure_s=exposure,
            column_period_s=dt,
            column_times=column_times,
        )
