"""Helpers the case modules share: hand-built frames and valid arguments per command."""

from __future__ import annotations

import math
import struct
import time
import zlib
from typing import Any

from conformance.connection import ENDPOINT_ERRORS, Closed, Conn
from conformance.context import Context
from conformance.model import EndpointTimeout, Fail, NotApplicable, Skip
from spec import messages as M
from spec import wire
from spec.codec import Packet
from spec.errors import ErrorCode
from spec.params import IDENTITY_LOCATION, FloatArray, Matrix, Value, encode_params
from spec.registry import CommandId as C
from spec.registry import CommandSpec
from spec.wire import PacketKind

#: The answers to a registry command an endpoint does not offer: 1.3's and 1.2's [RS-5.62].
NOT_OFFERED = (ErrorCode.NOT_SUPPORTED, ErrorCode.UNKNOWN_COMMAND)


def seal(header_and_payload: bytes) -> bytes:
    """Append the CRC-32 trailer [RS-3.6]."""
    return header_and_payload + struct.pack(">I", zlib.crc32(header_and_payload))


def raw_frame(
    command: int,
    request_id: int,
    params: tuple[Value, ...] = (),
    *,
    payload: bytes | None = None,
    kind: int = PacketKind.REQUEST,
    major: int = wire.VERSION_MAJOR,
    minor: int = wire.VERSION_MINOR,
    flags: int = 0,
    magic: bytes = wire.MAGIC,
    length: int | None = None,
    crc_ok: bool = True,
) -> bytes:
    """A frame with any header field set by hand (for the negative cases)."""
    body = encode_params(params) if payload is None else payload
    n = len(body) if length is None else length
    header = wire.HEADER.pack(magic, major, minor, kind, flags, command, request_id, n)
    framed = seal(header + body)
    if not crc_ok:
        framed = framed[:-1] + bytes([framed[-1] ^ 0xFF])
    return framed


def read_raw_frame(conn: Conn, timeout: float, *, header_only: bool = False) -> bytes:
    """The bytes of the next frame as they arrived (the decoder would hide header fields);
    only its header with ``header_only``. Raise EndpointTimeout when it does not arrive."""
    deadline = time.monotonic() + timeout
    raw = b""
    need = wire.HEADER_SIZE
    while len(raw) < need:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            break
        conn.sock.settimeout(remaining)
        try:
            chunk = conn.sock.recv(65536)
        except TimeoutError:
            break
        if not chunk:
            break
        conn.log.add("<-", conn.number, chunk)
        raw += chunk
        if not header_only and len(raw) >= wire.HEADER_SIZE:
            need = wire.HEADER_SIZE + wire.HEADER.unpack_from(raw)[7] + wire.TRAILER_SIZE
    if len(raw) < need:
        raise EndpointTimeout(f"only {len(raw)} of {need} bytes of a frame arrived")
    return raw


def retarget(frame: bytes, command: int) -> bytes:
    """The same frame with another command ID; the CRC is resealed only if it was valid."""
    if len(frame) < wire.HEADER_SIZE + wire.TRAILER_SIZE:
        return frame
    body = frame[:-4]
    crc_was_ok = zlib.crc32(body) == struct.unpack(">I", frame[-4:])[0]
    new = body[:6] + struct.pack(">H", command) + body[8:]
    if crc_was_ok:
        return seal(new)
    return new + frame[-4:]


def expect_error_echo(answer: Packet, request_id: int, code: int, command: int) -> None:
    """[RS-3.9] a usable header gets an error echoing its request ID."""
    got = answer.error
    if got is None or got[0] != code or answer.request_id != request_id:
        raise Fail(
            "wrong answer to a malformed frame with a usable header",
            f"error {_name(code)} echoing request ID {request_id}",
            f"{answer.kind.name} request ID {answer.request_id}"
            + (f" error {_name(got[0])}: {got[1]}" if got else ""),
            requirement="RS-3.9",
        )
    if answer.command != command:
        raise Fail(
            "the error does not echo the command ID",
            f"command 0x{command:04x}",
            f"command 0x{answer.command:04x}",
            requirement="RS-3.4",
        )


def _name(code: int) -> str:
    from spec.errors import ErrorCode

    try:
        return ErrorCode(code).name
    except ValueError:
        return str(code)


def still_answers(conn: Conn, what: str) -> None:
    """The same connection still answers the run's liveness probe after a recoverable error
    [RS-3.9]: Ping, or Hello when the endpoint does not answer Ping (which one case judges,
    not every case of the corpus again)."""
    ping = conn.probe_command == C.PING
    expected = "Ping echoed on the same connection" if ping else "Hello answered on it"
    try:
        if ping:
            echo = conn.ask(M.PingRequest(b"after")).data
        else:
            conn.ask(M.HelloRequest(1, 0, "conformance"))
            return
    except Fail as exc:
        raise Fail(
            f"the connection does not go on after {what}",
            expected,
            exc.actual if exc.actual is not None else exc.message,
            requirement="RS-3.9",
        ) from None
    except ENDPOINT_ERRORS as exc:
        raise Fail(
            f"the connection does not go on after {what}",
            expected,
            f"{type(exc).__name__}: {exc}",
            requirement="RS-3.9",
        ) from None
    if echo != b"after":
        raise Fail("Ping does not echo its bytes", b"after", echo, requirement="RS-5.8")


def endpoint_status(ctx: Context, conn: Conn) -> M.RobotStatusReply | M.SensorStatusReply:
    """The endpoint's GetStatus: a read-only command every robot and sensor answers."""
    if ctx.service == "robot":
        return conn.ask(M.RobotStatusRequest())
    return conn.ask(M.SensorStatusRequest())


def io_names(conn: Conn) -> tuple[list[str], list[str]]:
    """(outputs, inputs) from ListIO."""
    names = conn.ask(M.ListIORequest())
    return (
        [n.strip() for n in names.outputs.split(",") if n.strip()],
        [n.strip() for n in names.inputs.split(",") if n.strip()],
    )


#: Neutral arguments that are the same for every endpoint.
_FIXED_ARGS: dict[int, tuple[Value, ...]] = {
    C.HELLO: (1, 0, "conformance"),
    C.PING: (b"\x00\x01conformance\xff",),
    C.SET_FRAME_CRC: (True,),  # on: what every connection starts with
    C.HERE: (IDENTITY_LOCATION, IDENTITY_LOCATION),
    C.WAIT_END_MOVE: (0.05,),
    C.GET_IMAGE: (),
    C.GET_SEAM_POINTS: (-1,),
}
#: Setters given their current values: the getter, and the fields of its reply they take
#: (none named: the setter's own fields, which the getter's reply names alike).
_CURRENT_ARGS: dict[int, tuple[M.Request[Any], tuple[str, ...]]] = {
    C.JOINT_MOVE: (M.HerejRequest(), ()),
    C.SET_MOTION_DESC: (M.GetMotionDescRequest(), ()),
    C.SET_LASER: (M.SensorStatusRequest(), ("laser",)),
    C.SET_EXPOSURE: (M.GetSettingsRequest(), ()),
    C.SET_READOUT_WINDOW: (M.GetSettingsRequest(), ()),
    C.SET_SENSOR_ENDPOINT: (M.GetSyncConfigRequest(), ()),
    C.SET_SYNC_DELAY: (M.GetSyncConfigRequest(), ()),
    C.SET_SENSOR_TOOL: (M.GetSyncConfigRequest(), ()),
}


def valid_args(ctx: Context, conn: Conn, spec: CommandSpec) -> tuple[Value, ...]:
    """Correct arguments for ``spec`` that change nothing (current values where possible)."""
    c = spec.id
    if c in _FIXED_ARGS:
        return _FIXED_ARGS[c]
    if c in _CURRENT_ARGS:
        getter, fields = _CURRENT_ARGS[c]
        current = conn.ask(getter)
        return tuple(getattr(current, name) for name in fields or [p.name for p in spec.params])
    if c == C.TAKE_CONTROL:
        return (ctx.options.token,)
    if c in (C.TOOL_MOVE_J, C.TOOL_MOVE_L):
        here = conn.ask(M.HereRequest(IDENTITY_LOCATION, IDENTITY_LOCATION)).location
        return (here, IDENTITY_LOCATION, IDENTITY_LOCATION)
    if c == C.TOOL_MOVE_TRAJECTORY:
        here = conn.ask(M.HereRequest(IDENTITY_LOCATION, IDENTITY_LOCATION)).location
        return (
            FloatArray([0.0, 0.5]),
            Matrix(2, 6, here.as_tuple() * 2),
            IDENTITY_LOCATION,
            IDENTITY_LOCATION,
        )
    if c in (C.SET_OUTPUT, C.READ_IO):
        return _io_args(ctx, conn, c)
    if c == C.GET_JOINT_LOG:
        return (conn.ask(M.GetTimeRequest()).time - 0.1,)
    if c in (C.START_TRIGGERS, C.SCHEDULE_TRIGGERS):
        raise Skip("covered by the sync cases (needs a UDP sink)")
    if spec.params:
        raise Skip(f"no neutral arguments known for {spec.name}")
    return ()


def _io_args(ctx: Context, conn: Conn, c: int) -> tuple[Value, ...]:
    outputs, inputs = io_names(conn) if C.LIST_IO in ctx.advertised else ([], [])
    names = outputs if c == C.SET_OUTPUT else outputs + inputs
    if not names:
        raise NotApplicable("the robot lists no digital I/O")
    if c == C.READ_IO:
        return (names[0],)
    return (names[0], conn.ask(M.ReadIORequest(names[0])).value)


def wrong_type(spec_type: wire.ParamType) -> Value:
    """A value of a type other than ``spec_type``."""
    return "wrong type" if spec_type is not wire.ParamType.STRING else 12345


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def recoverable_check(
    ctx: Context, frame: bytes, rid: int, command: int, code: int, what: str
) -> None:
    """[RS-3.9] an error frame echoing the request ID and the code, the connection kept and
    still answering."""
    conn = ctx.connect()
    conn.send(frame, what)
    try:
        answer = conn.recv_packet()
    except Closed:
        raise Fail(
            f"the connection was closed after {what}",
            f"error {ErrorCode(code).name} echoing request ID {rid}, connection kept",
            "connection closed",
            requirement="RS-3.9",
        ) from None
    expect_error_echo(answer, rid, code, command)
    still_answers(conn, what)


def fatal_check(ctx: Context, data: bytes, codes: tuple[int, ...], what: str) -> None:
    """[RS-3.8] error frame with request ID 0, then close; then the liveness probe [RS-7.9]."""
    conn = ctx.connect()
    conn.send(data, what)
    try:
        packets = conn.expect_closed(ctx.timeout * 2)
    except EndpointTimeout:
        raise Fail(
            f"the connection stays open after {what}",
            "an error frame with request ID 0, then the connection closed",
            "still open",
            requirement="RS-3.8",
        ) from None
    names = " or ".join(ErrorCode(c).name for c in codes)
    if not packets or packets[0].error is None or packets[0].request_id != 0:
        raise Fail(
            f"no request-ID-0 error frame before the close after {what}",
            f"error {names}, request ID 0",
            "closed silently" if not packets else repr(packets[0]),
            requirement="RS-3.8",
        )
    if packets[0].error[0] not in codes:
        raise Fail(
            f"wrong error code after {what}",
            f"error {names}",
            f"error {packets[0].error[0]}: {packets[0].error[1]}",
            requirement="RS-3.8",
        )
    if packets[0].command != 0:
        raise Fail(
            f"the error after {what} answers no request but names a command",
            "command ID 0 (with request ID 0)",
            f"command ID 0x{packets[0].command:04x}",
            requirement="RS-3.20",
        )
    ctx.probe()
