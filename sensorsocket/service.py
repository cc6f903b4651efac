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
from spec import messages as M
from spec.codec import PreparedParams, prepare_params
from spec.errors import ErrorCode, ProtocolError
from spec.params import Image, Location, Matrix, Value
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
        self.register(M.SensorStatusRequest, self._status)
        self.register(M.GetDataRequest, self._get_data)
        self.register(M.GetImageRequest, self._get_image)
        self.register(M.GetProfileRequest, self._get_profile)
        self.register(M.SetLaserRequest, self._set_laser)
        self.register(M.SetExposureRequest, self._set_exposure)
        self.register(M.SetReadoutWindowRequest, self._set_readout_window)
        self.register(M.GetSettingsRequest, self._get_settings)
        self.register(M.AcquireRequest, self._acquire)
        self.register(M.GetTriggerEndpointRequest, self._trigger_endpoint)

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

    def _status(self, session: SessionView, request: M.SensorStatusRequest) -> tuple[Value, ...]:
        latest = self.sensor.latest
        return M.SensorStatusReply(
            self.sensor.settings.laser,
            self.sensor.frames,
            -1 if latest is None else latest.index,
            session.in_control,
            session.control_held,
            float(self.sensor.clock()),
        ).encode()

    def _get_data(self, session: SessionView, request: M.GetDataRequest) -> tuple[Value, ...]:
        r = self._latest()
        found = r.status is SensorStatus.FOUND
        seam = Location(*r.seam) if found else Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        # [SS-5.1] index, status, ^S_G T, quality, and the three sensor-clock times, which
        # satisfy t_arrival <= t_exposure_start <= t_exposure_end [SS-5.5].
        return M.GetDataReply(
            r.index,
            int(r.status),
            seam,
            float(r.quality),
            float(r.t_arrival),
            float(r.t_exposure_start),
            float(r.t_exposure_end),
        ).encode()

    def _get_image(self, session: SessionView, request: M.GetImageRequest) -> tuple[Value, ...]:
        r = self._latest()
        if request.column is None:
            return self._full(r)
        width, height = self.sensor.width, self.sensor.height
        column = request.column
        row = 0 if request.row is None else request.row
        w = width - column if request.width is None else request.width
        h = height - row if request.height is None else request.height
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

    def _get_profile(self, session: SessionView, request: M.GetProfileRequest) -> tuple[Value, ...]:
        r = self._latest()
        # [SS-5.9] N x 3 stripe points in S, mm.
        points = np.ascontiguousarray(r.points, dtype=np.float64).reshape(-1, 3)
        return (r.index, Matrix(points.shape[0], 3, points.ravel().tolist()))

    def _get_settings(
        self, session: SessionView, request: M.GetSettingsRequest
    ) -> tuple[Value, ...]:
        s = self.sensor.settings
        return M.GetSettingsReply(
            s.laser,
            float(s.exposure_s),
            s.first_column,
            s.columns,
            float(self.sensor.acquisition_time()),
            self.sensor.width,
            self.sensor.height,
        ).encode()

    def _trigger_endpoint(
        self, session: SessionView, request: M.GetTriggerEndpointRequest
    ) -> tuple[Value, ...]:
        host, port = self.trigger_endpoint
        return M.GetTriggerEndpointReply(host, int(port)).encode()

    # --- need control (checked by the shell) [RS-7.4] ---------------------------------------

    def _set_laser(self, session: SessionView, request: M.SetLaserRequest) -> tuple[Value, ...]:
        self.sensor.set_laser(request.on)
        return ()

    def _set_exposure(
        self, session: SessionView, request: M.SetExposureRequest
    ) -> tuple[Value, ...]:
        exposure = request.exposure
        # [SS-5.6] outside 1e-6..0.01 s: OUT_OF_RANGE (SensorError is mapped in handle).
        self.sensor.set_exposure(exposure if math.isfinite(exposure) else math.nan)
        return ()

    def _set_readout_window(
        self, session: SessionView, request: M.SetReadoutWindowRequest
    ) -> tuple[Value, ...]:
        # [SS-5.6] [SS-5.7] replies with the acquisition time, proportional to the columns.
        window = self.sensor.set_readout_window(request.first_column, request.columns)
        return (float(window),)

    def _acquire(self, session: SessionView, request: M.AcquireRequest) -> tuple[Value, ...]:
        return (self.sensor.acquire().index,)


__all__ = ["SENSOR_IDENTITY", "SensorService"]
