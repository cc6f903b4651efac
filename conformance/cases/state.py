"""What 1.2 left to guessing and 1.3 fixes (issue 32): which refusals set last_error, the
motion descriptor's owner, GetJointLog's NaN, TakeControl's check order, DisablePower and
RestartMove in every state (PROTOCOL.md sections 5.3 and 7)."""

from __future__ import annotations

from conformance.cases.robot import _Motion, _status
from conformance.connection import Conn
from conformance.context import Context
from conformance.model import Fail, Informational, Skip, case
from spec.codec import Packet
from spec.errors import ErrorCode
from spec.registry import CommandId as C


def _code(answer: Packet) -> str:
    return "a reply" if answer.error is None else f"error {ErrorCode(answer.error[0]).name}"


def _refused(answer: Packet, code: ErrorCode, what: str, requirement: str) -> None:
    if answer.error is None or answer.error[0] != code:
        raise Fail(what, f"error {code.name}", _code(answer), requirement=requirement)


def _release(conn: Conn) -> None:
    if not conn.closed:
        conn.call(C.RELEASE_CONTROL)


@case(
    "robot.jointlog.since_nan",
    requirements=["RS-5.58"],
    tags=["robot", "limits"],
    service="robot",
    commands=[C.GET_JOINT_LOG],
)
def jointlog_since_nan(ctx: Context) -> str:
    """GetJointLog with since NaN is OUT_OF_RANGE; +inf gives no sample, -inf the buffer."""
    conn = ctx.connect()
    _refused(
        conn.call(C.GET_JOINT_LOG, float("nan")),
        ErrorCode.OUT_OF_RANGE,
        "GetJointLog with since NaN is not refused",
        "RS-5.58",
    )
    rows = {}
    for since in (float("inf"), float("-inf")):
        log = conn.ok(C.GET_JOINT_LOG, since)[0]
        rows[since] = getattr(log, "rows", -1)
    if rows[float("inf")] != 0 or rows[float("-inf")] < 1:
        raise Fail(
            "GetJointLog with an infinite since",
            "+inf: 0 rows, -inf: the whole buffer (at least 1 row)",
            f"+inf: {rows[float('inf')]} rows, -inf: {rows[float('-inf')]} rows",
            requirement="RS-5.58",
        )
    return f"NaN refused; -inf: {rows[float('-inf')]} rows"


@case(
    "robot.last_error.only_moves",
    requirements=["RS-5.51", "RS-5.30"],
    tags=["robot", "status"],
    service="robot",
    commands=[C.ROBOT_STATUS, C.SET_MOTION_DESC, C.GET_MOTION_DESC, C.WAIT_END_MOVE],
)
def last_error_only_moves(ctx: Context) -> str:
    """A refused SetMotionDesc, a refused WaitEndMove and a NOT_IN_CONTROL leave GetStatus'
    last_error and last_message as they were (only moves, alter and EmergencyStop set them)."""
    conn = ctx.connect()
    before = _status(conn)
    # The refusals are the case's preconditions: their own rules (RS-7.4, RS-5.19, RS-5.29)
    # are judged by their own cases.
    with ctx.precondition("a refused SetMotionDesc without control"):
        conn.error(C.SET_MOTION_DESC, ErrorCode.NOT_IN_CONTROL, 10.0, 10.0, 10.0, 250.0, 90.0, 0.0)
    ctx.take_control(conn)
    try:
        with ctx.precondition("refusals of SetMotionDesc 150 % and WaitEndMove -1 s"):
            desc = conn.ok(C.GET_MOTION_DESC)[:6]
            conn.error(C.SET_MOTION_DESC, ErrorCode.OUT_OF_RANGE, 150.0, *desc[1:])
            conn.error(C.WAIT_END_MOVE, ErrorCode.OUT_OF_RANGE, -1.0)
        after = _status(conn)
    finally:
        _release(conn)
    was = (before.get("last_error"), before.get("last_message"))
    now = (after.get("last_error"), after.get("last_message"))
    if now != was:
        raise Fail(
            "a refusal of a command that queues no move changed last_error",
            was,
            now,
            requirement="RS-5.51",
        )
    return f"last_error stayed {was[0]!r}"


@case(
    "robot.motiondesc.owned_by_robot",
    requirements=["RS-5.56"],
    tags=["robot", "concurrency"],
    service="robot",
    commands=[C.SET_MOTION_DESC, C.GET_MOTION_DESC],
)
def motiondesc_owned_by_robot(ctx: Context) -> str:
    """One connection's SetMotionDesc is what another connection's GetMotionDesc returns,
    also after the first released control; the descriptor is restored afterwards."""
    a, b = ctx.connect(), ctx.connect()
    ctx.take_control(a)
    saved = a.ok(C.GET_MOTION_DESC)[:6]
    try:
        wanted = (7.0, 55.0, 45.0, 123.0, 33.0, 0.5)
        a.ok(C.SET_MOTION_DESC, *wanted)
        _release(a)
        seen = tuple(b.ok(C.GET_MOTION_DESC)[:6])
    finally:
        ctx.take_control(a)
        a.call(C.SET_MOTION_DESC, *saved)
        _release(a)
    if seen != wanted:
        raise Fail(
            "another connection does not see the motion descriptor in force",
            wanted,
            seen,
            requirement="RS-5.56",
        )
    return "shared across connections and kept over ReleaseControl"


@case(
    "control.take_control.order",
    requirements=["RS-7.25", "RS-7.13", "RS-6.4"],
    tags=["control", "errors"],
    commands=[C.TAKE_CONTROL],
)
def take_control_order(ctx: Context) -> str:
    """While A holds control, B's TakeControl with a watchdog of 1000 s gets OUT_OF_RANGE
    (the period is checked before the holder), and with a valid period BUSY."""
    a, b = ctx.connect(), ctx.connect()
    ctx.take_control(a)
    try:
        if a.lease is None:
            raise Skip("the endpoint grants no watchdog period (a 1.0/1.1 TakeControl)")
        token = ctx.options.token
        answer = b.call(C.TAKE_CONTROL, token, 1000.0)
        if answer.error is not None and answer.error[0] == ErrorCode.AUTH_FAILED:
            raise Informational("the token was refused; the order after it is not checked")
        _refused(
            answer,
            ErrorCode.OUT_OF_RANGE,
            "TakeControl with a watchdog out of range while another connection holds control",
            "RS-7.25",
        )
        _refused(
            b.call(C.TAKE_CONTROL, token, float(a.lease)),
            ErrorCode.BUSY,
            "TakeControl with a valid period while another connection holds control",
            "RS-7.8",
        )
    finally:
        _release(a)
        _release(b)
    return "OUT_OF_RANGE before BUSY"


MOTION = [C.ENABLE_POWER, C.DISABLE_POWER, C.SET_MOTION_DESC, C.ROBOT_STATUS]


@case(
    "robot.motion.disable_power_any_state",
    requirements=["RS-5.52", "RS-5.20"],
    tags=["robot", "motion"],
    service="robot",
    motion=True,
    commands=[*MOTION, C.EMERGENCY_STOP, C.RESET_EMERGENCY_STOP],
)
def disable_power_any_state(ctx: Context) -> str:
    """DisablePower with power already off, and under an engaged emergency stop, replies
    without error (nothing moves: power is off in both)."""
    with _Motion(ctx) as m:
        conn = m.conn
        conn.ok(C.DISABLE_POWER)
        for state in ("power off", "emergency stop engaged"):
            if state != "power off":
                conn.ok(C.EMERGENCY_STOP)
            answer = conn.call(C.DISABLE_POWER)
            if answer.error is not None:
                conn.call(C.RESET_EMERGENCY_STOP)
                raise Fail(
                    f"DisablePower refused with {state}",
                    "a reply",
                    _code(answer),
                    requirement="RS-5.52",
                )
        conn.ok(C.RESET_EMERGENCY_STOP)
    return "executed with power off and under the emergency stop"


@case(
    "robot.motion.restart_without_stop",
    requirements=["RS-5.54", "RS-5.53"],
    tags=["robot", "motion"],
    service="robot",
    motion=True,
    commands=[*MOTION, C.RESTART_MOVE],
)
def restart_without_stop(ctx: Context) -> str:
    """RestartMove with power off is NOT_POWERED; with power on and nothing held it replies
    and nothing moves (queue 0, not moving)."""
    with _Motion(ctx) as m:
        conn = m.conn
        conn.ok(C.DISABLE_POWER)
        _refused(
            conn.call(C.RESTART_MOVE),
            ErrorCode.NOT_POWERED,
            "RestartMove with power off",
            "RS-5.53",
        )
        m.power()
        answer = conn.call(C.RESTART_MOVE)
        status = _status(conn)
        conn.ok(C.DISABLE_POWER)
        if answer.error is not None:
            raise Fail(
                "RestartMove without StopMove refused",
                "a reply",
                _code(answer),
                requirement="RS-5.54",
            )
        if status.get("moving") or status.get("queue") != 0:
            raise Fail(
                "RestartMove without StopMove started something",
                "not moving, queue 0",
                status,
                requirement="RS-5.54",
            )
    return "nothing held, nothing started"
