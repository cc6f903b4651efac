"""Command line of the protocol package.

python -m spec decode HEX|FILE|-     dissect a frame or datagram field by field
python -m spec vectors [--generate]  decode every test vector (or write them, maintainers)
python -m spec requirements [--json] list the requirement IDs of PROTOCOL.md
python -m spec doc --check|--write   compare/regenerate PROTOCOL.md's tables and spec/messages.py
python -m spec fuzz --count N --seed S   fuzz the decoders
python -m spec replay FILE --robot HOST:PORT   replay a recording, report differing answers
python -m spec dissector --check|--write|--path   the Wireshark dissector (robotsocket.lua)
python -m spec record --listen PORT --to HOST:PORT -o FILE   record a session (a proxy)
"""

from __future__ import annotations

import argparse
import json
import signal
import string
import sys
from dataclasses import asdict
from pathlib import Path

from spec import cliargs, doc, requirements, vectorgen, wire
from spec.dissect import broken_rules, describe, describe_all
from spec.errors import PeerError
from spec.exitcodes import ExitCode


def _read_input(arg: str) -> bytes:
    if not arg.strip():
        return b""  # not the current directory: Path("") is "."
    if arg == "-":
        data = sys.stdin.buffer.read()
        text = data.decode("ascii", "replace").strip()
        if text and all(c in string.hexdigits + " \n\r\t:" for c in text):
            return _hex(text)
        return data
    path = Path(arg)
    try:
        is_file = path.exists()
    except OSError:  # a hex frame longer than a file name may be
        is_file = False
    if is_file:
        raw = path.read_bytes()
        text = raw.decode("ascii", "replace").strip()
        if text and all(c in string.hexdigits + " \n\r\t:" for c in text):
            return _hex(text)
        return raw
    return _hex(arg)


def _hex(text: str) -> bytes:
    cleaned = "".join(c for c in text if c not in " \n\r\t:")
    try:
        return bytes.fromhex(cleaned)
    except ValueError:
        raise ValueError(
            f"not hex and not a file: {text[:40]!r}{'…' if len(text) > 40 else ''}"
        ) from None


def cmd_decode(args: argparse.Namespace) -> int:
    try:
        raw = _read_input(args.input)
        if not raw:
            raise ValueError("empty input: give a frame or datagram as hex, a file or -")
        text, error = describe_all(raw)
        if text:
            print(text)  # the good frames before a bad or cut-off one
        if error is not None:
            raise error
        broken = broken_rules(raw)
        if broken:
            # decodable, but not conforming: said on stderr, exit 1 (2 is undecodable)
            print(f"spec decode: breaks {len(broken)} rule(s): " + "; ".join(broken),
                  file=sys.stderr)  # fmt: skip
            return ExitCode.FAILED
    except (ValueError, OSError) as exc:
        print(f"spec decode: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    except PeerError as exc:  # the input is bytes, but they break a rule of the spec
        print(f"spec decode: invalid: {exc}", file=sys.stderr)
        return ExitCode.FAILED
    return 0


def cmd_vectors(args: argparse.Namespace) -> int:
    if args.generate:
        written = vectorgen.write(force=args.force)
        for p in written:
            print(f"wrote {p}")
        if not written:
            print("vectors exist; use --force to overwrite them", file=sys.stderr)
        return 0
    counts = {"valid": 0, "invalid": 0}
    wrong: list[str] = []
    for name in ("frames.json", "datagrams.json"):
        for v in vectorgen.load(name):
            print(f"== {name}:{v['name']}  {v.get('description', '')}")
            raw = bytes.fromhex(v["hex"])
            counts["valid" if v["valid"] else "invalid"] += 1
            try:
                print(describe(raw))
                rejected = None
            except PeerError as exc:
                print(f"rejected: {exc}")
                rejected = exc.code.name
            if not v["valid"]:
                print(f"expected: {v['error']}")
            # the summary's verdict: a vector decodes exactly when it is marked valid, and an
            # invalid one is refused with the error code it names (INCOMPLETE means a stream
            # decoder waits for more; the one-shot dissector calls that a truncated BAD_FRAME)
            expected = None if v["valid"] else v["error"]
            if expected == "INCOMPLETE":
                expected = "BAD_FRAME"
            if rejected != expected:
                wrong.append(f"{name}:{v['name']}")
    total = counts["valid"] + counts["invalid"]
    print(
        f"{total} vectors: {counts['valid']} valid, {counts['invalid']} invalid; "
        + (f"{len(wrong)} not as expected: {', '.join(wrong)}" if wrong else "all as expected")
    )
    return ExitCode.FAILED if wrong else ExitCode.OK


def cmd_requirements(args: argparse.Namespace) -> int:
    reqs = requirements.requirements()
    if args.json:
        print(json.dumps([asdict(r) for r in reqs], indent=1, ensure_ascii=False))
    else:
        for r in reqs:
            print(f"{r.id:<8} {r.level:<6} {r.text}")
    return 0


def cmd_doc(args: argparse.Namespace) -> int:
    if args.write:
        changed = doc.write()
        print(
            "PROTOCOL.md / spec/messages.py updated"
            if changed
            else "PROTOCOL.md and spec/messages.py already up to date"
        )
        return 0
    diff = doc.differences()
    if diff:
        print(
            f"PROTOCOL.md or spec/messages.py differs from the registry in: {', '.join(diff)}",
            file=sys.stderr,
        )
        return ExitCode.FAILED
    print("PROTOCOL.md and spec/messages.py match the registry")
    return 0


def cmd_dissector(args: argparse.Namespace) -> int:
    from spec import dissector

    if args.path:
        print(dissector.LUA_PATH)
        return 0
    if args.write:
        changed = dissector.write()
        print(f"{dissector.LUA_PATH.name} " + ("updated" if changed else "already up to date"))
        return 0
    if dissector.differences():
        print(
            f"{dissector.LUA_PATH} differs from the registry: run python -m spec dissector --write",
            file=sys.stderr,
        )
        return ExitCode.FAILED
    print(f"{dissector.LUA_PATH.name} matches the registry")
    return 0


def cmd_fuzz(args: argparse.Namespace) -> int:
    from spec import fuzz

    report = fuzz.run(args.count, args.seed)
    print(f"{report.inputs} inputs, {report.packets} decoded packets, rejected by code:")
    for code, n in report.rejected.most_common():
        print(f"  {code:<22} {n}")
    for data, why in report.failures[:20]:
        print(f"FAILURE {why}: {data.hex()}")
    return ExitCode.FAILED if report.failures else ExitCode.OK


def _listen_address(text: str) -> tuple[str, int]:
    """``PORT`` (on 127.0.0.1) or ``HOST:PORT`` of ``--listen``; port 0 takes any free one."""
    host, _, port = text.rpartition(":")
    return host.strip("[]") or "127.0.0.1", cliargs.port(port)


def _udp_relay(text: str) -> tuple[int, tuple[str, int]]:
    """``LPORT:HOST:PORT`` of ``--udp``."""
    lport, sep, rest = text.partition(":")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected LPORT:HOST:PORT, got {text!r}")
    return cliargs.port(lport), cliargs.endpoint(0)(rest)


def cmd_record(args: argparse.Namespace) -> int:
    import datetime
    import logging

    from spec.record import RecordingProxy, SessionRecorder, UdpRelay, describe
    from spec.server import listen

    logging.basicConfig(level=logging.INFO, format="spec record: %(message)s")
    host, port = args.listen
    relays: list[UdpRelay] = []
    try:
        listener = listen(host, port)
        for lport, target in args.udp:
            relays.append(UdpRelay((host, lport), target))
    except OSError as exc:
        for relay in relays:
            relay.sock.close()
        print(
            f"spec record: cannot listen on {describe((host, port))}: {exc.strerror}",
            file=sys.stderr,
        )
        return ExitCode.USAGE  # nothing started: the port is taken or not ours
    here = listener.getsockname()[:2]
    started = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    comment = f"spec record {started}: clients of {describe(here)} relayed to {describe(args.to)}"
    comment += "".join(f"; UDP {describe(r.listen)} <-> {describe(r.target)}" for r in relays)
    try:
        recorder = SessionRecorder(args.output, comment, "python -m spec record")
    except OSError as exc:
        listener.close()
        print(f"spec record: cannot write {args.output}: {exc.strerror}", file=sys.stderr)
        return ExitCode.USAGE
    proxy = RecordingProxy(listener, args.to, recorder, tuple(relays))
    # SIGTERM ends the recording as Ctrl-C does: the file is complete and in place. SIGINT
    # gets the handler too: a shell starts a background job (`spec record … &`) with SIGINT
    # ignored, and `kill -INT` must still end the recording, as it ends `cell serve`.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: proxy._stop.set())
    print(f"listening on {describe(here)}, relaying to {describe(args.to)}", flush=True)
    for relay in relays:
        print(f"UDP {describe(relay.listen)} relayed to {describe(relay.target)}", flush=True)
    print(f"recording to {recorder.partial} (renamed to {recorder.path} at the end)", flush=True)
    try:
        proxy.serve_forever()
    finally:
        proxy.shutdown()
    print(f"recorded {proxy.connections} connections, {recorder.packets} packets to {args.output}")
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from spec import replay
    from spec.pcapng import PcapError

    targets = {"robot": args.robot, "sensor": args.sensor}
    if not any(targets.values()):
        print("spec replay: give --robot HOST:PORT or --sensor HOST:PORT", file=sys.stderr)
        return ExitCode.USAGE
    try:
        connections = replay.load(args.capture)
    except PcapError as exc:
        print(f"spec replay: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    # a connection whose service the capture does not tell goes to the one endpoint given
    only = (
        [s for s, t in targets.items() if t] if sum(bool(t) for t in targets.values()) == 1 else []
    )
    chosen = [(c, targets.get(c.service or (only[0] if only else ""))) for c in connections]
    chosen = [(c, t) for c, t in chosen if t]
    if not chosen:
        print(
            f"spec replay: {args.capture} holds no requests to a "
            + " or ".join(s for s, t in targets.items() if t),
            file=sys.stderr,
        )
        return ExitCode.USAGE
    moving = replay.motion_commands(c for c, _ in chosen)
    if moving and not args.allow_motion:
        print(
            f"spec replay: the recording moves the arm or switches outputs ({', '.join(moving)});"
            " replay it only with --allow-motion",
            file=sys.stderr,
        )
        return ExitCode.USAGE
    ignore = frozenset(args.ignore)
    total = different = 0
    skipped: set[str] = set()
    for conn, target in chosen:
        assert target is not None
        print(
            f"connection {conn.client} -> {conn.server} ({conn.service or 'service unknown'}):"
            f" {len(conn.exchanges)} requests to {target[0]}:{target[1]}"
        )
        try:
            results = replay.replay(
                conn,
                target,
                tolerance=args.tolerance,
                time_tolerance=args.time_tolerance,
                timeout=args.timeout,
                ignore=ignore,
            )
        except replay.EndpointLost as exc:
            print(f"spec replay: {exc}", file=sys.stderr)
            return ExitCode.UNREACHABLE
        skipped |= replay.not_compared(results)
        for r in results:
            total += 1
            x = r.exchange
            head = f"  #{total} {x.name} id={x.request.request_id}"
            recorded = x.recorded_time
            timing = f"{r.seconds * 1e3:.1f} ms" + (
                f", recorded {recorded * 1e3:.1f} ms" if recorded is not None else ""
            )
            if r.differences:
                different += 1
                print(f"{head}: DIFFERS ({timing})")
                for d in r.differences:
                    print(f"      {d}")
            elif args.verbose:
                print(f"{head}: as recorded ({timing})")
    if skipped:
        print(f"not compared (clock readings): {', '.join(sorted(skipped))}")
    print(f"{total} requests: {total - different} as recorded, {different} different")
    return ExitCode.FAILED if different else ExitCode.OK


def main(argv: list[str] | None = None) -> int:
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)  # `| head` ends quietly
    parser = cliargs.Parser(prog="python -m spec", description="protocol tools")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=cliargs.Parser)
    p = sub.add_parser(
        "decode", help="dissect frames (a capture of several too) or a datagram: hex, file or -"
    )
    p.add_argument("input")
    p.set_defaults(fn=cmd_decode)
    p = sub.add_parser("vectors", help="decode every test vector")
    p.add_argument("--generate", action="store_true", help="write spec/vectors (maintainers)")
    p.add_argument("--force", action="store_true")
    p.set_defaults(fn=cmd_vectors)
    p = sub.add_parser("requirements", help="list the requirements of PROTOCOL.md")
    p.add_argument("--json", action="store_true")
    p.set_defaults(fn=cmd_requirements)
    p = sub.add_parser("doc", help="check or regenerate PROTOCOL.md's tables and spec/messages.py")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--check", action="store_true", default=True)
    g.add_argument("--write", action="store_true")
    p.set_defaults(fn=cmd_doc)
    p = sub.add_parser(
        "dissector", help="the Wireshark dissector: check it against the registry, write, path"
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--check", action="store_true", default=True)
    g.add_argument("--write", action="store_true", help="regenerate it (maintainers)")
    g.add_argument("--path", action="store_true", help="print where the .lua file is")
    p.set_defaults(fn=cmd_dissector)
    p = sub.add_parser("fuzz", help="fuzz the decoders with seeded mutations")
    p.add_argument("--count", type=cliargs.int_in(1, 10**9), default=20000, help="inputs to try")
    p.add_argument("--seed", type=cliargs.seed, default=1, help="seed of the mutations")
    p.set_defaults(fn=cmd_fuzz)
    p = sub.add_parser(
        "record", help="relay connections to an endpoint and record them to a pcapng file"
    )
    p.add_argument(
        "--listen",
        type=_listen_address,
        required=True,
        metavar="[HOST:]PORT",
        help="where clients connect (HOST 127.0.0.1 unless given; port 0: any)",
    )
    p.add_argument(
        "--to",
        type=cliargs.endpoint(wire.ROBOT_PORT),
        required=True,
        metavar="HOST[:PORT]",
        help="the endpoint the connections are relayed to",
    )
    p.add_argument(
        "-o",
        "--output",
        type=cliargs.output_file,
        required=True,
        metavar="FILE",
        help="pcapng file (written as FILE.part until the recording ends)",
    )
    p.add_argument(
        "--udp",
        type=_udp_relay,
        action="append",
        default=[],
        metavar="LPORT:HOST:PORT",
        help="relay UDP datagrams arriving at LPORT to HOST:PORT, and back",
    )
    p.set_defaults(fn=cmd_record)
    p = sub.add_parser(
        "replay", help="send a recorded session's requests again and report differing answers"
    )
    p.add_argument("capture", help="pcapng or pcap file (python -m spec record, Wireshark)")
    cliargs.add_endpoint(p, "robot", ": replay the robot connections here")
    cliargs.add_endpoint(p, "sensor", ": replay the sensor connections here")
    p.add_argument(
        "--tolerance",
        type=cliargs.number_in(0, 1),
        default=1e-6,
        help="relative difference (absolute below 1) floats may have",
    )
    p.add_argument(
        "--time-tolerance",
        type=cliargs.nonnegative_float,
        default=0.25,
        metavar="S",
        help="how much slower than recorded an answer may be",
    )
    p.add_argument(
        "--timeout",
        type=cliargs.timeout,
        default=10.0,
        metavar="S",
        help="longest wait for one answer",
    )
    p.add_argument(
        "--ignore",
        action="append",
        default=[],
        metavar="COMMAND.PARAM",
        help="a reply value not to compare (e.g. GetJointLog.log)",
    )
    p.add_argument(
        "--allow-motion",
        action="store_true",
        help="replay commands that move the arm or switch outputs",
    )
    p.add_argument("-v", "--verbose", action="store_true", help="list every request")
    p.set_defaults(fn=cmd_replay)
    args = parser.parse_args(argv)
    result: int = args.fn(args)
    return result


def console() -> int:
    """The installed command (a console-script entry point of pyproject.toml)."""
    return cliargs.run_cli(main)


if __name__ == "__main__":
    raise SystemExit(console())
