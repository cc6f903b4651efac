"""``--emulate``: an in-process emulated cell (simulated clock) with the clients connected.

The only module of :mod:`welding` that builds a :mod:`cell`; everything else sees the
robot and the sensor through their clients, as it would see a real cell. The simulated
clock advances only when the robot waits for a move; :meth:`EmulatedSession.dwell` advances
it for pre-/post-flow, stitch and pause times, so a job runs as fast as the CPU allows and
the I/O log carries the robot-clock times a real controller would have.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from cell.cell import CellTiming, EmulatedCell
from cell.options import timing_kwargs
from cell.rtcell import CellProcess
from cell.seams import cell_seam
from cell.truth import WeldRecorder, WeldTruth
from kinematics.transforms import invert, location_to_transform, transform_to_location
from kinematics.types import IDENTITY_LOC, Loc
from robotsocket.client import RobotClient
from robotsocket.rtprocess import ChildStartError
from sensorsocket.client import SensorClient
from sensorsocket.scene import Scene
from spec.client import FramedClient
from spec.clocks import ClockKind
from spec.errors import ProtocolError
from spec.exitcodes import ExitCode
from spec.files import write_atomically
from spec.params import Location, Value
from spec.realtime import realtime_threads
from spec.registry import CommandId
from welding.tools import Entry, Tables
from welding.track_loop import (
    QueueState,
    RobotLink,
    TrackedWeld,
    TrackLink,
    laser_path,
    weld_tracked,
)
from welding.tracking import TOLERANCE_MM, NominalWeld, Tracker, seam_error

__all__ = ["EmulatedSession", "cell_tables", "realtime_cell"]

log = logging.getLogger(__name__)

#: SCHED_FIFO priority of the real-clock tracker's process: below the real-time child's
#: command (40) and timing (50) threads, above everything else.
TRACKER_PRIORITY = 30
#: Exit code of a tracked weld out of its tolerance (or stopped early), as ``welding track``:
#: a result out of its tolerance is FAILED in the one table (docs/CLI.md, "Exit codes").
EXIT_OUT_OF_TOLERANCE = ExitCode.FAILED


def _loc(values: object) -> Loc:
    v = [float(x) for x in np.asarray(values, dtype=np.float64)]
    return (v[0], v[1], v[2], v[3], v[4], v[5])


#: The names of the tools and the frame the emulated cell adds to the database.
CELL_TOOLS = ("laser", "sensor")
CELL_FRAME = "workpiece"


def cell_tables(cell: EmulatedCell | CellProcess) -> Tables:
    """The cell's tools ``laser``, ``sensor`` and its frame ``workpiece`` (where it should
    be: the cell puts it its ``workpiece_error`` off that)."""
    if isinstance(cell, CellProcess):
        facts = cell.child.facts
        laser, sensor = facts["laser_tool"], facts["sensor_tool"]
        w2b_true, placement = facts["workpiece2base"], facts["workpiece_error"]
    else:
        laser, sensor = cell.laser_tool, cell.sensor_tool
        w2b_true, placement = cell.scene.workpiece2base, cell.workpiece_error
    tables = Tables({}, {})
    tables.add(Entry(CELL_TOOLS[0], "laser", _loc(laser), "^N_L T of the cell"))
    tables.add(Entry(CELL_TOOLS[1], "sensor", _loc(sensor), "^N_S T of the cell"))
    # the workpiece as the operator believes it placed: without the placement error
    error = location_to_transform(np.array(placement, dtype=np.float64))
    w2b = _loc(transform_to_location(w2b_true @ invert(error)))
    tables.add(Entry(CELL_FRAME, "frame", w2b, "^B_W T of the cell's workpiece"))
    return tables


def realtime_cell(seam: str = "straight", *, seed: int = 0, dynamics: str = "off") -> CellProcess:
    """A started emulated cell on the real-time clock, its real-time part in a child process
    (the operator console's ``--emulate``: an operator watches and jogs it at the speed a
    real arm moves; the console's web server and status threads cannot starve its 4 ms
    loop). Raises ValueError when the child cannot start."""
    shape, placement = cell_seam(seam)
    try:
        cell = CellProcess(seam=shape, workpiece_error=placement, seed=seed, dynamics=dynamics)
    except ChildStartError as exc:
        raise ValueError(f"the real-time cell did not start: {exc}") from None
    return cell.start()


class EmulatedSession:
    """A started simulated cell (``seam``: a name of :mod:`cell.seams`), a robot client holding
    control with the arm powered, a sensor client, and tables naming its tools (``laser``,
    ``sensor``) and the workpiece frame (``workpiece``: where it should be; the cell puts it
    ``workpiece_error`` off that)."""

    def __init__(
        self,
        seam: str = "straight",
        *,
        seed: int = 0,
        sensor_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        laser_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        workpiece_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        dynamics: str = "off",
    ) -> None:
        shape, placement = cell_seam(seam, workpiece_error)
        self.cell = EmulatedCell(
            clock="sim",
            seam=shape,
            seed=seed,
            dynamics=dynamics,
            sensor_tool_error=sensor_tool_error,
            laser_tool_error=laser_tool_error,
            workpiece_error=placement,
        )
        # the ΔT in force: the cell's true one stands for what the section VI procedure
        # measures (tracked paths use it)
        self.cell.core.set_delay(self.cell.true_delta_t_s())
        self.cell.start()
        try:
            self.robot = RobotClient(*self.cell.robot_address, timeout=30.0)
            self.sensor = SensorClient(*self.cell.sensor_address, timeout=30.0)
            self.robot.take_control()
            self.robot.enable_power()
        except BaseException:
            self.cell.close()
            raise
        self.tables = cell_tables(self.cell)

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


# --- real-time seam tracking on the emulated cell (welding.tracking) ------------------------


@dataclass
class TrackingRun:
    """One tracked weld on the emulated cell; errors in mm, truth from the cell."""

    seam: str
    speed_mm_s: float
    delta_t_ms: float
    true_delta_t_ms: float
    tracked: bool
    stopped: str  # why the weld stopped early; "" when it was completed
    welded_mm: float
    tracking_error_max_mm: float
    tracking_error_rms_mm: float
    lateral_max_mm: float
    height_max_mm: float
    nominal_error_max_mm: float  # the untracked nominal path against the same seam
    laser_on_at_end: bool
    clock: ClockKind = "sim"
    cycles: int = 0  # controller cycles of the move
    corrections: int = 0  # corrections sent during it: one per cycle when the loop keeps up
    start_on_grid: bool = True  # the cycle the move started on is known exactly
    cell: str = "in-process"  # where the cell ran: in-process or the real-time child
    #: the tracker's own verdict (welding.tracking.Verdict.summary: no truth in it)
    verdict: dict[str, object] = field(default_factory=dict)
    timed: bool = False  # timed corrections (AlterQueue) or one Alter per cycle
    #: laser cycles whose applied correction is not the table's entry for that cycle
    #: (timed mode; the emulator's truth)
    misapplied_cycles: int = 0
    #: timed mode: when (s into the move) corrections reached the robot after their cycle
    late_at_s: list[float] = field(default_factory=list)
    #: when the weld stopped early: s into the move (None when it ran to its end)
    stopped_at_s: float | None = None
    plot: dict[str, npt.NDArray[np.float64]] = field(default_factory=dict, repr=False)

    def summary(self) -> dict[str, object]:
        return {k: v for k, v in asdict(self).items() if k != "plot"}

    @property
    def within_tolerance(self) -> bool:
        return bool(self.verdict.get("within_tolerance"))


def run_tracking(
    seam: str = "sine",
    speed_mm_s: float = 250.0,
    *,
    delta_t_ms: float | None = None,
    timing: CellTiming | None = None,
    weld_mm: float = 200.0,
    rate_hz: float = 200.0,
    seed: int = 0,
    track: bool = True,
    workpiece_error: Loc | None = None,
    sensor_silent_after_mm: float | None = None,
    measure_delta_t: bool = False,
    over_sockets: bool = False,
    sensor_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    laser_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    sensor_tool: Loc | None = None,
    clock: ClockKind = "sim",
    tolerance_mm: float = TOLERANCE_MM,
    timed: bool = True,
    load: Callable[[tuple[str, int]], contextlib.AbstractContextManager[object]] | None = None,
    dynamics: str = "off",
    cancelled: Callable[[], bool] | None = None,
) -> TrackingRun:
    """Weld ``weld_mm`` of ``seam`` (``straight|offset|sine``) at ``speed_mm_s`` on the
    simulated cell, correcting the laser every cycle from the synchronised seam points.

    The tracker uses the ΔT in force on the robot: ``delta_t_ms`` when given, else the one
    the section VI procedure measures first when ``measure_delta_t`` (as an operator would,
    through the sockets, a few seconds of simulated sine), else the cell's true ΔT.
    ``track=False`` welds the nominal path (the baseline). ``sensor_silent_after_mm`` stops
    the sensor's data once the laser has welded that far (a dropped sensor).
    ``over_sockets`` runs the tracker as a client of the cell's servers (AlterBegin, Alter,
    GetSeamPoints, WaitEndMove of one cycle to advance the simulated clock) instead of
    calling the robot and the sync core in-process; the truth is the same.
    ``sensor_tool_error`` / ``laser_tool_error`` make the cell's true tools differ from the
    nominal ones;
    ``sensor_tool`` is the ^N_S T the robot computes seam points with (SetSensorTool;
    default the nominal one), e.g. a calibrated tool. ``clock="real"``: the cell runs on the
    wall clock (its 4 ms cycle in a thread) and the tracker is a client of its servers that
    waits for each cycle. ``timed``: timed corrections sent ahead (AlterQueue) where the
    robot has them, else one Alter per cycle (a loop that stalls then misses cycles, which
    ``corrections`` < ``cycles`` shows). The verdict is the tracker's own (``tolerance_mm``);
    the errors against the truth stand beside it. ``load``: a context entered with the
    robot server's address around the weld on the real clock (a benchmark's load).
    ``dynamics``: the emulated arm's (``off`` or ``elastic``, :class:`EmulatedCell`).
    ``cancelled``: asked every cycle; true stops the weld (laser off, motion reset)."""
    shape, placement = cell_seam(seam, workpiece_error or IDENTITY_LOC)
    config: dict[str, Any] = {
        "timing": timing or CellTiming(),
        "seam": shape,
        "workpiece_error": placement,
        "seed": seed,
        "sensor_tool_error": sensor_tool_error,
        "laser_tool_error": laser_tool_error,
        "dynamics": dynamics,
    }
    if clock == "real":
        # the robot's clock runs by itself in the real-time child: only its servers reach
        # it, and the tracker here shares no GIL with its 4 ms loop
        try:
            child = CellProcess(**config)
        except ChildStartError as exc:
            raise ValueError(f"the real-time cell did not start: {exc}") from None
        # this process is the controller: its tracker and the servers it talks through
        # real-time too (the child's timing and command threads stay above them)
        try:
            with realtime_threads(TRACKER_PRIORITY) as got:
                log.info("tracker threads: scheduling %s", got)
                side = _ChildSide(child.start(), sensor_tool)
                with load(side.robot_address) if load else contextlib.nullcontext():
                    return _track_on(side, seam, speed_mm_s, delta_t_ms, weld_mm, rate_hz,
                                     track, sensor_silent_after_mm, measure_delta_t, True,
                                     tolerance_mm, timed, cancelled)  # fmt: skip
        finally:
            child.close()
    cell = EmulatedCell(clock=clock, **config)
    if sensor_tool is not None:
        cell.core.sensor2flange = location_to_transform(np.array(sensor_tool, dtype=np.float64))
    servers = over_sockets or (measure_delta_t and delta_t_ms is None)
    if servers:
        cell.start()
    try:
        return _track_on(
            _InProcessSide(cell),
            seam,
            speed_mm_s,
            delta_t_ms,
            weld_mm,
            rate_hz,
            track,
            sensor_silent_after_mm,
            measure_delta_t,
            over_sockets,
            tolerance_mm,
            timed,
            cancelled,
        )
    finally:
        if servers:
            cell.close()


class _InProcessSide:
    """The tracking run's view of an in-process cell."""

    def __init__(self, cell: EmulatedCell) -> None:
        self.cell = cell
        self.clock = cell.clock
        self.period = cell.robot.period
        self.laser_tool = cell.laser_tool
        self.recorder = WeldRecorder(cell)

    @property
    def robot_address(self) -> tuple[str, int]:
        return self.cell.robot_address

    @property
    def sensor_address(self) -> tuple[str, int]:
        return self.cell.sensor_address

    @property
    def udp_address(self) -> tuple[str, int]:
        return self.cell.udp_address

    def true_delta_t_s(self) -> float:
        return self.cell.true_delta_t_s()

    def ready_sensor2base(self) -> npt.NDArray[np.float64]:
        return self.cell.ready_sensor2base()

    def set_delay(self, seconds: float) -> None:
        self.cell.core.set_delay(seconds)

    def direct_link(self) -> TrackLink:
        return _DirectLink(self.cell)

    def record_weld(self) -> None:
        self.recorder.start()

    def weld_truth(self) -> WeldTruth:
        return self.recorder.truth()


class _ChildSide:
    """The tracking run's view of the cell in the real-time child: its servers, its facts
    and, after the run, its record of the laser's path. ``sensor_tool``: SetSensorTool."""

    def __init__(self, child: CellProcess, sensor_tool: Loc | None) -> None:
        self.child = child
        self.clock: ClockKind = "real"
        self.period = float(child.child.facts["period"])
        self.laser_tool: Loc = tuple(child.child.facts["laser_tool"])
        self.robot_address = child.robot_address
        self.sensor_address = child.sensor_address
        self.udp_address = child.udp_address
        self.true_delta_t_s = child.true_delta_t_s
        self.record_weld = child.record_weld
        self.weld_truth = child.weld_truth
        if sensor_tool is not None:
            self._configure(CommandId.SET_SENSOR_TOOL, Location(*sensor_tool))

    def ready_sensor2base(self) -> npt.NDArray[np.float64]:
        out: npt.NDArray[np.float64] = self.child.child.facts["ready_sensor2base"]
        return out

    def set_delay(self, seconds: float) -> None:
        self._configure(CommandId.SET_SYNC_DELAY, seconds)

    def _configure(self, command: CommandId, value: Value) -> None:
        with FramedClient(*self.robot_address, timeout=10.0, client_name="track") as c:
            c.take_control()
            c.call(command, value)
            c.release_control()

    def direct_link(self) -> TrackLink:
        raise AssertionError("the real-time child is reached through its servers only")


class _CellSide(Protocol):
    clock: ClockKind
    period: float
    laser_tool: Loc

    @property
    def robot_address(self) -> tuple[str, int]: ...
    @property
    def sensor_address(self) -> tuple[str, int]: ...
    @property
    def udp_address(self) -> tuple[str, int]: ...
    def true_delta_t_s(self) -> float: ...
    def ready_sensor2base(self) -> npt.NDArray[np.float64]: ...
    def set_delay(self, seconds: float) -> None: ...
    def direct_link(self) -> TrackLink: ...
    def record_weld(self) -> None: ...
    def weld_truth(self) -> WeldTruth: ...


def _track_on(
    cell: _CellSide,
    seam: str,
    speed_mm_s: float,
    delta_t_ms: float | None,
    weld_mm: float,
    rate_hz: float,
    track: bool,
    sensor_silent_after_mm: float | None,
    measure_delta_t: bool,
    over_sockets: bool,
    tolerance_mm: float,
    timed: bool,
    cancelled: Callable[[], bool] | None = None,
) -> TrackingRun:
    period = cell.period
    true_dt = cell.true_delta_t_s()
    if delta_t_ms is not None:
        cell.set_delay(delta_t_ms * 1e-3)
    elif measure_delta_t:
        _measure_delta_t(cell.robot_address, cell.sensor_address)
    else:
        cell.set_delay(true_dt)
    # the emulator's truth, every cycle: true setpoints, correction applied, laser output
    cell.record_weld()
    link: TrackLink
    if over_sockets:
        client = FramedClient(*cell.robot_address, timeout=10.0, client_name="track")
        client.take_control()
        robot_link = RobotLink(
            client, cell.udp_address, period=period, real_time=cell.clock == "real"
        )
        robot_link.use_queue = timed
        link = robot_link
    else:
        link = cell.direct_link()
        link.timed = timed
    try:
        dt = link.delta_t()  # the ΔT in force (GetSyncConfig)
        laser_tool = cell.laser_tool
        start = np.array(link.here(laser_tool))
        s2b = cell.ready_sensor2base()
        direction = s2b[:3, 0]  # the nominal seam runs along the sensor's x axis
        look_ahead = float((s2b[:3, 3] - start[:3]) @ direction)
        ramp_mm = speed_mm_s**2 / (2.0 * 2500.0)
        weld = NominalWeld(
            start=start[:3],
            direction=direction,
            angles=start[3:],
            length_mm=look_ahead + weld_mm + ramp_mm + 1.0,
            speed_mm_s=speed_mm_s,
        )
        tracker = Tracker(weld, look_ahead)
        plan = TrackedWeld(
            tracker, laser_tool, look_ahead, look_ahead + weld_mm, rate_hz, track,
            tolerance_mm=tolerance_mm,
        )  # fmt: skip
        outcome = weld_tracked(
            link, plan, sensor_silent_after_mm=sensor_silent_after_mm, cancelled=cancelled
        )
        stopped = outcome.stopped
    finally:
        if over_sockets:
            with contextlib.suppress(Exception):
                client.release_control()
            client.close()
    truth = cell.weld_truth()
    laser_pts, corr, scene = truth.laser, truth.correction, truth.scene
    b2w = scene.base2workpiece
    h = scene.joint.seam_height_mm
    lat, hgt = seam_error(laser_pts, b2w, scene.path.lateral, h)
    n_lat, _ = seam_error(laser_pts - corr, b2w, scene.path.lateral, h)
    err = np.hypot(lat, hgt)
    welded = len(laser_pts) * period * speed_mm_s
    return TrackingRun(
        seam=seam,
        speed_mm_s=speed_mm_s,
        delta_t_ms=dt * 1e3,
        true_delta_t_ms=true_dt * 1e3,
        tracked=track,
        stopped=stopped,
        welded_mm=round(welded, 1),
        tracking_error_max_mm=float(err.max()) if len(err) else math.nan,
        tracking_error_rms_mm=float(np.sqrt(np.mean(err**2))) if len(err) else math.nan,
        lateral_max_mm=float(np.abs(lat).max()) if len(lat) else math.nan,
        height_max_mm=float(np.abs(hgt).max()) if len(hgt) else math.nan,
        nominal_error_max_mm=float(np.abs(n_lat).max()) if len(n_lat) else math.nan,
        laser_on_at_end=truth.laser_on,
        clock=cell.clock,
        cycles=outcome.cycles,
        corrections=outcome.corrections,
        start_on_grid=outcome.start_on_grid,
        cell="real-time child" if isinstance(cell, _ChildSide) else "in-process",
        verdict=outcome.verdict.summary() if outcome.verdict is not None else {},
        timed=outcome.timed,
        misapplied_cycles=_misapplied(outcome.sent, truth.times, corr) if outcome.timed else 0,
        late_at_s=np.round(outcome.late_times - outcome.t0, 4).tolist(),
        stopped_at_s=round(outcome.stopped_at_s, 4)
        if math.isfinite(outcome.stopped_at_s)
        else None,
        plot={
            "laser": _to_w(laser_pts, b2w),
            "nominal": _to_w(laser_pts - corr, b2w),
            "measured": _to_w(tracker.model.points(), b2w),
            "seam": _true_seam(scene, laser_pts, b2w),
            "estimate": outcome.estimate,
            "truth_error": np.column_stack([weld.project(laser_pts), err]),
        },
    )


def _misapplied(
    sent: npt.NDArray[np.float64], times: npt.NDArray[np.float64], applied: npt.NDArray[np.float64]
) -> int:
    """Cycles at ``times`` (N,) whose applied correction (N, 3) is not the sent table's
    (rows t, correction 6) entry for that very cycle (RS-5.44: one entry per cycle)."""
    if not len(times):
        return 0
    if not len(sent):
        return len(times)
    i = np.clip(np.searchsorted(sent[:, 0], times - 1e-9), 0, len(sent) - 1)
    same_cycle = np.abs(sent[i, 0] - times) < 1e-9
    same_value = np.all(np.abs(sent[i, 1:4] - applied) < 1e-6, axis=1)
    return int(np.count_nonzero(~(same_cycle & same_value)))


class _DirectLink:
    """In-process: the emulator's robot API and the sync core (the data GetSeamPoints serves)."""

    def __init__(self, cell: EmulatedCell) -> None:
        self.cell = cell
        self.robot = cell.robot
        self.period = cell.robot.period
        self.timed = True

    def delta_t(self) -> float:
        return self.cell.core.delta_t_s

    def here(self, tool: Loc) -> Loc:
        return self.robot.here(tool)

    def start(self, tool: Loc, rate_hz: float) -> int:
        """Power, triggers, alter mode; the index of the first trigger."""
        self.robot.enable_power()
        self.cell.sync.set_endpoint(*self.cell.udp_address)
        first = self.cell.sync.start(rate_hz, 0)
        self.robot.alter_begin(tool, 0.1)
        return first

    def time(self) -> float:
        return self.robot.time()

    def next_cycle(self) -> float:
        return self.robot.time() + self.period

    def points(self, since: int) -> npt.NDArray[np.float64]:
        return self.cell.core.points_since(since)

    def alter(self, correction: npt.NDArray[np.float64]) -> None:
        self.robot.alter(correction)

    def queue(
        self, times: npt.NDArray[np.float64], corrections: npt.NDArray[np.float64]
    ) -> QueueState:
        report, _, now = self.robot.alter_queue(times, corrections)
        return QueueState(report.late_total, report.held_total, report.horizon, now, report.late)

    def laser_points(self, tool: Loc, since: float) -> npt.NDArray[np.float64]:
        _, joints = self.robot.joint_log(since)
        return laser_path(self.robot.model, joints, tool)

    def step(self) -> None:
        self.robot.step()

    def move(
        self, times: npt.NDArray[np.float64], locs: npt.NDArray[np.float64], tool: Loc
    ) -> tuple[float, bool]:
        t0 = self.robot.time()  # the move's law starts at the current cycle
        self.robot.tool_move_trajectory(times, locs, tool, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        return t0, True

    def queued(self) -> int:
        return self.robot.status().queue

    def set_laser(self, on: bool) -> None:
        self.robot.set_output("laser", on)

    def reset_motion(self) -> None:
        self.robot.reset_motion()

    def stop_triggers(self) -> None:
        self.cell.core.stop()

    def finish(self) -> None:
        self.robot.alter_end()
        self.cell.core.stop()
        self.robot.wait_end_move(5.0)

    def close(self) -> None:
        pass


def _measure_delta_t(robot: tuple[str, int], sensor: tuple[str, int]) -> None:
    """The section VI procedure through the sockets; SetSyncDelay applies the estimate. The
    arm returns to the ready pose."""
    from sync.experiment import ExperimentSettings, run_delay_experiment

    run_delay_experiment(
        robot,
        sensor,
        ExperimentSettings(apply=True, duration_s=4.0),
    )


def _to_w(points: npt.NDArray[np.float64], b2w: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    out: npt.NDArray[np.float64] = (np.column_stack([points, np.ones(len(points))]) @ b2w.T)[:, :3]
    return out


def _true_seam(
    scene: Scene, laser_pts: npt.NDArray[np.float64], b2w: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """The true seam (N, 3) in the workpiece frame under the laser's x."""
    x = _to_w(laser_pts, b2w)[:, 0]
    return np.column_stack([x, scene.path.y(x), np.full_like(x, scene.joint.seam_height_mm)])


# --- command line: python -m welding track --emulate ... ------------------------------------


def cmd_track(args: argparse.Namespace) -> int:
    """Run one tracked weld; print and optionally write the result and end with the
    tracker's own verdict: exit 0 within ``--tolerance``, 1 (``ExitCode.FAILED``, with the
    reason) when not, including a weld that stopped early (the laser is off)."""
    run = run_tracking(
        args.seam,
        args.speed,
        delta_t_ms=args.delta_t_ms,
        measure_delta_t=not args.true_delta_t,
        timing=CellTiming(**timing_kwargs(args)),
        weld_mm=args.length,
        rate_hz=args.rate,
        seed=args.seed,
        track=not args.untracked,
        over_sockets=True,
        sensor_tool_error=args.sensor_tool_error,
        laser_tool_error=args.laser_tool_error,
        sensor_tool=args.sensor_tool_location,
        clock=args.clock,
        tolerance_mm=args.tolerance,
        timed=not args.per_cycle,
        dynamics=args.dynamics,
    )
    data = run.summary()
    if args.json:
        write_atomically(args.json, json.dumps(data, indent=1) + "\n")
    if args.plot:
        _plot(run, Path(args.plot))
    estimate = float(run.verdict.get("estimate_max_mm", math.nan))  # type: ignore[arg-type]
    print(
        f"{run.seam} seam at {run.speed_mm_s:g} mm/s, ΔT {run.delta_t_ms:.2f} ms: "
        f"error against the emulator's truth max {run.tracking_error_max_mm * 1e3:.1f} µm, "
        f"rms {run.tracking_error_rms_mm * 1e3:.1f} µm over {run.welded_mm:g} mm "
        f"(nominal path {run.nominal_error_max_mm:.3f} mm); "
        f"the tracker's estimate max {estimate * 1e3:.1f} µm"
        + (f"; STOPPED: {run.stopped}" if run.stopped else "")
    )
    if run.clock == "real":
        print(
            f"real clock ({run.cell}, {'timed corrections' if run.timed else 'Alter per cycle'}"
            f"): {run.corrections} corrections in {run.cycles} cycles of the move"
            + ("" if run.start_on_grid else "; the move's start cycle was not known exactly")
        )
    print(run.verdict.get("line", "no verdict"))
    return ExitCode.OK if run.within_tolerance else EXIT_OUT_OF_TOLERANCE


def _plot(run: TrackingRun, out_dir: Path) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ValueError("--plot needs matplotlib") from None
    out_dir.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(10, 4))
    for key, style in (("nominal", "k--"), ("seam", "g-"), ("laser", "r-")):
        pts = run.plot[key]
        ax.plot(pts[:, 0], pts[:, 1], style, label=key, linewidth=1)
    m = run.plot["measured"]
    ax.plot(m[:, 0], m[:, 1], "b.", markersize=2, label="measured seam")
    ax.set_xlabel("x workpiece (mm)")
    ax.set_ylabel("y workpiece (mm)")
    ax.set_title(
        f"{run.seam} at {run.speed_mm_s:g} mm/s, ΔT {run.delta_t_ms:.2f} ms: "
        f"max {run.tracking_error_max_mm * 1e3:.0f} µm"
    )
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / "track.png", dpi=100)
    plt.close(fig)
