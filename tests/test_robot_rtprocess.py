"""The robot's real-time loop in a child process (robotsocket.rtprocess): real subprocesses,
real sockets on loopback."""

from __future__ import annotations

import json
import os
import pickle
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any, cast

import numpy as np
import pytest

from robotsocket.client import RobotClient
from robotsocket.emulator import HOME, RobotEmulator
from robotsocket.rtprocess import (
    ChildStartError,
    Command,
    ControlLost,
    ControlReleased,
    Query,
    RealtimeProcess,
    Request,
    RobotProcess,
    Who,
)
from robotsocket.service import RobotService
from spec.errors import ErrorCode, ProtocolError, RemoteError
from spec.messages import HereReply, PingRequest, RobotStatusReply
from spec.params import FloatArray, Joints, Location, Value
from spec.registry import CommandId
from spec.server import FramedServer, SessionView

C = CommandId
TARGET = [20.0, -10.0, 100.0, 5.0, 60.0, 10.0]
WORLD = Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
TOOL = Location(0.0, 0.0, 200.0, 0.0, 0.0, 0.0)
ROBOT = {
    "model": "RX90B",
    "encoder_latency_s": 0.0028,
    "host": "127.0.0.1",
    "udp_port": 0,
    "allow": (),
    "data_from_any": False,
}


@pytest.fixture
def child() -> Iterator[RealtimeProcess]:
    c = RealtimeProcess("robotsocket.rtprocess:build_robot", ROBOT)
    yield c
    c.close()


@pytest.fixture
def served(child: RealtimeProcess) -> Iterator[tuple[str, int]]:
    with FramedServer(RobotProcess(child), "127.0.0.1", 0) as srv:
        yield srv.address


# (command, parameters, what of the reply to compare: None = all of it)


def _settled_fields(reply: tuple[Any, ...]) -> tuple[Any, ...]:
    """RobotStatus without ``moving``: at rest it turns False only once the cycles one encoder
    latency (2.8 ms) past the last motion have run, which depends on wall-clock time, not on
    the commands; it is compared where it is determined (after JointMove, after WaitEndMove)."""
    s = RobotStatusReply.decode(reply)
    return (s.powered, s.estop, s.queue, s.in_control, s.controlled, s.last_error, s.last_message)


def _here_rounded(reply: tuple[Value, ...]) -> list[float]:
    """Here's location, rounded to 9 decimals."""
    rounded: list[float] = np.round(HereReply.decode(reply).location.as_tuple(), 9).tolist()
    return rounded


SEQUENCE: list[tuple[int, tuple[Value, ...], Callable[[tuple[Value, ...]], Any] | None]] = [
    (C.HEREJ, (), None),
    (C.HERE, (TOOL, WORLD), None),
    (C.JOINT_MOVE, (Joints(TARGET),), None),  # not powered
    (C.ENABLE_POWER, (), None),
    (C.ROBOT_STATUS, (), _settled_fields),
    (C.JOINT_MOVE, (Joints([0.0, 0.0, 0.0, 0.0, 0.0, 999.0]),), None),  # out of range
    (C.ROBOT_STATUS, (), _settled_fields),  # the last error
    (C.RESET_MOTION, (), None),
    (C.JOINT_MOVE, (Joints(TARGET),), None),
    (C.ROBOT_STATUS, (), lambda r: r[:4]),
    (C.WAIT_END_MOVE, (0.0,), None),  # a bad timeout
    (C.WAIT_END_MOVE, (20.0,), None),
    (C.HEREJ, (), None),
    (C.HERE, (TOOL, WORLD), _here_rounded),
    (C.ROBOT_STATUS, (), lambda r: r[:8]),
    (C.SET_OUTPUT, ("laser", True), None),
    (C.READ_IO, ("laser",), None),
    (C.SET_OUTPUT, ("door_closed", True), None),  # an input
    (C.GET_MOTION_DESC, (), None),
    (C.SET_MOTION_DESC, (-1.0, 100.0, 100.0, 250.0, 90.0, 0.0), None),
    (C.GET_SYNC_CONFIG, (), lambda r: r[2:]),
    (C.START_TRIGGERS, (100.0, 0), None),  # no sensor endpoint
    (C.SCHEDULE_TRIGGERS, (FloatArray([0.2, 0.1]),), None),
    (C.EMERGENCY_STOP, (), None),
    (C.READ_IO, ("laser",), None),
    (C.ENABLE_POWER, (), None),
    (C.ROBOT_STATUS, (), _settled_fields),
    (C.RESET_EMERGENCY_STOP, (), None),
    (C.ROBOT_STATUS, (), _settled_fields),
    (C.GET_JOINT_LIMITS, (), None),
]


def _run(address: tuple[str, int]) -> list[Any]:
    out: list[Any] = []
    with RobotClient(*address, timeout=30.0) as c:
        hello = c.hello()
        out.append(hello["commands"])
        c.take_control("")
        for cid, params, pick in SEQUENCE:
            try:
                reply = c.call(cid, *params)
                out.append(("ok", reply if pick is None else pick(reply)))
            except RemoteError as exc:
                out.append(("error", exc.code))
        _, q = c.joint_log(-1.0)
        out.append(("joint log ends at", q[-1].round(9).tolist()))
    return out


def test_the_child_answers_as_in_process(served: tuple[str, int]) -> None:
    robot = RobotEmulator(clock="real", encoder_latency=0.0028).start()
    service = RobotService(robot)
    from robotsocket.sync_service import attach_udp_sync

    _, endpoint = attach_udp_sync(service, robot)
    try:
        with FramedServer(service, "127.0.0.1", 0) as srv:
            expected = _run(srv.address)
    finally:
        endpoint.stop()
        robot.close()
    got = _run(served)
    steps = ["hello", *(f"{CommandId(c).name}{p}" for c, p, _ in SEQUENCE), "joint log"]
    for step, g, e in zip(steps, got, expected, strict=True):
        assert g == e, step
    assert ("error", ErrorCode.NOT_POWERED) in got and ("error", ErrorCode.BAD_STATE) in got


def test_a_killed_child_is_bad_state_not_a_hang(
    child: RealtimeProcess, served: tuple[str, int]
) -> None:
    with RobotClient(*served, timeout=10.0) as c:
        c.take_control("")
        c.enable_power()
        os.kill(child.pid, signal.SIGKILL)
        gone = threading.Event()
        while child.alive:  # the pipe's reader sees the EOF
            gone.wait(0.01)
        for cid, params in (
            (C.HEREJ, ()),
            (C.ROBOT_STATUS, ()),
            (C.JOINT_MOVE, (Joints(TARGET),)),
            (C.WAIT_END_MOVE, (5.0,)),
            (C.SET_OUTPUT, ("laser", True)),
            (C.EMERGENCY_STOP, ()),
        ):
            with pytest.raises(RemoteError) as e:
                c.call(cid, *params)
            assert e.value.code == ErrorCode.BAD_STATE
            assert "real-time process ended" in e.value.message
        c.call(C.PING)  # the server itself stays up


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_killing_the_server_stops_the_arm_laser_first() -> None:
    server = subprocess.Popen(
        [sys.executable, "-m", "robotsocket", "serve", "--port", "0", "--udp-port", "off"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert server.stdout is not None
    try:
        line = server.stdout.readline()
        host, port = line.split()[-1].rsplit(":", 1)
        with RobotClient(host, int(port), timeout=10.0) as c:
            c.take_control("")
            c.enable_power()
            c.set_output("laser", True)
            c.joint_move([-60.0, 0.0, 90.0, 0.0, 90.0, 0.0])  # a long move
            assert c.status().moving
            os.kill(server.pid, signal.SIGKILL)
            # the child keeps our stderr open until it exits
            _, err = server.communicate(timeout=30)
    finally:
        if server.poll() is None:
            server.kill()
    pid = int(re.search(r"real-time clock in process (\d+)", err).group(1))  # type: ignore[union-attr]
    lines = err.splitlines()

    def first(text: str) -> int:
        return next(i for i, s in enumerate(lines) if text in s)

    assert first("server process is gone") < first("laser off") < first("arm stopped at")
    assert first("arm stopped at") < first("real-time process exits")
    assert _exited(pid)


def _exited(pid: int) -> bool:
    """Gone, or a zombie waiting for whoever inherited it (the killed server's child)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def test_storm_does_not_disturb_the_grid(child: RealtimeProcess, served: tuple[str, int]) -> None:
    """16 clients polling Herej while the arm moves: the child's joint log has every 4 ms
    cycle once and on its grid time, every Herej reply is a logged sample, and the child's
    clock ran its own ticks meanwhile."""
    seen: set[tuple[float, ...]] = set()
    stop = threading.Event()

    def storm() -> None:
        with RobotClient(*served, timeout=10.0) as c:
            while not stop.is_set():
                seen.add(tuple(c.herej().tolist()))

    with RobotClient(*served, timeout=10.0) as c:
        c.take_control("")
        c.enable_power()
        c.joint_move(TARGET)
        threads = [threading.Thread(target=storm) for _ in range(16)]
        for th in threads:
            th.start()
        assert c.wait_end_move(20.0)
        stop.set()
        for th in threads:
            th.join(10.0)
        t, q = c.joint_log(-1.0)
    k = np.rint(t / 0.004)
    assert np.array_equal(k, np.arange(k[0], k[0] + k.size))  # every cycle, once, in order
    assert np.array_equal(t, k * 0.004)
    logged = {tuple(row) for row in q.tolist()} | {tuple(float(v) for v in HOME)}
    assert len(seen) > 10 and seen <= logged
    assert child.query("jitter")["count"] > 0


def test_a_child_that_cannot_be_built_is_one_error() -> None:
    with pytest.raises(ChildStartError, match="RX99"):
        RealtimeProcess("robotsocket.rtprocess:build_robot", {**ROBOT, "model": "RX99"})


def test_serve_with_a_bad_model_says_so_in_one_line() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "robotsocket", "serve", "--port", "0", "--model", "RX99"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1].startswith("error: ")
    assert "Traceback" not in done.stderr


def _call(endpoint: str, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "robotsocket", "call", endpoint, *args],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip


def test_call_setoutput_laser_on_then_exit_leaves_the_laser_off_on_the_real_clock() -> None:
    """The probe of issue 29 against `serve --clock real` (the real-time child): the laser
    a `call` switched on is off once the call has released control [RS-7.21]."""
    server = subprocess.Popen(
        [sys.executable, "-m", "robotsocket", "serve", "--port", "0", "--udp-port", "off"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert server.stdout is not None
    try:
        endpoint = server.stdout.readline().split()[-1]
        done = _call(endpoint, "setoutput", "laser", "on")
        assert done.returncode == 0, done.stderr
        read = _call(endpoint, "readio", "laser")
        assert read.returncode == 0, read.stderr
        assert json.loads(read.stdout)["value"] is False
    finally:
        server.send_signal(signal.SIGINT)
        _, err = server.communicate(timeout=30)
    assert "control released: laser off" in err


def test_an_unknown_pipe_message_is_answered_not_left_to_time_out(child: RealtimeProcess) -> None:
    """Every kind the child receives gets an answer: an unknown one an error, at once (the
    caller's timeout here is 30 s; a missing answer would fail the test by its timeout)."""
    with pytest.raises(ProtocolError) as err:
        child._call(cast(Any, "no-such-kind"), timeout=30.0)
    assert err.value.code is ErrorCode.INTERNAL_ERROR and "no-such-kind" in err.value.message
    assert child._call(ControlReleased("robot")) == ()  # the pipe still serves


@pytest.mark.parametrize(
    "request_",
    [
        Command("no-such-service", PingRequest(), Who(1, ("", 0), False, False)),
        ControlLost("no-such-service", "test"),
        ControlReleased("no-such-service"),
        Query("no-such-query"),
    ],
    ids=["command", "lost", "released", "query"],
)
def test_a_request_for_what_the_child_lacks_is_answered_with_an_error(
    child: RealtimeProcess, request_: Request
) -> None:
    """A service or query the child does not have is an INTERNAL_ERROR answer, at once; the
    child goes on serving (it used to die of the KeyError and leave the caller waiting)."""
    with pytest.raises(ProtocolError) as err:
        child._call(request_, timeout=30.0)
    assert err.value.code is ErrorCode.INTERNAL_ERROR
    assert child.alive and child._call(ControlReleased("robot")) == ()


def test_a_forwarded_session_is_a_session_view_with_no_server_behind_it() -> None:
    """The child's handlers get the session as the server process saw it: a plain value that
    pickles, typed as the shell's SessionView, with nothing of a server to fake."""
    view: SessionView = Who(3, ("10.0.0.1", 5000), False, True, "watchdog")
    assert Who.of(view) == view and pickle.loads(pickle.dumps(view)) == view
    assert not hasattr(view, "server")
