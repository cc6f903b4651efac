"""python -m conformance: the user's mistakes are said in one line, not as endpoint failures."""

from __future__ import annotations

import json
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from conformance.cli import main
from conformance.runner import EXIT_UNREACHABLE, EXIT_USAGE
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from spec.server import FramedServer, ServerPolicy


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
    assert code == EXIT_UNREACHABLE
    assert out == "" and err.count("\n") == 1 and "cannot connect" in err
    assert len(md.read_text().splitlines()) < 20  # not one line per case
    assert json.loads(js.read_text())["reachable"] is False


def test_missing_token_is_the_users_mistake_not_a_failure(
    protected_robot: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["robot", protected_robot, "-q"])
    _, err = capsys.readouterr()
    assert code == EXIT_USAGE
    assert err.strip().splitlines() == [
        "conformance: the robot requires a control token (none was given): pass --token or"
        " --token-file; nothing was run"
    ]


def test_the_token_given_runs_the_cases(
    protected_robot: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["robot", protected_robot, "-q", "--token", "s3cret", "--select", "control.*"])
    out, _ = capsys.readouterr()
    assert code == 0 and "pass" in out


def test_a_tcp_port_given_to_the_sync_profile_is_named(
    protected_robot: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code = main(["sync", protected_robot, "-q"])
    _, err = capsys.readouterr()
    assert code == EXIT_USAGE
    assert "is a TCP port" in err and "UDP trigger port" in err and err.count("\n") == 1
