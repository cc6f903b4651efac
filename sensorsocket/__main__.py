"""Command line of the SensorSocket emulator.

python -m sensorsocket serve [--host H] [--port 2000] [--udp-port 2001|0|auto|off] [--joint J]
                             [--seam S] [--motion M] [--clock real|sim] [--allow CIDR ...]
                             [--token-file F] [--seed N] [--network-delay S]
python -m sensorsocket call HOST:PORT COMMAND [ARGS...]
python -m sensorsocket snapshot HOST:PORT -o frame.pgm|frame.png [--acquire]

Errors: one line on stderr; exit 2 for usage errors, 1 for an error reply, 3 when the server
cannot be reached.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from spec import cliargs, wire
from spec.callcli import (
    ListCommands,
    main_call,
    unreachable,
)
from spec.cliargs import parse_endpoint, run_cli
from spec.clocks import CLOCK_KINDS
from spec.errors import ErrorCode, ProtocolError, RemoteError
from spec.exitcodes import ExitCode
from spec.files import atomic_path
from spec.server import FramedServer, ServerPolicy, serve_until_signal

if TYPE_CHECKING:
    from sensorsocket.client import SensorClient
    from sensorsocket.sensor import Reading

# The camera emulator (numpy) and the client are imported by the subcommands that use them:
# `call` needs only the protocol, and starts in half the time without them.

PROG = "python -m sensorsocket"
DEFAULT_PORT = wire.SENSOR_PORT
DEFAULT_UDP_PORT = 2001
log = logging.getLogger("sensorsocket")


class _UsageError(Exception):
    pass


def _token_file(parser: argparse.ArgumentParser) -> None:
    cliargs.add_token_file(parser, "the TakeControl")


def _parser() -> cliargs.Parser:
    p = cliargs.Parser(prog=PROG, description="SensorSocket seam-tracking sensor emulator")
    sub = p.add_subparsers(dest="command", required=True, parser_class=cliargs.Parser)
    s = sub.add_parser("serve", help="run the sensor server (TCP) and trigger listener (UDP)")
    s.add_argument("--host", default="127.0.0.1", help="bind address (default 127.0.0.1)")
    s.add_argument("--port", type=cliargs.port, default=DEFAULT_PORT, help="TCP port, 0 = any free")
    s.add_argument(
        "--udp-port",
        type=cliargs.udp_port,
        default=DEFAULT_UDP_PORT,
        help="UDP trigger port; 0 or auto = any free port, off = no trigger listener",
    )
    s.add_argument("--joint", choices=("butt", "fillet", "lap"), default="butt")
    s.add_argument("--seam", choices=("straight", "sine"), default="straight")
    s.add_argument(
        "--motion", default="fixed", help="fixed | sine:AMP_MM:FREQ_HZ | scan:SPEED_MM_S"
    )
    s.add_argument("--clock", choices=CLOCK_KINDS, default="real")
    s.add_argument(
        "--allow",
        nargs="+",
        type=cliargs.network,
        default=[],
        metavar="CIDR",
        help="networks allowed to connect (TCP) and to send triggers (UDP); default any",
    )
    _token_file(s)
    s.add_argument(
        "--watchdog",
        type=cliargs.watchdog,
        default=ServerPolicy.watchdog,
        metavar="S",
        help="control lease when TakeControl names none (s, default %(default)g)",
    )
    s.add_argument("--seed", type=cliargs.seed, default=0, help="random seed of the emulator")
    s.add_argument(
        "--network-delay",
        type=cliargs.number_in(0.0, 1.0),
        default=0.0,
        help="modelled UDP reply delay (s, 0..1)",
    )
    c = sub.add_parser("call", help="send one command and print the reply as JSON")
    c.add_argument("endpoint", metavar="HOST:PORT")
    c.add_argument("name", metavar="COMMAND")
    c.add_argument("args", nargs="*")
    c.add_argument("--timeout", type=cliargs.timeout, default=5.0, help="reply timeout (s)")
    c.add_argument("--all", action="store_true", help="print every row of a matrix reply")
    c.add_argument(
        "--list", action=ListCommands, service="sensor", help="list the commands and exit"
    )
    _token_file(c)
    n = sub.add_parser("snapshot", help="save the latest frame as PGM (or PNG)")
    n.add_argument("endpoint", metavar="HOST:PORT")
    n.add_argument(
        "-o",
        "--output",
        type=cliargs.output_file,
        required=True,
        help="frame.pgm or frame.png (a missing folder is created)",
    )
    n.add_argument("--acquire", action="store_true", help="take control and acquire first")
    n.add_argument("--timeout", type=cliargs.timeout, default=5.0, help="reply timeout (s)")
    _token_file(n)
    return p


def cmd_serve(args: argparse.Namespace) -> int:
    from sensorsocket.sensor import SensorError, SimClock, build_sensor
    from sensorsocket.service import SensorService
    from sensorsocket.udp import TriggerHandler, TriggerListener

    udp_port: int | None = args.udp_port
    token: str | None = args.token  # read (and refused if empty) by cliargs.token_file
    allow = tuple(args.allow)
    sim = args.clock == "sim"
    if sim:
        sim_clock = SimClock()
        clock = sim_clock

        def step(reading: Reading) -> None:
            # A free-running simulated sensor: its clock moves to the end of each frame.
            sim_clock.set(reading.t_done)

        after = step
    else:
        clock, after = time.monotonic, None  # type: ignore[assignment]
    try:
        sensor = build_sensor(
            joint=args.joint,
            seam=args.seam,
            motion=args.motion,
            seed=args.seed,
            clock=clock,
            after_acquire=after,
        )
    except SensorError as exc:
        raise _UsageError(str(exc)) from None
    service = SensorService(sensor)
    policy = ServerPolicy(allow=allow, token=token, watchdog=args.watchdog)
    listener: TriggerListener | None = None
    what = f"TCP {args.host}:{args.port}"
    try:
        server = FramedServer(service, args.host, args.port, policy)
        if udp_port is not None:
            what = f"UDP {args.host}:{udp_port} (--udp-port)"
            handler = TriggerHandler(sensor, network_delay_s=args.network_delay)
            listener = TriggerListener(
                handler,
                args.host,
                udp_port,
                clock=clock,
                hold=not sim,
                allow=allow,
                kernel_timestamps=not sim,
            )
    except OSError as exc:
        print(f"{PROG} serve: cannot bind {what}: {exc.strerror or exc}", file=sys.stderr)
        return ExitCode.USAGE
    host, port = server.address
    udp = f"{listener.address[0]}:{listener.address[1]}" if listener else "off"
    service.trigger_endpoint = listener.address if listener else (host, 0)
    if listener is not None:
        listener.start()
    server.start()

    def stop() -> None:
        if listener is not None:
            log.info("trigger statistics: %s", json.dumps(listener.statistics()))
            listener.stop()
        log.info("server statistics: %s", json.dumps(server.statistics()))

    def announce() -> None:
        log.info(
            "sensorsocket serving tcp %s:%d udp %s (joint %s, seam %s, motion %s, clock %s, "
            "seed %d)", host, port, udp, args.joint, args.seam, args.motion, args.clock, args.seed,
        )  # fmt: skip

    serve_until_signal([server], on_stop=stop, ready=announce)
    # only after SIGINT or SIGTERM: one line and exit 130, as every tool (docs/CLI.md)
    return cliargs.interrupted("python -m sensorsocket", "laser off, server closed")


def _require_matplotlib() -> None:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise _UsageError("PNG output needs matplotlib, which is not installed; use .pgm") from None


def _write_png(path: Path, image: Any) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    with atomic_path(path) as tmp:
        plt.imsave(tmp, image, cmap="gray", vmin=0, vmax=255, format="png")


def _fetch(client: SensorClient, acquire: bool, token: str | None) -> tuple[int, Any]:
    """The latest frame; acquire one first (briefly holding control) when asked or when the
    sensor has not measured yet."""
    if not acquire:
        try:
            return client.get_image()
        except RemoteError as exc:
            if exc.code is not ErrorCode.NO_DATA:
                raise
    client.take_control(token or "")
    client.acquire()
    client.release_control()
    return client.get_image()


def cmd_snapshot(args: argparse.Namespace) -> int:
    from sensorsocket.client import SensorClient
    from sensorsocket.pgm import write_pgm

    out = Path(args.output)
    suffix = out.suffix.lower()
    if suffix not in (".pgm", ".png"):
        raise _UsageError(f"output must end in .pgm or .png, got {args.output!r}")
    token: str | None = args.token
    try:
        host, port = parse_endpoint(args.endpoint, DEFAULT_PORT)
    except ValueError as exc:
        raise _UsageError(str(exc)) from None
    if suffix == ".png":
        _require_matplotlib()
    try:
        client = SensorClient(host, port, timeout=args.timeout)
        try:
            index, image = _fetch(client, args.acquire, token)
            settings = client.get_settings()
        finally:
            client.close()
    except RemoteError as exc:
        print(f"error {exc.code.name} ({exc.raw_code}): {exc.message}", file=sys.stderr)
        return ExitCode.FAILED
    except (OSError, ProtocolError) as exc:
        print(f"{PROG} snapshot: {unreachable(host, port, exc)}", file=sys.stderr)
        return ExitCode.UNREACHABLE
    try:
        if suffix == ".png":
            _write_png(out, image)
        else:
            write_pgm(out, image)
    except OSError as exc:  # checked before the call, but a disk fills, a mount is read-only
        print(f"{PROG} snapshot: cannot write {out}: {exc.strerror or exc}", file=sys.stderr)
        return ExitCode.USAGE
    print(f"wrote {out} ({image.shape[1]}x{image.shape[0]}, frame {index})")
    if settings.columns < settings.width:
        # the window is the sensor's, not this connection's: a frame half black is not a fault
        last = settings.first_column + settings.columns - 1
        print(
            f"readout window in force: columns {settings.first_column}..{last} of "
            f"{settings.width}, the rest of the frame is not read out "
            f"(SetReadoutWindow 0 {settings.width} restores the full frame)"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(
        level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    try:
        args = _parser().parse_args(argv)
        if args.command == "serve":
            return cmd_serve(args)
        if args.command == "snapshot":
            return cmd_snapshot(args)
        return main_call(
            "sensor", DEFAULT_PORT, args.endpoint, args.name, args.args, args.timeout,
            args.token, all_rows=args.all,
        )  # fmt: skip
    except _UsageError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return ExitCode.USAGE


def console() -> int:
    """The installed command (a console-script entry point of pyproject.toml)."""
    return run_cli(main)


if __name__ == "__main__":
    sys.exit(console())
