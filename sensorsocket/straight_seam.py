"""The renderer's fast path for a straight seam: column statistics without every sub-column
(pure). Tested against :class:`~sensorsocket.columns.ReferenceColumns`, which it must equal
(to rounding; the same lit, simple and complex columns).

On a straight seam the workpiece's lateral coordinate l is y_W, so everything the hit test
needs of a sub-column's laser line (where it starts, its span, where it crosses each piece)
is affine in the chip position u *and* linear in the pose. So the renderer

1. folds the workpiece transform and the pieces into two small matrices once
   (:meth:`StraightSeamColumns._line_quantities`), and per frame multiplies them with the
   poses (or with a few node poses and their weights, see
   :class:`~sensorsocket.scene.NodePoseProvider`): all line quantities of all columns;
2. evaluates them at every sub-column only for the lit test (λ in [0, 1], inside the piece,
   not shadowed);
3. for a column lit by one piece at every sub-column (the usual case), takes the mean and
   spread of the K rows from the outer two sub-columns (within one piece a column's stripe
   row is affine in u); only columns with an edge inside get every sub-column's row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinematics.types import FloatArray
from sensorsocket.columns import (
    SIMPLE_SPREAD_PX,
    UNLIT_ROW,
    WINDOW_CACHE_SIZE,
    ColumnStats,
    SubColumns,
    shadow_free_above,
    shadowed,
)
from sensorsocket.geometry import CameraError
from sensorsocket.scene import Piece, PoseProvider, Scene, node_poses_of


class _Layout:
    """Rows of the line quantities of N columns, ``q`` (2·size + 1, N).

    Each quantity is affine in the chip position u, value = c0 + u·c1: rows [0, size) hold
    the c0 of every quantity, rows [size, 2·size) their c1, in this order: the lateral
    position l of the line's start A, the lateral span l(B) - l(A), then for each profile
    piece the numerator and then for each piece the denominator of the line parameter λ of
    its hit. The last row is the laser source height (constant in u), whose minimum
    decides which shadow tests can be skipped."""

    LATERAL = 0
    SPAN = 1

    def __init__(self, n_pieces: int) -> None:
        self.num = slice(2, 2 + n_pieces)
        self.den = slice(2 + n_pieces, 2 + 2 * n_pieces)
        self.size = 2 + 2 * n_pieces
        self.source_height = 2 * self.size


class _Shadow:
    """Rows of the shadow quantities (6, N): the height of the line's start A and the
    height span h(B) - h(A) (c0, then both c1), then the laser source's lateral position
    and height (constant in u)."""

    HEIGHT, SPAN, HEIGHT_U, SPAN_U, SOURCE_LATERAL, SOURCE_HEIGHT = range(6)


@dataclass(frozen=True)
class _Samples:
    """Constants of N read columns: chip positions of the K sub-columns (K, N); camera-frame
    Y, Z of their line start points and the spans to the end points, of all K (4, K, N)
    and of the outer two (S, N)."""

    u_all: FloatArray = field(repr=False)
    cam_all: FloatArray = field(repr=False)  # (4, K, N): Y start, Y span, Z start, Z span
    ya_out: FloatArray = field(repr=False)
    dy_out: FloatArray = field(repr=False)
    za_out: FloatArray = field(repr=False)
    dz_out: FloatArray = field(repr=False)


class StraightSeamColumns:
    """:class:`~sensorsocket.columns.ColumnStats` of the read columns on a straight seam."""

    def __init__(self, scene: Scene, sub: SubColumns) -> None:
        if not scene.path.straight_line:
            raise CameraError("the straight-seam path needs a straight seam")
        self.scene = scene
        self.sub = sub
        self.camera = sub.camera
        k = sub.k
        self._pieces = scene.joint.pieces()
        self._layout = _Layout(len(self._pieces))
        self._windows: dict[tuple[int, int], _Samples] = {}
        # outer sub-columns: within one piece a column's stripe row is affine in u, so these
        # two give the mean and spread of all K; r_j = r_first + frac_j·(r_last - r_first)
        delta = sub.delta
        self._outer = [0, k - 1] if k > 1 else [0]
        self._ends = slice(None, None, k - 1) if k > 1 else slice(0, 1)
        span = delta[-1] - delta[0]
        self._frac = (delta - delta[0]) / span if k > 1 else np.zeros(1)
        self._spread = math.sqrt(float(np.mean(delta**2))) / span if k > 1 else 0.0
        self._lo = np.array([p.lo for p in self._pieces])[:, None, None]
        self._hi = np.array([p.hi for p in self._pieces])[:, None, None]
        self._kq, self._kq0, self._ks, self._ks0 = self._line_quantities()
        # every shadow test (lit piece, shadowing piece) with the source height above which
        # it cannot shadow
        self._shadow_pairs = [
            (i, c, shadow_free_above(c, p))
            for i, p in enumerate(self._pieces)
            for c in self._pieces
            if c is not p
        ]

    def _line_quantities(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Matrices (R, 12) and offsets (R, 1) that give the line quantities of N columns
        from their poses: matrix @ poses[:, :3].reshape(N, 12).T + offsets. First pair: the
        rows of :class:`_Layout`; second pair: those of :class:`_Shadow`.

        The quantities are linear in the pose (x[r, j] of
        :meth:`~sensorsocket.columns.ReferenceColumns.hits` is the sum over (a, b) of
        pose[a, b]·b2w[r, a]·line[b, j]), so the workpiece transform and the pieces fold
        into one small product per frame. Below, ``w[r, j, row]`` is the weight of x[r, j]
        (workpiece coordinate r of homogeneous column j: line ends A, B, their steps per
        column, the laser source) in quantity ``row``."""
        b2w, g = self.scene.base2workpiece, self.sub.line
        # (13, 3, 5): the last row is the pose's constant row (0, 0, 0, 1)
        basis = np.einsum("ra,bj->abrj", b2w[:3], g).reshape(16, 3, 5)[:13].copy()
        basis[12] = np.einsum("r,j->rj", b2w[:3, 3], g[3])
        lay = self._layout
        n = lay.size
        w = np.zeros((3, 5, 2 * n + 1))
        lateral, height = 1, 2  # workpiece coordinates: y_W across the seam, z_W up
        a, b, a_step, b_step, source = range(5)
        # c0 from the ends of column 0, c1 from their steps per column
        w[lateral, a, lay.LATERAL] = w[lateral, a_step, n + lay.LATERAL] = 1.0
        w[lateral, b, lay.SPAN] = w[lateral, b_step, n + lay.SPAN] = 1.0
        w[lateral, a, lay.SPAN] = w[lateral, a_step, n + lay.SPAN] = -1.0
        z_a, dz = np.zeros((3, 5, 2)), np.zeros((3, 5, 2))  # height of A and span: c0, c1
        z_a[height, a, 0] = z_a[height, a_step, 1] = 1.0
        dz[height, b, 0] = dz[height, b_step, 1] = 1.0
        dz[height, a, 0] = dz[height, a_step, 1] = -1.0
        for i, p in enumerate(self._pieces):
            # λ = (a + b·la - za) / (dz - b·dl), numerator and denominator affine in u
            for part in (0, 1):
                la, dl = w[..., part * n + lay.LATERAL], w[..., part * n + lay.SPAN]
                w[..., part * n + lay.num.start + i] = p.b * la - z_a[..., part]
                w[..., part * n + lay.den.start + i] = dz[..., part] - p.b * dl
        w[height, source, lay.source_height] = 1.0
        ws = np.zeros((3, 5, 6))
        ws[..., [_Shadow.HEIGHT, _Shadow.HEIGHT_U]] = z_a
        ws[..., [_Shadow.SPAN, _Shadow.SPAN_U]] = dz
        ws[lateral, source, _Shadow.SOURCE_LATERAL] = 1.0
        ws[height, source, _Shadow.SOURCE_HEIGHT] = 1.0
        out = []
        for m in (w, ws):
            full = basis.reshape(13, 15) @ m.reshape(15, -1)  # (13, R)
            out += [full[:12].T.copy(), full[12][:, None].copy()]
        for i, p in enumerate(self._pieces):
            out[1][lay.num.start + i] += p.a  # the numerator's constant a
        return out[0], out[1], out[2], out[3]

    def _samples(self, first_column: int, n_columns: int) -> _Samples:
        key = (first_column, n_columns)
        s = self._windows.get(key)
        if s is None:
            if len(self._windows) >= WINDOW_CACHE_SIZE:
                self._windows.clear()
            sub = self.sub
            cols = np.arange(first_column, first_column + n_columns)
            u = cols[:, None] + sub.delta[None, :]
            ya, za = sub.ya[cols], sub.za[cols]
            dy, dz = sub.yb[cols] - ya, sub.zb[cols] - za
            o = self._outer
            cam_all = np.ascontiguousarray(np.stack([ya.T, dy.T, za.T, dz.T]))
            arrays = (ya[:, o], dy[:, o], za[:, o], dz[:, o])
            s = _Samples(
                np.ascontiguousarray(u.T), cam_all, *(np.ascontiguousarray(a.T) for a in arrays)
            )
            self._windows[key] = s
        return s

    def _lit(
        self,
        q: FloatArray,
        u: FloatArray,
        shadow: tuple[list[tuple[int, Piece]], FloatArray] | None,
    ) -> tuple[NDArray[np.bool_], FloatArray]:
        """Which pieces each sub-column lights, from the line quantities ``q`` (see
        :class:`_Layout`) of the columns and the chip positions ``u`` (K, N) of their
        sub-columns; ``shadow``: the shadow tests to run (piece index, shadowing piece) and
        their quantities (see :class:`_Shadow`). The tests of
        :meth:`~sensorsocket.columns.ReferenceColumns.hits` (on the segment, inside the
        piece, not in another piece's shadow). Returns (lit (P, K, N), λ of the hit on the
        sub-column's line (P, K, N))."""
        lay = self._layout
        v = q[lay.size : 2 * lay.size, None, :] * u
        v += q[: lay.size, None, :]  # (Q, K, N): every quantity at every sub-column
        lam = v[lay.num] / v[lay.den]
        lh = lam * v[lay.SPAN]
        lh += v[lay.LATERAL]
        ok = lam >= 0.0
        ok &= lam <= 1.0
        ok &= lh >= self._lo
        ok &= lh < self._hi
        if shadow:
            pairs, qs = shadow
            h = qs[_Shadow.HEIGHT_U : _Shadow.SPAN_U + 1, None, :] * u
            h += qs[: _Shadow.SPAN + 1, None, :]  # height of A and span at every sub-column
            l_src, z_src = qs[_Shadow.SOURCE_LATERAL], qs[_Shadow.SOURCE_HEIGHT]
            for i, c in pairs:
                dls = lh[i] - l_src
                dzs = lam[i] * h[_Shadow.SPAN]
                dzs += h[_Shadow.HEIGHT]
                dzs -= z_src
                ok[i] &= ~shadowed(c, l_src, z_src, dls, dzs)
        return ok, lam

    def _row(
        self, lam: FloatArray, ya: FloatArray, dy: FloatArray, za: FloatArray, dz: FloatArray
    ) -> FloatArray:
        """Image row of the point at λ along column lines with camera-frame Y, Z (start
        ``ya``, ``za``; spans ``dy``, ``dz``), any broadcastable shapes."""
        num = lam * dy
        num += ya
        den = lam * dz
        den += za
        return self.camera.row_of(num, den)

    def _pose_rows(
        self, times: FloatArray, sensor2base: PoseProvider
    ) -> tuple[FloatArray, FloatArray | None]:
        """The top three rows of the poses at ``times`` (N,) s as (12, N) and None; or, from a
        provider with node poses (:class:`~sensorsocket.scene.NodePoseProvider`), those rows
        of its M nodes (12, M) and the weights (M, N): the line quantities are linear in
        the pose, so they are taken of the nodes and then weighted (M ~ 5-7, not N = 512)."""
        n = times.shape[0]
        hook = node_poses_of(sensor2base)
        nw = hook(times) if hook is not None else None
        if nw is not None:
            nodes, weights = nw
            m = nodes.shape[0]
            if nodes.shape != (m, 16) or weights.shape != (m, n):
                raise CameraError(
                    f"node pose provider returned shapes {nodes.shape}, {weights.shape}"
                )
            return nodes[:, :12].T, weights
        poses = np.asarray(sensor2base(times), dtype=np.float64)
        if poses.shape != (n, 4, 4):
            raise CameraError(f"pose provider returned shape {poses.shape}")
        return poses[:, :3].reshape(n, 12).T, None

    def stats(self, first_column: int, times: FloatArray, sensor2base: PoseProvider) -> ColumnStats:
        """Stripe statistics of the read columns from their poses at ``times`` (N,) s."""
        n = times.shape[0]
        s = self._samples(first_column, n)
        p12, weights = self._pose_rows(times, sensor2base)
        q = self._kq @ p12
        if weights is not None:
            q = q @ weights
        q += self._kq0
        z_min = float(q[self._layout.source_height].min())
        pairs = [(i, c) for i, c, free_above in self._shadow_pairs if not z_min > free_above]
        shadow = None
        if pairs:
            qs = self._ks @ p12
            if weights is not None:
                qs = qs @ weights
            qs += self._ks0
            shadow = (pairs, qs)
        k = self.sub.k
        n_p = len(self._pieces)
        with np.errstate(divide="ignore", invalid="ignore"):
            ok, lam = self._lit(q, s.u_all, shadow)
            count = np.add.reduce(ok.reshape(n_p * k, n), axis=0)
            # one piece lit at every sub-column (so no other piece anywhere): the rows lie
            # on one line of the image (a plane piece seen from one pose), affine in u, and
            # the outer two sub-columns give the mean and spread of all K
            uniform = np.add.reduce(np.logical_and.reduce(ok, axis=1), axis=0) == 1
            uniform &= count == k
            ends = self._ends
            lam_u = np.where(ok[:, ends], lam[:, ends], 0.0).sum(axis=0)
            r = self._row(lam_u, s.ya_out, s.dy_out, s.za_out, s.dz_out)
            mean = r[0] + r[-1]
            mean *= 0.5
            var = r[-1] - r[0]
            var *= self._spread
            var *= var
            coverage = count / k
            mixed = count > 0
            mixed &= ~uniform
            mi = np.flatnonzero(mixed)
            hit: NDArray[np.bool_] = np.empty((0, 0), dtype=bool)
            rows: FloatArray = np.empty((0, 0))
            if mi.size:
                # an edge inside the column: every sub-column's row
                hit = ok[:, :, mi].reshape(n_p * k, mi.size)
                c4 = s.cam_all[:, :, mi]
                rows = self._row(lam[:, :, mi], c4[0], c4[1], c4[2], c4[3])
                rows = rows.reshape(n_p * k, mi.size)
                rz = np.where(hit, rows, 0.0)
                c = count[mi]
                m = np.add.reduce(rz, axis=0) / c
                mean[mi] = m
                rz *= rz
                var[mi] = np.maximum(np.add.reduce(rz, axis=0) / c - m * m, 0.0)
        lit = coverage > 0.0
        simple = lit & (var <= SIMPLE_SPREAD_PX**2)
        ci = np.flatnonzero(lit & ~simple)
        out = np.full((ci.size, n_p * k if mi.size else k), UNLIT_ROW)
        if ci.size:
            steep = uniform[ci]
            # steep columns on one piece: their K rows on the line through the outer ones
            cu = ci[steep]
            out[steep, :k] = r[0, cu, None] + self._frac * (r[-1, cu] - r[0, cu])[:, None]
            if mi.size:
                sub = np.where(hit, rows, UNLIT_ROW).T
                out[~steep, : sub.shape[1]] = sub[np.searchsorted(mi, ci[~steep])]
        return ColumnStats(coverage, mean, var, simple, ci, out)
