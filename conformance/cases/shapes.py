"""Reply shapes, value ranges and shared state that PROTOCOL.md states beyond the command tables
(sections 5.3-5.5). Every request here either reads or is refused before it could execute; the
settings a case changes are put back."""

from __future__ import annotations

import itertools
import socket
import time

from conformance.cases._util import endpoint_status
from conformance.cases.robot import _step_back, _step_out
from conformance.connection import Conn, typed_reply
from conformance.context import Context
from conformance.model import Fail, Informational, NotApplicable, case
from spec import messages as M
from spec import wire
from spec.datagrams import Trigger, decode_datagram
from spec.errors import DatagramError, ErrorCode
from spec.params import FloatArray, Joints
from spec.registry import SEAM_POINT_COLUMNS
from spec.registry import CommandId as C


def _refused(conn: Conn, code: ErrorCode, requirement: str, command: int, *params: object) -> None:
    answer = conn.call(command, *params)  # type: ignore[arg-type]
    if answer.error is None or answer.error[0] != code:
        raise Fail(
            f"{C(command).name}{params!r} was not refused with {code.name}",
            code.name,
            answer.error or "executed",
            requirement=requirement,
        )


@case(
    "robot.shapes.joint_log",
    requirements=["RS-5.25", "RS-5.26", "RS-5.27"],
    tags=["robot", "shapes"],
    service="robot",
    commands=[C.GET_JOINT_LOG, C.GET_JOINT_LIMITS, C.LIST_IO],
)
def robot_shapes(ctx: Context) -> None:
    """GetJointLog is N x 7 (t, q1..q6), increasing t; GetJointLimits 6 x 2 (lower < upper);
    ListIO names are comma-separated without spaces."""
    conn = ctx.connect()
    joint_log = conn.ask(M.GetJointLogRequest(-1.0))
    m, period = joint_log.log, joint_log.period
    if m.cols != 7:
        raise Fail("GetJointLog rows are not (t, q1..q6)", 7, m.cols, requirement="RS-5.25")
    times = [m.row(i)[0] for i in range(m.rows)]
    if any(b <= a for a, b in itertools.pairwise(times)):
        raise Fail("GetJointLog times do not increase", "increasing", times[:5])
    if not 0 < period < 1:
        raise Fail("GetJointLog period is not T_r in s", "0 < period < 1", period)
    limits = conn.ask(M.GetJointLimitsRequest()).limits
    if (limits.rows, limits.cols) != (6, 2) or any(
        not limits.row(j)[0] < limits.row(j)[1] for j in range(limits.rows)
    ):
        raise Fail(
            "GetJointLimits is not 6 rows of (lower, upper)",
            "6 x 2, lower < upper",
            f"{limits.rows} x {limits.cols}",
            requirement="RS-5.26",
        )
    io = conn.ask(M.ListIORequest())
    for names in (io.outputs, io.inputs):
        if " " in names or (names and "" in names.split(",")):
            raise Fail(
                "ListIO names are not comma-separated without spaces",
                "a,b,c",
                names,
                requirement="RS-5.27",
            )


@case(
    "robot.shapes.ranges",
    requirements=["RS-5.28", "RS-5.29"],
    tags=["robot", "limits"],
    service="robot",
    commands=[C.JOINT_MOVE, C.WAIT_END_MOVE],
)
def robot_ranges(ctx: Context) -> None:
    """JointMove with 5 or 7 joints is BAD_PARAMETERS (refused before anything moves);
    WaitEndMove outside (0, 3600] s is OUT_OF_RANGE."""
    conn = ctx.connect()
    for timeout in (0.0, -1.0, 3600.5):
        _refused(conn, ErrorCode.OUT_OF_RANGE, "RS-5.29", C.WAIT_END_MOVE, timeout)
    ctx.take_control(conn)
    try:
        q = list(conn.ask(M.HerejRequest()).joints.values)
        for joints in (q[:5], [*q, 0.0]):
            _refused(conn, ErrorCode.BAD_PARAMETERS, "RS-5.28", C.JOINT_MOVE, Joints(joints))
    finally:
        conn.call(C.RELEASE_CONTROL)


@case(
    "control.status_fields",
    requirements=["RS-5.30", "RS-5.31"],
    tags=["control", "shapes"],
)
def status_fields(ctx: Context) -> None:
    """GetStatus in_control is per connection and controlled is for any connection; Hello's
    version is "major.minor" as in the frame header, and service names the service."""
    a, b = ctx.connect(), ctx.connect()
    ctx.take_control(a)
    try:
        mine, theirs = endpoint_status(ctx, a), endpoint_status(ctx, b)
        got = (mine.in_control, mine.controlled, theirs.in_control, theirs.controlled)
        if got != (True, True, False, True):
            raise Fail(
                "in_control / controlled do not tell this connection from any connection",
                "holder (True, True), other (False, True)",
                f"holder {got[:2]}, other {got[2:]}",
                requirement="RS-5.30",
            )
    finally:
        a.call(C.RELEASE_CONTROL)
    hello = a.ask(M.HelloRequest(1, 0, "conformance"))
    expected = f"{wire.VERSION_MAJOR}.{a.version_minor}"  # the header of that reply
    if hello.version != expected or hello.service != ctx.service:
        raise Fail(
            "Hello version/service do not match the frame header and the service",
            f"{expected!r}, {ctx.service!r}",
            f"{hello.version!r}, {hello.service!r}",
            requirement="RS-5.31",
        )


@case(
    "sensor.shapes.image_defaults",
    requirements=["SS-5.10", "SS-5.11", "SS-5.12"],
    tags=["sensor", "shapes", "limits"],
    service="sensor",
    commands=[C.GET_IMAGE, C.GET_SETTINGS, C.SET_READOUT_WINDOW, C.SET_EXPOSURE],
)
def image_defaults(ctx: Context) -> str:
    """GetImage(10, 20) is the rest of the sensor from there; settings are global (another
    connection sees a readout window); out-of-range exposure and windows are refused."""
    conn, other = ctx.connect(), ctx.connect()
    settings = conn.ask(M.GetSettingsRequest())
    exposure, first, columns = settings.exposure, settings.first_column, settings.columns
    width, height = settings.width, settings.height
    answer = conn.call(C.GET_IMAGE, 10, 20)
    note = ""
    if answer.error is not None:
        if answer.error[0] != ErrorCode.NO_DATA:
            raise Fail("GetImage(10, 20) refused", "an image or NO_DATA", answer.error)
        note = "no frame yet (NO_DATA): region defaults not checked"
    else:
        image = typed_reply(M.GetImageReply, answer.params).image
        if (image.width, image.height) != (width - 10, height - 20):
            got = (image.width, image.height)
            raise Fail(
                "GetImage's omitted width and height are not the rest of the sensor",
                (width - 10, height - 20),
                got,
                requirement="SS-5.10",
            )
    ctx.take_control(conn)
    try:
        _refused(conn, ErrorCode.OUT_OF_RANGE, "SS-5.12", C.SET_EXPOSURE, 0.5e-6)
        _refused(conn, ErrorCode.OUT_OF_RANGE, "SS-5.12", C.SET_EXPOSURE, 0.011)
        _refused(conn, ErrorCode.OUT_OF_RANGE, "SS-5.12", C.SET_READOUT_WINDOW, 0, 15)
        _refused(conn, ErrorCode.OUT_OF_RANGE, "SS-5.12", C.SET_READOUT_WINDOW, -1, 64)
        _refused(conn, ErrorCode.OUT_OF_RANGE, "SS-5.12", C.SET_READOUT_WINDOW, width - 8, 16)
        window = (width - 16, 16)  # the last 16 columns: valid on any sensor
        conn.ok(C.SET_READOUT_WINDOW, *window)
        now_in_force = other.ask(M.GetSettingsRequest())
        seen = (now_in_force.first_column, now_in_force.columns)
        if tuple(seen) != window:
            raise Fail(
                "a readout window set by one connection is not in force for another",
                window,
                tuple(seen),
                requirement="SS-5.11",
            )
    finally:
        conn.call(C.SET_READOUT_WINDOW, first, columns)
        conn.call(C.SET_EXPOSURE, exposure)
        conn.call(C.RELEASE_CONTROL)
    return note or "region defaults, global settings and ranges as specified"


@case(
    "robot.sync.shapes",
    requirements=["SY-5.5", "SY-5.6"],
    tags=["sync", "robot", "shapes", "limits"],
    service="robot",
    commands=[C.GET_SEAM_POINTS, C.SET_SYNC_DELAY, C.START_TRIGGERS, C.SET_SENSOR_ENDPOINT],
)
def sync_shapes(ctx: Context) -> None:
    """GetSeamPoints is N x 17; SetSyncDelay beyond ±1 s and a negative trigger count are
    OUT_OF_RANGE."""
    conn = ctx.connect()
    points = conn.ask(M.GetSeamPointsRequest(-1)).points
    if points.cols != len(SEAM_POINT_COLUMNS):
        raise Fail(
            "GetSeamPoints rows do not have the 17 columns of the table",
            len(SEAM_POINT_COLUMNS),
            points.cols,
            requirement="SY-5.5",
        )
    ctx.take_control(conn)
    family = socket.AF_INET6 if ":" in conn.sock.getsockname()[0] else socket.AF_INET
    sink = socket.socket(family, socket.SOCK_DGRAM)
    sink.bind((conn.sock.getsockname()[0], 0))
    config = conn.ask(M.GetSyncConfigRequest())
    try:
        _refused(conn, ErrorCode.OUT_OF_RANGE, "SY-5.6", C.SET_SYNC_DELAY, 1.5)
        _refused(conn, ErrorCode.OUT_OF_RANGE, "SY-5.6", C.SET_SYNC_DELAY, -1.5)
        conn.ok(C.SET_SENSOR_ENDPOINT, *sink.getsockname()[:2])
        _refused(conn, ErrorCode.OUT_OF_RANGE, "SY-5.6", C.START_TRIGGERS, 10.0, -1)
    finally:
        conn.call(C.STOP_TRIGGERS)
        conn.call(C.SET_SENSOR_ENDPOINT, config.host, config.port)
        conn.call(C.RELEASE_CONTROL)
        sink.close()


@case(
    "framing.error_without_request",
    requirements=["RS-3.18"],
    tags=["framing", "errors"],
)
def error_without_request(ctx: Context) -> None:
    """An error frame that answers no request (bad magic) has command ID 0 and request ID 0."""
    conn = ctx.connect()
    conn.send(b"XS" + bytes(20), "bad magic")
    packets = conn.expect_closed(ctx.timeout * 2)
    if not packets or packets[0].error is None:
        raise NotApplicable("no error frame before the close (checked by framing cases)")
    p = packets[0]
    if (p.command, p.request_id) != (0, 0):
        raise Fail(
            "an error answering no request does not carry command 0 and request ID 0",
            (0, 0),
            (p.command, p.request_id),
            requirement="RS-3.18",
        )
    ctx.probe()


@case(
    "sync.arrival_stamp",
    requirements=["SY-2.9"],
    level="INFO",
    tags=["sync", "not-observable"],
)
def arrival_stamp(ctx: Context) -> str:
    """Not observable over the wire: see the case's message."""
    raise Informational(
        "SY-2.9 says what t_arrival means (the kernel's receive time of the trigger, where the"
        " platform has one); from outside only its order (SY-2.6) and the ΔT it leads to can"
        " be seen. The reference sensor's tests check the kernel timestamp path."
    )


def _triggers(sink: socket.socket, n: int, wait: float) -> list[Trigger]:
    """Up to ``n`` trigger datagrams arriving at ``sink`` within ``wait`` seconds."""
    got: list[Trigger] = []
    deadline = time.monotonic() + wait
    while len(got) < n and (left := deadline - time.monotonic()) > 0:
        sink.settimeout(left)
        try:
            raw = sink.recv(2048)
        except (TimeoutError, OSError):
            break
        try:
            d = decode_datagram(raw)
        except DatagramError:
            continue
        if isinstance(d, Trigger):
            got.append(d)
    return got


@case(
    "robot.sync.trigger_times",
    requirements=["SY-5.7"],
    tags=["sync", "robot", "timing"],
    service="robot",
    commands=[C.SET_SENSOR_ENDPOINT, C.SCHEDULE_TRIGGERS, C.START_TRIGGERS, C.STOP_TRIGGERS],
    budget=20.0,
)
def trigger_times(ctx: Context) -> str:
    """Scheduled triggers carry their scheduled robot-clock times and rate triggers are 1/rate
    apart, also under a simulated clock (which the harness advances with a small move when
    motion is allowed); a burst stamped with one time fails."""
    conn = ctx.connect()
    ctx.take_control(conn)
    family = socket.AF_INET6 if ":" in conn.sock.getsockname()[0] else socket.AF_INET
    sink = socket.socket(family, socket.SOCK_DGRAM)
    sink.bind((conn.sock.getsockname()[0], 0))
    config = conn.ask(M.GetSyncConfigRequest())
    try:
        conn.ok(C.SET_SENSOR_ENDPOINT, *sink.getsockname()[:2])
        notes = []
        now = conn.ask(M.GetTimeRequest()).time
        offsets = (0.05, 0.1, 0.3)
        answer = conn.call(C.SCHEDULE_TRIGGERS, FloatArray([now + d for d in offsets]))
        if answer.error is None:
            got = _sent(ctx, conn, sink, 3)
            stamps = [t.t_trigger - now for t in got]
            # A trigger is stamped when it is sent: on time, or late on a busy host, never
            # early, and never all of them with one time.
            if len(got) != 3 or any(
                not d - 1e-3 <= t <= d + LATE_S for t, d in zip(stamps, offsets, strict=True)
            ):
                raise Fail(
                    "scheduled triggers do not carry their scheduled times",
                    [f"+{d:g} (up to {LATE_S * 1e3:g} ms late)" for d in offsets],
                    [f"+{t:.4f}" for t in stamps],
                    requirement="SY-5.7",
                )
            notes.append("scheduled times kept")
        conn.ok(C.START_TRIGGERS, 100.0, 10)
        got = _sent(ctx, conn, sink, 10)
        gaps = [b.t_trigger - a.t_trigger for a, b in itertools.pairwise(got)]
        if len(got) != 10 or min(gaps) <= 0 or abs(sum(gaps) / len(gaps) - 0.01) > 1e-3:
            raise Fail(
                "rate triggers are not stamped 1/rate apart on the robot clock",
                "10 triggers, increasing stamps, mean gap 10 ms ± 1 ms",
                f"{len(got)} triggers, gaps {[round(g * 1e3, 3) for g in gaps]} ms",
                requirement="SY-5.7",
            )
        notes.append(f"rate gaps {min(gaps) * 1e3:.2f}..{max(gaps) * 1e3:.2f} ms")
        return "; ".join(notes)
    finally:
        conn.call(C.STOP_TRIGGERS)
        conn.call(C.SET_SENSOR_ENDPOINT, config.host, config.port)
        conn.call(C.RELEASE_CONTROL)
        sink.close()


#: How late a trigger may be sent (and so stamped) on a busy host.
LATE_S = 0.05


def _sent(ctx: Context, conn: Conn, sink: socket.socket, n: int) -> list[Trigger]:
    """The next ``n`` triggers; a simulated clock is advanced with a small move if allowed."""
    got = _triggers(sink, n, 1.5)
    if len(got) < n:
        if not ctx.options.allow_motion:
            raise NotApplicable(
                f"{len(got)} of {n} triggers within 1.5 s: a simulated robot clock advances only"
                " with motion (--allow-motion lets the harness move joint 1 by 2 degrees)"
            )
        for _ in range(5):  # each move lets the clock pass ~0.3 s
            _advance_by_motion(conn)
            got += _triggers(sink, n - len(got), 1.0)
            if len(got) >= n:
                break
    return got


def _advance_by_motion(conn: Conn) -> None:
    """Joint 1 by +2 degrees and back (the documented motion): time passes on any clock."""
    if not conn.ask(M.RobotStatusRequest()).powered:
        conn.ok(C.ENABLE_POWER)
    _step_back(conn, _step_out(conn))
