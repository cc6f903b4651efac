"""The emulated cell's truth of a weld: where the laser focal point really went.

A :class:`WeldRecorder` hooks the robot's cycle and keeps, every cycle, the true joints (the
setpoints of a rigid arm, the link side of an elastic one),
the path correction applied and the laser output. :meth:`WeldRecorder.truth` turns them into
the laser focal point's path (through the TRUE laser tool) on the cycles the laser was on, with
the scene whose seam it is judged against. The same recorder runs in-process and in the
real-time child (:mod:`cell.rtcell`, a query after the run), so the truth comes from what the
emulated arm actually did, on the robot's clock.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from kinematics.types import FloatArray
from sensorsocket.scene import Scene

if TYPE_CHECKING:
    from cell.cell import EmulatedCell

__all__ = ["WeldRecorder", "WeldTruth"]


@dataclass(frozen=True)
class WeldTruth:
    """``laser``: the laser focal point (N, 3, base frame, mm) on the N cycles the laser was
    on; ``correction``: the path correction's translation applied on those cycles (N, 3);
    ``scene``: the workpiece and its true seam; ``laser_on``: the laser output now."""

    laser: FloatArray
    correction: FloatArray
    scene: Scene
    laser_on: bool
    #: robot time (s) of each of the N cycles
    times: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: every cycle recorded, the laser on or not: robot times (M,) and the laser focal point
    #: (M, 3): a weld judged over the cycles its window's stamps give, not over those its
    #: laser was on (switched by a client, so when that client's thread ran)
    cycle_times: FloatArray = field(default_factory=lambda: np.zeros(0))
    cycle_laser: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))


class WeldRecorder:
    """Records from :meth:`start` on (again: from scratch); cheap enough for the 4 ms loop."""

    def __init__(self, cell: EmulatedCell) -> None:
        self.cell = cell
        self._lock = threading.Lock()
        self._q: list[FloatArray] = []
        self._t: list[float] = []
        self._applied: list[FloatArray] = []
        self._lasing: list[bool] = []
        self._on = False
        cell.robot.cycle_hooks.append(self._record)

    def start(self) -> None:
        with self._lock:
            self._q, self._applied, self._lasing, self._t = [], [], [], []
            self._on = True

    def _record(self, t: float, q_sp: FloatArray, q_m: FloatArray) -> None:
        if not self._on:
            return
        robot = self.cell.robot
        applied, lasing = robot.alter_applied(), robot.read_io("laser")[0]
        with self._lock:
            self._q.append(robot.true_joints())
            self._t.append(t)
            self._applied.append(applied)
            self._lasing.append(lasing)

    def truth(self) -> WeldTruth:
        """Stop recording; the laser path so far."""
        with self._lock:
            self._on = False
            q, applied, lasing = list(self._q), list(self._applied), list(self._lasing)
            times = np.array(self._t)
        on = [i for i, v in enumerate(lasing) if v]
        cell = self.cell
        every = np.zeros((0, 3))
        if q:
            every = (cell.robot.model.flange2base_batch(np.array(q)) @ cell.laser2flange)[:, :3, 3]
        if on:
            laser = every[on]
            corr = np.array(applied)[on, :3]
        else:
            laser, corr = np.zeros((0, 3)), np.zeros((0, 3))
        return WeldTruth(
            laser, corr, cell.scene, cell.robot.read_io("laser")[0], times[on], times, every
        )
