"""Client base for both services: connect, send requests, turn error packets into exceptions.

``RobotClient`` and ``SensorClient`` add one method per command on top of :class:`FramedClient`.
"""

from __future__ import annotations

import socket
import threading
import time
from types import TracebackType

from spec import wire
from spec.codec import FrameDecoder, Packet, encode_packet, request
from spec.errors import ErrorCode, PeerError, ProtocolError, RemoteError
from spec.params import IntArray, Value
from spec.registry import BY_ID, CommandId, check_params
from spec.wire import PacketKind


class ClientTimeout(ProtocolError, TimeoutError):
    """No complete reply within the client's read timeout."""

    code = ErrorCode.TIMEOUT


class ConnectionClosed(ProtocolError, ConnectionError):
    """The server closed the connection."""

    code = ErrorCode.INTERNAL_ERROR


class FramedClient:
    """A blocking client for one TCP connection; thread-safe (one request at a time).

    ``timeout`` bounds connect and every reply; ``auto_reconnect`` reconnects once on a broken
    connection before a request is sent.
    """

    def __init__(
        self,
        host: str,
        port: int,
        *,
        timeout: float = 5.0,
        auto_reconnect: bool = False,
        client_name: str = "reference-client/0.1",
    ) -> None:
        self.host = host
        self.port = port
        self.timeout = timeout
        self.auto_reconnect = auto_reconnect
        self.client_name = client_name
        self._sock: socket.socket | None = None
        self._decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
        self._next_id = 1
        self._scratch = bytearray(1 << 18)  # reused receive buffer: no allocation per recv
        self._lock = threading.RLock()
        self.server_info: dict[str, Value] = {}
        self.connect()

    # --- connection --------------------------------------------------------------------------

    def connect(self) -> None:
        with self._lock:
            self.close()
            try:
                sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
            except TimeoutError:
                raise ClientTimeout(f"connect to {self.host}:{self.port} timed out") from None
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._sock = sock
            self._decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)

    def reconnect(self) -> None:
        """Open a new connection (control, if it was held, must be taken again)."""
        self.connect()

    def close(self) -> None:
        with self._lock:
            if self._sock is not None:
                try:
                    self._sock.close()
                finally:
                    self._sock = None

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
        error packet, :class:`ClientTimeout`, :class:`ConnectionClosed` or :class:`PeerError`."""
        with self._lock:
            if self._sock is None:
                if not self.auto_reconnect:
                    raise ConnectionClosed("not connected")
                self.connect()
            request_id = self._next_id
            self._next_id = (self._next_id % 0xFFFFFFFF) + 1
            data = encode_packet(request(command, request_id, *params))
            try:
                self._send(data)
            except OSError:
                if not self.auto_reconnect:
                    raise
                self.connect()
                self._send(data)
            reply = self._receive(timeout if timeout is not None else self.timeout)
        return self._check_reply(command, request_id, reply)

    def _send(self, data: bytes) -> None:
        assert self._sock is not None
        self._sock.sendall(data)

    def _receive(self, timeout: float) -> Packet:
        assert self._sock is not None
        deadline = time.monotonic() + timeout
        while True:
            event = self._decoder.next_event()
            if event is not None:
                if isinstance(event, Packet):
                    if event.kind is PacketKind.EVENT:
                        continue  # [RS-3.14] an event is never the reply to a request
                    return event
                self.close()
                raise event.error
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                self.close()  # a late reply would be mistaken for the next one
                raise ClientTimeout(f"no reply within {timeout:.3g} s")
            self._sock.settimeout(remaining)
            try:
                n = self._sock.recv_into(self._scratch)
            except TimeoutError:
                continue
            except OSError as exc:
                self.close()
                raise ConnectionClosed(f"connection lost: {exc}") from None
            if not n:
                self.close()
                raise ConnectionClosed("server closed the connection")
            try:
                with memoryview(self._scratch) as view, view[:n] as chunk:
                    self._decoder.feed(chunk)
            except PeerError:
                self.close()
                raise

    def _check_reply(self, command: int, request_id: int, reply: Packet) -> tuple[Value, ...]:
        if reply.kind is PacketKind.ERROR:
            code, message = reply.error or (0, "")
            if reply.request_id in (request_id, 0):
                raise RemoteError(code, message, reply.command, reply.request_id)
        if reply.request_id != request_id or reply.command != command:
            self.close()
            raise PeerError(
                f"reply does not match request: expected command 0x{command:04x} id "
                f"{request_id}, got 0x{reply.command:04x} id {reply.request_id}"
            )
        if reply.kind is not PacketKind.REPLY:
            self.close()
            raise PeerError(f"expected a REPLY packet, got {reply.kind.name}")
        spec = BY_ID.get(command)
        if spec is not None:
            check_params(spec.reply, reply.params, f"{spec.name} reply", allow_extra=True)
        return reply.params

    # --- common commands ---------------------------------------------------------------------

    def hello(self) -> dict[str, Value]:
        """Negotiate (Hello) and return what the server reports about itself."""
        values = self.call(
            CommandId.HELLO, wire.VERSION_MAJOR, wire.VERSION_MINOR, self.client_name
        )
        names = [p.name for p in BY_ID[CommandId.HELLO].reply]
        info = dict(zip(names, values, strict=False))
        commands = info.get("commands")
        if isinstance(commands, IntArray):
            info["commands"] = commands
        self.server_info = info
        return info

    def ping(self, data: bytes = b"") -> bytes:
        (echo,) = self.call(CommandId.PING, data)
        assert isinstance(echo, bytes)
        return echo

    def take_control(self, token: str = "") -> None:
        self.call(CommandId.TAKE_CONTROL, token)

    def release_control(self) -> None:
        self.call(CommandId.RELEASE_CONTROL)

    def get_time(self) -> float:
        (t,) = self.call(CommandId.GET_TIME)
        assert isinstance(t, float)
        return t


__all__ = ["ClientTimeout", "ConnectionClosed", "FramedClient", "RemoteError"]
