"""Generic command coverage, generated from the command registry (PROTOCOL.md section 5).

For every command of the service: ``commands.<group>.<Name>.reply`` sends correct arguments
that change nothing and checks the reply against the reply table [RS-5.5];
``.bad_params`` sends wrong counts and types and expects BAD_PARAMETERS [RS-5.4];
``.not_in_control`` sends a *control* command from a connection without control and expects
NOT_IN_CONTROL [RS-7.4]. A command the endpoint does not advertise is not applicable. Commands
that move or switch (and EmergencyStop) need ``--allow-motion``.

Safety note: without ``--allow-motion`` a moving command is only ever sent with a wrong
parameter count, which a conforming server rejects before anything executes.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable

from conformance.cases._util import NOT_OFFERED, valid_args, wrong_type
from conformance.connection import ENDPOINT_ERRORS, Conn, typed_reply
from conformance.context import Context
from conformance.model import Case, Fail, Informational, Skip, add_case
from spec import messages as M
from spec.errors import ErrorCode
from spec.messages import REPLIES
from spec.params import (
    FloatArray,
    Image,
    IntArray,
    Joints,
    Location,
    Matrix,
    Transform,
    Value,
)
from spec.registry import COMMANDS, CommandSpec
from spec.registry import CommandId as C
from spec.wire import MoveOutcome, ParamType

#: Errors a correct request may get in some states of the endpoint (not a reply-table break).
STATE_ERRORS = (
    ErrorCode.NO_DATA,
    ErrorCode.BAD_STATE,
    ErrorCode.NOT_POWERED,
    ErrorCode.EMERGENCY_STOP,
)

#: Commands the generic `.reply` case leaves to dedicated cases.
DEDICATED = {C.START_TRIGGERS, C.SCHEDULE_TRIGGERS}


def dummy(t: ParamType) -> Value:
    """A value of wire type ``t`` (used where the count, not the value, is under test)."""
    values: dict[ParamType, Value] = {
        ParamType.INT: 0,
        ParamType.FLOAT: 0.0,
        ParamType.BOOL: False,
        ParamType.STRING: "",
        ParamType.BYTES: b"",
        ParamType.FLOAT_ARRAY: FloatArray([]),
        ParamType.INT_ARRAY: IntArray([]),
        ParamType.JOINTS: Joints([0.0] * 6),
        ParamType.LOCATION: Location(0, 0, 0, 0, 0, 0),
        ParamType.TRANSFORM: Transform(),
        ParamType.MATRIX: Matrix(0, 0, []),
        ParamType.IMAGE: Image(0, 0, b""),
    }
    return values[t]


def _dangerous(spec: CommandSpec) -> bool:
    return spec.moves or spec.id == C.EMERGENCY_STOP


def _group(spec: CommandSpec) -> str:
    return spec.service


def _service(spec: CommandSpec) -> str:
    return (
        "any" if spec.service == "common" else ("robot" if spec.service == "sync" else spec.service)
    )


def _reply_case(spec: CommandSpec) -> Callable[[Context], str | None]:
    def run(ctx: Context) -> str | None:
        if spec.id in DEDICATED:
            raise Skip(f"{spec.name} is covered by the sync cases (needs a UDP sink)")
        if _dangerous(spec):
            ctx.require_motion(spec.name)
        conn = ctx.connect()
        if spec.needs_control:
            ctx.take_control(conn)
        try:
            with ctx.precondition(f"power and correct arguments for {spec.name}"):
                powered = _power_for(ctx, conn, spec)
                args = valid_args(ctx, conn, spec)
            answer = conn.call(spec.id, *args, timeout=ctx.timeout * 2)
            ended = None
            if powered:
                with ctx.precondition(f"WaitEndMove and GetStatus after {spec.name}"):
                    ended = _settle(conn)
            if answer.error is not None and answer.error[0] in STATE_ERRORS:
                raise Informational(
                    f"{spec.name} answered {ErrorCode(answer.error[0]).name} in the current"
                    f" state ({answer.error[1]}); reply types not checked"
                )
            if answer.error is not None:
                code, message = answer.error
                raise Fail(
                    f"{spec.name} with correct arguments was refused",
                    "a reply",
                    f"error {code}: {message}",
                    requirement="RS-5.3" if code in NOT_OFFERED else "RS-5.5",
                )
            # The reply's parameters against the table: a Fail of RS-5.5 when they break it.
            typed_reply(REPLIES[spec.id], answer.params)
            if ended is not None and spec.id in _QUEUE_A_MOVE:
                # Not this case's rule, but later cases would meet a robot not left as found.
                raise Informational(
                    f"{spec.name}'s reply matches its table, but the move it queued (to where"
                    f" the arm stands) {ended}, not 'reached'"
                )
            if spec.id == C.EMERGENCY_STOP and C.RESET_EMERGENCY_STOP in ctx.advertised:
                ctx.take_control(conn)
                conn.ok(C.RESET_EMERGENCY_STOP)
        finally:
            if spec.id == C.STOP_MOVE and C.RESET_MOTION in ctx.advertised:
                # StopMove holds the moves queued after it too: leave the robot as found
                with contextlib.suppress(*ENDPOINT_ERRORS):
                    conn.call(C.RESET_MOTION)
            if spec.needs_control:
                _release(conn)
        return None

    run.__doc__ = f"{spec.name} with correct arguments: a reply as in its reply table."
    return run


#: Motion commands whose reply needs a powered arm (the power commands test themselves).
_NEED_POWER = {C.JOINT_MOVE, C.TOOL_MOVE_J, C.TOOL_MOVE_L, C.RESTART_MOVE, C.TOOL_MOVE_TRAJECTORY}
#: Of those, the ones that queue a move of their own (RestartMove resumes a held one, so how
#: the last move ended after it may be another case's).
_QUEUE_A_MOVE = _NEED_POWER - {C.RESTART_MOVE}


def _power_for(ctx: Context, conn: Conn, spec: CommandSpec) -> bool:
    """With --allow-motion the harness powers the arm itself (and releases a software
    emergency stop) so that a motion command's reply is checked, not answered NOT_POWERED."""
    if ctx.service != "robot" or spec.id not in _NEED_POWER or not ctx.options.allow_motion:
        return False
    status = conn.ask(M.RobotStatusRequest())
    powered, estop = status.powered, status.estop
    if estop and C.RESET_EMERGENCY_STOP in ctx.advertised:
        conn.ok(C.RESET_EMERGENCY_STOP)
    if not powered and C.ENABLE_POWER in ctx.advertised:
        conn.ok(C.ENABLE_POWER)
    return True


#: How long a case waits for the (null) move it queued to end (s).
SETTLE_S = 30.0


def _settle(conn: Conn) -> str | None:
    """Wait for the (null) move to end, in pieces that keep the control lease; None when the
    robot says it reached its target, else how it ended instead, for the case to report.

    The wait ends as soon as the move no longer runs, whichever way [RS-5.50]: ``done``;
    ``outcome`` stopped or failed (1.3); or, from a 1.2 reply (``done`` false for a stop and
    an unfinished wait alike), GetStatus' ``moving`` false [RS-5.59]."""
    piece = (conn.lease or 1.0) / 2
    deadline = time.monotonic() + SETTLE_S
    while True:
        answer = conn.call(C.WAIT_END_MOVE, piece, timeout=piece + 5.0)
        if answer.error is not None:
            code, message = answer.error
            return f"WaitEndMove was refused (error {code}: {message})"
        ended = typed_reply(M.WaitEndMoveReply, answer.params)
        if ended.done:
            return None
        if ended.outcome is not None and ended.outcome != MoveOutcome.MOVING:
            return f"ended {ended.outcome!r} ({ended.reason or 'no reason given'})"
        if ended.outcome is None and not conn.ask(M.RobotStatusRequest()).moving:
            return "stands still without having reached its target (a 1.2 WaitEndMove reply)"
        if time.monotonic() >= deadline:
            return f"still moving after {SETTLE_S:g} s"


def _release(conn: Conn) -> None:
    try:
        conn.call(C.RELEASE_CONTROL)
    except ENDPOINT_ERRORS:  # cleanup: the case's verdict is already made
        pass


def _bad_params_case(spec: CommandSpec) -> Callable[[Context], str | None]:
    def run(ctx: Context) -> str | None:
        conn = ctx.connect()
        accept: tuple[int, ...] = (ErrorCode.BAD_PARAMETERS,)
        holding = False
        if spec.needs_control:
            if _dangerous(spec) and not ctx.options.allow_motion:
                # Without control nothing may execute either way: both answers are safe ones.
                accept = (ErrorCode.BAD_PARAMETERS, ErrorCode.NOT_IN_CONTROL)
            else:
                ctx.take_control(conn)
                holding = True
        try:
            good = tuple(dummy(p.type) for p in spec.params)
            trials: list[tuple[str, tuple[Value, ...]]] = [
                ("one parameter too many", (*good, 0)),
            ]
            if spec.params:
                first = spec.params[0]
                trials.append(
                    (f"{first.name} of the wrong type", (wrong_type(first.type), *good[1:]))
                )
            if any(not p.optional for p in spec.params):
                trials.append(("no parameters", ()))
            for what, args in trials:
                answer = conn.call(spec.id, *args)
                got = answer.error
                if got is None or got[0] not in accept:
                    raise Fail(
                        f"{spec.name} with {what} is not refused with BAD_PARAMETERS",
                        " or ".join(ErrorCode(c).name for c in accept),
                        "a reply" if got is None else f"error {got[0]}: {got[1]}",
                        requirement="RS-5.4",
                    )
        finally:
            if holding:
                _release(conn)
        return None

    run.__doc__ = f"{spec.name} with a wrong parameter count or type: BAD_PARAMETERS."
    return run


def _not_in_control_case(spec: CommandSpec) -> Callable[[Context], str | None]:
    def run(ctx: Context) -> str | None:
        if _dangerous(spec):
            ctx.require_motion(f"{spec.name} without control")
        if spec.id in DEDICATED:
            args: tuple[Value, ...] = (
                (10.0, 1) if spec.id == C.START_TRIGGERS else (FloatArray([1e9]),)
            )
        else:
            args = tuple(dummy(p.type) for p in spec.params)
            if _dangerous(spec):
                # A server that ignored control would execute this: make it a no-op target.
                probe = ctx.connect()
                with ctx.precondition(f"correct arguments for {spec.name}"):
                    args = valid_args(ctx, probe, spec)
        conn = ctx.connect()  # a fresh connection never holds control
        conn.error(spec.id, ErrorCode.NOT_IN_CONTROL, *args)
        return None

    run.__doc__ = f"{spec.name} from a connection without control: NOT_IN_CONTROL."
    return run


def _register() -> None:
    for spec in COMMANDS:
        base = f"commands.{_group(spec)}.{spec.name}"
        common = {
            "level": "MUST",
            "motion": False,
            "service": _service(spec),
            "commands": (int(spec.id),),
            "order": 40,
        }
        add_case(
            Case(
                id=f"{base}.reply",
                fn=_reply_case(spec),
                requirements=("RS-5.5", "RS-5.3"),
                tags=("commands", spec.service),
                profiles=("core", "full") + (("smoke",) if not spec.params else ()),
                budget=8.0,
                title=f"{spec.name}: correct arguments give a reply matching its table",
                **common,  # type: ignore[arg-type]
            )
        )
        add_case(
            Case(
                id=f"{base}.bad_params",
                fn=_bad_params_case(spec),
                requirements=("RS-5.4",),
                tags=("commands", "parameters", spec.service),
                profiles=("core", "full"),
                budget=8.0,
                title=f"{spec.name}: wrong parameter count or type gives BAD_PARAMETERS",
                **common,  # type: ignore[arg-type]
            )
        )
        if spec.needs_control:
            add_case(
                Case(
                    id=f"{base}.not_in_control",
                    fn=_not_in_control_case(spec),
                    requirements=("RS-7.4",),
                    tags=("commands", "control", spec.service),
                    profiles=("core", "full"),
                    budget=8.0,
                    title=f"{spec.name} without control gives NOT_IN_CONTROL",
                    **common,  # type: ignore[arg-type]
                )
            )


_register()
