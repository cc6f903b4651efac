"""Error precedence (PROTOCOL.md section 6, [RS-6.4]): a request that breaks several rules gets
the error of the first check in the table. Nothing here moves or switches anything: every
request probed is refused before it could execute."""

from __future__ import annotations

from conformance.cases._util import seal
from conformance.context import Context
from conformance.model import Fail, case
from spec import wire
from spec.codec import encode_packet, request
from spec.errors import ErrorCode
from spec.params import Joints
from spec.registry import CommandId as C

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
    """Parameter decoding before the command ID; the command ID before parameter types;
    parameter types before control; control before the command's own checks."""
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
        status = holder.ok(C.ROBOT_STATUS)
        if status[0] is False and status[1] is False:
            answer = holder.call(C.JOINT_MOVE, Joints([1000.0] * 6))
            _expect(answer.error, ErrorCode.NOT_POWERED, "JointMove to 1000 deg, power off")
            checked.append("power<range")
    holder.call(C.RELEASE_CONTROL)
    return ", ".join(checked)
