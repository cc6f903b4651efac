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

from kinematics.types import FloatArray
from robotsocket.alter import MAX_OFFSET_MM

#: Half width of the seam fit around the laser point (mm): several points at 250 mm/s and
#: 200 Hz (one per 1.25 mm) while short against the seam's curvature (R ≈ 32 mm).
FIT_HALF_WIDTH_MM = 4.0
#: Fewest seam points a fit needs.
MIN_FIT_POINTS = 4
#: The seam must be measured this far ahead of the laser (mm) or the weld stops: the fit
#: window around the laser point, a point's spacing and the cycles the stop takes to reach
#: the robot. The rest of the sensor's look-ahead is room for late seam points (ΔT,
#: matching, a busy machine: late, not wrong); a silent sensor still stops the weld before
#: the laser leaves the measured seam.
MIN_AHEAD_MM = 10.0


class TrackingError(Exception):
    """The seam is lost (sensor silent, seam out of view or beyond the correction range)."""


class WeldPath:
    """The motion law along a nominal laser path of ``length_mm`` (arc length s): constant
    acceleration ramps of ``accel_mm_s2`` at both ends, ``speed_mm_s`` between; the tool
    keeps ``angles`` (3,) deg. Subclasses give the geometry: :meth:`point` and
    :meth:`project`."""

    angles: FloatArray
    length_mm: float
    speed_mm_s: float
    accel_mm_s2: float

    def _check_law(self) -> None:
        if not (0.0 < self.speed_mm_s <= 1000.0):
            raise ValueError(f"speed must be in (0, 1000] mm/s, got {self.speed_mm_s}")
        if not (0.0 < self.length_mm <= 2000.0):
            raise ValueError(f"length must be in (0, 2000] mm, got {self.length_mm}")

    def point(self, s: FloatArray | float) -> FloatArray:
        raise NotImplementedError

    def project(self, points: FloatArray) -> FloatArray:
        raise NotImplementedError

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


@dataclass(frozen=True)
class NominalWeld(WeldPath):
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
        self._check_law()

    def point(self, s: FloatArray | float) -> FloatArray:
        """Nominal laser points (..., 3) at arc lengths ``s``."""
        ss = np.asarray(s, dtype=np.float64)[..., None]
        out: FloatArray = self.start + ss * self.direction
        return out

    def project(self, points: FloatArray) -> FloatArray:
        """Arc lengths (M,) of the points (M, 3) projected on the line (unbounded)."""
        out: FloatArray = (points - self.start) @ self.direction
        return out


@dataclass
class SeamModel:
    """The measured seam as offsets e(s) (3,) from the nominal laser path, base frame."""

    weld: WeldPath
    half_width_mm: float = FIT_HALF_WIDTH_MM
    _s: FloatArray = field(default_factory=lambda: np.zeros(0))
    _e: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))

    def add(self, points: FloatArray) -> None:
        """Seam points (M, 3) in the base frame (^B_G T translations)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        p = p[np.all(np.isfinite(p), axis=1)]
        s = self.weld.project(p)
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
    def first(self) -> float:
        """The nearest arc length measured (mm; +inf before the first point)."""
        return float(self._s.min()) if len(self._s) else math.inf

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

    def scatter_at(self, s: float) -> float:
        """RMS distance (mm) of the seam points within ``half_width_mm`` of ``s`` from the
        local fit there, weighted as the fit: how far one measurement is from the seam the
        tracker believes; 0 where there are too few points to tell."""
        ss = self._s
        near = np.abs(ss - s) <= self.half_width_mm
        n = int(np.count_nonzero(near))
        if n <= MIN_FIT_POINTS:
            return 0.0
        x = ss[near] - s
        w = (1.0 - (np.abs(x) / self.half_width_mm) ** 3) ** 3 + 1e-6
        A = np.vander(x, 3, increasing=True)
        sw = np.sqrt(w)[:, None]
        coef, *_ = np.linalg.lstsq(A * sw, self._e[near] * sw, rcond=None)
        r = np.linalg.norm(self._e[near] - A @ coef, axis=1)
        # the degrees of freedom the quadratic took from the points
        return float(np.sqrt(np.sum(w * r**2) / np.sum(w) * n / (n - 3)))


@dataclass(frozen=True)
class OffsetWeld(WeldPath):
    """``base`` moved by a taught seam: rows (arc length mm, offset (3,) mm, base frame)
    ``seam``, linear between them, its ends held; the law and the tool's angles are the
    base's, and so is the arc length (:meth:`project` is the base's: the offsets are
    across the path). A tracker on it measures the workpiece's deviation from the taught
    seam, not the seam itself."""

    base: WeldPath
    seam: FloatArray
    angles: FloatArray = field(init=False)
    length_mm: float = field(init=False)
    speed_mm_s: float = field(init=False)
    accel_mm_s2: float = field(init=False)

    def __post_init__(self) -> None:
        for name in ("angles", "length_mm", "speed_mm_s", "accel_mm_s2"):
            object.__setattr__(self, name, getattr(self.base, name))
        seam = np.asarray(self.seam, dtype=np.float64).reshape(-1, 4)
        if len(seam) and not np.all(np.diff(seam[:, 0]) > 0):
            raise ValueError("the taught seam's arc lengths must increase")
        object.__setattr__(self, "seam", seam)

    def offsets(self, s: FloatArray | float) -> FloatArray:
        """The taught offsets (..., 3) at arc lengths ``s``; zero without a seam."""
        ss = np.asarray(s, dtype=np.float64)
        if not len(self.seam):
            return np.zeros((*ss.shape, 3))
        out: FloatArray = np.stack(
            [np.interp(ss, self.seam[:, 0], self.seam[:, 1 + c]) for c in range(3)], axis=-1
        )
        return out

    def point(self, s: FloatArray | float) -> FloatArray:
        out: FloatArray = self.base.point(s) + self.offsets(s)
        return out

    def project(self, points: FloatArray) -> FloatArray:
        return self.base.project(points)


@dataclass
class Tracker:
    """The correction each cycle: the seam offset at the laser's nominal arc length at the
    cycle that applies it. ``look_ahead_mm`` is the sensor's lead over the laser (the sensor
    tool offset); ``max_correction_mm`` the robot's alter limit."""

    weld: WeldPath
    look_ahead_mm: float
    max_correction_mm: float = MAX_OFFSET_MM
    #: arc length (mm) where the seam may end (the weld's end): the sensor need not see
    #: beyond it; default the path's end
    seam_end_mm: float | None = None
    #: the half width of the seam fit (mm, :class:`SeamModel`)
    fit_half_width_mm: float = FIT_HALF_WIDTH_MM
    #: a taught seam on ``weld`` (its base): the model measures the workpiece's deviation
    #: from it and the correction is the taught offset plus that deviation
    taught: OffsetWeld | None = None
    #: with ``taught``: the seam as this arm's sensor reads it where the workpiece is the
    #: taught one (an ILC table's last trial, :attr:`welding.ilc.IlcTable.seen`): the arm's
    #: repeatable error at the sensor, 40 mm ahead of the laser, is in it and is not the
    #: workpiece's; the deviation is measured from it (default: from ``taught``)
    expected: OffsetWeld | None = None
    model: SeamModel = field(init=False)

    def __post_init__(self) -> None:
        base = self.taught if self.expected is None else self.expected
        self.model = SeamModel(base or self.weld, self.fit_half_width_mm)

    def base_correction(self, s: float) -> FloatArray:
        """The correction (6,) before any seam point: the taught offset at ``s`` (zero
        without a taught seam)."""
        if self.taught is None:
            return np.zeros(6)
        return np.concatenate([self.taught.offsets(s), np.zeros(3)])

    def correction(self, t_move: float) -> FloatArray:
        """Correction (6,) (mm, deg; base frame) for the laser at ``t_move`` s after the move
        start. Raises :class:`TrackingError` when the seam ahead is not measured or needs more
        than the robot may correct: the weld must stop."""
        self.check_ahead(t_move)
        return self.correction_at(float(self.weld.s_at(t_move)))

    def check_ahead(self, t_move: float) -> None:
        """TrackingError unless the seam is measured :data:`MIN_AHEAD_MM` ahead of the laser
        at ``t_move`` s after the move start (near the seam's end: to that much before it),
        so a silent sensor stops the weld and a late one does not."""
        s = float(self.weld.s_at(t_move))
        end = self.weld.length_mm if self.seam_end_mm is None else self.seam_end_mm
        need = min(s + MIN_AHEAD_MM, end - MIN_AHEAD_MM)
        if self.model.furthest < need:
            raise TrackingError(
                f"seam not measured ahead of the laser: furthest point {self.model.furthest:.1f}"
                f" mm, laser at {s:.1f} mm (the weld needs {need:.1f} mm)"
            )

    def correction_at(self, s: float) -> FloatArray:
        """Correction (6,) for the laser at arc length ``s`` from the seam measured there;
        TrackingError when it is not measured or needs more than the robot may correct."""
        e = self.model.offset_at(s)
        if self.taught is not None:
            e = e + self.taught.offsets(s)
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


#: Corner radius (mm) of a tracked polyline path: the paper's smallest radius of curvature
#: of its Fig. 10 seam, which the tracker is shown to follow within 0.1 mm at 250 mm/s.
CORNER_RADIUS_MM = 32.0
#: Half the field of view across the laser stripe (mm): the 512 columns over 20.48 mm of the
#: sensor (DESIGN.md); the seam must stay inside it, less :data:`FIELD_MARGIN_MM`.
SENSOR_HALF_FIELD_MM = 10.24
#: Room kept at the edge of the field for the correction and the seam's own deviation (mm).
FIELD_MARGIN_MM = 1.5


class CornerError(ValueError):
    """A polyline corner the tracker cannot follow; ``corner`` is the vertex index."""

    def __init__(self, corner: int, message: str) -> None:
        super().__init__(message)
        self.corner = corner


#: One primitive of a :class:`PolylineWeld`: kind (0 line, 1 arc), start s, and per kind the
#: geometry (see :func:`_build`), its length and radius (an arc's; 0 for a line).
Prim = tuple[int, float, FloatArray, FloatArray, FloatArray, float, float]
#: An explicit arc meets the line or arc beside it tangentially to within this (deg): it is
#: not rounded, so a kink would be one the arm and the tracker cannot follow.
ARC_KINK_DEG = 0.5


@dataclass(frozen=True)
class PolylineWeld(WeldPath):
    """A nominal laser path through ``vertices`` (K, 3) mm, base frame, its corners rounded
    with ``radius_mm`` (tangent arcs: the path a seam tracker can follow at speed); law as
    :class:`NominalWeld`. Two vertices give the straight line of :class:`NominalWeld` with
    the same arithmetic. ``arcs`` (K - 1, 3): a point each segment's circular arc passes
    through (a job's ``<arc>``: from its vertex through that point to the next), NaN rows
    for lines; an arc must be tangent to what is beside it. Raises :class:`CornerError` for
    a corner whose rounding does not fit between its neighbours, or a kink at an arc."""

    vertices: FloatArray
    angles: FloatArray
    speed_mm_s: float
    accel_mm_s2: float = 2500.0
    radius_mm: float = CORNER_RADIUS_MM
    arcs: FloatArray | None = None
    length_mm: float = field(init=False)
    _prims: tuple[Prim, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        arcs = None if self.arcs is None else np.asarray(self.arcs, dtype=np.float64)
        prims = _build(np.asarray(self.vertices, dtype=np.float64), self.radius_mm, arcs)
        _kind, s0, _, _, _, length, _r = prims[-1]
        object.__setattr__(self, "_prims", prims)
        object.__setattr__(self, "length_mm", s0 + length)
        self._check_law()

    @property
    def start(self) -> FloatArray:
        return self._prims[0][2]

    @property
    def direction(self) -> FloatArray:
        """Direction (3,) of the path at its start."""
        kind, _s0, _a, b, c, _length, _r = self._prims[0]
        return b if kind == 0 else c

    def point(self, s: FloatArray | float) -> FloatArray:
        """Nominal laser points (..., 3) at arc lengths ``s`` (the end segments extended)."""
        ss = np.asarray(s, dtype=np.float64)
        starts = np.array([p[1] for p in self._prims])
        idx = np.clip(np.searchsorted(starts, ss, side="right") - 1, 0, len(starts) - 1)
        out = np.empty((*ss.shape, 3))
        for k, (kind, s0, a, b, c, _length, r) in enumerate(self._prims):
            m = idx == k
            if not np.any(m):
                continue
            u = ss[m] - s0
            if kind == 0:  # line: a + u·b
                out[m] = a + u[..., None] * b
            else:  # arc: centre a, start radius direction -n = b, start tangent c
                th = u / r
                out[m] = a + r * (np.cos(th)[..., None] * b + np.sin(th)[..., None] * c)
        return out

    def project(self, points: FloatArray) -> FloatArray:
        """Arc lengths (M,) of the nearest path points of ``points`` (M, 3)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        best_s = np.zeros(len(p))
        best_d = np.full(len(p), np.inf)
        last = len(self._prims) - 1
        for k, (kind, s0, a, b, c, length, r) in enumerate(self._prims):
            if kind == 0:
                u = (p - a) @ b
                u = np.clip(u, -np.inf if k == 0 else 0.0, np.inf if k == last else length)
                q = a + u[:, None] * b
            else:
                sweep = length / r
                th = np.mod(np.arctan2((p - a) @ c, (p - a) @ b), 2.0 * math.pi)
                # beyond the sweep: the nearer end (before the start is just under 2π)
                th = np.where(th > sweep, np.where(th - sweep < 2.0 * math.pi - th, sweep, 0.0), th)
                u = th * r
                q = a + r * (np.cos(th)[:, None] * b + np.sin(th)[:, None] * c)
            d = np.linalg.norm(p - q, axis=1)
            better = d < best_d
            best_d = np.where(better, d, best_d)
            best_s = np.where(better, s0 + u, best_s)
        return best_s

    def corner_s(self) -> list[tuple[int, float]]:
        """(vertex index, arc length of the middle of its rounding) of every rounded corner
        (between two lines)."""
        v = np.asarray(self.vertices, dtype=np.float64)
        d = np.diff(v, axis=0)
        d /= np.linalg.norm(d, axis=1)[:, None]
        line = [not _is_arc(self.arcs, k) for k in range(len(d))]
        turns = [
            k
            for k in range(1, len(v) - 1)
            if line[k - 1] and line[k] and float(d[k - 1] @ d[k]) < 1.0 - 1e-12
        ]
        return [(k, float(self.project(v[k])[0])) for k in turns]


def _is_arc(arcs: FloatArray | None, k: int) -> bool:
    return arcs is not None and bool(np.all(np.isfinite(arcs[k])))


def _circle(
    k: int, p0: FloatArray, mid: FloatArray, p1: FloatArray
) -> tuple[FloatArray, float, FloatArray, FloatArray, float]:
    """The arc from ``p0`` through ``mid`` to ``p1``: (centre, radius, start radius direction,
    start tangent, sweep rad); CornerError (at vertex ``k``) when the points are on a line."""
    u, w = p1 - p0, mid - p0
    n = np.cross(u, w)
    nn = float(n @ n)
    if nn < 1e-9 * float(u @ u) * float(w @ w) or nn == 0.0:
        raise CornerError(k, "the arc's three points are on one line")
    centre = p0 + (float(w @ w) * np.cross(n, u) + float(u @ u) * np.cross(w, n)) / (2.0 * nn)
    r = float(np.linalg.norm(p0 - centre))
    b = (p0 - centre) / r
    t = np.cross(n / math.sqrt(nn), b)

    def angle(p: FloatArray, tan: FloatArray) -> float:
        return float(np.mod(math.atan2((p - centre) @ tan, (p - centre) @ b), 2.0 * math.pi))

    if angle(mid, t) > angle(p1, t):
        t = -t  # the other way round reaches the middle point first
    return centre, r, b, t, angle(p1, t)


def _build(v: FloatArray, radius: float, arcs: FloatArray | None = None) -> tuple[Prim, ...]:
    """Lines (0, s0, start, direction, -, length, 0) and arcs (1, s0, centre, start radius
    direction, start tangent, length, radius) of the rounded polyline with its explicit
    ``arcs``; collinear vertices pass."""
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 2 or not np.all(np.isfinite(v)):
        raise ValueError("a polyline needs at least two finite vertices (K, 3)")
    if arcs is not None and arcs.shape != (len(v) - 1, 3):
        raise ValueError("arcs must be (K - 1, 3): a point per segment, NaN for a line")
    seg = np.diff(v, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    if np.any(lengths < 1e-9):
        raise CornerError(int(np.argmin(lengths)) + 1, "two consecutive vertices coincide")
    dirs = seg / lengths[:, None]
    circles = {
        k: _circle(k, v[k], arcs[k], v[k + 1])
        for k in range(len(seg))
        if arcs is not None and _is_arc(arcs, k)
    }
    first = list(dirs)  # each segment's tangent at its start and at its end
    last = list(dirs)
    for k, (_centre, _r, b, t, sweep) in circles.items():
        first[k] = t
        last[k] = -math.sin(sweep) * b + math.cos(sweep) * t
    turns = [0.0]  # tangent length of the rounding at each vertex
    for k in range(1, len(v) - 1):
        cos_phi = float(np.clip(last[k - 1] @ first[k], -1.0, 1.0))
        phi = math.acos(cos_phi)
        if k - 1 in circles or k in circles:
            if phi > math.radians(ARC_KINK_DEG):
                raise CornerError(
                    k,
                    f"the path kinks by {math.degrees(phi):.1f}° there: an arc must be"
                    " tangent to the line or arc beside it",
                )
            turns.append(0.0)
            continue
        if phi > math.radians(179.0):
            raise CornerError(k, f"the path turns back on itself ({math.degrees(phi):.0f}°)")
        turns.append(radius * math.tan(phi / 2.0))
    turns.append(0.0)
    for k, length in enumerate(lengths):
        need = turns[k] + turns[k + 1]
        if need > length + 1e-9:
            corner = k if turns[k] >= turns[k + 1] else k + 1
            raise CornerError(
                corner,
                f"the line from point {k} to point {k + 1} is {length:.1f} mm long: rounding"
                f" its corners with R {radius:g} mm needs {need:.1f} mm",
            )
    prims: list[Prim] = []
    s = 0.0
    none = np.zeros(3)
    for k, length in enumerate(lengths):
        if k in circles:
            centre, r, b, t, sweep = circles[k]
            prims.append((1, s, centre, b, t, r * sweep, r))
            s += r * sweep
            continue
        a = v[k] + turns[k] * dirs[k]
        run = float(length - turns[k] - turns[k + 1])
        if run > 0.0 or k == 0 or k == len(lengths) - 1:
            prims.append((0, s, v[k] if k == 0 else a, dirs[k], none, run, 0.0))
            s += run
        if k + 1 < len(lengths) and turns[k + 1] > 0.0:
            d0, d1 = dirs[k], dirs[k + 1]
            n = d1 - (d0 @ d1) * d0
            n /= np.linalg.norm(n)
            phi = math.acos(float(np.clip(d0 @ d1, -1.0, 1.0)))
            start = v[k + 1] - turns[k + 1] * d0
            prims.append((1, s, start + radius * n, -n, d0, radius * phi, radius))
            s += radius * phi
    return tuple(prims)


def check_sensor_view(
    weld: PolylineWeld,
    laser2sensor_offset: FloatArray,
    stripe_normal: FloatArray,
    stripe_across: FloatArray,
    *,
    half_field_mm: float = SENSOR_HALF_FIELD_MM - FIELD_MARGIN_MM,
    step_mm: float = 1.0,
) -> None:
    """Raise :class:`CornerError` (at the corner nearest the worst place) when the sensor,
    at ``laser2sensor_offset`` (3,) from the laser in the base frame (the tool keeps its
    orientation), would not see the nominal path in its laser plane (normal
    ``stripe_normal`` (3,)) within ``half_field_mm`` across it (along ``stripe_across``):
    the seam would be lost there and the weld stop."""
    s_fine = np.arange(0.0, weld.length_mm + step_mm / 10, step_mm / 10)
    path = weld.point(s_fine)
    worst, worst_s = 0.0, 0.0
    for s in np.arange(0.0, weld.length_mm + 1e-9, step_mm):
        sensor = weld.point(s) + laser2sensor_offset
        f = (path - sensor) @ stripe_normal
        cross = np.nonzero((np.sign(f[:-1]) != np.sign(f[1:])) & (s_fine[:-1] >= s))[0]
        if len(cross):
            lateral = abs(float((path[cross[0]] - sensor) @ stripe_across))
        elif sensor @ stripe_normal >= path[-1] @ stripe_normal:
            break  # past the end of the path: the rest was seen already
        else:
            lateral = math.inf
        if lateral > worst:
            worst, worst_s = lateral, float(s)
    if worst > half_field_mm:
        corners = weld.corner_s()
        at = min(corners, key=lambda c: abs(c[1] - worst_s))[0] if corners else 0
        ahead = float(laser2sensor_offset @ weld.direction)
        seen = (
            "would lose the seam"
            if math.isinf(worst)
            else (f"would see the seam up to {worst:.1f} mm off the middle of its field")
        )
        raise CornerError(
            at,
            f"the corner turns too sharply for the sensor {ahead:.0f} mm ahead: it {seen}"
            f" (at most {half_field_mm:g} mm)",
        )


# --- the tracked weld's own verdict (no truth needed) -------------------------------------------

#: Default tolerance of a tracked weld (mm): the paper's 0.1 mm.
TOLERANCE_MM = 0.1


@dataclass(frozen=True)
class Verdict:
    """What a tracked weld can say about itself on a real cell: the laser's error estimated
    from the robot's measured joints (the laser's path) against the seam the sensor measured
    ahead of it, and the corrections the robot did not get in time. ``within``: exit 0;
    else ``reason`` (exit 1, FAILED)."""

    within: bool
    reason: str
    tolerance_mm: float
    estimate_max_mm: float
    estimate_rms_mm: float
    cycles: int  # laser cycles estimated
    late: int  # timed corrections that reached the robot after their cycle
    held: int  # cycles the robot held a correction because the next one had not come

    def line(self) -> str:
        est = (
            f"estimated error max {self.estimate_max_mm:.3f} mm, rms {self.estimate_rms_mm:.3f}"
            f" mm over {self.cycles} cycles; {self.late} late corrections, {self.held} held"
            " cycles"
        )
        if self.within:
            return f"WITHIN TOLERANCE {self.tolerance_mm:g} mm: {est}"
        return f"OUT OF TOLERANCE {self.tolerance_mm:g} mm: {self.reason} ({est})"

    def summary(self) -> dict[str, object]:
        return {
            "within_tolerance": self.within,
            "reason": self.reason,
            "tolerance_mm": self.tolerance_mm,
            "estimate_max_mm": self.estimate_max_mm,
            "estimate_rms_mm": self.estimate_rms_mm,
            "estimate_cycles": self.cycles,
            "late_corrections": self.late,
            "held_cycles": self.held,
            "line": self.line(),
        }


def estimate_errors(
    model: SeamModel, laser_points: FloatArray, s_from: float, s_to: float
) -> tuple[FloatArray, FloatArray]:
    """(arc lengths (K,), errors (K,) mm) of the laser points (N, 3) (base frame, from the
    measured joints) inside [``s_from``, ``s_to``] against the measured seam there: the
    distance of the laser's offset from the nominal path to the seam's (the local fit the
    tracker used, now with every point the sensor measured around it), plus the scatter of
    the seam points about that fit (the measurement's own error, which the fit cannot
    average away when it is correlated along the seam, as a camera's is). A place without
    enough seam points is an error of +inf (not measured: not within any tolerance)."""
    p = np.asarray(laser_points, dtype=np.float64).reshape(-1, 3)
    s = model.weld.project(p)
    keep = (s >= s_from) & (s <= s_to)
    s, p = s[keep], p[keep]
    e_laser = p - model.weld.point(s)
    err = np.empty(len(s))
    for i, si in enumerate(s):
        try:
            off = float(np.linalg.norm(e_laser[i] - model.offset_at(float(si))))
            err[i] = off + model.scatter_at(float(si))
        except TrackingError:
            err[i] = math.inf
    return s, err


def judge(
    errors: FloatArray,
    *,
    late: int,
    held: int,
    tolerance_mm: float = TOLERANCE_MM,
    stopped: str = "",
    s: FloatArray | None = None,
) -> Verdict:
    """The verdict of a tracked weld: within ``tolerance_mm`` when it was completed, every
    estimated error is within it and every correction reached the robot in time."""
    e = np.asarray(errors, dtype=np.float64)
    finite = e[np.isfinite(e)]
    e_max = float(e.max()) if len(e) else math.nan
    e_rms = float(np.sqrt(np.mean(finite**2))) if len(finite) else math.nan
    reason = ""
    if stopped:
        reason = f"the weld stopped: {stopped}"
    elif not len(e):
        reason = "no laser cycle to estimate the error on"
    elif not np.all(np.isfinite(e)):
        at = f" at s = {float(s[np.argmax(~np.isfinite(e))]):.1f} mm" if s is not None else ""
        reason = f"the seam was not measured under the laser{at}"
    elif e_max > tolerance_mm:
        at = f" at s = {float(s[int(np.argmax(e))]):.1f} mm" if s is not None else ""
        reason = f"estimated error {e_max:.3f} mm{at} exceeds {tolerance_mm:g} mm"
    elif late:
        reason = f"{late} corrections reached the robot after their cycle"
    elif held:
        reason = f"the robot held the correction for {held} cycles (the next had not come)"
    return Verdict(not reason, reason, tolerance_mm, e_max, e_rms, len(e), late, held)
