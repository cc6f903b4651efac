"""SyncService: the synchronisation commands 0x3001-0x3009 as robot-service handlers, driven
through RobotService.handle with a recording transport (no sockets, simulated robot clock)."""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import pytest

from kinematics.robot import get_model
from robotsocket.emulator import RobotEmulator
from robotsocket.interface import BadStateError, OutOfRangeError, RobotInfo
from robotsocket.service import RobotService
from robotsocket.sync_service import MAX_ROWS, SyncService, flange2base_for
from spec.errors import ErrorCode, ProtocolError
from spec.messages import request_of
from spec.params import FloatArray, Location, Matrix, Value
from spec.registry import BY_ID, SEAM_POINT_COLUMNS, CommandId
from spec.server import SessionView
from sync.udp import RobotSyncCore

C = CommandId
SESSION = cast(SessionView, None)  # the handlers do not look at the session


class Transport:
    def __init__(self) -> None:
        self.targets: list[tuple[str, int]] = []
        self.wakes = 0

    def set_target(self, host: str, port: int) -> None:
        self.targets.append((host, port))

    def wake(self) -> None:
        self.wakes += 1


class Rig:
    def __init__(self) -> None:
        self.robot = RobotEmulator()
        self.core = RobotSyncCore(flange2base=flange2base_for(self.robot), first_index=100)
        self.transport = Transport()
        self.sync = SyncService(self.robot, self.core, self.transport, trigger_lead_s=0.002)
        self.service = RobotService(self.robot)
        self.sync.install(self.service)

    def call(self, command: CommandId, *params: Value) -> tuple[Value, ...]:
        return self.service.handle(SESSION, request_of(command, params))

    def refused(self, command: CommandId, *params: Value) -> ErrorCode:
        with pytest.raises(ProtocolError) as e:
            self.call(command, *params)
        return e.value.code


@pytest.fixture
def rig() -> Rig:
    return Rig()


def test_install_registers_the_nine_sync_commands(rig: Rig) -> None:
    sync_ids = {int(c) for c in range(C.SET_SENSOR_ENDPOINT, C.GET_SYNC_STATISTICS + 1)}
    assert len(sync_ids) == 9 and sync_ids <= set(rig.service.implemented())
    assert int(C.SET_SENSOR_ENDPOINT) not in RobotService(RobotEmulator()).implemented()


def test_triggers_need_an_endpoint_first(rig: Rig) -> None:
    assert rig.refused(C.START_TRIGGERS, 100.0, 0) == ErrorCode.BAD_STATE  # [SY-5.4]
    assert rig.refused(C.SCHEDULE_TRIGGERS, FloatArray([0.1])) == ErrorCode.BAD_STATE
    with pytest.raises(BadStateError):
        rig.sync.start(100.0, 0)
    assert rig.transport.wakes == 0


def test_endpoint_is_set_reported_and_cleared(rig: Rig) -> None:
    assert rig.call(C.GET_SYNC_CONFIG)[:2] == ("", 0)
    assert rig.call(C.SET_SENSOR_ENDPOINT, "127.0.0.1", 5000) == ()
    assert rig.call(C.GET_SYNC_CONFIG)[:2] == ("127.0.0.1", 5000)
    for host, port in (("127.0.0.1", 0), ("127.0.0.1", 65536), ("", 5000)):
        assert rig.refused(C.SET_SENSOR_ENDPOINT, host, port) == ErrorCode.OUT_OF_RANGE
    assert rig.sync.endpoint == ("127.0.0.1", 5000)  # a refused endpoint changes nothing
    rig.call(C.SET_SENSOR_ENDPOINT, "", 0)
    assert rig.sync.endpoint is None and rig.call(C.GET_SYNC_CONFIG)[:2] == ("", 0)
    assert rig.transport.targets == [("127.0.0.1", 5000), ("", 0)]


def test_start_schedule_and_stop(rig: Rig) -> None:
    rig.call(C.SET_SENSOR_ENDPOINT, "127.0.0.1", 5000)
    for bad_rate in (0.0, -1.0, 1001.0, float("nan")):
        assert rig.refused(C.START_TRIGGERS, bad_rate, 0) == ErrorCode.OUT_OF_RANGE  # [SY-5.3]
    assert rig.transport.wakes == 0
    (first,) = rig.call(C.START_TRIGGERS, 250.0, 10)
    assert first == 100 and rig.transport.wakes == 1
    *_, triggering, rate = rig.call(C.GET_SYNC_CONFIG)
    assert triggering is True and rate == 250.0
    # The first trigger is planned trigger_lead_s after the robot's clock.
    assert rig.core.next_due() == pytest.approx(rig.robot.time() + 0.002, abs=1e-12)
    rig.call(C.STOP_TRIGGERS)
    assert rig.call(C.GET_SYNC_CONFIG)[4] is False
    assert rig.refused(C.SCHEDULE_TRIGGERS, FloatArray([0.2, 0.1])) == ErrorCode.OUT_OF_RANGE
    (first,) = rig.call(C.SCHEDULE_TRIGGERS, FloatArray([0.01, 0.02]))
    assert isinstance(first, int) and rig.transport.wakes == 2


def test_delay_and_sensor_tool(rig: Rig) -> None:
    rig.call(C.SET_SYNC_DELAY, 0.0049)
    assert rig.core.delta_t_s == 0.0049
    for bad in (1.5, -1.01, float("inf"), float("nan")):
        assert rig.refused(C.SET_SYNC_DELAY, bad) == ErrorCode.OUT_OF_RANGE
    assert rig.core.delta_t_s == 0.0049
    tool = Location(40.0, 0.0, 200.0, 0.0, 90.0, 0.0)
    rig.call(C.SET_SENSOR_TOOL, tool)
    _, _, delta_t, s2f, _, _ = rig.call(C.GET_SYNC_CONFIG)
    assert delta_t == 0.0049
    assert isinstance(s2f, Location)
    np.testing.assert_allclose(s2f.as_tuple(), tool.as_tuple(), atol=1e-12)
    np.testing.assert_allclose(rig.core.sensor2flange[:3, 3], [40.0, 0.0, 200.0], atol=1e-12)


def test_seam_points_and_statistics_have_the_registered_shape(rig: Rig) -> None:
    (pts,) = rig.call(C.GET_SEAM_POINTS, -1)
    assert isinstance(pts, Matrix) and (pts.rows, pts.cols) == (0, len(SEAM_POINT_COLUMNS))
    stats = rig.call(C.GET_SYNC_STATISTICS)
    names = [p.name for p in BY_ID[C.GET_SYNC_STATISTICS].reply]
    assert len(stats) == len(names) and all(v == 0 for v in stats)
    assert MAX_ROWS * len(SEAM_POINT_COLUMNS) * 8 < 4 * 1024 * 1024  # one reply under 4 MB


def test_plain_api_raises_robot_errors(rig: Rig) -> None:
    with pytest.raises(OutOfRangeError):
        rig.sync.set_endpoint("host", 0)
    rig.sync.set_endpoint("127.0.0.1", 1)
    with pytest.raises(OutOfRangeError):
        rig.sync.schedule([1.0, 1.0])


class _Named:
    """A robot known only by the model name it reports (an adapter without ``.model``)."""

    def __init__(self, model: str) -> None:
        self._model = model

    def info(self) -> RobotInfo:
        return RobotInfo("vendor", self._model, "0")


def test_flange2base_for_uses_the_robot_model() -> None:
    q = np.array([[10.0, -20.0, 95.0, 5.0, 40.0, -30.0]])
    f = flange2base_for(RobotEmulator("RX160"))
    assert f is not None and np.array_equal(f(q), get_model("RX160").flange2base_batch(q))
    g = flange2base_for(cast(Any, _Named("tx90")))
    assert g is not None and np.array_equal(g(q), get_model("TX90").flange2base_batch(q))
    assert flange2base_for(cast(Any, _Named("KR16"))) is None
