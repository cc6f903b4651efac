"""``python -m welding console``: the operator console in the browser.

``--emulate`` starts an emulated cell on the real-time clock (its real-time part in a child
process, docs/REALTIME.md; its robot and sensor servers on free loopback ports here) and
connects to it as it would to a real cell;
``--robot HOST:PORT [--sensor HOST:PORT] [--token-file PATH]`` connects to a real one. The
console binds to 127.0.0.1:8024 unless ``--host``/``--port`` say otherwise.
"""

from __future__ import annotations

import argparse
import errno
import logging
import socket
import sys
from pathlib import Path
from typing import Any

from spec import cliargs
from spec.exitcodes import ExitCode
from spec.server import listen
from welding import job as J

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
    where = p.add_mutually_exclusive_group(required=True)
    cliargs.add_endpoint(where, "robot")
    where.add_argument(
        "--emulate", action="store_true", help="start an emulated cell (real-time clock)"
    )
    cliargs.add_endpoint(p, "sensor", ", with --robot")
    p.add_argument(
        "--token-file",
        metavar="PATH",
        type=cliargs.token_file,
        help="file holding the robot's control token (one line)",
    )
    p.add_argument(
        "--seam", choices=("straight", "sine", "corner"), default="straight", help="--emulate"
    )
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default loopback)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help="default %(default)s")
    p.add_argument("--jobs", metavar="DIR", default=".", help="folder of job files (default: here)")
    p.add_argument(
        "--timeout", type=cliargs.positive_float, default=10.0, help="seconds per robot reply"
    )
    add_tools_option(p)


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
            )
        except OSError as exc:
            raise CliError(
                str(exc), ExitCode.UNREACHABLE
            ) from None  # names robot or sensor and its address
        try:
            port = listener.getsockname()[1]  # the one bound (--port 0: a free one)
            print(f"console: http://{args.host}:{port}/", file=sys.stderr, flush=True)
            config = uvicorn.Config(
                create_app(console),
                log_level="warning",
                ws_ping_interval=5.0,
                ws_ping_timeout=5.0,
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
