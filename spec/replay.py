"""Replay a recorded session against an endpoint and say where its answers differ.

``python -m spec replay session.pcapng --robot HOST:PORT`` takes every connection of the
capture whose client spoke to a robot (``--sensor`` for the sensor's), sends the client's
requests again, byte for byte and one at a time, and compares each answer with the recorded
one: its kind (reply or error), error code, parameter types and values (floats within
``--tolerance``), and its response time (slower than recorded by more than
``--time-tolerance``). Values the registry documents as clock readings ("... clock") are not
compared (they differ on every run); ``--ignore Command.param`` leaves out more.

Exit codes: 0 every answer as recorded, 1 differences, 2 a bad command line or capture, 3 the
endpoint could not be reached or dropped the connection where the recording did not.

Safety: a recording holding commands that move the arm or switch an output is replayed only
with ``--allow-motion`` (it may be a real robot).
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from spec import wire
from spec.codec import FrameDecoder, Header, Packet, Rejected
from spec.errors import ErrorCode, PeerError
from spec.params import FloatArray, Image, IntArray, Joints, Location, Matrix, Transform, Value
from spec.pcapng import TcpStream, read_capture, sessions
from spec.registry import BY_ID, ParamSpec
from spec.wire import PacketKind

#: How long to wait for an answer to a request the recording holds none for (s).
UNANSWERED_WAIT = 1.0


class ReplayError(ValueError):
    """A capture that cannot be replayed (the message says why)."""


@dataclass
class Exchange:
    """One recorded request, its frame, and the answer it got (None: none recorded)."""

    request: Packet
    frame: bytes
    sent_ns: int
    answer: Packet | None = None
    answer_ns: int = 0

    @property
    def name(self) -> str:
        spec = BY_ID.get(self.request.command)
        return spec.name if spec else f"0x{self.request.command:04x}"

    @property
    def recorded_time(self) -> float | None:
        return (self.answer_ns - self.sent_ns) / 1e9 if self.answer is not None else None


@dataclass
class Connection:
    """The client's side of one recorded connection."""

    client: str
    server: str
    service: str | None
    exchanges: list[Exchange] = field(default_factory=list)


def _frames(stream: TcpStream, from_a: bool) -> list[tuple[Packet | Rejected, bytes, int]]:
    """Every frame one side sent: (event, its bytes, the time its last byte was captured)."""
    decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
    out: list[tuple[Packet | Rejected, bytes, int]] = []
    pending = bytearray()
    for stamp, side, data in stream.chunks:
        if side != from_a:
            continue
        pending += data
        try:
            decoder.feed(data)
            events = list(decoder.events())
        except PeerError:
            break  # the boundary is lost: the rest is garbage, as the server saw it
        for event in events:
            size = wire.FRAME_OVERHEAD + Header.unpack(pending).length
            out.append((event, bytes(pending[:size]), stamp))
            del pending[:size]
    return out


def _service(packets: Iterable[Packet]) -> str | None:
    for p in packets:
        hello = p.command == 0x0001 and p.kind is PacketKind.REPLY and len(p.params) > 1
        if hello and p.params[1] in ("robot", "sensor"):
            return str(p.params[1])
        spec = BY_ID.get(p.command)
        if spec is not None and spec.service != "common":
            return "robot" if spec.service in ("robot", "sync") else "sensor"
    return None


def load(path: str | Path) -> list[Connection]:
    """The connections of a capture that carry RobotSocket/SensorSocket requests."""
    streams, _ = sessions(read_capture(path))
    connections = []
    for s in streams:
        a, b = _frames(s, True), _frames(s, False)
        # the client is the side that sends requests (a capture may start after the SYN)
        a_requests = sum(isinstance(e, Packet) and e.kind is PacketKind.REQUEST for e, _, _ in a)
        b_requests = sum(isinstance(e, Packet) and e.kind is PacketKind.REQUEST for e, _, _ in b)
        if not a_requests and not b_requests:
            continue
        client, server = (a, b) if a_requests >= b_requests else (b, a)
        ends = (s.a, s.b) if client is a else (s.b, s.a)
        conn = Connection(
            f"{ends[0][0]}:{ends[0][1]}",
            f"{ends[1][0]}:{ends[1][1]}",
            _service([e for e, _, _ in client + server if isinstance(e, Packet)]),
        )
        by_id: dict[int, Exchange] = {}
        for event, raw, stamp in client:
            request = event if isinstance(event, Packet) else _rejected_request(event)
            x = Exchange(request, raw, stamp)
            conn.exchanges.append(x)
            by_id.setdefault(request.request_id, x)
        for event, _, stamp in server:
            if not isinstance(event, Packet):
                continue
            asked = by_id.get(event.request_id)
            if asked is not None and asked.answer is None and event.kind is not PacketKind.EVENT:
                asked.answer, asked.answer_ns = event, stamp
        connections.append(conn)
    return connections


def _rejected_request(event: Rejected) -> Packet:
    """A request frame the recorded server had to reject (bad CRC, ...): replayed as is."""
    h = event.header
    return Packet(PacketKind.REQUEST, h.command, h.request_id, ())


# --- comparing answers ---------------------------------------------------------------------


def _clock_reading(spec: ParamSpec) -> bool:
    """A value the registry documents as a reading of a clock: different on every run."""
    return "clock" in spec.doc


def _floats(value: Value) -> tuple[float, ...] | None:
    if isinstance(value, FloatArray | Joints | Transform):
        return tuple(value.values)
    if isinstance(value, Location):
        return value.as_tuple()
    if isinstance(value, Matrix):
        return (float(value.rows), float(value.cols), *value.values)
    return None


def _close(a: float, b: float, tol: float) -> bool:
    if math.isnan(a) and math.isnan(b):
        return True
    return abs(a - b) <= tol * max(1.0, abs(a), abs(b))


def _show(value: Value) -> str:
    from spec.dissect import format_value

    return format_value(value)


def compare(
    recorded: Packet | None,
    now: Packet | None,
    command: int,
    tolerance: float,
    ignore: frozenset[str] = frozenset(),
) -> list[str]:
    """What differs between two answers to the same request (empty: nothing)."""
    if recorded is None or now is None:
        if recorded is None and now is None:
            return []
        return [f"recorded {_what(recorded)}, now {_what(now)}"]
    if recorded.kind is not now.kind:
        out = [f"recorded {recorded.kind.name.lower()}, now {now.kind.name.lower()}"]
        if now.error is not None:
            out[0] += f" {_error(now)}"
        elif recorded.error is not None:
            out[0] += f" (recorded {_error(recorded)})"
        return out
    if recorded.kind is PacketKind.ERROR:
        if recorded.error and now.error and recorded.error[0] != now.error[0]:
            return [f"error code: recorded {_error(recorded)}, now {_error(now)}"]
        return []
    spec = BY_ID.get(command)
    names = spec.reply if spec and recorded.kind is PacketKind.REPLY else ()
    cmd = spec.name if spec else f"0x{command:04x}"
    out = []
    if len(recorded.params) != len(now.params):
        out.append(f"{len(recorded.params)} parameters recorded, now {len(now.params)}")
    for i, (a, b) in enumerate(zip(recorded.params, now.params, strict=False)):
        p = names[i] if i < len(names) else None
        label = p.name if p else f"#{i}"
        if (p is not None and _clock_reading(p)) or f"{cmd}.{label}" in ignore:
            continue
        if (difference := _param_difference(label, a, b, tolerance)) is not None:
            out.append(difference)
    return out


def _param_difference(label: str, a: Value, b: Value, tolerance: float) -> str | None:
    """How one reply parameter differs from its recording (None: it does not)."""

    def differs() -> str:
        return f"{label}: recorded {_show(a)}, now {_show(b)}"

    if type(a) is not type(b):
        return f"{label}: recorded {type(a).__name__}, now {type(b).__name__}"
    if isinstance(a, float) and isinstance(b, float):
        return None if _close(a, b, tolerance) else differs()
    if (fa := _floats(a)) is not None:
        fb = _floats(b)
        assert fb is not None
        same = len(fa) == len(fb) and all(
            _close(x, y, tolerance) for x, y in zip(fa, fb, strict=True)
        )
        return None if same else differs()
    if isinstance(a, Image) and isinstance(b, Image):
        if (a.width, a.height, a.format, a.order) != (b.width, b.height, b.format, b.order):
            return differs()
        if a.data != b.data:
            n = sum(x != y for x, y in zip(a.data, b.data, strict=True))
            return f"{label}: {n} of {len(a.data)} pixel bytes differ"
        return None
    if isinstance(a, IntArray | bytes | str | int | bool) and a != b:
        return differs()
    return None


def _what(p: Packet | None) -> str:
    return "no answer" if p is None else p.kind.name.lower()


def not_compared(results: Iterable[Result]) -> set[str]:
    """``Command.param`` of the clock readings the answers carried (not compared)."""
    out = set()
    for r in results:
        spec = BY_ID.get(r.exchange.request.command)
        if spec is not None and r.answer is not None and r.answer.kind is PacketKind.REPLY:
            out |= {f"{spec.name}.{p.name}" for p in spec.reply if _clock_reading(p)}
    return out


def _error(p: Packet) -> str:
    code, message = p.error or (0, "")
    try:
        name = ErrorCode(code).name
    except ValueError:
        name = f"code {code}"
    return f"{name} ({message})" if message else name


# --- sending them again --------------------------------------------------------------------


class EndpointLost(ConnectionError):
    """The endpoint could not be reached, or closed where the recording went on."""


@dataclass
class Result:
    exchange: Exchange
    answer: Packet | None
    seconds: float
    differences: list[str]


class _Link:
    """One TCP connection to the endpoint: send a frame, wait for the answer to its ID."""

    def __init__(self, address: tuple[str, int], timeout: float) -> None:
        try:
            self.sock = socket.create_connection(address, timeout=timeout)
        except OSError as exc:
            raise EndpointLost(f"cannot connect to {address[0]}:{address[1]}: {exc}") from None
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
        self.timeout = timeout
        self.closed = False

    def exchange(
        self, frame: bytes, request_id: int, timeout: float
    ) -> tuple[Packet | None, float]:
        start = time.monotonic()
        try:
            self.sock.sendall(frame)
        except OSError:
            self.closed = True
            return None, time.monotonic() - start
        deadline = start + timeout
        while True:
            try:
                for event in self.decoder.events():
                    if not isinstance(event, Packet) or event.kind is PacketKind.EVENT:
                        continue  # a frame we cannot read, an event: no answer
                    if event.request_id in (request_id, 0):
                        return event, time.monotonic() - start
            except PeerError:
                self.closed = True
                return None, time.monotonic() - start
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None, time.monotonic() - start
            self.sock.settimeout(remaining)
            try:
                data = self.sock.recv(1 << 18)
            except TimeoutError:
                continue
            except OSError:
                data = b""
            if not data:
                self.closed = True
                return None, time.monotonic() - start
            self.decoder.feed(data)

    def close(self) -> None:
        self.sock.close()


def motion_commands(connections: Iterable[Connection]) -> list[str]:
    """Names of the recorded commands that move the arm or switch an output."""
    names = []
    for c in connections:
        for x in c.exchanges:
            spec = BY_ID.get(x.request.command)
            if spec is not None and spec.moves and spec.name not in names:
                names.append(spec.name)
    return names


def replay(
    connection: Connection,
    address: tuple[str, int],
    *,
    tolerance: float = 1e-6,
    time_tolerance: float = 0.25,
    timeout: float = 10.0,
    ignore: frozenset[str] = frozenset(),
) -> list[Result]:
    """Send the connection's requests again, in order, each after the previous answer."""
    link = _Link(address, timeout)
    results = []
    try:
        for x in connection.exchanges:
            if link.closed:
                raise EndpointLost(f"the endpoint closed the connection before {x.name}")
            # a request the recording has no answer to: wait briefly, not the whole timeout
            wait = timeout if x.answer is not None else min(timeout, UNANSWERED_WAIT)
            answer, seconds = link.exchange(x.frame, x.request.request_id, wait)
            diffs = compare(x.answer, answer, x.request.command, tolerance, ignore)
            recorded = x.recorded_time
            if answer is not None and recorded is not None and seconds > recorded + time_tolerance:
                diffs.append(
                    f"answered in {seconds * 1e3:.1f} ms, recorded {recorded * 1e3:.1f} ms "
                    f"(tolerance {time_tolerance * 1e3:g} ms)"
                )
            results.append(Result(x, answer, seconds, diffs))
    finally:
        link.close()
    return results


__all__ = [
    "Connection",
    "EndpointLost",
    "Exchange",
    "ReplayError",
    "Result",
    "compare",
    "load",
    "motion_commands",
    "not_compared",
    "replay",
]
