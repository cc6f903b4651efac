"""What a case gets: the endpoint, the negotiated capabilities, options and logged sockets."""

from __future__ import annotations

import math
import secrets
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from conformance.connection import ENDPOINT_ERRORS, Closed, Conn, UdpConn, WireLog, typed_reply
from conformance.model import (
    Blocked,
    EndpointGone,
    EndpointTimeout,
    Fail,
    NotApplicable,
    Skip,
)
from spec import messages as M
from spec.codec import Packet
from spec.errors import ErrorCode
from spec.params import IntArray, Value
from spec.registry import BY_ID, CommandId, commands_for
from spec.wire import PacketKind

#: Hello's reply fields, in order (the registry's table).
HELLO_FIELDS = tuple(p.name for p in BY_ID[CommandId.HELLO].reply)


#: Lease the harness asks for at TakeControl (s): its cases pause for seconds at a time.
HARNESS_LEASE = 10.0


@dataclass
class Options:
    """Run options that cases read."""

    allow_motion: bool = False
    timeout_scale: float = 1.0
    token: str = ""  # control token of the endpoint, if it has one
    fuzz: int = 0
    seed: int = 1
    reply_timeout: float = 2.0  # s before scaling: how long one answer may take
    not_offered: frozenset[int] = frozenset()  # from a capability file


@dataclass
class Hello:
    """The endpoint's Hello reply, by field name."""

    fields: dict[str, Value]

    @property
    def commands(self) -> frozenset[int]:
        cmds = self.fields.get("commands")
        return frozenset(cmds.values) if isinstance(cmds, IntArray) else frozenset()

    def number(self, name: str, default: float) -> float:
        value = self.fields.get(name)
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        return default

    def text(self, name: str) -> str:
        value = self.fields.get(name)
        return value if isinstance(value, str) else ""


@dataclass
class Shared:
    """State shared by the cases of one run (measurements, UDP index counter)."""

    measurements: dict[str, dict[str, Any]] = field(default_factory=dict)
    # A random start: a sensor that remembers answered indices [SY-2.2] must not take a
    # second run of the suite for duplicates of the first.
    next_index: int = field(default_factory=lambda: secrets.randbelow(1 << 30))
    lock: threading.Lock = field(default_factory=threading.Lock)
    #: The request that tells "stopped answering" from "refused" (see runner.LIVENESS):
    #: Ping, or Hello when the endpoint does not answer Ping (reported once, as RS-5.8).
    probe_command: int = CommandId.PING

    def take_indices(self, n: int) -> int:
        """``n`` fresh trigger indices, never used before in this run."""
        with self.lock:
            first = self.next_index
            self.next_index += n + 16  # a gap, so no two cases look like one sequence
            return first


class Context:
    """Handed to every case: endpoint, service, negotiated Hello, options, sockets."""

    def __init__(
        self,
        service: str,
        host: str,
        port: int,
        options: Options,
        hello: Hello | None,
        shared: Shared,
    ) -> None:
        self.service = service
        self.host = host
        self.port = port
        self.options = options
        self.hello = hello
        self.shared = shared
        self.log = WireLog()
        self.details: dict[str, Any] = {}
        self._conns: list[Conn | UdpConn] = []
        self._lock = threading.Lock()

    # --- time ----------------------------------------------------------------------------------

    @property
    def timeout(self) -> float:
        """How long one answer may take (s), after --timeout-scale."""
        return self.options.reply_timeout * self.options.timeout_scale

    def scaled(self, seconds: float) -> float:
        return seconds * self.options.timeout_scale

    # --- capabilities --------------------------------------------------------------------------

    @property
    def advertised(self) -> frozenset[int]:
        """Command IDs the endpoint offers: its Hello list, minus a capability file's exclusions."""
        if self.hello is not None and self.hello.commands:
            cmds = self.hello.commands
        else:
            cmds = frozenset(int(c.id) for c in commands_for(self.service))
        return cmds - self.options.not_offered

    def require(self, *commands: int) -> None:
        """Raise NotApplicable unless every command is advertised."""
        missing = [c for c in commands if c not in self.advertised]
        if missing:
            names = ", ".join(BY_ID[c].name if c in BY_ID else f"0x{c:04x}" for c in missing)
            raise NotApplicable(f"the endpoint does not offer {names}")

    @contextmanager
    def precondition(self, what: str) -> Iterator[None]:
        """Requests a case needs before the one it judges: a Fail in them ends the case as
        BLOCKED with ``what`` named, never as a failure of the case's own rule."""
        try:
            yield
        except Fail as exc:
            req = f" [{exc.requirement}]" if exc.requirement else ""
            got = f": {exc.actual}" if exc.actual not in (None, "") else ""
            raise Blocked(what, f"{exc.message}{req}{got}") from None

    def require_motion(self, what: str) -> None:
        if not self.options.allow_motion:
            raise Skip(f"{what}: moves the robot or switches an output; needs --allow-motion")

    # --- sockets -------------------------------------------------------------------------------

    def connect(self, hello: bool = False) -> Conn:
        """A new logged TCP connection; optionally negotiate with Hello first [RS-5.9]."""
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
        except TimeoutError:
            raise EndpointTimeout(f"connect to {self.host}:{self.port} timed out") from None
        except OSError as exc:
            raise EndpointGone(f"cannot connect to {self.host}:{self.port}: {exc}") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self._lock:
            number = len(self._conns) + 1
            conn = Conn(sock, self.log, number, self.timeout)
            self._conns.append(conn)
        self.log.add("--", number, b"", f"connected to {self.host}:{self.port}")
        conn.alive = self.alive
        conn.probe_command = self.shared.probe_command
        idle = self.hello.number("idle_timeout", conn.idle_timeout) if self.hello else 0.0
        if 0.0 < idle < math.inf:  # a broken value is the negotiation cases' to judge
            conn.idle_timeout = idle
        if hello:
            conn.ok(CommandId.HELLO, 1, 0, "conformance")
        return conn

    def udp(self) -> UdpConn:
        """A new logged UDP socket aimed at the endpoint (the sensor's trigger listener)."""
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        sock.bind(("::" if family == socket.AF_INET6 else "0.0.0.0", 0))
        with self._lock:
            number = len(self._conns) + 1
            conn = UdpConn(sock, (self.host, self.port), self.log, number)
            self._conns.append(conn)
        return conn

    def take_control(self, conn: Conn, watchdog: float | None = HARNESS_LEASE) -> None:
        """TakeControl, asking for a lease long enough for the harness's pauses [RS-7.13];
        an endpoint without the watchdog parameter (1.0) or with a shorter maximum is asked
        again without it. ``conn.lease`` is what it granted."""
        token = self.options.token
        asked: tuple[Value, ...] = (token,) if watchdog is None else (token, float(watchdog))
        # A connection the harness has just closed may hold control until the endpoint has
        # read its close and stopped what it started [RS-7.10]: BUSY is asked again for one
        # reply timeout, as control.released_on_close does, before the case is skipped.
        deadline = time.monotonic() + self.timeout
        while True:
            answer = conn.call(CommandId.TAKE_CONTROL, *asked)
            refused = _refusal(answer)
            if refused != ErrorCode.BUSY or time.monotonic() > deadline:
                break
            time.sleep(0.02)
        if watchdog is not None and refused in (ErrorCode.BAD_PARAMETERS, ErrorCode.OUT_OF_RANGE):
            answer = conn.call(CommandId.TAKE_CONTROL, token)
        if answer.kind is PacketKind.ERROR:
            code, message = answer.error or (0, "")
            raise Skip(f"cannot take control of the endpoint (error {code}: {message})")
        # By field name [RS-5.6]: a newer minor version's trailing fields are passed over, and a
        # reply that breaks the table blocks the case rather than passing for "no lease" (1.0).
        with self.precondition("TakeControl's reply"):
            conn.lease = typed_reply(M.TakeControlReply, answer.params).watchdog

    def alive(self) -> bool:
        """True when a new connection answers the liveness probe (quietly; not logged)."""
        try:
            with socket.create_connection((self.host, self.port), timeout=self.timeout) as sock:
                return probe_answered(Conn(sock, WireLog(), 0, self.timeout), self.shared)
        # OSError: no connection (refused, reset, unreachable, timed out); the rest of
        # ENDPOINT_ERRORS: connected, but the probe not answered as it must be (closed, no
        # answer in time, a wrong answer). A harness bug (TypeError, ...) is not "not alive".
        except ENDPOINT_ERRORS:
            return False

    def probe(self) -> None:
        """Liveness probe: a new connection answers it [RS-7.9]; raise Fail otherwise."""
        deadline = time.monotonic() + self.timeout * 2
        last = ""
        name = BY_ID[self.shared.probe_command].name
        # The endpoint may still be closing the previous connection: retry briefly.
        while time.monotonic() < deadline:
            try:
                conn = self.connect()
                try:
                    answered = probe_answered(conn, self.shared)
                finally:
                    conn.close()
                if not answered:
                    last = f"{name} was not answered as its table says"
                    break
                return
            except (EndpointGone, Closed) as exc:
                last = str(exc)
                time.sleep(0.05)
            except EndpointTimeout as exc:
                last = str(exc)
                break
        raise Fail(
            "the endpoint no longer answers after the input (liveness probe)",
            f"a new connection that answers {name}",
            last,
            requirement="RS-7.9",
        )

    def measure(self, name: str, **values: Any) -> None:
        """Record a measurement (reported apart from verdicts)."""
        with self.shared.lock:
            self.shared.measurements[name] = values

    def close_all(self) -> None:
        with self._lock:
            conns = list(self._conns)
        for c in conns:
            c.close()


def _refusal(answer: Packet) -> int:
    """The error code of an error packet, 0 for any other answer."""
    return (answer.error or (0, ""))[0] if answer.kind is PacketKind.ERROR else 0


PROBE_PAYLOAD = b"conformance-liveness"


#: How many reply times a Ping may take before it counts as not answered at all (a slow
#: endpoint is slow, not broken: its cases time out, Ping is not blamed).
PING_PATIENCE = 5.0


def probe_answered(conn: Conn, shared: Shared, timeout: float | None = None) -> bool:
    """One liveness probe on ``conn``: Ping echoed [RS-5.8], or (fallback) Hello answered."""
    if shared.probe_command == CommandId.PING:
        echoed = conn.ok(CommandId.PING, PROBE_PAYLOAD, timeout=timeout)[:1]
        return echoed == (PROBE_PAYLOAD,)
    conn.ok(CommandId.HELLO, 1, 0, "conformance")
    return True
