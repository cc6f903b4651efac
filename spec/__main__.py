"""Command line of the protocol package.

python -m spec decode HEX|FILE|-     dissect a frame or datagram field by field
python -m spec vectors [--generate]  decode every test vector (or write them, maintainers)
python -m spec requirements [--json] list the requirement IDs of PROTOCOL.md
python -m spec doc --check|--write   compare/regenerate PROTOCOL.md's tables from the registry
python -m spec fuzz --count N --seed S   fuzz the decoders
"""

from __future__ import annotations

import argparse
import json
import signal
import string
import sys
from dataclasses import asdict
from pathlib import Path

from spec import cliargs, doc, requirements, vectorgen
from spec.dissect import describe, describe_all
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
    if path.exists():
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
        print("PROTOCOL.md updated" if changed else "PROTOCOL.md already up to date")
        return 0
    diff = doc.differences()
    if diff:
        print(f"PROTOCOL.md differs from the registry in: {', '.join(diff)}", file=sys.stderr)
        return ExitCode.FAILED
    print("PROTOCOL.md matches the registry")
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
    p = sub.add_parser("doc", help="check or regenerate PROTOCOL.md's tables")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--check", action="store_true", default=True)
    g.add_argument("--write", action="store_true")
    p.set_defaults(fn=cmd_doc)
    p = sub.add_parser("fuzz", help="fuzz the decoders with seeded mutations")
    p.add_argument("--count", type=cliargs.int_in(1, 10**9), default=20000, help="inputs to try")
    p.add_argument("--seed", type=cliargs.seed, default=1, help="seed of the mutations")
    p.set_defaults(fn=cmd_fuzz)
    args = parser.parse_args(argv)
    result: int = args.fn(args)
    return result


def console() -> int:
    """The installed command (a console-script entry point of pyproject.toml)."""
    return cliargs.run_cli(main)


if __name__ == "__main__":
    raise SystemExit(console())
