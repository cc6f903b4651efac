"""The real-clock cell with its real-time part in a process of its own (docs/REALTIME.md).

The child process (:mod:`robotsocket.rtprocess`, built by :func:`build_cell`) runs the whole
:class:`~cell.cell.EmulatedCell` except its TCP servers: the robot's 4 ms loop, the UDP
trigger sender and data receiver, the sensor's trigger listener and camera. So the trigger
stamps, the exposures and the data replies never wait for the GIL behind the request threads
of many clients. :class:`CellProcess`, in the calling process, serves RobotSocket (the polls
from shared memory, the rest forwarded) and SensorSocket (forwarded).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from cell.cell import EmulatedCell, bound
from cell.timing import CellError
from cell.truth import WeldRecorder, WeldTruth
from kinematics.robot import get_model
from robotsocket.rtprocess import ChildParts, ForwardedService, RealtimeProcess, RobotProcess
from spec.server import FramedServer, ServerPolicy, listen

__all__ = ["CellProcess", "build_cell"]

log = logging.getLogger(__name__)


def build_cell(config: dict[str, Any]) -> ChildParts:
    """The child's cell: real clock, not serving TCP itself."""
    cell = EmulatedCell(clock="real", serve=False, **config["cell"])

    def stop() -> None:
        cell.close()
        j = cell.robot.jitter()
        if j["count"]:
            log.info(
                "tick jitter: p50 %.3f ms, p99 %.3f ms, max %.3f ms over %d ticks",
                j["p50"] * 1e3, j["p99"] * 1e3, j["max"] * 1e3, int(j["count"]),
            )  # fmt: skip

    assert cell.listener is not None
    listener = cell.listener
    recorder = WeldRecorder(cell)

    def acquisitions(first: int = 0) -> list[tuple[int, float, float]]:
        """The sensor's own record of each acquisition from index ``first`` on: (index,
        t_trigger, time its seam column was exposed) (the truth of a reading's time)."""
        return [(r.index, r.t_trigger, r.t_seam) for r in cell.delta_t.records if r.index >= first]

    queries: dict[str, Callable[..., Any]] = {
        "weld_record": recorder.start,
        "weld_truth": recorder.truth,
        "true_delta_t": cell.true_delta_t_s,
        "io_log": lambda: list(cell.robot.io_log),
        "measured_delta_t": cell.measured_delta_t,
        "acquisitions": acquisitions,
        "next_index": lambda: cell.core.next_index,
        "jitter": cell.robot.jitter,
        "kernel_timestamps": lambda: listener.kernel_timestamps,
    }
    facts = {
        "describe": cell.describe(),
        "udp_address": cell.udp_address,
        "period": cell.robot.period,
        "laser_tool": cell.laser_tool,
        "sensor_tool": cell.sensor_tool,
        "workpiece_error": cell.workpiece_error,
        "workpiece2base": cell.scene.workpiece2base,
        "ready_sensor2base": cell.ready_sensor2base(),
        "ready_flange2base": cell.ready_flange2base(),
        "model": cell.model,
        "laser2flange": cell.laser2flange,
        "true_laser_tool": cell.true_laser_tool,
        "true_sensor_tool": cell.true_sensor_tool,
    }
    services = {"robot": cell.robot_service, "sensor": cell.sensor_service}
    return ChildParts(cell.robot, services, cell.start, stop, queries, facts)


class CellProcess:
    """``python -m cell serve --clock real``: the cell's real-time part in a child process,
    its two TCP servers here. Keyword arguments are :class:`~cell.cell.EmulatedCell`'s
    (``clock`` is real). Raises :class:`~robotsocket.rtprocess.ChildStartError` when the
    child cannot be built and :class:`~cell.timing.CellError` when a port cannot be bound."""

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        robot_port: int = 0,
        sensor_port: int = 0,
        policy: ServerPolicy | None = None,
        **cell: Any,
    ) -> None:
        # The TCP ports are bound before the child starts: a port in use is one error, not
        # the child's start-up log followed by it.
        robot_sock = bound(
            "robot's TCP port", "--robot-port", host, robot_port, lambda: listen(host, robot_port)
        )
        try:
            sensor_sock = bound(
                "sensor's TCP port", "--sensor-port", host, sensor_port,
                lambda: listen(host, sensor_port),
            )  # fmt: skip
        except CellError:
            robot_sock.close()
            raise
        config = {"cell": {"host": host, **cell}}
        try:
            self.child = RealtimeProcess("cell.rtcell:build_cell", config)
        except BaseException:
            robot_sock.close()
            sensor_sock.close()
            raise
        self.robot_server = FramedServer(
            RobotProcess(self.child), policy=policy, listener=robot_sock
        )
        self.sensor_server = FramedServer(
            ForwardedService(self.child, "sensor"), policy=policy, listener=sensor_sock
        )
        self.udp_address: tuple[str, int] = tuple(self.child.facts["udp_address"])
        self._model = get_model(self.child.facts["model"])

    @property
    def robot_address(self) -> tuple[str, int]:
        return self.robot_server.address

    @property
    def sensor_address(self) -> tuple[str, int]:
        return self.sensor_server.address

    def describe(self) -> dict[str, object]:
        """As :meth:`EmulatedCell.describe`, with the addresses served here."""
        d = dict(self.child.facts["describe"])
        d["robot"] = "{}:{}".format(*self.robot_address)
        d["sensor"] = "{}:{}".format(*self.sensor_address)
        d["real_time_process"] = self.child.pid
        return d

    def measured_delta_t(self, first_index: int = 0) -> float:
        """:meth:`EmulatedCell.measured_delta_t`, from the child's records."""
        out: float = self.child.query("measured_delta_t", first_index)
        return out

    def next_index(self) -> int:
        """The index the robot's next trigger will carry."""
        out: int = self.child.query("next_index")
        return out

    def record_weld(self) -> None:
        """The child starts recording the laser's path (:class:`~cell.truth.WeldRecorder`)."""
        self.child.query("weld_record")

    def weld_truth(self) -> WeldTruth:
        """What the child recorded since :meth:`record_weld`: the laser's true path."""
        out: WeldTruth = self.child.query("weld_truth")
        return out

    @property
    def io_log(self) -> list[tuple[float, str, bool]]:
        """(robot time s, output, value) of every output change of the child's robot."""
        out: list[tuple[float, str, bool]] = self.child.query("io_log")
        return out

    # --- the truth the emulated spot detector and the error-vs-true figures need ----------------

    @property
    def laser_tool(self) -> Any:
        """The nominal laser tool the cell was built with (mm, deg)."""
        return self.child.facts["laser_tool"]

    @property
    def laser2flange(self) -> Any:
        """The laser's true ^N_L T (4, 4) mm."""
        return self.child.facts["laser2flange"]

    @property
    def true_laser_tool(self) -> Any:
        return self.child.facts["true_laser_tool"]

    @property
    def true_sensor_tool(self) -> Any:
        return self.child.facts["true_sensor_tool"]

    def ready_flange2base(self) -> Any:
        return self.child.facts["ready_flange2base"]

    def flange2base_now(self) -> Any:
        """^B_N T of the arm's latest setpoint, from the shared state (no round trip)."""
        q = np.array(self.child.state.read().setpoint, dtype=np.float64)
        return self._model.flange2base(q)

    def true_delta_t_s(self) -> float:
        """The cell's true ΔT (the emulator's timing), s."""
        out: float = self.child.query("true_delta_t")
        return out

    def start(self) -> CellProcess:
        self.robot_server.start()
        self.sensor_server.start()
        return self

    def close(self) -> None:
        self.robot_server.shutdown()
        self.sensor_server.shutdown()
        self.child.close()

    def __enter__(self) -> CellProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
