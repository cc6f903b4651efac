"""Command-line values: every bad value is a one-line usage error (exit 2), never a traceback
or a value the tool cannot use (infinite, huge, negative seed, zero timeout)."""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from cell.__main__ import _parser as cell_parser
from conformance.cli import UsageError as ConformanceUsage
from conformance.cli import build_parser as conformance_parser
from robotsocket.__main__ import build_parser as robot_parser
from sensorsocket.__main__ import _parser as sensor_parser
from spec import cliargs
from spec.callcli import find_command, parse_arg, parse_args
from spec.registry import ParamSpec
from spec.wire import ParamType
from sync.__main__ import _parser as sync_parser

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


# --- the shared types ---------------------------------------------------------------------------


@pytest.mark.parametrize("text", ["inf", "-inf", "nan", "1e300", "1e10", "abc", ""])
def test_positive_float_refuses_non_finite_and_huge(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        cliargs.positive_float(text)


@pytest.mark.parametrize("text", ["0.0000009", "0", "-1", "1e300", "1e7"])
def test_timeout_is_bounded_both_ways(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=r"between 0\.001 and 1e"):
        cliargs.timeout(text)


def test_timeout_accepts_the_sensible_range() -> None:
    assert cliargs.timeout("0.001") == 0.001
    assert cliargs.timeout("5") == 5.0
    assert cliargs.timeout("1e6") == 1e6


@pytest.mark.parametrize("text", ["-1", "18446744073709551616", "1.5", "x"])
def test_seed_refuses_negative_huge_and_non_integers(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        cliargs.seed(text)


def test_seed_accepts_64_bits() -> None:
    assert cliargs.seed("0") == 0
    assert cliargs.seed(str(2**64 - 1)) == 2**64 - 1


def test_number_in_and_int_in_name_the_range() -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be in \(0, 10\]"):
        cliargs.number_in(0.0, 10.0, low_open=True)("0")
    assert cliargs.number_in(0.0, 10.0)("0") == 0.0
    with pytest.raises(argparse.ArgumentTypeError, match=r"must be in \[1, 3\]"):
        cliargs.int_in(1, 3)("4")


def test_token_file_type_reads_and_refuses(tmp_path: Path) -> None:
    good, empty = tmp_path / "good", tmp_path / "empty"
    good.write_text("tok\n", encoding="utf-8")
    empty.write_text(" \n", encoding="utf-8")
    assert cliargs.token_file(str(good)) == "tok"
    with pytest.raises(argparse.ArgumentTypeError, match=f"token file {empty} is empty"):
        cliargs.token_file(str(empty))


def test_network_type() -> None:
    assert str(cliargs.network("10.1.2.3/24")) == "10.1.2.0/24"
    with pytest.raises(argparse.ArgumentTypeError, match="not a network address"):
        cliargs.network("10.0.0.300")


# --- call arguments -----------------------------------------------------------------------------


@pytest.mark.parametrize("text", [str(2**63), str(-(2**63) - 1), "0x" + "f" * 17, "1" * 40])
def test_call_refuses_integers_beyond_64_bits(text: str) -> None:
    with pytest.raises(ValueError, match="signed 64-bit"):
        parse_arg(ParamSpec("count", ParamType.INT), text)
    with pytest.raises(ValueError, match="signed 64-bit"):
        parse_arg(ParamSpec("ids", ParamType.INT_ARRAY), f"1,{text}")


def test_call_refuses_what_cannot_be_encoded_before_connecting() -> None:
    # An undecodable byte on the command line reaches Python as a lone surrogate.
    with pytest.raises(ValueError, match="TakeControl: the arguments cannot be encoded"):
        parse_args(find_command("takecontrol", "robot"), ["\udcff"])


def test_call_takes_64_bit_integers_and_finite_floats() -> None:
    assert parse_arg(ParamSpec("count", ParamType.INT), str(2**63 - 1)) == 2**63 - 1
    assert parse_arg(ParamSpec("count", ParamType.INT), "-0x10") == -16
    with pytest.raises(ValueError, match="finite"):
        parse_arg(ParamSpec("rate", ParamType.FLOAT), "inf")


# --- every parser, driven by hypothesis ---------------------------------------------------------

Parse = Callable[[list[str]], argparse.Namespace]


def _argparse(build: Callable[[], argparse.ArgumentParser]) -> Parse:
    return lambda argv: build().parse_args(argv)


#: (parser, arguments before the option, option, attribute): every number a CLI takes.
NUMERIC_OPTIONS: list[tuple[Parse, list[str], str, str]] = [
    (_argparse(robot_parser), ["serve"], "--encoder-latency-ms", "encoder_latency_ms"),
    (_argparse(robot_parser), ["serve"], "--port", "port"),
    (_argparse(robot_parser), ["serve"], "--max-clients", "max_clients"),
    (_argparse(robot_parser), ["call", "h:1", "herej"], "--timeout", "timeout"),
    (_argparse(robot_parser), ["call", "h:1", "herej"], "--wait", "wait"),
    (_argparse(robot_parser), ["watch", "h:1"], "--interval", "interval"),
    (_argparse(sensor_parser), ["serve"], "--seed", "seed"),
    (_argparse(sensor_parser), ["serve"], "--network-delay", "network_delay"),
    (_argparse(sensor_parser), ["call", "h:1", "ping"], "--timeout", "timeout"),
    (_argparse(sensor_parser), ["snapshot", "h:1", "-o", "x.pgm"], "--timeout", "timeout"),
    (_argparse(sync_parser), ["delay"], "--duration", "duration"),
    (_argparse(sync_parser), ["delay"], "--rate", "rate"),
    (_argparse(sync_parser), ["delay"], "--search-max-ms", "search_max_ms"),
    (_argparse(sync_parser), ["delay"], "--seed", "seed"),
    (_argparse(sync_parser), ["delay"], "--encoder-latency-ms", "encoder_latency_ms"),
    (_argparse(sync_parser), ["curvature"], "--speed", "speed"),
    (_argparse(cell_parser), ["serve"], "--seed", "seed"),
    (_argparse(cell_parser), ["serve"], "--trigger-poll-hz", "trigger_poll_hz"),
    (_argparse(cell_parser), ["serve"], "--frame-timeout", "frame_timeout"),
    (_argparse(cell_parser), ["demo"], "--duration", "duration"),
    (_argparse(conformance_parser), ["robot"], "--timeout-scale", "timeout_scale"),
    (_argparse(conformance_parser), ["robot"], "--fuzz", "fuzz"),
    (_argparse(conformance_parser), ["robot"], "--seed", "seed"),
]

VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.sampled_from(["inf", "-inf", "nan", "1e308", "1e-300", "0.0000009", "-0", "0x10", ""]),
    st.text(max_size=8),
)


@pytest.mark.parametrize(
    ("parse", "before", "option", "attr"),
    NUMERIC_OPTIONS,
    # stable ids (a lambda's repr holds its address, which differs between test processes)
    ids=[
        f"{i}-{'_'.join(before)}-{option}"
        for i, (_, before, option, _) in enumerate(NUMERIC_OPTIONS)
    ],
)
@settings(max_examples=60, deadline=None)
@given(value=VALUES)
@example(value="--")  # Python 3.11's argparse stored [] for --seed=-- (spec.cliargs.Parser)
def test_numeric_options_are_usable_or_one_line_errors(
    parse: Parse, before: list[str], option: str, attr: str, value: str
) -> None:
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            args = parse([*before, f"{option}={value}"])
    except SystemExit as exc:
        assert exc.code == 2
        lines = err.getvalue().strip().splitlines()
        assert len(lines) == 1 and "error" in lines[0], err.getvalue()
        return
    except ConformanceUsage as exc:  # the harness's usage errors: exit 2 (USAGE)
        assert "\n" not in str(exc)
        return
    got = getattr(args, attr)
    assert isinstance(got, int | float) and math.isfinite(got), got
    if isinstance(got, float):
        assert abs(got) <= cliargs.MAX_NUMBER
        if attr in ("timeout", "wait"):
            assert got >= cliargs.MIN_TIMEOUT
    else:
        assert 0 <= got < 2**64


# --- real processes: exit code and one line on stderr ------------------------------------------


def _run(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", *argv],
        capture_output=True,
        text=True,
        env=ENV,
        cwd=ROOT,
        timeout=60,
    )


@pytest.fixture(scope="module")
def empty_token(tmp_path_factory: pytest.TempPathFactory) -> str:
    path = tmp_path_factory.mktemp("tok") / "empty-token"
    path.write_text("  \n", encoding="utf-8")
    return str(path)


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (("robotsocket", "call", "127.0.0.1:1", "herej", "--timeout", "1e300"), "--timeout"),
        (("robotsocket", "call", "127.0.0.1:1", "herej", "--timeout", "inf"), "--timeout"),
        (("robotsocket", "call", "127.0.0.1:1", "herej", "--timeout", "0.0000009"), "--timeout"),
        (("robotsocket", "serve", "--encoder-latency-ms", "1e308"), "--encoder-latency-ms"),
        (("robotsocket", "serve", "--allow"), "--allow"),
        (("robotsocket", "call", "127.0.0.1:1", "starttriggers", "250", "1" * 25), "64-bit"),
        (("sensorsocket", "serve", "--network-delay", "inf"), "--network-delay"),
        (("sensorsocket", "serve", "--seed", "-1"), "--seed"),
        (("sensorsocket", "serve", "--allow"), "--allow"),
        (("cell", "serve", "--seed", "-1"), "--seed"),
        (("sync", "delay", "--emulate", "--duration", "1e300"), "--duration"),
        (("sync", "curvature", "--speed", "1e-300"), "--speed"),
        (("kinematics", "ik", "--location=1e300,0,0,0,0,0"), "within"),
        (("kinematics", "fk", "--joints=--"), "joints"),  # was a traceback: joints = []
        (("welding", "track", "--seed=--"), "--seed"),
        (("spec", "decode", ""), "empty input"),
        (("spec", "fuzz", "--seed", "-1"), "--seed"),
        (("spec", "nonsense"), "invalid choice"),
    ],
)
def test_bad_values_are_one_line_usage_errors(argv: tuple[str, ...], needle: str) -> None:
    done = _run(*argv)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert needle in lines[0]
    assert "Traceback" not in done.stderr


@pytest.mark.parametrize("service", ["robotsocket", "sensorsocket"])
def test_empty_token_file_stops_every_server(service: str, empty_token: str) -> None:
    done = _run(service, "serve", "--port", "0", "--token-file", empty_token)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [done.stderr.strip()]
    assert f"token file {empty_token} is empty" in done.stderr


@pytest.mark.parametrize(
    "argv",
    [
        ("robotsocket", "call", "127.0.0.1:1", "takecontrol", "--token-file"),
        ("sensorsocket", "call", "127.0.0.1:1", "acquire", "--token-file"),
        ("conformance", "robot", "127.0.0.1:1", "--token-file"),
        ("sync", "delay", "--robot", "127.0.0.1:1", "--token-file"),
    ],
)
def test_empty_token_file_stops_every_client(argv: tuple[str, ...], empty_token: str) -> None:
    done = _run(*argv, empty_token)
    assert done.returncode in (2, 3)  # 3: the harness's documented usage code
    assert f"token file {empty_token} is empty" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr


def test_program_name_is_how_the_user_started_the_tool() -> None:
    assert cliargs.program_name("/x/site-packages/conformance/__main__.py") == (
        "python -m conformance"
    )
    assert cliargs.program_name("/x/.venv/bin/rsf-conformance") == "rsf-conformance"


def test_help_names_each_options_default_once() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "cell", "serve", "--help"],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    text = " ".join(done.stdout.split())  # argparse wraps lines to the terminal width
    for option, default in [
        ("--robot-port ROBOT_PORT", "4000"),
        ("--sensor-port SENSOR_PORT", "2000"),
        ("--udp-port UDP_PORT", "2001"),
        ("--clock {sim,real}", "real"),
        ("--model MODEL", "RX90B"),
    ]:
        assert f"{option} default {default} " in text, option
    # a help that already names its default keeps it, once
    assert "(ms), default 2.8 --trigger-poll-hz" in text
    assert "--in-process default" not in text  # a flag has no default to show


def test_a_default_is_shown_for_a_plain_help_too() -> None:
    parser = cliargs.Parser(prog="tool")
    parser.add_argument("--interval", type=float, default=0.5, help="seconds between lines")
    parser.add_argument("--allow", nargs="+", default=[], help="networks")
    parser.add_argument("--error", default=(0.0,) * 3, help="mm")
    text = " ".join(parser.format_help().split())
    assert "seconds between lines; default 0.5" in text
    assert "mm; default 0,0,0" in text
    assert "networks default" not in text and "networks;" not in text
    assert text == " ".join(parser.format_help().split())  # formatting twice adds nothing


def test_an_unknown_option_is_named_not_taken_for_a_prefix() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "welding", "track", "--emulate", "--robot", "127.0.0.1:4000",
         "--sensor", "127.0.0.1:2000"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        "python -m welding: error: unrecognized arguments: --robot 127.0.0.1:4000"
        " --sensor 127.0.0.1:2000"
    ]  # not "ambiguous option: --sensor could match --sensor-tool, ..."
    parser = cliargs.Parser(prog="tool")
    parser.add_argument("--duration", type=float)
    with pytest.raises(SystemExit):
        parser.parse_args(["--dur", "1"])
