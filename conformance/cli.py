"""Command line: ``python -m conformance {robot,sensor,sync} [HOST:PORT] [options]``.

Exit codes: the project's one table (:class:`spec.exitcodes.ExitCode`, docs/CONFORMANCE.md).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from string import hexdigits
from typing import NoReturn

from conformance import SUITE_VERSION, TOOL_VERSION
from conformance.context import Options
from conformance.model import PROFILES, CaseResult, all_cases
from conformance.reference import ReferenceUnavailable, start
from conformance.replaycase import ReplayUsageError, add_replay_case
from conformance.report import (
    load_expectations,
    terminal,
    to_json,
    to_junit,
    to_markdown,
    write_atomic,
)
from conformance.runner import (
    RunResult,
    Selection,
    exit_code,
    run,
)
from spec import cliargs
from spec.exitcodes import ExitCode
from spec.registry import BY_ID, COMMANDS

EPILOG = """exit codes: 0 conformant; 1 a MUST failed; 2 usage error; 3 endpoint unreachable or
stopped answering; 4 harness fault (no verdict); 5 only SHOULD failures (with --strict);
6 conformant to the capability profiles claimed only (the summary's scope: line); 7 nothing
selected.
Without HOST:PORT the reference server of the service is started in-process."""


class UsageError(Exception):
    """A bad command line or input file (exit code 2, ``ExitCode.USAGE``)."""


class _Parser(cliargs.Parser):
    def error(self, message: str) -> NoReturn:
        raise UsageError(message)


def parse_endpoint(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"endpoint must be HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


def parse_capabilities(path: str) -> frozenset[int]:
    """Command IDs a capability file declares not offered: {"not_offered": [name or id]}."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UsageError(f"cannot read capability file {path}: {exc}") from None
    listed = data.get("not_offered", []) if isinstance(data, dict) else None
    if not isinstance(listed, list):
        raise UsageError(f'capability file {path}: expected {{"not_offered": [names or IDs]}}')
    names = {c.name: int(c.id) for c in COMMANDS}
    out: set[int] = set()
    for item in listed:
        if isinstance(item, str) and item.lower().startswith("0x"):
            number = int(item, 16) if all(c in hexdigits for c in item[2:]) and item[2:] else -1
        else:  # bool is an int in Python, not a command ID in JSON
            number = item if isinstance(item, int) and not isinstance(item, bool) else -1
        if number in BY_ID:
            out.add(number)
        elif isinstance(item, str) and item in names:
            out.add(names[item])
        else:
            raise UsageError(f"capability file {path}: unknown command {item!r}")
    return frozenset(out)


def read_expectations(path: str) -> frozenset[str]:
    """The --expect file's case IDs; a file that cannot be read or parsed is a usage error."""
    try:
        return load_expectations(path)
    except OSError as exc:
        raise UsageError(f"cannot read --expect file {path}: {exc.strerror or exc}") from None
    except ValueError as exc:  # not UTF-8, not JSON, not a list of IDs
        raise UsageError(f"--expect file {path}: {exc}") from None


def add_recording(path: str, service: str) -> str:
    """Register the --replay case of a recording; its case ID."""
    if service == "sync":
        raise UsageError("--replay replays robot or sensor sessions, not sync")
    try:
        return add_replay_case(path, service).id
    except ReplayUsageError as exc:
        raise UsageError(f"--replay: {exc}") from None
    except ValueError as exc:  # a second recording with the same file stem
        raise UsageError(f"--replay {path}: {exc}") from None


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="python -m conformance",
        description="Check a robot, sensor or UDP sync endpoint against PROTOCOL.md.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("service", choices=["robot", "sensor", "sync"])
    p.add_argument(
        "endpoint",
        nargs="?",
        help="HOST:PORT: the TCP port for robot and sensor, the sensor's UDP trigger port for "
        "sync (default: start our reference server)",
    )
    p.add_argument("--udp", metavar="HOST:PORT", help="the sensor's trigger endpoint (sync)")
    p.add_argument("--list", action="store_true", help="list the selected cases and exit")
    p.add_argument("--profile", choices=PROFILES, default="core")
    p.add_argument("--select", action="append", default=[], metavar="GLOB")
    p.add_argument("--exclude", action="append", default=[], metavar="GLOB")
    p.add_argument("--tag", action="append", default=[])
    p.add_argument(
        "--timeout-scale", type=cliargs.number_in(0.01, 1000.0), default=1.0,
        metavar="F",
        help="multiply every time budget (slow embedded endpoints: 3)",
    )  # fmt: skip
    p.add_argument("--expect", metavar="FILE", help="known failures: case IDs, one per line")
    p.add_argument("--capabilities", metavar="FILE", help='JSON {"not_offered": [...]}')
    p.add_argument("--allow-motion", action="store_true", help="run cases that move or switch")
    p.add_argument(
        "--replay",
        action="append",
        default=[],
        metavar="FILE",
        help="also run a recorded session (pcapng, spec record) as the case replay.<stem>",
    )
    token = p.add_mutually_exclusive_group()
    token.add_argument("--token", default="", help="the endpoint's control token")
    cliargs.add_token_file(token, "the endpoint's")
    p.add_argument(
        "--fuzz",
        type=cliargs.int_in(0, 10**9),
        default=0,
        metavar="N",
        help="add N seeded mutations of valid frames",
    )
    p.add_argument("--seed", type=cliargs.seed, default=1, metavar="S", help="seed of --fuzz")
    p.add_argument("--json", metavar="FILE", type=cliargs.output_file, help="JSON report")
    p.add_argument("--junit", metavar="FILE", type=cliargs.output_file, help="JUnit XML")
    p.add_argument("--markdown", metavar="FILE", type=cliargs.output_file, help="Markdown report")
    p.add_argument("--strict", action="store_true", help="SHOULD failures give exit code 5")
    p.add_argument("-v", "--verbose", action="store_true", help="print every case")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.add_argument(
        "--version", action="version", version=f"conformance {TOOL_VERSION} suite {SUITE_VERSION}"
    )
    return p


def write_reports(args: argparse.Namespace, result: RunResult) -> None:
    if args.json:
        write_atomic(args.json, json.dumps(to_json(result, args.strict), indent=1) + "\n")
    if args.junit:
        write_atomic(args.junit, to_junit(result, args.strict))
    if args.markdown:
        write_atomic(args.markdown, to_markdown(result, args.strict))


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _main(argv)
    except UsageError as exc:
        print(f"conformance: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    except BrokenPipeError:
        raise  # our stdout was closed (`| head`): cliargs.run_cli ends quietly
    except OSError as exc:
        print(f"conformance: {exc}", file=sys.stderr)
        return ExitCode.USAGE


def _main(argv: Sequence[str] | None) -> int:
    args = build_parser().parse_args(argv)
    # An in-process reference server logs through `logging`; keep the report readable.
    logging.basicConfig(level=logging.ERROR)
    replays = tuple(add_recording(path, args.service) for path in args.replay)
    selection = Selection(
        args.profile,
        tuple(args.select),
        tuple(args.exclude),
        tuple(args.tag),
        # --fuzz adds the fuzz case, --replay its recordings, whatever the profile
        include=("robustness.fuzz",) * bool(args.fuzz) + replays,
    )
    cases = selection.pick(all_cases(), args.service)
    if not cases and not args.list:
        print("conformance: no case matches the profile, selections and tags", file=sys.stderr)
        return ExitCode.NOTHING_SELECTED
    if args.list:
        for c in cases:
            flags = " motion" if c.motion else ""
            print(f"{c.id:<52} {c.level:<6} {','.join(c.requirements):<28} {c.title}{flags}")
        return 0 if cases else ExitCode.NOTHING_SELECTED
    options = Options(
        allow_motion=args.allow_motion,
        timeout_scale=args.timeout_scale,
        token=args.token,
        fuzz=args.fuzz,
        seed=args.seed,
        not_offered=parse_capabilities(args.capabilities) if args.capabilities else frozenset(),
    )
    expect = read_expectations(args.expect) if args.expect else frozenset()
    endpoint = args.udp if args.service == "sync" and args.udp else args.endpoint
    reference = None
    if endpoint:
        host, port = parse_endpoint(endpoint)
    else:
        try:
            reference = start(args.service)
        except ReferenceUnavailable as exc:
            print(f"conformance: {exc}", file=sys.stderr)
            return ExitCode.FAILED
        host, port = reference.host, reference.port
        if not args.quiet:
            print(
                f"started the reference {args.service} endpoint on {host}:{port}", file=sys.stderr
            )

    def progress(r: CaseResult) -> None:
        if not args.quiet:
            print(f"  {r.outcome.value:<14} {r.case.id}", file=sys.stderr, flush=True)

    try:
        result = run(args.service, host, port, options, selection, expect, progress)
    finally:
        if reference is not None:
            reference.stop()
    write_reports(args, result)
    if not result.reachable or result.refused:
        print(f"conformance: {result.refused or result.negotiation_error}", file=sys.stderr)
    elif not args.quiet or result.results:
        sys.stdout.write(terminal(result, args.strict, args.verbose))
    return exit_code(result, args.strict)


def console() -> int:
    """The installed command ``rsf-conformance`` (a console-script entry point)."""
    from spec.cliargs import run_cli

    return run_cli(main)
