"""Argument types shared by the command lines: a bad value is refused by argparse with one
line naming the option, before any work starts (never a traceback after it)."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from spec import wire
from spec.auth import Network, read_token_file
from spec.exitcodes import ExitCode
from spec.files import prepare_output_dir, prepare_output_path
from spec.server import ServerPolicy, parse_networks


def port(text: str) -> int:
    """A TCP/UDP port, 0 (any free port) to 65535."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 0..65535, got {value}")
    return value


#: Largest value a plain number option takes: far above any quantity these tools handle in
#: its unit, far below where arithmetic on it overflows or a buffer sized by it explodes.
MAX_NUMBER = 1e9
#: Timeouts and waits: below a millisecond a socket timeout rounds to 0, which the kernel
#: reads as "wait forever"; above 1e6 s (11.6 days) nothing is worth waiting for.
MIN_TIMEOUT = 1e-3
MAX_TIMEOUT = 1e6
#: Seeds: numpy takes any non-negative integer; 64 bits is what a report can print back.
MAX_SEED = (1 << 64) - 1


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def number_in(low: float, high: float, *, low_open: bool = False) -> Callable[[str], float]:
    """A number in [low, high] (or (low, high] with ``low_open``), e.g. a modelled latency
    whose buffers would not fit in memory beyond ``high``."""

    def parse(text: str) -> float:
        value = _number(text)
        if value < low or (low_open and value == low) or value > high:
            left = "(" if low_open else "["
            raise argparse.ArgumentTypeError(f"must be in {left}{low:g}, {high:g}], got {text}")
        return value

    parse.__name__ = "number"
    return parse


def positive_float(text: str) -> float:
    """A number > 0 and <= MAX_NUMBER."""
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    if value > MAX_NUMBER:
        raise argparse.ArgumentTypeError(f"must be <= {MAX_NUMBER:g}, got {text}")
    return value


def nonnegative_float(text: str) -> float:
    """A number >= 0 and <= MAX_NUMBER."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    if value > MAX_NUMBER:
        raise argparse.ArgumentTypeError(f"must be <= {MAX_NUMBER:g}, got {text}")
    return value


def udp_port(text: str) -> int | None:
    """A UDP port option: a number, ``0``/``auto`` any free port, ``off`` none (None)."""
    if text == "off":
        return None
    if text == "auto":
        return 0
    try:
        return port(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(f"{exc} (or auto, off)") from None


def watchdog(text: str) -> float:
    """A control watchdog period within the server's limits (PROTOCOL.md [RS-7.13])."""
    value = positive_float(text)
    low, high = ServerPolicy.watchdog_min, ServerPolicy.watchdog_max
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"must be within {low:g}..{high:g} s, got {text!r}")
    return value


def timeout(text: str) -> float:
    """Seconds to wait, MIN_TIMEOUT to MAX_TIMEOUT."""
    value = _number(text)
    if not MIN_TIMEOUT <= value <= MAX_TIMEOUT:
        # the parsed value, not the raw text: "\r0" is 0 too and must not break the line
        msg = f"must be between {MIN_TIMEOUT:g} and {MAX_TIMEOUT:g} s, got {value:g}"
        raise argparse.ArgumentTypeError(msg)
    return value


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def int_in(low: int, high: int) -> Callable[[str], int]:
    """An integer in [low, high]."""

    def parse(text: str) -> int:
        value = _integer(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be in [{low}, {high}], got {value}")
        return value

    parse.__name__ = "integer"
    return parse


def positive_int(text: str) -> int:
    value = _integer(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def seed(text: str) -> int:
    """A random seed, 0 to 2**64 - 1."""
    value = _integer(text)
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"a seed is 0..2**64-1, got {value}")
    return value


def token_file(text: str) -> str:
    """A file holding the control token: the token (stripped), read now, so a missing, empty
    or unreadable file stops the tool before it starts [RS-7.3]."""
    try:
        return read_token_file(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_token_file(parser: Any, whose: str, *, dest: str = "token") -> None:
    """``--token-file FILE`` on ``parser``: the one declaration every command line shares. The
    token is read (and a missing or empty file refused) when the option is parsed
    (:func:`token_file`); a file, not the token itself, so ``ps`` does not show it. ``whose``
    names it in the help line: "the robot's", "the endpoint's", "the TakeControl"."""
    parser.add_argument(
        "--token-file",
        dest=dest,
        type=token_file,
        metavar="FILE",
        help=f"file holding {whose} control token (one line; not shown by ps)",
    )


def network(text: str) -> Network:
    """One network of an allow-list (``10.0.0.0/24``, ``127.0.0.1``, ``::1``)."""
    try:
        return parse_networks([text])[0]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def parse_endpoint(text: str, default_port: int) -> tuple[str, int]:
    """``HOST:PORT``, ``HOST`` or ``[V6]:PORT``; ValueError names the problem."""
    host, sep, port = text.rpartition(":")
    if not sep or "]" in port:
        return text.strip("[]"), default_port
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"bad port in {text!r}") from None
    if not 0 < number < 65536:
        raise ValueError(f"port out of range in {text!r}")
    return host.strip("[]") or "127.0.0.1", number


def endpoint(default_port: int) -> Callable[[str], tuple[str, int]]:
    """An argparse type: ``HOST[:PORT]`` (``[V6]:PORT``), ``default_port`` when none is given."""

    def parse(text: str) -> tuple[str, int]:
        try:
            return parse_endpoint(text, default_port)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return parse


_SERVICES = {
    "robot": ("RobotSocket", wire.ROBOT_PORT),
    "sensor": ("SensorSocket", wire.SENSOR_PORT),
}


def add_endpoint(parser: Any, service: str, note: str = "") -> None:
    """``--robot`` or ``--sensor`` HOST[:PORT] on ``parser`` (or a group of it), the paper's
    port when none is given; ``note`` ends the help line (e.g. ", with --robot")."""
    name, port = _SERVICES[service]
    parser.add_argument(
        f"--{service}",
        type=endpoint(port),
        metavar="HOST[:PORT]",
        help=f"the {name} server (port {port} when none is given){note}",
    )


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr and exit status 2 (no usage
    dump); give it to ``add_subparsers(parser_class=Parser)`` too.

    Options are not taken by a prefix: ``welding track --robot X --sensor Y`` (track has
    neither) said "ambiguous option: --sensor could match --sensor-tool, ..." instead of
    naming the unknown options, and a script's abbreviation changes meaning when an option
    is added."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")

    def format_help(self) -> str:
        for action in self._actions:
            _show_default(action)
        return super().format_help()

    def _get_values(self, action: argparse.Action, arg_strings: list[str]) -> Any:
        # Python 3.11's argparse drops the value of ``--seed=--`` as if it ended the options
        # and stores [] unchecked (a traceback later): the value goes through the option's
        # type like any other instead, an error for a number and "--" for a string.
        if action.option_strings and action.nargs is None and arg_strings == ["--"]:
            return self._get_value(action, "--")
        return super()._get_values(action, arg_strings)


def _show_default(action: argparse.Action) -> None:
    """Add an option's default to its help line, unless the help already names one: a user
    reading ``--help`` must not have to guess the port or the clock."""
    default, text = action.default, action.help or ""
    if not action.option_strings or text == argparse.SUPPRESS or "default" in text:
        return
    if default is None or isinstance(default, bool) or default in ("", argparse.SUPPRESS):
        return
    if isinstance(default, list | tuple) and not default:
        return
    values = default if isinstance(default, list | tuple) else [default]
    shown = ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in values)
    action.help = f"{text}; default {shown}" if text else f"default {shown}"


def output_file(text: str) -> str:
    """A file the tool will write; its directory is created now, a bad path refused now."""
    try:
        prepare_output_path(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def output_dir(text: str) -> str:
    """A directory the tool will write files into (created now if missing)."""
    try:
        prepare_output_dir(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def program_name(argv0: str) -> str:
    """How the user started us: ``python -m conformance`` or ``rsf-conformance``."""
    path = Path(argv0)
    return f"python -m {path.parent.name}" if path.name == "__main__.py" else path.name


def interrupted(prog: str, stopped: str = "") -> ExitCode:
    """Ctrl-C (or SIGTERM) ended a command: the one line every tool prints, and its code.
    ``stopped`` says what the tool's controlled stop ended and in which state it left things
    (``"the emulated cell stopped, its servers closed"``): ``PROG: interrupted: STOPPED``."""
    print(f"{prog}: interrupted" + (f": {stopped}" if stopped else ""), file=sys.stderr)
    return ExitCode.INTERRUPTED


def run_cli(main: Callable[[], int]) -> int:
    """Run a command line's ``main``. A reader that closed our standard output (``… | head``)
    ends it quietly, as it ends a Unix tool, instead of with an error message; Ctrl-C that
    ``main`` does not handle itself is one line and exit status 130, not a traceback."""
    try:
        code = main()
        sys.stdout.flush()
        return code
    except KeyboardInterrupt:
        return interrupted(program_name(sys.argv[0]))
    except BrokenPipeError:
        # Python flushes stdout again at exit: point it at /dev/null so that stays quiet.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return ExitCode.BROKEN_PIPE
