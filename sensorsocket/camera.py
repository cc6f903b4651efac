"""Laser-stripe renderer of the seam-tracking camera (pure).

The parts, each in its module: the camera geometry and its calibration (sensor frame S,
pixel <-> S) in :mod:`sensorsocket.geometry`; what each read column sees (sub-column hits
and their statistics, the plain model) in :mod:`sensorsocket.columns`, with the fast
straight-seam path in :mod:`sensorsocket.straight_seam`; light to grey levels (background,
noise, the stripe's exposure) in :mod:`sensorsocket.exposure`. This module puts them
together: :class:`StripeRenderer`.

Image coordinates: column u grows with y_S, row v grows with z_S (farther away). The chip
is read **column by column**, column 0 first. Frames are stored in readout order as
``(columns, rows) = (512, 256)`` uint8, C-contiguous: ``frame[u]`` is column u, one
contiguous run of 256 bytes. ``frame.T`` is the conventional (256 rows, 512 columns) view.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinematics.types import FloatArray
from sensorsocket.columns import ColumnStats, ReferenceColumns, SubColumns
from sensorsocket.exposure import Exposure, RenderSettings
from sensorsocket.geometry import CameraError, CameraGeometry
from sensorsocket.scene import PoseProvider, Scene
from sensorsocket.straight_seam import StraightSeamColumns

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
class RenderTruth:
    """What the renderer put in each read column (N,): centre row, coverage, simple column.

    ``simple`` columns hold one Gaussian stripe whose true centre is ``center_row``;
    ``coverage`` is the fraction of the column's width that the surface lit (0 in a gap).
    """

    center_row: FloatArray = field(repr=False)
    coverage: FloatArray = field(repr=False)
    simple: NDArray[np.bool_] = field(repr=False)


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
        self.exposure = Exposure(self.camera, self.settings, rng)
        sub = SubColumns(self.camera, self.settings.subsamples)
        self.reference = ReferenceColumns(scene, sub)
        self.straight = StraightSeamColumns(scene, sub) if scene.path.straight_line else None

    def column_stats(
        self, first_column: int, times: FloatArray, sensor2base: PoseProvider
    ) -> ColumnStats:
        """What the read columns ``first_column + i`` exposed at ``times[i]`` (N,) s see:
        the straight-seam path where it applies, else every sub-column."""
        if self.straight is not None:
            return self.straight.stats(first_column, times, sensor2base)
        return self.reference.stats(first_column, times, sensor2base)

    def hits(
        self, columns: NDArray[np.intp], column_times: FloatArray, sensor2base: PoseProvider
    ) -> tuple[NDArray[np.bool_], FloatArray]:
        """Lit points of every sub-column and profile piece: (lit (N, K·P), row (N, K·P)).

        A point is lit when the laser plane meets a piece of the surface there and the
        laser ray from the source does not cross another piece first (shadow); the camera
        sees every lit point (no occlusion). Rows are NaN where unlit.
        """
        ref = self.reference
        return ref.hits(ref.columns(np.asarray(columns, dtype=np.intp)), column_times, sensor2base)

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
        self.exposure.background(first_column, n, frame)
        cols = np.arange(first_column, first_column + n)
        exposure = st.reference_exposure_s if exposure_s is None else exposure_s
        amp = st.stripe_peak_dn * self.scene.brightness * exposure / st.reference_exposure_s
        if not laser_on or amp <= 0.0:
            empty = np.full(n, np.nan)
            return frame, RenderTruth(empty, np.zeros(n), np.zeros(n, dtype=bool))
        times = np.asarray(column_times, dtype=np.float64)
        stats = self.column_stats(first_column, times, sensor2base)
        coverage, mean, var, simple = stats.coverage, stats.mean, stats.var, stats.simple
        k = st.subsamples
        sigma2 = st.stripe_sigma_px**2
        # simple columns: one Gaussian with the sub-columns' mass and spread
        si = np.flatnonzero(simple)
        if si.size:
            self.exposure.simple_columns(frame, first_column, si, coverage, mean, var, amp)
        # complex columns (an edge inside the column): every sub-column over the full column
        ci = stats.complex_columns
        if ci.size:
            all_rows = np.arange(cam.rows, dtype=np.float64)
            d2 = (all_rows[None, None, :] - stats.complex_rows[:, :, None]) ** 2
            signal = (amp / k) * np.exp(-d2 / (2.0 * sigma2)).sum(axis=1)
            at = cols[ci, None] * cam.rows + np.arange(cam.rows)
            self.exposure.add_signal(frame, at, signal.astype(np.float32))
        return frame, RenderTruth(np.where(simple, mean, np.nan), coverage, simple)


def image_rows(frame: U8Array) -> U8Array:
    """Conventional (rows, columns) view of a column-major frame (no copy)."""
    return frame.T


def frame_from_image(image: U8Array) -> U8Array:
    """Column-major C-contiguous frame (columns, rows) from a (rows, columns) image."""
    return np.ascontiguousarray(np.asarray(image).T)
