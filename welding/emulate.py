"""``--emulate``: an in-process emulated cell (simulated clock) with the clients connected.

The only module of :mod:`welding` that builds a :mod:`cell`; everything else sees the
robot and the sensor through their clients, as it would see a real cell. The simulated
clock advances only when the robot waits for a move; :meth:`EmulatedSession.dwell` advances
it for pre-/post-flow, stitch and pause times, so a job runs as fast as the CPU allows and
the I/O log carries the robot-clock times a real controller would have.
"""

from __future__ import annotations

from types import TracebackType

import numpy as np
import numpy.typing as npt

from cell.cell import EmulatedCell
from kinematics.transforms import transform_to_location
from robotsocket.client import RobotClient
from sensorsocket.client import SensorClient
from spec.errors import ProtocolError
from welding.tools import Entry, Loc, Tables

__all__ = ["EmulatedSession"]


def _loc(values: object) -> Loc:
    v = [float(x) for x in np.asarray(values, dtype=np.float64)]
    return (v[0], v[1], v[2], v[3], v[4], v[5])


class EmulatedSession:
    """A started simulated cell (``seam``: straight|sine), a robot client holding control
    with the arm powered, a sensor client, and tables naming its tools (``laser``,
    ``sensor``) and the workpiece frame (``workpiece``)."""

    def __init__(
        self,
        seam: str = "straight",
        *,
        seed: int = 0,
        sensor_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        laser_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    ) -> None:
        self.cell = EmulatedCell(
            clock="sim",
            seam=seam,
            seed=seed,
            sensor_tool_error=sensor_tool_error,
            laser_tool_error=laser_tool_error,
        )
        self.cell.start()
        try:
            self.robot = RobotClient(*self.cell.robot_address, timeout=30.0)
            self.sensor = SensorClient(*self.cell.sensor_address, timeout=30.0)
            self.robot.take_control()
            self.robot.enable_power()
        except BaseException:
            self.cell.close()
            raise
        self.tables = Tables({}, {})
        self.tables.add(Entry("laser", "laser", self.cell.laser_tool, "^N_L T of the cell"))
        self.tables.add(Entry("sensor", "sensor", self.cell.sensor_tool, "^N_S T of the cell"))
        w2b = _loc(transform_to_location(self.cell.scene.workpiece2base))
        self.tables.add(Entry("workpiece", "frame", w2b, "^B_W T of the cell's workpiece"))

    def dwell(self, seconds: float) -> None:
        """Let ``seconds`` of robot time pass (the simulated clock)."""
        self.cell.advance(seconds)

    @property
    def io_log(self) -> list[tuple[float, str, bool]]:
        """(robot time s, output, value) of every output change of the emulated robot."""
        return list(self.cell.robot.io_log)

    def seam_error_mm(self, seam2base: list[npt.NDArray[np.float64]]) -> float:
        """Largest distance (mm) from the points of ``seam2base`` (each (4, 4), base frame)
        to the scene's true seam curve (stations searched ±2 mm around each, 10 nm apart)."""
        scene = self.cell.scene
        worst = 0.0
        for T in seam2base:
            p = (scene.base2workpiece @ T)[:3, 3]
            x = np.linspace(p[0] - 2.0, p[0] + 2.0, 400_001)
            dy, dz = scene.path.y(x) - p[1], scene.joint.seam_height_mm - p[2]
            worst = max(worst, float(np.sqrt((x - p[0]) ** 2 + dy**2 + dz**2).min()))
        return worst

    def close(self) -> None:
        for client in (self.robot, self.sensor):
            try:
                client.release_control()
            except (OSError, ProtocolError):  # not held, or gone: nothing left to give back
                pass
            client.close()
        self.cell.close()

    def __enter__(self) -> EmulatedSession:
        return self

    def __exit__(
        self, et: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
