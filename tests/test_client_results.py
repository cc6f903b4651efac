"""One result type per kind of value across the client API (issue 35 item 6): the rule of
robotsocket/client.py's docstring, checked against live servers."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from robotsocket.client import IoNames, JointLog, RobotClient
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from sensorsocket.client import SensorClient
from sensorsocket.service import SensorService
from tests.test_sensor_service import make_sensor

if TYPE_CHECKING:
    from tests.conftest import Serve


def _is_loc(value: object) -> bool:
    return type(value) is tuple and len(value) == 6 and all(type(v) is float for v in value)


def _is_float_array(value: object, shape: tuple[int, ...]) -> bool:
    return isinstance(value, np.ndarray) and value.dtype == np.float64 and value.shape == shape


def test_robot_results_by_kind(serve: Serve) -> None:
    server = serve(RobotService(RobotEmulator()), None)
    with RobotClient(*server.address) as robot:
        assert _is_float_array(robot.herej(), (6,))  # joints: an array
        assert _is_loc(robot.here())  # a location: six Python floats
        assert _is_float_array(robot.joint_limits(), (6, 2))
        log = robot.joint_log()
        assert isinstance(log, JointLog)  # named, and unpacks as before
        times, joints = log
        assert times is log.times and joints is log.joints and joints.shape[1:] == (6,)
        assert times.dtype == np.float64
        io = robot.list_io()
        assert isinstance(io, IoNames) and "laser" in io.outputs


def test_sensor_results_by_kind(serve: Serve) -> None:
    server = serve(SensorService(make_sensor(), trigger_endpoint=("127.0.0.1", 2001)), None)
    with SensorClient(*server.address) as sensor:
        sensor.take_control()
        data = sensor.measure()
        assert data.found and _is_loc(data.seam)  # a seam pose is a location, as here()
        index, image = sensor.get_image()
        assert index == data.index and image.dtype == np.uint8 and image.shape == (256, 512)
        index, points = sensor.get_profile()
        assert points.dtype == np.float64 and points.shape[1] == 3
