"""Safety of control with real processes: a killed, frozen or interrupted controller stops
the arm (laser off first), and EmergencyStop gets through a full server [RS-7.10..RS-7.14].

The robot server runs in this process (real clock) so the tests can read the emulator's
state; the controllers are real ``python -m robotsocket call`` processes or small client
scripts, faulted with kill -9, SIGSTOP, SIGINT and SIGTERM. Assertions are on outcomes (the
arm stopped short of its target, queue empty, outputs off), never on how fast.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from robotsocket.client import RobotClient
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from robotsocket.sync_service import attach_udp_sync
from spec.server import FramedServer, ServerPolicy

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
FAR = "150,0,90,0,90,0"  # joint 1 by 150 degrees: several seconds at the default speed
WATCHDOG = 0.3


class Cell:
    def __init__(self, robot: RobotEmulator, server: FramedServer) -> None:
        self.robot = robot
        self.server = server
        self.endpoint = f"127.0.0.1:{server.address[1]}"

    def wait_until(self, what: Callable[[], bool], timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if what():
                return True
            time.sleep(0.005)
        return False

    def control_state(self) -> str:
        """Who holds control, whose controlled stop runs, and every thread's stack: what a
        wait for free control that timed out needs to say (it failed once under load)."""
        control = self.server.control
        stacks = "\n".join(
            f"--- {names.get(ident, ident)}\n" + "".join(traceback.format_stack(frame))
            for names in [{t.ident: t.name for t in threading.enumerate()}]
            for ident, frame in sys._current_frames().items()
        )
        return f"holder {control.holder}, stopping for {control.stopping_for}\n{stacks}"

    def moving(self) -> bool:
        return self.robot.status().moving

    def stopped_short(self) -> bool:
        """Stopped with an empty queue, joint 1 far from the 150 degree target."""
        st = self.robot.status()
        return not st.moving and st.queue == 0 and abs(self.robot.herej()[0] - 150.0) > 5.0


@pytest.fixture
def cell() -> Iterator[Cell]:
    robot = RobotEmulator(clock="real").start()
    service = RobotService(robot)
    _sync, endpoint = attach_udp_sync(service, robot)
    policy = ServerPolicy(max_clients=8, reserved_slots=1, watchdog=WATCHDOG)
    server = FramedServer(service, "127.0.0.1", 0, policy)
    endpoint.start()
    with server:
        robot.enable_power()
        yield Cell(robot, server)
    endpoint.stop()
    robot.close()
    assert server.handler_errors == []


def call(cell: Cell, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "robotsocket", "call", cell.endpoint, *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT,
    )  # fmt: skip


def moving_under_control(cell: Cell) -> None:
    assert cell.wait_until(lambda: cell.moving() and cell.server.control_holder is not None)
    cell.robot.set_output("laser", True)  # what a welding job would have switched on
    cell.robot.set_output("gas", True)


def assert_safe_stop(cell: Cell) -> None:
    assert cell.wait_until(cell.stopped_short), cell.robot.status()
    assert cell.robot.read_io("laser") == (False, True)
    assert cell.robot.read_io("gas") == (False, True)
    # [RS-7.22] a lost controller's arm loses power once it stands (category 1 stop).
    assert cell.wait_until(lambda: not cell.robot.status().powered)
    assert cell.server.control_holder is None


def test_kill_9_while_waiting_in_wait_end_move_stops_the_arm(cell: Cell) -> None:
    proc = call(cell, "JointMove", FAR)
    moving_under_control(cell)
    time.sleep(0.3)  # well inside WaitEndMove
    proc.kill()
    proc.wait(5)
    assert_safe_stop(cell)


def test_frozen_controller_loses_control_by_the_watchdog(cell: Cell) -> None:
    proc = call(cell, "JointMove", FAR)
    moving_under_control(cell)
    proc.send_signal(signal.SIGSTOP)
    try:
        assert_safe_stop(cell)
        assert cell.server.statistics()["watchdog_expired"] == 1
        assert proc.poll() is None  # still frozen: the close did not do it
    finally:
        proc.send_signal(signal.SIGCONT)
        proc.kill()
        proc.wait(5)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_call_stops_releases_and_exits_130(cell: Cell, sig: signal.Signals) -> None:
    proc = call(cell, "JointMove", FAR)
    moving_under_control(cell)
    time.sleep(0.3)
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=10)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["interrupted; the move was stopped; control released"]
    assert out == ""
    assert cell.wait_until(cell.stopped_short)
    # Released, not lost: nothing went through the controlled-stop path.
    assert cell.server.statistics()["watchdog_expired"] == 0


def test_client_keeps_its_lease_while_idle_and_while_waiting(cell: Cell) -> None:
    with RobotClient(*cell.server.address, timeout=5.0) as robot:
        assert robot.take_control() == WATCHDOG
        time.sleep(WATCHDOG * 4)  # idle: the keeper pings
        robot.joint_move([10.0, 0.0, 90.0, 0.0, 90.0, 0.0])
        assert robot.wait_end_move(30.0)  # many pieces, each shorter than the lease
        assert robot.status().in_control
    assert cell.server.statistics()["watchdog_expired"] == 0


SCRIPT = textwrap.dedent(
    """
    import sys, time
    from robotsocket.client import RobotClient
    from spec.registry import CommandId
    host, port, udp = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    robot = RobotClient(host, port)
    robot.take_control()
    robot.call(CommandId.SET_SENSOR_ENDPOINT, "127.0.0.1", udp)
    robot.call(CommandId.START_TRIGGERS, 250.0, 0)
    print("triggering", flush=True)
    time.sleep(60)
    """
)


def test_killed_controller_stops_its_triggers(cell: Cell) -> None:
    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.settimeout(2.0)
    host, port = cell.server.address
    proc = subprocess.Popen(
        [sys.executable, "-c", SCRIPT, host, str(port), str(sink.getsockname()[1])],
        stdout=subprocess.PIPE, text=True, env=ENV, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "triggering"
        sink.recv(64)  # triggers arrive
        proc.kill()
        proc.wait(5)
        with RobotClient(host, port) as watcher:
            assert cell.wait_until(lambda: not watcher.status().controlled)
        sink.settimeout(0.3)
        for _ in range(100):  # drain what was in flight
            try:
                sink.recv(64)
            except TimeoutError:
                break
        with pytest.raises(TimeoutError):
            sink.recv(64)
    finally:
        proc.kill()
        sink.close()


def test_emergency_stop_gets_through_a_full_server(cell: Cell) -> None:
    fillers = [socket.create_connection(cell.server.address, timeout=5) for _ in range(8)]
    try:
        assert cell.wait_until(lambda: cell.server.statistics()["clients"] == 8)
        proc = call(cell, "EmergencyStop")
        _out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert cell.robot.status().estop
        proc = call(cell, "GetStatus")  # anything else is refused while full
        _, err = proc.communicate(timeout=10)
        assert proc.returncode == 1 and "BUSY" in err
    finally:
        for s in fillers:
            s.close()


def test_server_shutdown_stops_the_controllers_motion(cell: Cell) -> None:
    with RobotClient(*cell.server.address) as robot:
        robot.take_control()
        robot.joint_move([150.0, 0.0, 90.0, 0.0, 90.0, 0.0])
        moving_under_control(cell)
        cell.server.shutdown()
        assert_safe_stop(cell)


RAW_WAIT = textwrap.dedent(
    """
    import sys
    from spec.client import FramedClient
    from spec.params import Joints
    from spec.registry import CommandId as C
    client = FramedClient(sys.argv[1], int(sys.argv[2]), timeout=120)
    client.keepalive = False
    client.take_control("", 10.0)  # a long lease: only the close can stop the arm
    client.call(C.JOINT_MOVE, Joints([150.0, 0.0, 90.0, 0.0, 90.0, 0.0]))
    client.call(C.WAIT_END_MOVE, 60.0, timeout=120)  # one long request, pending when killed
    """
)


def test_close_is_seen_while_a_long_wait_end_move_is_pending(cell: Cell) -> None:
    """[RS-7.12] the reader keeps reading during WaitEndMove(60): the close stops the arm
    long before the 10 s lease would."""
    host, port = cell.server.address
    proc = subprocess.Popen([sys.executable, "-c", RAW_WAIT, host, str(port)], env=ENV, cwd=ROOT)
    try:
        moving_under_control(cell)
        time.sleep(0.3)
        proc.kill()
        proc.wait(5)
        assert_safe_stop(cell)
        assert cell.server.statistics()["watchdog_expired"] == 0
    finally:
        proc.kill()


STREAMING = textwrap.dedent(
    """
    import sys, time
    from robotsocket.client import RobotClient
    from spec.params import FloatArray, Location, Matrix
    from spec.registry import CommandId as C
    robot = RobotClient(sys.argv[1], int(sys.argv[2]))
    robot.take_control()
    here = robot.here()
    times = [0.5 * k for k in range(21)]  # 10 s along a straight line, 5 mm per 0.5 s
    locs = [(here[0], here[1] + 5.0 * k, *here[2:]) for k in range(21)]
    flat = [v for loc in locs for v in loc]
    ident = Location(0, 0, 0, 0, 0, 0)
    robot.call(C.TOOL_MOVE_TRAJECTORY, FloatArray(times), Matrix(21, 6, flat), ident, ident)
    robot.set_output("laser", True)
    print("streaming", flush=True)
    time.sleep(60)
    """
)

IDLE = textwrap.dedent(
    """
    import signal, sys, time
    from robotsocket.client import RobotClient
    # Ctrl-C as in a terminal, even where the test runner's worker ignores SIGINT (a child
    # started with SIGINT ignored keeps it ignored)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    robot = RobotClient(sys.argv[1], int(sys.argv[2]))
    robot.take_control()
    robot.set_output("laser", True)
    robot.set_output("gas", True)
    print("idle", flush=True)
    time.sleep(60)
    """
)


@contextmanager
def controller(cell: Cell, script: str, ready: str) -> Iterator[subprocess.Popen[str]]:
    """A controlling client process running ``script`` (which prints ``ready`` once it holds
    control); always let go and killed afterwards, frozen or not."""
    host, port = cell.server.address
    proc = subprocess.Popen(
        [sys.executable, "-c", script, host, str(port)],
        stdout=subprocess.PIPE, text=True, env=ENV, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == ready
        yield proc
    finally:
        proc.send_signal(signal.SIGCONT)
        proc.kill()
        proc.wait(5)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSTOP])
def test_a_streamed_trajectory_stops_when_its_controller_dies_or_freezes(
    cell: Cell, sig: signal.Signals
) -> None:
    with controller(cell, STREAMING, "streaming") as proc:
        assert cell.wait_until(cell.moving)
        y0 = cell.robot.here()[1]
        proc.send_signal(sig)
        assert cell.wait_until(lambda: not cell.moving() and cell.server.control_free), (
            cell.control_state()
        )
        assert cell.robot.read_io("laser") == (False, True)
        assert abs(cell.robot.here()[1] - y0) < 50.0  # stopped, far short of the 100 mm path
        assert cell.robot.status().queue == 0


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSTOP])
def test_an_idle_controller_that_dies_or_freezes_leaves_the_outputs_off(
    cell: Cell, sig: signal.Signals
) -> None:
    with controller(cell, IDLE, "idle") as proc:
        assert cell.robot.read_io("laser") == (True, True)
        proc.send_signal(sig)
        assert cell.wait_until(lambda: cell.server.control_free), cell.control_state()
        assert cell.robot.read_io("laser") == (False, True)
        assert cell.robot.read_io("gas") == (False, True)


# --- [RS-7.21] the process outputs follow control -------------------------------------------


def _laser_off_after(cell: Cell, what: str) -> float:
    """Robot-clock seconds from the server seeing ``what`` (a control event) to the laser's
    switch-off in the robot's I/O log."""
    seen = [t for t, _sid, ev, _last in cell.server.control_events if ev.startswith(what)]
    off = [t for t, name, value in cell.robot.io_log if name == "laser" and not value]
    assert seen and off, (list(cell.server.control_events), list(cell.robot.io_log))
    return off[-1] - seen[-1]


def test_call_setoutput_laser_on_leaves_the_laser_off_when_it_exits(cell: Cell) -> None:
    """The probe of issue 29: `call setoutput laser on`, the CLI exits -> laser off, in the
    same cycle the release was seen; power stays (a release is a handover) [RS-7.22]."""
    proc = call(cell, "setoutput", "laser", "on")
    _out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert ("laser", True) in [(n, v) for _, n, v in cell.robot.io_log]
    assert cell.robot.read_io("laser") == (False, True)
    assert 0.0 <= _laser_off_after(cell, "released") <= cell.robot.period
    assert cell.robot.status().powered
    assert cell.server.statistics()["watchdog_expired"] == 0


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_a_controller_killed_or_interrupted_with_the_laser_on_leaves_it_off(
    cell: Cell, sig: signal.Signals
) -> None:
    """kill -9 and Ctrl-C of a client that switched laser and gas on: off, laser first, in
    the cycle the close was seen [RS-7.10] [RS-7.21]."""
    with controller(cell, IDLE, "idle") as proc:
        assert cell.robot.read_io("laser") == (True, True)
        proc.send_signal(sig)
        assert cell.wait_until(lambda: cell.server.control_free), cell.control_state()
        assert cell.robot.read_io("laser") == (False, True)
        assert cell.robot.read_io("gas") == (False, True)
        offs = [name for _, name, value in cell.robot.io_log if not value]
        assert offs == ["laser", "gas"]
        assert 0.0 <= _laser_off_after(cell, "lost: connection closed") <= cell.robot.period


def test_emergency_stop_switches_the_outputs_off_laser_first(cell: Cell) -> None:
    with controller(cell, IDLE, "idle"):
        proc = call(cell, "EmergencyStop")
        _out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert [n for _, n, v in cell.robot.io_log if not v] == ["laser", "gas"]
        st = cell.robot.status()
        assert st.estop and not st.powered


# --- [RS-5.50] a move that did not reach its target never reports done ----------------------


def test_emergency_stop_during_call_jointmove_exits_non_zero_naming_the_stop(cell: Cell) -> None:
    """The probe of issue 29: EmergencyStop from a second client during `call jointmove`; the
    call printed done true, rc 0. Now: done false, outcome stopped, exit 1 naming it."""
    proc = call(cell, "JointMove", FAR)
    moving_under_control(cell)
    stop = call(cell, "EmergencyStop")
    _o, err = stop.communicate(timeout=10)
    assert stop.returncode == 0, err
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 1, (out, err)
    reply = json.loads(out)
    assert reply["done"] is False
    assert reply["outcome"] == "stopped" and reply["reason"] == "emergency stop"
    assert err.strip() == "error: the move was stopped: emergency stop"


def test_a_move_cut_short_by_reset_motion_is_stopped_and_one_that_ends_is_reached(
    cell: Cell,
) -> None:
    with RobotClient(*cell.server.address, timeout=5.0) as robot:
        robot.take_control()
        robot.joint_move([150.0, 0.0, 90.0, 0.0, 90.0, 0.0])
        assert cell.wait_until(cell.moving)
        robot.reset_motion()
        result = robot.wait_move(30.0)
        assert (result.outcome.value, result.reason) == ("stopped", "ResetMotion")
        assert not robot.status().moving  # it answered once the arm stood
        q = cell.robot.herej()
        q[0] += 1.0
        robot.joint_move(list(q))
        assert robot.wait_move(30.0).reached


# --- [RS-7.13] a frozen controller at cruise, timed on the robot clock ----------------------

CRUISE = textwrap.dedent(
    """
    import sys, time
    from robotsocket.client import MotionDesc, RobotClient
    robot = RobotClient(sys.argv[1], int(sys.argv[2]))
    robot.take_control()  # the server's default lease
    robot.set_motion_desc(MotionDesc(joint_speed=10.0))
    robot.joint_move([150.0, 0.0, 90.0, 0.0, 90.0, 0.0])
    robot.set_output("laser", True)
    time.sleep(0.5)  # past the acceleration: at cruise
    print("cruise", flush=True)
    time.sleep(60)
    """
)


def freeze_at_cruise(cell: Cell) -> tuple[float, float, float]:
    """SIGSTOP a controller at cruise; (lease, laser off, arm stopped), the last two in robot
    seconds after its last frame: its lost event's stamp, the I/O log and the joint log."""
    with controller(cell, CRUISE, "cruise") as proc:
        assert cell.moving()
        proc.send_signal(signal.SIGSTOP)
        assert cell.wait_until(lambda: cell.server.control_free and not cell.moving())
    lost = [e for e in cell.server.control_events if e[2].startswith("lost: watchdog")]
    assert len(lost) == 1, list(cell.server.control_events)
    last_frame = lost[0][3]
    off = [t for t, name, value in cell.robot.io_log if name == "laser" and not value]
    times, joints = cell.robot.joint_log(last_frame - 1.0)
    still = np.all(np.abs(np.diff(joints, axis=0)) < 1e-9, axis=1)
    moving_rows = np.flatnonzero(~still)
    stopped_at = float(times[moving_rows[-1] + 1])  # the first sample of the standing arm
    return cell.server.policy.watchdog, off[0] - last_frame, stopped_at - last_frame


def test_a_frozen_controller_at_cruise_loses_the_laser_and_the_arm_within_the_lease(
    cell_default_lease: Cell,
) -> None:
    """The laser goes off one lease (plus the watchdog's wake-up) after the frozen
    controller's last frame, the arm stands one deceleration later; both on the robot
    clock. The issue's targets (0.3 s, 0.35 s) are measured by bench/bench_lease.py on a
    quiet machine; here only the order and the bound by the lease are checked."""
    lease, laser_off, stopped = freeze_at_cruise(cell_default_lease)
    assert lease <= laser_off <= lease + 0.1, (lease, laser_off)
    assert laser_off < stopped <= laser_off + 0.2, (laser_off, stopped)


@pytest.fixture
def cell_default_lease() -> Iterator[Cell]:
    robot = RobotEmulator(clock="real").start()
    server = FramedServer(RobotService(robot), "127.0.0.1", 0, ServerPolicy())
    with server:
        robot.enable_power()
        yield Cell(robot, server)
    robot.close()
    assert server.handler_errors == []
