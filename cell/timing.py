"""Timing of the emulated cell: the delays and jitters that make up ΔT (pure)."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["CellError", "CellTiming"]


class CellError(ValueError):
    """A cell parameter is out of range."""


@dataclass(frozen=True)
class CellTiming:
    """Timing of the cell (seconds, Hz, mm); defaults give the paper's ΔT ≈ 4.9 ms.

    encoder_latency_s: measured joints lag the true motion by this much.
    poll_rate_hz: the sensor's trigger loop (4 kHz: 0..0.25 ms).
    start_jitter_s: uniform extra delay before the exposure starts (0..0.25 ms).
    start_latency_s: fixed extra delay before the exposure starts.
    acquisition_s: readout of the full 512 columns (3.5 ms).
    processing_s: image processing after the readout.
    network_delay_s, network_jitter_s: one-way UDP delay, mean and uniform width (sim only;
        in real time the network is real).
    sensor_noise_mm: Gaussian noise added to the seam's y and z in the data datagrams, on
        top of the detector's own noise.
    """

    encoder_latency_s: float = 2.8e-3
    poll_rate_hz: float = 4000.0
    start_jitter_s: float = 0.25e-3
    start_latency_s: float = 0.0
    acquisition_s: float = 3.5e-3
    processing_s: float = 1.0e-3
    network_delay_s: float = 0.1e-3
    network_jitter_s: float = 0.1e-3
    sensor_noise_mm: float = 0.010

    def __post_init__(self) -> None:
        for name in (
            "encoder_latency_s",
            "start_jitter_s",
            "start_latency_s",
            "processing_s",
            "network_delay_s",
            "network_jitter_s",
            "sensor_noise_mm",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise CellError(f"{name} must be >= 0, got {v}")
        if not (math.isfinite(self.poll_rate_hz) and self.poll_rate_hz > 0):
            raise CellError("poll_rate_hz must be > 0")
        if not (math.isfinite(self.acquisition_s) and 0 < self.acquisition_s <= 0.1):
            raise CellError("acquisition_s must be in (0, 0.1] s")
        if self.network_jitter_s > 2 * self.network_delay_s:
            raise CellError("network_jitter_s must be <= 2 x network_delay_s")

    def true_delta_t_s(self, seam_time_s: float | None = None) -> float:
        """ΔT the experiment should find: encoder latency + mean network delay + mean poll
        wait + mean start jitter + start latency + the time from exposure start to the seam
        column (half the acquisition for a centred seam on the full chip, the default)."""
        seam = self.acquisition_s / 2.0 if seam_time_s is None else seam_time_s
        return (
            self.encoder_latency_s
            + self.network_delay_s
            + 0.5 / self.poll_rate_hz
            + self.start_jitter_s / 2.0
            + self.start_latency_s
            + seam
        )

    def jitter_width_s(self) -> float:
        """Total width of the trigger-to-exposure jitter (s): poll + start + network."""
        return 1.0 / self.poll_rate_hz + self.start_jitter_s + self.network_jitter_s
