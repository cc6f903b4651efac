"""The cell's sensor as its trigger handler sees it: the seam reading with extra noise."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sensorsocket.sensor import Reading, Sensor
from sensorsocket.udp import TriggerHandler
from spec.wire import SensorStatus

__all__ = ["NoisyHandler", "NoisySensor"]


class NoisySensor:
    """The sensor as the trigger handler sees it, with extra Gaussian noise on the seam y, z
    of FOUND readings: the noise goes in before the reply is encoded (no decode and
    re-encode of the datagram). The sensor's own records and latest reading stay noiseless."""

    def __init__(self, sensor: Sensor, noise_mm: float, rng: np.random.Generator) -> None:
        self.sensor = sensor
        self.noise_mm = noise_mm
        self._rng = rng

    def busy(self, t_arrival: float) -> bool:
        return self.sensor.busy(t_arrival)

    def acquire(
        self,
        t_arrival: float | None = None,
        *,
        index: int | None = None,
        t_trigger: float = math.nan,
    ) -> Reading:
        r = self.sensor.acquire(t_arrival, index=index, t_trigger=t_trigger)
        if self.noise_mm <= 0 or r.status is not SensorStatus.FOUND:
            return r
        dy, dz = self._rng.normal(0.0, self.noise_mm, 2)
        s = r.seam
        return dataclasses.replace(r, seam=(s[0], s[1] + dy, s[2] + dz, s[3], s[4], s[5]))


class NoisyHandler(TriggerHandler):
    """The sensor's trigger handler with extra Gaussian noise on the reported seam y, z."""

    def __init__(self, sensor: Sensor, *, network_delay_s: float, noise_mm: float,
                 rng: np.random.Generator) -> None:  # fmt: skip
        super().__init__(NoisySensor(sensor, noise_mm, rng), network_delay_s=network_delay_s)
        self.noise_mm = noise_mm
