"""Framing: byte order, header fields, CRC, echo, splitting, pipelining, recoverable and fatal
frame errors (PROTOCOL.md sections 2, 3 and 6)."""

from __future__ import annotations

import itertools
import math
import zlib

from conformance.cases._util import fatal_check, raw_frame, read_raw_frame, recoverable_check
from conformance.connection import Conn
from conformance.context import Context
from conformance.model import Fail, Informational, case
from spec import messages as M
from spec import wire
from spec.codec import FrameDecoder, Packet, encode_packet, request
from spec.errors import ErrorCode
from spec.registry import CommandId as C
from spec.wire import PacketKind

SMOKE = ("smoke", "core", "full")


@case(
    "framing.byte_order.header",
    requirements=["RS-2.1", "RS-3.1", "RS-3.3"],
    tags=["framing"],
    profiles=SMOKE,
)
def byte_order_header(ctx: Context) -> None:
    """The reply header is big-endian: magic, version, kind, command, request ID, length."""
    conn = ctx.connect()
    rid = 0x01020304
    conn.send(raw_frame(C.PING, rid, (b"\xaa\xbb\xcc",)), "Ping id 0x01020304")
    raw = read_raw_frame(conn, ctx.timeout, header_only=True)
    magic, major, _minor, kind, flags, command, got_rid, length = wire.HEADER.unpack_from(raw)
    expected = (b"RS", 1, PacketKind.REPLY, 0, C.PING, rid, 2 + 1 + 4 + 3)
    actual = (magic, major, kind, flags, command, got_rid, length)
    if actual != expected:
        raise Fail(
            "reply header fields are not as the header table says (big-endian)",
            "magic RS, major 1, kind 2, flags 0, command 0x0002, id 0x01020304, length 10",
            f"magic {magic!r}, major {major}, kind {kind}, flags {flags}, command 0x{command:04x},"
            f" id 0x{got_rid:08x}, length {length}",
            requirement="RS-2.1",
        )


@case(
    "framing.float64.time",
    requirements=["RS-2.2", "RS-8.4", "RS-2.1"],
    tags=["framing", "time"],
    profiles=SMOKE,
)
def float64_time(ctx: Context) -> str:
    """GetTime is a finite float64 in seconds that never goes backwards."""
    conn = ctx.connect()
    times = []
    for _ in range(5):
        times.append(conn.ask(M.GetTimeRequest()).time)
    if not all(math.isfinite(t) and abs(t) < 1e11 for t in times):
        raise Fail("GetTime is not a plausible float64 in seconds", "finite, |t| < 1e11", times)
    if any(b < a for a, b in itertools.pairwise(times)):
        raise Fail("GetTime went backwards", "monotonic", times, requirement="RS-8.4")
    if times[-1] - times[0] > 10 * ctx.timeout + 1:
        raise Fail("GetTime advanced far faster than real time", "seconds", times)
    return f"clock {times[-1]:.6f} s"


@case("framing.reply.echo", requirements=["RS-3.4", "RS-6.2"], tags=["framing"], profiles=SMOKE)
def reply_echo(ctx: Context) -> None:
    """Replies and errors echo the command ID and request ID of their request."""
    conn = ctx.connect()
    for rid, command in ((7, C.PING), (1000, C.GET_TIME), (0x7FFFFFFF, C.PING), (42, 0xBFFE)):
        conn.send(raw_frame(command, rid, ()), f"request 0x{command:04x} id {rid}")
        answer = conn.recv_packet()
        if answer.request_id != rid or answer.command != command:
            raise Fail(
                "the answer does not echo command and request ID",
                f"command 0x{command:04x} id {rid}",
                f"command 0x{answer.command:04x} id {answer.request_id}",
                requirement="RS-3.4",
            )


@case("framing.split.byte_by_byte", requirements=["RS-2.4"], tags=["framing"], budget=10.0)
def byte_by_byte(ctx: Context) -> None:
    """A request sent one byte per TCP segment is answered."""
    conn = ctx.connect()
    conn.send_bytewise(raw_frame(C.PING, 5, (b"bytewise",)), "Ping id 5")
    answer = conn.recv_packet()
    if answer.request_id != 5 or answer.params[:1] != (b"bytewise",):
        raise Fail("a frame split byte by byte is not answered", "Ping echo id 5", answer)


@case("framing.coalesced", requirements=["RS-2.4", "RS-6.2"], tags=["framing"], profiles=SMOKE)
def coalesced(ctx: Context) -> None:
    """Three requests in one segment get three answers."""
    conn = ctx.connect()
    data = b"".join(raw_frame(C.PING, 10 + i, (bytes([i]) * (i + 1),)) for i in range(3))
    conn.send(data, "3 Pings in one segment")
    for i in range(3):
        answer = conn.recv_packet()
        if answer.request_id != 10 + i or answer.params[:1] != (bytes([i]) * (i + 1),):
            raise Fail("frames in one segment are not all answered in order", 10 + i, answer)
    extra = conn.quiet(ctx.scaled(0.1))
    if extra:
        raise Fail("more answers than requests", 3, 3 + len(extra), requirement="RS-6.2")


@case("framing.pipelined.ordered", requirements=["RS-3.10", "RS-6.2"], tags=["framing"])
def pipelined(ctx: Context) -> None:
    """Twenty pipelined requests (some invalid) are answered once each, in order."""
    conn = ctx.connect()
    sent: list[tuple[int, int]] = []
    frames = []
    for i in range(20):
        command = (C.PING, C.GET_TIME, 0xBFFF, C.PING)[i % 4]
        params: tuple[bytes, ...] = (bytes([i]),) if command == C.PING else ()
        frames.append(raw_frame(command, 100 + i, params))
        sent.append((command, 100 + i))
    conn.send(b"".join(frames), "20 pipelined requests")
    got = [conn.recv_packet() for _ in sent]
    order = [(p.command, p.request_id) for p in got]
    if order != sent:
        raise Fail(
            "pipelined requests are not answered in order", sent, order, requirement="RS-3.10"
        )
    extra = conn.quiet(ctx.scaled(0.1))
    if extra:
        raise Fail("more answers than requests", 20, 20 + len(extra), requirement="RS-6.2")


@case("framing.crc.bad", requirements=["RS-3.6", "RS-3.9"], tags=["framing", "errors"])
def bad_crc(ctx: Context) -> None:
    """A bad CRC gets BAD_CRC echoing the request ID; the connection goes on."""
    frame = raw_frame(C.PING, 31, (b"crc",), crc_ok=False)
    recoverable_check(ctx, frame, 31, C.PING, ErrorCode.BAD_CRC, "a frame with a bad CRC")


@case(
    "framing.version.major",
    requirements=["RS-3.11", "RS-3.9", "RS-3.2"],
    tags=["framing", "errors"],
)
def version_major(ctx: Context) -> None:
    """A version 2.0 frame gets UNSUPPORTED_VERSION; the connection goes on."""
    frame = raw_frame(C.PING, 32, (b"v2",), major=2)
    recoverable_check(ctx, frame, 32, C.PING, ErrorCode.UNSUPPORTED_VERSION, "a version 2.0 frame")


@case("framing.kind.not_request", requirements=["RS-3.12", "RS-3.9"], tags=["framing", "errors"])
def kind_not_request(ctx: Context) -> None:
    """Frames of kind reply, error, event, 0 and 9 get BAD_FRAME; the connection goes on."""
    for i, kind in enumerate((PacketKind.REPLY, PacketKind.ERROR, PacketKind.EVENT, 0, 9)):
        frame = raw_frame(C.PING, 40 + i, (), kind=int(kind))
        recoverable_check(
            ctx, frame, 40 + i, C.PING, ErrorCode.BAD_FRAME, f"a frame of kind {kind}"
        )


@case(
    "framing.flags.nonzero",
    requirements=["RS-3.7", "RS-3.9", "RS-3.17"],
    tags=["framing", "errors"],
)
def flags_nonzero(ctx: Context) -> None:
    """Flags 0x01 on a request (NO_CRC is for server frames only) get BAD_FRAME; the connection
    goes on."""
    frame = raw_frame(C.PING, 33, (), flags=0x01)
    recoverable_check(ctx, frame, 33, C.PING, ErrorCode.BAD_FRAME, "a frame with flags 0x01")


@case("framing.magic.bad", requirements=["RS-3.8", "RS-3.1", "RS-7.9"], tags=["framing", "errors"])
def magic_bad(ctx: Context) -> None:
    """Wrong magic: error BAD_FRAME with request ID 0, then the connection closes."""
    frame = raw_frame(C.PING, 34, (), magic=b"XS")
    fatal_check(ctx, frame, (ErrorCode.BAD_FRAME,), "a frame with magic 'XS'")


@case(
    "framing.length.over_limit",
    requirements=["RS-3.5", "RS-3.8"],
    tags=["framing", "errors", "limits"],
)
def length_over_limit(ctx: Context) -> None:
    """A length above the announced maximum is refused from the header alone (no payload sent)."""
    limit = (
        int(ctx.hello.number("max_payload", wire.MAX_PAYLOAD)) if ctx.hello else wire.MAX_PAYLOAD
    )
    limit = min(limit, wire.MAX_PAYLOAD)
    header = wire.HEADER.pack(wire.MAGIC, 1, 0, PacketKind.REQUEST, 0, C.PING, 35, limit + 1)
    what = f"a header announcing {limit + 1} bytes"
    fatal_check(ctx, header, (ErrorCode.FRAME_TOO_LARGE,), what)


@case(
    "framing.length.under_minimum",
    requirements=["RS-4.1", "RS-4.3", "RS-3.9"],
    tags=["framing", "errors"],
)
def length_under_minimum(ctx: Context) -> None:
    """Payload lengths 0 and 1 (below the 2-byte count) get BAD_PARAMETERS, connection kept."""
    for rid, payload in ((36, b""), (37, b"\x00")):
        frame = raw_frame(C.PING, rid, payload=payload)
        recoverable_check(
            ctx, frame, rid, C.PING, ErrorCode.BAD_PARAMETERS, f"a payload of {len(payload)} B"
        )


@case("framing.error.shape", requirements=["RS-6.1", "RS-5.1"], tags=["framing", "errors"])
def error_shape(ctx: Context) -> None:
    """An unknown command gets UNKNOWN_COMMAND as (INT, STRING); the connection stays open."""
    conn = ctx.connect()
    for command in (0x0FFF, 0x7ABC, 0xBEEF, 0xFFFE):
        conn.error(command, ErrorCode.UNKNOWN_COMMAND)
    conn.ok(C.PING, b"open")


@case(
    "framing.ping.echo",
    requirements=["RS-5.8"],
    tags=["framing", "commands"],
    profiles=SMOKE,
)
def ping_echo(ctx: Context) -> None:
    """Ping echoes its BYTES (all 256 byte values) and answers an empty BYTES without one."""
    conn = ctx.connect()
    data = bytes(range(256)) * 4
    echo = conn.ask(M.PingRequest(data)).data
    if echo != data:
        raise Fail("Ping does not echo its bytes", data.hex()[:32] + "...", repr(echo)[:80])
    echo = conn.ask(M.PingRequest()).data
    if echo != b"":
        raise Fail("Ping without a parameter does not echo empty BYTES", b"", echo)


@case(
    "framing.client.events_ignored",
    requirements=["RS-3.14"],
    level="INFO",
    tags=["framing", "client-side"],
)
def events_ignored(ctx: Context) -> str:
    """Client-side rule: the harness skips event frames; reports whether the endpoint sent any."""
    conn = ctx.connect()
    conn.ok(C.PING, b"")
    conn.quiet(ctx.scaled(0.05))
    return f"client-side rule; {conn.events_seen} event frame(s) seen and ignored"


@case(
    "framing.client.extra_reply_params",
    requirements=["RS-5.6"],
    level="INFO",
    tags=["framing", "client-side"],
)
def extra_reply_params(ctx: Context) -> str:
    """Client-side rule: the harness accepts reply parameters appended by a newer minor version."""
    conn = ctx.connect()
    params = conn.ok(C.HELLO, 1, 0, "conformance")
    if len(params) > 11:
        raise Informational(f"Hello carries {len(params) - 11} appended parameter(s); ignored")
    return "client-side rule; the harness checks replies with extra parameters allowed"


@case(
    "framing.request.encoding",
    requirements=["RS-3.1", "RS-3.6"],
    tags=["framing"],
)
def request_encoding(ctx: Context) -> None:
    """Our own encoder's frame for Ping is answered (codec self-check against the endpoint)."""
    conn = ctx.connect()
    conn.send(encode_packet(request(C.PING, 9, b"codec")), "Ping id 9")
    answer = conn.recv_packet()
    if answer.params[:1] != (b"codec",):
        raise Fail("Ping through the reference codec not echoed", b"codec", answer.params)


def _no_crc_ping(ctx: Context, conn: Conn, rid: int, no_crc: bool) -> None:
    """Ping on ``conn``; its reply must (not) carry the NO_CRC flag and a zero trailer."""
    conn.send(raw_frame(C.PING, rid, (b"nocrc",)), f"Ping id {rid}")
    raw = read_raw_frame(conn, ctx.timeout)
    flags = raw[5]
    (trailer,) = wire.TRAILER.unpack_from(raw, len(raw) - wire.TRAILER_SIZE)
    crc_ok = zlib.crc32(raw[: -wire.TRAILER_SIZE]) == trailer
    if no_crc and (flags != wire.FLAG_NO_CRC or trailer != 0):
        raise Fail(
            "after SetFrameCrc(false) a reply still carries a CRC",
            "flags 0x01 (NO_CRC) and a trailer of 00 00 00 00",
            f"flags 0x{flags:02x}, trailer {trailer:08x}",
            requirement="RS-3.16",
        )
    if not no_crc and (flags != 0 or not crc_ok):
        raise Fail(
            "a reply that should carry its CRC-32 does not",
            "flags 0x00 and the CRC-32 of header and payload",
            f"flags 0x{flags:02x}, trailer {trailer:08x}",
            requirement="RS-3.16",
        )
    decoder = FrameDecoder(accept_no_crc=no_crc)
    decoder.feed(raw)
    packet = decoder.next_event()
    if not isinstance(packet, Packet):
        what = "incomplete" if packet is None else packet.error.message
        raise Fail("the Ping reply is not a valid frame", "a Ping reply", what)
    if packet.request_id != rid or packet.params != (b"nocrc",):
        raise Fail(
            "the Ping reply does not echo request and bytes",
            f"id {rid}, data b'nocrc'",
            f"id {packet.request_id}, params {packet.params!r}",
            requirement="RS-5.8",
        )


@case(
    "framing.no_crc",
    requirements=["RS-3.15", "RS-3.16", "RS-3.6"],
    tags=["framing"],
    commands=[C.SET_FRAME_CRC],
)
def no_crc(ctx: Context) -> str:
    """SetFrameCrc(false): later frames on that connection carry NO_CRC and a zero trailer,
    its own reply and other connections keep their CRC; SetFrameCrc(true) restores it."""
    ctx.require(C.SET_FRAME_CRC)
    conn = ctx.connect()
    other = ctx.connect()
    # The harness decoder checks CRCs: a reply arriving here had a valid one.
    enabled = conn.ask(M.SetFrameCrcRequest(False)).enabled
    if enabled is not False:
        raise Fail("SetFrameCrc(false) did not report CRCs off", "enabled false", enabled)
    _no_crc_ping(ctx, conn, 501, no_crc=True)
    _no_crc_ping(ctx, other, 502, no_crc=False)
    # The reply to SetFrameCrc(true) still goes out without CRC, the next one with it.
    conn.decoder.accept_no_crc = True
    enabled = conn.ask(M.SetFrameCrcRequest(True)).enabled
    conn.decoder.accept_no_crc = False
    if enabled is not True:
        raise Fail("SetFrameCrc(true) did not report CRCs on", "enabled true", enabled)
    _no_crc_ping(ctx, conn, 503, no_crc=False)
    return "NO_CRC frames after SetFrameCrc(false); CRCs back after SetFrameCrc(true)"
