"""Stripe and seam detector of the seam-tracking sensor (pure numpy, vectorised over columns).

Input: a frame in readout layout ``(columns, rows)`` (see :mod:`sensorsocket.camera`), from
the renderer or from anywhere else (a saved PGM, a real camera): uint8 as is; 16-bit
integers scaled by 1/256, floats in [0, 1] by 255, so thresholds stay in 8-bit DN. Steps:

1. Stripe (:mod:`sensorsocket.stripe`): per column the sub-pixel intensity centroid of the
   stripe and whether the column is valid.
2. Profile: valid centres mapped through the calibration (laser plane + pinhole) to points
   (0, y, z) in the sensor frame S, mm; isolated outliers (reflections) removed against a
   3-point running median.
3. Seam feature for the configured joint type: butt -> the widest gap between two coplanar
   plates, edges refined to sub-column precision from the stripe mass (a column half over
   the gap carries half the light); fillet -> the corner where two robust line fits meet;
   lap -> the largest depth step, the edge refined from the light on either level in the
   edge column, seam on the lower plate at that edge.

Result: status (``FOUND`` or why not), ^S_G T (4x4 mm; x_G = x_S because one profile does not
show the seam direction, z_G the surface normal in the laser plane, pointing away from the
sensor), quality in [0, 1], and the chip column where the seam lies (fractional), which the
caller turns into the time inside the readout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from kinematics.types import FloatArray
from sensorsocket.geometry import CameraGeometry
from sensorsocket.scene import JointType
from sensorsocket.stripe import MAD_TO_SIGMA, StripeFinder, StripeProfile, median_of_copy, to_dn

_EYE4 = np.eye(4)
_EYE4.setflags(write=False)

#: Rms of the plate fits (mm) at which the fit factor of the quality is one half: about the
#: depth noise of one column's centroid.
_HALF_QUALITY_RMS_MM = 0.03
#: A second gap at least this fraction as wide as the widest makes a butt seam ambiguous.
_AMBIGUOUS_GAP_RATIO = 0.6
#: Full-plate columns whose median light is a full column's reference (butt edges), taken
#: from the 10th to the 2nd column before the edge columns (the one next to them may be
#: partly lit too).
_N_REF_COLUMNS = 9
#: Robust line fits drop points beyond this many robust sigmas, but never within 10 µm.
_OUTLIER_SIGMAS, _MIN_OUTLIER_MM = 3.5, 0.01
# a ufunc reduction called directly (ndarray.min() goes through a Python wrapper); "any" and
# "all" of a mask as np.count_nonzero, half the cost of a logical reduction
_MIN = np.minimum.reduce
_COUNT = np.count_nonzero


class DetectorError(ValueError):
    """Invalid detector configuration (bad images give a status, not this)."""


class SeamStatus(StrEnum):
    """Why a seam was or was not reported."""

    FOUND = "found"
    NO_STRIPE = "no_stripe"  # too few stripe columns: laser off, dark, out of range, noise
    NO_FEATURE = "no_feature"  # a stripe, but no seam feature of the configured joint type
    AMBIGUOUS = "ambiguous"  # more than one plausible feature
    BAD_IMAGE = "bad_image"  # not a 2-D image with enough rows


@dataclass(frozen=True)
class DetectorConfig:
    """Detector thresholds; grey levels in DN, lengths in mm, angles in degrees."""

    joint: JointType = JointType.BUTT
    half_window: int = 6
    noise_factor: float = 3.0
    min_contrast_dn: float = 15.0
    max_width_px: float = 3.5
    min_valid_columns: int = 40
    min_side_points: int = 20
    outlier_mm: float = 0.15
    corner_margin_mm: float = 0.3
    min_gap_mm: float = 0.1
    max_gap_mm: float = 3.0
    max_plate_angle_deg: float = 15.0
    max_mismatch_mm: float = 2.0
    min_step_mm: float = 0.25
    min_corner_angle_deg: float = 20.0
    max_extrapolation_mm: float = 0.5
    max_rms_mm: float = 0.1

    def __post_init__(self) -> None:
        if not isinstance(self.joint, JointType):
            raise DetectorError(f"unknown joint type {self.joint!r}")
        if not 2 <= self.half_window <= 32:
            raise DetectorError("half_window must be 2..32 rows")
        if self.min_valid_columns < 4 or self.min_side_points < 3:
            raise DetectorError("need at least 4 valid columns and 3 points per side")


@dataclass(frozen=True)
class Detection:
    """Outcome of one frame. ``seam2sensor`` is the identity when nothing was found."""

    status: SeamStatus
    seam2sensor: FloatArray = field(repr=False)
    quality: float
    column: float  # chip column of the seam (fractional), NaN if none
    points: FloatArray = field(repr=False)  # (M, 3) profile points in S, mm
    point_columns: NDArray[np.intp] = field(repr=False)  # (M,) chip columns of ``points``
    stripe: StripeProfile | None = field(repr=False, default=None)

    @property
    def found(self) -> bool:
        return self.status is SeamStatus.FOUND


class _Centred(NamedTuple):
    """A profile's points as columns [1, y, z, y², yz, z²] (6, n) of y - cy and z - cz
    (mm) and its centre (cy, cz)."""

    w: FloatArray
    cy: float
    cz: float


class _Line(NamedTuple):
    """z = a + b·y fitted to n points with rms residual (mm)."""

    a: float
    b: float
    rms: float
    n: int


class SeamDetector:
    """Finds the stripe and the seam in frames of a camera with the given geometry."""

    def __init__(self, camera: CameraGeometry | None = None, config: DetectorConfig | None = None):
        self.camera = camera if camera is not None else CameraGeometry()
        self.config = config if config is not None else DetectorConfig()
        cfg = self.config
        self.stripes = StripeFinder(
            cfg.half_window, cfg.noise_factor, cfg.min_contrast_dn, cfg.max_width_px
        )
        self._empty_points = np.zeros((0, 3))
        self._empty_cols = np.zeros(0, dtype=np.intp)

    def stripe(self, frame: NDArray[np.generic], first_column: int = 0) -> StripeProfile:
        """Stage 1, the stripe of every column: :meth:`StripeFinder.stripe`."""
        return self.stripes.stripe(frame, first_column)

    # -- stage 2 and 3 ---------------------------------------------------------------------
    def detect(self, frame: NDArray[np.generic], first_column: int = 0) -> Detection:
        """Stripe, profile and seam of one frame (n columns, rows) starting at chip column
        ``first_column``. Never raises on image content; the status says what happened."""
        a = np.asarray(frame)
        cfg = self.config
        if (
            a.ndim != 2
            or a.shape[1] < 2 * cfg.half_window + 1
            or a.shape[0] < 1
            or a.dtype.kind not in "iuf"  # integers and floats, as np.issubdtype would say
        ):
            return self._none(SeamStatus.BAD_IMAGE, None)
        if a.dtype.type is not np.uint8:
            a = to_dn(a)
        stripe = self.stripe(a, first_column)
        cols = stripe.valid.nonzero()[0]
        if cols.size < cfg.min_valid_columns:
            return self._none(SeamStatus.NO_STRIPE, stripe)
        u = cols + first_column if first_column else cols
        y, z = self.camera.plane_point(u, stripe.rows.take(cols))
        # depth steps between neighbours: the outliers' quick test and the lap's step
        steps = np.abs(z[1:] - z[:-1])
        keep = _not_isolated_outliers(z, steps, cfg.outlier_mm)
        jumps = steps if keep is None else None
        if keep is not None:
            u, y, z = u[keep], y[keep], z[keep]
        pts = np.empty((u.size, 3))  # np.zeros costs four times as much here
        pts[:, 0] = 0.0
        pts[:, 1] = y
        pts[:, 2] = z
        if u.size < cfg.min_valid_columns:
            return self._none(SeamStatus.NO_STRIPE, stripe, pts, u)
        if cfg.joint is JointType.BUTT:
            return self._butt(a, stripe, u, y, z, pts)
        if cfg.joint is JointType.FILLET:
            return self._fillet(stripe, u, y, z, pts)
        return self._lap(a, stripe, u, y, z, pts, jumps)

    def _line_rows(self, cols: list[int], line: _Line) -> list[float]:
        """Rows where chip columns ``cols`` meet a profile line. The image of a line is a
        straight line, so two exact end points give all (equal to line_row to ~1e-13 px)."""
        if not cols:
            return []
        u1, u2 = min(cols), max(cols)
        v1 = self.camera.line_row(float(u1), line.a, line.b)
        if u2 == u1:
            return [v1] * len(cols)
        v2 = self.camera.line_row(float(u2), line.a, line.b)
        slope = (v2 - v1) / (u2 - u1)
        return [v1 + (c - u1) * slope for c in cols]

    def _none(
        self,
        status: SeamStatus,
        stripe: StripeProfile | None,
        pts: FloatArray | None = None,
        u: NDArray[np.intp] | None = None,
    ) -> Detection:
        return Detection(
            status=status,
            seam2sensor=_EYE4.copy(),
            quality=0.0,
            column=math.nan,
            points=self._empty_points if pts is None else pts,
            point_columns=self._empty_cols if u is None else u,
            stripe=stripe,
        )

    def _found(
        self,
        stripe: StripeProfile,
        y: float,
        z: float,
        slope: float,
        quality: float,
        pts: FloatArray,
        u: NDArray[np.intp],
    ) -> Detection:
        """FOUND with the seam at (0, y, z) in S (mm), the plates' slope dz/dy; a seam
        that is not finite (a degenerate fit) is no feature."""
        finite = math.isfinite(y) and math.isfinite(z) and math.isfinite(slope)
        column = self.camera.plane_column(y, z) if finite else math.nan
        if not math.isfinite(column):
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        norm = math.hypot(1.0, slope)
        cy, sy = 1.0 / norm, slope / norm
        # item by item into a copy of the identity: half the cost of np.array(nested lists)
        t = _EYE4.copy()
        t[1, 1] = t[2, 2] = cy
        t[1, 2] = -sy
        t[2, 1] = sy
        t[1, 3] = y
        t[2, 3] = z
        return Detection(
            status=SeamStatus.FOUND,
            seam2sensor=t,
            quality=float(min(max(quality, 0.0), 1.0)),
            column=column,
            points=pts,
            point_columns=u,
            stripe=stripe,
        )

    def _quality(self, n_used: int, n_columns: int, rms: float, feature: float) -> float:
        coverage = min(1.0, n_used / max(0.5 * n_columns, 1.0))
        fit = 1.0 / (1.0 + (rms / _HALF_QUALITY_RMS_MM) ** 2)
        return coverage * fit * min(max(feature, 0.0), 1.0)

    def _butt(
        self,
        frame: NDArray[np.generic],
        stripe: StripeProfile,
        u: NDArray[np.intp],
        y: FloatArray,
        z: FloatArray,
        pts: FloatArray,
    ) -> Detection:
        cfg = self.config
        holes = ((u[1:] - u[:-1]) > 1).nonzero()[0]
        if holes.size == 0:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        # few holes in a usable profile: plain Python beats a dozen numpy calls
        n, m = u.size, cfg.min_side_points
        found = [
            (w, i)
            for i in holes.tolist()
            if cfg.min_gap_mm <= (w := y.item(i + 1) - y.item(i)) <= cfg.max_gap_mm
            and i + 1 >= m
            and n - i - 1 >= m
        ]
        if not found:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        # widest candidate (the last of equal widths); a second one nearly as wide makes the
        # seam ambiguous
        best_w, i = max(found)
        if any(j != i and w >= _AMBIGUOUS_GAP_RATIO * best_w for w, j in found):
            return self._none(SeamStatus.AMBIGUOUS, stripe, pts, u)
        p = _centred(y, z)
        left = _robust_line(p, slice(0, i + 1))
        right = _robust_line(p, slice(i + 1, None))
        if left is None or right is None:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        angle = abs(math.degrees(math.atan(left.b) - math.atan(right.b)))
        yc = 0.5 * (float(y[i]) + float(y[i + 1]))
        mismatch = abs((left.a + left.b * yc) - (right.a + right.b * yc))
        rms = max(left.rms, right.rms)
        if (
            angle > cfg.max_plate_angle_deg
            or mismatch > cfg.max_mismatch_mm
            or rms > cfg.max_rms_mm
        ):
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        # sub-column edges: light in the edge columns relative to the plate's full columns
        edge_l, edge_r = self._coverage(frame, stripe, int(u[i]), int(u[i + 1]), left, right)
        y_l, z_l = self.camera.line_point(edge_l, left.a, left.b)
        y_r, z_r = self.camera.line_point(edge_r, right.a, right.b)
        slope = math.tan(0.5 * (math.atan(left.b) + math.atan(right.b)))
        q = self._quality(left.n + right.n, stripe.rows.size, rms, 1.0)
        return self._found(stripe, 0.5 * (y_l + y_r), 0.5 * (z_l + z_r), slope, q, pts, u)

    def _coverage(
        self,
        frame: NDArray[np.generic],
        stripe: StripeProfile,
        u_left: int,
        u_right: int,
        left: _Line,
        right: _Line,
    ) -> tuple[float, float]:
        """Fractional chip columns of both plate edges next to a gap (u_left, u_right).

        The plate ending at u_left (line ``left``) or starting at u_right (``right``)
        covers the columns beyond the gap fully; the columns next to the gap carry light in
        proportion to the part of their width the plate covers. One gather for both sides.
        """
        n_ref = _N_REF_COLUMNS
        edge_l = [u_left, u_left + 1] if u_left + 1 < u_right else [u_left]
        edge_r = [u_right, u_right - 1] if u_right - 1 > u_left else [u_right]
        cols_l = list(range(u_left - n_ref - 1, u_left - 1)) + edge_l
        cols_r = list(range(u_right + 2, u_right + n_ref + 2)) + edge_r
        n_l = len(cols_l)
        rows = self._line_rows(cols_l, left) + self._line_rows(cols_r, right)
        m = self.stripes.mass_at(frame, stripe, cols_l + cols_r, rows, self.config.half_window)
        out = []
        for side, masses, edge in ((-1, m[:n_l], edge_l), (1, m[n_l:], edge_r)):
            ref = _list_median(masses[:n_ref])
            if ref <= 0:
                out.append(edge[0] + 0.5 * side)
                continue
            cover = sum(min(max(x / ref, 0.0), 1.0) for x in masses[n_ref:])
            out.append(edge[0] - 0.5 + cover if side < 0 else edge[0] + 0.5 - cover)
        return out[0], out[1]

    def _fillet(
        self,
        stripe: StripeProfile,
        u: NDArray[np.intp],
        y: FloatArray,
        z: FloatArray,
        pts: FloatArray,
    ) -> Detection:
        cfg = self.config
        # split where the profile is farthest from its chord, then refine at the corner
        y0, z0 = float(y[0]), float(z[0])
        dy, dz = float(y[-1]) - y0, float(z[-1]) - z0
        dist = np.abs(dy * (z - z0) - dz * (y - y0))
        y_split = float(y[int(dist.argmax())])
        left = right = None
        p = _centred(y, z)
        ascending = _COUNT(y[1:] >= y[:-1]) == y.size - 1  # the usual profile; no NaN
        lm_prev = rm_prev = None
        for _ in range(2):
            margin = cfg.corner_margin_mm
            lm, rm = _beside(y, ascending, y_split - margin, y_split + margin)
            # a side with the same points as before keeps its line (often, as the corner
            # moves by less than a column); both the same: the same corner
            new_l = lm_prev is None or not _same(lm, lm_prev)
            new_r = rm_prev is None or not _same(rm, rm_prev)
            if not (new_l or new_r):
                break
            if new_l:
                left = _robust_line(p, lm)
            if new_r:
                right = _robust_line(p, rm)
            if left is None or right is None or left.b == right.b:
                return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
            y_split = (right.a - left.a) / (left.b - right.b)
            lm_prev, rm_prev = lm, rm
        assert left is not None and right is not None
        if left.n < cfg.min_side_points or right.n < cfg.min_side_points:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        angle = abs(math.degrees(math.atan(left.b) - math.atan(right.b)))
        rms = max(left.rms, right.rms)
        z_c = left.a + left.b * y_split
        if (
            angle < cfg.min_corner_angle_deg
            or rms > cfg.max_rms_mm
            or not (y0 < y_split < float(y[-1]))
        ):
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        gap_to_data = float(_MIN(np.hypot(y - y_split, z - z_c)))
        if gap_to_data > cfg.max_extrapolation_mm:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        # the corner's normal bisects the plates' directions
        n_l, n_r = math.hypot(1.0, left.b), math.hypot(1.0, right.b)
        slope = (left.b / n_l + right.b / n_r) / (1.0 / n_l + 1.0 / n_r)
        q = self._quality(
            left.n + right.n, stripe.rows.size, rms, angle / (2.0 * cfg.min_corner_angle_deg)
        )
        return self._found(stripe, y_split, z_c, slope, q, pts, u)

    def _lap(
        self,
        frame: NDArray[np.generic],
        stripe: StripeProfile,
        u: NDArray[np.intp],
        y: FloatArray,
        z: FloatArray,
        pts: FloatArray,
        jumps: FloatArray | None,
    ) -> Detection:
        """Lap joint; ``jumps`` |z[k + 1] - z[k]| (n - 1,) if known (taken over)."""
        cfg = self.config
        if jumps is None:
            jumps = np.abs(z[1:] - z[:-1])
        i = int(jumps.argmax())
        step = jumps.item(i)
        if step < cfg.min_step_mm:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        # the largest of the other jumps is the second largest of all
        if jumps.size > 1:
            jumps.partition(jumps.size - 2)  # in place: the method, not np.partition's copy
            second = jumps.item(-2)
            if second >= max(cfg.min_step_mm, 0.5 * step):
                return self._none(SeamStatus.AMBIGUOUS, stripe, pts, u)
        if i + 1 < cfg.min_side_points or u.size - i - 1 < cfg.min_side_points:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        # the two columns next to the step may mix both levels: fit without them
        p = _centred(y, z)
        left = _robust_line(p, slice(0, max(i - 1, 0)))
        right = _robust_line(p, slice(i + 3, None))
        if left is None or right is None:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        rms = max(left.rms, right.rms)
        angle = abs(math.degrees(math.atan(left.b) - math.atan(right.b)))
        if rms > cfg.max_rms_mm or angle > cfg.max_plate_angle_deg:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        y_e = 0.5 * (float(y[i]) + float(y[i + 1]))
        upper_left = (left.a + left.b * y_e) < (right.a + right.b * y_e)
        upper, lower = (left, right) if upper_left else (right, left)
        # The upper plate's edge is lit and seen (its light ends there; the lower plate near
        # the wall may lie in its laser shadow). Count the upper plate's share of the
        # columns around the step, each relative to a full upper-plate column, then drop
        # from the edge perpendicular to the plates onto the lower plate: the inside corner.
        u_a, u_b = int(u[i]), int(u[i + 1])
        n_cols = u_b - u_a + 3
        ref_cols = u[max(i - 10, 0) : i - 1] if upper_left else u[i + 3 : min(i + 12, u.size)]
        all_cols = list(range(u_a - 1, u_b + 2)) + ref_cols.tolist()
        r_up = self._line_rows(all_cols, upper)
        r_lo = self._line_rows(all_cols[:n_cols], lower)
        gaps = [abs(p - q) for p, q in zip(r_up, r_lo, strict=False)]
        sep = min((g for g in gaps if not math.isnan(g)), default=math.nan)
        if not math.isfinite(sep):
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        half = int(max(1, min(cfg.half_window, math.floor(sep / 2.0 - 0.5))))
        m_up = self.stripes.mass_at(frame, stripe, all_cols, r_up, half)
        ref = _list_median(m_up[n_cols:]) if ref_cols.size else 0.0
        if ref <= 0.0:
            return self._none(SeamStatus.NO_FEATURE, stripe, pts, u)
        cover = sum(min(max(x / ref, 0.0), 1.0) for x in m_up[:n_cols])
        u_edge = (u_a - 1.5 + cover) if upper_left else (u_b + 1.5 - cover)
        e_y, e_z = self.camera.line_point(u_edge, upper.a, upper.b)
        n_lo = math.hypot(1.0, lower.b)
        d_y, d_z = 1.0 / n_lo, lower.b / n_lo
        t = e_y * d_y + (e_z - lower.a) * d_z
        q = self._quality(left.n + right.n, stripe.rows.size, rms, step / (2.0 * cfg.min_step_mm))
        return self._found(stripe, t * d_y, lower.a + t * d_z, lower.b, q, pts, u)


def _list_median(x: list[float]) -> float:
    """Median of a short non-empty list."""
    s = sorted(x)
    k = len(s) // 2
    return s[k] if len(s) % 2 else 0.5 * (s[k] + s[k - 1])


def _beside(
    y: FloatArray, ascending: bool, lo: float, hi: float
) -> tuple[slice | NDArray[np.bool_], slice | NDArray[np.bool_]]:
    """The points with y < lo and those with y > hi: as slices found by two binary searches
    where y ascends (a slice is cheaper to fit than a mask), else as masks."""
    if not ascending:
        return y < lo, y > hi
    n = y.size
    # a NaN bound, like the masks: no point
    i = int(y.searchsorted(lo)) if lo == lo else 0
    j = int(y.searchsorted(hi, "right")) if hi == hi else n
    return slice(0, i), slice(j, n)


def _same(a: slice | NDArray[np.bool_], b: slice | NDArray[np.bool_]) -> bool:
    """Whether two selections of :func:`_beside` hold the same points."""
    if isinstance(a, slice):
        return a == b
    assert not isinstance(b, slice)
    return not _COUNT(a ^ b)


def _not_isolated_outliers(
    z: FloatArray, jumps: FloatArray, tol: float
) -> NDArray[np.bool_] | None:
    """Mask of points within ``tol`` of the 3-point running median of z (drops glints);
    None when that is every point (the usual case). ``jumps``: |z[k + 1] - z[k]| (n - 1,)."""
    if z.size < 3:
        return None
    # a point off the median of itself and its neighbours is off both neighbours by more
    # than tol (the median is one of them): no two such jumps in a row, no outlier; at
    # most one such jump (a butt or fillet profile: none, a lap: its step), none in a row
    near = jumps <= tol
    if near.size - _COUNT(near) <= 1 or _COUNT(near[:-1] | near[1:]) == near.size - 1:
        return None
    a, b, c = z[:-2], z[1:-1], z[2:]
    med = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))
    inner = np.abs(b - med) <= tol
    if _COUNT(inner) == inner.size:
        return None
    keep = np.ones(z.size, dtype=bool)
    keep[1:-1] = inner
    return keep


def _centred(y: FloatArray, z: FloatArray) -> _Centred:
    """The points of a profile for :func:`_robust_line`, centred on the end points'
    midpoint (cy, cz) so that the closed-form moment sums lose no precision, with their
    moment products; built once per frame, a fit's sums are then one matrix-vector
    product with a slice or subset of columns."""
    cy = 0.5 * (y.item(0) + y.item(-1))
    cz = 0.5 * (z.item(0) + z.item(-1))
    w = np.empty((6, y.size))
    w[0] = 1.0
    dy = np.subtract(y, cy, out=w[1])
    dz = np.subtract(z, cz, out=w[2])
    np.multiply(w[1:3], dy, out=w[3:5])  # y², zy in one call
    np.multiply(dz, dz, out=w[5])
    return _Centred(w, cy, cz)


def _robust_line(
    p: _Centred, columns: slice | NDArray[np.bool_], iterations: int = 2
) -> _Line | None:
    """Least-squares line z = a + b·y through the ``columns`` of profile ``p``, refitted
    without points beyond 3.5 robust sigma. A fit's moment sums are one product of the
    moment rows with a weight vector (ones, or the points kept); a (3, n) point matrix
    times its transpose made BLAS copy both operands, at more than the product's cost."""
    # contiguous (a slice copied once): BLAS would copy a strided operand in every product
    w = p.w[:, columns].copy() if isinstance(columns, slice) else p.w.compress(columns, axis=1)
    n = w.shape[1]
    if n < 3:
        return None
    sums = w.dot(p.w[0, :n])  # row 0 is ones
    keep: NDArray[np.bool_] | None = None
    a = b = rms = 0.0
    for it in range(iterations + 1):
        count, sy, sz, syy, syz, szz = sums.tolist()
        n = int(count)
        if n < 3:
            return None
        my, mz = sy / n, sz / n
        syy_c = syy - sy * my
        if syy_c <= 1e-12 or syy_c <= 1e-10 * syy:  # all points at one y (to rounding)
            return None
        syz_c = syz - sy * mz
        b = syz_c / syy_c
        a = mz - b * my
        rms = math.sqrt(max(szz - sz * mz - b * syz_c, 0.0) / n)
        if it < iterations:
            res = np.abs(np.array([-a, -b, 1.0, 0.0, 0.0, 0.0]).dot(w))
            fitted = res.copy() if keep is None else res[keep]
            sigma = MAD_TO_SIGMA * median_of_copy(fitted)  # sorts ``fitted``
            limit = max(_OUTLIER_SIGMAS * sigma, _MIN_OUTLIER_MM)
            # the same points as in this fit: every further fit would repeat it exactly;
            # in the first fit, that is the largest residual (NaN sorts last) within limit
            if keep is None and fitted.item(-1) <= limit:
                break
            new_keep = res <= limit
            # (in the first fit some residual is beyond the limit, or it broke off above)
            if keep is not None and not _COUNT(new_keep ^ keep):
                break
            keep = new_keep
            sums = w.dot(keep)  # as float64 ones and zeros, the same sums
    return _Line(a=a + p.cz - b * p.cy, b=b, rms=rms, n=n)
