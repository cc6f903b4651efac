"""Robustness: the deterministic corpus of spec/vectors (each followed by a liveness probe),
garbage, disconnects mid-frame, many connections, timeouts and seeded fuzzing
(PROTOCOL.md sections 3, 4 and 7)."""

from __future__ import annotations

import random
import struct
import time
import zlib
from collections.abc import Callable

from conformance.cases._util import fatal_check, recoverable_check, retarget
from conformance.context import Context
from conformance.model import (
    Case,
    EndpointGone,
    EndpointTimeout,
    Fail,
    Skip,
    add_case,
    case,
)
from spec import messages as M
from spec import wire
from spec.codec import encode_packet, request
from spec.errors import ErrorCode
from spec.fuzz import mutate
from spec.registry import CommandId as C
from spec.vectorgen import load

#: Requirement IDs per corpus vector (the vectors' own names, spec/vectors/frames.json).
VECTOR_RULES: dict[str, tuple[str, ...]] = {
    "bad-magic": ("RS-3.8", "RS-3.1", "RS-3.20"),
    "bad-magic-two-bytes": ("RS-3.19", "RS-3.8", "RS-3.20"),
    "bad-magic-second-byte": ("RS-3.19", "RS-3.8", "RS-3.20"),
    "garbage-http": ("RS-3.8", "RS-3.1", "RS-3.20"),
    "length-over-max": ("RS-3.5", "RS-3.8", "RS-3.20"),
    "length-max-u32": ("RS-3.5", "RS-3.8", "RS-3.20"),
    "bad-crc": ("RS-3.6", "RS-3.9"),
    "bad-crc-payload": ("RS-3.6", "RS-3.9"),
    "version-2": ("RS-3.11", "RS-3.9"),
    "version-0": ("RS-3.11", "RS-3.9"),
    "kind-0": ("RS-3.12", "RS-3.9"),
    "kind-5": ("RS-3.12", "RS-3.9"),
    "flags-set": ("RS-3.7", "RS-3.9"),
    "empty-payload": ("RS-4.1", "RS-4.3"),
    "one-byte-payload": ("RS-4.1", "RS-4.3"),
    "unknown-tag": ("RS-4.2",),
    "tag-zero": ("RS-4.2",),
    "count-too-high": ("RS-4.1", "RS-4.3"),
    "trailing-in-payload": ("RS-4.3",),
    "int-truncated": ("RS-4.3",),
    "bool-2": ("RS-4.5",),
    "string-bad-utf8": ("RS-4.6",),
    "string-past-payload": ("RS-4.3",),
    "bytes-huge-length": ("RS-4.3",),
    "float-array-truncated": ("RS-4.3",),
    "joints-0": ("RS-4.1",),
    "joints-17": ("RS-4.1",),
    "joints-nan": ("RS-4.4",),
    "location-inf": ("RS-4.4",),
    "location-truncated": ("RS-4.3",),
    "transform-last-row": ("RS-4.7",),
    "matrix-truncated": ("RS-4.3",),
    "image-length-mismatch": ("RS-4.8",),
    "image-unknown-format": ("RS-4.8",),
    "image-unknown-order": ("RS-4.8",),
    "truncated-1-byte": ("RS-7.9", "RS-2.4"),
    "truncated-1-wrong-byte": ("RS-3.19", "RS-2.4"),
    "truncated-header": ("RS-7.9", "RS-2.4"),
    "truncated-payload": ("RS-7.9", "RS-2.4"),
    "truncated-crc": ("RS-7.9", "RS-2.4"),
}

#: The corpus targets a command every service implements and that takes no parameters, so a
#: server that checks the command before the payload still reaches the payload check.
TARGET = int(C.GET_TIME)


def _vector_case(vector: dict[str, object]) -> Callable[[Context], str | None]:
    name = str(vector["name"])
    data = retarget(bytes.fromhex(str(vector["hex"])), TARGET)
    error = str(vector["error"])
    fatal = bool(vector.get("fatal"))
    rid = struct.unpack_from(">I", data, 8)[0] if len(data) >= wire.HEADER_SIZE else 0

    def run(ctx: Context) -> str | None:
        what = f"corpus frame {name!r}"
        if error == "INCOMPLETE":
            conn = ctx.connect()
            conn.send(data, f"{what}, then disconnect")
            conn.close()
            ctx.probe()
            return None
        code = ErrorCode[error]
        if fatal:
            fatal_check(ctx, data, (code,), what)
            return None
        recoverable_check(ctx, data, rid, TARGET, code, what)
        ctx.probe()
        return None

    run.__doc__ = f"Corpus vector {name}: {vector.get('description', '')}"
    return run


def _register_corpus() -> None:
    for vector in load("frames.json"):
        if vector["valid"]:
            continue
        name = str(vector["name"])
        rules = VECTOR_RULES.get(name, ("RS-7.9",))
        add_case(
            Case(
                id=f"robustness.corpus.{name}",
                fn=_vector_case(vector),
                requirements=(*rules, "RS-7.9"),
                level="MUST",
                tags=("robustness", "corpus"),
                profiles=("full", "robustness")
                + (("core",) if not name.startswith("trunc") else ()),
                budget=10.0,
                motion=False,
                service="any",
                commands=(),
                title=f"corpus {name}: {vector.get('description', '')}",
                order=70,
            )
        )


_register_corpus()

ROBUST = ("full", "robustness")


@case(
    "robustness.garbage.random",
    requirements=["RS-3.8", "RS-7.9"],
    tags=["robustness"],
    profiles=ROBUST,
    order=70,
)
def garbage_random(ctx: Context) -> None:
    """512 seeded random bytes (not starting with RS): BAD_FRAME, close, endpoint alive."""
    rng = random.Random(ctx.options.seed)
    data = b"\x00" + rng.randbytes(511)
    fatal_check(ctx, data, (ErrorCode.BAD_FRAME,), "512 bytes of garbage")


@case(
    "robustness.disconnect.mid_frame",
    requirements=["RS-7.9", "RS-2.4"],
    tags=["robustness"],
    profiles=("core", "full", "robustness"),
    order=70,
)
def disconnect_mid_frame(ctx: Context) -> None:
    """Ten connections that stop half-way through a frame and close; the endpoint lives on."""
    frame = encode_packet(request(C.PING, 1, b"x" * 100))
    for cut in (1, 2, 8, 15, 16, 17, 50, 100, len(frame) - 4, len(frame) - 1):
        conn = ctx.connect()
        conn.send(frame[:cut], f"first {cut} bytes, then close")
        conn.close()
    ctx.probe()


@case(
    "robustness.connections.many",
    requirements=["RS-7.1", "RS-7.9"],
    tags=["robustness", "concurrency"],
    profiles=("core", "full", "robustness"),
    budget=15.0,
    order=70,
)
def many_connections(ctx: Context) -> str:
    """Many connections at once, each sends a Ping before any is read; all are answered."""
    max_clients = int(ctx.hello.number("max_clients", 64)) if ctx.hello else 64
    n = max(1, min(32, max_clients - 4))
    conns = [ctx.connect() for _ in range(n)]
    for i, conn in enumerate(conns):
        conn.request(C.PING, f"conn {i}".encode(), request_id=i + 1)
    for i, conn in enumerate(conns):
        answer = conn.recv_packet()
        if answer.request_id != i + 1 or answer.params[:1] != (f"conn {i}".encode(),):
            raise Fail("a connection got another connection's answer", f"conn {i}", answer)
    for conn in conns:
        conn.close()
    ctx.probe()
    return f"{n} simultaneous connections answered"


@case(
    "robustness.fuzz",
    requirements=["RS-7.9", "RS-3.9", "RS-6.2"],
    tags=["robustness", "fuzz"],
    profiles=("robustness",),
    budget=600.0,
    order=75,
)
def fuzz(ctx: Context) -> str:
    """--fuzz N seeded mutations of valid requests; a probe after each; failing inputs kept."""
    count = ctx.options.fuzz
    if count <= 0:
        raise Skip("no --fuzz N given")
    rng = random.Random(ctx.options.seed)
    seeds = [
        encode_packet(request(C.PING, 1, b"fuzz")),
        encode_packet(request(C.HELLO, 2, 1, 0, "fuzz")),
        encode_packet(request(C.GET_TIME, 3)),
        encode_packet(request(C.TAKE_CONTROL, 4, "")),
    ] + [
        retarget(bytes.fromhex(str(v["hex"])), TARGET)
        for v in load("frames.json")
        if v["valid"] and bytes.fromhex(str(v["hex"]))[4] == 1
    ]
    failures: list[dict[str, object]] = []
    for i in range(count):
        data = rng.choice(seeds)
        for _ in range(rng.randrange(1, 4)):
            data = mutate(data, rng)
        if rng.random() < 0.6 and len(data) > 4:
            data = data[:-4] + struct.pack(">I", zlib.crc32(data[:-4]))
        try:
            conn = ctx.connect()
            conn.send(data, f"fuzz input {i}")
            # Whatever comes back must be well-formed frames; the wait is short on purpose.
            conn.quiet(ctx.scaled(0.02))
            conn.close()
            ctx.probe()
        except (Fail, EndpointGone, EndpointTimeout) as exc:
            failures.append(
                {"index": i, "seed": ctx.options.seed, "hex": data.hex(), "why": str(exc)}
            )
            if len(failures) >= 5:
                break
            try:
                ctx.probe()
            except Fail:
                break  # the endpoint is gone: later inputs prove nothing
    ctx.details["fuzz_inputs"] = count
    ctx.details["fuzz_failures"] = failures
    if failures:
        raise Fail(
            f"{len(failures)} fuzz input(s) broke the endpoint (replay: same --fuzz/--seed; hex in"
            " the report)",
            "every input answered or closed, endpoint alive",
            failures[0],
            requirement="RS-7.9",
        )
    return f"{count} mutated inputs, seed {ctx.options.seed}"


@case(
    "timeouts.frame",
    requirements=["RS-7.5", "RS-3.20"],
    tags=["timeouts"],
    profiles=("core", "full"),
    budget=60.0,
    order=60,
)
def frame_timeout(ctx: Context) -> str:
    """A frame stopped half-way gets TIMEOUT (request ID 0) after frame_timeout, then a close."""
    ft = ctx.hello.number("frame_timeout", 5.0) if ctx.hello else 5.0
    if ft > 25.0:
        raise Skip(f"frame timeout {ft:g} s is longer than this case's budget")
    conn = ctx.connect()
    conn.send(encode_packet(request(C.PING, 1, b"late"))[:10], "10 of 27 bytes, then nothing")
    t0 = time.monotonic()
    try:
        packets = conn.expect_closed(ft * 1.5 + ctx.timeout * 2)
    except EndpointTimeout:
        raise Fail(
            "a half-sent frame is not timed out",
            f"error TIMEOUT (request ID 0) and a close after about {ft:g} s",
            f"still open after {time.monotonic() - t0:.2f} s",
            requirement="RS-7.5",
        ) from None
    waited = time.monotonic() - t0
    if not packets or packets[0].error is None or packets[0].error[0] != ErrorCode.TIMEOUT:
        raise Fail(
            "no TIMEOUT error frame before the close",
            "error TIMEOUT with request ID 0",
            "closed silently" if not packets else repr(packets[0]),
            requirement="RS-7.5",
        )
    if packets[0].request_id != 0 or packets[0].command != 0:
        # [RS-3.20] 10 header bytes arrived (command ID among them): the error answers none.
        raise Fail(
            "TIMEOUT error naming a request",
            "command ID 0 and request ID 0",
            f"command ID 0x{packets[0].command:04x}, request ID {packets[0].request_id}",
            requirement="RS-3.20",
        )
    ctx.measure("frame_timeout", announced_s=ft, observed_s=round(waited, 4))
    return f"closed after {waited:.3f} s (announced {ft:g} s)"


@case(
    "timeouts.idle",
    requirements=["RS-7.6"],
    level="SHOULD",
    tags=["timeouts"],
    profiles=("full",),
    budget=30.0,
    order=60,
)
def idle_timeout(ctx: Context) -> str:
    """An idle connection is closed after idle_timeout with a TIMEOUT error frame."""
    idle = ctx.hello.number("idle_timeout", 300.0) if ctx.hello else 300.0
    if idle > 10.0:
        raise Skip(f"idle timeout {idle:g} s is longer than this case's budget")
    conn = ctx.connect()
    try:
        packets = conn.expect_closed(idle * 1.5 + ctx.timeout * 2)
    except EndpointTimeout:
        raise Fail("an idle connection stays open", f"closed after {idle:g} s", "open") from None
    if not packets or packets[0].error is None or packets[0].error[0] != ErrorCode.TIMEOUT:
        raise Fail("no TIMEOUT error before the idle close", "error TIMEOUT", packets[:1])
    return f"idle connection closed (announced {idle:g} s)"


def _limit(ctx: Context) -> int:
    limit = int(ctx.hello.number("max_payload", wire.MAX_PAYLOAD)) if ctx.hello else 0
    if limit <= 0:
        raise Skip("no max_payload known from Hello")
    return min(limit, wire.MAX_PAYLOAD)


@case(
    "limits.max_payload.accepted",
    requirements=["RS-3.5"],
    tags=["limits"],
    profiles=("full",),
    budget=30.0,
    order=60,
)
def max_payload_accepted(ctx: Context) -> str:
    """A Ping whose payload is exactly max_payload bytes is answered."""
    limit = _limit(ctx)
    data = bytes(i % 251 for i in range(limit - 2 - 1 - 4))  # count, tag, BYTES length
    conn = ctx.connect()
    echo = conn.ask(M.PingRequest(data), timeout=ctx.timeout * 10).data
    if echo != data:
        raise Fail("a maximum-size Ping is not echoed", f"{len(data)} bytes", "different bytes")
    return f"{limit} byte payload echoed"
