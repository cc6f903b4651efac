"""What 1.2 left to guessing and 1.3 fixes (issue 32): which refusals set last_error, the
motion descriptor's owner, GetJointLog's NaN, TakeControl's check order, DisablePower and
RestartMove in every state (PROTOCOL.md sections 5.3 and 7)."""

from __future__ import annotations

from dataclasses import replace

from conformance.cases.robot import (
    SLOW,
    STEP_DEG,
    _joints,
    _Motion,
    _status,
    _step_back,
    _step_out,
    _wait_still,
    motion_desc,
)
from conformance.connection import Conn
from conformance.context import Context
from conformance.model import Fail, Informational, Skip, case
from spec import messages as M
from spec.codec import Packet
from spec.errors import ErrorCode
from spec.params import Joints, Matrix
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
        rows[since] = conn.ask(M.GetJointLogRequest(since)).log.rows
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
            too_fast = replace(motion_desc(conn), joint_speed=150.0)
            conn.error(C.SET_MOTION_DESC, ErrorCode.OUT_OF_RANGE, *too_fast.encode())
            conn.error(C.WAIT_END_MOVE, ErrorCode.OUT_OF_RANGE, -1.0)
        after = _status(conn)
    finally:
        _release(conn)
    was = (before.last_error, before.last_message)
    now = (after.last_error, after.last_message)
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
    saved = motion_desc(a)
    try:
        wanted = M.SetMotionDescRequest(7.0, 55.0, 45.0, 123.0, 33.0, 0.5)
        a.ask(wanted)
        _release(a)
        seen = motion_desc(b)
    finally:
        ctx.take_control(a)
        a.call(C.SET_MOTION_DESC, *saved.encode())
        _release(a)
    if seen != wanted:
        raise Fail(
            "another connection does not see the motion descriptor in force",
            wanted.encode(),
            seen.encode(),
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
        if status.moving or status.queue != 0:
            raise Fail(
                "RestartMove without StopMove started something",
                "not moving, queue 0",
                status,
                requirement="RS-5.54",
            )
    return "nothing held, nothing started"


@case(
    "timeouts.idle_while_pending",
    requirements=["RS-7.28"],
    level="INFO",
    tags=["timeouts", "not-observable"],
)
def idle_while_pending(ctx: Context) -> str:
    """Not observable in a case's budget: see the case's message."""
    idle = ctx.hello.number("idle_timeout", 300.0) if ctx.hello else 300.0
    raise Informational(
        f"RS-7.28 needs a request pending for longer than the idle timeout ({idle:g} s here),"
        " i.e. a move longer than that; the harness's documented motion is a 2 degree move."
        " The reference server's tests check it (tests/test_spec_server.py)."
    )


#: [RS-7.27] a server queues at least this many requests behind a pending one.
MIN_QUEUED = 16


@case(
    "robot.motion.queued_behind_wait",
    requirements=["RS-7.27", "RS-7.12", "RS-3.10"],
    tags=["robot", "motion", "limits"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=[C.JOINT_MOVE, C.ENABLE_POWER, C.WAIT_END_MOVE, C.SET_MOTION_DESC, C.HEREJ],
)
def queued_behind_wait(ctx: Context) -> str:
    """During a 2 degree move, WaitEndMove and 40 Herej go out back to back: the first 16
    Herej queue behind the pending WaitEndMove and are answered after it, in order; any
    BUSY goes only to the later ones. The arm comes back."""
    count = 40
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        step = _step_out(conn)
        piece = 5.0 if conn.lease is None else min(5.0, conn.lease / 2)
        wait_id = conn.request(C.WAIT_END_MOVE, piece)
        ids = [conn.request(C.HEREJ) for _ in range(count)]
        # Collected by request ID: a BUSY may overtake the pending replies [RS-7.27].
        got: dict[int, Packet] = {}
        while len(got) < count + 1:
            packet = conn.recv_packet(timeout=piece + 10.0)
            got[packet.request_id] = packet
        _wait_still(conn, 30.0)
        _step_back(conn, step)
    if set(got) != {wait_id, *ids}:
        raise Fail("answers that echo no request", sorted(ids), sorted(got), requirement="RS-3.4")
    answers = [got[rid] for rid in ids]
    busy = [k for k, a in enumerate(answers) if a.error is not None]
    wrong = [
        (k, _code(answers[k]))
        for k in busy
        if k < MIN_QUEUED or answers[k].error[0] != ErrorCode.BUSY  # type: ignore[index]
    ]
    if wrong:
        raise Fail(
            f"requests behind a pending WaitEndMove refused (the first {MIN_QUEUED} must queue;"
            " only BUSY may refuse later ones)",
            f"replies to the first {MIN_QUEUED}",
            wrong[:5],
            requirement="RS-7.27",
        )
    return f"{count - len(busy)} queued, {len(busy)} BUSY"


#: [RS-5.57] the joint speeds of the two moves (% of nominal): low, so 2 degrees cruise.
SPEED_PCTS = (1.0, 2.0)
#: The part of the travel where both moves cruise (fractions of the 2 degrees).
CRUISE_BAND = (0.3, 0.7)


def _crossing(ts: list[float], qs: list[float], level: float) -> float | None:
    """The time joint 1 first passes ``level``, interpolated between samples."""
    for k in range(1, len(qs)):
        a, b = qs[k - 1] - level, qs[k] - level
        if a == 0.0:
            return ts[k - 1]
        if a * b < 0.0 or b == 0.0:
            return ts[k - 1] + (ts[k] - ts[k - 1]) * a / (a - b)
    return None


def _cruise_speeds(log: Matrix, q_from: float, q_to: float) -> tuple[float, float] | None:
    """Joint 1's mean speed (deg/s) over the first and the second half of CRUISE_BAND of its
    travel from ``q_from`` to ``q_to``; None when the log does not cover the band."""
    rows = log.to_rows()
    ts, qs = [r[0] for r in rows], [r[1] for r in rows]
    lo, hi = CRUISE_BAND
    levels = [q_from + (q_to - q_from) * f for f in (lo, (lo + hi) / 2, hi)]
    times = [_crossing(ts, qs, level) for level in levels]
    if any(t is None for t in times):
        return None
    t0, t1, t2 = (float(t) for t in times)  # type: ignore[arg-type]
    half = abs(q_to - q_from) * (hi - lo) / 2
    if t1 <= t0 or t2 <= t1:
        return None
    return half / (t1 - t0), half / (t2 - t1)


@case(
    "robot.motiondesc.joint_speed_scales",
    requirements=["RS-5.57"],
    tags=["robot", "motion"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=[*MOTION, C.JOINT_MOVE, C.WAIT_END_MOVE, C.GET_JOINT_LOG, C.GET_TIME, C.HEREJ],
)
def joint_speed_scales(ctx: Context) -> str:
    """Joint 1 turns +2 degrees at 1 % joint speed and back at 2 % (5 % acceleration): in the
    middle of its travel it cruises twice as fast on the way back. The nominal speed the
    cruise implies is reported; the descriptor and the power state are restored."""
    with _Motion(ctx) as m:
        conn = m.conn
        was_powered = bool(_status(conn).powered)
        m.power()
        start = _joints(conn)
        legs = (
            (SPEED_PCTS[0], start[0], start[0] + STEP_DEG),
            (SPEED_PCTS[1], start[0] + STEP_DEG, start[0]),
        )
        logs: list[tuple[float, Matrix, float, float]] = []
        try:  # both moves first, so the arm is back before anything is judged
            for pct, q_from, q_to in legs:
                conn.ok(C.SET_MOTION_DESC, pct, SLOW, SLOW, 50.0, 20.0, 0.0)
                since = conn.ask(M.GetTimeRequest()).time
                conn.ok(C.JOINT_MOVE, Joints([q_to, *start[1:]]))
                if not _wait_still(conn, 30.0):
                    raise Fail(f"a 2 degree move at {pct:g} % did not end within 30 s", True, False)
                log = conn.ask(M.GetJointLogRequest(since - 0.01)).log
                logs.append((pct, log, q_from, q_to))
        finally:
            if not was_powered and not conn.closed:
                conn.call(C.DISABLE_POWER)
    cruise: list[float] = []
    for pct, log, q_from, q_to in logs:
        speeds = _cruise_speeds(log, q_from, q_to)
        if speeds is None:
            raise Informational(
                f"the joint log does not show joint 1 crossing the middle of its travel at"
                f" {pct:g} %; the speed is not judged"
            )
        first, second = speeds
        if abs(first - second) > 0.05 * max(first, second):
            raise Informational(
                f"joint 1 does not cruise at {pct:g} % in the middle of a 2 degree move"
                f" ({first:.3f} then {second:.3f} deg/s); the speed is not judged"
            )
        cruise.append((first + second) / 2)
    ratio = cruise[1] / cruise[0]
    want = SPEED_PCTS[1] / SPEED_PCTS[0]
    ctx.measure(
        "joint_speed_scales",
        cruise_deg_s=[round(v, 4) for v in cruise],
        implied_nominal_deg_s=round(cruise[0] * 100.0 / SPEED_PCTS[0], 2),
    )
    if abs(ratio - want) > 0.075 * want:
        raise Fail(
            f"joint 1's cruise speed does not scale with joint_speed ({SPEED_PCTS[0]:g} % and"
            f" {SPEED_PCTS[1]:g} %)",
            f"ratio {want:g}",
            f"ratio {ratio:.3f} ({cruise[0]:.3f} and {cruise[1]:.3f} deg/s)",
            requirement="RS-5.57",
        )
    return (
        f"{cruise[0]:.3f} and {cruise[1]:.3f} deg/s (ratio {ratio:.3f}); nominal joint 1 speed"
        f" implied: {cruise[0] * 100.0 / SPEED_PCTS[0]:.1f} deg/s"
    )
