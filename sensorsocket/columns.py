"""What each read column of the camera sees: the plain per-column model (pure).

Every chip column is sampled by K sub-columns (``RenderSettings.subsamples``) at offsets
``delta`` (K,) around its centre. A sub-column sees one line of the laser plane
(:meth:`~sensorsocket.geometry.CameraGeometry.column_lines`); where that line meets a piece
of the workpiece's profile, and the laser ray from the source does not cross another piece
first (shadow), the sub-column is lit at the row the camera sees the hit on. The renderer
draws a column from its sub-columns' statistics (:class:`ColumnStats`):

- *simple* columns, whose lit sub-columns' rows spread by at most ``SIMPLE_SPREAD_PX``:
  one Gaussian with their mass and spread;
- *complex* columns (an edge or a step inside the column): every sub-column's Gaussian.

:class:`ReferenceColumns` computes this for any seam path, sub-column by sub-column; the
straight-seam renderer (:mod:`sensorsocket.straight_seam`) is tested against it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinematics.types import FloatArray
from sensorsocket.geometry import CameraError, CameraGeometry
from sensorsocket.scene import Piece, PoseProvider, Scene

#: A column whose lit sub-columns' rows spread (rms) by at most this is drawn as one
#: Gaussian with their mean and variance: against the sum of the K Gaussians (σ = 1.4 px)
#: the shape differs by < 0.1 % of the peak, far below the noise.
SIMPLE_SPREAD_PX = 0.3
#: Row of an unlit sub-column in :attr:`ColumnStats.complex_rows`: so far off the chip that
#: its Gaussian adds exactly 0.0 to every pixel, so all K can be summed without a mask.
UNLIT_ROW = -1e9
#: A ray from the laser source to a hit is shadowed by a piece it crosses strictly before
#: the hit: μ < 1 - this, so the hit's own piece (μ = 1 up to rounding) never counts.
SHADOW_MARGIN = 1e-9
#: Per-window constants cached per renderer: a sensor uses one or two readout windows.
WINDOW_CACHE_SIZE = 8


def cut(p: Piece, l0: FloatArray, z0: FloatArray, dl: FloatArray, dz: FloatArray) -> FloatArray:
    """Parameter λ where the segment (l0, z0) + λ·(dl, dz) meets the line h = a + b·l of
    piece ``p``; a flat piece (b = 0) skips the products with zero."""
    if p.b == 0.0:
        out: FloatArray = (p.a - z0) / dz
    else:
        out = (p.a + p.b * l0 - z0) / (dz - p.b * dl)
    return out


def within(x: FloatArray, lo: float, hi: float) -> NDArray[np.bool_]:
    """lo <= x < hi, without the comparison with an infinite bound."""
    if math.isinf(lo):
        out: NDArray[np.bool_] = x < hi
    elif math.isinf(hi):
        out = x >= lo
    else:
        out = (x >= lo) & (x < hi)
    return out


def shadow_free_above(q: Piece, p: Piece) -> float:
    """Laser source height (mm, workpiece frame) above which no ray from the source to a
    point of piece ``p`` can cross piece ``q`` first; inf when there is none. Both flat and
    q not above p: with the source above q the ray meets q's plane at or beyond the hit
    (the shadow test's μ >= 1), so the test can be skipped."""
    return q.a if p.b == 0.0 and q.b == 0.0 and q.a <= p.a else math.inf


def shadowed(
    q: Piece, l_src: FloatArray, z_src: FloatArray, dls: FloatArray, dzs: FloatArray
) -> NDArray[np.bool_]:
    """Whether the laser rays from the source (l_src, z_src) along (dls, dzs) to their hits
    cross piece ``q`` strictly before the hit."""
    mu = cut(q, l_src, z_src, dls, dzs)
    lq = l_src + mu * dls
    out: NDArray[np.bool_] = (mu > 0.0) & (mu < 1.0 - SHADOW_MARGIN) & within(lq, q.lo, q.hi)
    return out


@dataclass(frozen=True)
class ColumnStats:
    """What the exposure needs of N read columns: lit fraction, mean row and spread
    (variance, px²) of the sub-columns' rows (N,), the simple columns (N,), and for the
    other lit columns (indices (M,)) every sub-column's row (M, X), ``UNLIT_ROW`` where a
    sub-column is unlit."""

    coverage: FloatArray
    mean: FloatArray
    var: FloatArray
    simple: NDArray[np.bool_]
    complex_columns: NDArray[np.intp]
    complex_rows: FloatArray


def sub_column_stats(
    hit: NDArray[np.bool_], rows: FloatArray, k: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Coverage, mean row and spread (variance, px²) of columns (M,) from the hits and rows
    (M, X) of their K sub-columns; mean and spread NaN where nothing is lit."""
    count = np.count_nonzero(hit, axis=1)
    rz = np.where(hit, rows, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        mean = rz.sum(axis=1) / count
        # spread of the sub-columns' rows (rows ~ 1e2 px: E[r²] - mean² loses ~1e-11 px²)
        var = np.maximum(np.einsum("ij,ij->i", rz, rz) / count - mean * mean, 0.0)
    return count / k, mean, var


class SubColumns:
    """The chip's K sub-columns per column and their laser-plane lines, in S (constants of
    a camera and K).

    ``delta`` (K,): sub-column offsets from the column centre (px); ``line`` (4, 5): the
    lines' end points A, B of column 0 and their steps per column (affine in u), and the
    laser source, as homogeneous columns, so that pose @ line gives all of them in one
    product; ``ya, za, yb, zb`` (columns, K): camera-frame Y and Z of every sub-column's end
    points, for the row of a hit (Y and Z are linear along the line, the row is v0 + f·Y/Z).
    """

    def __init__(self, camera: CameraGeometry, k: int) -> None:
        self.camera = camera
        self.k = k
        a0, b0 = camera.column_lines(np.array([0.0]))
        a1, b1 = camera.column_lines(np.array([1.0]))
        self.line = np.zeros((4, 5))
        for j, v in enumerate((a0[0], b0[0], a1[0] - a0[0], b1[0] - b0[0])):
            self.line[:3, j] = v
        self.line[:3, 4] = (0.0, 0.0, -camera.laser_standoff_mm)
        self.line[3, [0, 1, 4]] = 1.0
        self.delta = (np.arange(k) + 0.5) / k - 0.5
        us = np.arange(camera.columns, dtype=np.float64)[:, None] + self.delta[None, :]
        pa, pb = camera.column_lines(us)
        self.ya, self.za = camera.camera_yz(pa)
        self.yb, self.zb = camera.camera_yz(pb)


@dataclass(frozen=True)
class _Columns:
    """Constants of a set of N read columns: the chip column of every sub-column (N, K), and
    the camera-frame Y and Z of the sub-column end points with their spans (N, K·P), tiled
    once per profile piece."""

    us: FloatArray = field(repr=False)
    ya: FloatArray = field(repr=False)
    dy: FloatArray = field(repr=False)
    za: FloatArray = field(repr=False)
    dz: FloatArray = field(repr=False)


class ReferenceColumns:
    """Every sub-column's hit and the columns' statistics, for any seam path."""

    def __init__(self, scene: Scene, sub: SubColumns) -> None:
        self.scene = scene
        self.sub = sub
        self.pieces = scene.joint.pieces()
        self._windows: dict[tuple[int, int], _Columns] = {}

    def columns(self, columns: NDArray[np.intp]) -> _Columns:
        """Per-column constants of ``columns`` (N,): the same for every frame of a window."""
        n_pieces, sub = len(self.pieces), self.sub
        ya, za = np.tile(sub.ya[columns], n_pieces), np.tile(sub.za[columns], n_pieces)
        yb, zb = np.tile(sub.yb[columns], n_pieces), np.tile(sub.zb[columns], n_pieces)
        us = columns[:, None] + sub.delta[None, :]
        return _Columns(us=us, ya=ya, dy=yb - ya, za=za, dz=zb - za)

    def window(self, first_column: int, n_columns: int) -> _Columns:
        """:meth:`columns` of a readout window, cached."""
        key = (first_column, n_columns)
        w = self._windows.get(key)
        if w is None:
            if len(self._windows) >= WINDOW_CACHE_SIZE:
                self._windows.clear()
            w = self.columns(np.arange(first_column, first_column + n_columns))
            self._windows[key] = w
        return w

    def hits(
        self, col: _Columns, column_times: FloatArray, sensor2base: PoseProvider
    ) -> tuple[NDArray[np.bool_], FloatArray]:
        """Lit sub-columns and their rows (N, K·P) of the columns ``col`` exposed at
        ``column_times`` (N,) s; rows NaN where unlit."""
        poses = np.asarray(sensor2base(column_times), dtype=np.float64)
        n, k = col.us.shape
        if poses.shape != (n, 4, 4):
            raise CameraError(f"pose provider returned shape {poses.shape}")
        # the laser-line ends, their per-column steps and the laser source in the workpiece
        # frame: x[c, i, j] = coordinate c of homogeneous column j of sub.line at column i,
        # from two BLAS products instead of per-column einsums
        sg = (poses.reshape(-1, 4) @ self.sub.line).reshape(n, 4, 5)
        wide = np.ascontiguousarray(sg.transpose(1, 0, 2)).reshape(4, 5 * n)
        x = (self.scene.base2workpiece[:3] @ wide).reshape(3, n, 5)
        us = col.us

        def end(c: int, j: int) -> FloatArray:
            # coordinate c of the sub-column end points (N, K): line end j, step j + 2
            out: FloatArray = x[c, :, j : j + 1] + us * x[c, :, j + 2 : j + 3]
            return out

        path = self.scene.path
        za, zb = end(2, 0), end(2, 1)
        if path.straight_line:
            la, lb = end(1, 0), end(1, 1)
            l_src = x[1, :, 4:5]
        else:  # x only matters on a curved seam
            la = path.lateral(end(0, 0), end(1, 0))
            lb = path.lateral(end(0, 1), end(1, 1))
            l_src = path.lateral(x[0, :, 4:5], x[1, :, 4:5])
        dl, dz = lb - la, zb - za
        # laser source per column (N, 1), for shadows cast by one plate on another
        z_src = x[2, :, 4:5]
        z_src_min = float(z_src.min())
        lam = np.empty((n, len(self.pieces) * k))
        with np.errstate(divide="ignore", invalid="ignore"):
            for i, p in enumerate(self.pieces):
                lam_p = cut(p, la, za, dl, dz)
                lh = la + lam_p * dl
                ok = (lam_p >= 0.0) & (lam_p <= 1.0)
                ok &= within(lh, p.lo, p.hi)
                zh = za + lam_p * dz
                for q in self.pieces:
                    if q is not p and not z_src_min > shadow_free_above(q, p):
                        ok &= ~shadowed(q, l_src, z_src, lh - l_src, zh - z_src)
                np.copyto(lam[:, i * k : (i + 1) * k], np.where(ok, lam_p, np.nan))
            hit = np.isfinite(lam)
            rows = self.sub.camera.row_of(col.ya + lam * col.dy, col.za + lam * col.dz)
        return hit, rows

    def stats(self, first_column: int, times: FloatArray, sensor2base: PoseProvider) -> ColumnStats:
        """:class:`ColumnStats` of the read columns from every sub-column's hits."""
        hit, rows = self.hits(self.window(first_column, times.shape[0]), times, sensor2base)
        coverage, mean, var = sub_column_stats(hit, rows, self.sub.k)
        lit = coverage > 0
        simple = lit & (var <= SIMPLE_SPREAD_PX**2)
        ci = np.flatnonzero(lit & ~simple)
        return ColumnStats(coverage, mean, var, simple, ci, np.where(hit[ci], rows[ci], UNLIT_ROW))
