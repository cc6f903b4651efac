"""Laser-stripe renderer of the seam-tracking camera (pure).

The camera geometry and its calibration (sensor frame S, pixel <-> S) live in
:mod:`sensorsocket.geometry`.

Image coordinates: column u grows with y_S, row v grows with z_S (farther away). The chip
is read **column by column**, column 0 first. Frames are stored in readout order as
``(columns, rows) = (512, 256)`` uint8, C-contiguous: ``frame[u]`` is column u, one
contiguous run of 256 bytes. ``frame.T`` is the conventional (256 rows, 512 columns) view.
"""

from __future__ import annotations

import functools
import math
import statistics
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from sensorsocket.geometry import CameraError, CameraGeometry
from sensorsocket.scene import FloatArray, Piece, PoseProvider, Scene, node_poses_of

__all__ = [
    "CameraError",
    "CameraGeometry",
    "RenderSettings",
    "RenderTruth",
    "StripeRenderer",
    "frame_from_image",
    "image_rows",
]

U8Array = NDArray[np.uint8]


@dataclass(frozen=True)
class RenderSettings:
    """Image formation; grey levels in DN (0..255), times in seconds.

    The stripe is a Gaussian across rows (``stripe_sigma_px``) whose peak is
    ``stripe_peak_dn · brightness · exposure / reference_exposure``. Noise: a background
    level with Gaussian read noise, shot noise of variance ``shot_gain_dn · signal`` and
    multiplicative speckle of contrast ``speckle_contrast`` on the stripe; then rounding and
    clipping to uint8 (saturation at 255). Both noises are pre-drawn (a background tile of
    twice the chip, a pool of unit normals) and read at random offsets per frame; they are
    drawn anew every ``noise_refresh_frames`` frames. The unit normals are the standard
    normal quantiles of 16-bit uniform draws (|z| <= 4.33, variance 1 - 2e-5).
    """

    stripe_sigma_px: float = 1.4
    stripe_peak_dn: float = 170.0
    reference_exposure_s: float = 3.5e-3 / 512
    background_dn: float = 8.0
    read_noise_dn: float = 2.0
    shot_gain_dn: float = 0.3
    speckle_contrast: float = 0.04
    subsamples: int = 4
    noise_refresh_frames: int = 64

    def __post_init__(self) -> None:
        if not 0.5 <= self.stripe_sigma_px <= 8.0:
            raise CameraError("stripe_sigma_px must be 0.5..8")
        if not 1 <= self.subsamples <= 32:
            raise CameraError("subsamples must be 1..32")
        for name in ("stripe_peak_dn", "background_dn", "read_noise_dn", "shot_gain_dn"):
            if not 0.0 <= getattr(self, name) <= 1e4:
                raise CameraError(f"{name} out of range")
        if not 0.0 <= self.speckle_contrast <= 1.0:
            raise CameraError("speckle_contrast must be 0..1")
        if self.reference_exposure_s <= 0 or self.noise_refresh_frames < 1:
            raise CameraError("reference exposure and refresh period must be positive")


@dataclass(frozen=True)
class RenderTruth:
    """What the renderer put in each read column (N,): centre row, coverage, simple column.

    ``simple`` columns hold one Gaussian stripe whose true centre is ``center_row``;
    ``coverage`` is the fraction of the column's width that the surface lit (0 in a gap).
    """

    center_row: FloatArray = field(repr=False)
    coverage: FloatArray = field(repr=False)
    simple: NDArray[np.bool_] = field(repr=False)


def _cut(p: Piece, l0: FloatArray, z0: FloatArray, dl: FloatArray, dz: FloatArray) -> FloatArray:
    """Parameter λ where the segment (l0, z0) + λ·(dl, dz) meets the line h = a + b·l of
    piece ``p``; a flat piece (b = 0) skips the products with zero."""
    if p.b == 0.0:
        out: FloatArray = (p.a - z0) / dz
    else:
        out = (p.a + p.b * l0 - z0) / (dz - p.b * dl)
    return out


def _within(x: FloatArray, lo: float, hi: float) -> NDArray[np.bool_]:
    """lo <= x < hi, without the comparison with an infinite bound."""
    if math.isinf(lo):
        out: NDArray[np.bool_] = x < hi
    elif math.isinf(hi):
        out = x >= lo
    else:
        out = (x >= lo) & (x < hi)
    return out


def _never_shadows(q: Piece, p: Piece, z_src: FloatArray) -> bool:
    """True when no ray from the laser source (heights ``z_src``, mm) to a point of flat
    piece ``p`` can cross flat piece ``q`` first: q is not above p and the source is above
    q, so the ray meets q's plane at or beyond the hit (the shadow test's mu >= 1)."""
    return p.b == 0.0 and q.b == 0.0 and q.a <= p.a and bool(z_src.min() > q.a)


@dataclass(frozen=True)
class _Columns:
    """Constants of a set of N read columns: the chip column of every sub-column (N, K), and
    the camera-frame Y and Z of the sub-column end points with their spans (N, K·P), tiled
    once per profile piece."""

    us: FloatArray
    ya: FloatArray
    dy: FloatArray
    za: FloatArray
    dz: FloatArray


@dataclass(frozen=True)
class _Samples:
    """Constants of N read columns for the straight-seam path: chip positions of the K
    sub-columns (K, N); camera-frame Y, Z of their column-line start points and the spans
    to the end points, of all K (4, K, N) and of the outer two (S, N)."""

    u_all: FloatArray
    cam_all: FloatArray  # (4, K, N): Y start, Y span, Z start, Z span
    ya_out: FloatArray
    dy_out: FloatArray
    za_out: FloatArray
    dz_out: FloatArray


@dataclass(frozen=True)
class _Stats:
    """What the exposure needs of N read columns: lit fraction, mean row and spread of the
    sub-columns' rows (N,), the simple columns (N,), and for the other lit columns
    (indices (M,)) every sub-column's row (M, X), -1e9 where a sub-column is unlit."""

    coverage: FloatArray
    mean: FloatArray
    var: FloatArray
    simple: NDArray[np.bool_]
    complex_columns: NDArray[np.intp]
    complex_rows: FloatArray


# Quantities of a column's laser line in W for the straight-seam path, each affine in the
# chip position u (value c0 + u·c1). Evaluated at every sample: lateral start, lateral span,
# then per piece the numerator and denominator of the line parameter λ of the hit. Only for
# shadow tests: height start and span, laser source (lateral, height).
_LA, _DL, _NUM = 0, 1, 2
_ZA, _DZ, _LS, _ZS = 0, 1, 4, 5  # rows of the shadow block (2, 3: the spans in u)


class StripeRenderer:
    """Renders column-major 512x256 uint8 frames of a scene seen from moving poses."""

    def __init__(
        self,
        scene: Scene,
        camera: CameraGeometry | None = None,
        settings: RenderSettings | None = None,
        *,
        rng: np.random.Generator,
    ) -> None:
        self.scene = scene
        self.camera = camera if camera is not None else CameraGeometry()
        self.settings = settings if settings is not None else RenderSettings()
        self._rng = rng
        cam, st = self.camera, self.settings
        k = st.subsamples
        u = np.arange(cam.columns, dtype=np.float64)
        da, db = cam.column_lines(np.array([1.0]))
        a0, b0 = cam.column_lines(np.array([0.0]))
        self._da, self._db = da[0] - a0[0], db[0] - b0[0]  # per column step (affine in u)
        # homogeneous columns (4, 5): laser-line ends of column 0, their steps per column,
        # laser source; pose @ this gives all of them in one product
        self._g = np.zeros((4, 5))
        for j, v in enumerate((a0[0], b0[0], self._da, self._db)):
            self._g[:3, j] = v
        self._g[:3, 4] = (0.0, 0.0, -cam.laser_standoff_mm)
        self._g[3, [0, 1, 4]] = 1.0
        self._delta = (np.arange(k) + 0.5) / k - 0.5  # sub-column offsets (K,)
        # camera-frame Y and Z of the sub-column end points, for the row of a hit: v is
        # v0 + f·Y/Z with Y, Z linear along the line
        us = u[:, None] + self._delta[None, :]
        pa, pb = cam.column_lines(us)
        ax, c = cam.axes, cam.center
        self._ya = (pa - c) @ ax[1]
        self._za = (pa - c) @ ax[2]
        self._yb = (pb - c) @ ax[1]
        self._zb = (pb - c) @ ax[2]
        self._half = math.ceil(4.0 * st.stripe_sigma_px * 1.1)
        self._win = np.arange(2 * self._half + 1)
        self._win_f32 = self._win.astype(np.float32)
        # scratch for the simple columns of a frame: per column (3, columns) and per pixel
        # (2, columns·window) float32
        self._col_f32 = np.empty((3, cam.columns), dtype=np.float32)
        self._px_f32 = np.empty((2, cam.columns * self._win.size), dtype=np.float32)
        self._win_col_f32 = self._win_f32[:, None].copy()
        self._tile = np.empty((0, 0), dtype=np.uint8)
        self._frames_on_tile = st.noise_refresh_frames
        self._background_table = _rounded_normal_table(st.background_dn, st.read_noise_dn)
        # unit normals for the stripe noise: room for a few frames' stripes at random offsets
        self._normals = np.empty(0, dtype=np.float32)
        self._normals_size = 1 << 17
        self._pieces = scene.joint.pieces()
        self._windows: dict[tuple[int, int], _Columns] = {}
        self._sample_windows: dict[tuple[int, int], _Samples] = {}
        # outer sub-columns: within one piece a column's stripe row is affine in u, so these
        # two give the mean and spread of all K; r_j = r_first + frac_j·(r_last - r_first)
        self._outer = [0, k - 1] if k > 1 else [0]
        self._ends = slice(None, None, k - 1) if k > 1 else slice(0, 1)
        span = self._delta[-1] - self._delta[0]
        self._frac = (self._delta - self._delta[0]) / span if k > 1 else np.zeros(1)
        self._spread = math.sqrt(float(np.mean(self._delta**2))) / span if k > 1 else 0.0
        self._lo = np.array([p.lo for p in self._pieces])[:, None, None]
        self._hi = np.array([p.hi for p in self._pieces])[:, None, None]
        self._kq, self._kq0, self._ks, self._ks0 = self._line_quantities()
        # shadow tests a flat piece c cannot pass on flat piece p while the laser source is
        # above c (see _never_shadows): (p, c, the source height it takes); others always
        self._shadow_pairs = [
            (i, c, c.a if p.b == 0.0 and c.b == 0.0 and c.a <= p.a else math.inf)
            for i, p in enumerate(self._pieces)
            for c in self._pieces
            if c is not p
        ]

    def _columns(self, columns: NDArray[np.intp]) -> _Columns:
        """Per-column constants of ``columns`` (N,): the same for every frame of a window."""
        n_pieces = len(self._pieces)
        ya, za = np.tile(self._ya[columns], n_pieces), np.tile(self._za[columns], n_pieces)
        yb, zb = np.tile(self._yb[columns], n_pieces), np.tile(self._zb[columns], n_pieces)
        us = columns[:, None] + self._delta[None, :]
        return _Columns(us=us, ya=ya, dy=yb - ya, za=za, dz=zb - za)

    def _line_quantities(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Matrices (R, 12) and offsets (R, 1) that give the line quantities of N columns
        from their poses: matrix @ poses[:, :3].reshape(N, 12).T + offsets. First pair: the
        c0 rows then the c1 rows of _LA.., then the source height (2Q + 1 rows); second
        pair: c0 then c1 of _ZA and _DZ, and c0 of _LS, _ZS (6 rows).

        The quantities are linear in the pose (x[r, j] of :meth:`_hits` is the sum over
        (a, b) of pose[a, b]·b2w[r, a]·g[b, j]), so the workpiece transform and the pieces
        fold into one small product per frame."""
        b2w, g = self.scene.base2workpiece, self._g
        # (13, 3, 5): the last row is the pose's constant row (0, 0, 0, 1)
        basis = np.einsum("ra,bj->abrj", b2w[:3], g).reshape(16, 3, 5)[:13].copy()
        basis[12] = np.einsum("r,j->rj", b2w[:3, 3], g[3])
        n_p = len(self._pieces)
        n_q = _NUM + 2 * n_p
        w = np.zeros((3, 5, 2 * n_q + 1))  # x[r, j] -> row
        w[1, 0, _LA] = w[1, 2, n_q + _LA] = 1.0
        w[1, 1, _DL] = w[1, 3, n_q + _DL] = 1.0
        w[1, 0, _DL] = w[1, 2, n_q + _DL] = -1.0
        z_a, dz = np.zeros((3, 5, 2)), np.zeros((3, 5, 2))
        z_a[2, 0, 0] = z_a[2, 2, 1] = 1.0
        dz[2, 1, 0] = dz[2, 3, 1] = 1.0
        dz[2, 0, 0] = dz[2, 2, 1] = -1.0
        for i, p in enumerate(self._pieces):
            # λ = (a + b·la - za) / (dz - b·dl), numerator and denominator affine in u
            for part in (0, 1):
                la, dl = w[..., part * n_q + _LA], w[..., part * n_q + _DL]
                w[..., part * n_q + _NUM + i] = p.b * la - z_a[..., part]
                w[..., part * n_q + _NUM + n_p + i] = dz[..., part] - p.b * dl
        w[2, 4, 2 * n_q] = 1.0
        ws = np.zeros((3, 5, 6))
        ws[..., [0, 2]] = z_a
        ws[..., [1, 3]] = dz
        ws[1, 4, _LS] = ws[2, 4, _ZS] = 1.0
        out = []
        for m in (w, ws):
            full = basis.reshape(13, 15) @ m.reshape(15, -1)  # (13, R)
            out += [full[:12].T.copy(), full[12][:, None].copy()]
        for i, p in enumerate(self._pieces):
            out[1][_NUM + i] += p.a
        return out[0], out[1], out[2], out[3]

    def _samples(self, first_column: int, n_columns: int) -> _Samples:
        key = (first_column, n_columns)
        s = self._sample_windows.get(key)
        if s is None:
            if len(self._sample_windows) >= 8:
                self._sample_windows.clear()
            cols = np.arange(first_column, first_column + n_columns)
            u = cols[:, None] + self._delta[None, :]
            ya, za = self._ya[cols], self._za[cols]
            dy, dz = self._yb[cols] - ya, self._zb[cols] - za
            o = self._outer
            cam_all = np.ascontiguousarray(np.stack([ya.T, dy.T, za.T, dz.T]))
            arrays = (ya[:, o], dy[:, o], za[:, o], dz[:, o])
            s = _Samples(
                np.ascontiguousarray(u.T), cam_all, *(np.ascontiguousarray(a.T) for a in arrays)
            )
            self._sample_windows[key] = s
        return s

    def _window(self, first_column: int, n_columns: int) -> _Columns:
        key = (first_column, n_columns)
        w = self._windows.get(key)
        if w is None:
            if len(self._windows) >= 8:  # a few readout windows in use at a time
                self._windows.clear()
            w = self._columns(np.arange(first_column, first_column + n_columns))
            self._windows[key] = w
        return w

    def _refresh_tile(self) -> None:
        cam = self.camera
        shape = (2 * cam.columns, 2 * cam.rows)
        # uniform 16-bit draws through the inverse CDF of the rounded, clipped Gaussian:
        # the same grey-level distribution (to 2^-16) as rounding fresh normals, ~5x cheaper
        # The uint32 words Generator.bytes draws (the same stream, read as little-endian
        # 16-bit halves like the bytes would be) without its 4x slower bytes object.
        words = self._rng.integers(0, 1 << 32, size=shape[0] * shape[1] // 2, dtype=np.uint32)
        u = words.astype("<u4", copy=False).view("<u2")
        self._tile = self._background_table.take(u).reshape(shape)
        # unit normals the same way, from a quantile table: ~10x cheaper than
        # standard_normal, which took most of the refresh time
        words = self._rng.integers(0, 1 << 32, size=self._normals_size // 2, dtype=np.uint32)
        self._normals = _normal_table().take(words.astype("<u4", copy=False).view("<u2"))
        self._frames_on_tile = 0

    def _unit_normals(self, shape: tuple[int, int]) -> NDArray[np.float32]:
        """Unit normals of ``shape`` from the pool at a random offset (fresh if too many)."""
        size = shape[0] * shape[1]
        pool = self._normals
        if size > pool.size // 2:
            return self._rng.standard_normal(shape, dtype=np.float32)
        o = int(self._rng.integers(0, pool.size - size + 1))
        return pool[o : o + size].reshape(shape)

    def background(self, first_column: int, n_columns: int, out: U8Array) -> None:
        """Write dark-frame background + read noise into ``out[first:first+n]``."""
        if self._frames_on_tile >= self.settings.noise_refresh_frames:
            self._refresh_tile()
        self._frames_on_tile += 1
        cam = self.camera
        c0 = int(self._rng.integers(0, self._tile.shape[0] - n_columns + 1))
        r0 = int(self._rng.integers(0, self._tile.shape[1] - cam.rows + 1))
        out[first_column : first_column + n_columns] = self._tile[
            c0 : c0 + n_columns, r0 : r0 + cam.rows
        ]

    def hits(
        self, columns: NDArray[np.intp], column_times: FloatArray, sensor2base: PoseProvider
    ) -> tuple[NDArray[np.bool_], FloatArray]:
        """Lit points of every sub-column and profile piece: (lit (N, K·P), row (N, K·P)).

        A point is lit when the laser plane meets a piece of the surface there and the
        laser ray from the source does not cross another piece first (shadow); the camera
        sees every lit point (no occlusion). Rows are NaN where unlit.
        """
        columns = np.asarray(columns, dtype=np.intp)
        return self._hits(self._columns(columns), column_times, sensor2base)

    def _hits(
        self, col: _Columns, column_times: FloatArray, sensor2base: PoseProvider
    ) -> tuple[NDArray[np.bool_], FloatArray]:
        poses = np.asarray(sensor2base(column_times), dtype=np.float64)
        n, k = col.us.shape
        if poses.shape != (n, 4, 4):
            raise CameraError(f"pose provider returned shape {poses.shape}")
        # the laser-line ends, their per-column steps and the laser source in the workpiece
        # frame: x[c, i, j] = coordinate c of homogeneous column j of self._g at column i,
        # from two BLAS products instead of per-column einsums
        sg = (poses.reshape(-1, 4) @ self._g).reshape(n, 4, 5)
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
        lam = np.empty((n, len(self._pieces) * k))
        with np.errstate(divide="ignore", invalid="ignore"):
            for i, p in enumerate(self._pieces):
                lam_p = _cut(p, la, za, dl, dz)
                lh = la + lam_p * dl
                ok = (lam_p >= 0.0) & (lam_p <= 1.0)
                ok &= _within(lh, p.lo, p.hi)
                zh = za + lam_p * dz
                for q in self._pieces:
                    if q is p or _never_shadows(q, p, z_src):
                        continue
                    # does the laser ray source -> hit cross piece q first?
                    dls, dzs = lh - l_src, zh - z_src
                    mu = _cut(q, l_src, z_src, dls, dzs)
                    lq = l_src + mu * dls
                    ok &= ~((mu > 0.0) & (mu < 1.0 - 1e-9) & _within(lq, q.lo, q.hi))
                np.copyto(lam[:, i * k : (i + 1) * k], np.where(ok, lam_p, np.nan))
            hit = np.isfinite(lam)
            v0 = self.camera.principal_point[1]
            rows = v0 + self.camera.focal_px * (col.ya + lam * col.dy) / (col.za + lam * col.dz)
        return hit, rows

    def _lit(
        self,
        q: FloatArray,
        u: FloatArray,
        shadow: tuple[list[tuple[int, Piece]], FloatArray] | None,
    ) -> tuple[NDArray[np.bool_], FloatArray]:
        """Straight seam: which pieces each sub-column lights, from the line quantities
        ``q`` (2Q + 1, N) of the columns and the chip positions ``u`` (K, N) of their
        sub-columns; ``shadow``: the shadow tests to run (piece index, shadowing piece) and
        their line quantities (6, N). The tests of :meth:`_hits` (on the segment, inside the
        piece, not in another piece's shadow). Returns (lit (P, K, N), λ of the hit on the
        sub-column's line (P, K, N))."""
        n_p = len(self._pieces)
        n_q = _NUM + 2 * n_p
        v = q[n_q : 2 * n_q, None, :] * u
        v += q[:n_q, None, :]  # (Q, K, N): every quantity at every sub-column
        lam = v[_NUM : _NUM + n_p] / v[_NUM + n_p :]
        lh = lam * v[_DL]
        lh += v[_LA]
        ok = lam >= 0.0
        ok &= lam <= 1.0
        ok &= lh >= self._lo
        ok &= lh < self._hi
        if shadow:
            pairs, qs = shadow
            w = qs[2:4, None, :] * u
            w += qs[:2, None, :]  # heights of the line (start, span) at every sub-column
            l_src, z_src = qs[_LS], qs[_ZS]
            for i, c in pairs:
                # does the laser ray source -> hit cross piece c first?
                dls = lh[i] - l_src
                dzs = lam[i] * w[_DZ]
                dzs += w[_ZA]
                dzs -= z_src
                mu = _cut(c, l_src, z_src, dls, dzs)
                lq = l_src + mu * dls
                ok[i] &= ~((mu > 0.0) & (mu < 1.0 - 1e-9) & _within(lq, c.lo, c.hi))
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
        num /= den
        num *= self.camera.focal_px
        num += self.camera.principal_point[1]
        return num

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

    def _stats(self, first_column: int, times: FloatArray, sensor2base: PoseProvider) -> _Stats:
        """Stripe statistics of the read columns from their poses at ``times`` (N,) s."""
        n = times.shape[0]
        if not self.scene.path.straight_line:
            return self._stats_sampled(self._window(first_column, n), times, sensor2base)
        s = self._samples(first_column, n)
        p12, weights = self._pose_rows(times, sensor2base)
        q = self._kq @ p12
        if weights is not None:
            q = q @ weights
        q += self._kq0
        z_min = float(q[-1].min())
        pairs = [(i, c) for i, c, z in self._shadow_pairs if not z_min > z]
        shadow = None
        if pairs:
            qs = self._ks @ p12
            if weights is not None:
                qs = qs @ weights
            qs += self._ks0
            shadow = (pairs, qs)
        k = self.settings.subsamples
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
            if 2 <= mi.size <= 8 and n_p * k <= 64:
                # a few edge columns (the usual case): their sub-columns' rows on Python
                # floats, ~20 small numpy calls fewer
                self._mixed_stats(mi, ok, lam, s.cam_all, count, mean, var)
            elif mi.size:
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
        simple = lit & (var <= 0.3**2)
        ci = np.flatnonzero(lit & ~simple)
        out = np.full((ci.size, n_p * k if mi.size else k), -1e9)
        if ci.size:
            steep = uniform[ci]
            # steep columns on one piece: their K rows on the line through the outer ones
            cu = ci[steep]
            out[steep, :k] = r[0, cu, None] + self._frac * (r[-1, cu] - r[0, cu])[:, None]
            if mi.size:
                if not hit.size:
                    hit = ok[:, :, mi].reshape(n_p * k, mi.size)
                    c4 = s.cam_all[:, :, mi]
                    rows = self._row(lam[:, :, mi], c4[0], c4[1], c4[2], c4[3])
                    rows = rows.reshape(n_p * k, mi.size)
                sub = np.where(hit, rows, -1e9).T
                out[~steep, : sub.shape[1]] = sub[np.searchsorted(mi, ci[~steep])]
        return _Stats(coverage, mean, var, simple, ci, out)

    def _mixed_stats(
        self,
        mi: NDArray[np.intp],
        ok: NDArray[np.bool_],
        lam: FloatArray,
        cam: FloatArray,
        count: NDArray[np.intp],
        mean: FloatArray,
        var: FloatArray,
    ) -> None:
        """Mean row and spread of the edge columns ``mi`` (M,) from every lit sub-column
        (``ok``, ``lam`` (P, K, N), camera-frame constants ``cam`` (4, K, N)), written into
        ``mean`` and ``var``. The arithmetic of the numpy path of :meth:`_stats`, summed
        sub-column after sub-column: the same values as numpy's reduction where that runs
        row after row (the cell's butt frames), else within an ulp (numpy's summation order
        depends on the array layout: a contiguous run is summed in SIMD lanes)."""
        f = self.camera.focal_px
        v0 = self.camera.principal_point[1]
        for j in mi.tolist():
            ya, dy, za, dz = cam[:, :, j].tolist()
            s1 = s2 = 0.0
            first = True
            for hits, lams in zip(ok[:, :, j].tolist(), lam[:, :, j].tolist(), strict=True):
                for h, lm, a, b, c, d in zip(hits, lams, ya, dy, za, dz, strict=True):
                    r = ((lm * b + a) / (lm * d + c)) * f + v0 if h else 0.0
                    if first:
                        s1, s2, first = r, r * r, False
                    else:
                        s1 += r
                        s2 += r * r
            n = int(count[j])
            m = s1 / n
            mean[j] = m
            var[j] = max(s2 / n - m * m, 0.0)

    def _stats_sampled(self, col: _Columns, times: FloatArray, sensor2base: PoseProvider) -> _Stats:
        """:meth:`_stats` from every sub-column's hits (any seam path)."""
        hit, rows = self._hits(col, times, sensor2base)
        k = self.settings.subsamples
        coverage, mean, var = _sub_column_stats(hit, rows, k)
        lit = coverage > 0
        simple = lit & (var <= 0.3**2)
        ci = np.flatnonzero(lit & ~simple)
        return _Stats(coverage, mean, var, simple, ci, np.where(hit[ci], rows[ci], -1e9))

    def render(
        self,
        first_column: int,
        column_times: FloatArray,
        sensor2base: PoseProvider,
        *,
        laser_on: bool = True,
        exposure_s: float | None = None,
    ) -> tuple[U8Array, RenderTruth]:
        """One frame (columns, rows) uint8, columns outside the readout window zero.

        Column ``first_column + i`` is exposed at ``column_times[i]`` (s) and sees the
        scene from ``sensor2base`` at that time.
        """
        cam, st = self.camera, self.settings
        n = int(np.shape(column_times)[0])
        if first_column < 0 or n < 1 or first_column + n > cam.columns:
            raise CameraError(f"readout window {first_column}+{n} outside 0..{cam.columns}")
        # every pixel of a full-chip readout is written by the background
        full = first_column == 0 and n == cam.columns
        frame = (np.empty if full else np.zeros)((cam.columns, cam.rows), dtype=np.uint8)
        self.background(first_column, n, frame)
        cols = np.arange(first_column, first_column + n)
        exposure = st.reference_exposure_s if exposure_s is None else exposure_s
        amp = st.stripe_peak_dn * self.scene.brightness * exposure / st.reference_exposure_s
        if not laser_on or amp <= 0.0:
            empty = np.full(n, np.nan)
            return frame, RenderTruth(empty, np.zeros(n), np.zeros(n, dtype=bool))
        times = np.asarray(column_times, dtype=np.float64)
        stats = self._stats(first_column, times, sensor2base)
        coverage, mean, var, simple = stats.coverage, stats.mean, stats.var, stats.simple
        k = st.subsamples
        sigma2 = st.stripe_sigma_px**2
        # simple columns: one Gaussian with the sub-columns' mass and spread
        si = np.flatnonzero(simple)
        if si.size:
            self._expose_simple(frame, first_column, si, coverage, mean, var, amp)
        # complex columns (an edge inside the column): every sub-column over the full column
        ci = stats.complex_columns
        if ci.size:
            all_rows = np.arange(cam.rows, dtype=np.float64)
            d2 = (all_rows[None, None, :] - stats.complex_rows[:, :, None]) ** 2
            signal = (amp / k) * np.exp(-d2 / (2.0 * sigma2)).sum(axis=1)
            at = cols[ci, None] * cam.rows + np.arange(cam.rows)
            self._expose(frame, at, signal.astype(np.float32))
        return frame, RenderTruth(np.where(simple, mean, np.nan), coverage, simple)

    def _expose_simple(
        self,
        frame: U8Array,
        first_column: int,
        si: NDArray[np.intp],
        coverage: FloatArray,
        mean: FloatArray,
        var: FloatArray,
        amp: float,
    ) -> None:
        """One Gaussian per simple column ``si`` (M,) (read-window indices) with the
        sub-columns' mass and spread, plus noise, into the window of 2·half + 1 rows around
        its mean row. The arithmetic of the plain expressions (float64 per column, float32
        per pixel, in that order), written into preallocated buffers: fewer, fused calls."""
        rows, w = self.camera.rows, self._win.size
        m_cols = si.size
        sigma2 = self.settings.stripe_sigma_px**2
        s_eff2 = var.take(si)
        s_eff2 += sigma2
        # peak = amp·coverage·sqrt(σ²/σ_eff²), float64, then float32
        t = np.divide(sigma2, s_eff2)
        np.sqrt(t, out=t)
        c = coverage.take(si)
        c *= amp
        peak = self._col_f32[0, :m_cols]
        np.multiply(c, t, out=peak)
        # window start: rint(mean) - half, clamped to the frame
        m = mean.take(si)
        start = np.rint(m)
        start -= self._half
        np.maximum(start, 0.0, out=start)
        np.minimum(start, float(rows - w), out=start)
        # float32 from here: the Gaussian's centre to ~1e-6 px, far below the noise
        dm = self._col_f32[1, :m_cols]
        np.subtract(start, m, out=dm)
        e = self._col_f32[2, :m_cols]
        np.divide(-0.5, s_eff2, out=e)
        # pixels as (W, M), window row by column: the per-column factors broadcast along
        # contiguous rows (cheap), not one short row per column
        size = w * m_cols
        signal = self._px_f32[0, :size].reshape(w, m_cols)
        np.add(self._win_col_f32, dm, out=signal)
        np.multiply(signal, signal, out=signal)
        signal *= e
        np.exp(signal, out=signal)
        signal *= peak
        value = self._px_f32[1, :size].reshape(w, m_cols)
        st = self.settings
        # sd = sqrt(signal·(signal·c² + g)), value = normals·sd + signal + 0.5 + background
        np.multiply(signal, np.float32(st.speckle_contrast**2), out=value)
        value += np.float32(st.shot_gain_dn)
        value *= signal
        np.sqrt(value, out=value)
        value *= self._unit_normals((m_cols, w)).T  # the pixel order of (M, W) draws
        value += signal
        value += np.float32(0.5)
        # the windows of a strided view over the frame, by the flat index of their first
        # pixel: window row j of every column is one gather and one scatter
        at = start.astype(np.intp)
        at += si * rows
        at += first_column * rows
        flat = frame.reshape(-1)
        windows = np.ndarray((w, flat.size - w + 1), np.uint8, flat, 0, (1, 1))
        value += windows[:, at]
        np.clip(value, 0.0, 255.0, out=value)
        windows[:, at] = value.astype(np.uint8)

    def _expose(self, frame: U8Array, at: NDArray[np.intp], signal: NDArray[np.float32]) -> None:
        """Add stripe signal (M, W) DN with shot noise and speckle to the pixels at flat
        indices ``at`` (M, W) of the C-contiguous frame, in place."""
        st = self.settings
        c2, g = np.float32(st.speckle_contrast**2), np.float32(st.shot_gain_dn)
        sd = np.sqrt(signal * (signal * c2 + g))
        value = self._unit_normals(signal.shape) * sd
        value += signal
        value += np.float32(0.5)
        # one gather and one scatter on the flat frame
        flat = frame.reshape(-1)
        value += flat[at]
        np.clip(value, 0.0, 255.0, out=value)
        flat[at] = value.astype(np.uint8)


def _sub_column_stats(
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


def _rounded_normal_table(mean: float, sigma: float) -> U8Array:
    """Grey level (65536,) uint8 for each 16-bit uniform draw: the inverse CDF of
    uint8(clip(mean + sigma·z + 0.5, 0, 255)) with z standard normal (DN)."""
    k = np.arange(255, dtype=np.float64)
    if sigma > 0.0:
        # P(level <= k) = P(mean + sigma·z < k + 0.5)
        cdf = np.array([0.5 * math.erfc(-(x + 0.5 - mean) / (sigma * math.sqrt(2.0))) for x in k])
    else:
        cdf = (k + 0.5 > mean).astype(np.float64)
    p = (np.arange(65536, dtype=np.float64) + 0.5) / 65536.0
    out: U8Array = np.searchsorted(cdf, p, side="right").astype(np.uint8)
    return out


@functools.cache
def _normal_table() -> NDArray[np.float32]:
    """Standard normal quantile (65536,) float32 for each 16-bit uniform draw k:
    Φ⁻¹((k + 0.5) / 65536), symmetric about zero (read-only, built once per process)."""
    nd = statistics.NormalDist()
    lower = np.array([nd.inv_cdf((k + 0.5) / 65536.0) for k in range(32768)])
    out: NDArray[np.float32] = np.concatenate([lower, -lower[::-1]]).astype(np.float32)
    out.setflags(write=False)
    return out


def image_rows(frame: U8Array) -> U8Array:
    """Conventional (rows, columns) view of a column-major frame (no copy)."""
    return frame.T


def frame_from_image(image: U8Array) -> U8Array:
    """Column-major C-contiguous frame (columns, rows) from a (rows, columns) image."""
    return np.ascontiguousarray(np.asarray(image).T)
