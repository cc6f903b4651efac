"""Sensor service rules (PROTOCOL.md section 5.4). Acquire and the settings need control but
move nothing; every setting changed by a case is restored."""

from __future__ import annotations

import math

from conformance.connection import Conn
from conformance.context import Context
from conformance.model import Fail, Informational, NotApplicable, case
from spec import messages as M
from spec.errors import ErrorCode
from spec.registry import CommandId as C
from spec.wire import BYTES_PER_PIXEL, PixelFormat, PixelOrder, SensorStatus


def _data(conn: Conn) -> M.GetDataReply:
    return conn.ask(M.GetDataRequest())


def _settings(conn: Conn) -> M.GetSettingsReply:
    return conn.ask(M.GetSettingsRequest())


def _acquire(ctx: Context, conn: Conn) -> int:
    ctx.take_control(conn)
    return conn.ask(M.AcquireRequest(), timeout=ctx.timeout * 2).index


@case(
    "sensor.getdata.no_data",
    requirements=["SS-5.2"],
    tags=["sensor"],
    service="sensor",
    commands=[C.GET_DATA, C.SENSOR_STATUS],
    order=5,
)
def getdata_no_data(ctx: Context) -> None:
    """Before the first measurement GetData gives NO_DATA (only checkable on a fresh sensor)."""
    conn = ctx.connect()
    last_index = conn.ask(M.SensorStatusRequest()).last_index
    if last_index != -1:
        raise NotApplicable(f"the sensor has measured already (last_index {last_index!r})")
    conn.error(C.GET_DATA, ErrorCode.NO_DATA)


@case(
    "sensor.acquire.data",
    requirements=["SS-5.1", "SS-5.5", "RS-8.4"],
    tags=["sensor", "time"],
    service="sensor",
    profiles=("smoke", "core", "full"),
    commands=[C.ACQUIRE, C.GET_DATA, C.GET_TIME],
)
def acquire_data(ctx: Context) -> str:
    """After Acquire, GetData gives that index, a known status, quality in 0..1 and ordered
    sensor-clock times no later than GetTime."""
    conn = ctx.connect()
    try:
        t0 = conn.ask(M.GetTimeRequest()).time
        index = _acquire(ctx, conn)
        d = _data(conn)
        t1 = conn.ask(M.GetTimeRequest()).time
    finally:
        conn.call(C.RELEASE_CONTROL)
    if d.index != index:
        raise Fail("GetData is not the latest measurement", index, d.index, requirement="SS-5.1")
    status, quality = d.status, d.quality
    if status not in {int(s) for s in SensorStatus}:
        raise Fail("unknown measurement status", "0..4", status, requirement="SS-5.1")
    if not 0.0 <= quality <= 1.0:
        raise Fail("quality outside 0..1", "0..1", quality, requirement="SS-5.1")
    ta, ts, te = d.t_arrival, d.t_exposure_start, d.t_exposure_end
    if not ta <= ts <= te:
        raise Fail(
            "timestamps out of order",
            "t_arrival <= t_start <= t_end",
            (ta, ts, te),
            requirement="SS-5.5",
        )
    if not t0 - 1e-6 <= ta <= t1 + 1e-6:
        raise Fail(
            "measurement times are not on the GetTime clock", (t0, t1), ta, requirement="RS-8.4"
        )
    return f"index {index}, status {status}, acquisition {1000 * (te - ts):.2f} ms"


@case(
    "sensor.image.full",
    requirements=["SS-5.3", "RS-4.8"],
    tags=["sensor", "image"],
    service="sensor",
    commands=[C.ACQUIRE, C.GET_IMAGE, C.GET_SETTINGS],
)
def image_full(ctx: Context) -> str:
    """GetImage() gives the full frame (sensor width x height) of the latest acquisition."""
    conn = ctx.connect()
    try:
        index = _acquire(ctx, conn)
    finally:
        conn.call(C.RELEASE_CONTROL)
    s = _settings(conn)
    reply = conn.ask(M.GetImageRequest(), timeout=ctx.timeout * 3)
    got_index, image = reply.index, reply.image
    if got_index != index:
        raise Fail("GetImage is not the latest acquisition", index, got_index, requirement="SS-5.3")
    if (image.width, image.height) != (s.width, s.height):
        raise Fail(
            "GetImage is not the full frame",
            (s.width, s.height),
            (image.width, image.height),
            requirement="SS-5.3",
        )
    if image.format not in set(PixelFormat) or image.order not in set(PixelOrder):
        raise Fail("unknown image format or order", "known values", (image.format, image.order))
    bpp = BYTES_PER_PIXEL[PixelFormat(image.format)]
    if len(image.data) != image.width * image.height * bpp:
        raise Fail("image byte count", image.width * image.height * bpp, len(image.data))
    return f"{image.width} x {image.height} {PixelFormat(image.format).name}"


@case(
    "sensor.image.region",
    requirements=["SS-5.4"],
    tags=["sensor", "image", "limits"],
    service="sensor",
    commands=[C.ACQUIRE, C.GET_IMAGE, C.GET_SETTINGS],
)
def image_region(ctx: Context) -> None:
    """A region inside the sensor has the asked size; one outside gives OUT_OF_RANGE."""
    conn = ctx.connect()
    try:
        _acquire(ctx, conn)
    finally:
        conn.call(C.RELEASE_CONTROL)
    s = _settings(conn)
    w, h = s.width, s.height
    image = conn.ask(M.GetImageRequest(0, 0, 16, 8)).image
    if (image.width, image.height) != (16, 8):
        raise Fail("a 16 x 8 region has another size", (16, 8), (image.width, image.height))
    for region in ((w - 8, 0, 16, 8), (0, h, 4, 4), (-1, 0, 4, 4), (0, 0, w + 1, h)):
        conn.error(C.GET_IMAGE, ErrorCode.OUT_OF_RANGE, *region)


@case(
    "sensor.settings.range",
    requirements=["SS-5.6"],
    tags=["sensor", "limits"],
    service="sensor",
    commands=[C.SET_EXPOSURE, C.SET_READOUT_WINDOW, C.GET_SETTINGS],
)
def settings_range(ctx: Context) -> str:
    """SetExposure and SetReadoutWindow out of range give OUT_OF_RANGE; a valid window replies
    with its acquisition time; settings are restored."""
    conn = ctx.connect()
    ctx.take_control(conn)
    before = _settings(conn)
    w = before.width
    try:
        for bad in (0.0, -1e-3, 10.0):
            conn.error(C.SET_EXPOSURE, ErrorCode.OUT_OF_RANGE, bad)
        for first, cols in ((0, 0), (w - 10, 20), (-1, 10), (0, w + 1)):
            conn.error(C.SET_READOUT_WINDOW, ErrorCode.OUT_OF_RANGE, first, cols)
        acq = conn.ask(M.SetReadoutWindowRequest(0, w // 2)).acquisition_time
        if not (math.isfinite(acq) and acq > 0):
            raise Fail("SetReadoutWindow's acquisition time", "> 0 s", acq, requirement="SS-5.6")
    finally:
        conn.call(C.SET_READOUT_WINDOW, before.first_column, before.columns)
        conn.call(C.SET_EXPOSURE, before.exposure)
        conn.call(C.RELEASE_CONTROL)
    return f"half window: {acq * 1000:.3f} ms"


@case(
    "sensor.settings.proportional",
    requirements=["SS-5.7"],
    level="SHOULD",
    tags=["sensor"],
    service="sensor",
    commands=[C.SET_READOUT_WINDOW, C.GET_SETTINGS],
)
def settings_proportional(ctx: Context) -> str:
    """The acquisition time is proportional to the columns read out (within 20 %)."""
    conn = ctx.connect()
    ctx.take_control(conn)
    before = _settings(conn)
    w = before.width
    try:
        full = conn.ask(M.SetReadoutWindowRequest(0, w)).acquisition_time
        quarter = conn.ask(M.SetReadoutWindowRequest(0, w // 4)).acquisition_time
    finally:
        conn.call(C.SET_READOUT_WINDOW, before.first_column, before.columns)
        conn.call(C.RELEASE_CONTROL)
    ratio = full / quarter if quarter > 0 else math.inf
    if not 4 * 0.8 <= ratio <= 4 * 1.2:
        raise Fail("acquisition time not proportional to the columns", "ratio 4 (+-20 %)", ratio)
    return f"full {full * 1000:.3f} ms, quarter {quarter * 1000:.3f} ms"


@case(
    "sensor.client.laser_off_named",
    requirements=["SS-5.13"],
    level="INFO",
    tags=["sensor", "client-side"],
    service="sensor",
    commands=[C.SENSOR_STATUS],
)
def laser_off_named(ctx: Context) -> str:
    """Client-side rule: the harness names a laser that is off as such, with how to switch it
    on; it reports whether the sensor's laser is on as the run starts."""
    conn = ctx.connect()
    if conn.ask(M.SensorStatusRequest()).laser:
        return "client-side rule; the sensor's laser is on"
    raise Informational(SensorStatus.LASER_OFF.problem(f"{ctx.host}:{ctx.port}"))


@case(
    "sensor.laser_off",
    requirements=["SS-5.8"],
    tags=["sensor"],
    service="sensor",
    commands=[C.SET_LASER, C.ACQUIRE, C.GET_DATA, C.SENSOR_STATUS],
)
def laser_off(ctx: Context) -> None:
    """With the laser off a measurement has status LASER_OFF and no seam; laser restored."""
    conn = ctx.connect()
    ctx.take_control(conn)
    was_on = conn.ask(M.SensorStatusRequest()).laser
    try:
        conn.ok(C.SET_LASER, False)
        index = conn.ask(M.AcquireRequest(), timeout=ctx.timeout * 2).index
        d = _data(conn)
    finally:
        conn.call(C.SET_LASER, was_on)
        conn.call(C.RELEASE_CONTROL)
    if d.index != index or d.status != SensorStatus.LASER_OFF:
        raise Fail(
            "a laser-off measurement", "status LASER_OFF (2)", d.status, requirement="SS-5.8"
        )
    values = d.seam.as_tuple()
    if not (all(v == 0.0 for v in values) or all(math.isnan(v) for v in values)):
        raise Fail(
            "a laser-off measurement carries a seam",
            "six zeros or NaN",
            values,
            requirement="SS-5.8",
        )


@case(
    "sensor.profile",
    requirements=["SS-5.9"],
    tags=["sensor"],
    service="sensor",
    commands=[C.ACQUIRE, C.GET_PROFILE],
)
def profile(ctx: Context) -> str:
    """GetProfile gives an N x 3 matrix of finite points (mm) for the latest frame."""
    conn = ctx.connect()
    try:
        index = _acquire(ctx, conn)
    finally:
        conn.call(C.RELEASE_CONTROL)
    reply = conn.ask(M.GetProfileRequest())
    got_index, points = reply.index, reply.points
    if got_index != index:
        raise Fail("GetProfile is not the latest frame", index, got_index, requirement="SS-5.9")
    if points.rows and points.cols != 3:
        raise Fail("profile points are not N x 3", 3, points.cols, requirement="SS-5.9")
    if not all(math.isfinite(v) for v in points.values):
        raise Fail("profile points are not finite", "finite", "NaN or inf", requirement="SS-5.9")
    if points.rows == 0:
        raise Informational("the profile of the latest frame is empty")
    return f"{points.rows} points"
