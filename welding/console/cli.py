"""``python -m welding console``: the operator console in the browser.

``--emulate`` starts an emulated cell on the real-time clock (its real-time part in a child
process, docs/REALTIME.md; its robot and sensor servers on free loopback ports here) and
connects to it as it would to a real cell;
``--robot HOST:PORT [--sensor HOST:PORT] [--token-file PATH]`` connects to a real one. The
console binds to 127.0.0.1:8024 unless ``--host``/``--port`` say otherwise; off loopback it
needs ``--certfile/--keyfile`` (TLS) or ``--insecure``.

Who may use it (issue 28): the printed one-time sign-in URL, and the accounts of ``--users FILE``
(``python -m welding console adduser FILE NAME``). Every operator action goes to the audit log
(``--audit FILE``, default beside the tool database).
"""

from __future__ import annotations

import argparse
import errno
import getpass
import ipaddress
import logging
import socket
import sys
from pathlib import Path
from typing import Any

from spec import cliargs
from spec.exitcodes import ExitCode
from spec.server import listen
from welding import job as J
from welding.track_options import add_seam_option

__all__ = ["add_parser", "cmd_console", "demo_job"]

log = logging.getLogger("welding.console")
DEFAULT_PORT = 8024


def add_parser(sub: Any, add_tools_option: Any) -> None:
    p = sub.add_parser(
        "console",
        help="the operator console in the browser (pip install '.[console]')",
        description="Serve the operator console: status, jog, sensor view, tools and frames, "
        "jobs, teaching. Open http://HOST:PORT/ in a browser.",
    )
    # not required here: `console adduser` needs neither; cmd_console says so when missing
    where = p.add_mutually_exclusive_group()
    cliargs.add_endpoint(where, "robot")
    where.add_argument(
        "--emulate", action="store_true", help="start an emulated cell (real-time clock)"
    )
    cliargs.add_endpoint(p, "sensor", ", with --robot")
    cliargs.add_token_file(p, "the robot's", dest="token_file")
    add_seam_option(p, "straight", " (with --emulate)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default loopback)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help="default %(default)s")
    p.add_argument("--jobs", metavar="DIR", default=".", help="folder of job files (default: here)")
    p.add_argument(
        "--timeout", type=cliargs.positive_float, default=10.0, help="seconds per robot reply"
    )
    add_tools_option(p)
    who = p.add_argument_group("access (who may use the console)")
    who.add_argument(
        "--users",
        metavar="FILE",
        help="operator and viewer accounts (written by `python -m welding console adduser`); "
        "without it only the printed sign-in URL signs in",
    )
    who.add_argument(
        "--allow-host",
        metavar="NAME",
        action="append",
        default=[],
        help="a host name the console is reached by (besides IP addresses and localhost); "
        "repeatable. Requests naming another Host are refused (DNS rebinding)",
    )
    who.add_argument("--certfile", metavar="PEM", help="TLS certificate (serves https)")
    who.add_argument("--keyfile", metavar="PEM", help="TLS private key, with --certfile")
    who.add_argument(
        "--insecure",
        action="store_true",
        help="serve plain http on a non-loopback address (passwords and sessions readable "
        "on the network; a warning on every start)",
    )
    who.add_argument(
        "--audit",
        metavar="FILE",
        help="audit log, one JSON line per operator action (default: beside --tools)",
    )
    who.add_argument(
        "--session-hours",
        type=cliargs.positive_float,
        default=12.0,
        help="a sign-in lasts this long (default %(default)s)",
    )
    sub2 = p.add_subparsers(dest="console_command", metavar="adduser")
    add = sub2.add_parser(
        "adduser",
        help="add a user to a users file (or change its role and password)",
        description="Add NAME to FILE (created if missing) with an scrypt hash of the password, "
        "or change an existing user's role and password. The password is asked for twice, "
        "or read from one line of stdin with --password-stdin.",
    )
    add.add_argument("file", metavar="FILE", help="the users file (JSON)")
    add.add_argument("name", metavar="NAME", help="user name: letters, digits, '_.-@'")
    add.add_argument("--role", choices=("operator", "viewer"), default="operator")
    add.add_argument("--password-stdin", action="store_true", help="read the password from stdin")


def cmd_adduser(args: argparse.Namespace) -> int:
    from welding.cli import CliError
    from welding.console.auth import add_user

    if args.password_stdin:
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        try:
            password = getpass.getpass(f"password for {args.name}: ")
            if getpass.getpass("again: ") != password:
                raise CliError("the two passwords differ; nothing changed", 1)
        except EOFError:
            raise CliError("no password given (--password-stdin reads it from stdin)", 2) from None
    new = add_user(args.file, args.name, args.role, password)
    print(f"{'added' if new else 'updated'} {args.role} {args.name} in {args.file}")
    return 0


def _is_loopback(host: str) -> bool:
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def demo_job() -> J.Job:
    """A short job on the emulated cell's workpiece: approach, a seam, a stitch, away."""

    def at(x: float, y: float, z: float) -> J.Location:
        return J.Location(x, y, z, 180.0, 0.0, 0.0, "laser", "workpiece")

    return J.Job(
        "demo",
        (
            J.Via("approach", at(-40, 0, 30), speed=20),
            J.Path(
                "seam",
                at(-40, 0, 0),
                (J.Line(at(0, 0, 0)),),
                velocity=20,
                power=1000,
                preflow=0.2,
                postflow=0.2,
            ),
            J.Stitch("spot", at(10, 0, 0), duration=0.2, power=800),
            J.Via("away", at(10, 0, 40), speed=20),
        ),
        description="the emulated cell's straight seam",
    )


def cmd_console(args: argparse.Namespace) -> int:
    if args.console_command == "adduser":
        return cmd_adduser(args)
    if args.robot is None and not args.emulate:
        print(
            "python -m welding console: error: one of --robot or --emulate is required",
            file=sys.stderr,
        )
        return ExitCode.USAGE
    try:
        import uvicorn

        from welding.console.app import create_app
        from welding.console.backend import Console
    except ImportError as exc:
        print(
            f"python -m welding console: {exc.name} is missing: pip install '.[console]'",
            file=sys.stderr,
        )
        return ExitCode.FAILED
    from welding.cli import CliError, merge_cell_tools
    from welding.console.access import Access
    from welding.console.audit import AuditLog, default_audit_path
    from welding.console.auth import Sessions, load_users

    tls = args.certfile is not None or args.keyfile is not None
    if tls and (args.certfile is None or args.keyfile is None):
        raise CliError("--certfile and --keyfile go together", 2)
    if not _is_loopback(args.host) and not tls and not args.insecure:
        raise CliError(
            f"--host {args.host} serves the console to the network: give --certfile and "
            "--keyfile (https), or --insecure to serve plain http anyway",
            2,
        )
    if not args.verbose:  # refusals and failed sign-ins are shown even without -v
        logging.getLogger("welding.console").setLevel(logging.WARNING)
    users = load_users(args.users) if args.users else {}
    audit = AuditLog(args.audit or default_audit_path(args.tools))
    try:
        audit.check()
    except OSError as exc:
        why = exc.strerror or exc
        raise CliError(f"cannot write the audit log {audit.path}: {why}", 2) from None
    sessions = Sessions(users, lifetime=args.session_hours * 3600.0)
    access = Access(sessions, audit, frozenset(args.allow_host), tls=tls)

    # the port first: a console that cannot serve says so before it starts a cell or a URL
    listener = _listen(args.host, args.port, CliError)
    cell = None
    if args.emulate:
        from welding.emulate import cell_tables, realtime_cell

        cell = realtime_cell(args.seam)
        robot, sensor = cell.robot_address, cell.sensor_address
        # other tools (a status client, the conformance suite) can talk to the same cell
        print(
            f"emulated cell: robot {robot[0]}:{robot[1]}, sensor {sensor[0]}:{sensor[1]}",
            file=sys.stderr,
            flush=True,
        )
        merge_cell_tools(args.tools, cell_tables(cell))
        jobs = Path(args.jobs)
        if not any(jobs.glob("*.xml")):
            jobs.mkdir(parents=True, exist_ok=True)
            J.save(demo_job(), jobs / "demo.xml")
    else:
        robot, sensor = args.robot, args.sensor
    try:
        try:
            console = Console(
                robot,
                sensor,
                tools=args.tools,
                jobs=args.jobs,
                token=args.token_file or "",
                timeout=args.timeout,
                emulated=args.emulate,
                cell=cell,
            ).open()  # before the sign-in URL: an unreachable cell is said first
        except OSError as exc:
            raise CliError(
                str(exc), ExitCode.UNREACHABLE
            ) from None  # names robot or sensor and its address
        try:
            port = listener.getsockname()[1]  # the one bound (--port 0: a free one)
            name = f"[{args.host}]" if ":" in args.host else args.host
            base = f"{'https' if tls else 'http'}://{name}:{port}"
            if args.insecure and not tls and not _is_loopback(args.host):
                log.warning(
                    "--insecure: serving plain http on %s: passwords and session cookies "
                    "cross the network readable by anyone on it",
                    args.host,
                )
            print(f"console: {base}/signin?token={sessions.token}", file=sys.stderr, flush=True)
            print(f"console: audit log {audit.path}", file=sys.stderr, flush=True)

            def announce(text: str) -> None:
                print(text, file=sys.stderr, flush=True)

            config = uvicorn.Config(
                create_app(console, access, announce=announce, base_url=base),
                log_level="warning",
                ws_ping_interval=5.0,
                ws_ping_timeout=5.0,
                ssl_certfile=args.certfile,
                ssl_keyfile=args.keyfile,
            )
            uvicorn.Server(config).run(sockets=[listener])
        finally:
            console.close()
    finally:
        listener.close()
        if cell is not None:
            cell.close()
    return 0


def _listen(host: str, port: int, error: Any) -> socket.socket:
    """A listening TCP socket on host:port (as every server binds it); ``error`` (one line,
    exit 1) when it cannot be."""
    try:
        return listen(host, port)
    except (OSError, UnicodeError) as exc:
        code = exc.errno if isinstance(exc, OSError) else None
        why = "in use" if code == errno.EADDRINUSE else getattr(exc, "strerror", None) or exc
        raise error(f"cannot serve on {host}:{port}: {why}", ExitCode.FAILED) from None
