"""Command line: ``python -m robotsocket serve | call | watch``.

serve   run a RobotSocket server in front of the robot emulator
call    send one command and print the reply as JSON (errors: code and message, exit 1)
watch   show live status and joints

Arguments of ``call`` are parsed from the registry's parameter types: joints and locations as
comma-separated numbers ("0,-30,90,0,60,0"), booleans as on/off/true/false/1/0; trailing
tool/frame locations may be left off (identity). Commands needing control take it first
(with --token-file) and release it afterwards; motion commands wait for the end of the move
(--wait S, exit 1 if it did not end in time; --no-wait returns at once and the move goes on,
since control is released, not lost).
"""

from __future__ import annotations

import argparse
import json
import logging
import socket
import sys
import time
from collections.abc import Sequence
from typing import Any

from spec import callcli, cliargs, wire
from spec.auth import Network
from spec.clocks import CLOCK_KINDS
from spec.errors import ProtocolError, RemoteError, error_text
from spec.exitcodes import ExitCode
from spec.server import FramedServer, ServerPolicy, listen, serve_until_signal

# The emulator, its kinematics (numpy) and the client are imported by the subcommands that use
# them: `call` needs only the protocol, and starts in half the time without them.

log = logging.getLogger("robotsocket")

DEFAULT_PORT = wire.ROBOT_PORT


class CliError(Exception):
    """A user mistake on the command line: one line on stderr, exit code 2."""


class CliUnreachable(Exception):
    """The server cannot be reached or does not speak the protocol: one line, exit code 3."""


def parse_endpoint(text: str) -> tuple[str, int]:
    try:
        return cliargs.parse_endpoint(text, DEFAULT_PORT)
    except ValueError as exc:
        raise CliError(str(exc)) from None


# --- serve ------------------------------------------------------------------------------------


def _announce(server: FramedServer) -> None:
    print(f"listening on {server.address[0]}:{server.address[1]}", flush=True)


def _listen(args: argparse.Namespace) -> socket.socket:
    """The TCP port, bound before the emulator or its real-time child starts: a port in use is
    one error line, not the child's start-up log followed by it."""
    try:
        return listen(args.host, args.port)
    except OSError as exc:
        raise CliError(
            f"cannot listen on {args.host}:{args.port} (--port): {exc.strerror or exc}"
        ) from None


def _robot_config(args: argparse.Namespace, allow: tuple[Network, ...]) -> dict[str, Any]:
    return {
        "model": args.model,
        "clock": args.clock,
        "encoder_latency_s": args.encoder_latency_ms / 1000.0,
        "dynamics": args.dynamics,
        "host": args.host,
        "udp_port": args.udp_port,
        "allow": allow,
        "data_from_any": args.data_from_any,
    }


def cmd_serve(args: argparse.Namespace) -> int:
    from kinematics.errors import KinematicsError
    from robotsocket.rtprocess import ChildStartError, build_robot

    token: str | None = args.token  # read (and refused if empty) by cliargs.token_file
    allow = tuple(args.allow or ())
    sock = _listen(args)
    if args.clock == "real" and not args.in_process:
        return _serve_child(args, allow, sock)
    try:
        # The synchronisation commands (0x3001-0x3009) and their UDP endpoint are registered
        # before the server reads the service's command list.
        parts = build_robot(_robot_config(args, allow))
    except (ValueError, KinematicsError, ChildStartError) as exc:
        sock.close()
        raise CliError(str(exc)) from None
    policy = ServerPolicy(
        max_clients=args.max_clients,
        max_per_address=args.max_per_address,
        allow=allow,
        token=token,
        watchdog=args.watchdog,
    )
    server = FramedServer(parts.services["robot"], policy=policy, listener=sock)
    parts.start()
    log.info(
        "robot %s emulator, %s clock, encoder latency %.1f ms, control token %s, allow %s",
        parts.robot.model.name,
        "real-time" if args.clock == "real" else "simulated (advances in WaitEndMove)",
        args.encoder_latency_ms,
        "required" if token else "not required",
        ", ".join(str(n) for n in allow) or "any",
    )
    server.start()

    def on_stop() -> None:
        parts.stop()  # logs UDP drops and the tick jitter
        log.info("statistics: %s", json.dumps(server.statistics()))

    serve_until_signal([server], on_stop, ready=lambda: _announce(server))
    return _stopped()


def _serve_child(args: argparse.Namespace, allow: tuple[Network, ...], sock: socket.socket) -> int:
    """The real clock's default: the 4 ms loop and the UDP endpoint in a real-time child
    process, the TCP server here on ``sock`` (docs/REALTIME.md)."""
    from robotsocket.rtprocess import ChildStartError, RealtimeProcess, RobotProcess

    try:
        child = RealtimeProcess("robotsocket.rtprocess:build_robot", _robot_config(args, allow))
    except ChildStartError as exc:
        sock.close()
        raise CliError(str(exc)) from None
    policy = ServerPolicy(
        max_clients=args.max_clients,
        max_per_address=args.max_per_address,
        allow=allow,
        token=args.token,
        watchdog=args.watchdog,
    )
    server = FramedServer(RobotProcess(child), policy=policy, listener=sock)
    log.info(
        "robot %s emulator, real-time clock in process %d, encoder latency %.1f ms, "
        "control token %s, allow %s",
        args.model,
        child.pid,
        args.encoder_latency_ms,
        "required" if args.token else "not required",
        ", ".join(str(n) for n in allow) or "any",
    )
    server.start()

    def on_stop() -> None:
        server.shutdown()  # a controller's work stops first, in the child [RS-7.10]
        child.close()  # the child logs its tick jitter and UDP drops
        log.info("statistics: %s", json.dumps(server.statistics()))

    serve_until_signal([server], on_stop, ready=lambda: _announce(server))
    return _stopped()


def _stopped() -> int:
    # serve_until_signal returns only after SIGINT or SIGTERM: one line and exit 130, as
    # every tool ends on Ctrl-C (docs/CLI.md, "Exit codes")
    return cliargs.interrupted(
        "python -m robotsocket", "robot stopped (laser off, motion stopped), server closed"
    )


# --- call -------------------------------------------------------------------------------------


def cmd_call(args: argparse.Namespace) -> int:
    return callcli.main_call(
        "robot", DEFAULT_PORT, args.endpoint, args.command, args.args, args.timeout,
        args.token, None if args.no_wait else args.wait, args.all,
    )  # fmt: skip


# --- watch ------------------------------------------------------------------------------------


def cmd_watch(args: argparse.Namespace) -> int:
    from robotsocket.client import RobotClient

    host, port = parse_endpoint(args.endpoint)
    try:
        client = RobotClient(host, port, timeout=args.timeout)
    except (OSError, ProtocolError) as exc:
        raise CliUnreachable(callcli.unreachable(host, port, exc)) from None
    with client:
        n = 0
        while args.count is None or n < args.count:
            if n:
                time.sleep(args.interval)  # CLI pacing, not core code
            st = client.status()
            q = client.herej()
            joints = " ".join(f"{v:8.3f}" for v in q)
            err = f" error={st.last_error} {st.last_message!r}" if st.last_error else ""
            print(
                f"t={st.time:10.3f} power={'on' if st.powered else 'off'}"
                f" estop={'ON' if st.estop else 'off'} moving={'yes' if st.moving else 'no'}"
                f" queue={st.queue} control={'yes' if st.controlled else 'no'}"
                f" q=[{joints}]{err}",
                flush=True,
            )
            n += 1
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = cliargs.Parser(prog="python -m robotsocket", description=__doc__.split("\n")[0])
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=cliargs.Parser)
    s = sub.add_parser("serve", help="run the RobotSocket server with the emulator")
    s.add_argument("--model", default="RX90B", help="RX90B (default), RX130B, RX160, TX90")
    s.add_argument("--host", default="127.0.0.1", help="listen address (default loopback)")
    s.add_argument("--port", type=cliargs.port, default=4000)
    s.add_argument("--clock", choices=CLOCK_KINDS, default="real")
    s.add_argument(
        "--in-process",
        action="store_true",
        help="real clock: run the 4 ms loop in the server's process instead of the "
        "real-time child process used by default (docs/REALTIME.md)",
    )
    s.add_argument(
        "--allow",
        nargs="+",
        type=cliargs.network,
        metavar="CIDR",
        help="networks allowed to connect (TCP) and to send datagrams (UDP); default any",
    )
    cliargs.add_token_file(s, "the TakeControl")
    s.add_argument(
        "--encoder-latency-ms",
        type=cliargs.number_in(0.0, 1000.0),
        default=0.0,
        help="measured joints lag the setpoints by this (ms, 0..1000); default 0, an ideal "
        "robot: the cell (python -m cell serve) uses 2.8, its model of a CS8's encoders",
    )
    from cell.options import add_dynamics_option  # one option for every emulated arm

    add_dynamics_option(s)
    s.add_argument(
        "--udp-port",
        type=cliargs.udp_port,
        default=0,
        help="UDP port of the trigger/data endpoint (0/auto = any, off = no sync commands)",
    )
    s.add_argument(
        "--data-from-any",
        action="store_true",
        help="accept data datagrams from any source, not only the sensor endpoint set by "
        "SetSensorEndpoint (for a sensor that replies from another port)",
    )
    s.add_argument("--max-clients", type=cliargs.int_in(1, 65535), default=64)
    s.add_argument(
        "--max-per-address",
        type=cliargs.int_in(1, 65535),
        default=ServerPolicy.max_per_address,
        metavar="N",
        help="connections one source address may hold (default %(default)d, RS-7.24)",
    )
    s.add_argument(
        "--watchdog",
        type=cliargs.watchdog,
        default=ServerPolicy.watchdog,
        metavar="S",
        help="control lease when TakeControl names none (s, default %(default)g)",
    )
    s.set_defaults(fn=cmd_serve)
    c = sub.add_parser("call", help="send one command, print the reply as JSON")
    c.add_argument("endpoint", metavar="HOST:PORT")
    c.add_argument("command", help="command name, case-insensitive (e.g. herej)")
    c.add_argument("args", nargs="*", help="parameters (joints as 0,-30,90,0,60,0)")
    cliargs.add_token_file(c, "the TakeControl")
    c.add_argument("--timeout", type=cliargs.timeout, default=5.0, help="reply timeout (s)")
    c.add_argument("--wait", type=cliargs.timeout, default=60.0, help="max wait for a move (s)")
    c.add_argument("--no-wait", action="store_true", help="do not wait for a move to end")
    c.add_argument("--all", action="store_true", help="print every row of a matrix reply")
    c.add_argument(
        "--list", action=callcli.ListCommands, service="robot", help="list the commands and exit"
    )
    c.set_defaults(fn=cmd_call)
    w = sub.add_parser("watch", help="show live status and joints")
    w.add_argument("endpoint", metavar="HOST:PORT")
    w.add_argument("--count", type=cliargs.positive_int, help="stop after N lines")
    w.add_argument(
        "--interval",
        type=cliargs.number_in(0.0, cliargs.MAX_TIMEOUT),
        default=0.5,
        help="seconds between lines",
    )
    w.add_argument("--timeout", type=cliargs.timeout, default=5.0)
    w.set_defaults(fn=cmd_watch)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)-7s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        code: int = args.fn(args)
        return code
    except CliError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    except CliUnreachable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return ExitCode.UNREACHABLE
    except RemoteError as exc:
        print(f"error {error_text(exc)}", file=sys.stderr)  # as `call` prints it
        return ExitCode.FAILED
    except BrokenPipeError:
        raise  # our stdout was closed (`| head`): cliargs.run_cli ends quietly
    except (ProtocolError, OSError) as exc:
        # No reply, closed, or a frame that is not ours (an HTTP server): unreachable, as
        # `call` says (docs/CLI.md), not an error reply.
        print(f"error: {error_text(exc)}", file=sys.stderr)
        return ExitCode.UNREACHABLE
    except KeyboardInterrupt:
        return ExitCode.INTERRUPTED


def console() -> int:
    """The installed command (a console-script entry point of pyproject.toml)."""
    return cliargs.run_cli(main)


if __name__ == "__main__":
    raise SystemExit(console())
