"""Argument types shared by the command lines: a bad value is refused by argparse with one
line naming the option, before any work starts (never a traceback after it)."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path

from spec.files import prepare_output_path
from spec.server import ServerPolicy


def port(text: str) -> int:
    """A TCP/UDP port, 0 (any free port) to 65535."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 0..65535, got {value}")
    return value


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def nonnegative_float(text: str) -> float:
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def watchdog(text: str) -> float:
    """A control watchdog period within the server's limits (PROTOCOL.md [RS-7.13])."""
    value = positive_float(text)
    low, high = ServerPolicy.watchdog_min, ServerPolicy.watchdog_max
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"must be within {low:g}..{high:g} s, got {text!r}")
    return value


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def output_file(text: str) -> str:
    """A file the tool will write; its directory is created now, a bad path refused now."""
    try:
        prepare_output_path(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def output_dir(text: str) -> str:
    """A directory the tool will write files into (created now if missing)."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text} exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        msg = f"cannot create directory {text}: {exc.strerror}"
        raise argparse.ArgumentTypeError(msg) from None
    return text


def positive_floats(text: str) -> list[float]:
    """Comma-separated numbers, each > 0 (e.g. sweep frequencies)."""
    return [positive_float(item) for item in text.split(",") if item.strip()]


#: Exit status of a Unix tool stopped by SIGPIPE (128 + 13).
EXIT_BROKEN_PIPE = 141


def run_cli(main: Callable[[], int]) -> int:
    """Run a command line's ``main``. A reader that closed our standard output (``… | head``)
    ends it quietly, as it ends a Unix tool, instead of with an error message."""
    try:
        code = main()
        sys.stdout.flush()
        return code
    except BrokenPipeError:
        # Python flushes stdout again at exit: point it at /dev/null so that stays quiet.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
