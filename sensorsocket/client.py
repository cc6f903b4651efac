"""SensorClient: one typed method per SensorSocket command (PROTOCOL.md section 5.4).

Results follow the rule of :mod:`robotsocket.client`: a seam pose (``SeamData.seam``) is a
VAL3 location, :data:`kinematics.types.Loc` (a tuple of six floats); images and point sets are
numpy arrays (an image (rows, columns) uint8 or uint16, a profile (N, 3) float64 mm); a reply
of several values is a frozen dataclass, and a measurement's data comes with its index as an
``(index, data)`` pair: ``index, image = sensor.get_image()``.

Errors arrive as :class:`spec.errors.RemoteError` with the wire code (e.g. NO_DATA before the
first measurement, OUT_OF_RANGE, NOT_IN_CONTROL).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinematics.types import Loc
from spec import wire
from spec.client import FramedClient
from spec.errors import PeerError
from spec.messages import (
    AcquireReply,
    GetDataReply,
    GetImageReply,
    GetProfileReply,
    GetSettingsReply,
    GetTriggerEndpointReply,
    SensorStatusReply,
    SetReadoutWindowReply,
)
from spec.params import Image
from spec.registry import CommandId
from spec.wire import PixelFormat, PixelOrder, SensorStatus

#: GetStatus reply (laser, frames, last_index, in_control, controlled, time on the sensor
#: clock in s): the registry's message class.
SensorState = SensorStatusReply


@dataclass(frozen=True)
class SeamData:
    """GetData reply: ``seam`` is ^S_G T as a VAL3 location (mm, deg), None unless FOUND."""

    index: int
    status: SensorStatus
    seam: Loc | None
    quality: float
    t_arrival: float
    t_exposure_start: float
    t_exposure_end: float

    @property
    def found(self) -> bool:
        return self.status is SensorStatus.FOUND


#: GetSettings reply (laser, exposure, first_column, columns, acquisition_time, width,
#: height; times in s, columns in px): the registry's message class.
Settings = GetSettingsReply


def image_to_array(image: Image) -> NDArray[np.uint8] | NDArray[np.uint16]:
    """An IMAGE parameter as a (height rows, width columns) array, whatever its order."""
    dtype = np.uint8 if image.format is PixelFormat.MONO8 else np.dtype(">u2")
    flat = np.frombuffer(image.data, dtype=dtype)
    if image.order is PixelOrder.COLUMN_MAJOR:
        arr = flat.reshape(image.width, image.height).T
    else:
        arr = flat.reshape(image.height, image.width)
    if image.format is PixelFormat.MONO16:
        return np.ascontiguousarray(arr, dtype=np.uint16)
    return np.ascontiguousarray(arr)


class SensorClient(FramedClient):
    """Blocking client of a SensorSocket server (default port 2000)."""

    DEFAULT_PORT = wire.SENSOR_PORT
    CLIENT_NAME = "sensorsocket-client/0.1"

    def __enter__(self) -> SensorClient:
        return self

    def status(self) -> SensorState:
        return SensorStatusReply.decode(self.call(CommandId.SENSOR_STATUS))

    def get_data(self) -> SeamData:
        """The latest measurement (paper: data = GetData())."""
        d = GetDataReply.decode(self.call(_GET_DATA))
        status = SensorStatus(d.status)
        seam = d.seam.as_tuple() if status is SensorStatus.FOUND else None
        return SeamData(
            d.index, status, seam, d.quality, d.t_arrival, d.t_exposure_start, d.t_exposure_end
        )

    def get_image_raw(self, region: tuple[int, ...] | None = None) -> tuple[int, Image]:
        """(index, IMAGE) of the latest frame; ``region`` = (column, row, width, height),
        trailing values optional (the rest of the sensor)."""
        if region is None:
            v = self.call(_GET_IMAGE)
        else:
            v = self.call(_GET_IMAGE, *(int(x) for x in region))
        reply = GetImageReply.decode(v)
        return reply.index, reply.image

    def get_image(
        self, region: tuple[int, ...] | None = None
    ) -> tuple[int, NDArray[np.uint8] | NDArray[np.uint16]]:
        """(index, image (rows, columns)) of the latest frame (paper: image = GetImage())."""
        index, image = self.get_image_raw(region)
        return index, image_to_array(image)

    def get_profile(self) -> tuple[int, NDArray[np.float64]]:
        """(index, stripe points (N, 3) mm in the sensor frame)."""
        reply = GetProfileReply.decode(self.call(CommandId.GET_PROFILE))
        m = reply.points
        return reply.index, np.asarray(m.values, dtype=np.float64).reshape(m.rows, m.cols)

    def set_laser(self, on: bool) -> None:
        self.call(CommandId.SET_LASER, bool(on))

    def set_exposure(self, exposure_s: float) -> None:
        self.call(CommandId.SET_EXPOSURE, float(exposure_s))

    def set_readout_window(self, first_column: int, columns: int) -> float:
        """Returns the resulting acquisition time (s)."""
        reply = self.call(CommandId.SET_READOUT_WINDOW, int(first_column), int(columns))
        return SetReadoutWindowReply.decode(reply).acquisition_time

    def get_settings(self) -> Settings:
        return GetSettingsReply.decode(self.call(CommandId.GET_SETTINGS))

    def acquire(self) -> int:
        """Software trigger; returns the index of the new measurement (needs control)."""
        return AcquireReply.decode(self.call(CommandId.ACQUIRE)).index

    def measure(self) -> SeamData:
        """Acquire (needs control) and return that measurement, checked to be the new one."""
        index = self.acquire()
        data = self.get_data()
        if data.index != index:
            raise PeerError(f"GetData returned measurement {data.index}, expected {index}")
        return data

    def problem(self, data: SeamData) -> str:
        """What a measurement without a seam tells the operator, "" when FOUND: a laser that
        is off says so and how to switch it on here, never "no seam" [SS-5.13]."""
        return data.status.problem(self.address)

    def get_trigger_endpoint(self) -> tuple[str, int]:
        reply = GetTriggerEndpointReply.decode(self.call(CommandId.GET_TRIGGER_ENDPOINT))
        return reply.host, reply.port


# Enum members as ints: an enum attribute look-up is slow in Python 3.11.
_GET_IMAGE, _GET_DATA = int(CommandId.GET_IMAGE), int(CommandId.GET_DATA)


__all__ = ["SeamData", "SensorClient", "SensorState", "Settings", "image_to_array"]
