"""Real-time seam tracking (method 2 of the paper): the laser follows the seam the sensor
measures ahead of it, corrected every 4 ms cycle through alter mode (PROTOCOL.md RS-5.32).

The pure parts: :class:`NominalWeld` (the laser tool's straight, timed nominal path),
:class:`SeamModel` (the synchronised seam points ^B_G T of the trigger stream as offsets from
the nominal path, smoothed by a local quadratic fit *centred* on the laser: the sensor is the
look-ahead distance ahead, so the laser point lies inside the measured seam and the filter
adds no lag) and :class:`Tracker` (the correction for the cycle the robot applies next, and
the safety rule: no measured seam where the laser goes means the weld stops).

:func:`run_tracking` drives the emulated cell in simulated time and scores the laser focal
point against the cell's true seam (lateral and height error, max and rms over the weld).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from robotsocket.alter import MAX_OFFSET_MM

FloatArray = NDArray[np.float64]

#: Half width of the seam fit around the laser point (mm): several points at 250 mm/s and
#: 200 Hz (one per 1.25 mm) while short against the seam's curvature (R ≈ 32 mm).
FIT_HALF_WIDTH_MM = 4.0
#: Fewest seam points a fit needs.
MIN_FIT_POINTS = 4
#: The seam must be measured this far ahead of the laser (mm) or the weld stops: the
#: look-ahead minus the distance travelled while a seam point is on its way (ΔT, matching).
MIN_AHEAD_MM = 10.0


class TrackingError(Exception):
    """The seam is lost (sensor silent, seam out of view or beyond the correction range)."""


@dataclass(frozen=True)
class NominalWeld:
    """The laser tool's nominal path: a straight line from ``start`` (3,) mm along the unit
    ``direction`` (3,), base frame, ``length_mm`` long, at ``speed_mm_s`` with constant
    acceleration ramps of ``accel_mm_s2`` at both ends; the tool keeps ``angles`` (3,) deg."""

    start: FloatArray
    direction: FloatArray
    angles: FloatArray
    length_mm: float
    speed_mm_s: float
    accel_mm_s2: float = 2500.0

    def __post_init__(self) -> None:
        if not (0.0 < self.speed_mm_s <= 1000.0):
            raise ValueError(f"speed must be in (0, 1000] mm/s, got {self.speed_mm_s}")
        if not (0.0 < self.length_mm <= 2000.0):
            raise ValueError(f"length must be in (0, 2000] mm, got {self.length_mm}")

    @property
    def _ramp(self) -> tuple[float, float]:
        """(ramp time, ramp length); the speed is reached (the line is long enough)."""
        v, a = self.speed_mm_s, self.accel_mm_s2
        t_r = v / a
        d_r = 0.5 * a * t_r * t_r
        if 2.0 * d_r > self.length_mm:
            raise ValueError("the weld is too short to reach its speed")
        return t_r, d_r

    @property
    def duration(self) -> float:
        t_r, d_r = self._ramp
        return 2.0 * t_r + (self.length_mm - 2.0 * d_r) / self.speed_mm_s

    def s_at(self, t: FloatArray | float) -> FloatArray:
        """Arc length (mm) at ``t`` s after the move starts (any shape)."""
        tt = np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration)
        v, a = self.speed_mm_s, self.accel_mm_s2
        t_r, d_r = self._ramp
        t_end = self.duration
        s = np.where(
            tt < t_r,
            0.5 * a * tt * tt,
            np.where(
                tt <= t_end - t_r,
                d_r + v * (tt - t_r),
                self.length_mm - 0.5 * a * (t_end - tt) ** 2,
            ),
        )
        out: FloatArray = s
        return out

    def point(self, s: FloatArray | float) -> FloatArray:
        """Nominal laser points (..., 3) at arc lengths ``s``."""
        ss = np.asarray(s, dtype=np.float64)[..., None]
        out: FloatArray = self.start + ss * self.direction
        return out

    def timed_path(self, period: float) -> tuple[FloatArray, FloatArray]:
        """(times (N,), laser locations (N, 6)) sampled every ``period`` for
        ToolMoveTrajectory; the robot's path between samples is linear, so the tracker's
        :meth:`s_at` and the robot agree to within the chord of one 4 ms sample."""
        n = math.ceil(self.duration / period)
        times: FloatArray = np.arange(n + 1, dtype=np.float64) * period
        times[-1] = max(times[-1], self.duration)
        pts = self.point(self.s_at(times))
        locs = np.column_stack([pts, np.tile(self.angles, (len(times), 1))])
        return times, locs


@dataclass
class SeamModel:
    """The measured seam as offsets e(s) (3,) from the nominal laser path, base frame."""

    weld: NominalWeld
    half_width_mm: float = FIT_HALF_WIDTH_MM
    _s: FloatArray = field(default_factory=lambda: np.zeros(0))
    _e: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))

    def add(self, points: FloatArray) -> None:
        """Seam points (M, 3) in the base frame (^B_G T translations)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        s = (p - self.weld.start) @ self.weld.direction
        e = p - self.weld.point(s)
        self._s = np.concatenate([self._s, s])
        self._e = np.concatenate([self._e, e])

    @property
    def count(self) -> int:
        return len(self._s)

    def points(self) -> FloatArray:
        """The measured seam points (M, 3), base frame."""
        out: FloatArray = self.weld.point(self._s) + self._e
        return out

    @property
    def furthest(self) -> float:
        """The furthest arc length measured (mm; -inf before the first point)."""
        return float(self._s.max()) if len(self._s) else -math.inf

    def offset_at(self, s: float) -> FloatArray:
        """Seam offset (3,) at arc length ``s``: a tricube-weighted quadratic fit of the
        points within ``half_width_mm``; before the first measured point, the offset there
        (the laser is brought onto the seam before it reaches it)."""
        if not len(self._s):
            raise TrackingError("no seam point measured")
        ss = self._s
        s0 = max(s, float(ss.min()))
        h = self.half_width_mm
        near = np.abs(ss - s0) <= h
        if np.count_nonzero(near) < MIN_FIT_POINTS:
            raise TrackingError(f"too few seam points around s = {s0:.1f} mm")
        x = ss[near] - s0
        y = self._e[near]
        w = (1.0 - (np.abs(x) / h) ** 3) ** 3 + 1e-6
        span = float(x.max() - x.min())
        deg = 2 if span > 0.5 * h else 0  # a standing arm measures one place: average it
        A = np.vander(x, deg + 1, increasing=True) * np.sqrt(w)[:, None]
        coef, *_ = np.linalg.lstsq(A, y * np.sqrt(w)[:, None], rcond=None)
        out: FloatArray = coef[0]
        return out


@dataclass
class Tracker:
    """The correction each cycle: the seam offset at the laser's nominal arc length at the
    cycle that applies it. ``look_ahead_mm`` is the sensor's lead over the laser (the sensor
    tool offset); ``max_correction_mm`` the robot's alter limit."""

    weld: NominalWeld
    look_ahead_mm: float
    max_correction_mm: float = MAX_OFFSET_MM
    model: SeamModel = field(init=False)

    def __post_init__(self) -> None:
        self.model = SeamModel(self.weld)

    def correction(self, t_move: float) -> FloatArray:
        """Correction (6,) (mm, deg; base frame) for the laser at ``t_move`` s after the move
        start. Raises :class:`TrackingError` when the seam ahead is not measured or needs more
        than the robot may correct: the weld must stop."""
        s = float(self.weld.s_at(t_move))
        sensor_at = min(s + self.look_ahead_mm, self.weld.length_mm)
        if self.model.furthest < sensor_at - MIN_AHEAD_MM:
            raise TrackingError(
                f"seam not measured ahead of the laser: furthest point {self.model.furthest:.1f}"
                f" mm, sensor at {sensor_at:.1f} mm"
            )
        e = self.model.offset_at(s)
        if float(np.linalg.norm(e)) > self.max_correction_mm:
            raise TrackingError(
                f"the seam is {np.linalg.norm(e):.2f} mm off the path: more than"
                f" {self.max_correction_mm} mm"
            )
        return np.concatenate([e, np.zeros(3)])


def seam_error(
    laser2base_points: FloatArray,
    base2workpiece: FloatArray,
    lateral_of: Callable[[FloatArray, FloatArray], FloatArray],
    seam_height_mm: float,
) -> tuple[FloatArray, FloatArray]:
    """(lateral (N,), height (N,)) errors in mm of laser points (N, 3) from the true seam."""
    p = np.column_stack([laser2base_points, np.ones(len(laser2base_points))]) @ base2workpiece.T
    lateral = lateral_of(p[:, 0], p[:, 1])
    height = p[:, 2] - seam_height_mm
    return np.asarray(lateral, dtype=np.float64), np.asarray(height, dtype=np.float64)
