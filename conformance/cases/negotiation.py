"""Negotiation: Hello, version, advertised commands and limits (PROTOCOL.md 1, 5.1, 5.2)."""

from __future__ import annotations

from conformance.cases._util import NOT_OFFERED, raw_frame
from conformance.cases.commands import dummy
from conformance.context import PING_PATIENCE, Context
from conformance.model import EndpointTimeout, Fail, Informational, case
from spec import messages as M
from spec import wire
from spec.codec import Packet
from spec.errors import ErrorCode
from spec.registry import BY_ID, commands_for, profiles_for
from spec.registry import CommandId as C

SMOKE = ("smoke", "core", "full")


@case(
    "negotiation.ping.liveness",
    requirements=["RS-5.8"],
    tags=["negotiation", "liveness"],
    profiles=("smoke", "core", "full", "robustness"),
    commands=[C.PING],
    order=5,
    budget=15.0,  # Ping gets PING_PATIENCE reply times, then Hello one
)
def ping_liveness(ctx: Context) -> str:
    """A new connection's Ping is echoed: the harness's liveness probe (see the summary's
    "liveness probe" line). An endpoint that answers Hello but not Ping breaks RS-5.8 here,
    once; the runner then probes with Hello so the other cases are judged on their own."""
    payload = b"conformance-liveness"
    conn = ctx.connect()
    try:
        echoed = conn.ask(M.PingRequest(payload), timeout=ctx.timeout * PING_PATIENCE).data
    except EndpointTimeout:
        other = ctx.connect()
        other.ok(C.HELLO, 1, 0, "conformance")  # a timeout here too: the endpoint hangs
        raise Fail(
            "Ping is not answered although Hello is",
            "Ping's reply echoing its bytes",
            f"no answer within {ctx.timeout * PING_PATIENCE:g} s",
            requirement="RS-5.8",
        ) from None
    if echoed != payload:
        raise Fail("Ping does not echo its bytes", payload, echoed, requirement="RS-5.8")
    return "Ping echoed on a new connection"


@case(
    "negotiation.hello.reply",
    requirements=["RS-5.2", "RS-5.5", "RS-1.1"],
    tags=["negotiation"],
    profiles=SMOKE,
    order=10,
)
def hello_reply(ctx: Context) -> str:
    """Hello returns version, service, identity, commands and limits with the table's types."""
    conn = ctx.connect()
    hello = conn.ask(M.HelloRequest(1, 0, "conformance"))
    version = hello.version
    if not version.startswith(f"{wire.VERSION_MAJOR}."):
        raise Fail("Hello reports another major version", "1.x", version, requirement="RS-5.2")
    if hello.service != ctx.service:
        raise Fail("Hello names another service", ctx.service, hello.service)
    ctx.details["hello"] = {k: repr(v) for k, v in hello.as_dict().items()}
    return f"{hello.vendor} {hello.model} serial {hello.serial} version {version}"


@case(
    "negotiation.hello.major_mismatch",
    requirements=["RS-5.2"],
    tags=["negotiation", "errors"],
    profiles=SMOKE,
    order=10,
)
def hello_major_mismatch(ctx: Context) -> None:
    """A client speaking major version 2 gets UNSUPPORTED_VERSION."""
    conn = ctx.connect()
    conn.error(C.HELLO, ErrorCode.UNSUPPORTED_VERSION, 2, 0, "conformance-v2")
    conn.ok(C.PING, b"still open")


@case(
    "negotiation.hello.commands_ranges",
    requirements=["RS-5.7", "RS-5.3"],
    tags=["negotiation"],
    order=10,
)
def commands_ranges(ctx: Context) -> str:
    """Advertised command IDs lie in the common, own-service, vendor or experimental ranges."""
    conn = ctx.connect()
    cmds = conn.ask(M.HelloRequest(1, 0, "conformance")).commands
    own = [wire.COMMON_RANGE, wire.VENDOR_RANGE, wire.EXPERIMENTAL_RANGE]
    own += [wire.ROBOT_RANGE, wire.SYNC_RANGE] if ctx.service == "robot" else [wire.SENSOR_RANGE]
    bad = [c for c in cmds.values if not any(c in r for r in own)]
    if bad:
        raise Fail(
            "Hello advertises command IDs outside the ranges of this service",
            "IDs in 0x0001-0x0FFF, the service's range, 0x8000-0xBFFF or 0xC000-0xFFFE",
            ", ".join(f"0x{c:04x}" for c in bad),
            requirement="RS-5.7",
        )
    for needed in (C.HELLO, C.PING, C.TAKE_CONTROL, C.RELEASE_CONTROL, C.GET_TIME):
        if needed not in cmds.values:
            raise Fail(
                "Hello does not list a common command it must answer",
                f"0x{int(needed):04x} in commands",
                sorted(cmds.values),
                requirement="RS-5.3",
            )
    vendor = [c for c in cmds.values if c in wire.VENDOR_RANGE or c in wire.EXPERIMENTAL_RANGE]
    return f"{len(cmds.values)} commands, {len(vendor)} vendor/experimental"


@case(
    "negotiation.hello.commands_complete",
    requirements=["RS-5.3", "RS-5.1"],
    tags=["negotiation"],
    budget=15.0,
    order=11,
)
def commands_complete(ctx: Context) -> str:
    """Registry commands not advertised in Hello are answered as not offered: NOT_SUPPORTED
    [RS-5.62] or UNKNOWN_COMMAND (1.2), never as if offered."""
    conn = ctx.connect()
    advertised = ctx.hello.commands if ctx.hello else frozenset()
    checked = 0
    for spec in commands_for(ctx.service):
        if spec.id in advertised:
            continue
        if (spec.moves or spec.id == C.EMERGENCY_STOP) and not ctx.options.allow_motion:
            continue  # it could move, stop or switch something if the server does implement it
        # Without control and with arguments that cannot execute, a server that does implement
        # the command answers NOT_IN_CONTROL or BAD_PARAMETERS; a command not offered gets
        # NOT_SUPPORTED (1.3) or UNKNOWN_COMMAND (1.2), whatever its arguments [RS-6.4].
        answer = conn.call(spec.id)
        checked += 1
        got = answer.error
        if got is None or got[0] not in NOT_OFFERED:
            raise Fail(
                f"{spec.name} (0x{int(spec.id):04x}) is answered but not listed in Hello",
                "NOT_SUPPORTED or UNKNOWN_COMMAND for a command missing from Hello's list",
                answer.kind.name if got is None else f"error {ErrorCode(got[0]).name}",
                requirement="RS-5.3",
            )
    return f"{checked} unlisted registry commands answered as not offered"


@case(
    "negotiation.hello.limits",
    requirements=["RS-3.5"],
    tags=["negotiation", "limits"],
    profiles=SMOKE,
    order=10,
)
def hello_limits(ctx: Context) -> str:
    """Hello's limits are sane: 0 < max_payload <= 16 MiB, clients >= 1, timeouts > 0."""
    conn = ctx.connect()
    f = conn.ask(M.HelloRequest(1, 0, "conformance"))
    mp, mc, idle, ft = f.max_payload, f.max_clients, f.idle_timeout, f.frame_timeout
    if not 0 < mp <= wire.MAX_PAYLOAD:
        raise Fail("max_payload out of range", f"1..{wire.MAX_PAYLOAD}", mp, requirement="RS-3.5")
    if mc < 1:
        raise Fail("max_clients below 1", ">= 1", mc)
    if not (idle > 0 and ft > 0):
        raise Fail("timeouts must be positive", "> 0 s", (idle, ft))
    return f"max_payload {mp} B, max_clients {mc}, idle {idle:g} s, frame {ft:g} s"


@case(
    "negotiation.minor_version_higher",
    requirements=["RS-1.2", "RS-3.2"],
    tags=["negotiation", "framing"],
    order=10,
)
def minor_version_higher(ctx: Context) -> None:
    """A frame with version 1.7 is accepted (same major version)."""
    conn = ctx.connect()
    conn.send(raw_frame(C.PING, 77, (b"minor",), minor=7), "Ping in a version 1.7 frame")
    answer = conn.recv_packet()
    if answer.error is not None or answer.request_id != 77 or answer.params[:1] != (b"minor",):
        raise Fail(
            "a frame with a higher minor version is not accepted",
            "Ping reply echoing b'minor' to request 77",
            _describe(answer),
            requirement="RS-1.2",
        )


def _describe(p: Packet) -> str:
    if p.error is not None:
        return f"error {p.error[0]}: {p.error[1]} (request ID {p.request_id})"
    return f"{p.kind.name} request ID {p.request_id} params {p.params!r}"


@case(
    "negotiation.port.default",
    requirements=["RS-2.3"],
    level="INFO",
    tags=["negotiation"],
    order=10,
)
def default_port(ctx: Context) -> str:
    """The endpoint's port against the default (4000 robot, 2000 sensor); configurable."""
    default = 4000 if ctx.service == "robot" else 2000
    if ctx.port == default:
        return f"listens on the default port {default}"
    raise Informational(f"listens on port {ctx.port}, the default is {default} (configurable)")


@case(
    "negotiation.client.hello_first",
    requirements=["RS-5.9"],
    level="INFO",
    tags=["negotiation", "client-side"],
    order=10,
)
def client_hello_first(ctx: Context) -> str:
    """Client-side rule, not observable at a server: the harness sends Hello first itself."""
    conn = ctx.connect(hello=True)
    conn.ok(C.PING, b"")
    return "client-side rule; the harness negotiates with Hello before any other request"


@case(
    "negotiation.request_id.max",
    requirements=["RS-3.13", "RS-3.4"],
    level="SHOULD",
    tags=["negotiation", "framing"],
    order=10,
)
def request_id_max(ctx: Context) -> None:
    """Request IDs 4 294 967 295 and then 1 (the wrap) are echoed."""
    conn = ctx.connect()
    for rid in (0xFFFFFFFF, 1):
        conn.send(raw_frame(C.PING, rid, (b"w",)), f"Ping id {rid}")
        answer = conn.recv_packet()
        if answer.request_id != rid:
            raise Fail("request ID not echoed across the wrap", rid, answer.request_id)


@case(
    "negotiation.profile.core",
    requirements=["RS-5.60", "RS-5.61", "RS-5.63"],
    tags=["negotiation", "profiles"],
    profiles=SMOKE,
    order=10,
)
def profile_core(ctx: Context) -> str:
    """Hello lists every command of the service's core profile."""
    conn = ctx.connect()
    offered = frozenset(conn.ask(M.HelloRequest(1, 0, "conformance")).commands.values)
    core = profiles_for(ctx.service)[0]
    missing = [BY_ID[c].name for c in core.commands if c not in offered]
    if missing:
        raise Fail(
            f"Hello leaves out commands of the {ctx.service} core profile",
            "every core command listed",
            ", ".join(missing),
            requirement="RS-5.60",
        )
    claimed = [p.name for p in profiles_for(ctx.service) if set(p.commands) <= offered]
    return "profiles claimed: " + ", ".join(claimed)


@case(
    "negotiation.profile.not_offered_answer",
    requirements=["RS-5.62"],
    level="SHOULD",
    tags=["negotiation", "profiles"],
    profiles=("core", "full"),
    order=12,
)
def profile_not_offered_answer(ctx: Context) -> str:
    """A registry command left out of Hello is answered NOT_SUPPORTED (or a 1.2 endpoint's
    UNKNOWN_COMMAND), from a connection without control, so nothing can execute."""
    if ctx.hello is None or not ctx.hello.commands:
        raise Informational("no Hello command list to compare with")
    conn = ctx.connect()
    tried = []
    for spec in commands_for(ctx.service):
        if spec.id in ctx.hello.commands or (spec.moves and not spec.needs_control):
            continue
        answer = conn.call(spec.id, *(dummy(p.type) for p in spec.params))
        got = answer.error[0] if answer.error is not None else None
        if got not in NOT_OFFERED:
            raise Fail(
                f"{spec.name}, left out of Hello, is answered as if offered",
                "error NOT_SUPPORTED (or UNKNOWN_COMMAND)",
                "a reply" if answer.error is None else f"error {answer.error}",
                requirement="RS-5.62",
            )
        tried.append(spec.name)
    if not tried:
        raise Informational("Hello lists every command of the service")
    return f"{len(tried)} unlisted command(s) answered as not offered"
