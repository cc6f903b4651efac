"""Robot service rules (PROTOCOL.md sections 5.3, 7 and 8).

Motion cases (``motion=True``) run only with ``--allow-motion``. Their motions are small and
documented: joint 1 turns by +2 degrees at 5 % joint speed and comes back; no other joint
moves. Before moving they check the arm is still and powered on by the case itself; after a
case the motion descriptor in force before it is restored.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, replace

from conformance.connection import ENDPOINT_ERRORS, Conn
from conformance.context import Context
from conformance.model import Fail, Informational, NotApplicable, Skip, case
from spec import messages as M
from spec.errors import ErrorCode
from spec.params import IDENTITY_LOCATION, FloatArray, Joints, Location, Matrix
from spec.registry import CommandId as C

Mat = list[list[float]]

RESERVED_WAIT_S = 6.0  # a refused connection closes within 5 s [RS-7.2]
STEP_DEG = 2.0  # the documented motion: joint 1 by +2 degrees and back
SLOW = 5.0  # % of nominal joint speed, acceleration and deceleration


def loc_to_matrix(loc: Location) -> Mat:
    """4x4 homogeneous matrix of a VAL3 location, R = Rx(rx)·Ry(ry)·Rz(rz) [RS-8.2]."""
    a, b, c = (math.radians(v) for v in (loc.rx, loc.ry, loc.rz))
    ca, sa, cb, sb, cc, sc = (
        math.cos(a),
        math.sin(a),
        math.cos(b),
        math.sin(b),
        math.cos(c),
        math.sin(c),
    )
    rx = [[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]]
    ry = [[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]]
    rz = [[cc, -sc, 0.0], [sc, cc, 0.0], [0.0, 0.0, 1.0]]
    r = _mul3(_mul3(rx, ry), rz)
    return [
        [*r[0], loc.x],
        [*r[1], loc.y],
        [*r[2], loc.z],
        [0.0, 0.0, 0.0, 1.0],
    ]


def _mul3(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def mul(a: Mat, b: Mat) -> Mat:
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def inv(t: Mat) -> Mat:
    """Inverse of a rigid transform."""
    rt = [[t[j][i] for j in range(3)] for i in range(3)]
    p = [-sum(rt[i][k] * t[k][3] for k in range(3)) for i in range(3)]
    return [[*rt[0], p[0]], [*rt[1], p[1]], [*rt[2], p[2]], [0.0, 0.0, 0.0, 1.0]]


def max_diff(a: Mat, b: Mat) -> tuple[float, float]:
    """(largest translation difference in mm, largest rotation-matrix entry difference)."""
    dp = max(abs(a[i][3] - b[i][3]) for i in range(3))
    dr = max(abs(a[i][j] - b[i][j]) for i in range(3) for j in range(3))
    return dp, dr


def _joints(conn: Conn) -> list[float]:
    return list(conn.ask(M.HerejRequest()).joints.values)


def _limits(conn: Conn) -> list[tuple[float, float]]:
    m = conn.ask(M.GetJointLimitsRequest()).limits
    return [(r[0], r[1]) for r in m.to_rows()] if m.cols >= 2 else []


def _status(conn: Conn) -> M.RobotStatusReply:
    return conn.ask(M.RobotStatusRequest())


def motion_desc(conn: Conn) -> M.SetMotionDescRequest:
    """The motion descriptor in force, as the SetMotionDesc that sets it (again)."""
    return M.SetMotionDescRequest(**conn.ask(M.GetMotionDescRequest()).as_dict())


def _flange(conn: Conn) -> Location:
    """Here(flange, world): where the flange is in the base frame."""
    return conn.ask(M.HereRequest(IDENTITY_LOCATION, IDENTITY_LOCATION)).location


@case(
    "robot.herej.six_joints",
    requirements=["RS-5.10", "RS-8.1", "RS-8.3"],
    tags=["robot"],
    service="robot",
    profiles=("smoke", "core", "full"),
    commands=[C.HEREJ, C.GET_JOINT_LIMITS],
)
def herej_six_joints(ctx: Context) -> str:
    """Herej gives six finite joints in degrees, inside the robot's joint limits."""
    conn = ctx.connect()
    q = _joints(conn)
    if len(q) != 6 or not all(math.isfinite(v) for v in q):
        raise Fail(
            "Herej does not give six finite joints", "6 finite values", q, requirement="RS-5.10"
        )
    limits = _limits(conn)
    if len(limits) != 6 or any(lo >= hi for lo, hi in limits):
        raise Fail("GetJointLimits is not a 6 x 2 (min, max) matrix", "6 rows min < max", limits)
    if all(abs(v) <= 2 * math.pi + 1e-6 for pair in limits for v in pair):
        raise Fail("joint limits look like radians", "degrees", limits, requirement="RS-8.1")
    outside = [
        i + 1
        for i, (v, (lo, hi)) in enumerate(zip(q, limits, strict=True))
        if not lo - 0.5 <= v <= hi + 0.5
    ]
    if outside:
        raise Fail("joints outside the joint limits", limits, q, requirement="RS-8.3")
    return "joints " + ", ".join(f"{v:.2f}" for v in q)


@case(
    "robot.here.frames",
    requirements=["RS-5.16", "RS-8.1", "RS-8.2"],
    tags=["robot", "kinematics"],
    service="robot",
    commands=[C.HERE, C.ROBOT_STATUS],
)
def here_frames(ctx: Context) -> str:
    """Here(tool, frame) equals frame^-1 · Here(flange, world) · tool, VAL3 RxRyRz angles."""
    conn = ctx.connect()
    if _status(conn).moving:
        raise Skip("the arm is moving; Here would change between the calls")
    tool = Location(10.0, -20.0, 100.0, 30.0, -45.0, 60.0)
    frame = Location(500.0, -200.0, 50.0, 10.0, 20.0, 30.0)
    flange = _flange(conn)
    got = conn.ask(M.HereRequest(tool, frame)).location
    want = mul(mul(inv(loc_to_matrix(frame)), loc_to_matrix(flange)), loc_to_matrix(tool))
    dp, dr = max_diff(loc_to_matrix(got), want)
    if dp > 0.01 or dr > 1e-4:
        raise Fail(
            "Here(tool, frame) is not frame^-1 · flange · tool (mm, degrees, R = Rx·Ry·Rz)",
            [round(want[i][3], 3) for i in range(3)],
            got.as_tuple(),
            requirement="RS-5.16",
        )
    return f"flange at {flange.x:.1f}, {flange.y:.1f}, {flange.z:.1f} mm"


@case(
    "robot.jointlog.order",
    requirements=["RS-5.17", "RS-8.4"],
    tags=["robot", "time"],
    service="robot",
    commands=[C.GET_JOINT_LOG],
)
def jointlog_order(ctx: Context) -> str:
    """GetJointLog(since) gives samples with t > since, increasing, on the GetTime clock."""
    conn = ctx.connect()
    t0 = conn.ask(M.GetTimeRequest()).time
    time.sleep(0.05)
    reply = conn.ask(M.GetJointLogRequest(t0 - 0.2))
    log, period = reply.log, reply.period
    t1 = conn.ask(M.GetTimeRequest()).time
    if log.rows == 0:
        raise Fail("the joint log has no samples for the last 0.2 s", "samples", "none")
    if log.cols != 7:
        raise Fail("joint log rows are not (t, q1..q6)", 7, log.cols, requirement="RS-5.17")
    ts = [log.values[i * 7] for i in range(log.rows)]
    if ts[0] <= t0 - 0.2:
        raise Fail("a sample not newer than since", f"> {t0 - 0.2}", ts[0], requirement="RS-5.17")
    if any(b <= a for a, b in itertools.pairwise(ts)):
        raise Fail("joint log times do not increase", "increasing", ts[:10], requirement="RS-5.17")
    if ts[-1] > t1 + 0.001 or ts[-1] < t0 - 1.0:
        raise Fail(
            "joint log times are not on the GetTime clock",
            f"between {t0 - 1.0:.3f} and {t1:.3f}",
            ts[-1],
            requirement="RS-5.17",
        )
    ctx.measure("joint_log", period_s=period, samples_last_0_2s=log.rows)
    return f"{log.rows} samples, period {period * 1000:.3g} ms"


@case(
    "robot.jointlog.capacity",
    requirements=["RS-5.18"],
    level="SHOULD",
    tags=["robot"],
    service="robot",
    commands=[C.GET_JOINT_LOG],
)
def jointlog_capacity(ctx: Context) -> str:
    """The joint buffer spans at least 10 s (informational while the server is younger)."""
    conn = ctx.connect()
    reply = conn.ask(M.GetJointLogRequest(-1.0))
    log, period = reply.log, reply.period
    if log.rows < 2:
        raise Informational("fewer than two samples in the buffer")
    span = log.values[(log.rows - 1) * log.cols] - log.values[0]
    if span >= 10.0 - 2 * period:
        return f"buffer spans {span:.2f} s ({log.rows} samples)"
    raise Informational(f"buffer spans {span:.2f} s; the server may have started < 10 s ago")


@case(
    "robot.motiondesc.range",
    requirements=["RS-5.19"],
    tags=["robot", "limits"],
    service="robot",
    commands=[C.SET_MOTION_DESC, C.GET_MOTION_DESC],
)
def motiondesc_range(ctx: Context) -> None:
    """SetMotionDesc values out of range give OUT_OF_RANGE and change nothing."""
    conn = ctx.connect()
    ctx.take_control(conn)
    try:
        before = motion_desc(conn)
        for field, bad in (
            ("joint_speed", 0.0),
            ("joint_speed", 150.0),
            ("joint_accel", -1.0),
            ("joint_decel", 101.0),
            ("tool_speed", 0.0),
            ("tool_rot_speed", -5.0),
            ("blend", -1.0),
        ):
            wrong = replace(before, **{field: bad})
            conn.error(C.SET_MOTION_DESC, ErrorCode.OUT_OF_RANGE, *wrong.encode())
        after = motion_desc(conn)
        if after != before:
            raise Fail(
                "a refused SetMotionDesc changed the descriptor", before.encode(), after.encode()
            )
    finally:
        conn.call(C.RELEASE_CONTROL)


@case(
    "robot.io.unknown_name",
    requirements=["RS-5.21"],
    tags=["robot", "io"],
    service="robot",
    commands=[C.READ_IO],
)
def io_unknown_name(ctx: Context) -> None:
    """ReadIO (and, with --allow-motion, SetOutput) of an unknown name give OUT_OF_RANGE."""
    conn = ctx.connect()
    conn.error(C.READ_IO, ErrorCode.OUT_OF_RANGE, "no-such-io-conformance")
    if ctx.options.allow_motion and C.SET_OUTPUT in ctx.advertised:
        ctx.take_control(conn)
        try:
            conn.error(C.SET_OUTPUT, ErrorCode.OUT_OF_RANGE, "no-such-io-conformance", False)
        finally:
            conn.call(C.RELEASE_CONTROL)


# --- motion (only with --allow-motion) ------------------------------------------------------


class _Motion:
    """Control, power and a slow motion descriptor for one motion case; restores on exit."""

    def __init__(self, ctx: Context) -> None:
        self.ctx = ctx
        self.conn = ctx.connect()
        self.saved: M.SetMotionDescRequest | None = None

    def __enter__(self) -> _Motion:
        conn = self.conn
        self.ctx.take_control(conn)
        status = _status(conn)
        if status.moving:
            raise Skip("the arm is already moving")
        if status.estop:
            conn.ok(C.RESET_EMERGENCY_STOP)
        self.saved = motion_desc(conn)
        conn.ok(C.SET_MOTION_DESC, SLOW, SLOW, SLOW, 50.0, 20.0, 0.0)
        return self

    def power(self) -> None:
        self.conn.ok(C.ENABLE_POWER)

    def __exit__(self, *exc: object) -> None:
        try:
            if self.saved is not None and not self.conn.closed:
                self.conn.call(C.SET_MOTION_DESC, *self.saved.encode())
            if not self.conn.closed:
                self.conn.call(C.RELEASE_CONTROL)
        except ENDPOINT_ERRORS:  # cleanup: the case's verdict is already made
            pass


def _wait_still(conn: Conn, timeout: float) -> bool:
    """WaitEndMove in pieces shorter than the control lease, which each renew it [RS-7.13]."""
    remaining = timeout
    while True:
        piece = remaining if conn.lease is None else min(remaining, conn.lease / 2)
        done = conn.ask(M.WaitEndMoveRequest(piece), timeout=piece + 5.0).done
        remaining -= piece
        if done or remaining <= 1e-9:
            return done


@dataclass(frozen=True)
class _Step:
    """The documented motion's way out, queued: joint 1 from ``start`` to ``target`` (deg)."""

    start: list[float]
    target: list[float]
    #: When JointMove went out (time.monotonic()), and how long its reply took (s).
    sent_at: float
    reply_s: float


def _step_out(conn: Conn) -> _Step:
    """JointMove joint 1 by +STEP_DEG from where the arm stands (the documented motion's way
    out); returns at JointMove's reply while the move runs on [RS-5.11]."""
    start = _joints(conn)
    target = [start[0] + STEP_DEG, *start[1:]]
    sent_at = time.monotonic()
    conn.ok(C.JOINT_MOVE, Joints(target))
    return _Step(start, target, sent_at, time.monotonic() - sent_at)


def _step_back(conn: Conn, step: _Step) -> bool:
    """JointMove back to where ``step`` started, then wait (30 s at most) until the arm
    stands: a case leaves joint 1 as it found it. False if the arm did not stand in time."""
    conn.ok(C.JOINT_MOVE, Joints(step.start))
    return _wait_still(conn, 30.0)


MOTION = [C.JOINT_MOVE, C.ENABLE_POWER, C.DISABLE_POWER, C.WAIT_END_MOVE, C.SET_MOTION_DESC]


@case(
    "robot.motion.not_powered",
    requirements=["RS-5.12"],
    tags=["robot", "motion"],
    service="robot",
    motion=True,
    commands=MOTION,
)
def motion_not_powered(ctx: Context) -> None:
    """With power off, JointMove gives NOT_POWERED and queues nothing (no motion happens)."""
    with _Motion(ctx) as m:
        conn = m.conn
        conn.ok(C.DISABLE_POWER)
        q = _joints(conn)
        q[0] += STEP_DEG
        conn.error(C.JOINT_MOVE, ErrorCode.NOT_POWERED, Joints(q))
        status = _status(conn)
        if status.queue != 0 or status.moving:
            raise Fail(
                "a refused move was queued", "queue 0, not moving", status, requirement="RS-5.12"
            )


@case(
    "robot.motion.estop",
    requirements=["RS-5.13", "RS-5.20"],
    tags=["robot", "motion", "control"],
    service="robot",
    motion=True,
    commands=[*MOTION, C.EMERGENCY_STOP, C.RESET_EMERGENCY_STOP, C.ROBOT_STATUS],
)
def motion_estop(ctx: Context) -> None:
    """EmergencyStop from a connection without control stops, powers off; moves get
    EMERGENCY_STOP until ResetEmergencyStop (power stays off)."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        other = ctx.connect()
        other.ok(C.EMERGENCY_STOP)  # no control needed [RS-5.20]
        status = _status(conn)
        if not status.estop or status.powered or status.queue != 0:
            raise Fail(
                "EmergencyStop did not engage, power off and empty the queue",
                "estop true, powered false, queue 0",
                status,
                requirement="RS-5.20",
            )
        q = _joints(conn)
        q[0] += STEP_DEG
        conn.error(C.JOINT_MOVE, ErrorCode.EMERGENCY_STOP, Joints(q))
        conn.ok(C.RESET_EMERGENCY_STOP)
        status = _status(conn)
        if status.estop or status.powered:
            raise Fail("after ResetEmergencyStop", "estop false, powered false", status)


@case(
    "robot.motion.stopped_is_not_done",
    requirements=["RS-5.50", "RS-5.22"],
    tags=["robot", "motion", "control"],
    service="robot",
    motion=True,
    commands=[*MOTION, C.RESET_MOTION, C.ROBOT_STATUS],
)
def motion_stopped_is_not_done(ctx: Context) -> str:
    """A move cut short by ResetMotion: WaitEndMove says done false, outcome stopped, with a
    reason; the same move run to its end says done true, outcome reached."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        step = _step_out(conn)
        time.sleep(0.05)
        conn.ok(C.RESET_MOTION)
        cut = conn.ask(M.WaitEndMoveRequest(10.0), timeout=15.0)
        stopped = cut.encode()
        if cut.reason is None:
            raise Fail("WaitEndMove has no outcome (a 1.2 reply)", "done, outcome, reason", stopped)
        if cut.done is not False or cut.outcome != "stopped" or not cut.reason:
            raise Fail("a move cut short by ResetMotion", "(False, 'stopped', reason)", stopped)
        conn.ok(C.JOINT_MOVE, Joints(step.start))
        ended = conn.ask(M.WaitEndMoveRequest(10.0), timeout=15.0)
        reply = ended.encode()
        if (ended.done, ended.outcome, ended.reason) != (True, "reached", ""):
            raise Fail("a move that reached its target", "(True, 'reached', '')", reply)
    return f"ResetMotion: {stopped!r}; run to its end: {reply!r}"


@case(
    "robot.motion.out_of_range",
    requirements=["RS-5.14"],
    tags=["robot", "motion", "limits"],
    service="robot",
    motion=True,
    commands=[*MOTION, C.GET_JOINT_LIMITS],
)
def motion_out_of_range(ctx: Context) -> None:
    """A JointMove target 5 degrees beyond a joint limit gives OUT_OF_RANGE; nothing moves."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        limits = _limits(conn)
        q = _joints(conn)
        q[0] = limits[0][1] + 5.0
        conn.error(C.JOINT_MOVE, ErrorCode.OUT_OF_RANGE, Joints(q))
        if _status(conn).queue != 0:
            raise Fail("a refused move was queued", 0, _status(conn).queue)


@case(
    "robot.motion.unreachable",
    requirements=["RS-5.15"],
    tags=["robot", "motion", "limits"],
    service="robot",
    motion=True,
    commands=[*MOTION, C.TOOL_MOVE_J, C.TOOL_MOVE_L],
)
def motion_unreachable(ctx: Context) -> None:
    """ToolMoveJ/L to a point 20 m away give UNREACHABLE; nothing is queued."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        far = Location(20000.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        conn.error(C.TOOL_MOVE_J, ErrorCode.UNREACHABLE, far, IDENTITY_LOCATION, IDENTITY_LOCATION)
        conn.error(
            C.TOOL_MOVE_L,
            (ErrorCode.UNREACHABLE, ErrorCode.SINGULARITY),
            far,
            IDENTITY_LOCATION,
            IDENTITY_LOCATION,
        )
        if _status(conn).queue != 0:
            raise Fail("a refused move was queued", 0, _status(conn).queue)


def _held_still(conn: Conn, timeout: float) -> M.RobotStatusReply:
    """GetStatus once ``moving`` is false (StopMove's hold reached), or the last one seen."""
    deadline = time.monotonic() + timeout
    while True:
        status = _status(conn)
        if not status.moving or time.monotonic() > deadline:
            return status
        time.sleep(0.02)


@case(
    "robot.motion.stop_restart",
    requirements=["RS-5.59", "RS-5.54"],
    tags=["robot", "motion"],
    service="robot",
    motion=True,
    budget=90.0,
    commands=[*MOTION, C.STOP_MOVE, C.RESTART_MOVE, C.RESET_MOTION, C.ROBOT_STATUS],
)
def stop_restart(ctx: Context) -> str:
    """The documented motion (joint 1 by +2 degrees and back) stopped and resumed: StopMove
    holds the arm short of its target with the move still queued and GetStatus not moving
    [RS-5.59]; RestartMove resumes it to the target, and a second RestartMove changes
    nothing [RS-5.54]; the way back stopped and dropped by ResetMotion is not started again
    by RestartMove [RS-5.54]."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        step = _step_out(conn)
        conn.ok(C.STOP_MOVE)
        held = _held_still(conn, 10.0)
        at = _joints(conn)
        if held.moving:
            raise Fail("GetStatus while StopMove holds the arm", "moving false", held,
                       requirement="RS-5.59")  # fmt: skip
        if held.queue != 1 or abs(at[0] - step.target[0]) < 0.01:
            raise Fail(
                "StopMove during a move: held short of the target with the move queued",
                f"queue 1, joint 1 short of {step.target[0]:.3f}",
                f"queue {held.queue!r}, joint 1 at {at[0]:.3f}",
                requirement="RS-5.59",
            )
        conn.ok(C.RESTART_MOVE)
        again = conn.call(C.RESTART_MOVE)  # already restarted: changes nothing
        if again.error is not None:
            raise Fail("a second RestartMove", "a reply", again.error, requirement="RS-5.54")
        if not _wait_still(conn, 30.0):
            raise Fail("the restarted move did not end within 30 s", True, False)
        reached = _joints(conn)
        if abs(reached[0] - step.target[0]) > 0.05:
            raise Fail("RestartMove resumes the held move to its target", step.target[0],
                       reached[0], requirement="RS-5.54")  # fmt: skip
        # the way back: stopped, dropped, and not started again by RestartMove
        conn.ok(C.JOINT_MOVE, Joints(step.start))
        conn.ok(C.STOP_MOVE)
        _held_still(conn, 10.0)
        conn.ok(C.RESET_MOTION)
        dropped = _held_still(conn, 10.0)
        before = _joints(conn)
        conn.ok(C.RESTART_MOVE)
        conn.pause(0.5)
        after, status = _joints(conn), _status(conn)
        _step_back(conn, step)  # back where the case began
        conn.ok(C.DISABLE_POWER)
        if dropped.queue != 0 or status.moving or abs(after[0] - before[0]) > 0.01:
            raise Fail(
                "RestartMove after ResetMotion dropped the move",
                "nothing moves, queue 0",
                f"queue {status.queue!r}, moving {status.moving!r}, joint 1 "
                f"{before[0]:.3f} -> {after[0]:.3f}",
                requirement="RS-5.54",
            )
    return (
        f"held at {at[0] - step.start[0]:+.3f} deg of {STEP_DEG:g}, resumed to the target; "
        "a dropped move stays dropped"
    )


@case(
    "robot.motion.queued",
    requirements=["RS-5.11", "RS-5.22", "RS-5.59"],
    tags=["robot", "motion"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=[*MOTION, C.ROBOT_STATUS],
)
def motion_queued(ctx: Context) -> str:
    """JointMove (+2 degrees on joint 1, 5 % speed) replies at once; WaitEndMove is false before
    the end and true after, and GetStatus then says not moving, queue 0; the arm comes back."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        step = _step_out(conn)
        reply_s = step.reply_s
        status = _status(conn)
        queue = status.queue
        still_moving = bool(status.moving) or (isinstance(queue, int) and queue > 0)
        early = conn.ask(M.WaitEndMoveRequest(0.001)).done if still_moving else None
        if not _wait_still(conn, 30.0):
            raise Fail("WaitEndMove(30 s) did not see the end of a 2 degree move", True, False)
        move_s = time.monotonic() - step.sent_at
        reached = _joints(conn)
        settled = _status(conn)
        if abs(reached[0] - step.target[0]) > 0.05:
            raise Fail("the arm did not reach the target", step.target[0], reached[0])
        _step_back(conn, step)
        if settled.moving or settled.queue != 0:
            raise Fail(
                "GetStatus after WaitEndMove said done",
                "moving false, queue 0",
                {"moving": settled.moving, "queue": settled.queue},
                requirement="RS-5.59",
            )
        if not still_moving:
            raise Fail(
                "JointMove did not return before the move ended",
                "reply while the move is queued or running",
                f"reply after {reply_s:.3f} s with the move already over",
                requirement="RS-5.11",
            )
        if early is not False:
            raise Fail("WaitEndMove(1 ms) during a move", False, early, requirement="RS-5.22")
        ctx.measure("joint_move_2deg", reply_s=round(reply_s, 4), move_s=round(move_s, 3))
        return f"reply after {reply_s * 1000:.1f} ms, move took {move_s:.2f} s"


@case(
    "robot.motion.release_keeps_moves",
    requirements=["RS-7.11", "RS-7.22"],
    tags=["robot", "motion", "control"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=[*MOTION, C.ROBOT_STATUS, C.HEREJ],
)
def release_keeps_moves(ctx: Context) -> str:
    """JointMove (+2 degrees on joint 1), then ReleaseControl at once: the queued move goes on
    to its target (a release hands the arm over, it does not stop it) and power stays on;
    the arm comes back."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        step = _step_out(conn)
        conn.ok(C.RELEASE_CONTROL)
        released = _status(conn)
        # WaitEndMove needs no control: the former controller waits for its move's end.
        done = _wait_still(conn, 30.0)
        after = _status(conn)
        reached = _joints(conn)
        ctx.take_control(conn)
        _step_back(conn, step)
    was_moving = bool(released.moving) or released.queue != 0
    if not was_moving:
        raise Informational("the move was over before ReleaseControl was answered")
    if not done or abs(reached[0] - step.target[0]) > 0.05:
        raise Fail(
            "a move queued before ReleaseControl did not reach its target",
            f"joint 1 at {step.target[0]:.3f} deg, WaitEndMove done",
            f"joint 1 at {reached[0]:.3f} deg, done {done}",
            requirement="RS-7.11",
        )
    if not after.powered:
        raise Fail(
            "arm power went off after ReleaseControl", "powered", after, requirement="RS-7.22"
        )
    return "the move went on to its target after the release; power stayed on"


@case(
    "robot.motion.control_lost",
    requirements=["RS-7.10", "RS-7.22"],
    tags=["robot", "motion", "control"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=[*MOTION, C.ROBOT_STATUS],
)
def motion_control_lost(ctx: Context) -> str:
    """When the controlling connection closes mid-move the arm stops, the queue empties and
    then arm power goes off (a stop of category 1)."""
    lost = _lose_controller_mid_move(ctx, wait_pending=False, requirement="RS-7.10")
    if lost.powered_after_stop:
        raise Fail(
            "arm power stayed on after a lost controller's stop",
            "power off once the arm stands",
            lost.status,
            requirement="RS-7.22",
        )
    return "stopped and emptied the queue; then power went off"


@dataclass
class _Lost:
    status: M.RobotStatusReply
    stopped_after_s: float
    ran_to_the_end: bool
    #: Power still on a second after the arm stood [RS-7.22].
    powered_after_stop: bool


def _lose_controller_mid_move(ctx: Context, *, wait_pending: bool, requirement: str) -> _Lost:
    """Queue joint 1 +STEP_DEG and back, close the controlling connection (with a
    WaitEndMove pending if asked), watch the arm stop from another connection, then bring
    joint 1 back. ``ran_to_the_end``: the second move ran although the controller left."""
    watcher = ctx.connect()
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        step = _step_out(conn)
        conn.ok(C.JOINT_MOVE, Joints(step.start))
        if wait_pending:
            conn.request(C.WAIT_END_MOVE, 60.0)
            time.sleep(0.05)
        conn.close()
    closed = time.monotonic()
    status = _status(watcher)
    while time.monotonic() < closed + 10.0:
        status = _status(watcher)
        if not status.moving and status.queue == 0:
            break
        time.sleep(0.01)
    else:
        raise Fail(
            "the arm did not stop after the controller left",
            "stopped, queue 0",
            status,
            requirement=requirement,
        )
    stopped_after = time.monotonic() - closed
    ran_to_the_end = abs(_joints(watcher)[0] - step.start[0]) < 0.05
    stood = time.monotonic()
    powered = bool(status.powered)
    while powered and time.monotonic() < stood + 1.0:
        time.sleep(0.01)
        powered = bool(_status(watcher).powered)
    # Bring joint 1 back to where it started.
    ctx.take_control(watcher)
    watcher.ok(C.ENABLE_POWER)
    _step_back(watcher, step)
    watcher.call(C.RELEASE_CONTROL)
    return _Lost(status, stopped_after, ran_to_the_end, powered)


@case(
    "robot.motion.trajectory_refused",
    requirements=["RS-5.23"],
    tags=["robot", "motion", "limits"],
    service="robot",
    motion=True,
    commands=[*MOTION, C.TOOL_MOVE_TRAJECTORY, C.HERE],
)
def trajectory_refused(ctx: Context) -> None:
    """ToolMoveTrajectory refuses bad timing, mismatched counts, too-fast and unreachable
    paths before moving; nothing is queued."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        p = _flange(conn).as_tuple()
        away = (p[0], p[1], p[2] - 50.0, *p[3:])  # reachable, but not in 4 ms
        far = (20000.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        bad: list[tuple[str, list[float], list[tuple[float, ...]], tuple[int, ...]]] = [
            ("times not starting at 0", [0.5, 1.0], [p, p], (ErrorCode.OUT_OF_RANGE,)),
            ("decreasing times", [0.0, 1.0, 0.5], [p, p, p], (ErrorCode.OUT_OF_RANGE,)),
            (
                "2 times for 3 locations",
                [0.0, 1.0],
                [p, p, p],
                (ErrorCode.OUT_OF_RANGE, ErrorCode.BAD_PARAMETERS),
            ),
            ("50 mm in 4 ms", [0.0, 0.004], [p, away], (ErrorCode.OUT_OF_RANGE,)),
            (
                "a point 20 m away",
                [0.0, 30.0],
                [p, far],
                (ErrorCode.UNREACHABLE, ErrorCode.OUT_OF_RANGE),
            ),
        ]
        for what, times, locs, codes in bad:
            answer = conn.call(
                C.TOOL_MOVE_TRAJECTORY,
                FloatArray(times),
                Matrix(len(locs), 6, [v for loc in locs for v in loc]),
                IDENTITY_LOCATION,
                IDENTITY_LOCATION,
            )
            if answer.error is None or answer.error[0] not in codes:
                raise Fail(
                    f"ToolMoveTrajectory with {what} is not refused",
                    " or ".join(ErrorCode(c).name for c in codes),
                    "accepted" if answer.error is None else answer.error,
                    requirement="RS-5.23",
                )
        status = _status(conn)
        if status.queue != 0 or status.moving:
            raise Fail("a refused path was queued", "queue 0", status, requirement="RS-5.23")


@case(
    "robot.motion.trajectory_tracking",
    requirements=["RS-5.24"],
    level="SHOULD",
    tags=["robot", "motion"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=[*MOTION, C.TOOL_MOVE_TRAJECTORY, C.HERE],
)
def trajectory_tracking(ctx: Context) -> str:
    """A 2 mm out-and-back timed path (2 s, at rest at both ends) ends within 0.01 mm of its
    last point (the harness has no kinematic model to check the 4 ms samples themselves)."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        p = _flange(conn).as_tuple()
        times = [0.1 * k for k in range(21)]
        # x(t) = 2 mm * sin^2(pi t / T): starts and ends at rest.
        locs = [(p[0] + 2.0 * math.sin(math.pi * t / 2.0) ** 2, *p[1:]) for t in times]
        conn.ok(
            C.TOOL_MOVE_TRAJECTORY,
            FloatArray(times),
            Matrix(len(locs), 6, [v for loc in locs for v in loc]),
            IDENTITY_LOCATION,
            IDENTITY_LOCATION,
        )
        if not _wait_still(conn, 30.0):
            raise Fail("the timed path did not end", True, False)
        end = _flange(conn)
        err = math.dist(end.as_tuple()[:3], locs[-1][:3])
        if err > 0.01:
            raise Fail(
                "the path's end is missed", "<= 0.01 mm", f"{err:.4f} mm", requirement="RS-5.24"
            )
        return f"end error {err * 1000:.2f} µm"


@case(
    "robot.motion.close_while_waiting",
    requirements=["RS-7.12", "RS-7.10"],
    tags=["robot", "motion", "control", "safety"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=[*MOTION, C.ROBOT_STATUS],
)
def close_while_waiting(ctx: Context) -> str:
    """A controller that closes while its WaitEndMove is pending stops the arm: the queue
    empties and the second move never runs."""
    lost = _lose_controller_mid_move(ctx, wait_pending=True, requirement="RS-7.12")
    ctx.measure("close_while_waiting", stop_s=lost.stopped_after_s)
    if lost.ran_to_the_end:
        raise Fail(
            "the queue ran to its end although the controller closed during WaitEndMove",
            "stopped on the way (second move dropped)",
            "back at the start",
            requirement="RS-7.12",
        )
    return f"stopped {lost.stopped_after_s * 1e3:.0f} ms after the close"


def _refused_at_connect(conn: Conn) -> bool:
    """The server is still full for ``conn``: its first answer is the BUSY of a connection
    over the limit (request ID 0, [RS-7.2]), not the answer to a GetStatus."""
    conn.request(C.ROBOT_STATUS)
    first = conn.recv_packet()
    return first.error is not None and first.request_id == 0


@case(
    "robot.emergency_stop_when_full",
    requirements=["RS-7.14"],
    tags=["robot", "safety", "limits"],
    service="robot",
    motion=True,
    profiles=("full",),
    budget=30.0,
    order=66,
    commands=[C.EMERGENCY_STOP, C.RESET_EMERGENCY_STOP, C.ROBOT_STATUS],
)
def emergency_stop_when_full(ctx: Context) -> str:
    """With every connection slot taken, a new connection still gets EmergencyStop executed
    (after its BUSY frame); it is then reset."""
    limit = int(ctx.hello.number("max_clients", 0)) if ctx.hello else 0
    if not 0 < limit <= 256:
        raise Skip(f"max_clients {limit} is not in 1..256; not tried")
    conns = []
    try:
        refused = None
        for _ in range(limit + 2):
            conn = ctx.connect(hello=False)
            conns.append(conn)
            conn.request(C.ROBOT_STATUS)
            answer = conn.recv_packet()
            if answer.error is not None and answer.request_id == 0:
                refused = conn
                break
        if refused is None:
            raise NotApplicable(f"no connection was refused up to {limit + 2}")
        t0 = time.perf_counter()
        # A fresh request ID, and the answer matched by command and ID [RS-3.4]: the
        # server's answer to the GetStatus sent before is not EmergencyStop's.
        rid = refused.request(C.EMERGENCY_STOP)
        answer = refused.answer_to(C.EMERGENCY_STOP, rid)
        latency = time.perf_counter() - t0
        if answer.error is not None:
            raise Fail(
                "EmergencyStop was refused on a full server",
                "executed",
                answer.error,
                requirement="RS-7.14",
            )
        ctx.measure("emergency_stop_when_full", latency_s=latency)
    finally:
        for conn in conns:
            conn.close()
    deadline = time.monotonic() + RESERVED_WAIT_S
    while True:  # the closed connections may still hold their slots for a moment
        watcher = ctx.connect()
        if not _refused_at_connect(watcher) or time.monotonic() > deadline:
            break
        watcher.close()
        time.sleep(0.1)
    status = _status(watcher)
    ctx.take_control(watcher)
    watcher.ok(C.RESET_EMERGENCY_STOP)
    watcher.call(C.RELEASE_CONTROL)
    if not status.estop:
        raise Fail("EmergencyStop replied but is not engaged", "estop", status)
    return f"EmergencyStop on a full server in {latency * 1e3:.1f} ms"
