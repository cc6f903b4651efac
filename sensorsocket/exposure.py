"""Image formation of the seam-tracking camera: light to grey levels (pure).

A frame is a dark background with read noise (pre-drawn tile, :meth:`Exposure.background`)
plus the stripe's light with shot noise and speckle, rounded and clipped to uint8. The
stripe signal of a *simple* column (one Gaussian, see :mod:`sensorsocket.columns`) goes in
through :meth:`Exposure.simple_columns`, any other signal through :meth:`Exposure.add_signal`.
Frames are column-major ``(columns, rows)`` uint8, see :mod:`sensorsocket.camera`.
"""

from __future__ import annotations

import functools
import math
import statistics
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinematics.types import FloatArray
from sensorsocket.geometry import CameraError, CameraGeometry

U8Array = NDArray[np.uint8]

#: Unit normals pre-drawn for the stripe noise: a frame's simple columns take 512 × 15, so
#: the pool holds ~17 frames' worth and each frame reads it at a random offset.
NORMAL_POOL_SIZE = 1 << 17


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
    ``subsamples``: sub-columns per chip column (K), see :mod:`sensorsocket.columns`.
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


class Exposure:
    """Background, noise and the stripe's light into frames of one camera (owns the rng)."""

    def __init__(
        self, camera: CameraGeometry, settings: RenderSettings, rng: np.random.Generator
    ) -> None:
        self.camera = camera
        self.settings = settings
        self._rng = rng
        # a simple column's window: 4.4 σ (4 σ + 10 %) either side of the centre row, where
        # the Gaussian is e^(-9.7) ≈ 6e-5 of the peak (< 0.01 DN at the default peak)
        self.half = math.ceil(4.0 * settings.stripe_sigma_px * 1.1)
        self._win_f32 = np.arange(2 * self.half + 1).astype(np.float32)
        self._tile = np.empty((0, 0), dtype=np.uint8)
        self._frames_on_tile = settings.noise_refresh_frames
        self._background_table = _rounded_normal_table(
            settings.background_dn, settings.read_noise_dn
        )
        self.normals = np.empty(0, dtype=np.float32)  # the pool, see unit_normals

    def _refresh(self) -> None:
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
        words = self._rng.integers(0, 1 << 32, size=NORMAL_POOL_SIZE // 2, dtype=np.uint32)
        self.normals = _normal_table().take(words.astype("<u4", copy=False).view("<u2"))
        self._frames_on_tile = 0

    def unit_normals(self, shape: tuple[int, int]) -> NDArray[np.float32]:
        """Unit normals of ``shape`` from the pool at a random offset (fresh if too many)."""
        size = shape[0] * shape[1]
        pool = self.normals
        if size > pool.size // 2:
            return self._rng.standard_normal(shape, dtype=np.float32)
        o = int(self._rng.integers(0, pool.size - size + 1))
        return pool[o : o + size].reshape(shape)

    def background(self, first_column: int, n_columns: int, out: U8Array) -> None:
        """Write dark-frame background + read noise into ``out[first:first+n]``."""
        if self._frames_on_tile >= self.settings.noise_refresh_frames:
            self._refresh()
        self._frames_on_tile += 1
        cam = self.camera
        c0 = int(self._rng.integers(0, self._tile.shape[0] - n_columns + 1))
        r0 = int(self._rng.integers(0, self._tile.shape[1] - cam.rows + 1))
        out[first_column : first_column + n_columns] = self._tile[
            c0 : c0 + n_columns, r0 : r0 + cam.rows
        ]

    def simple_columns(
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
        sub-columns' mass (``coverage``) and spread (``var``, px²) around their ``mean``
        row, plus noise, into the window of 2·half + 1 rows around the mean row: float64
        per column, float32 per pixel."""
        rows, half = self.camera.rows, self.half
        w = 2 * half + 1
        st = self.settings
        sigma2 = st.stripe_sigma_px**2
        s_eff2 = var[si] + sigma2
        peak = (coverage[si] * amp * np.sqrt(sigma2 / s_eff2)).astype(np.float32)
        start = np.clip(np.rint(mean[si]) - half, 0.0, float(rows - w))
        # float32 from here: the Gaussian's centre to ~1e-6 px, far below the noise
        dm = (start - mean[si]).astype(np.float32)
        e = (-0.5 / s_eff2).astype(np.float32)
        x = self._win_f32[None, :] + dm[:, None]
        signal = np.exp(x * x * e[:, None]) * peak[:, None]
        c2, g = np.float32(st.speckle_contrast**2), np.float32(st.shot_gain_dn)
        sd = np.sqrt(signal * (signal * c2 + g))
        at = (first_column + si)[:, None] * rows + start.astype(np.intp)[:, None] + np.arange(w)
        flat = frame.reshape(-1)
        value = self.unit_normals((si.size, w)) * sd + signal + np.float32(0.5) + flat[at]
        flat[at] = np.clip(value, 0.0, 255.0).astype(np.uint8)

    def add_signal(self, frame: U8Array, at: NDArray[np.intp], signal: NDArray[np.float32]) -> None:
        """Add stripe signal (M, W) DN with shot noise and speckle to the pixels at flat
        indices ``at`` (M, W) of the C-contiguous frame, in place."""
        st = self.settings
        c2, g = np.float32(st.speckle_contrast**2), np.float32(st.shot_gain_dn)
        sd = np.sqrt(signal * (signal * c2 + g))
        value = self.unit_normals(signal.shape) * sd
        value += signal
        value += np.float32(0.5)
        # one gather and one scatter on the flat frame
        flat = frame.reshape(-1)
        value += flat[at]
        np.clip(value, 0.0, 255.0, out=value)
        flat[at] = value.astype(np.uint8)


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
