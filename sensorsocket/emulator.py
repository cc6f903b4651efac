"""The seam-tracking camera as one object: trigger -> frame -> measurement (pure).

``CameraEmulator.acquire(t_arrival)`` schedules the acquisition with the timing model,
renders each column at its own time from the pose provider and returns a :class:`Frame`;
``measure(frame)`` runs the detector and returns a :class:`Measurement` carrying the
sensor-clock timestamps the UDP data datagram needs. No sockets, threads or clocks: the
server or the emulated cell calls these with its own times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinematics.types import FloatArray
from sensorsocket.camera import CameraGeometry, RenderSettings, RenderTruth, StripeRenderer
from sensorsocket.detector import DetectorConfig, SeamDetector, SeamStatus
from sensorsocket.scene import PoseProvider, Scene
from sensorsocket.timing import Acquisition, TimingModel


class SettingsError(ValueError):
    """A sensor setting (exposure, readout window) is out of range."""


@dataclass(frozen=True)
class SensorSettings:
    """Exposure per column (s) and readout window (first chip column, column count)."""

    exposure_s: float
    first_column: int = 0
    n_columns: int = 512


@dataclass(frozen=True)
class Frame:
    """One acquired image; ``image`` is (columns, rows) uint8, C-contiguous, readout order.

    Columns outside the readout window are not read and are 0. ``image.T`` is the
    conventional (rows, columns) view.
    """

    index: int
    image: NDArray[np.uint8] = field(repr=False)
    acquisition: Acquisition
    laser_on: bool
    truth: RenderTruth | None = field(repr=False, default=None)

    @property
    def rows_view(self) -> NDArray[np.uint8]:
        """(rows, columns) view for saving or display (no copy)."""
        return self.image.T

    @property
    def window(self) -> NDArray[np.uint8]:
        """The read columns only, (n_columns, rows)."""
        a = self.acquisition
        return self.image[a.first_column : a.first_column + a.n_columns]

    @property
    def column_times(self) -> FloatArray:
        return self.acquisition.column_times


@dataclass(frozen=True)
class Measurement:
    """What GetData() and the UDP data datagram report for one frame (mm, s, sensor clock)."""

    index: int
    found: bool
    status: SeamStatus
    seam2sensor: FloatArray = field(repr=False)
    quality: float
    t_arrival: float
    t_exposure_start: float
    t_exposure_end: float
    seam_column: float  # chip column of the seam, NaN if none
    t_seam: float  # time that column was exposed, NaN if none
    points: FloatArray = field(repr=False)  # (M, 3) profile in S, mm


class CameraEmulator:
    """Seam-tracking sensor emulator: scene + pose provider + timing + renderer + detector."""

    def __init__(
        self,
        scene: Scene,
        sensor2base: PoseProvider,
        timing: TimingModel,
        camera: CameraGeometry | None = None,
        *,
        rng: np.random.Generator,
        render: RenderSettings | None = None,
        detector: DetectorConfig | None = None,
    ) -> None:
        self.scene = scene
        self.sensor2base = sensor2base
        self.timing = timing
        self.camera = camera if camera is not None else CameraGeometry()
        if self.camera.columns != timing.full_frame_columns:
            raise SettingsError("camera columns and timing full_frame_columns differ")
        self.renderer = StripeRenderer(scene, self.camera, render, rng=rng)
        cfg = detector if detector is not None else DetectorConfig(joint=scene.joint.kind)
        self.detector = SeamDetector(self.camera, cfg)
        self.laser_on = True
        self._settings = SensorSettings(
            exposure_s=timing.column_period_s, n_columns=self.camera.columns
        )
        self._index = 0
        self._busy_until = -math.inf

    @property
    def settings(self) -> SensorSettings:
        return self._settings

    def set_laser(self, on: bool) -> None:
        """Switch the laser; with the laser off frames are dark and no seam is found."""
        self.laser_on = bool(on)

    def configure(
        self,
        *,
        exposure_s: float | None = None,
        first_column: int | None = None,
        n_columns: int | None = None,
    ) -> SensorSettings:
        """Change exposure (s, 1 µs..10 ms) and/or readout window; returns the new settings."""
        s = self._settings
        exposure = s.exposure_s if exposure_s is None else float(exposure_s)
        first = s.first_column if first_column is None else int(first_column)
        n = s.n_columns if n_columns is None else int(n_columns)
        if not (1e-6 <= exposure <= 10e-3):
            raise SettingsError(f"exposure {exposure} s outside 1 µs..10 ms")
        if first < 0 or n < 16 or first + n > self.camera.columns:
            raise SettingsError(
                f"readout window {first}+{n} must lie in 0..{self.camera.columns}, >= 16 columns"
            )
        self._settings = SensorSettings(exposure_s=exposure, first_column=first, n_columns=n)
        return self._settings

    def acquisition_time(self) -> float:
        """Readout time of the current window (s): 3.5 ms for all 512 columns."""
        return self.timing.acquisition_time(self._settings.n_columns)

    def acquire(self, t_arrival: float, *, keep_truth: bool = False) -> Frame:
        """Take the image triggered by a datagram that arrived at t_arrival (s, sensor clock)."""
        s = self._settings
        acq = self.timing.schedule(
            t_arrival,
            first_column=s.first_column,
            n_columns=s.n_columns,
            exposure_s=s.exposure_s,
            not_before=self._busy_until,
        )
        self._busy_until = acq.t_exposure_end
        image, truth = self.renderer.render(
            s.first_column,
            acq.column_times,
            self.sensor2base,
            laser_on=self.laser_on,
            exposure_s=s.exposure_s,
        )
        frame = Frame(
            index=self._index,
            image=image,
            acquisition=acq,
            laser_on=self.laser_on,
            truth=truth if keep_truth else None,
        )
        self._index += 1
        return frame

    def measure(self, frame: Frame) -> Measurement:
        """Find the seam in ``frame``; the result keeps the frame's index and timestamps."""
        acq = frame.acquisition
        det = self.detector.detect(frame.window, acq.first_column)
        return Measurement(
            index=frame.index,
            found=det.found,
            status=det.status,
            seam2sensor=det.seam2sensor,
            quality=det.quality,
            t_arrival=acq.t_arrival,
            t_exposure_start=acq.t_exposure_start,
            t_exposure_end=acq.t_exposure_end,
            seam_column=det.column,
            t_seam=acq.column_time(det.column) if det.found else math.nan,
            points=det.points,
        )
