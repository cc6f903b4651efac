"""The generic ``call`` command line both services share, in the manner of redis-cli.

``python -m robotsocket call HOST:PORT COMMAND [ARGS...]`` parses each argument by the type the
registry gives the command's parameter (joints and locations as comma-separated numbers,
booleans as on/off), sends one request and prints the reply as JSON named by the registry's
reply table. A command that needs control takes it first (with the token) and gives it back
(released, not lost: a queued move goes on unless ``call`` waits for it, the default).
Exit codes: 0 ok, 1 error reply (code and message on stderr) or a move that did not reach its
target (stopped, failed or still moving: the reason on stderr), 2 usage, 3 unreachable,
130 interrupted (Ctrl-C or SIGTERM: a move this call queued is stopped with ResetMotion and
control is released first).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from spec.cliargs import parse_endpoint
from spec.client import FramedClient, MoveResult, wait_move
from spec.codec import encode_packet, request
from spec.errors import ErrorCode, ProtocolError, RemoteError, error_text
from spec.exitcodes import ExitCode
from spec.jsonform import plain
from spec.params import FloatArray, IntArray, Joints, Location, Transform, Value
from spec.registry import BY_ID, COMMANDS, CommandId, CommandSpec, ParamSpec
from spec.wire import MoveOutcome, ParamType, SensorStatus

_QUEUED_MOVES = {
    CommandId.JOINT_MOVE,
    CommandId.TOOL_MOVE_J,
    CommandId.TOOL_MOVE_L,
    CommandId.TOOL_MOVE_TRAJECTORY,
    CommandId.RESTART_MOVE,
}


def find_command(name: str, service: str) -> CommandSpec:
    """A command of ``service`` by name (case-insensitive) or by ID (``0x1002``)."""
    try:
        number = int(name, 0)
    except ValueError:
        number = -1
    for c in COMMANDS:
        if service in c.services and (c.name.lower() == name.lower() or int(c.id) == number):
            return c
    names = ", ".join(sorted(c.name for c in COMMANDS if service in c.services))
    raise ValueError(f"unknown {service} command {name!r}; commands: {names}")


def _numbers(text: str, what: str) -> list[float]:
    try:
        values = [float(x) for x in text.replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise ValueError(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what}: numbers must be finite")
    return values


def _int64(text: str, what: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise ValueError(f"{what}: expected an integer, got {text!r}") from None
    if not _I64_MIN <= value <= _I64_MAX:
        # A usage error now, not an encoding failure after connecting (INT is i64 on the wire).
        raise ValueError(f"{what}: integers are signed 64-bit, got {text!r}")
    return value


_I64_MIN, _I64_MAX = -(1 << 63), (1 << 63) - 1


def _float(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{what}: expected a float, got {text!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{what}: numbers must be finite, got {text!r}")
    return value


def parse_arg(spec: ParamSpec, text: str) -> Value:
    """Parse one command-line argument as the parameter ``spec`` says."""
    what = spec.name
    t = spec.type
    if t is ParamType.INT:
        return _int64(text, what)
    if t is ParamType.FLOAT:
        return _float(text, what)
    if t is ParamType.BOOL:
        lowered = text.lower()
        if lowered in ("1", "true", "on", "yes"):
            return True
        if lowered in ("0", "false", "off", "no"):
            return False
        raise ValueError(f"{what}: expected on/off or true/false, got {text!r}")
    if t is ParamType.STRING:
        return text
    if t is ParamType.BYTES:
        return text.encode("utf-8")
    if t is ParamType.FLOAT_ARRAY:
        return FloatArray(_numbers(text, what))
    if t is ParamType.INT_ARRAY:
        return IntArray(_int64(x, what) for x in text.replace(" ", "").split(",") if x != "")
    if t is ParamType.JOINTS:
        return Joints(_numbers(text, what))
    if t is ParamType.LOCATION:
        values = _numbers(text, what)
        if len(values) != 6:
            raise ValueError(f"{what}: a location is x,y,z,rx,ry,rz (6 numbers), got {text!r}")
        return Location(*values)
    if t is ParamType.TRANSFORM:
        return Transform(_numbers(text, what))
    raise ValueError(f"{what}: {t.name} parameters cannot be given on the command line")


#: Trailing parameters that may be left off on the command line: the identity location.
_IDENTITY_DEFAULTS = {"tool", "frame"}


def _defaultable(p: ParamSpec) -> bool:
    return p.optional or (p.type is ParamType.LOCATION and p.name in _IDENTITY_DEFAULTS)


def parse_args(spec: CommandSpec, args: list[str]) -> tuple[Value, ...]:
    """Parse a command's arguments; a trailing tool or frame left off is the identity."""
    required = len(spec.params)
    while required and _defaultable(spec.params[required - 1]):
        required -= 1
    if not required <= len(args) <= len(spec.params):
        usage = " ".join(
            f"[{p.name}]" if _defaultable(p) else f"<{p.name}:{p.type.name.lower()}>"
            for p in spec.params
        )
        raise ValueError(f"usage: {spec.name} {usage}".rstrip())
    values = [parse_arg(p, a) for p, a in zip(spec.params, args, strict=False)]
    for p in spec.params[len(args) :]:
        if not p.optional:
            values.append(Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    try:
        # Encoded once now, so what cannot go on the wire (a string that is not UTF-8, a
        # frame over the size limit) is a usage error, not "cannot reach" after connecting.
        encode_packet(request(spec.id, 1, *values))
    except (ProtocolError, UnicodeError) as exc:
        raise ValueError(f"{spec.name}: the arguments cannot be encoded: {exc}") from None
    return tuple(values)


def reply_notes(spec: CommandSpec, values: tuple[Value, ...], endpoint: str) -> list[str]:
    """What a reply's enumerated values tell the user beyond their number: a measurement
    whose status says the sensor's laser is off says so, and how to switch it on [SS-5.13]."""
    notes = []
    for p, value in zip(spec.reply, values, strict=False):
        if (
            p.enum is SensorStatus
            and isinstance(value, int)
            and value in SensorStatus._value2member_map_
        ):
            notes.append(SensorStatus(value).problem(endpoint))
    return [n for n in notes if n]


def reply_json(spec: CommandSpec, values: tuple[Value, ...]) -> dict[str, Any]:
    names = [p.name for p in spec.reply]
    out: dict[str, Any] = {}
    for i, value in enumerate(values):
        out[names[i] if i < len(names) else f"extra_{i}"] = plain(value)
    return out


#: Reals are printed to DECIMALS places (a nanometre, a nano-degree, a nanosecond: far below
#: any sensor or encoder) and at most DIGITS significant digits, without float noise like
#: 3.7520000000000002 or 1.98806763458e-15 for a joint at zero.
DECIMALS = 9
DIGITS = 12
#: A matrix reply (a joint log, seam points) of more rows than this is summarised unless
#: ``--all``: its shape, the first and the last rows.
SUMMARY_ROWS = 20
_ENDS = 3


def _rounded(value: Any) -> Any:
    if isinstance(value, float):
        return float(f"{round(value, DECIMALS):.{DIGITS}g}") + 0.0  # + 0.0: no -0.0
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return value


def _is_matrix(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(r, list) for r in value)


def summarised(reply: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """The reply with each matrix of more than SUMMARY_ROWS rows replaced by its shape, first
    and last rows; and the names of the matrices summarised."""
    out, names = dict(reply), []
    for name, value in reply.items():
        if _is_matrix(value) and len(value) > SUMMARY_ROWS:
            out[name] = {
                "rows": len(value),
                "columns": len(value[0]),
                "first": value[:_ENDS],
                "last": value[-_ENDS:],
            }
            names.append(name)
    return out, names


def format_reply(reply: dict[str, Any]) -> str:
    """The reply as JSON, reals rounded (DECIMALS, DIGITS); a matrix (a joint log, seam
    points) gets one row per line so it can be read, grepped and cut."""
    parts = []
    for name, value in _rounded(reply).items():
        text = json.dumps(value, ensure_ascii=False)
        if _is_matrix(value):
            rows = ",\n  ".join(json.dumps(r) for r in value)
            text = f"[\n  {rows}\n]"
        parts.append(f"{json.dumps(name)}: {text}")
    return "{" + ", ".join(parts) + "}"


def list_commands(service: str) -> str:
    """One line per command of ``service``: name, ID, parameters, and whether it needs
    control (``call`` takes and releases it itself) or moves the arm."""
    lines = []
    for c in COMMANDS:
        if service not in c.services:
            continue
        params = " ".join(
            f"[{p.name}]" if _defaultable(p) else f"<{p.name}:{p.type.name.lower()}>"
            for p in c.params
        )
        flags = ("control " if c.needs_control else "") + ("moves" if c.moves else "")
        lines.append(f"{c.name:<20} 0x{int(c.id):04x}  {params:<52} {flags}".rstrip())
    return "\n".join(lines)


class ListCommands(argparse.Action):
    """``call --list``: print the service's commands and exit (no endpoint needed)."""

    def __init__(self, option_strings: list[str], dest: str, service: str = "", **kw: Any):
        super().__init__(option_strings, dest, nargs=0, **kw)
        self.service = service

    def __call__(self, parser: argparse.ArgumentParser, *args: Any, **kw: Any) -> None:
        print(list_commands(self.service))
        parser.exit(0)


def main_call(
    service: str, default_port: int, endpoint: str, command: str, args: list[str],
    timeout: float = 5.0, token: str | None = None, wait: float | None = 60.0,
    all_rows: bool = False,
) -> int:  # fmt: skip
    """Run one ``call``; returns the process exit code (0 ok, 1 error reply or a move that did
    not end within ``wait``, 2 usage, 3 unreachable). A queued move is followed by WaitEndMove
    up to ``wait`` seconds and the reply gets ``"done"``; with ``wait=None`` the command
    returns at once and the move goes on (control is released, not lost)."""
    if wait is not None and not wait > 0:
        print(f"error: the wait must be > 0 s, got {wait}", file=sys.stderr)
        return ExitCode.USAGE
    if not timeout > 0:
        print(f"error: the timeout must be > 0 s, got {timeout}", file=sys.stderr)
        return ExitCode.USAGE
    try:
        host, port = parse_endpoint(endpoint, default_port)
        spec = find_command(command, service)
        params = parse_args(spec, args)
    except (ValueError, ProtocolError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    queued = False
    result: MoveResult | None = None
    try:
        with stop_signals_interrupt(), FramedClient(host, port, timeout=timeout) as client:
            take = spec.needs_control and spec.id != CommandId.TAKE_CONTROL
            if take:
                client.take_control(token or "")
            try:
                values = client.call(spec.id, *params)
                reply = reply_json(BY_ID[spec.id], values)
                notes = reply_notes(BY_ID[spec.id], values, endpoint)
                queued = spec.id in _QUEUED_MOVES
                if queued and wait is not None:
                    result = wait_move(client, wait)
                    reply["done"] = result.reached
                    reply["outcome"] = result.outcome.value
                    if result.reason:
                        reply["reason"] = result.reason
            except KeyboardInterrupt:
                _stop_what_was_started(client, take and queued)
                raise
            finally:
                if take and client.connected:
                    # Released, not lost: a move that is still running goes on [RS-7.11];
                    # also after an error reply, so the next call finds control free.
                    client.release_control()
    except KeyboardInterrupt:
        stopped = "; the move was stopped" if queued else ""
        print(f"interrupted{stopped}; control released", file=sys.stderr)
        return ExitCode.INTERRUPTED
    except RemoteError as exc:
        hint = ""
        if exc.code is ErrorCode.AUTH_FAILED and not token:
            hint = " (the server wants a control token: --token-file FILE)"
        print(f"error {error_text(exc)}{hint}", file=sys.stderr)
        return ExitCode.FAILED
    except (OSError, ProtocolError) as exc:
        print(f"error: {unreachable(host, port, exc)}", file=sys.stderr)
        return ExitCode.UNREACHABLE
    return _print_reply(reply, notes, result, wait, all_rows=all_rows)


def _print_reply(
    reply: dict[str, Any],
    notes: list[str],
    result: MoveResult | None,
    wait: float | None,
    *,
    all_rows: bool,
) -> int:
    """Print a call's reply and notes; the exit code of the move it waited for, if any."""
    if not all_rows:
        reply, cut = summarised(reply)
        for name in cut:
            notes.append(f"{name}: {reply[name]['rows']} rows summarised; --all prints every row")
    print(format_reply(reply))
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    if result is not None and result.outcome is MoveOutcome.MOVING:
        print(f"error: the move did not end within {wait:g} s (it goes on)", file=sys.stderr)
        return ExitCode.FAILED
    if result is not None and not result.reached:
        # [RS-5.50] stopped short or failed: a script must not take it for done.
        print(f"error: the move was {result.outcome.value}: {result.reason}", file=sys.stderr)
        return ExitCode.FAILED
    return ExitCode.OK


def unreachable(host: str, port: int, exc: OSError | ProtocolError) -> str:
    """What went wrong reaching a server, in one line naming it: the client's own errors
    (no reply, a bad frame, closed) already name the server, and their wire code
    ("INTERNAL_ERROR (19)" for a closed connection) would read as the server's; a socket
    error does not name it."""
    if isinstance(exc, ProtocolError):
        return error_text(exc)
    return f"cannot reach {host}:{port}: {error_text(exc)}"


def _stop_what_was_started(client: FramedClient, moved: bool) -> None:
    """After Ctrl-C: a move this call queued decelerates and the queue empties. Best
    effort: an unreachable server stops the arm itself when control is lost [RS-7.10]."""
    if not moved or not client.connected:
        return
    try:
        client.call(CommandId.RESET_MOTION)
    except (OSError, ProtocolError):
        pass


@contextmanager
def stop_signals_interrupt() -> Iterator[None]:
    """SIGINT and SIGTERM end a command that holds control with a KeyboardInterrupt in the main
    thread, so it stops what it started. Installed explicitly: a process started with SIGINT
    ignored (a background job of a script, a test runner's worker) must still stop the arm."""

    def interrupt(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    try:
        previous = {s: signal.signal(s, interrupt) for s in (signal.SIGINT, signal.SIGTERM)}
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
