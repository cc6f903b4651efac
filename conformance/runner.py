"""Select cases, negotiate with the endpoint, run each case in its time budget, judge it."""

from __future__ import annotations

import fnmatch
import logging
import secrets
import socket
import threading
import time
import traceback
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from conformance.connection import Closed, WireLog
from conformance.context import (
    HELLO_FIELDS,
    PING_PATIENCE,
    Context,
    Hello,
    Options,
    Shared,
    probe_answered,
)
from conformance.model import (
    Blocked,
    Case,
    CaseResult,
    EndpointGone,
    EndpointTimeout,
    Fail,
    Informational,
    NotApplicable,
    Outcome,
    Skip,
    all_cases,
)
from spec import wire
from spec.datagrams import Trigger, encode_trigger
from spec.errors import ErrorCode
from spec.exitcodes import ExitCode
from spec.registry import BY_ID, CommandId, profiles_for
from spec.wire import PacketKind

log = logging.getLogger(__name__)

#: The case that judges Ping once when the runner has to fall back to Hello as its probe.
PING_CASE = "negotiation.ping.liveness"


@dataclass
class Selection:
    """Which cases to run: profile, globs on case IDs, tags."""

    profile: str = "core"
    select: tuple[str, ...] = ()
    exclude: tuple[str, ...] = ()
    tags: tuple[str, ...] = ()
    include: tuple[str, ...] = ()  # case IDs selected whatever the rest says (e.g. --fuzz)

    def pick(self, cases: Iterable[Case], service: str) -> list[Case]:
        out = []
        for c in cases:
            if not c.applies_to(service):
                continue
            if c.id in self.include:
                out.append(c)
                continue
            if self.select:
                if not any(fnmatch.fnmatchcase(c.id, g) for g in self.select):
                    continue
            elif self.profile not in c.profiles:
                continue
            if any(fnmatch.fnmatchcase(c.id, g) for g in self.exclude):
                continue
            if self.tags and not set(self.tags) & set(c.tags):
                continue
            out.append(c)
        return out


@dataclass
class RunResult:
    """Everything a report needs."""

    service: str
    endpoint: str
    options: Options
    profile: str
    hello: Hello | None
    reachable: bool
    negotiation_error: str
    results: list[CaseResult] = field(default_factory=list)
    measurements: dict[str, dict[str, Any]] = field(default_factory=dict)
    started: float = 0.0  # wall clock (s since the epoch)
    duration: float = 0.0  # s
    harness_errors: int = 0  # cases that ended in ERROR because of a harness fault
    #: Why nothing was run although the endpoint answers: the user's mistake, not the
    #: endpoint's (a control token missing, a TCP port given for the UDP profile).
    refused: str = ""
    #: The one line saying which request tells "stopped answering" from "refused".
    liveness: str = ""

    def scope(self) -> tuple[list[str], list[str]]:
        """(profiles claimed, profiles not covered): a profile is claimed when every one of
        its commands is offered (Hello's list minus --capabilities' not_offered)."""
        if self.service not in ("robot", "sensor") or not self.reachable or self.refused:
            return [], []
        ctx = Context(self.service, "", 0, self.options, self.hello, Shared())
        offered = ctx.advertised
        claimed: list[str] = []
        missing: list[str] = []
        for profile in profiles_for(self.service):
            (claimed if set(profile.commands) <= offered else missing).append(profile.name)
        return claimed, missing

    def scope_line(self) -> str:
        claimed, missing = self.scope()
        if not claimed and not missing:
            return ""
        text = "scope: profiles claimed " + (", ".join(claimed) or "none")
        if missing:
            text += f"; not covered (not offered): {', '.join(missing)}"
        return text


def negotiate(
    service: str, host: str, port: int, options: Options
) -> tuple[bool, Hello | None, str]:
    """Connect and send Hello: (reachable, hello or None, error text)."""
    timeout = options.reply_timeout * options.timeout_scale
    if service == "sync":
        try:
            socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except OSError as exc:
            return False, None, f"cannot resolve {host}: {exc.strerror or exc}"
        if _probe_trigger(host, port, timeout) == "refused" and not _tcp_listens(
            host, port, timeout
        ):
            return False, None, f"nothing listens on UDP {host}:{port} (port unreachable)"
        return True, None, ""  # a TCP port given by mistake: preflight says so
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except OSError as exc:
        return False, None, f"cannot connect to {host}:{port}: {exc}"
    ctx = Context(service, host, port, options, None, Shared())
    from conformance.connection import Conn

    conn = Conn(sock, WireLog(), 1, timeout)
    try:
        params = conn.ok(CommandId.HELLO, wire.VERSION_MAJOR, wire.VERSION_MINOR, "conformance")
    except EndpointTimeout:
        # Nothing at all came back: every case would only time out (a wall of them), and
        # "stopped answering" would be wrong, it never answered.
        return (
            False,
            None,
            (
                f"{host}:{port} accepted the connection but did not answer Hello within"
                f" {timeout:g} s: is it a {service} endpoint? (a slow one: --timeout-scale)"
            ),
        )
    except (Fail, EndpointGone, Closed) as exc:
        received = b"".join(e.data for e in conn.log.entries if e.direction == "<-")
        if not received and conn.closed:
            # Closed before a byte came back: every case would end the same way.
            return (
                False,
                None,
                (
                    f"{host}:{port} closed the connection without answering Hello: does it"
                    " refuse this machine (an allow-list) or take no more clients?"
                ),
            )
        if received and not received.startswith(wire.MAGIC[: len(received)]):
            # Not this protocol at all (an HTTP or SSH server on that port): one line says
            # so. Frames with the right magic but broken fields still get every case.
            return (
                False,
                None,
                (
                    f"{host}:{port} answered Hello with bytes that are not a frame"
                    f" ({_shown(received)}): is it a {service} endpoint?"
                ),
            )
        return True, None, f"Hello failed: {exc}"
    finally:
        conn.close()
        ctx.close_all()
    return True, Hello(dict(zip(HELLO_FIELDS, params, strict=False))), ""


def _shown(data: bytes, count: int = 12) -> str:
    """The first bytes of an answer, as hex and as text: ``48 54 54 50 "HTTP"``."""
    head = data[:count]
    text = "".join(chr(b) if 32 <= b < 127 else "." for b in head)
    return f'{head.hex(" ")} "{text}"'


def other_service(service: str, hello: Hello | None, endpoint: str) -> str:
    """The endpoint announces the other TCP service in Hello [RS-5.31] (a sensor port given
    to the robot suite): the user's mistake, said in one line; "" when it is not that."""
    announced = hello.text("service") if hello is not None else ""
    if announced in ("robot", "sensor") and announced != service:
        return (
            f"{endpoint} is a {announced} endpoint (its Hello says so), not a {service} one:"
            f" check it with `python -m conformance {announced} {endpoint}`; nothing was run"
        )
    return ""


def preflight(service: str, host: str, port: int, options: Options) -> str:
    """Mistakes of the user that would make most cases skip or fail for the wrong reason:
    a control token the endpoint wants and was not given, a TCP port given to the UDP sync
    profile. Returns the one-line reason, or "" when the run can go ahead."""
    timeout = options.reply_timeout * options.timeout_scale
    if service == "sync":
        return _tcp_port_for_udp(host, port, timeout)
    from conformance.connection import Conn

    try:
        conn = Conn(socket.create_connection((host, port), timeout=timeout), WireLog(), 1, timeout)
    except OSError:
        return ""
    try:
        answer = conn.call(CommandId.TAKE_CONTROL, options.token)
        if answer.error is not None and answer.error[0] == ErrorCode.AUTH_FAILED:
            given = "the token given was refused" if options.token else "none was given"
            return (
                f"the {service} requires a control token ({given}): pass --token or"
                " --token-file; nothing was run"
            )
        if answer.error is None:
            conn.call(CommandId.RELEASE_CONTROL)
    except (Fail, EndpointTimeout, EndpointGone, Closed):
        return ""  # the cases will say what is wrong
    finally:
        conn.close()
    return ""


def _tcp_port_for_udp(host: str, port: int, timeout: float) -> str:
    """The sync profile talks UDP to the sensor's trigger port; a TCP listener there that
    does not answer a trigger is the sensor's command port given by mistake."""
    if _probe_trigger(host, port, timeout) == "answered" or not _tcp_listens(host, port, timeout):
        return ""
    return (
        f"{host}:{port} is a TCP port and no trigger was answered there: the sync"
        " profile needs the sensor's UDP trigger port (GetTriggerEndpoint tells it,"
        " e.g. `python -m sensorsocket call HOST:2000 GetTriggerEndpoint`)"
    )


def _probe_trigger(host: str, port: int, timeout: float) -> str:
    """Send one trigger: "answered" (a datagram came back), "refused" (the host said
    nothing listens on that UDP port) or "silent"."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_DGRAM) as udp:
        udp.settimeout(min(timeout, 1.0))
        try:
            udp.connect((host, port))  # connected: the host's "port unreachable" is reported
            udp.send(encode_trigger(Trigger(secrets.randbelow(1 << 31), 0.0)))
            udp.recv(2048)
            return "answered"
        except ConnectionRefusedError:
            return "refused"
        except OSError:
            return "silent"


def _tcp_listens(host: str, port: int, timeout: float) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


def _judge(case: Case, exc: Fail) -> Outcome:
    if case.level == "MUST":
        return Outcome.FAIL
    if case.level == "SHOULD":
        return Outcome.NON_STRICT
    return Outcome.INFORMATIONAL


def run_case(case: Case, ctx: Context) -> CaseResult:
    """Run one case in a worker thread, bounded by its budget."""
    result = CaseResult(case, Outcome.ERROR)
    budget = ctx.scaled(case.budget)
    box: dict[str, Any] = {}

    def work() -> None:
        try:
            box["note"] = case.fn(ctx)
        except BaseException as exc:  # noqa: BLE001  fault barrier: the case's outcome, any cause
            box["exc"] = exc
            box["tb"] = traceback.format_exc()

    t0 = time.monotonic()
    worker = threading.Thread(target=work, name=f"case-{case.id}", daemon=True)
    worker.start()
    worker.join(budget)
    hung = worker.is_alive()
    ctx.close_all()  # unblocks a hung worker: its socket calls fail and it ends
    if hung:
        worker.join(1.0)
    result.duration = time.monotonic() - t0
    exc = box.get("exc")
    if hung:
        result.outcome = Outcome.TIMEOUT
        result.message = f"the case did not finish within its budget of {budget:.3g} s"
    elif exc is None:
        note = box.get("note")
        result.outcome = Outcome.INFORMATIONAL if case.level == "INFO" else Outcome.PASS
        result.message = note if isinstance(note, str) else ""
    elif isinstance(exc, Fail):
        result.outcome = _judge(case, exc)
        req = f" [{exc.requirement}]" if exc.requirement else ""
        result.message = exc.message + req
        result.expected = exc.expected
        result.actual = exc.actual
    elif isinstance(exc, NotApplicable):
        result.outcome, result.message = Outcome.NOT_APPLICABLE, str(exc)
    elif isinstance(exc, Blocked):
        result.outcome, result.message = Outcome.BLOCKED, str(exc)
        result.details["precondition"] = exc.precondition
    elif isinstance(exc, Skip):
        result.outcome, result.message = Outcome.SKIPPED, str(exc)
    elif isinstance(exc, Informational):
        result.outcome, result.message = Outcome.INFORMATIONAL, str(exc)
    elif isinstance(exc, EndpointTimeout):
        result.outcome, result.message = Outcome.TIMEOUT, str(exc)
    elif isinstance(exc, Closed) and ctx.alive():
        # Closed where an answer was due, while the endpoint lives on: [RS-6.2] is broken.
        result.outcome = Outcome.FAIL if case.level == "MUST" else Outcome.NON_STRICT
        result.message = "the endpoint closed the connection where an answer was due [RS-6.2]"
        result.expected, result.actual = "exactly one reply or error frame", f"closed ({exc})"
    elif isinstance(exc, EndpointGone | Closed):
        result.outcome, result.message = Outcome.ERROR, f"endpoint: {exc}"
        result.details["endpoint_error"] = True
    else:
        result.outcome = Outcome.ERROR
        result.message = f"harness fault: {type(exc).__name__}: {exc}"
        result.details["harness_error"] = True
        result.details["traceback"] = box.get("tb", "")
    result.wire = list(ctx.log.entries)
    result.wire_truncated = ctx.log.dropped
    result.details.update(ctx.details)
    return result


def _sends_ping(result: CaseResult) -> bool:
    """True when a frame the case sent starts with a Ping request header."""
    for entry in result.wire:
        data = entry.data
        if entry.direction == "->" and len(data) >= wire.HEADER_SIZE:
            magic, _, _, kind, _, command, _, _ = wire.HEADER.unpack_from(data)
            if magic == wire.MAGIC and kind == PacketKind.REQUEST and command == CommandId.PING:
                return True
    return False


def liveness_line(probe: int, why: str = "") -> str:
    """The one line of the summary that names the liveness probe."""
    line = (
        f"liveness probe: {BY_ID[probe].name} (0x{probe:04x}) on a new connection; no answer"
        " in time = stopped answering, connection refused or closed = refused"
    )
    if why:
        line += f" (Ping is not answered: {why}; breaks RS-5.8, see negotiation.ping.liveness)"
    return line


def choose_probe(host: str, port: int, options: Options) -> tuple[int, str]:
    """Ping on a new connection is the liveness probe; an endpoint that answers Hello but
    not Ping (a proxy that swallows it) gets Hello instead, so one broken rule is reported
    once and not as a wall of timeouts. Returns (command, why Ping was not used)."""
    ping_failed = ""
    for command in (CommandId.PING, CommandId.HELLO):
        ctx = Context("robot", host, port, options, None, Shared(probe_command=command))
        try:
            if probe_answered(ctx.connect(), ctx.shared, ctx.timeout * PING_PATIENCE):
                return command, ping_failed
            ping_failed = ping_failed or "Ping is answered without its bytes echoed"
        except (Fail, EndpointTimeout, EndpointGone, Closed) as exc:
            ping_failed = ping_failed or str(exc) or type(exc).__name__
        finally:
            ctx.close_all()
    return CommandId.PING, ""  # answers neither: the cases say what is wrong


def alive(
    host: str, port: int, options: Options, probe: int = CommandId.PING
) -> tuple[Outcome, str]:
    """(PASS, '') when the endpoint still answers the liveness probe on a new connection,
    else the outcome the remaining cases get (TIMEOUT when it hangs, ERROR when it refuses)
    and why."""
    ctx = Context("robot", host, port, options, None, Shared(probe_command=probe))
    try:
        if not probe_answered(ctx.connect(), ctx.shared):
            return Outcome.ERROR, f"{BY_ID[probe].name} not answered as its table says"
        return Outcome.PASS, ""
    except EndpointTimeout as exc:
        return Outcome.TIMEOUT, str(exc)
    except (Fail, EndpointGone, Closed) as exc:
        return Outcome.ERROR, str(exc) or type(exc).__name__
    finally:
        ctx.close_all()


def _blocked_if_it_rode_on_ping(result: CaseResult) -> None:
    """Ping is a failed case's vehicle, not its rule: the one broken rule is reported by
    PING_CASE, not again by every case that rides on it."""
    if result.is_problem and _sends_ping(result):
        result.outcome = Outcome.BLOCKED
        result.message = (
            f"blocked: precondition Ping answered failed (see {PING_CASE});"
            f" the case sends Ping. It ended: {result.message}"
        )
        result.details["precondition"] = "Ping answered"


def _mark_expected(result: CaseResult) -> None:
    """A case the user expects to fail (``--expect``): a failure is known, a pass news."""
    if result.outcome in (Outcome.FAIL, Outcome.NON_STRICT):
        result.known_failure = True
    elif result.outcome is Outcome.PASS:
        result.unexpected_pass = True


def run(
    service: str,
    host: str,
    port: int,
    options: Options,
    selection: Selection,
    expect: frozenset[str] = frozenset(),
    progress: Callable[[CaseResult], None] | None = None,
) -> RunResult:
    """Negotiate, then run the selected cases in order; never raises for endpoint faults."""
    started = time.time()
    t0 = time.monotonic()
    cases = selection.pick(all_cases(), service)
    reachable, hello, why = negotiate(service, host, port, options)
    run_result = RunResult(
        service, f"{host}:{port}", options, selection.profile, hello, reachable, why
    )
    run_result.started = started
    if not reachable:
        run_result.duration = time.monotonic() - t0
        return run_result  # one line says why; no case could have run
    run_result.refused = other_service(service, hello, run_result.endpoint) or preflight(
        service, host, port, options
    )
    if run_result.refused:
        run_result.duration = time.monotonic() - t0
        return run_result
    shared = Shared(next_index=1000 + (options.seed % 1000) * 1_000_000)
    ping_failed = ""
    if service != "sync":
        shared.probe_command, ping_failed = choose_probe(host, port, options)
        run_result.liveness = liveness_line(shared.probe_command, ping_failed)
    dead = "" if reachable else why
    dead_outcome = Outcome.ERROR
    for case in cases:
        if dead:
            result = CaseResult(case, dead_outcome, f"not run: endpoint {dead}")
            result.details["endpoint_error"] = True
        elif case.motion and not options.allow_motion:
            result = CaseResult(
                case, Outcome.SKIPPED, "moves the robot or switches an output: needs --allow-motion"
            )
        else:
            ctx = Context(service, host, port, options, hello, shared)
            missing = [c for c in case.commands if c not in ctx.advertised]
            if missing:
                names = ", ".join(f"0x{c:04x}" for c in missing)
                result = CaseResult(case, Outcome.NOT_APPLICABLE, f"not offered: {names}")
            elif ping_failed and CommandId.PING in case.commands and case.id != PING_CASE:
                result = CaseResult(
                    case,
                    Outcome.BLOCKED,
                    f"blocked: precondition Ping answered failed (see {PING_CASE})",
                )
                result.details["precondition"] = "Ping answered"
            else:
                result = run_case(case, ctx)
                if ping_failed and case.id != PING_CASE:
                    _blocked_if_it_rode_on_ping(result)
                if result.outcome in (Outcome.TIMEOUT, Outcome.ERROR) and service != "sync":
                    # One dead endpoint must not cost every remaining case its full budget.
                    dead_outcome, dead = alive(host, port, options, shared.probe_command)
                    if dead:
                        dead = f"stopped answering after {case.id} ({dead})"
        if case.id in expect:
            _mark_expected(result)
        if result.details.get("harness_error"):
            run_result.harness_errors += 1
        run_result.results.append(result)
        if progress is not None:
            progress(result)
    run_result.measurements = shared.measurements
    run_result.duration = time.monotonic() - t0
    return run_result


def exit_code(run_result: RunResult, strict: bool = False) -> int:
    """The process exit code for a run (:class:`spec.exitcodes.ExitCode`, docs/CONFORMANCE.md)."""
    results = run_result.results
    if not run_result.reachable:
        return ExitCode.UNREACHABLE
    if run_result.refused:
        return ExitCode.USAGE
    if not results:
        return ExitCode.NOTHING_SELECTED
    fresh = [r for r in results if not r.known_failure]
    if any(r.outcome is Outcome.FAIL for r in fresh):
        return ExitCode.FAILED
    if any(
        r.outcome in (Outcome.ERROR, Outcome.TIMEOUT) and not r.details.get("harness_error")
        for r in fresh
    ):
        return ExitCode.UNREACHABLE
    if run_result.harness_errors:  # the harness cannot vouch for a verdict it did not reach
        return ExitCode.UNTRUSTED
    if strict and any(r.outcome is Outcome.NON_STRICT for r in fresh):
        return ExitCode.SHOULD_FAILED
    if run_result.scope()[1]:
        return ExitCode.SUBSET
    return ExitCode.OK
