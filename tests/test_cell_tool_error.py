"""The cell's true tools differ from the nominal ones: the camera sees through the true
sensor tool, the robot's synchronisation keeps the nominal one; the options that set them."""

from __future__ import annotations

import numpy as np
import pytest

from cell.__main__ import main
from cell.cell import CellError, EmulatedCell
from cell.options import tool_error
from kinematics.transforms import invert, location_to_transform, transform_to_location
from robotsocket.client import RobotClient
from sensorsocket.client import SensorClient

ERROR = (2.0, -1.0, 3.0, 1.5, -2.0, 2.5)


def _seen_from(sensor2base: np.ndarray, cell: EmulatedCell) -> np.ndarray:
    """Where the seam line of the cell's straight seam crosses the laser plane (x_S = 0) of
    the sensor at ``sensor2base``, in that sensor frame (3,) mm."""
    w = cell.scene.workpiece2base
    c = w[:3, 3] + w[:3, 2] * cell.scene.joint.seam_height_mm
    d = w[:3, 0]
    n, o = sensor2base[:3, 0], sensor2base[:3, 3]
    p = c + d * float(n @ (o - c) / (n @ d))
    out: np.ndarray = (invert(sensor2base) @ np.append(p, 1.0))[:3]
    return out


def test_the_camera_sees_through_the_true_sensor_tool() -> None:
    with EmulatedCell(clock="sim", sensor_tool_error=ERROR) as cell:
        nominal = location_to_transform(cell.sensor_tool)
        assert np.allclose(cell.core.sensor2flange, nominal)  # what the robot computes with
        assert np.allclose(cell.sensor2flange, nominal @ location_to_transform(ERROR))
        assert np.allclose(location_to_transform(cell.true_sensor_tool), cell.sensor2flange)
        with (
            RobotClient(*cell.robot_address, timeout=30.0) as robot,
            SensorClient(*cell.sensor_address, timeout=30.0) as sensor,
        ):
            robot.take_control()
            robot.enable_power()
            sensor.take_control()
            # turn the sensor about its nominal z and shift it across: the seam shows where
            # the true tool's laser plane cuts it, not where the nominal one's would
            here = location_to_transform(robot.here(cell.sensor_tool))
            turn = location_to_transform((0.0, 3.0, 1.0, 5.0, 0.0, 10.0))
            target = here @ turn
            robot.tool_move_j(_loc(target), cell.sensor_tool)
            assert robot.wait_end_move(30.0)
            sensor.acquire()
            data = sensor.get_data()
            flange = location_to_transform(robot.here())
            true_view = _seen_from(flange @ cell.sensor2flange, cell)
            nominal_view = _seen_from(flange @ nominal, cell)
    assert data.seam is not None
    seen = np.array(data.seam[:3])
    assert np.abs(seen - true_view).max() < 0.01
    assert np.abs(seen - nominal_view).max() > 1.0


def _loc(T: np.ndarray) -> tuple[float, ...]:
    return tuple(float(v) for v in transform_to_location(T))


def test_laser_tool_error_moves_the_true_laser_tool_only() -> None:
    cell = EmulatedCell(clock="sim", laser_tool_error=ERROR)
    try:
        assert cell.laser_tool == (0.0, 0.0, 200.0, 0.0, 0.0, 0.0)
        want = location_to_transform(cell.laser_tool) @ location_to_transform(ERROR)
        assert np.allclose(location_to_transform(cell.true_laser_tool), want)
        assert cell.describe()["laser_tool_error"] == list(ERROR)
    finally:
        cell.close()


@pytest.mark.parametrize("error", [(60.0, 0, 0, 0, 0, 0), (0, 0, 0, 0, 31.0, 0), (np.nan,) * 6])
def test_implausible_tool_errors_are_refused(error: tuple[float, ...]) -> None:
    with pytest.raises(CellError, match="sensor tool error"):
        EmulatedCell(clock="sim", sensor_tool_error=error)  # type: ignore[arg-type]


@pytest.mark.parametrize("text", ["1,2,3", "1,2,3,4,5,x", "0,0,0,0,0,45", "nan,0,0,0,0,0"])
def test_bad_tool_error_options_exit_2_naming_the_option(
    text: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["serve", "--clock", "sim", "--sensor-tool-error", text])
    assert exc.value.code == 2
    assert "--sensor-tool-error" in capsys.readouterr().err


def test_tool_error_parses_six_numbers() -> None:
    assert tool_error("1,-2,3.5,0,0.5,-3") == (1.0, -2.0, 3.5, 0.0, 0.5, -3.0)
