"""The framed TCP server shell both services share (PROTOCOL.md section 7).

A reader thread per connection reads bytes, feeds the sans-I/O :class:`FrameDecoder` and
answers each request in order. The shell owns every policy that is not a command's business:
the allow-list, the client limit, frame size and timeouts, error packets for malformed frames,
the common commands (Hello, Ping, TakeControl, ReleaseControl, GetTime), control ownership and
its watchdog, parameter checks against the registry, and statistics. The rules of control
and of the connection slots are plain objects of :mod:`spec.control` (the h11 split); this
shell holds the locks, the threads and the sockets around them. A service implements
:class:`Service` (or :class:`HandlerService`, a table of handlers); its handlers and hooks see
a connection only as a :class:`SessionView`.

Safety of control (PROTOCOL.md 7.1):

- A session never goes blind. Requests that may block (the service's ``blocking`` commands,
  e.g. WaitEndMove) run on a per-session worker thread, so the reader keeps reading: it sees
  the connection close at once, renews the control lease with every frame, and executes the
  service's ``urgent`` commands (the stopping ones) the moment they arrive [RS-7.12].
- The controlling connection holds a lease (the watchdog period, set at TakeControl): a
  controller that sends no frame for that long loses control and the service makes its
  controlled stop (:meth:`Service.on_control_lost`) [RS-7.13]. The same on close and on
  server shutdown.
- A server at its client limit keeps a few reserved connections open for EmergencyStop only,
  so it always gets through [RS-7.14].

The server never dies from what a client sends: every rejection becomes an error packet or a
clean close, and a failing handler becomes an INTERNAL_ERROR reply [RS-7.9].
"""

from __future__ import annotations

import ipaddress
import logging
import math
import selectors
import signal
import socket
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from types import FrameType
from typing import Any, NamedTuple, TypeVar

from spec import wire
from spec.auth import Network, address_allowed
from spec.codec import (
    LARGE_FRAME,
    FrameDecoder,
    Packet,
    Rejected,
    encode_packet_parts,
    encode_reply,
    error_packet,
)
from spec.control import ControlState, SessionView, Slots, WrongToken
from spec.errors import ErrorCode, PeerError, ProtocolError
from spec.messages import (
    REQUESTS,
    HelloReply,
    HelloRequest,
    PingRequest,
    Request,
    SetFrameCrcRequest,
    TakeControlRequest,
)
from spec.params import IntArray, Value
from spec.registry import BY_ID, CommandId, CommandSpec, check_params, commands_for, lookup
from spec.shells import register
from spec.sockopt import set_kernel_timeouts
from spec.wire import PacketKind

log = logging.getLogger(__name__)

# How long TakeControl waits for a lost controller's controlled stop before it says BUSY.
CONTROL_STOP_WAIT_S = 5.0
#: A frame may take 1 s longer for every this many bytes of it received [RS-7.5]: a large
#: frame on a slow link is not cut off, a trickle of bytes is.
FRAME_ALLOWANCE_BYTES = 65536
#: Control changes kept in :attr:`FramedServer.control_events`.
CONTROL_EVENTS = 256
#: Requests of one connection that may wait behind a pending one; a further one gets BUSY
#: at once [RS-7.27], so a client cannot make the server hold an unbounded queue for it.
MAX_PENDING = 64


@dataclass(frozen=True)
class ServerPolicy:
    """Connection policies (PROTOCOL.md section 7); the defaults are the spec's SHOULDs."""

    max_clients: int = 64
    #: Connections one source address may hold at once; more are treated as over the
    #: client limit (BUSY, EmergencyStop only), so one host cannot take every slot [RS-7.24].
    max_per_address: int = 48
    #: Connections over ``max_clients`` kept open for EmergencyStop only [RS-7.14].
    reserved_slots: int = 4
    #: s a reserved connection stays open for its EmergencyStop [RS-7.14].
    reserved_grace: float = 2.0
    max_payload: int = wire.DEFAULT_MAX_PAYLOAD
    #: s to finish a frame from its first byte, plus 1 s per FRAME_ALLOWANCE_BYTES of it
    #: received [RS-7.5]
    frame_timeout: float = 5.0
    idle_timeout: float = 300.0  # s without any byte before the server closes [RS-7.6]
    allow: tuple[Network, ...] = ()  # empty: every client that can reach the address
    token: str | None = None  # TakeControl must present it when set [RS-7.3]
    #: Control lease (s) when TakeControl names none, and the range a client may ask [RS-7.13].
    #: 0.25 s (1.3; 1.0 before): a frozen controller at cruise has its laser off 0.25 s and
    #: its arm stopped 0.28 s after its last frame (bench/lease.py, issue 29 item 3).
    watchdog: float = 0.25
    watchdog_min: float = 0.05
    watchdog_max: float = 10.0

    def __post_init__(self) -> None:
        if not 0.0 < self.watchdog_min <= self.watchdog <= self.watchdog_max < math.inf:
            raise ValueError(
                f"control watchdog must satisfy 0 < min <= default <= max < inf, got "
                f"{self.watchdog_min} <= {self.watchdog} <= {self.watchdog_max}"
            )
        if self.max_per_address < 1:
            raise ValueError(f"max_per_address must be >= 1, got {self.max_per_address}")
        if self.token is not None and not self.token.strip():
            # An empty token would be presented by any client: protection silently off.
            raise ValueError("the control token is empty (use None for no token)")

    @property
    def per_address(self) -> int:
        """The connections one address may hold [RS-7.24]; below ``max_clients`` only when
        ``max_per_address`` is (a test filling the server from one host sets both)."""
        return self.max_per_address

    def allows(self, host: str) -> bool:
        return address_allowed(self.allow, host)


def parse_networks(items: Iterable[str]) -> tuple[Network, ...]:
    """CIDR strings (``10.0.0.0/8``, ``127.0.0.1``) to networks; ValueError names the bad one."""
    nets: list[Network] = []
    for item in items:
        try:
            nets.append(ipaddress.ip_network(item, strict=False))
        except ValueError:
            msg = f"not a network address: {item!r} (use CIDR, e.g. 10.0.0.0/24)"
            raise ValueError(msg) from None
    return tuple(nets)


@dataclass(frozen=True)
class Identity:
    """What Hello reports about the endpoint."""

    service: str
    vendor: str = "reference"
    model: str = "emulator"
    serial: str = "0"
    software: str = "0.1.0"


class _HotCounts:
    """The counters every request moves, kept without a lock: each is changed only by a
    single ``+=`` of an int on a slot, which CPython's GIL never interrupts half-way (no
    bytecode in it checks for a thread switch, and no Python code runs in it). A lock taken
    for them cost the request path more than all its counting. :meth:`FramedServer.statistics`
    adds them to the locked counters."""

    __slots__ = ("bytes_in", "bytes_out", "frames_in", "replies")

    def __init__(self) -> None:
        self.frames_in = self.replies = self.bytes_in = self.bytes_out = 0


class Session:
    """One client connection, as the server shell sees it (a :class:`SessionView`)."""

    def __init__(
        self,
        server: FramedServer,
        sock: socket.socket,
        peer: tuple[Any, ...],
        *,
        reserved: bool = False,
    ) -> None:
        self.server = server
        self.sock = sock
        self.peer = peer
        self.id = next(server._session_ids)
        self._send_lock = threading.Lock()
        self.closed = False
        #: Over the client limit: only EmergencyStop is served [RS-7.14].
        self.reserved = reserved
        self.opened = time.monotonic()
        #: When the last frame arrived: the control lease runs from it [RS-7.13].
        self.alive_at = self.opened
        #: Why control was taken away from this connection, for its next control command.
        self.control_lost: str | None = None
        #: False after SetFrameCrc(false): frames to this client carry NO_CRC [RS-3.16].
        self.crc = True
        self._worker: _Worker | None = None
        #: When the worker last sent a reply: the idle timeout runs from it too [RS-7.28].
        self.replied_at = self.opened

    @property
    def in_control(self) -> bool:
        return self.server.control.holder is self

    @property
    def control_held(self) -> bool:
        return self.server.control.holder is not None

    @property
    def busy(self) -> bool:
        """A request of this connection is queued or executing on its worker."""
        return self._worker is not None and self._worker.pending > 0

    def send(self, packet: Packet) -> None:
        self.send_parts(encode_packet_parts(packet, wire.MAX_PAYLOAD, crc=self.crc))

    def send_parts(self, parts: list[bytes]) -> None:
        """Send one encoded frame given as pieces: small frames joined and sent at once,
        large ones (images) handed to the kernel piece by piece, never copied here."""
        size = len(parts[0]) if len(parts) == 1 else sum(map(len, parts))
        # Counted before sending: a client that reads statistics() right after the reply
        # must find it counted.
        self.server._hot.bytes_out += size
        with self._send_lock:
            if size < LARGE_FRAME or not hasattr(self.sock, "sendmsg"):
                self.sock.sendall(parts[0] if len(parts) == 1 else b"".join(parts))
            else:
                _sendmsg_all(self.sock, parts, size)

    def __repr__(self) -> str:
        return f"<Session {self.id} {self.peer[0]}:{self.peer[1]}>"


class _Worker:
    """Executes a session's requests that may block, in arrival order, so that the session's
    reader keeps watching the connection meanwhile. Started on the first blocking request;
    while it has work, every later request of the session queues behind it (replies stay in
    request order), except the urgent ones."""

    def __init__(self, server: FramedServer, session: Session) -> None:
        self._server = server
        self._session = session
        self._items: deque[Packet | Rejected] = deque()
        self._cond = threading.Condition()
        #: Requests submitted and not yet answered; read without the lock by the reader,
        #: decremented only after the reply went out, so "0" means every reply is sent.
        self.pending = 0
        self._thread = threading.Thread(
            target=self._run, name=f"session-{session.id}-worker", daemon=True
        )
        self._thread.start()

    def submit(self, item: Packet | Rejected) -> None:
        with self._cond:
            self.pending += 1
            self._items.append(item)
            self._cond.notify()

    def wake(self) -> None:
        with self._cond:
            self._cond.notify()

    def _run(self) -> None:
        session = self._session
        while True:
            with self._cond:
                while not self._items and not session.closed:
                    self._cond.wait()
                if session.closed:
                    return  # what is still queued was sent by a connection that is gone
                item = self._items.popleft()
            try:
                self._server._answer(session, item)
            except OSError:
                pass  # the connection broke; the reader ends the session
            finally:
                session.replied_at = time.monotonic()
                with self._cond:
                    self.pending -= 1


class Service:
    """What a RobotSocket or SensorSocket implementation provides to the shell."""

    identity: Identity
    #: Commands executed the moment they arrive, even while earlier requests of the same
    #: connection are pending (the stopping commands) [RS-7.12].
    urgent: frozenset[int] = frozenset()
    #: Commands that may block (WaitEndMove): run on the session's worker [RS-7.12].
    blocking: frozenset[int] = frozenset()

    def handle(self, session: SessionView, request: Request[Any]) -> tuple[Value, ...]:
        """Execute ``request``, decoded by the shell after its parameters matched the
        registry; return the reply parameters or raise :class:`ProtocolError`."""
        what = BY_ID[request.command].name
        raise ProtocolError(f"{what} not implemented", ErrorCode.UNKNOWN_COMMAND)

    def implemented(self) -> tuple[int, ...]:
        """Command IDs this service answers (default: all of its service in the registry)."""
        return tuple(int(c.id) for c in commands_for(self.identity.service))

    def clock(self) -> float:
        """The service clock in seconds (GetTime, status timestamps)."""
        return time.monotonic()

    def on_control_lost(self, session: SessionView) -> None:
        """The controller is gone (closed, silent past its watchdog, or the server stops):
        stop what it started in a controlled way, process outputs first [RS-7.10]."""

    def on_control_released(self, session: SessionView) -> None:
        """The controller gave control back (ReleaseControl): what may be on only under
        control goes off, the laser first [RS-7.21]; queued moves go on [RS-7.11]."""

    def on_disconnect(self, session: SessionView) -> None:
        """A connection closed (after control was released)."""


#: The request class a handler takes.
Q = TypeVar("Q", bound="Request[Any]")
#: A handler of request class ``Q``: ``handler(session, request) -> reply parameters``.
Handler = Callable[[SessionView, Q], tuple[Value, ...]]


class HandlerService(Service):
    """A service whose commands are a table of handlers, as both reference services are.

    :meth:`register` adds or replaces a handler (before the server is constructed: the shell
    reads :meth:`implemented` once); :meth:`error_code` maps the service's own exceptions to
    wire codes in one place. A handler takes the typed request of its command
    (``session, AlterRequest -> reply parameters``) and reads its fields by name."""

    def __init__(self) -> None:
        self._handlers: dict[int, Handler[Any]] = {}

    def register(self, request: type[Q], handler: Handler[Q]) -> None:
        """Serve the command of request class ``request`` with ``handler``."""
        self._handlers[int(request.command)] = handler

    def implemented(self) -> tuple[int, ...]:
        return tuple(sorted(self._handlers))

    def error_code(self, exc: Exception) -> ErrorCode | None:
        """The wire code of a service exception; None lets it become INTERNAL_ERROR."""
        return None

    def handle(self, session: SessionView, request: Request[Any]) -> tuple[Value, ...]:
        handler = self._handlers.get(request.command)  # an IntEnum hashes as its int
        if handler is None:  # the shell answers unknown IDs before: only a direct call
            return super().handle(session, request)
        try:
            return handler(session, request)
        except ProtocolError:
            raise
        except Exception as exc:
            code = self.error_code(exc)
            if code is None:
                raise
            raise ProtocolError(str(exc), code) from None


class _Command(NamedTuple):
    """What the shell knows of a command it serves, found by one look-up per request."""

    spec: CommandSpec
    message: type[Request[Any]]
    #: The field classes of a request with every field (:attr:`Message.exact`).
    exact: tuple[type, ...] | None
    #: The request class as the constructor of such a request.
    make: Callable[..., Request[Any]]
    #: The one instance of a request without fields (None if it has fields).
    bare: Request[Any] | None
    #: The shell's own handler of a common command (None: the service's command).
    common: _Handler | None


def listen(host: str, port: int) -> socket.socket:
    """A TCP socket listening on ``host:port`` (OSError when it cannot be bound). A command
    line binds first, so a port in use is its one error line before anything else starts
    (a real-time child process, its log lines)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(128)
    except OSError:
        sock.close()
        raise
    return sock


class FramedServer:
    """Threaded TCP server shell; ``serve_forever`` in a thread, ``shutdown`` to stop."""

    def __init__(
        self,
        service: Service,
        host: str = "127.0.0.1",
        port: int = 0,
        policy: ServerPolicy | None = None,
        *,
        listener: socket.socket | None = None,
    ) -> None:
        """Binds ``host:port``, unless ``listener`` (from :func:`listen`) is given: then the
        port was bound before the service was built, and that listener is served."""
        self.service = service
        self.policy = policy or ServerPolicy()
        self._listener = listener if listener is not None else listen(host, port)
        self.address: tuple[str, int] = self._listener.getsockname()[:2]
        # shutdown() writes a byte here to wake the accept loop at once (no polling).
        self._wake_r, self._wake_w = socket.socketpair()
        #: The served and the reserved connections; changed under ``_lock``.
        self.slots: Slots[Session] = Slots()
        self._lock = threading.Lock()
        self._stats: Counter[str] = Counter()
        self._hot = _HotCounts()
        self._rejected: Counter[str] = Counter()
        self._session_ids: Iterator[int] = iter(range(1, 1 << 62))
        self._shutdown = threading.Event()
        self._stopped = threading.Event()
        self._thread: threading.Thread | None = None
        #: Control changes and the watchdog wait on this condition [RS-7.13].
        self._control = threading.Condition()
        self._watchdog_thread: threading.Thread | None = None
        #: Who holds control, the lease, the controlled stop; changed under ``_control``.
        self.control: ControlState[Session] = ControlState()
        #: (service clock s, session ID, what, last frame) of every control change: "took",
        #: "released", "lost: why", stamped when the server saw it, before the service acted
        #: on it; ``last frame``: when the session's last frame arrived, on the same clock.
        self.control_events: deque[tuple[float, int, str, float]] = deque(maxlen=CONTROL_EVENTS)
        self.handler_errors: list[BaseException] = []
        register(self)
        self._implemented = frozenset(service.implemented()) | {int(c) for c in _COMMON}
        # Per request, one dict look-up finds what the shell needs to know of a command.
        name = service.identity.service
        self._specs: dict[int, _Command] = {}
        for command in self._implemented:
            spec = lookup(command, name)
            if spec is not None:
                message = REQUESTS[command]
                bare = None if message.table else message()  # immutable: one serves all
                common = _COMMON.get(command)
                self._specs[command] = _Command(spec, message, message.exact, message, bare, common)
        self._urgent = frozenset(service.urgent)
        self._blocking = frozenset(service.blocking)

    # --- lifecycle ---------------------------------------------------------------------------

    def start(self) -> FramedServer:
        """Serve in a background thread; returns self."""
        self._thread = threading.Thread(
            target=self.serve_forever, name=f"{self.service.identity.service}-server", daemon=True
        )
        self._thread.start()
        return self

    def serve_forever(self) -> None:
        """Accept connections until :meth:`shutdown`; blocks without polling."""
        log.info("%s server listening on %s:%d", self.service.identity.service, *self.address[:2])
        self._listener.setblocking(False)
        self._watchdog_thread = threading.Thread(
            target=self._watch_control, name="control-watchdog", daemon=True
        )
        self._watchdog_thread.start()
        try:
            with selectors.DefaultSelector() as sel:
                sel.register(self._listener, selectors.EVENT_READ)
                sel.register(self._wake_r, selectors.EVENT_READ)
                while not self._shutdown.is_set():
                    for key, _ in sel.select():
                        if key.fileobj is self._listener:
                            self._accept()
        finally:
            self._stopped.set()

    def shutdown(self, timeout: float = 5.0) -> None:
        """Stop accepting; the controller's work stops in a controlled way first [RS-7.10];
        then every connection closes and the threads are joined."""
        self._shutdown.set()
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass
        self._revoke_control(None, "server shutting down")
        with self._control:
            self._control.notify_all()
        if self._thread is not None:
            self._stopped.wait(timeout)
        with self._lock:
            sessions = self.slots.all()
        for s in sessions:
            _close_quietly(s.sock)
        self._listener.close()
        if self._thread is not None:
            self._thread.join(timeout)
        if self._watchdog_thread is not None:
            self._watchdog_thread.join(timeout)
        self._wake_r.close()
        self._wake_w.close()

    def __enter__(self) -> FramedServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    # --- statistics --------------------------------------------------------------------------

    def _count(self, key: str, n: int = 1) -> None:
        with self._lock:
            self._stats[key] += n

    def statistics(self) -> dict[str, Any]:
        """Counters: connections, frames in, replies, errors sent, rejected frames by code."""
        with self._lock:
            stats: dict[str, Any] = {
                k: self._stats.get(k, 0)
                for k in (
                    "connections",
                    "frames_in",
                    "replies",
                    "errors_sent",
                    "rejected",
                    "refused_busy",
                    "refused_per_address",
                    "refused_address",
                    "reserved_connections",
                    "timeouts",
                    "watchdog_expired",
                    "handler_errors",
                    "bytes_in",
                    "bytes_out",
                )
            }
            hot = self._hot
            for key in _HotCounts.__slots__:
                stats[key] += getattr(hot, key)
            stats["clients"] = len(self.slots.served)
            stats["rejected_by_code"] = dict(self._rejected)
        return stats

    # --- connections -------------------------------------------------------------------------

    def _accept(self) -> None:
        try:
            sock, peer = self._listener.accept()
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            if not self._shutdown.is_set():
                log.exception("accept failed")
            return
        sock.setblocking(True)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if not self.policy.allows(peer[0]):
            # [RS-7.7] a client outside the allow-list is closed before any byte is read.
            self._count("refused_address")
            log.warning("refused %s: not in the allow-list", peer[0])
            _close_quietly(sock)
            return
        policy = self.policy
        with self._lock:
            admission = self.slots.admit(
                peer[0], policy.max_clients, policy.per_address, policy.reserved_slots
            )
            full, crowded, reserved = admission.full, admission.crowded, admission.reserved
            session = Session(self, sock, peer, reserved=reserved)
            # the oldest reserved one makes room for a newcomer
            evicted = self.slots.add(session, admission, policy.reserved_slots)
            if not full:
                self._stats["connections"] += 1
            elif reserved:
                self._stats["reserved_connections"] += 1
        if evicted is not None:
            _close_quietly(evicted.sock)
        if full:
            # [RS-7.2] the client over the limit gets BUSY (request ID 0); [RS-7.14] on a
            # reserved connection it may still send EmergencyStop for a short while.
            self._count("refused_busy")
            if crowded:
                self._count("refused_per_address")
            text = (
                f"connection limit per address reached ({self.policy.per_address} from {peer[0]})"
                if crowded
                else "client limit reached"
            )
            if reserved:
                grace = self.policy.reserved_grace
                text += f": this connection serves only EmergencyStop for {grace:g} s"
            try:
                sock.settimeout(1.0)
                session.send(error_packet(0, 0, ErrorCode.BUSY, text))
            except OSError:
                pass
            if not reserved:
                _close_quietly(sock)
                return
            log.warning("client limit reached: %s:%s on a reserved connection", *peer[:2])
        else:
            log.info("client %s:%s connected (session %d)", peer[0], peer[1], session.id)
        threading.Thread(
            target=self._serve_session, args=(session,), name=f"session-{session.id}", daemon=True
        ).start()

    def _serve_session(self, session: Session) -> None:
        try:
            self._session_loop(session)
        except OSError as exc:
            log.info("session %d: connection error: %s", session.id, exc)
        except BaseException as exc:  # never let a session kill the process silently
            self.handler_errors.append(exc)
            log.exception("session %d failed", session.id)
        finally:
            self._end_session(session)

    def _deadline(
        self, session: Session, decoder: FrameDecoder, frame_start: float, last_byte: float
    ) -> tuple[float, str]:
        """(time, reason) of the next deadline of a connection [RS-7.5], [RS-7.6], [RS-7.14]."""
        policy = self.policy
        if session.reserved:
            return session.opened + policy.reserved_grace, ""
        if decoder.in_frame:
            allowance = decoder.buffered / FRAME_ALLOWANCE_BYTES
            return frame_start + policy.frame_timeout + allowance, "frame not finished in time"
        if session.busy:
            return math.inf, ""  # waiting for our own reply is not idleness [RS-7.28]
        return max(last_byte, session.replied_at) + policy.idle_timeout, "idle"

    def _session_loop(self, session: Session) -> None:
        policy = self.policy
        decoder = FrameDecoder(
            max_payload=policy.max_payload, kinds=frozenset({PacketKind.REQUEST})
        )
        sock = session.sock
        # Blocking reads that wake up every ``tick`` (SO_RCVTIMEO) cost one system call per
        # request instead of the three of a Python socket timeout; deadlines are checked on
        # each wake-up, so they are kept to within a tick.
        tick = min(1.0, policy.frame_timeout / 5, policy.idle_timeout / 5)
        if session.reserved:
            tick = min(tick, policy.reserved_grace / 4)
        ticking = set_kernel_timeouts(sock, tick)
        last_byte = frame_start = time.monotonic()
        # Received bytes land in one reused buffer; the decoder borrows them (no copy).
        scratch = bytearray(65536)
        view = memoryview(scratch)
        # After bytes arrived no deadline can be due (each runs from the last byte or from a
        # frame that is still running), except the reserved connection's: the others are
        # looked at on the ticks without data, off the request path.
        look = True
        hot = self._hot
        while not session.closed:
            if look or session.reserved or not ticking:
                # Off the request path too: shutdown() also closes this socket, which ends
                # a receive that is waiting.
                if self._shutdown.is_set():
                    return
                now = time.monotonic()
                deadline, why = self._deadline(session, decoder, frame_start, last_byte)
                if now >= deadline:
                    if why:
                        self._count("timeouts")
                        self._send_error(session, 0, 0, ErrorCode.TIMEOUT, f"timeout: {why}")
                    return
                if not ticking:
                    sock.settimeout(min(deadline - now, 1.0))
            decoder.keep()  # the scratch buffer is about to be written again
            try:
                n = sock.recv_into(scratch)
            except (TimeoutError, BlockingIOError):
                look = True  # a tick without data: check the deadlines again
                continue
            if not n:
                return
            look = False
            hot.bytes_in += n
            last_byte = time.monotonic()
            was_in_frame = decoder.in_frame
            try:
                event = decoder.feed_next(view[:n])
                if event is not None:
                    was_in_frame = False  # a frame ended here: what is left began here too
                while event is not None:
                    # [RS-7.13] every frame from the controller renews its lease.
                    session.alive_at = last_byte
                    self._route(session, event)
                    event = decoder.next_event()
            except PeerError as exc:
                # [RS-3.8] header unusable: say why with request ID 0, then close.
                self._reject_code(exc.code)
                self._send_error(session, 0, 0, exc.code, exc.message)
                return
            # [RS-7.5] the partial-frame clock runs from the frame's first byte (a trickle of
            # bytes cannot hold a connection open); its allowance grows with what arrived.
            if decoder.in_frame and not was_in_frame:
                frame_start = last_byte

    def _route(self, session: Session, event: Packet | Rejected) -> None:
        """Answer now on the reader, or queue on the session's worker [RS-7.12]. Only a
        request that may block, or one behind it, crosses to the worker: every other one is
        answered by the thread that read it, with no thread hand-off on the way."""
        worker = session._worker
        busy = worker is not None and worker.pending > 0
        if isinstance(event, Packet):
            command = event.command
            if command in self._urgent or not (busy or command in self._blocking):
                self._dispatch(session, event)  # an urgent one may overtake pending replies
                return
        elif not busy:
            self._reject(session, event)
            return
        if worker is not None and worker.pending >= MAX_PENDING:
            # [RS-7.27] refused at once (overtaking the pending replies), never executed.
            header = event.header if isinstance(event, Rejected) else event
            self._count("frames_in")
            self._reject_code(ErrorCode.BUSY)
            self._send_error(
                session,
                header.command,
                header.request_id,
                ErrorCode.BUSY,
                f"{worker.pending} requests of this connection are pending (at most {MAX_PENDING})",
            )
            return
        if worker is None:
            worker = session._worker = _Worker(self, session)
        worker.submit(event)

    def _answer(self, session: Session, event: Packet | Rejected) -> None:
        if isinstance(event, Rejected):
            self._reject(session, event)
        else:
            self._dispatch(session, event)

    def _end_session(self, session: Session) -> None:
        session.closed = True
        with self._lock:
            self.slots.remove(session)
        if session._worker is not None:
            session._worker.wake()
        _close_quietly(session.sock)
        # [RS-7.10] a controller that closes (or is killed) stops the arm whatever it was
        # doing, also while a request of it is still executing on its worker.
        self._revoke_control(session, "connection closed")
        self._guard(self.service.on_disconnect, session)
        log.info("session %d closed", session.id)

    def _guard(self, fn: Callable[[Session], None], session: Session) -> None:
        try:
            fn(session)
        except Exception as exc:
            self.handler_errors.append(exc)
            log.exception("service hook failed")

    # --- control and its watchdog ------------------------------------------------------------

    def _revoke_control(self, session: Session | None, why: str) -> None:
        """Take control from ``session`` (None: from whoever holds it) and let the service
        make its controlled stop."""
        self._end_control(session, why, lost=True)

    def _end_control(self, session: Session | None, why: str, *, lost: bool) -> None:
        """Control of ``session`` (None: whoever holds it) ends; the service switches off
        what needs an owner (lost: the controlled stop [RS-7.10]; released: the outputs
        [RS-7.21]) before control is free again."""
        with self._control:
            holder = self.control.end(session)
            if holder is None:
                return
            if lost:
                holder.control_lost = why
            self._note_control(holder, f"lost: {why}" if lost else "released")
            self._control.notify_all()
        if lost:
            log.warning("session %d lost control (%s): controlled stop", holder.id, why)
        else:
            log.info("session %d released control", holder.id)
        hook = self.service.on_control_lost if lost else self.service.on_control_released
        try:
            self._guard(hook, holder)
        finally:
            with self._control:
                self.control.stopped()
                self._control.notify_all()

    def _note_control(self, session: Session, what: str) -> None:
        now = float(self.service.clock())
        last = now - (time.monotonic() - session.alive_at)
        self.control_events.append((now, session.id, what, last))

    @property
    def control_free(self) -> bool:
        """Nobody holds control and no controlled stop is still running: TakeControl gets it."""
        with self._control:
            return self.control.free

    @property
    def control_holder(self) -> Session | None:
        """The connection holding control, None when nobody does."""
        return self.control.holder

    @control_holder.setter
    def control_holder(self, session: Session | None) -> None:
        self.control.holder = session

    def _watch_control(self) -> None:
        """[RS-7.13] A controller that shows no life for its watchdog period loses control.
        Sleeps until the holder's deadline; a frame in between moves the deadline on."""
        while not self._shutdown.is_set():
            with self._control:
                holder, lease = self.control.holder, self.control.lease
                if holder is None:
                    self._control.wait()
                    continue
                late = time.monotonic() - self.control.expires_at(holder.alive_at)
                if late < 0:
                    self._control.wait(-late)
                    continue
                if _unread(holder.sock):
                    # Bytes from the controller wait in the kernel: it is alive, only this
                    # busy process has not read them yet. Late, not a lost controller.
                    holder.alive_at = time.monotonic()
                    continue
            self._count("watchdog_expired")
            self._revoke_control(holder, f"watchdog: no frame for {lease:g} s")

    # --- requests ----------------------------------------------------------------------------

    def _reject_code(self, code: ErrorCode) -> None:
        with self._lock:
            self._stats["rejected"] += 1
            self._rejected[code.name] += 1

    def _reject(self, session: Session, event: Rejected) -> None:
        self._count("frames_in")
        self._reject_code(event.code)
        h = event.header
        self._send_error(session, h.command, h.request_id, event.code, event.error.message)

    def _send_error(
        self, session: Session, command: int, request_id: int, code: ErrorCode, message: str
    ) -> None:
        self._count("errors_sent")
        try:
            session.send(error_packet(command, request_id, code, message))
        except OSError:
            pass

    def _dispatch(self, session: Session, packet: Packet) -> None:
        hot = self._hot
        hot.frames_in += 1  # on arrival: statistics() shows a request a handler still holds
        crc = session.crc  # the reply to SetFrameCrc goes out as before it [RS-3.16]
        try:
            params = self._execute(session, packet)
        except ProtocolError as exc:
            self._send_error(session, packet.command, packet.request_id, exc.code, exc.message)
            return
        except Exception as exc:
            self._count("handler_errors")
            self.handler_errors.append(exc)
            log.exception("handler failed on command 0x%04x", packet.command)
            message = f"internal error: {type(exc).__name__}"
            self._send_error(
                session, packet.command, packet.request_id, ErrorCode.INTERNAL_ERROR, message
            )
            return
        try:
            parts = encode_reply(packet.command, packet.request_id, params, crc)
        except ProtocolError as exc:  # reply too large to encode: a server-side bug
            self.handler_errors.append(exc)
            self._send_error(
                session, packet.command, packet.request_id, ErrorCode.INTERNAL_ERROR, str(exc)
            )
            return
        # Counted before sending, so statistics() never lags a received reply.
        hot.replies += 1
        session.send_parts(parts)

    def _execute(self, session: Session, packet: Packet) -> tuple[Value, ...]:
        entry = self._specs.get(packet.command)
        if entry is None:
            service = self.service.identity.service
            known = lookup(packet.command, service)
            if known is not None:
                # [RS-5.62] a command of the service that this endpoint does not offer.
                raise ProtocolError(
                    f"{known.name} (0x{packet.command:04x}) is not offered by this {service}",
                    ErrorCode.NOT_SUPPORTED,
                )
            raise ProtocolError(
                f"unknown command 0x{packet.command:04x} for the {service} service",
                ErrorCode.UNKNOWN_COMMAND,
            )
        spec, message, exact, make, bare, common = entry
        if session.reserved and packet.command != CommandId.EMERGENCY_STOP:
            # [RS-7.14] a reserved connection serves EmergencyStop only.
            raise ProtocolError(
                f"client limit reached: only EmergencyStop is served here, not {spec.name}",
                ErrorCode.BUSY,
            )
        # Decoded once, here: every handler reads its request's fields by name.
        params = packet.params
        request: Request[Any]
        if bare is not None and not params:
            request = bare  # Herej, RobotStatus, ...: nothing to check
        elif tuple(map(type, params)) == exact:
            request = make(*params)  # nearly always: every field, of its declared class
        else:
            check_params(spec.params, params, spec.name)  # [RS-5.4] in its own words
            request = message.decode(params)  # optional fields left off
        if spec.needs_control and not session.in_control:
            # [RS-7.4] commands that move or switch anything need control.
            why = self.control.refusal(session.control_lost)
            raise ProtocolError(f"{spec.name} needs control ({why})", ErrorCode.NOT_IN_CONTROL)
        if common is not None:
            return common(self, session, request)
        return self.service.handle(session, request)

    # --- common commands ---------------------------------------------------------------------

    def _hello(self, session: Session, request: HelloRequest) -> tuple[Value, ...]:
        major = request.major
        if major != wire.VERSION_MAJOR:
            # [RS-5.2] a client that cannot speak our major version is told so.
            raise ProtocolError(
                f"client speaks {major!r}.x, this server speaks {wire.VERSION}",
                ErrorCode.UNSUPPORTED_VERSION,
            )
        ident = self.service.identity
        return HelloReply(
            wire.VERSION,
            ident.service,
            ident.vendor,
            ident.model,
            ident.serial,
            ident.software,
            IntArray(sorted(self._implemented)),
            self.policy.max_payload,
            self.policy.max_clients,
            float(self.policy.idle_timeout),
            float(self.policy.frame_timeout),
        ).encode()

    def _ping(self, session: Session, request: PingRequest) -> tuple[Value, ...]:
        return (b"" if request.data is None else request.data,)

    def _take_control(self, session: Session, request: TakeControlRequest) -> tuple[Value, ...]:
        token, policy = request.token, self.policy
        address = session.peer[0]
        try:
            with self._lock:  # the back-off table is shared by every session's reader
                self.control.authorize(address, token, policy.token, time.monotonic())
        except WrongToken as exc:
            # A refusal during the back-off is not logged (a guesser would fill the log); the
            # failures that were compared are.
            log.warning(
                "session %d: wrong control token from %s (%d in a row, back-off %.2f s)",
                session.id, address, exc.failures, exc.delay,
            )  # fmt: skip
            raise
        watchdog = self.control.check_lease(
            request.watchdog, policy.watchdog, policy.watchdog_min, policy.watchdog_max
        )
        with self._control:
            # The wait for a lost controller's controlled stop is here; the rule is take's.
            self._control.wait_for(lambda: self.control.stopping_for is None, CONTROL_STOP_WAIT_S)
            self.control.take(session, watchdog)
            session.alive_at = time.monotonic()
            session.control_lost = None
            self._note_control(session, "took")
            self._control.notify_all()
        log.info("session %d took control (watchdog %g s)", session.id, watchdog)
        return (watchdog,)

    def _release_control(self, session: Session, request: Request[Any]) -> tuple[Value, ...]:
        # [RS-7.21] the outputs are off before the reply: a client that reads them after
        # it finds them off.
        self._end_control(session, "released", lost=False)
        return ()

    def _get_time(self, session: Session, request: Request[Any]) -> tuple[Value, ...]:
        return (float(self.service.clock()),)

    def _set_frame_crc(self, session: Session, request: SetFrameCrcRequest) -> tuple[Value, ...]:
        session.crc = request.enabled
        log.info("session %d: frame CRC %s", session.id, "on" if session.crc else "off")
        return (session.crc,)


_Handler = Callable[[FramedServer, Session, Any], tuple[Value, ...]]
_COMMON: dict[int, _Handler] = {
    CommandId.HELLO: FramedServer._hello,
    CommandId.PING: FramedServer._ping,
    CommandId.TAKE_CONTROL: FramedServer._take_control,
    CommandId.RELEASE_CONTROL: FramedServer._release_control,
    CommandId.GET_TIME: FramedServer._get_time,
    CommandId.SET_FRAME_CRC: FramedServer._set_frame_crc,
}


def _sendmsg_all(sock: socket.socket, parts: list[bytes], size: int) -> None:
    """``sendall`` for a list of buffers (``size`` bytes in all): ``sendmsg`` until every
    byte is out. A blocking socket takes them in one call; views only for what is left."""
    sent = sock.sendmsg(parts)
    if sent == size:
        return
    views = [memoryview(p) for p in parts if p]
    while True:
        while views and sent >= len(views[0]):
            sent -= len(views[0])
            views.pop(0)
        if not views:
            return
        if sent:
            views[0] = views[0][sent:]
        sent = sock.sendmsg(views)


def _unread(sock: socket.socket) -> bool:
    """True when received bytes wait unread on ``sock`` (not at its end of stream)."""
    try:
        return bool(sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT))
    except OSError:
        return False


def _close_quietly(sock: socket.socket) -> None:
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass
    sock.close()


class _StopSignal(BaseException):
    """Raised in the main thread by the first SIGINT/SIGTERM to end the wait. A BaseException,
    like KeyboardInterrupt: an ``except Exception`` it lands in (logging's emit) must not eat it."""


def serve_until_signal(
    servers: list[FramedServer],
    on_stop: Callable[[], None] | None = None,
    ready: Callable[[], None] | None = None,
) -> None:
    """Run servers (already started) until SIGINT or SIGTERM, then shut them down. ``ready``
    announces the server once the handlers are in place: a script that signals as soon as it
    reads the announcement gets the clean stop, not the default handlers' death.

    The handler raises instead of setting an Event: it runs between two bytecodes of the main
    thread, and ``Event.set()`` there deadlocks when the main thread is inside ``Event.wait()``
    holding the same lock (a server that never stopped on SIGINT, seen once under load). For
    the same reason a later signal is only counted, not logged, in the handler."""
    signals = (signal.SIGINT, signal.SIGTERM)
    again: list[int] = []

    def _later(signum: int, frame: FrameType | None) -> None:
        again.append(signum)  # a second Ctrl-C must not turn a clean stop into a traceback

    def _first(signum: int, frame: FrameType | None) -> None:
        for s in signals:
            signal.signal(s, _later)
        raise _StopSignal(signum)

    # A signal may be delivered to any thread; the main thread runs the handler only when it
    # next executes bytecode. The wakeup socket wakes it at once, with no polling.
    wake_r, wake_w = socket.socketpair()
    wake_w.setblocking(False)
    previous: dict[int, Any] = {}
    old_wakeup = signal.set_wakeup_fd(wake_w.fileno(), warn_on_full_buffer=False)
    try:
        try:
            for sig in signals:
                previous[sig] = signal.signal(sig, _first)
            if ready is not None:
                ready()
            while True:
                wake_r.recv(64)  # a signal's byte; its handler runs right after
        except _StopSignal as stop:
            log.info("received %s, shutting down", signal.Signals(stop.args[0]).name)
        if on_stop is not None:
            on_stop()
        for server in servers:
            server.shutdown()
        if again:
            log.info(
                "received %s during the shutdown: ignored",
                ", ".join(signal.Signals(s).name for s in again),
            )
        log.info("stopped")
    finally:
        for signum, h in previous.items():
            signal.signal(signum, h)
        signal.set_wakeup_fd(old_wakeup)
        wake_r.close()
        wake_w.close()


__all__ = [
    "FramedServer",
    "Handler",
    "HandlerService",
    "Identity",
    "ServerPolicy",
    "Service",
    "Session",
    "SessionView",
    "listen",
    "parse_networks",
    "serve_until_signal",
]
