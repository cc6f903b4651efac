"""Wire-logging connections: raw TCP and UDP sockets driven with the spec codec.

Every send and receive is recorded (direction, time offset from the case start, bytes) so a
failure can show the bytes exchanged. The harness never uses a client library: it writes
frames with :func:`spec.codec.encode_packet` or by hand, and reads them with
:class:`spec.codec.FrameDecoder`.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

from conformance.model import EndpointGone, EndpointTimeout, Fail, WireEntry
from spec import wire
from spec.codec import FrameDecoder, Packet, Rejected, encode_packet, request
from spec.errors import ErrorCode, PeerError, ProtocolError
from spec.messages import REPLIES, MessageError, Reply, Request
from spec.params import Value
from spec.registry import BY_ID, CommandId
from spec.wire import PacketKind

R = TypeVar("R", bound=Reply)

MAX_LOG_ENTRIES = 200  # per case
#: The idle timeout (s) of an endpoint that did not say its own in Hello [RS-7.6].
DEFAULT_IDLE_TIMEOUT = 300.0
KEEP_ALIVE_PAYLOAD = b"conformance-keep-alive"
MAX_LOG_BYTES = 4096  # bytes kept of one send or receive


@dataclass
class WireLog:
    """The bytes a case exchanged, bounded in size."""

    start: float = field(default_factory=time.monotonic)
    entries: list[WireEntry] = field(default_factory=list)
    dropped: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add(self, direction: str, conn: int, data: bytes, note: str = "") -> None:
        with self._lock:
            if len(self.entries) >= MAX_LOG_ENTRIES:
                self.dropped += 1
                return
            if len(data) > MAX_LOG_BYTES:
                note = f"{note} (first {MAX_LOG_BYTES} of {len(data)} bytes)".strip()
                data = data[:MAX_LOG_BYTES]
            self.entries.append(
                WireEntry(time.monotonic() - self.start, direction, conn, data, note)
            )


def _not_a_frame(exc: PeerError) -> Fail:
    """The verdict when the endpoint's bytes cannot be framed at all [RS-3.1]."""
    return Fail(
        "the endpoint sent bytes that are not a frame",
        "a frame starting with 52 53 and a usable header",
        str(exc),
        requirement="RS-3.1",
    )


class Closed(Exception):
    """The endpoint closed the connection (EOF or reset)."""


#: What a :class:`Conn` call raises when the endpoint (not the harness) misbehaves: the
#: socket's errors, a close, no answer in time, a broken answer. Cleanup and liveness code
#: catches these, never a blind ``Exception`` that would hide a harness bug.
ENDPOINT_ERRORS: tuple[type[Exception], ...] = (
    OSError,
    Closed,
    EndpointTimeout,
    EndpointGone,
    Fail,
    ProtocolError,
)


class Conn:
    """One logged TCP connection to the endpoint under test."""

    def __init__(self, sock: socket.socket, log: WireLog, number: int, timeout: float) -> None:
        self.sock = sock
        self.log = log
        self.number = number
        self.timeout = timeout
        self.decoder = FrameDecoder(
            max_payload=wire.MAX_PAYLOAD,
            kinds=frozenset({PacketKind.REPLY, PacketKind.ERROR, PacketKind.EVENT}),
        )
        self.events_seen = 0
        #: The minor protocol version in the header of the endpoint's last reply or error
        #: frame (None before the first), for rules that compare a field with it [RS-5.31].
        self.version_minor: int | None = None
        self.closed = False
        #: Control lease (s) the endpoint granted this connection, None when it has none.
        self.lease: float | None = None
        self._next_id = 1
        #: Requests sent on this connection and not answered yet: request ID -> command ID.
        #: A late answer to one of them is never taken for the answer to a later request.
        self.pending: dict[int, int] = {}
        #: Set by the context: True when the endpoint still answers on a new connection.
        self.alive: Callable[[], bool] | None = None
        #: Set by the context: the run's liveness probe (Hello when Ping is not answered).
        self.probe_command: int = CommandId.PING
        #: Set by the context from Hello: the endpoint closes the connection after this long
        #: without a frame from the harness [RS-7.6]; :meth:`keep_alive` stays within it.
        self.idle_timeout = DEFAULT_IDLE_TIMEOUT
        #: When the harness last sent on this connection (time.monotonic()).
        self.last_sent = time.monotonic()
        #: Request IDs of keep-alive Pings not answered yet: their answers are passed over.
        self._keep_alive_ids: set[int] = set()

    # --- raw bytes ---------------------------------------------------------------------------

    def send(self, data: bytes, note: str = "") -> None:
        self.log.add("->", self.number, data, note)
        try:
            self.sock.sendall(data)
        except OSError as exc:
            self.log.add("--", self.number, b"", f"send failed: {exc}")
            raise EndpointGone(f"connection lost while sending: {exc}") from None
        self.last_sent = time.monotonic()

    def send_bytewise(self, data: bytes, note: str = "") -> None:
        """Send one byte per TCP segment (TCP_NODELAY and a short pause between bytes)."""
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.log.add("->", self.number, data, f"{note} (one byte per segment)".strip())
        for i in range(len(data)):
            try:
                self.sock.sendall(data[i : i + 1])
            except OSError as exc:
                raise EndpointGone(f"connection lost while sending byte {i}: {exc}") from None
            time.sleep(0.0005)
        self.last_sent = time.monotonic()

    def keep_alive(self) -> None:
        """A Ping when the harness has sent nothing for half the endpoint's idle timeout, so
        that a case busy elsewhere (playing the sensor over UDP, waiting for an effect) is
        not closed as idle [RS-7.6]: a conforming client lives with the timeout the endpoint
        announces. Not waited for, so it never delays the caller: the next call passes its
        answer over."""
        if not self.closed and time.monotonic() - self.last_sent >= self.idle_timeout / 2:
            rid = self.request(CommandId.PING, KEEP_ALIVE_PAYLOAD)
            self._keep_alive_ids.add(rid)

    def pause(self, seconds: float) -> None:
        """Sleep ``seconds`` with the connection kept alive (:meth:`keep_alive`)."""
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.keep_alive()
            time.sleep(min(left, self.idle_timeout / 4))

    def next_request_id(self) -> int:
        """A request ID not used before on this connection [RS-3.13] (IDs 1..2^32-1)."""
        rid = self._next_id
        self._next_id = rid % 0xFFFFFFFF + 1
        return rid

    def request(self, command: int, *params: Value, request_id: int | None = None) -> int:
        """Send one request frame; return its request ID. An explicit ``request_id`` (a case
        that tests ID handling) moves the counter past it, so later requests stay fresh."""
        if request_id is None:
            rid = self.next_request_id()
        else:
            rid = request_id
            if rid >= self._next_id:
                self._next_id = rid % 0xFFFFFFFF + 1
        name = BY_ID[command].name if command in BY_ID else f"0x{command:04x}"
        self.send(encode_packet(request(command, rid, *params)), f"request {name} id {rid}")
        self.pending[rid] = command
        return rid

    def answer_to(self, command: int, request_id: int, timeout: float | None = None) -> Packet:
        """The answer to the request (``command``, ``request_id``) [RS-3.4]: answers to this
        connection's earlier, still unanswered requests are passed over (logged), anything
        else that does not echo both IDs is a Fail of RS-3.4."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            answer = self._recv(max(deadline - time.monotonic(), 0.0))
            if answer.request_id == request_id and answer.command == command:
                self.pending.pop(request_id, None)
                return answer
            earlier = self.pending.get(answer.request_id)
            if answer.request_id != request_id and earlier == answer.command:
                del self.pending[answer.request_id]
                if answer.request_id in self._keep_alive_ids:
                    self._keep_alive_ids.discard(answer.request_id)
                else:
                    self.log.add("--", self.number, b"", f"late answer to id {answer.request_id}")
                continue
            check_echo(answer, command, request_id)

    def _fill(self, deadline: float) -> None:
        """Read once from the socket; raise EndpointTimeout at the deadline, Closed on EOF."""
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise EndpointTimeout("no answer from the endpoint in time")
        self.sock.settimeout(remaining)
        try:
            chunk = self.sock.recv(1 << 20)
        except TimeoutError:
            raise EndpointTimeout("no answer from the endpoint in time") from None
        except OSError as exc:
            self.closed = True
            self.log.add("--", self.number, b"", f"connection reset: {exc}")
            raise Closed(str(exc)) from None
        if not chunk:
            self.closed = True
            self.log.add("--", self.number, b"", "closed by the endpoint")
            raise Closed("closed by the endpoint")
        self.log.add("<-", self.number, chunk)
        try:
            self.decoder.feed(chunk)
        except PeerError as exc:
            raise _not_a_frame(exc) from None

    def recv_packet(self, timeout: float | None = None) -> Packet:
        """The next reply or error frame (event frames are counted and skipped [RS-3.14];
        answers to :meth:`keep_alive` Pings too)."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            packet = self._recv(max(deadline - time.monotonic(), 0.0))
            if self.pending.get(packet.request_id) == packet.command:
                del self.pending[packet.request_id]
                if packet.request_id in self._keep_alive_ids:
                    self._keep_alive_ids.discard(packet.request_id)
                    continue
            return packet

    def _recv(self, timeout: float | None) -> Packet:
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            try:
                event = self.decoder.next_event()
            except PeerError as exc:
                raise _not_a_frame(exc) from None
            if isinstance(event, Rejected):
                raise Fail(
                    f"the endpoint sent a malformed frame ({event.code.name})",
                    "a well-formed reply or error frame (valid CRC-32, version 1, kind 2/3/4)",
                    event.error.message,
                    requirement="RS-3.6" if event.code is ErrorCode.BAD_CRC else "RS-3.1",
                )
            if isinstance(event, Packet):
                if event.kind is PacketKind.EVENT:
                    self.events_seen += 1
                    continue
                if event.kind is PacketKind.ERROR:
                    check_error_shape(event)
                self.version_minor = event.version_minor
                return event
            self._fill(deadline)

    def expect_closed(self, timeout: float | None = None) -> list[Packet]:
        """Read until the endpoint closes; return the frames received before. Raise
        EndpointTimeout when it stays open."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        packets: list[Packet] = []
        while True:
            try:
                packets.append(self.recv_packet(max(deadline - time.monotonic(), 0.0)))
            except Closed:
                return packets

    def quiet(self, wait: float) -> list[Packet]:
        """Frames that arrive within ``wait`` seconds (none expected, usually)."""
        packets: list[Packet] = []
        deadline = time.monotonic() + wait
        while True:
            try:
                packets.append(self.recv_packet(max(deadline - time.monotonic(), 0.0)))
            except (EndpointTimeout, Closed):
                return packets

    # --- request / answer --------------------------------------------------------------------

    def call(self, command: int, *params: Value, timeout: float | None = None) -> Packet:
        """Send a request and return its answer (reply or error), checking the echo [RS-3.4]."""
        rid = self.request(command, *params)
        try:
            answer = self.answer_to(command, rid, timeout)
        except Closed as exc:
            name = BY_ID[command].name if command in BY_ID else f"0x{command:04x}"
            if self.alive is not None and self.alive():
                # The endpoint lives on: closing instead of answering breaks [RS-6.2].
                raise Fail(
                    f"the endpoint closed the connection instead of answering {name}",
                    "exactly one reply or error frame",
                    f"connection closed ({exc})",
                    requirement="RS-6.2",
                ) from None
            raise EndpointGone(
                f"the endpoint closed the connection instead of answering: {exc}"
            ) from None
        return answer

    def ok(self, command: int, *params: Value, timeout: float | None = None) -> tuple[Value, ...]:
        """Call and require a reply whose parameters match the command's reply table [RS-5.5];
        :meth:`ask` gives the reply as its typed message."""
        answer = self._replied(command, params, timeout)
        cls = REPLIES.get(command)
        if cls is not None:
            typed_reply(cls, answer.params)
        return answer.params

    def ask(self, message: Request[R], timeout: float | None = None) -> R:
        """Send a typed request and return its typed reply: a refusal is a Fail, and so is a
        reply whose parameters do not match the command's reply table [RS-5.5]."""
        answer = self._replied(message.command, message.encode(), timeout)
        return typed_reply(message.reply_type(), answer.params)

    def _replied(self, command: int, params: tuple[Value, ...], timeout: float | None) -> Packet:
        answer = self.call(command, *params, timeout=timeout)
        if answer.kind is PacketKind.ERROR:
            name = BY_ID[command].name if command in BY_ID else f"0x{command:04x}"
            code, message = answer.error or (0, "")
            raise Fail(
                f"{name} was refused",
                "a reply",
                f"error {_code_name(code)}: {message}",
            )
        return answer

    def error(
        self,
        command: int,
        code: int | tuple[int, ...],
        *params: Value,
        timeout: float | None = None,
    ) -> Packet:
        """Call and require an error frame with ``code`` (or one of several codes)."""
        answer = self.call(command, *params, timeout=timeout)
        expect_code(answer, code)
        return answer

    def close(self) -> None:
        if not self.closed:
            self.log.add("--", self.number, b"", "closed by the harness")
        self.closed = True
        try:
            self.sock.close()
        except OSError:
            pass


def typed_reply(cls: type[R], params: tuple[Value, ...]) -> R:
    """The reply message ``cls`` of ``params``; parameters that do not match the command's
    reply table (count, or a field's type) are the endpoint's Fail of [RS-5.5], never a
    harness fault."""
    try:
        return cls.decode(params)
    except MessageError as exc:
        raise Fail(
            f"{cls.what} parameters do not match the reply table",
            ", ".join(f"{p.name}:{p.type.name}" for p in cls.table) or "none",
            exc.message,
            requirement="RS-5.5",
        ) from None


def _code_name(code: int) -> str:
    try:
        return ErrorCode(code).name
    except ValueError:
        return f"code {code}"


def codes_text(code: int | tuple[int, ...]) -> str:
    codes = code if isinstance(code, tuple) else (code,)
    return " or ".join(_code_name(c) for c in codes)


def expect_code(answer: Packet, code: int | tuple[int, ...]) -> None:
    codes = code if isinstance(code, tuple) else (code,)
    got = answer.error
    if got is None:
        raise Fail(
            "the request was accepted where an error was required",
            f"error {codes_text(code)}",
            f"{answer.kind.name} with {len(answer.params)} parameter(s)",
        )
    if got[0] not in codes:
        raise Fail(
            "wrong error code",
            f"error {codes_text(code)}",
            f"error {_code_name(got[0])}: {got[1]}",
        )


def check_echo(answer: Packet, command: int, request_id: int) -> None:
    """[RS-3.4] an answer carries the command ID and request ID of its request."""
    if answer.request_id != request_id or answer.command != command:
        raise Fail(
            "the answer does not echo the request's command ID and request ID",
            f"command 0x{command:04x}, request ID {request_id}",
            f"command 0x{answer.command:04x}, request ID {answer.request_id} ({answer.kind.name})",
            requirement="RS-3.4",
        )


def check_error_shape(packet: Packet) -> None:
    """[RS-6.1] an error frame carries exactly (INT code, STRING message) with a known code."""
    p = packet.params
    code = p[0] if p and type(p[0]) is not bool and isinstance(p[0], int) else None
    if code is None or len(p) != 2 or not isinstance(p[1], str):
        raise Fail(
            "an error frame does not carry (INT code, STRING message)",
            "2 parameters: INT, STRING",
            f"{len(p)} parameter(s): {[type(v).__name__ for v in p]}",
            requirement="RS-6.1",
        )
    if code not in set(int(c) for c in ErrorCode):
        raise Fail(
            "an error frame carries a code outside the error table",
            "a code of PROTOCOL.md section 6 (1..19)",
            str(code),
            requirement="RS-6.1",
        )


class UdpConn:
    """One logged UDP socket talking to the sensor's trigger endpoint."""

    def __init__(
        self, sock: socket.socket, target: tuple[str, int], log: WireLog, number: int
    ) -> None:
        self.sock = sock
        self.target = target
        self.log = log
        self.number = number

    def send(self, data: bytes, note: str = "") -> float:
        """Send one datagram; return the monotonic send time (s)."""
        self.log.add("->", self.number, data, note)
        t = time.monotonic()
        self.sock.sendto(data, self.target)
        return t

    def recv(self, timeout: float) -> tuple[bytes, tuple[str, int], float] | None:
        """One datagram, its source and monotonic arrival time, or None after ``timeout``."""
        if timeout <= 0:
            return None
        self.sock.settimeout(timeout)
        try:
            data, source = self.sock.recvfrom(65536)
        except TimeoutError:
            return None
        except OSError as exc:  # e.g. ICMP port unreachable reported on Linux
            self.log.add("--", self.number, b"", f"receive failed: {exc}")
            raise EndpointGone(f"UDP endpoint unreachable: {exc}") from None
        t = time.monotonic()
        self.log.add("<-", self.number, data)
        return data, (str(source[0]), int(source[1])), t

    def collect(self, wait: float) -> list[tuple[bytes, tuple[str, int], float]]:
        """Every datagram arriving within ``wait`` seconds."""
        out: list[tuple[bytes, tuple[str, int], float]] = []
        deadline = time.monotonic() + wait
        while True:
            got = self.recv(deadline - time.monotonic())
            if got is None:
                return out
            out.append(got)

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass
