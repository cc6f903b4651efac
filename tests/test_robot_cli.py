"""python -m robotsocket: serve, call, watch."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from robotsocket.__main__ import main
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from spec.server import ServerPolicy

if TYPE_CHECKING:
    from tests.conftest import BusyPort, NotAServer, Serve

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def endpoint(tmp_path: Path, serve: Serve) -> str:
    (tmp_path / "token").write_text("tok\n")
    srv = serve(RobotService(RobotEmulator()), ServerPolicy(token="tok"))
    return f"127.0.0.1:{srv.address[1]}"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_call_prints_json_and_errors(
    endpoint: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = run(capsys, "call", endpoint, "HEREJ")
    assert code == 0 and json.loads(out) == {"joints": [0.0, 0.0, 90.0, 0.0, 90.0, 0.0]}
    tok = ["--token-file", str(tmp_path / "token")]
    code, _, err = run(capsys, "call", endpoint, "jointmove", "0,-30,90,0,60,0", *tok)
    assert code == 1 and "NOT_POWERED" in err and "10" in err
    assert run(capsys, "call", endpoint, "EnablePower", *tok)[0] == 0
    code, out, _ = run(capsys, "call", endpoint, "jointmove", "0,-30,90,0,60,0", *tok)
    assert code == 0 and json.loads(out) == {"move_id": 1, "done": True, "outcome": "reached"}
    code, out, _ = run(capsys, "call", endpoint, "herej")
    assert json.loads(out)["joints"] == [0.0, -30.0, 90.0, 0.0, 60.0, 0.0]
    code, out, _ = run(capsys, "call", endpoint, "here", "0,0,100,0,0,0")
    assert code == 0 and len(json.loads(out)["location"]) == 6
    code, out, _ = run(capsys, "call", endpoint, "setoutput", "laser", "on", *tok)
    assert code == 0
    code, out, _ = run(capsys, "call", endpoint, "readio", "laser")
    # [RS-7.21] the laser needs an owner: off again once the call released control
    assert json.loads(out) == {"value": False, "is_output": True}
    code, _, err = run(capsys, "call", endpoint, "EnablePower")
    assert code == 1 and "AUTH_FAILED" in err
    code, _, err = run(capsys, "call", endpoint, "toolmovel", "5000,0,0,0,0,0", *tok)
    assert code == 1 and "UNREACHABLE" in err
    code, out, _ = run(capsys, "call", endpoint, "getjointlimits")
    assert json.loads(out)["limits"][0] == [-160.0, 160.0]


@pytest.mark.parametrize(
    "argv",
    [
        ["call", "nohost:port", "herej"],
        ["call", "127.0.0.1:1", "nosuchcommand"],
        ["call", "127.0.0.1:1", "jointmove"],
        ["call", "127.0.0.1:1", "jointmove", "a,b"],
        ["call", "127.0.0.1:1", "setoutput", "laser", "maybe"],
    ],
)
def test_usage_errors_exit_2(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, *argv)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1


def test_connection_refused_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "call", "127.0.0.1:1", "herej")
    assert code == 3 and err.startswith("error") and "Traceback" not in err


def test_watch_stops_after_count(endpoint: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "watch", endpoint, "--count", "3", "--interval", "0.01")
    lines = out.strip().splitlines()
    assert code == 0 and len(lines) == 3 and all("power=off" in ln for ln in lines)


def test_serve_runs_until_sigint(capsys: pytest.CaptureFixture[str]) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-m", "robotsocket", "serve", "--port", "0", "--clock", "sim"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("listening on 127.0.0.1:")
        port = line.rsplit(":", 1)[1].strip()
        # The client side in-process (the same main()): one interpreter start-up less.
        code, out, _ = run(capsys, "call", f"127.0.0.1:{port}", "gettime")
        assert code == 0 and json.loads(out) == {"time": 0.0}
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=15)
        assert proc.returncode == 130, err  # as every tool ends on Ctrl-C (docs/CLI.md)
        assert "simulated" in err and "statistics" in err
        assert err.rstrip().splitlines()[-1].startswith("python -m robotsocket: interrupted: ")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_watch_into_a_closed_pipe_ends_quietly(endpoint: str) -> None:
    """`watch … | head -1`: the reader goes away; no error message, SIGPIPE's exit status."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-m", "robotsocket", "watch", endpoint, "--interval", "0.01"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        cwd=ROOT,
    )
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    proc.stdout.close()  # what `head -1` does after its line
    try:
        err = proc.stderr.read()
        code = proc.wait(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert b"power=" in first
    assert code == 141 and err == b""


def test_call_list_and_a_joint_log_one_row_per_line(
    endpoint: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as done:
        main(["call", "--list"])
    out = capsys.readouterr().out
    assert done.value.code == 0
    joint_move = next(line for line in out.splitlines() if line.startswith("JointMove"))
    assert "<joints:joints>" in joint_move and joint_move.endswith("control moves")
    code, out, _ = run(capsys, "call", endpoint, "getjointlog", "-1", "--all")
    assert code == 0
    log = json.loads(out)["log"]
    assert len(out.splitlines()) == len(log) + 2  # "{log: [", one line per sample, "]..."
    assert all(len(row) == 7 for row in log)


def test_a_long_matrix_reply_is_summarised_unless_all() -> None:
    from spec.callcli import format_reply, summarised

    # issue 35 item 6: `call … getjointlog -1` printed 15,002 lines
    log = [[0.004 * k, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0] for k in range(15_002)]
    short, cut = summarised({"log": log, "period": 0.004})
    assert cut == ["log"] and short["period"] == 0.004
    assert short["log"] == {"rows": 15_002, "columns": 7, "first": log[:3], "last": log[-3:]}
    assert len(format_reply(short).splitlines()) == 1
    assert summarised({"log": log[:20]}) == ({"log": log[:20]}, [])


def test_reals_are_rounded_to_a_nanometre_not_to_float_noise() -> None:
    from spec.callcli import format_reply

    # issue 35 item 6: herej printed 1.98806763458e-15 for a joint at zero
    got = format_reply({"joints": [1.98806763458e-15, -2e-12, 59.99999999999999, 3.752000000002]})
    assert got == '{"joints": [0.0, 0.0, 60.0, 3.752]}'


def robot_cli(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "robotsocket", *argv],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip


@pytest.mark.parametrize("command", [["call"], ["watch", "--count", "1"]])
def test_a_server_of_another_protocol_is_named_not_unreachable(
    command: list[str], not_a_server: NotAServer
) -> None:
    address = not_a_server(b"HTTP/1.0 400 Bad request\r\n\r\n")
    # call and watch agree (docs/CLI.md: 3 = unreachable or not the protocol); watch said
    # "error: BAD_FRAME (1): ..." and exited 1 as if the robot had refused something.
    done = robot_cli(command[0], address, *(["herej"] if command == ["call"] else command[1:]))
    assert done.returncode == 3, done.stderr
    assert done.stderr.splitlines() == [
        f"error: {address} sent a bad frame: bad magic 4854, expected 5253"
        " (not a RobotSocket or SensorSocket endpoint?)"
    ]


def test_a_silent_server_is_named_with_the_time_waited(not_a_server: NotAServer) -> None:
    address = not_a_server(None)
    done = robot_cli("call", address, "herej", "--timeout", "0.3")
    assert done.returncode == 3, done.stderr
    assert done.stderr.splitlines() == [f"error: no reply from {address} within 0.3 s"]


def test_watch_names_the_address_it_cannot_reach() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    done = robot_cli("watch", f"127.0.0.1:{port}", "--count", "1")  # nobody listens
    assert done.returncode == 3, done.stderr
    assert done.stderr.splitlines() == [f"error: cannot reach 127.0.0.1:{port}: Connection refused"]


def test_a_missing_token_names_the_option(serve: Serve, tmp_path: Path) -> None:
    srv = serve(RobotService(RobotEmulator()), ServerPolicy(token="s3cret"))
    address = "{}:{}".format(*srv.address)
    done = robot_cli("call", address, "enablepower")
    assert done.returncode == 1, done.stderr
    assert done.stderr.splitlines() == [
        "error AUTH_FAILED (14): control token missing or wrong"
        " (the server wants a control token: --token-file FILE)"
    ]
    wrong = tmp_path / "token.txt"
    wrong.write_text("wrong\n")
    done = robot_cli("call", address, "enablepower", "--token-file", str(wrong))
    assert done.stderr.splitlines() == ["error AUTH_FAILED (14): control token missing or wrong"]


@pytest.mark.parametrize("option", ["--port", "--udp-port"])
def test_serve_names_the_option_of_a_port_in_use(option: str, busy_port: BusyPort) -> None:
    port = busy_port(option == "--udp-port")
    ports = {"--port": "0", "--udp-port": "0", option: str(port)}
    done = robot_cli("serve", "--clock", "sim", *(x for kv in ports.items() for x in kv))
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines()[-1] == (
        f"error: cannot listen on 127.0.0.1:{port} ({option}): Address already in use"
    )


@pytest.mark.parametrize("clock", [[], ["--clock", "real", "--in-process"], ["--clock", "sim"]])
def test_a_tcp_port_in_use_is_the_only_line(clock: list[str], busy_port: BusyPort) -> None:
    port = busy_port(False)
    done = robot_cli("serve", *clock, "--port", str(port), "--udp-port", "0")
    assert done.returncode == 2, done.stderr
    # The port is bound before the real-time child starts: before, its six INFO lines of
    # start-up and exit came first.
    assert done.stderr.splitlines() == [
        f"error: cannot listen on 127.0.0.1:{port} (--port): Address already in use"
    ]
