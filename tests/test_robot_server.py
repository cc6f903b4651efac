"""RobotSocket over real loopback sockets: every command, its reply and its errors; control."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np
import pytest

from robotsocket.client import (
    AuthError,
    BadParametersError,
    BusyError,
    EmergencyStopError,
    MotionDesc,
    MoveResult,
    NotInControlError,
    NotPoweredError,
    NotSupportedError,
    OutOfRangeError,
    RobotClient,
    SingularityError,
    UnknownCommandError,
    UnreachableError,
)
from robotsocket.emulator import HOME, RobotEmulator
from robotsocket.service import RobotService
from spec.codec import FrameDecoder, Packet, encode_packet, request
from spec.errors import ErrorCode
from spec.messages import StopTriggersRequest
from spec.params import Joints, Location
from spec.registry import CommandId, commands_for
from spec.server import FramedServer, ServerPolicy
from spec.wire import MoveOutcome

if TYPE_CHECKING:
    from tests.conftest import Serve

TARGET = (30.0, -20.0, 100.0, 10.0, 45.0, -30.0)


@pytest.fixture
def robot() -> RobotEmulator:
    return RobotEmulator()


@pytest.fixture
def server(robot: RobotEmulator, serve: Serve) -> FramedServer:
    return serve(RobotService(robot), ServerPolicy(token="s3cret"))


@pytest.fixture
def client(server: FramedServer) -> Iterator[RobotClient]:
    with RobotClient(*server.address, timeout=10.0) as c:
        yield c


def test_hello_lists_what_the_service_implements(client: RobotClient) -> None:
    info = client.hello()
    assert info["service"] == "robot" and info["model"] == "RX90B"
    ids = set(info["commands"].values)  # type: ignore[union-attr]
    robot_ids = {int(c.id) for c in commands_for("robot") if c.service == "robot"}
    assert robot_ids <= ids
    assert int(CommandId.START_TRIGGERS) not in ids  # sync commands: not registered here


def test_read_only_commands_need_no_control(client: RobotClient) -> None:
    assert np.array_equal(client.herej(), HOME)
    st = client.status()
    assert not st.powered and not st.in_control and not st.controlled and st.queue == 0
    assert client.here() == pytest.approx((450.0, 0.0, 365.0, 180.0, 0.0, 180.0), abs=1e-9)
    lim = client.joint_limits()
    assert lim.shape == (6, 2) and lim[0, 1] == 160.0
    assert client.motion_desc() == MotionDesc()
    t, q = client.joint_log()
    assert len(t) == 1 and np.array_equal(q[0], HOME)
    assert client.read_io("laser") is False
    assert "crossjet" in client.list_io()[0]
    assert client.get_time() == 0.0
    assert client.ping(b"abc") == b"abc"


@pytest.mark.parametrize(
    ("call", "args"),
    [
        ("enable_power", ()),
        ("disable_power", ()),
        ("joint_move", (TARGET,)),
        ("tool_move_j", ((400.0, 0.0, 400.0, 180.0, 0.0, 180.0),)),
        ("tool_move_l", ((400.0, 0.0, 400.0, 180.0, 0.0, 180.0),)),
        ("set_motion_desc", (MotionDesc(),)),
        ("stop_move", ()),
        ("restart_move", ()),
        ("reset_motion", ()),
        ("reset_emergency_stop", ()),
        ("set_output", ("laser", True)),
    ],
)
def test_commands_that_move_or_switch_need_control(
    client: RobotClient, call: str, args: tuple[object, ...]
) -> None:
    with pytest.raises(NotInControlError) as info:
        getattr(client, call)(*args)
    assert info.value.code is ErrorCode.NOT_IN_CONTROL and "control" in info.value.message


def test_token_is_checked(client: RobotClient) -> None:
    with pytest.raises(AuthError):
        client.take_control("wrong")
    client.take_control("s3cret")
    assert client.status().in_control


def test_full_motion_session(client: RobotClient, robot: RobotEmulator) -> None:
    client.take_control("s3cret")
    with pytest.raises(NotPoweredError):
        client.joint_move(TARGET)
    assert client.status().last_error == ErrorCode.NOT_POWERED
    client.enable_power()
    client.set_motion_desc(MotionDesc(joint_speed=50.0, tool_speed=200.0, blend=0.0))
    assert client.motion_desc().joint_speed == 50.0
    assert client.joint_move(TARGET) == 1
    st = client.status()
    assert st.moving and st.queue == 1 and st.in_control and st.controlled
    assert client.wait_end_move(30.0) is True
    assert np.array_equal(client.herej(), TARGET)
    assert client.status().time > 0.0
    start = np.array(client.here())
    goal = start + np.array([50.0, 0.0, -30.0, 0.0, 0.0, 0.0])
    client.tool_move_l(goal)
    assert client.wait_end_move(30.0)
    assert client.here() == pytest.approx(tuple(goal), abs=1e-6)
    client.tool_move_j(start.tolist())
    assert client.wait_end_move(30.0)
    assert client.here() == pytest.approx(tuple(start), abs=1e-6)
    t, _ = client.joint_log(0.5)
    assert np.all(t > 0.5) and np.allclose(np.diff(t), 0.004)
    client.set_output("laser", True)
    assert client.read_io("laser") is True
    client.disable_power()
    assert not client.status().powered


def test_motion_errors(client: RobotClient) -> None:
    client.take_control("s3cret")
    client.enable_power()
    with pytest.raises(OutOfRangeError, match="J1"):
        client.joint_move((170.0, 0.0, 90.0, 0.0, 90.0, 0.0))
    with pytest.raises(UnreachableError):
        client.tool_move_l((2000.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(UnreachableError):
        client.tool_move_j((2000.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    client.joint_move((0.0, 10.0, 90.0, 0.0, 30.0, 0.0))
    with pytest.raises(SingularityError):
        client.tool_move_l(tuple(_flange_loc((0.0, 10.0, 90.0, 0.0, -30.0, 0.0))))
    with pytest.raises(OutOfRangeError):
        client.set_motion_desc(MotionDesc(joint_speed=150.0))
    with pytest.raises(BadParametersError):
        client.joint_move((1.0, 2.0, 3.0))
    with pytest.raises(OutOfRangeError):  # [RS-5.21]
        client.set_output("nope", True)
    with pytest.raises(BadParametersError):
        client.call(CommandId.JOINT_MOVE, 1.0)  # wrong type
    with pytest.raises(BadParametersError):
        client.call(CommandId.HERE, Location(0, 0, 0, 0, 0, 0))  # missing frame
    with pytest.raises(UnknownCommandError):
        client.call(0x1FFF)
    with pytest.raises(NotSupportedError):  # [RS-5.62] known, not offered by this robot
        client.call(CommandId.STOP_TRIGGERS)
    client.emergency_stop()
    with pytest.raises(EmergencyStopError):
        client.enable_power()
    st = client.status()
    assert st.estop and st.last_error == ErrorCode.EMERGENCY_STOP
    client.reset_emergency_stop()
    client.enable_power()


def _flange_loc(q: tuple[float, ...]) -> np.ndarray:
    from kinematics.robot import get_model
    from kinematics.transforms import transform_to_location

    return transform_to_location(get_model().flange2base(np.array(q)))


def test_stop_restart_and_reset(client: RobotClient, robot: RobotEmulator) -> None:
    client.take_control("s3cret")
    client.enable_power()
    client.joint_move(TARGET)
    robot.step(40)
    client.stop_move()
    assert client.wait_end_move(1.0) is False  # held: the queue is kept
    st = client.status()
    assert not st.moving and st.queue == 1
    client.restart_move()
    assert client.wait_end_move(30.0)
    assert np.array_equal(client.herej(), TARGET)
    client.joint_move(HOME)
    robot.step(40)
    client.reset_motion()
    assert client.wait_move(10.0) == MoveResult(MoveOutcome.STOPPED, "ResetMotion")
    assert client.status().queue == 0 and not np.allclose(client.herej(), HOME)


def test_emergency_stop_is_open_to_everyone(server: FramedServer, client: RobotClient) -> None:
    client.take_control("s3cret")
    client.enable_power()
    client.joint_move(TARGET)
    with RobotClient(*server.address) as other:
        other.emergency_stop()
    st = client.status()
    assert st.estop and not st.powered and st.queue == 0


def test_two_clients_compete_for_control(server: FramedServer) -> None:
    with RobotClient(*server.address) as a, RobotClient(*server.address) as b:
        a.take_control("s3cret")
        with pytest.raises(BusyError):
            b.take_control("s3cret")
        with pytest.raises(NotInControlError, match="another client"):
            b.enable_power()
        a.enable_power()
        assert b.status().controlled and not b.status().in_control
        b.release_control()  # harmless: b does not hold it
        assert a.status().in_control
        a.release_control()
        b.take_control("s3cret")
        b.disable_power()
        with pytest.raises(NotInControlError):
            a.enable_power()


def test_controller_disconnect_during_a_move_stops_on_the_path() -> None:
    robot = RobotEmulator(clock="real").start()
    srv = FramedServer(RobotService(robot), "127.0.0.1", 0).start()
    try:
        c = RobotClient(*srv.address)
        c.take_control()
        c.enable_power()
        c.set_motion_desc(MotionDesc(joint_speed=5.0))
        c.joint_move(TARGET)
        c.joint_move(HOME)
        deadline = time.monotonic() + 5.0
        while robot.cycle < 60 and time.monotonic() < deadline:
            time.sleep(0.01)
        c.close()  # the controller vanishes mid-move
        with RobotClient(*srv.address) as watcher:
            deadline = time.monotonic() + 5.0
            while watcher.status().moving and time.monotonic() < deadline:
                time.sleep(0.02)
            st = watcher.status()
            q = watcher.herej()
            while watcher.status().powered and time.monotonic() < deadline:
                time.sleep(0.02)
            powered = watcher.status().powered
        assert not st.moving and st.queue == 0
        assert not powered  # [RS-7.22] off once the arm stands
        frac = (q - np.array(HOME)) / (np.array(TARGET) - np.array(HOME))
        assert 0.0 < frac[0] < 1.0
        np.testing.assert_allclose(frac, frac[0], atol=1e-9)  # stopped on the joint line
    finally:
        srv.shutdown()
        robot.close()
    assert not srv.handler_errors


def test_extra_handlers_can_be_registered() -> None:
    service = RobotService(RobotEmulator())
    service.register(StopTriggersRequest, lambda session, request: ())
    assert int(CommandId.STOP_TRIGGERS) in service.implemented()
    with FramedServer(service, "127.0.0.1", 0) as srv, RobotClient(*srv.address) as c:
        c.take_control()
        assert c.call(CommandId.STOP_TRIGGERS) == ()


def test_raw_frames_get_the_request_id_echoed(server: FramedServer) -> None:
    with socket.create_connection(server.address, timeout=5.0) as s:
        s.sendall(encode_packet(request(CommandId.HEREJ, 77)))
        s.sendall(encode_packet(request(CommandId.JOINT_MOVE, 78, Joints(TARGET))))
        dec = FrameDecoder()
        got: list[Packet] = []
        while len(got) < 2:
            dec.feed(s.recv(4096))
            for event in dec.events():
                assert isinstance(event, Packet), event  # no frame of the server's rejected
                got.append(event)
    assert [p.request_id for p in got] == [77, 78]
    assert got[1].error is not None and got[1].error[0] == ErrorCode.NOT_IN_CONTROL


def test_long_simulated_wait_of_a_bystander_does_not_freeze_the_server(
    robot: RobotEmulator, server: FramedServer, client: RobotClient
) -> None:
    """Sim clock, a very slow move: another connection's WaitEndMove(600) advances the clock
    cycle by cycle; Herej from a third connection is answered meanwhile (the emulator's lock
    is taken per cycle), and the controller's EmergencyStop gets in and ends the wait as a
    stopped move, not a done one [RS-5.50]."""
    client.take_control("s3cret")
    client.enable_power()
    client.set_motion_desc(MotionDesc(joint_speed=0.1))
    client.joint_move([20.0, 0.0, 90.0, 0.0, 90.0, 0.0])
    done: list[MoveResult] = []
    with RobotClient(*server.address, timeout=120.0) as bystander:
        waiter = threading.Thread(target=lambda: done.append(bystander.wait_move(600.0)))
        waiter.start()
        with RobotClient(*server.address) as reader:
            answered = 0
            while waiter.is_alive() and answered < 3:
                reader.herej()
                answered += 1
        alive_while_answering = waiter.is_alive()
        client.emergency_stop()
        waiter.join(120.0)
    assert answered == 3 and alive_while_answering
    assert done == [MoveResult(MoveOutcome.STOPPED, "emergency stop")]


def test_controller_keeps_its_lease_while_a_slow_simulated_wait_runs(
    robot: RobotEmulator, server: FramedServer, client: RobotClient
) -> None:
    """A busy simulated server takes longer than the lease to answer one WaitEndMove piece
    (each 4 ms cycle costs 10 ms of wall time here): the client's keeper pings beside the
    pending call, so the controller is not taken for lost."""
    robot.cycle_hooks.append(lambda t, q_sp, q_m: time.sleep(0.01))
    assert client.take_control("s3cret", 0.1) == 0.1
    client.enable_power()
    client.joint_move([1.0, 0.0, 90.0, 0.0, 90.0, 0.0])
    assert client.wait_end_move(30.0)
    assert client.status().in_control
    assert server.statistics()["watchdog_expired"] == 0


def test_client_storm_sees_only_grid_samples() -> None:
    """Herej under a storm of clients: the joint log stays on the 4 ms grid with every cycle
    once, and every Herej reply is one of the logged samples (never a value of the moment
    a thread happened to run)."""
    import threading

    robot = RobotEmulator(clock="real").start()
    seen: set[tuple[float, ...]] = set()
    stop = threading.Event()
    try:
        with FramedServer(RobotService(robot), "127.0.0.1", 0) as srv:
            robot.enable_power()
            robot.joint_move(np.array([20.0, -10.0, 100.0, 5.0, 60.0, 10.0]))

            def storm() -> None:
                with RobotClient(*srv.address, timeout=10.0) as c:
                    while not stop.is_set():
                        seen.add(tuple(c.herej().tolist()))

            threads = [threading.Thread(target=storm) for _ in range(16)]
            for th in threads:
                th.start()
            assert robot.wait_end_move(20.0)
            stop.set()
            for th in threads:
                th.join(10.0)
    finally:
        robot.close()
    t, q = robot.joint_log(-1.0)
    k = np.rint(t / 0.004)
    assert np.array_equal(k, np.arange(k[0], k[0] + k.size))  # every cycle, once, in order
    assert np.array_equal(t, k * 0.004)
    logged = {tuple(row) for row in q.tolist()} | {tuple(float(v) for v in HOME)}
    assert len(seen) > 10 and seen <= logged


# --- what 1.2 left to guessing (PROTOCOL.md 1.3) --------------------------------------------


def test_joint_log_since_nan_is_out_of_range_and_infinities_are_times(client: RobotClient) -> None:
    """[RS-5.58] NaN is no time; -inf returns the whole buffer and +inf no sample."""
    with pytest.raises(OutOfRangeError, match="NaN"):
        client.joint_log(float("nan"))
    t_all, _ = client.joint_log(float("-inf"))
    t_none, _ = client.joint_log(float("inf"))
    assert len(t_all) >= 1 and len(t_none) == 0


def test_only_refused_or_failed_moves_set_last_error(client: RobotClient) -> None:
    """[RS-5.51] a refused SetMotionDesc or WaitEndMove, or a control refusal, leaves
    last_error alone; a move refused for power sets it; ResetMotion clears it."""
    with pytest.raises(NotInControlError):
        client.joint_move(tuple(HOME))
    client.take_control("s3cret")
    with pytest.raises(OutOfRangeError):
        client.set_motion_desc(MotionDesc(joint_speed=150.0))
    with pytest.raises(OutOfRangeError):
        client.call(CommandId.WAIT_END_MOVE, 0.0)
    assert client.status().last_error == 0
    with pytest.raises(NotPoweredError):
        client.joint_move(tuple(HOME))
    st = client.status()
    assert st.last_error == ErrorCode.NOT_POWERED and "power" in st.last_message
    client.reset_motion()
    assert client.status().last_error == 0


def test_disable_power_and_restart_move_in_every_state(client: RobotClient) -> None:
    """[RS-5.52] DisablePower with power off and under an emergency stop replies without
    error; [RS-5.54] RestartMove without StopMove changes nothing; [RS-5.53] it needs power."""
    client.take_control("s3cret")
    client.disable_power()  # power already off
    with pytest.raises(NotPoweredError):
        client.restart_move()
    client.enable_power()
    client.restart_move()  # nothing held: nothing starts
    st = client.status()
    assert st.powered and not st.moving and st.queue == 0
    client.set_output("gas", True)
    client.emergency_stop()
    client.disable_power()  # under the emergency stop
    st = client.status()
    assert st.estop and not st.powered
    assert client.read_io("gas") is False  # [RS-5.20] EmergencyStop switched it off
    with pytest.raises(EmergencyStopError):
        client.restart_move()
