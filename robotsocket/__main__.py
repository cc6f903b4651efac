"""Command line: ``python -m robotsocket serve | call | watch``.

serve   run a RobotSocket server in front of the robot emulator
call    send one command and print the reply as JSON (errors: code and message, exit 1)
watch   show live status and joints

Arguments of ``call`` are parsed from the registry's parameter types: joints and locations as
comma-separated numbers ("0,-30,90,0,60,0"), booleans as on/off/true/false/1/0; trailing
tool/frame locations may be left off (identity). Commands needing control take it first
(with --token-file); motion commands then wait for the end of the move (--no-wait to skip;
without waiting, the move is stopped when the connection closes, since the controller left).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from kinematics.errors import KinematicsError
from robotsocket.client import RobotClient
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from spec.client import ClientTimeout, ConnectionClosed
from spec.errors import ProtocolError, RemoteError
from spec.params import (
    FloatArray,
    Image,
    IntArray,
    Joints,
    Location,
    Matrix,
    Transform,
    Value,
)
from spec.registry import COMMANDS, CommandId, CommandSpec, ParamSpec
from spec.server import FramedServer, ServerPolicy, parse_networks, serve_until_signal
from spec.wire import ParamType

log = logging.getLogger("robotsocket")

#: Commands after which ``call`` waits for the end of the move.
MOTION = frozenset(
    {CommandId.JOINT_MOVE, CommandId.TOOL_MOVE_J, CommandId.TOOL_MOVE_L, CommandId.RESTART_MOVE}
)


class CliError(Exception):
    """A user mistake on the command line: one line on stderr, exit code 2."""


def robot_commands() -> dict[str, CommandSpec]:
    """Robot-service commands by lower-case name."""
    return {c.name.lower(): c for c in COMMANDS if "robot" in c.services}


def parse_endpoint(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise CliError(f"expected HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


def _numbers(text: str, what: str) -> list[float]:
    try:
        vals = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise CliError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in vals):
        raise CliError(f"{what}: numbers must be finite")
    return vals


def parse_value(spec: ParamSpec, text: str) -> Value:
    """One command-line argument as the registry's parameter type."""
    t, name = spec.type, spec.name
    try:
        if t is ParamType.INT:
            return int(text, 0)
        if t is ParamType.FLOAT:
            return float(text)
        if t is ParamType.BOOL:
            low = text.lower()
            if low in ("on", "true", "1", "yes"):
                return True
            if low in ("off", "false", "0", "no"):
                return False
            raise CliError(f"{name}: expected on/off/true/false, got {text!r}")
        if t is ParamType.STRING:
            return text
        if t is ParamType.BYTES:
            return text.encode("utf-8")
        if t is ParamType.JOINTS:
            return Joints(_numbers(text, name))
        if t is ParamType.LOCATION:
            return Location.of(_numbers(text, name))
        if t is ParamType.FLOAT_ARRAY:
            return FloatArray(_numbers(text, name))
        if t is ParamType.INT_ARRAY:
            return IntArray(int(v) for v in _numbers(text, name))
        if t is ParamType.TRANSFORM:
            return Transform(_numbers(text, name))
    except ValueError as exc:
        if isinstance(exc, CliError):
            raise
        raise CliError(f"{name}: {exc}") from None
    raise CliError(f"{name}: parameters of type {t.name} cannot be given on the command line")


def parse_args_for(spec: CommandSpec, args: Sequence[str]) -> tuple[Value, ...]:
    specs = spec.params
    if len(args) > len(specs):
        raise CliError(f"{spec.name} takes at most {len(specs)} arguments, got {len(args)}")
    values = [parse_value(s, a) for s, a in zip(specs, args, strict=False)]
    for s in specs[len(args) :]:
        if s.type is ParamType.LOCATION and s.name in ("tool", "frame"):
            values.append(Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        elif not s.optional:
            usage = " ".join(f"{p.name}:{p.type.name}" for p in specs)
            raise CliError(f"{spec.name}: missing {s.name} (usage: {spec.name} {usage})")
    return tuple(values)


def to_json(value: Value) -> object:
    if isinstance(value, Joints | FloatArray | IntArray | Transform):
        return list(value.values)
    if isinstance(value, Location):
        return list(value.as_tuple())
    if isinstance(value, Matrix):
        return [list(r) for r in value.to_rows()]
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, Image):
        return {"width": value.width, "height": value.height, "bytes": len(value.data)}
    return value


def read_token(path: Path | None) -> str:
    if path is None:
        return ""
    try:
        return path.read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise CliError(f"cannot read token file {path}: {exc.strerror}") from None


# --- serve ------------------------------------------------------------------------------------


def cmd_serve(args: argparse.Namespace) -> int:
    token = read_token(args.token_file) if args.token_file else None
    if args.token_file and not token:
        raise CliError(f"token file {args.token_file} is empty")
    try:
        allow = parse_networks(args.allow or [])
        robot = RobotEmulator(
            args.model, clock=args.clock, encoder_latency=args.encoder_latency_ms / 1000.0
        )
    except (ValueError, KinematicsError) as exc:
        raise CliError(str(exc)) from None
    policy = ServerPolicy(max_clients=args.max_clients, allow=allow, token=token)
    try:
        server = FramedServer(RobotService(robot), args.host, args.port, policy)
    except OSError as exc:
        raise CliError(f"cannot listen on {args.host}:{args.port}: {exc.strerror}") from None
    robot.start()
    log.info(
        "robot %s emulator, %s clock, encoder latency %.1f ms, control token %s, allow %s",
        robot.model.name,
        "real-time" if args.clock == "real" else "simulated (advances in WaitEndMove)",
        args.encoder_latency_ms,
        "required" if token else "not required",
        ", ".join(str(n) for n in allow) or "any",
    )
    server.start()
    print(f"listening on {server.address[0]}:{server.address[1]}", flush=True)

    def on_stop() -> None:
        robot.close()
        j = robot.jitter()
        if j["count"]:
            log.info(
                "tick jitter: p50 %.3f ms, p99 %.3f ms, max %.3f ms over %d ticks",
                j["p50"] * 1e3,
                j["p99"] * 1e3,
                j["max"] * 1e3,
                int(j["count"]),
            )
        log.info("statistics: %s", json.dumps(server.statistics()))

    serve_until_signal([server], on_stop)
    return 0


# --- call -------------------------------------------------------------------------------------


def cmd_call(args: argparse.Namespace) -> int:
    host, port = parse_endpoint(args.endpoint)
    spec = robot_commands().get(args.command.lower())
    if spec is None:
        known = ", ".join(sorted(c.name for c in robot_commands().values()))
        raise CliError(f"unknown command {args.command!r}; known: {known}")
    params = parse_args_for(spec, args.args)
    with RobotClient(host, port, timeout=args.timeout) as client:
        if spec.needs_control:
            client.take_control(read_token(args.token_file))
        values = client.call(spec.id, *params)
        reply = {p.name: to_json(v) for p, v in zip(spec.reply, values, strict=False)}
        if spec.id in MOTION and not args.no_wait:
            reply["done"] = client.wait_end_move(args.wait)
        if spec.needs_control:
            client.release_control()
    print(json.dumps(reply))
    return 0


# --- watch ------------------------------------------------------------------------------------


def cmd_watch(args: argparse.Namespace) -> int:
    host, port = parse_endpoint(args.endpoint)
    with RobotClient(host, port, timeout=args.timeout) as client:
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
    p = argparse.ArgumentParser(prog="python -m robotsocket", description=__doc__.split("\n")[0])
    p.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = p.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("serve", help="run the RobotSocket server with the emulator")
    s.add_argument("--model", default="RX90B", help="RX90B (default), RX130B, RX160, TX90")
    s.add_argument("--host", default="127.0.0.1", help="listen address (default loopback)")
    s.add_argument("--port", type=int, default=4000)
    s.add_argument("--clock", choices=("real", "sim"), default="real")
    s.add_argument("--allow", nargs="*", metavar="CIDR", help="client networks allowed")
    s.add_argument("--token-file", type=Path, help="file holding the TakeControl token")
    s.add_argument("--encoder-latency-ms", type=float, default=0.0)
    s.add_argument("--max-clients", type=int, default=64)
    s.set_defaults(fn=cmd_serve)
    c = sub.add_parser("call", help="send one command, print the reply as JSON")
    c.add_argument("endpoint", metavar="HOST:PORT")
    c.add_argument("command", help="command name, case-insensitive (e.g. herej)")
    c.add_argument("args", nargs="*", help="parameters (joints as 0,-30,90,0,60,0)")
    c.add_argument("--token-file", type=Path, help="token for TakeControl")
    c.add_argument("--timeout", type=float, default=5.0, help="reply timeout (s)")
    c.add_argument("--wait", type=float, default=60.0, help="max wait for a move to end (s)")
    c.add_argument("--no-wait", action="store_true", help="do not wait for a move to end")
    c.set_defaults(fn=cmd_call)
    w = sub.add_parser("watch", help="show live status and joints")
    w.add_argument("endpoint", metavar="HOST:PORT")
    w.add_argument("--count", type=int, help="stop after N lines")
    w.add_argument("--interval", type=float, default=0.5, help="seconds between lines")
    w.add_argument("--timeout", type=float, default=5.0)
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
        return 2
    except RemoteError as exc:
        print(f"error {exc.raw_code} {exc.code.name}: {exc.message}", file=sys.stderr)
        return 1
    except (ClientTimeout, ConnectionClosed) as exc:
        print(f"error: {exc.message}", file=sys.stderr)
        return 1
    except ProtocolError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
