"""python -m conformance: the user's mistakes are said in one line, not as endpoint failures."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from conformance.cli import main
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from spec.exitcodes import ExitCode
from spec.server import FramedServer, ServerPolicy

if TYPE_CHECKING:
    from tests.conftest import NotAServer


@pytest.fixture
def protected_robot() -> Iterator[str]:
    policy = ServerPolicy(token="s3cret")
    with FramedServer(RobotService(RobotEmulator()), "127.0.0.1", 0, policy) as srv:
        yield f"127.0.0.1:{srv.address[1]}"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def test_unreachable_endpoint_is_one_line_and_a_short_report(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    md, js = tmp_path / "r.md", tmp_path / "r.json"
    code = main(["robot", f"127.0.0.1:{free_port()}", "--markdown", str(md), "--json", str(js)])
    out, err = capsys.readouterr()
    assert code == ExitCode.UNREACHABLE
    assert out == "" and err.count("\n") == 1 and "cannot connect" in err
    assert len(md.read_text().splitlines()) < 20  # not one line per case
    assert json.loads(js.read_text())["reachable"] is False


def test_missing_token_is_the_users_mistake_not_a_failure(
    protected_robot: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["robot", protected_robot, "-q"])
    _, err = capsys.readouterr()
    assert code == ExitCode.USAGE
    assert err.strip().splitlines() == [
        "conformance: the robot requires a control token (none was given): pass --token or"
        " --token-file; nothing was run"
    ]


def test_the_token_given_runs_the_cases(
    protected_robot: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["robot", protected_robot, "-q", "--token", "s3cret", "--select", "control.*"])
    out, _ = capsys.readouterr()
    assert code == ExitCode.SUBSET and "pass" in out  # this robot has no sync profile


def test_a_tcp_port_given_to_the_sync_profile_is_named(
    protected_robot: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["sync", protected_robot, "-q"])
    _, err = capsys.readouterr()
    assert code == ExitCode.USAGE
    assert "is a TCP port" in err and "UDP trigger port" in err and err.count("\n") == 1


# --- a first-time user points the harness at the wrong thing (real subprocesses) ------------


def conformance_cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "conformance", *args],
        capture_output=True, text=True, timeout=timeout,
    )  # fmt: skip


def test_a_server_that_never_answers_is_one_line_exit_4(
    tmp_path: Path, not_a_server: NotAServer
) -> None:
    js = tmp_path / "r.json"
    address = not_a_server(None)
    done = conformance_cli("robot", address, "--timeout-scale", "0.25", "--json", str(js))
    assert done.returncode == ExitCode.UNREACHABLE, done.stderr
    assert done.stdout == ""
    assert done.stderr.splitlines() == [
        f"conformance: {address} accepted the connection but did not answer Hello within"
        " 0.5 s: is it a robot endpoint? (a slow one: --timeout-scale)"
    ]
    assert json.loads(js.read_text())["reachable"] is False


def test_a_server_of_another_protocol_is_one_line_exit_4(not_a_server: NotAServer) -> None:
    address = not_a_server(b"HTTP/1.0 400 Bad request\r\n\r\n")
    done = conformance_cli("sensor", address)
    assert done.returncode == ExitCode.UNREACHABLE, done.stderr
    assert done.stdout == ""
    assert done.stderr.splitlines() == [
        f"conformance: {address} answered Hello with bytes that are not a frame"
        ' (48 54 54 50 2f 31 2e 30 20 34 30 30 "HTTP/1.0 400"): is it a sensor endpoint?'
    ]


def test_the_other_service_is_named_with_the_command_to_use(protected_robot: str) -> None:
    done = conformance_cli("sensor", protected_robot)
    assert done.returncode == ExitCode.USAGE, done.stderr
    assert done.stdout == ""
    assert done.stderr.splitlines() == [
        f"conformance: {protected_robot} is a robot endpoint (its Hello says so), not a sensor"
        f" one: check it with `python -m conformance robot {protected_robot}`; nothing was run"
    ]


def test_a_closed_udp_port_and_an_unknown_host_are_one_line_exit_4() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    done = conformance_cli("sync", "--udp", f"127.0.0.1:{port}")  # nothing listens there now
    assert done.returncode == ExitCode.UNREACHABLE, done.stderr
    assert done.stderr.splitlines() == [
        f"conformance: nothing listens on UDP 127.0.0.1:{port} (port unreachable)"
    ]
    done = conformance_cli("sync", "--udp", "no-such-host.invalid:2001")
    assert done.returncode == ExitCode.UNREACHABLE, done.stderr
    assert done.stderr.startswith("conformance: cannot resolve no-such-host.invalid: ")
    assert done.stderr.count("\n") == 1


def test_ctrl_c_in_a_run_is_one_line_and_exit_130(protected_robot: str) -> None:
    # As from a terminal: SIGINT raises KeyboardInterrupt (a test worker may ignore SIGINT,
    # and a child inherits that).
    start = (
        "import runpy, signal; signal.signal(signal.SIGINT, signal.default_int_handler);"
        " runpy.run_module('conformance', run_name='__main__', alter_sys=True)"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", start, "robot", protected_robot, "--token", "s3cret"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stderr is not None
    for line in proc.stderr:
        if line.split()[:1] == ["pass"]:  # a case has run: the run is under way
            break
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert err.splitlines()[-1] == "python -m conformance: interrupted"


def test_a_server_that_closes_at_once_is_one_line_exit_4(not_a_server: NotAServer) -> None:
    address = not_a_server(b"")  # reads the Hello, answers nothing and closes
    done = conformance_cli("robot", address)
    assert done.returncode == ExitCode.UNREACHABLE, done.stderr
    assert done.stderr.splitlines() == [
        f"conformance: {address} closed the connection without answering Hello: does it"
        " refuse this machine (an allow-list) or take no more clients?"
    ]


@pytest.mark.parametrize(
    ("option", "content", "says"),
    [
        ("--expect", b"[1", "--expect file {path}: Expecting ',' delimiter"),
        ("--expect", b"[1]", "--expect file {path}: expected a JSON list of case IDs"),
        ("--expect", b"\xff\xfe", "--expect file {path}: 'utf-8' codec can't decode"),
        ("--expect", None, "cannot read --expect file {path}: No such file or directory"),
        (
            "--capabilities",
            b'{"not_offered": 5}',
            'capability file {path}: expected {{"not_offered": [names or IDs]}}',
        ),
        (
            "--capabilities",
            b'{"not_offered": ["0xzz"]}',
            "capability file {path}: unknown command '0xzz'",
        ),
        (
            "--capabilities",
            b'{"not_offered": ["0x7777"]}',
            "capability file {path}: unknown command '0x7777'",
        ),
        (
            "--capabilities",
            b'{"not_offered": [true]}',
            "capability file {path}: unknown command True",
        ),
    ],
)
def test_a_bad_expect_or_capability_file_is_one_line_exit_3(
    tmp_path: Path, option: str, content: bytes | None, says: str
) -> None:
    path = tmp_path / "given"
    if content is not None:
        path.write_bytes(content)
    done = conformance_cli("robot", "127.0.0.1:1", option, str(path))
    assert done.returncode == ExitCode.USAGE, done.stderr
    assert len(done.stderr.splitlines()) == 1 and "Traceback" not in done.stderr
    assert done.stderr.startswith("conformance: " + says.format(path=path)), done.stderr
