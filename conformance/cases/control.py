"""Control ownership and several clients (PROTOCOL.md section 7)."""

from __future__ import annotations

import select
import statistics
import threading
import time

from conformance.cases._util import endpoint_status
from conformance.connection import Closed, Conn
from conformance.context import Context
from conformance.model import EndpointTimeout, Fail, Informational, NotApplicable, Skip, case
from spec import messages as M
from spec.errors import ErrorCode
from spec.registry import CommandId as C

#: A refused (reserved) connection is closed within this many seconds [RS-7.2].
RESERVED_CLOSE_S = 5.0
#: A robot keeps a refused connection open (reserved) at least this long [RS-7.14] ...
RESERVED_OPEN_S = 1.0
#: ... measured from the BUSY frame's arrival, which follows the accept by a little.
RESERVED_SLACK_S = 0.05


def _control_probe(ctx: Context) -> int:
    """A control command that changes nothing and that the endpoint advertises."""
    for c in (C.RESET_MOTION, C.STOP_TRIGGERS, C.ACQUIRE, C.SET_LASER):
        if c in ctx.advertised:
            return int(c)
    raise NotApplicable("the endpoint offers no harmless control command to probe with")


@case("control.take_release", requirements=["RS-7.11", "RS-7.8"], tags=["control"])
def take_release(ctx: Context) -> None:
    """TakeControl twice succeeds for the holder; ReleaseControl twice is harmless."""
    conn = ctx.connect()
    conn.ok(C.RELEASE_CONTROL)  # not holding it: no error [RS-7.11]
    ctx.take_control(conn)
    conn.ok(C.TAKE_CONTROL, ctx.options.token)  # the holder again [RS-7.8]
    conn.ok(C.RELEASE_CONTROL)
    conn.ok(C.RELEASE_CONTROL)


@case("control.exclusive", requirements=["RS-7.8", "RS-7.11"], tags=["control", "concurrency"])
def exclusive(ctx: Context) -> None:
    """While A holds control B gets BUSY; after A releases, B takes it."""
    a, b = ctx.connect(), ctx.connect()
    ctx.take_control(a)
    try:
        b.error(C.TAKE_CONTROL, ErrorCode.BUSY, ctx.options.token)
        a.ok(C.RELEASE_CONTROL)
        b.ok(C.TAKE_CONTROL, ctx.options.token)
        a.error(C.TAKE_CONTROL, ErrorCode.BUSY, ctx.options.token)
    finally:
        b.call(C.RELEASE_CONTROL)


@case("control.read_only_open", requirements=["RS-7.4"], tags=["control", "concurrency"])
def read_only_open(ctx: Context) -> None:
    """While A holds control, B's read-only commands are answered and its control ones are not."""
    a, b = ctx.connect(), ctx.connect()
    ctx.take_control(a)
    try:
        endpoint_status(ctx, b)
        b.ok(C.GET_TIME)
        probe = _control_probe(ctx)
        args = (a.ask(M.SensorStatusRequest()).laser,) if probe == C.SET_LASER else ()
        b.error(probe, ErrorCode.NOT_IN_CONTROL, *args)
    finally:
        a.call(C.RELEASE_CONTROL)


@case("control.released_on_close", requirements=["RS-7.8"], tags=["control"])
def released_on_close(ctx: Context) -> None:
    """When the holder disconnects, another connection can take control."""
    a = ctx.connect()
    ctx.take_control(a)
    a.close()
    b = ctx.connect()
    deadline = time.monotonic() + ctx.timeout
    while True:
        answer = b.call(C.TAKE_CONTROL, ctx.options.token)
        if answer.error is None:
            break
        if time.monotonic() > deadline:
            raise Fail(
                "control is not freed when its holder disconnects",
                "TakeControl succeeds on another connection",
                f"error {answer.error[0]}: {answer.error[1]}",
            )
        time.sleep(0.02)
    b.ok(C.RELEASE_CONTROL)


@case("control.token", requirements=["RS-7.3"], tags=["control", "security"])
def token(ctx: Context) -> str:
    """A wrong control token gets AUTH_FAILED (not applicable when no token is configured)."""
    conn = ctx.connect()
    answer = conn.call(C.TAKE_CONTROL, ctx.options.token + "-wrong-conformance-token")
    if answer.error is None:
        conn.call(C.RELEASE_CONTROL)
        if ctx.options.token:
            raise Fail("a wrong token was accepted", "AUTH_FAILED", "control granted")
        raise NotApplicable("the endpoint has no control token (any token is accepted)")
    if answer.error[0] != ErrorCode.AUTH_FAILED:
        raise Fail("wrong error for a wrong token", "AUTH_FAILED", answer.error)
    if not ctx.options.token:
        return "a token is configured; pass it with --token to run the control cases"
    return "wrong token refused"


@case(
    "connections.several_clients",
    requirements=["RS-7.1"],
    tags=["concurrency"],
    profiles=("smoke", "core", "full"),
)
def several_clients(ctx: Context) -> None:
    """Eight connections, interleaved requests: each gets its own answers."""
    conns = [ctx.connect() for _ in range(8)]
    for round_ in range(3):
        for i, conn in enumerate(conns):
            conn.request(C.PING, f"{i}/{round_}".encode(), request_id=1000 * i + round_ + 1)
        for i in reversed(range(len(conns))):
            answer = conns[i].recv_packet()
            want = (f"{i}/{round_}".encode(),)
            if answer.request_id != 1000 * i + round_ + 1 or answer.params[:1] != want:
                raise Fail("a connection got a wrong answer", want, answer.params[:1])


@case(
    "connections.max_clients",
    requirements=["RS-7.2", "RS-7.14"],
    tags=["concurrency", "limits"],
    profiles=("full",),
    budget=30.0,
    order=65,
)
def max_clients(ctx: Context) -> str:
    """Connections beyond max_clients get BUSY with request ID 0 and are closed within 5 s; a
    robot keeps such a connection open (reserved for EmergencyStop) for at least 1 s."""
    limit = int(ctx.hello.number("max_clients", 0)) if ctx.hello else 0
    if not 0 < limit <= 256:
        raise Skip(f"max_clients {limit} is not in 1..256; not tried")
    conns = []
    try:
        for i in range(limit + 2):
            conn = ctx.connect()
            conns.append(conn)
            conn.request(C.PING, b"n", request_id=i + 1)
            try:
                answer = conn.recv_packet()
            except Closed:
                raise Fail(
                    "a connection over the limit was closed without an error frame",
                    "error BUSY, request ID 0",
                    "closed silently",
                    requirement="RS-7.2",
                ) from None
            if answer.error is None:
                continue
            if answer.error[0] != ErrorCode.BUSY or answer.request_id != 0:
                raise Fail("wrong refusal over the limit", "BUSY with request ID 0", answer.error)
            busy_at = time.monotonic()
            try:
                # A reserved connection [RS-7.14] answers BUSY until it closes (<= 5 s).
                later = conn.expect_closed(RESERVED_CLOSE_S + ctx.timeout)
            except EndpointTimeout:
                raise Fail(
                    "the refused connection stays open",
                    f"closed within {RESERVED_CLOSE_S:g} s",
                    "open",
                    requirement="RS-7.2",
                ) from None
            open_s = time.monotonic() - busy_at
            if ctx.service == "robot" and open_s < RESERVED_OPEN_S - RESERVED_SLACK_S:
                raise Fail(
                    "a robot's refused connection closed before EmergencyStop had its chance",
                    f"open at least {RESERVED_OPEN_S:g} s after the BUSY frame (reserved)",
                    f"closed after {open_s:.3f} s",
                    requirement="RS-7.14",
                )
            for packet in later:
                if packet.error is None or packet.error[0] != ErrorCode.BUSY:
                    raise Fail(
                        "a refused connection served a request",
                        "BUSY for every request but EmergencyStop",
                        packet.error or packet.params,
                        requirement="RS-7.14",
                    )
            if i < limit - 1:
                # Sessions of earlier cases may still be closing; accept a small slack.
                ctx.details["busy_at"] = i + 1
            return f"connection {i + 1} refused with BUSY (max_clients {limit})"
        raise Fail(
            "no connection was refused",
            f"BUSY at connection {limit + 1}",
            f"{limit + 2} accepted",
            requirement="RS-7.2",
        )
    finally:
        for conn in conns:
            conn.close()


#: Reserved connections the eviction case fills before it gives up finding the limit.
RESERVED_TRIED = 16


def _closed_now(conns: list[Conn], wait: float) -> list[int]:
    """The indices of ``conns`` the endpoint has closed (each had nothing left to read): EOF
    arrives at once on a closed connection, so one short ``select`` finds them all."""
    readable, _, _ = select.select([c.sock for c in conns], [], [], wait)
    closed = []
    for i, conn in enumerate(conns):
        if conn.sock in readable:
            try:
                conn.expect_closed(wait)
            except EndpointTimeout:
                continue  # a frame, not the close: the caller judges what it is not
            closed.append(i)
    return closed


def _reserved(conn: Conn) -> bool:
    """Whether ``conn`` was refused at connect (BUSY with request ID 0, [RS-7.2]); then its
    GetStatus is answered BUSY too (a reserved connection serves EmergencyStop only)."""
    rid = conn.request(C.ROBOT_STATUS)
    first = conn.recv_packet()
    if first.error is None or first.request_id != 0:
        return False
    answer = conn.answer_to(C.ROBOT_STATUS, rid)
    if answer.error is None or answer.error[0] != ErrorCode.BUSY:
        raise Fail(
            "a reserved connection served GetStatus",
            "BUSY for every request but EmergencyStop",
            answer.error or "a reply",
            requirement="RS-7.14",
        )
    return True


@case(
    "connections.reserved.oldest_closed",
    requirements=["RS-7.14"],
    tags=["robot", "safety", "limits", "concurrency"],
    service="robot",
    profiles=("full",),
    budget=30.0,
    order=67,
    commands=[C.ROBOT_STATUS],
)
def reserved_oldest_closed(ctx: Context) -> str:
    """With the client limit reached and every reserved connection taken, one connection more
    makes the robot close the oldest reserved connection, not the newest (which keeps its
    chance of an EmergencyStop) nor any other."""
    limit = int(ctx.hello.number("max_clients", 0)) if ctx.hello else 0
    if not 0 < limit <= 256:
        raise Skip(f"max_clients {limit} is not in 1..256; not tried")
    conns: list[Conn] = []
    reserved: list[Conn] = []
    first_at = 0.0
    try:
        for _ in range(limit + RESERVED_TRIED + 1):
            conn = ctx.connect()
            conns.append(conn)
            try:
                if not _reserved(conn):
                    continue  # served (a slot may come free as an earlier case's closes)
            except Closed:
                pass  # closed at once: the newest is one of those closed, judged below
            reserved.append(conn)
            if len(reserved) == 1:
                first_at = time.monotonic()
            closed = _closed_now(reserved, ctx.scaled(0.02))
            age = time.monotonic() - first_at
            if age >= RESERVED_OPEN_S - RESERVED_SLACK_S:
                # The oldest may close on its own time now: an eviction is not told apart.
                raise Informational(
                    f"{len(reserved)} reserved connections in {age:.2f} s: the oldest may have"
                    " timed out by now, so which one makes room is not judged"
                )
            if not closed:
                continue
            n = len(reserved)
            if n == 1:
                raise Fail(
                    "a robot's refused connection closed at once",
                    f"open at least {RESERVED_OPEN_S:g} s after the BUSY frame (reserved)",
                    "closed",
                    requirement="RS-7.14",
                )
            if closed != [0]:
                raise Fail(
                    "the reserved connection closed to make room is not the oldest",
                    f"connection 1 of the {n} reserved closed, connection {n} open",
                    f"reserved connection(s) {', '.join(str(i + 1) for i in closed)} closed",
                    requirement="RS-7.14",
                )
            return f"{n - 1} reserved connection(s) held; connection {n} closed the oldest"
        raise Informational(f"{RESERVED_TRIED} reserved connections held, none closed")
    finally:
        for conn in conns:
            conn.close()


@case(
    "connections.load.round_trip",
    requirements=["RS-7.1", "RS-3.10"],
    tags=["concurrency", "measurement"],
    profiles=("core", "full"),
    budget=20.0,
)
def load_round_trip(ctx: Context) -> str:
    """Four clients send 50 Pings each at the same time; all answered; round trips measured."""
    errors: list[str] = []
    rtts: list[float] = []
    lock = threading.Lock()
    conns = [ctx.connect() for _ in range(4)]

    def client(i: int) -> None:
        conn = conns[i]
        try:
            for k in range(50):
                data = f"{i}:{k}".encode()
                t0 = time.perf_counter()
                echo = conn.ask(M.PingRequest(data)).data
                dt = time.perf_counter() - t0
                if echo != data:
                    errors.append(f"client {i} request {k}: echo {echo!r}")
                    return
                with lock:
                    rtts.append(dt)
        except Exception as exc:  # noqa: BLE001  a client thread's failure, reported below
            errors.append(f"client {i}: {type(exc).__name__}: {exc}")

    threads = [threading.Thread(target=client, args=(i,)) for i in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise Fail("concurrent clients did not all get their answers", "200 echoes", errors[0])
    rtts.sort()
    q = statistics.quantiles(rtts, n=100, method="inclusive")
    ctx.measure(
        "tcp_round_trip",
        samples=len(rtts),
        p50_ms=round(q[49] * 1000, 4),
        p90_ms=round(q[89] * 1000, 4),
        p99_ms=round(q[98] * 1000, 4),
        max_ms=round(rtts[-1] * 1000, 4),
    )
    return f"Ping round trip p50 {q[49] * 1000:.3f} ms, p99 {q[98] * 1000:.3f} ms"


@case(
    "control.watchdog",
    requirements=["RS-7.13"],
    tags=["control", "safety"],
    budget=30.0,  # ~1.5 s; the budget is scaled down in the harness's self-tests
)
def watchdog(ctx: Context) -> str:
    """A controller that keeps sending frames keeps control; one that goes silent for longer
    than its watchdog period loses it (NOT_IN_CONTROL, and GetStatus shows nobody in control)."""
    probe = _control_probe(ctx)
    period = 0.3
    conn = ctx.connect()
    ctx.take_control(conn, watchdog=period)
    if conn.lease is None:
        raise NotApplicable("the endpoint grants no control lease (a 1.0 TakeControl)")
    if abs(conn.lease - period) > 1e-9:
        raise Fail("the watchdog period asked for was not granted", period, conn.lease)
    _keep_lease(ctx, conn, probe, period)
    time.sleep(period * 2 + 0.2)
    answer = conn.call(probe)
    if answer.error is None or answer.error[0] != ErrorCode.NOT_IN_CONTROL:
        raise Fail(
            f"a controller silent for {period * 2 + 0.2:g} s kept control",
            "NOT_IN_CONTROL",
            answer.error or "executed",
            requirement="RS-7.13",
        )
    other = ctx.connect()
    controlled = endpoint_status(ctx, other).controlled
    if controlled is not False:
        raise Fail("control still held after the watchdog", "controlled false", controlled)
    bad = conn.call(C.TAKE_CONTROL, ctx.options.token, 1.0e6)
    if bad.error is None or bad.error[0] != ErrorCode.OUT_OF_RANGE:
        raise Fail(
            "a watchdog period of 1e6 s was not refused",
            "OUT_OF_RANGE",
            bad.error or "granted",
            requirement="RS-7.13",
        )
    conn.call(C.RELEASE_CONTROL)
    return f"lease {period:g} s kept by Pings, lost after silence"


#: Tries of the keep-alive part of control.watchdog before a harness too late to keep its own
#: pace gives up (a busy machine: a case cannot judge a lease it did not keep itself).
KEEP_TRIES = 3


def _keep_lease(ctx: Context, conn: Conn, probe: int, period: float) -> None:
    """1.2 s of Pings, each well inside the lease ``period``, then ``probe`` still has
    control [RS-7.13]. A gap between the harness's own frames near the lease (the harness's
    process not run in time) judges nothing: control is taken again and the part repeated;
    after ``KEEP_TRIES`` such tries the case is skipped with the gap, never failed."""
    gap = 0.0
    for _ in range(KEEP_TRIES):
        last, gap = time.monotonic(), 0.0
        for ping in range(9):  # 8 Pings, then the probe
            time.sleep(period / 4)
            now = time.monotonic()
            gap, last = max(gap, now - last), now
            if gap > 0.8 * period:
                break
            if ping < 8:
                conn.ok(C.PING, b"lease")
                continue
            answer = conn.call(probe)
            if answer.error is not None:
                raise Fail(
                    "a controller that kept sending frames lost control",
                    "control kept",
                    answer.error,
                    requirement="RS-7.13",
                )
            return
        ctx.take_control(conn, watchdog=period)  # the lease may be lost: take it again
    raise Skip(
        f"the harness could not keep its own pace: {gap:.3f} s between two of its frames "
        f"against a {period:g} s lease (a busy machine; try again, or --timeout-scale)"
    )


#: [RS-7.13] the longest default lease a server may grant a TakeControl without a period.
MAX_DEFAULT_LEASE_S = 1.0


@case(
    "control.watchdog.default",
    requirements=["RS-7.13", "RS-7.10"],
    tags=["control", "safety"],
    budget=20.0,  # ~1.5 s at most; scaled down in the harness's self-tests
)
def watchdog_default(ctx: Context) -> str:
    """A 1.0/1.1 TakeControl (no watchdog parameter) gets the server's default lease, at most
    1 s; a controller that then stays silent for longer than it loses control."""
    probe = _control_probe(ctx)
    conn = ctx.connect()
    ctx.take_control(conn, watchdog=None)
    try:
        lease = conn.lease
        if lease is None:
            raise NotApplicable("the endpoint grants no control lease (a 1.0/1.1 TakeControl)")
        if not 0.0 < lease <= MAX_DEFAULT_LEASE_S:
            raise Fail(
                "the default lease of a TakeControl without a period",
                f"0 < lease <= {MAX_DEFAULT_LEASE_S:g} s",
                f"{lease:g} s",
                requirement="RS-7.13",
            )
        silence = lease * 1.5 + 0.2
        time.sleep(silence)
        answer = conn.call(probe)
    finally:
        conn.call(C.RELEASE_CONTROL)
    if answer.error is None or answer.error[0] != ErrorCode.NOT_IN_CONTROL:
        raise Fail(
            f"a 1.0-style controller silent for {silence:.2f} s (default lease {lease:g} s)"
            " kept control",
            "NOT_IN_CONTROL",
            answer.error or "executed",
            requirement="RS-7.13",
        )
    return f"default lease {lease:g} s; lost after {silence:.2f} s of silence"


@case(
    "connections.per_address_limit",
    requirements=["RS-7.24"],
    tags=["concurrency", "limits", "security"],
    profiles=("full",),
    budget=30.0,
    order=66,
)
def per_address_limit(ctx: Context) -> str:
    """max_clients + 8 connections from 127.0.0.2, each stopped after the first byte of a
    frame, leave a connection from 127.0.0.1 served (an endpoint on loopback only)."""
    import ipaddress
    import socket

    try:
        loopback = ipaddress.ip_address(ctx.host).is_loopback
    except ValueError:
        loopback = ctx.host == "localhost"
    if not loopback:
        raise NotApplicable("needs a second source address: runs against a loopback endpoint")
    limit = int(ctx.hello.number("max_clients", 0)) if ctx.hello else 0
    if not 1 <= limit <= 256:
        raise Skip(f"max_clients {limit} is not in 1..256; not tried")
    flood: list[socket.socket] = []
    try:
        for _ in range(limit + 8):
            s = socket.socket()
            s.settimeout(ctx.timeout)
            try:
                s.bind(("127.0.0.2", 0))
                s.connect((ctx.host if ctx.host != "localhost" else "127.0.0.1", ctx.port))
                s.sendall(b"R")
            except OSError as exc:
                s.close()
                if not flood:
                    raise NotApplicable(f"cannot connect from 127.0.0.2: {exc}") from None
                break
            flood.append(s)
        time.sleep(0.2)  # the endpoint accepts them
        try:
            conn = ctx.connect()
            answer = conn.call(C.PING, b"fair")
        except Closed:
            answer = None
        if answer is None or answer.error is not None:
            why = "closed" if answer is None else answer.error
            raise Fail(
                f"{len(flood)} stalled connections from 127.0.0.2 locked out 127.0.0.1",
                "Ping answered",
                why,
            )
    finally:
        for s in flood:
            s.close()
    return f"{len(flood)} connections from 127.0.0.2; 127.0.0.1 still served"
