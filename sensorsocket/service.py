"""SensorSocket: the sensor commands (PROTOCOL.md section 5.4) on the shared framed server.

The shell (:class:`spec.server.FramedServer`) does Hello, Ping, control, GetTime, parameter
checks, limits and error packets; :class:`SensorService` answers the sensor commands from a
:class:`~sensorsocket.sensor.Sensor`.

Images go on the wire as IMAGE MONO8 ROW_MAJOR (row 0 first), width = columns; the sensor
keeps frames in readout (column-major) order and transposes on the way out. A measurement
that is not FOUND carries a location of six zeros in GetData (LOCATION values must be finite
on the wire; the status says the location is void) [SS-5.8].
"""

from __future__ import annotations

import logging
import math

import numpy as np

from sensorsocket.sensor import Reading, Sensor, SensorError
from spec.codec import PreparedParams, prepare_params
from spec.errors import ErrorCode, ProtocolError
from spec.messages import (
    GetDataReply,
    GetSettingsReply,
    GetTriggerEndpointReply,
    SensorStatusReply,
)
from spec.params import Image, Location, Matrix, Value
from spec.registry import CommandId
from spec.server import HandlerService, Identity, SessionView
from spec.wire import PixelFormat, PixelOrder, SensorStatus

log = logging.getLogger(__name__)

SENSOR_IDENTITY = Identity(
    service="sensor", vendor="reference", model="seam-tracker-emulator 512x256", serial="0"
)


class SensorService(HandlerService):
    """Sensor commands over a :class:`Sensor`; ``trigger_endpoint`` is reported by
    GetTriggerEndpoint ((host, 0) when UDP triggering is off)."""

    def __init__(
        self,
        sensor: Sensor,
        *,
        identity: Identity = SENSOR_IDENTITY,
        trigger_endpoint: tuple[str, int] = ("", 0),
    ) -> None:
        super().__init__()
        self.sensor = sensor
        self.identity = identity
        self.trigger_endpoint = trigger_endpoint
        # The full-frame reply of the latest reading: transposing 128 KiB costs ~70 µs and
        # its CRC a pass over it, so both are done once per frame, not once per GetImage.
        self._full_reply: tuple[Reading, PreparedParams] | None = None
        for command, handler in {
            CommandId.SENSOR_STATUS: self._status,
            CommandId.GET_DATA: self._get_data,
            CommandId.GET_IMAGE: self._get_image,
            CommandId.GET_PROFILE: self._get_profile,
            CommandId.SET_LASER: self._set_laser,
            CommandId.SET_EXPOSURE: self._set_exposure,
            CommandId.SET_READOUT_WINDOW: self._set_readout_window,
            CommandId.GET_SETTINGS: self._get_settings,
            CommandId.ACQUIRE: self._acquire,
            CommandId.GET_TRIGGER_ENDPOINT: self._trigger_endpoint,
        }.items():
            self.register(command, handler)

    def clock(self) -> float:
        return self.sensor.clock()

    def error_code(self, exc: Exception) -> ErrorCode | None:
        return ErrorCode.OUT_OF_RANGE if isinstance(exc, SensorError) else None

    def on_control_lost(self, session: SessionView) -> None:
        # [RS-7.10] [RS-7.23] the laser goes off and stays off until SetLaser switches it on.
        if self.sensor.settings.laser:
            log.warning("controller lost: sensor laser off")
            self.sensor.set_laser(False)

    def on_control_released(self, session: SessionView) -> None:
        """[RS-7.23] A release hands the sensor over as it is: the laser stays as it was."""

    # --- read-only --------------------------------------------------------------------------

    def _latest(self) -> Reading:
        reading = self.sensor.latest
        if reading is None:
            # [SS-5.2] nothing measured yet: NO_DATA.
            raise ProtocolError("no measurement yet: trigger or Acquire first", ErrorCode.NO_DATA)
        return reading

    def _status(self, session: SessionView, params: tuple[Value, ...]) -> tuple[Value, ...]:
        latest = self.sensor.latest
        return SensorStatusReply(
            self.sensor.settings.laser,
            self.sensor.frames,
            -1 if latest is None else latest.index,
            session.in_control,
            session.control_held,
            float(self.sensor.clock()),
        ).encode()

    def _get_data(self, session: SessionView, params: tuple[Value, ...]) -> tuple[Value, ...]:
        r = self._latest()
        found = r.status is SensorStatus.FOUND
        seam = Location(*r.seam) if found else Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        # [SS-5.1] index, status, ^S_G T, quality, and the three sensor-clock times, which
        # satisfy t_arrival <= t_exposure_start <= t_exposure_end [SS-5.5].
        return GetDataReply(
            r.index,
            int(r.status),
            seam,
            float(r.quality),
            float(r.t_arrival),
            float(r.t_exposure_start),
            float(r.t_exposure_end),
        ).encode()

    def _get_image(self, session: SessionView, params: tuple[Value, ...]) -> tuple[Value, ...]:
        r = self._latest()
        if not params:
            return self._full(r)
        width, height = self.sensor.width, self.sensor.height
        ints = [int(p) for p in params if isinstance(p, int)]
        column = ints[0] if len(ints) > 0 else 0
        row = ints[1] if len(ints) > 1 else 0
        w = ints[2] if len(ints) > 2 else width - column
        h = ints[3] if len(ints) > 3 else height - row
        if not (
            0 <= column < width and 0 <= row < height and w >= 1 and h >= 1
            and column + w <= width and row + h <= height
        ):  # fmt: skip
            # [SS-5.4] a region outside the sensor is OUT_OF_RANGE.
            raise ProtocolError(
                f"region column={column} row={row} width={w} height={h} is not inside the "
                f"{width}x{height} sensor",
                ErrorCode.OUT_OF_RANGE,
            )
        if (column, row, w, h) == (0, 0, width, height):
            return self._full(r)
        # [SS-5.3] the frame is (columns, rows) in readout order; rows go on the wire.
        pixels = r.frame[column : column + w, row : row + h].T.tobytes()
        image = Image(w, h, pixels, PixelFormat.MONO8, PixelOrder.ROW_MAJOR)
        return (r.index, image)

    def _full(self, r: Reading) -> PreparedParams:
        """The reply (index, whole frame) of reading ``r``, encoded once for every GetImage."""
        cached = self._full_reply
        if cached is not None and cached[0] is r:
            return cached[1]
        pixels = np.ascontiguousarray(r.frame.T).tobytes()
        image = Image(r.frame.shape[0], r.frame.shape[1], pixels)  # MONO8, ROW_MAJOR
        reply = prepare_params((r.index, image))
        self._full_reply = (r, reply)
        return reply

    def _get_profile(self, session: SessionView, params: tuple[Value, ...]) -> tuple[Value, ...]:
        r = self._latest()
        # [SS-5.9] N x 3 stripe points in S, mm.
        points = np.ascontiguousarray(r.points, dtype=np.float64).reshape(-1, 3)
        return (r.index, Matrix(points.shape[0], 3, points.ravel().tolist()))

    def _get_settings(self, session: SessionView, params: tuple[Value, ...]) -> tuple[Value, ...]:
        s = self.sensor.settings
        return GetSettingsReply(
            s.laser,
            float(s.exposure_s),
            s.first_column,
            s.columns,
            float(self.sensor.acquisition_time()),
            self.sensor.width,
            self.sensor.height,
        ).encode()

    def _trigger_endpoint(
        self, session: SessionView, params: tuple[Value, ...]
    ) -> tuple[Value, ...]:
        host, port = self.trigger_endpoint
        return GetTriggerEndpointReply(host, int(port)).encode()

    # --- need control (checked by the shell) [RS-7.4] ---------------------------------------

    def _set_laser(self, session: SessionView, params: tuple[Value, ...]) -> tuple[Value, ...]:
        self.sensor.set_laser(bool(params[0]))
        return ()

    def _set_exposure(self, session: SessionView, params: tuple[Value, ...]) -> tuple[Value, ...]:
        exposure = params[0]
        assert isinstance(exposure, float)
        # [SS-5.6] outside 1e-6..0.01 s: OUT_OF_RANGE (SensorError is mapped in handle).
        self.sensor.set_exposure(exposure if math.isfinite(exposure) else math.nan)
        return ()

    def _set_readout_window(
        self, session: SessionView, params: tuple[Value, ...]
    ) -> tuple[Value, ...]:
        first, columns = params
        assert isinstance(first, int) and isinstance(columns, int)
        # [SS-5.6] [SS-5.7] replies with the acquisition time, proportional to the columns.
        return (float(self.sensor.set_readout_window(first, columns)),)

    def _acquire(self, session: SessionView, params: tuple[Value, ...]) -> tuple[Value, ...]:
        return (self.sensor.acquire().index,)


__all__ = ["SENSOR_IDENTITY", "SensorService"]
