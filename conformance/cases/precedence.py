"""Error precedence (PROTOCOL.md section 6, [RS-6.4]): a request that breaks several rules gets
the error of the first check in the table. Nothing here moves or switches anything: every
request probed is refused before it could execute."""

from __future__ import annotations

from conformance.cases._util import NOT_OFFERED, seal
from conformance.context import Context
from conformance.model import Fail, case
from spec import messages as M
from spec import wire
from spec.codec import encode_packet, request
from spec.errors import ErrorCode
from spec.params import Joints
from spec.registry import CommandId as C
from spec.registry import commands_for

#: An ID in the experimental range that no endpoint of this document implements.
UNKNOWN = 0xFFF0


def _expect(answer_error: tuple[int, str] | None, code: ErrorCode, what: str) -> None:
    if answer_error is None or answer_error[0] != code:
        raise Fail(
            f"wrong error for {what}",
            code.name,
            answer_error or "executed",
            requirement="RS-6.4",
        )


@case("errors.precedence", requirements=["RS-6.4"], tags=["errors"])
def precedence(ctx: Context) -> str:
    """Parameter decoding before the command ID; the command ID (unknown, or not offered)
    before parameter types; parameter types before control; control before the command's
    own checks."""
    conn = ctx.connect()
    checked = []
    # 7 before 8: an unknown command whose parameter list does not decode.
    frame = bytearray(encode_packet(request(UNKNOWN, 1, 5))[:-4])
    frame[wire.HEADER_SIZE + 2] = 0x7F  # the INT's type tag becomes an unknown one
    conn.send(seal(bytes(frame)), "unknown command, unknown parameter tag")
    _expect(conn.recv_packet().error, ErrorCode.BAD_PARAMETERS, "an undecodable parameter list")
    checked.append("decode<command")
    # 8 before 10: an unknown command with (decodable) parameters of any type.
    _expect(conn.call(UNKNOWN, "x", 1.5).error, ErrorCode.UNKNOWN_COMMAND, "an unknown command")
    checked.append("command<types")
    # 8 before 10 and 11: a registry command the endpoint does not offer (left out of Hello),
    # with a wrong parameter count and without control, is NOT_SUPPORTED (1.2: UNKNOWN_COMMAND).
    listed = ctx.hello.commands if ctx.hello is not None else frozenset()
    unoffered = [s for s in commands_for(ctx.service) if listed and s.id not in listed]
    if unoffered:
        spec = unoffered[0]
        answer = conn.call(spec.id, *(["not-a-value"] * (len(spec.params) + 1)))
        if answer.error is None or answer.error[0] not in NOT_OFFERED:
            raise Fail(
                f"wrong error for {spec.name} (not offered) with wrong parameters, no control",
                "NOT_SUPPORTED (or a 1.2 endpoint's UNKNOWN_COMMAND)",
                answer.error or "executed",
                requirement="RS-6.4",
            )
        checked.append("offered<types<control")
    # 10 before 11: a control command with wrong parameter types, sent without control.
    probe = C.JOINT_MOVE if ctx.service == "robot" else C.SET_LASER
    if probe in ctx.advertised:
        answer = conn.call(probe, "not-a-value")
        _expect(answer.error, ErrorCode.BAD_PARAMETERS, "wrong types without control")
        checked.append("types<control")
    # 12: the token before the holder, when a token is configured.
    holder = ctx.connect()
    ctx.take_control(holder)
    answer = conn.call(C.TAKE_CONTROL, ctx.options.token + "-wrong-conformance-token")
    if answer.error is not None and answer.error[0] == ErrorCode.AUTH_FAILED:
        checked.append("token<holder")
    elif answer.error is None or answer.error[0] != ErrorCode.BUSY:
        raise Fail("wrong error for TakeControl while held", "AUTH_FAILED or BUSY", answer.error)
    # 12: power before values, for a robot that is powered off.
    if ctx.service == "robot" and C.JOINT_MOVE in ctx.advertised:
        status = holder.ask(M.RobotStatusRequest())
        if not status.powered and not status.estop:
            answer = holder.call(C.JOINT_MOVE, Joints([1000.0] * 6))
            _expect(answer.error, ErrorCode.NOT_POWERED, "JointMove to 1000 deg, power off")
            checked.append("power<range")
    holder.call(C.RELEASE_CONTROL)
    return ", ".join(checked)
