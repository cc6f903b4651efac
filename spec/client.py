"""Client base for both services: connect, send requests, turn error packets into exceptions.

``RobotClient`` and ``SensorClient`` add one method per command on top of :class:`FramedClient`.

Two safety duties live here (PROTOCOL.md 7.1): while the client holds control it keeps the
control lease alive on its own (a Ping whenever nothing else was sent for a third of the
watchdog period) [RS-7.13]; and a request abandoned half-way (Ctrl-C) leaves its request ID
behind, so its late reply is dropped instead of being taken for the next one's.
"""

from __future__ import annotations

import itertools
import os
import re
import socket
import threading
import time
from dataclasses import dataclass
from types import TracebackType
from typing import NoReturn, TypeVar

from spec import wire
from spec.codec import FrameDecoder, Packet, encode_request
from spec.errors import ErrorCode, PeerError, ProtocolError, RemoteError
from spec.messages import (
    GetTimeReply,
    HelloReply,
    PingReply,
    Reply,
    Request,
    TakeControlReply,
    WaitEndMoveReply,
)
from spec.params import Value
from spec.realtime import promote_current_thread
from spec.record import SessionRecorder
from spec.registry import BY_ID, CommandId, check_params, exact_classes
from spec.sockopt import set_kernel_timeouts
from spec.wire import MoveOutcome, PacketKind

#: SCHED_FIFO priority of the control-lease keeper: below the robot's own timing threads (50)
#: and command threads (40) when both run on one host.
KEEPER_PRIORITY = 30

R = TypeVar("R", bound=Reply)


class ClientTimeout(ProtocolError, TimeoutError):
    """No complete reply within the client's read timeout."""

    code = ErrorCode.TIMEOUT


class ConnectionClosed(ProtocolError, ConnectionError):
    """The server closed the connection."""

    code = ErrorCode.INTERNAL_ERROR


#: The longest TakeControl back-off a client waits out by itself (s); a longer one is said.
MAX_BACK_OFF_WAIT_S = 2.0
_RETRY_IN = re.compile(r"retry in (\d+(?:\.\d+)?) s")


def _back_off(exc: RemoteError) -> float | None:
    """The wait an AUTH_FAILED back-off asks for [RS-7.20] when short enough, else None."""
    m = _RETRY_IN.search(exc.message) if exc.code is ErrorCode.AUTH_FAILED else None
    if m is None or float(m.group(1)) > MAX_BACK_OFF_WAIT_S:
        return None
    return float(m.group(1)) + 0.01  # the message rounds to 0.01 s


class FramedClient:
    """A blocking client for one TCP connection; thread-safe (one request at a time).

    ``timeout`` bounds connect and every reply; ``auto_reconnect`` reconnects once on a broken
    connection before a request is sent. ``frame_crc=False`` asks the server to send its frames
    without CRC (SetFrameCrc, PROTOCOL.md 3.1) on each connection: for bulk transfers on a
    trusted link; a server without SetFrameCrc keeps its CRCs (see :attr:`frame_crc_active`).
    """

    #: Port used when none is given (a service's default, e.g. 4000 for RobotSocket).
    DEFAULT_PORT: int | None = None
    #: Client name sent in Hello unless one is given.
    CLIENT_NAME = "reference-client/0.1"

    def __init__(
        self,
        host: str,
        port: int | None = None,
        *,
        timeout: float = 5.0,
        auto_reconnect: bool = False,
        client_name: str | None = None,
        frame_crc: bool = True,
        record: str | os.PathLike[str] | SessionRecorder | None = None,
    ) -> None:
        if port is None:
            if self.DEFAULT_PORT is None:
                raise TypeError(f"{type(self).__name__} needs a port")
            port = self.DEFAULT_PORT
        self.host = host
        self.port = port
        self.timeout = timeout
        self.auto_reconnect = auto_reconnect
        self.client_name = self.CLIENT_NAME if client_name is None else client_name
        self.frame_crc = frame_crc
        self._sock: socket.socket | None = None
        self._kernel_timeout: float | None = None  # SO_RCVTIMEO in force, None: Python's
        self._decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
        # next() of an itertools.count is atomic: the lease keeper takes IDs beside a call.
        self._ids = itertools.count()
        self._send_lock = threading.Lock()
        self._scratch = bytearray(1 << 18)  # reused receive buffer: no allocation per recv
        self._scratch_view = memoryview(self._scratch)
        self._lock = threading.RLock()
        self.server_info: dict[str, Value] = {}
        #: Request IDs whose reply was not waited for (interrupted): dropped when they come.
        self._abandoned: set[int] = set()
        #: Control lease in force (s) while this client holds control, else None.
        self.lease: float | None = None
        self._last_sent = 0.0
        self._keeper: threading.Thread | None = None
        self._keeper_stop = threading.Event()
        #: The pcapng recording of this client's connections (``record``): a file name starts
        #: one, ended by :meth:`close`; a :class:`SessionRecorder` is shared (its owner ends it).
        self.recorder: SessionRecorder | None = None
        self._owns_recorder = False
        self._flow = 0
        if record is not None:
            if isinstance(record, SessionRecorder):
                self.recorder = record
            else:
                comment = f"{self.client_name} to {host}:{port}"
                self.recorder = SessionRecorder(record, comment, self.client_name)
                self._owns_recorder = True
        try:
            self.connect()
        except BaseException:
            self.close()
            raise

    # --- connection --------------------------------------------------------------------------

    def connect(self) -> None:
        with self._lock:
            self._disconnect()
            try:
                sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
            except TimeoutError:
                raise ClientTimeout(f"connect to {self.host}:{self.port} timed out") from None
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._sock = sock
            if self.recorder is not None:
                here, there = sock.getsockname()[:2], sock.getpeername()[:2]
                self._flow = self.recorder.open_tcp(here, there)
            self._decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
            self._kernel_timeout = None
            self._abandoned.clear()
            if not self.frame_crc:
                self._turn_frame_crc_off()

    def _turn_frame_crc_off(self) -> None:
        try:
            (enabled,) = self.call(CommandId.SET_FRAME_CRC, False)
        except RemoteError as exc:
            if exc.code not in (ErrorCode.NOT_SUPPORTED, ErrorCode.UNKNOWN_COMMAND):
                raise
            return  # a server without it (1.0: unknown): its frames keep their CRC [RS-3.15]
        # The reply came with a CRC; every later frame carries NO_CRC [RS-3.16], [RS-3.17].
        self._decoder.accept_no_crc = not enabled

    @property
    def frame_crc_active(self) -> bool:
        """False when the server sends this connection's frames without CRC."""
        return not self._decoder.accept_no_crc

    def reconnect(self) -> None:
        """Open a new connection (control, if it was held, must be taken again)."""
        self.connect()

    def close(self) -> None:
        """Close the connection; a recording this client started is complete now."""
        self._disconnect()
        if self._owns_recorder and self.recorder is not None:
            self.recorder.close()

    def _disconnect(self) -> None:
        self._stop_keeper()
        with self._lock:
            self.lease = None
            if self._sock is not None:
                try:
                    self._sock.close()
                finally:
                    self._sock = None
                    if self.recorder is not None:
                        self.recorder.close_tcp(self._flow, True)
                        self.recorder.forget_tcp(self._flow)

    @property
    def connected(self) -> bool:
        return self._sock is not None

    def __enter__(self) -> FramedClient:
        return self

    def __exit__(
        self, et: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # --- requests ----------------------------------------------------------------------------

    def call(self, command: int, *params: Value, timeout: float | None = None) -> tuple[Value, ...]:
        """Send one request and return the reply's parameters; raise :class:`RemoteError` for an
        error packet, :class:`ClientTimeout`, :class:`ConnectionClosed` or :class:`PeerError`.
        An interrupted call (KeyboardInterrupt) leaves the connection usable: its reply is
        dropped when it arrives."""
        with self._lock:
            if self._sock is None:
                if not self.auto_reconnect:
                    raise ConnectionClosed("not connected")
                self.connect()
            request_id = self._new_request_id()
            data = encode_request(command, request_id, params)
            # Marked abandoned until its reply is read: an interruption anywhere from here on
            # (Ctrl-C between the send and the wait too) leaves its late reply to be dropped.
            self._abandoned.add(request_id)
            try:
                self._send(data)
            except OSError:
                if not self.auto_reconnect:
                    raise
                self.connect()
                self._abandoned.add(request_id)
                self._send(data)
            wait = timeout if timeout is not None else self.timeout
            reply = self._receive(wait, command, request_id)
            self._abandoned.discard(request_id)
        kind, reply_command, reply_id, params, _ = reply
        if kind is not _REPLY or reply_id != request_id or reply_command != command:
            self._refuse_reply(command, request_id, reply)  # raises
        expected = _REPLY_PARAMS.get(command)
        # Exactly the declared classes passes check_params (its fast path, without a call).
        if expected is not None and tuple(map(type, params)) != expected[2]:
            check_params(expected[0], params, expected[1], allow_extra=True)
        return params

    def _new_request_id(self) -> int:
        """1, 2, ... 0xFFFFFFFF, then 1 again (0 is never a request's ID)."""
        return next(self._ids) % 0xFFFFFFFF + 1

    def _send(self, data: bytes) -> None:
        sock = self._sock
        assert sock is not None
        try:
            with self._send_lock:  # the lease keeper may send beside a pending call
                sock.sendall(data)
                self._last_sent = time.monotonic()
                if self.recorder is not None:
                    self.recorder.tcp(self._flow, True, data)
        except BlockingIOError:  # the kernel send timeout expired: the server stopped reading
            self._disconnect()
            raise ClientTimeout("the server does not take the request (send timed out)") from None

    # C901 allowed: the reply loop of every call (a hot path), kept in one frame on purpose
    def _receive(  # noqa: C901
        self, timeout: float, command: int = -1, request_id: int = -1
    ) -> Packet:
        sock = self._sock
        assert sock is not None
        deadline = time.monotonic() + timeout
        decoder = self._decoder
        first = True
        # Nothing buffered (the usual case between calls): straight to the socket.
        idle = not decoder.in_frame
        event = None if idle else decoder.next_event()
        while True:
            if event is not None:
                if type(event) is Packet and event[2] == request_id and event[0] is not _EVENT:
                    return event  # the awaited reply (never a limit notice: its ID is 0)
                if not isinstance(event, Packet):
                    self._disconnect()
                    raise self._from_peer(event.error)
                if event.kind is _EVENT:
                    pass  # [RS-3.14] an event is never the reply to a request
                elif event.request_id in self._abandoned and event.request_id != request_id:
                    self._abandoned.discard(event.request_id)  # late reply, interrupted request
                elif not (command == _EMERGENCY_STOP and _is_limit_notice(event)):
                    return event  # a reserved connection still takes EmergencyStop [RS-7.14]
                event = decoder.next_event()
                continue
            remaining = timeout if first else deadline - time.monotonic()
            first = False
            if remaining <= 0:
                self._disconnect()  # a late reply would be mistaken for the next one
                raise ClientTimeout(f"no reply from {self.address} within {timeout:.3g} s")
            current = self._kernel_timeout
            if current is None or current > remaining * 1.1 + 0.01:
                self._arm_timeout(remaining)  # else it overshoots by at most 10 % + 10 ms
            # The rest of a large frame (an image) goes straight into its own buffer.
            view = None if idle else decoder.get_buffer()
            if view is None and not idle:
                decoder.keep()  # the scratch buffer is about to be written again
            idle = False
            try:
                n = sock.recv_into(self._scratch if view is None else view)
            except (TimeoutError, BlockingIOError):
                continue
            except OSError as exc:
                self._disconnect()
                raise ConnectionClosed(f"connection to {self.address} lost: {exc}") from None
            if self.recorder is not None:
                self._record_received(view, n)
            if not n:
                self._disconnect()
                raise ConnectionClosed(f"{self.address} closed the connection")
            if view is not None:
                decoder.buffer_updated(n)
                event = decoder.next_event()
                continue
            try:
                event = decoder.feed_next(self._scratch_view[:n])
            except PeerError as exc:
                self._disconnect()
                raise self._from_peer(exc) from None

    def _record_received(self, view: memoryview | None, n: int) -> None:
        assert self.recorder is not None
        if n:
            self.recorder.tcp(self._flow, False, (self._scratch_view if view is None else view)[:n])
        else:
            self.recorder.close_tcp(self._flow, False)

    @property
    def address(self) -> str:
        """``host:port`` of the server, as messages name it."""
        return f"[{self.host}]:{self.port}" if ":" in self.host else f"{self.host}:{self.port}"

    def _from_peer(self, exc: PeerError) -> PeerError:
        """``exc`` with its message naming the server; bytes that do not even start like a
        frame mean another protocol is listening there (an HTTP server, the wrong port)."""
        hint = (
            " (not a RobotSocket or SensorSocket endpoint?)" if "bad magic" in exc.message else ""
        )
        exc.message = f"{self.address} sent a bad frame: {exc.message}{hint}"
        exc.args = (exc.message,)
        return exc

    def _arm_timeout(self, remaining: float) -> None:
        """Bound the next receive (and send) by about ``remaining`` seconds: a kernel timeout,
        else Python's socket timeout. The caller sets it again only when the one in force is
        clearly longer than what remains (e.g. a call with its own timeout): one system call
        per receive otherwise."""
        assert self._sock is not None
        if set_kernel_timeouts(self._sock, remaining):
            self._kernel_timeout = remaining
        else:
            self._sock.settimeout(remaining)

    def _refuse_reply(self, command: int, request_id: int, reply: Packet) -> NoReturn:
        """Raise for a reply that is not this request's REPLY: the error packet's exception,
        else :class:`PeerError`, closing the connection (its replies are out of step)."""
        if reply.kind is _ERROR:
            code, message = reply.error or (0, "")
            if reply.request_id in (request_id, 0):
                raise self._remote_error(code, message, reply.command, reply.request_id)
        self._disconnect()
        if reply.request_id != request_id or reply.command != command:
            raise PeerError(
                f"reply does not match request: expected command 0x{command:04x} id "
                f"{request_id}, got 0x{reply.command:04x} id {reply.request_id}"
            )
        raise PeerError(f"expected a REPLY packet, got {reply.kind.name}")

    def _remote_error(self, code: int, message: str, command: int, request_id: int) -> RemoteError:
        """The exception an error packet raises (a service's client maps codes to its own
        subclasses here)."""
        return RemoteError(code, message, command, request_id)

    # --- common commands ---------------------------------------------------------------------

    def hello(self, timeout: float | None = None) -> dict[str, Value]:
        """Negotiate (Hello) and return what the server reports about itself; ``timeout``
        (s) bounds this reply alone, e.g. shorter as a connection check."""
        values = self.call(
            CommandId.HELLO, wire.VERSION_MAJOR, wire.VERSION_MINOR, self.client_name,
            timeout=timeout,
        )  # fmt: skip
        info: dict[str, Value] = HelloReply.decode(values).as_dict()
        self.server_info = info
        return info

    def ping(self, data: bytes = b"") -> bytes:
        return PingReply.decode(self.call(_PING, data)).data

    def ask(self, request: Request[R], timeout: float | None = None) -> R:
        """Send a typed request (a class of :mod:`spec.messages`) and return its typed reply:
        every command of the registry, also one without a method of its own here."""
        reply = self.call(request.command, *request.encode(), timeout=timeout)
        return request.reply_type().decode(reply)

    def take_control(self, token: str = "", watchdog: float | None = None) -> float | None:
        """Take control; ``watchdog`` (s) asks for a lease period, else the server's default.
        Returns the period in force (None from a server without the watchdog) and, when
        ``keepalive`` is on, keeps the lease alive from a background thread [RS-7.13]."""
        params: tuple[Value, ...] = (token,) if watchdog is None else (token, float(watchdog))
        try:
            reply = self.call(CommandId.TAKE_CONTROL, *params)
        except RemoteError as exc:
            # [RS-7.20] a back-off after wrong tokens (another client's, or a typo fixed):
            # a short one is waited out and TakeControl asked once more
            wait = _back_off(exc)
            if wait is None:
                raise
            time.sleep(wait)
            reply = self.call(CommandId.TAKE_CONTROL, *params)
        lease = TakeControlReply.decode(reply).watchdog  # None from a 1.0 server
        self.lease = lease
        if lease is not None and self.keepalive:
            self._start_keeper(lease)
        return lease

    def take_control_asking(self, token: str, watchdog: float) -> float | None:
        """:meth:`take_control` asking for ``watchdog`` (s); a server whose leases are
        shorter (OUT_OF_RANGE) gives its default instead. Returns the period in force."""
        try:
            return self.take_control(token, watchdog=watchdog)
        except RemoteError as exc:
            if exc.code is not ErrorCode.OUT_OF_RANGE:
                raise
            return self.take_control(token)

    def release_control(self) -> None:
        self._stop_keeper()
        self.lease = None
        self.call(CommandId.RELEASE_CONTROL)

    # --- the control lease -------------------------------------------------------------------

    #: Keep the control lease alive from a background thread while control is held.
    keepalive = True

    def _start_keeper(self, lease: float) -> None:
        if self._keeper is not None and self._keeper.is_alive():
            return
        self._keeper_stop.clear()
        self._keeper = threading.Thread(
            target=self._keep_lease, args=(lease,), name="control-lease", daemon=True
        )
        self._keeper.start()

    def _stop_keeper(self) -> None:
        self._keeper_stop.set()
        keeper = self._keeper
        if keeper is not None and keeper is not threading.current_thread():
            keeper.join(2.0)
        self._keeper = None

    def _keep_lease(self, lease: float) -> None:
        """A Ping whenever nothing was sent for lease / 3. Idle, it is an ordinary call; while
        a call is in flight (a WaitEndMove piece that a busy or simulated server takes long
        to answer) it is sent beside it and its reply is dropped when it comes."""
        interval = lease / 3
        # Real-time priority where the process may have it: a busy host must not delay the
        # keeper past the lease (a false trip of a live controller). Else it runs as it is.
        promote_current_thread(KEEPER_PRIORITY)
        while not self._keeper_stop.wait(interval / 2):
            if time.monotonic() - self._last_sent < interval:
                continue
            try:
                if self._lock.acquire(blocking=False):
                    try:
                        if self._sock is None or self._keeper_stop.is_set():
                            return
                        self.call(CommandId.PING, b"", timeout=max(self.timeout, lease))
                    finally:
                        self._lock.release()
                else:
                    request_id = self._new_request_id()
                    self._abandoned.add(request_id)
                    if self._sock is None:
                        return
                    self._send(encode_request(CommandId.PING, request_id, (b"",)))
            except (OSError, ProtocolError, AssertionError):
                return  # the connection is gone; the next request will say so

    def get_time(self) -> float:
        return GetTimeReply.decode(self.call(CommandId.GET_TIME)).time


# Enum members as constants: an enum attribute look-up is slow in Python 3.11 and these are
# read on every call.
_EVENT, _ERROR, _REPLY = PacketKind.EVENT, PacketKind.ERROR, PacketKind.REPLY
_EMERGENCY_STOP, _PING = int(CommandId.EMERGENCY_STOP), int(CommandId.PING)
#: Each command's reply parameters, its name in messages and their exact classes, built once.
_REPLY_PARAMS = {
    int(cid): (spec.reply, f"{spec.name} reply", exact_classes(spec.reply))
    for cid, spec in BY_ID.items()
}


@dataclass(frozen=True)
class MoveResult:
    """How the last queued move ended [RS-5.50]: ``reason`` names what stopped or failed it."""

    outcome: MoveOutcome
    reason: str = ""

    @property
    def reached(self) -> bool:
        return self.outcome is MoveOutcome.REACHED

    @classmethod
    def from_reply(cls, reply: tuple[Value, ...]) -> MoveResult:
        """WaitEndMove's reply; a 1.2 server sends ``done`` only (reached or still moving)."""
        r = WaitEndMoveReply.decode(reply)
        done = r.done
        if r.outcome is None:
            return cls(MoveOutcome.REACHED if done else MoveOutcome.MOVING)
        reason = r.reason or ""
        try:
            outcome = MoveOutcome(r.outcome)
        except ValueError:
            return cls(MoveOutcome.FAILED, f"unknown outcome {r.outcome!r}: {reason}".rstrip(": "))
        if outcome is MoveOutcome.REACHED and not done:  # contradicts itself: not reached
            return cls(MoveOutcome.FAILED, "outcome reached but done false")
        return cls(outcome, reason)


def wait_move(client: FramedClient, timeout: float) -> MoveResult:
    """WaitEndMove for up to ``timeout`` s, sent in pieces shorter than half the control
    lease, so a controller waiting for a long move keeps its lease [RS-7.13]. The pieces add
    up to ``timeout`` on the robot's clock (simulated or real); the result says whether the
    last move reached its target, was stopped or failed (and why), or is still moving."""
    remaining = float(timeout)
    while True:
        lease = client.lease
        piece = remaining if lease is None else min(remaining, lease / 2)
        reply = client.call(CommandId.WAIT_END_MOVE, piece, timeout=piece + client.timeout)
        result = MoveResult.from_reply(reply)
        remaining -= piece
        if result.outcome is not MoveOutcome.MOVING or remaining <= 1e-9:
            return result


def wait_end_move(client: FramedClient, timeout: float) -> bool:
    """:func:`wait_move`: True only when the last move reached its target [RS-5.50]."""
    return wait_move(client, timeout).reached


def _is_limit_notice(packet: Packet) -> bool:
    """The unsolicited BUSY (request ID 0) of a server at its client limit [RS-7.2]."""
    return (
        packet.kind is PacketKind.ERROR
        and packet.request_id == 0
        and packet.error is not None
        and packet.error[0] == ErrorCode.BUSY
    )


__all__ = [
    "ClientTimeout",
    "ConnectionClosed",
    "FramedClient",
    "MoveResult",
    "RemoteError",
    "wait_end_move",
    "wait_move",
]
