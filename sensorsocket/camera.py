"""Triangulation geometry and laser-stripe renderer of the seam-tracking camera (pure).

Sensor frame S (mm): origin at the centre of the measuring range, where the camera's optical
axis crosses the laser plane; x_S in the welding direction (along the seam); z_S along the
laser, from the sensor towards the workpiece; y_S = z_S × x_S across the seam. The laser
plane is x_S = 0, so the stripe runs across the seam.

Default geometry (``CameraGeometry()``), chosen like compact laser-welding seam trackers:

- laser: plane x_S = 0, source 60 mm above the origin (at z_S = -60);
- camera: pinhole trailing the laser, centre at (-D sin θ, 0, -D cos θ) with working distance
  D = 64 mm and triangulation angle θ = 45° between the optical axis and the laser, so the
  baseline (laser-to-camera distance across the laser direction) is D sin θ ≈ 45.3 mm;
- lens f = 16 mm, pixel pitch 10 µm, 512 columns × 256 rows, principal point at the centre;
- hence ≈ 40 µm per column across the seam (field of view ≈ 20.5 mm wide at z_S = 0) and
  ≈ 57 µm per row in depth near the origin (z_S from ≈ -6.7 mm at row 0 to ≈ +7.8 mm at
  row 255; ≈ 14.5 mm deep). Ideal pinhole: no lens distortion, so the calibration the
  detector uses is exact.

Image coordinates: column u grows with y_S, row v grows with z_S (farther away). The chip
is read **column by column**, column 0 first. Frames are stored in readout order as
``(columns, rows) = (512, 256)`` uint8, C-contiguous: ``frame[u]`` is column u, one
contiguous run of 256 bytes. ``frame.T`` is the conventional (256 rows, 512 columns) view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from sensorsocket.scene import FloatArray, Piece, PoseProvider, Scene

U8Array = NDArray[np.uint8]


class CameraError(ValueError):
    """Invalid camera geometry, render setting or readout window."""


@dataclass(frozen=True)
class CameraGeometry:
    """Pinhole camera over a laser plane; lengths in mm, angles in degrees."""

    columns: int = 512
    rows: int = 256
    pixel_pitch_mm: float = 0.010
    focal_length_mm: float = 16.0
    triangulation_angle_deg: float = 45.0
    working_distance_mm: float = 64.0
    laser_standoff_mm: float = 60.0

    def __post_init__(self) -> None:
        if not (8 <= self.columns <= 8192 and 8 <= self.rows <= 8192):
            raise CameraError("columns and rows must be 8..8192")
        if not 5.0 <= self.triangulation_angle_deg <= 85.0:
            raise CameraError("triangulation angle must be 5..85 degrees")
        for name in ("pixel_pitch_mm", "focal_length_mm", "working_distance_mm"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise CameraError(f"{name} must be positive")
        th = math.radians(self.triangulation_angle_deg)
        object.__setattr__(self, "_sin", math.sin(th))
        object.__setattr__(self, "_cos", math.cos(th))

    _sin: float = field(init=False, repr=False, compare=False, default=0.0)
    _cos: float = field(init=False, repr=False, compare=False, default=0.0)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return self.focal_length_mm / self.pixel_pitch_mm

    @property
    def principal_point(self) -> tuple[float, float]:
        """(u0, v0) in pixels: the chip centre."""
        return (self.columns - 1) / 2.0, (self.rows - 1) / 2.0

    @property
    def baseline_mm(self) -> float:
        """Distance from the laser line to the camera centre across the laser direction (mm)."""
        return self.working_distance_mm * math.sin(math.radians(self.triangulation_angle_deg))

    @property
    def center(self) -> FloatArray:
        """Camera centre in S (3,) mm."""
        th = math.radians(self.triangulation_angle_deg)
        d = self.working_distance_mm
        return np.array([-d * math.sin(th), 0.0, -d * math.cos(th)])

    @property
    def axes(self) -> FloatArray:
        """Camera axes in S as rows (3, 3): x_c (along columns), y_c (along rows), z_c."""
        th = math.radians(self.triangulation_angle_deg)
        s, c = math.sin(th), math.cos(th)
        return np.array([[0.0, 1.0, 0.0], [-c, 0.0, s], [s, 0.0, c]])

    def pixel_to_sensor(self, u: FloatArray, v: FloatArray) -> FloatArray:
        """Points on the laser plane seen at pixel (u, v) (any shape) -> (..., 3) mm in S.

        With k = (u - u0)/f and t = (v - v0)/f (f in pixels), the ray meets x_S = 0 at
        z = t·D / (sin θ - t·cos θ) and y = k·(D + z·cos θ).
        """
        u0, v0 = self.principal_point
        f = self.focal_px
        s, c, d = self._sin, self._cos, self.working_distance_mm
        k = (np.asarray(u, dtype=np.float64) - u0) / f
        t = (np.asarray(v, dtype=np.float64) - v0) / f
        z = t * d / (s - t * c)
        y = k * (d + z * c)
        return np.stack([np.zeros_like(z), y, z], axis=-1)

    def project(self, points: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Pixel coordinates (u, v) of points (..., 3) in S.

        Camera coordinates of (x, y, z): X = y, Y = z·sin θ - x·cos θ,
        Z = D + x·sin θ + z·cos θ.
        """
        p = np.asarray(points, dtype=np.float64)
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        s, c = self._sin, self._cos
        zc = self.working_distance_mm + x * s + z * c
        u0, v0 = self.principal_point
        f = self.focal_px
        return u0 + f * y / zc, v0 + f * (z * s - x * c) / zc

    def column_lines(self, u: FloatArray, margin_px: float = 8.0) -> tuple[FloatArray, FloatArray]:
        """End points (..., 3) in S of the laser-plane line seen by column u.

        A at row -margin and B at row rows-1+margin; the line is affine in u.
        """
        u = np.asarray(u, dtype=np.float64)
        a = self.pixel_to_sensor(u, np.full_like(u, -margin_px))
        b = self.pixel_to_sensor(u, np.full_like(u, self.rows - 1 + margin_px))
        return a, b

    def line_row(self, u: FloatArray, a: float, b: float) -> tuple[FloatArray, FloatArray]:
        """Where column u meets the profile line z = a + b·y: (row v, point (..., 3) in S)."""
        s, c, d = self._sin, self._cos, self.working_distance_mm
        u0, v0 = self.principal_point
        f = self.focal_px
        k = (np.asarray(u, dtype=np.float64) - u0) / f
        with np.errstate(divide="ignore", invalid="ignore"):
            y = k * (d + a * c) / (1.0 - k * b * c)
        z = a + b * y
        v = v0 + f * z * s / (d + z * c)
        return v, np.stack([np.zeros_like(y), y, z], axis=-1)

    def field_of_view(self) -> dict[str, float]:
        """Width at z_S = 0 and depth range along the laser (mm)."""
        u0, v0 = self.principal_point
        left = self.pixel_to_sensor(np.array(-0.5), np.array(v0))
        right = self.pixel_to_sensor(np.array(self.columns - 0.5), np.array(v0))
        top = self.pixel_to_sensor(np.array(u0), np.array(-0.5))
        bottom = self.pixel_to_sensor(np.array(u0), np.array(self.rows - 0.5))
        return {
            "width_mm": float(right[1] - left[1]),
            "z_min_mm": float(top[2]),
            "z_max_mm": float(bottom[2]),
            "depth_mm": float(bottom[2] - top[2]),
        }


@dataclass(frozen=True)
class RenderSettings:
    """Image formation; grey levels in DN (0..255), times in seconds.

    The stripe is a Gaussian across rows (``stripe_sigma_px``) whose peak is
    ``stripe_peak_dn · brightness · exposure / reference_exposure``. Noise: a background
    level with Gaussian read noise (precomputed tile, random offsets per frame, refreshed
    every ``noise_refresh_frames``), shot noise of variance ``shot_gain_dn · signal`` and
    multiplicative speckle of contrast ``speckle_contrast`` on the stripe, drawn fresh per
    frame; then rounding and clipping to uint8 (saturation at 255).
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


def _left_multiply(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a @ b`` for one (4, 4) ``a`` and a stack (N, 4, 4) ``b``, as one (4, 4N) product:
    a single BLAS call instead of N small ones."""
    n = b.shape[0]
    wide = np.ascontiguousarray(b.transpose(1, 0, 2)).reshape(4, 4 * n)
    out: FloatArray = (a @ wide).reshape(4, n, 4).transpose(1, 0, 2)
    return out


def _cut(p: Piece, l0: FloatArray, z0: FloatArray, dl: FloatArray, dz: FloatArray) -> FloatArray:
    """Parameter λ where the segment (l0, z0) + λ·(dl, dz) meets the line h = a + b·l of
    piece ``p``; a flat piece (b = 0) skips the products with zero."""
    if p.b == 0.0:
        out: FloatArray = (p.a - z0) / dz
    else:
        out = (p.a + p.b * l0 - z0) / (dz - p.b * dl)
    return out


@dataclass(frozen=True)
class _Columns:
    """Constants of a set of N read columns: laser-line end points in S (N, 3) mm, and the
    camera-frame Y and Z of the sub-column end points with their spans (N, K·P), tiled once
    per profile piece."""

    a_s: FloatArray
    b_s: FloatArray
    ya: FloatArray
    dy: FloatArray
    za: FloatArray
    dz: FloatArray


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
        self._a_s, self._b_s = cam.column_lines(u)  # (C, 3)
        da, db = cam.column_lines(np.array([1.0]))
        a0, b0 = cam.column_lines(np.array([0.0]))
        self._da, self._db = da[0] - a0[0], db[0] - b0[0]  # per column step (affine in u)
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
        self._tile = np.empty((0, 0), dtype=np.uint8)
        self._frames_on_tile = st.noise_refresh_frames
        self._pieces = scene.joint.pieces()
        self._source = np.array([0.0, 0.0, -cam.laser_standoff_mm])
        self._windows: dict[tuple[int, int], _Columns] = {}

    def _columns(self, columns: NDArray[np.intp]) -> _Columns:
        """Per-column constants of ``columns`` (N,): the same for every frame of a window."""
        n_pieces = len(self._pieces)
        ya, za = np.tile(self._ya[columns], n_pieces), np.tile(self._za[columns], n_pieces)
        yb, zb = np.tile(self._yb[columns], n_pieces), np.tile(self._zb[columns], n_pieces)
        return _Columns(
            a_s=self._a_s[columns], b_s=self._b_s[columns], ya=ya, dy=yb - ya, za=za, dz=zb - za
        )

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
        st, cam = self.settings, self.camera
        shape = (2 * cam.columns, 2 * cam.rows)
        noise = self._rng.standard_normal(shape, dtype=np.float32)
        noise *= np.float32(st.read_noise_dn)
        noise += np.float32(st.background_dn + 0.5)
        np.clip(noise, 0, 255, out=noise)
        self._tile = noise.astype(np.uint8)
        self._frames_on_tile = 0

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
        n = col.a_s.shape[0]
        if poses.shape != (n, 4, 4):
            raise CameraError(f"pose provider returned shape {poses.shape}")
        s2w = _left_multiply(self.scene.base2workpiece, poses)
        r, t = s2w[:, :3, :3], s2w[:, :3, 3]
        a_w = np.einsum("nij,nj->ni", r, col.a_s) + t
        b_w = np.einsum("nij,nj->ni", r, col.b_s) + t
        da_w = r @ self._da
        db_w = r @ self._db
        # sub-column end points A, B: (2 ends, 3 coordinates, N, K), each (N, K) plane
        # contiguous; x only matters on a curved seam
        k = self._delta.shape[0]
        ends = np.stack([a_w.T, b_w.T])[..., None]
        steps = np.stack([da_w.T, db_w.T])[..., None]
        sub = ends + self._delta * steps
        path = self.scene.path
        za, zb = sub[0, 2], sub[1, 2]
        if path.straight_line:
            la, lb = sub[0, 1], sub[1, 1]
        else:
            la = path.lateral(sub[0, 0], sub[0, 1])
            lb = path.lateral(sub[1, 0], sub[1, 1])
        dl, dz = lb - la, zb - za
        # laser source per column, for shadows cast by one plate on another; spread over
        # the K sub-columns once so the shadow tests below run on contiguous (N, K) arrays
        src = np.einsum("nij,j->ni", r, self._source) + t
        l_src = np.repeat(path.lateral(src[:, 0:1], src[:, 1:2]), k, axis=1)
        z_src = np.repeat(src[:, 2:3], k, axis=1)
        lam = np.empty((n, len(self._pieces) * k))
        with np.errstate(divide="ignore", invalid="ignore"):
            for i, p in enumerate(self._pieces):
                lam_p = _cut(p, la, za, dl, dz)
                lh = la + lam_p * dl
                ok = (lam_p >= 0.0) & (lam_p <= 1.0) & (lh >= p.lo) & (lh < p.hi)
                zh = za + lam_p * dz
                for q in self._pieces:
                    if q is p:
                        continue
                    # does the laser ray source -> hit cross piece q first?
                    dls, dzs = lh - l_src, zh - z_src
                    mu = _cut(q, l_src, z_src, dls, dzs)
                    lq = l_src + mu * dls
                    ok &= ~((mu > 0.0) & (mu < 1.0 - 1e-9) & (lq >= q.lo) & (lq < q.hi))
                np.copyto(lam[:, i * k : (i + 1) * k], np.where(ok, lam_p, np.nan))
            hit = np.isfinite(lam)
            v0 = self.camera.principal_point[1]
            rows = v0 + self.camera.focal_px * (col.ya + lam * col.dy) / (col.za + lam * col.dz)
        return hit, rows

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
        hit, rows = self._hits(self._window(first_column, n), times, sensor2base)
        k = st.subsamples
        count = np.count_nonzero(hit, axis=1)
        coverage = count / k
        rz = np.where(hit, rows, 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            mean = rz.sum(axis=1) / count
            var = (np.where(hit, rows - mean[:, None], 0.0) ** 2).sum(axis=1) / count
        lit = count > 0
        simple = lit & (var <= 0.3**2)
        sigma2 = st.stripe_sigma_px**2
        # simple columns: one Gaussian with the sub-columns' mass and spread
        si = np.flatnonzero(simple)
        if si.size:
            s_eff2 = sigma2 + var[si]
            peak = amp * coverage[si] * np.sqrt(sigma2 / s_eff2)
            start = np.clip(
                np.rint(mean[si]).astype(np.intp) - self._half, 0, cam.rows - len(self._win)
            )
            idx = start[:, None] + self._win[None, :]
            signal = peak[:, None] * np.exp(
                -((idx - mean[si, None]) ** 2) / (2.0 * s_eff2[:, None])
            )
            self._expose(frame, cols[si], idx, signal)
        # complex columns (an edge inside the column): every sub-column over the full column
        ci = np.flatnonzero(lit & ~simple)
        if ci.size:
            all_rows = np.arange(cam.rows, dtype=np.float64)
            d2 = (all_rows[None, None, :] - np.where(hit[ci], rows[ci], -1e9)[:, :, None]) ** 2
            signal = (amp / k) * np.exp(-d2 / (2.0 * sigma2)).sum(axis=1)
            idx = np.broadcast_to(np.arange(cam.rows), (ci.size, cam.rows))
            self._expose(frame, cols[ci], idx, signal)
        return frame, RenderTruth(np.where(simple, mean, np.nan), coverage, simple)

    def _expose(
        self, frame: U8Array, cols: NDArray[np.intp], idx: NDArray[np.intp], signal: FloatArray
    ) -> None:
        """Add stripe signal with shot noise and speckle to frame[cols, idx] in place."""
        st = self.settings
        var = signal * signal * st.speckle_contrast**2 + st.shot_gain_dn * signal
        noise = self._rng.standard_normal(signal.shape) * np.sqrt(var)
        # flat indices into the C-contiguous frame: one gather and one scatter
        flat = frame.reshape(-1)
        at = cols[:, None] * frame.shape[1] + idx
        value = flat[at] + signal + noise + 0.5
        np.clip(value, 0.0, 255.0, out=value)
        flat[at] = value.astype(np.uint8)


def image_rows(frame: U8Array) -> U8Array:
    """Conventional (rows, columns) view of a column-major frame (no copy)."""
    return frame.T


def frame_from_image(image: U8Array) -> U8Array:
    """Column-major C-contiguous frame (columns, rows) from a (rows, columns) image."""
    return np.ascontiguousarray(np.asarray(image).T)
