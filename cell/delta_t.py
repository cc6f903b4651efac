"""ΔT bookkeeping of the emulated cell: the delay the experiment should find (pure).

Two truths to compare the ΔT experiment with: :meth:`DeltaTBook.true_delta_t_s`, from the
timing parameters, and :meth:`DeltaTBook.measured_delta_t`, from the sensor's own record of
every triggered acquisition (when the seam's column was exposed, :meth:`DeltaTBook.record`,
the sensor's ``after_acquire`` hook).

The robot places a reading exposed late (the chip still busy with the previous frame) later
by its extra lag [SY-3.8], so the ΔT it adds to t_i^T is that of a reading exposed on time:
the records take the same extra lag off (:class:`~sync.exposure_lag.ExposureLag`, the
sensor's stamps), and where no reading is late they give the ΔT they always gave.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cell.timing import CellTiming
from sensorsocket.emulator import CameraEmulator
from sensorsocket.sensor import Reading
from sensorsocket.timing import TimingModel
from spec.wire import SensorStatus
from sync.exposure_lag import ExposureLag

__all__ = ["DeltaTBook", "Record"]


@dataclass
class Record:
    """One acquisition: trigger index, robot send time of the trigger t_i^T and the time the
    seam column was exposed (s; NaN when no seam was found); ``extra_lag_s`` the lag its
    exposure started later than the sensor's usual by (0.0 unless exposed late, SY-3.8)."""

    index: int
    t_trigger: float
    t_seam: float
    status: SensorStatus
    extra_lag_s: float = 0.0


class DeltaTBook:
    """The records of the cell's acquisitions and the ΔT they imply."""

    def __init__(self, timing: CellTiming, camera: CameraEmulator, camera_timing: TimingModel):
        self.timing = timing
        self.camera = camera
        self.camera_timing = camera_timing
        self.records: list[Record] = []
        self._lag = ExposureLag()

    def record(self, reading: Reading) -> None:
        """Record one acquisition; the seam's time is the middle of its column's exposure."""
        settings = self.camera.settings
        t_seam = math.nan
        extra = 0.0
        if reading.status is SensorStatus.FOUND:
            extra = self._lag.extra(reading.t_arrival, reading.t_exposure_start)
            u = self.camera.camera.plane_column(float(reading.seam[1]), float(reading.seam[2]))
            t_seam = (
                reading.t_exposure_start
                + (u - settings.first_column) * self.camera_timing.column_period_s
                + settings.exposure_s / 2.0
            )
        self.records.append(Record(reading.index, reading.t_trigger, t_seam, reading.status, extra))

    def true_delta_t_s(self) -> float:
        """ΔT from the timing parameters, for a centred seam on the current readout window."""
        s = self.camera.settings
        cols = self.camera.camera.columns
        seam = ((cols - 1) / 2.0 - s.first_column) * self.camera_timing.column_period_s
        return self.timing.true_delta_t_s(seam + s.exposure_s / 2.0)

    def measured_delta_t(self, first_index: int = 0) -> float:
        """ΔT from the records of triggered acquisitions with index >= ``first_index``:
        encoder latency + mean(time of the seam column - t_i^T - extra lag, 0.0 but for a
        reading exposed late). NaN when none found a seam."""
        d = [
            r.t_seam - r.t_trigger - r.extra_lag_s
            for r in self.records
            if r.index >= first_index and math.isfinite(r.t_seam) and math.isfinite(r.t_trigger)
        ]
        if not d:
            return math.nan
        return self.timing.encoder_latency_s + float(np.mean(d))
