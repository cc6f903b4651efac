"""Job processing: a job becomes a list of steps (pure, checked before anything moves), and
the runner sends the steps to a RobotSocket server.

Output sequencing (paper section III-C, the robot controller switches laser, gas and
crossjet): for a path, the arm moves to the start with every output off; gas on and
pre-flow; crossjet on; laser on; the welding segments at the path's velocity; laser off;
crossjet off; post-flow; gas off. A stitch weld is the same with a dwell of its duration
instead of the segments. The laser therefore is on only while the arm stands at or moves
along a welding path. ``dry_run`` keeps every output off (motion only).

Abort: Ctrl-C (KeyboardInterrupt), :meth:`JobRunner.cancel` (from another thread: the
operator console's abort), a lost connection or an error reply stop the job: the
laser goes off first, then the motion is reset (the arm decelerates along its path and the
queue is dropped), then crossjet and gas go off. When the connection itself is gone the
server's controlled stop does the same [RS-7.10].

Tracked paths (``tracked="on"``, method 2): the path's lines become a
:class:`~welding.tracking.PolylineWeld` in the base frame, corners rounded with R 32 mm, with a
lead-in of the sensor's look-ahead before the start (the sensor must have seen the seam
before the laser gets there) and a run-out of the braking distance after the end; a
:class:`Track` step runs it through :mod:`welding.track_loop`: the laser is on from the
path's start to its end and only while the tracker has a valid correction; a lost seam or
a silent sensor switches it off and stops the arm, and the job aborts ("seam lost").

Time: the robot's clock stamps the log; waits without motion (pre-/post-flow, stitch
duration, pauses) go through ``dwell(seconds)``, ``time.sleep`` on a real robot and the
simulated clock's advance on the emulated cell.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from kinematics.transforms import (
    invert,
    location_to_transform,
    matrix_from_rotvec,
    rotvec_from_matrix,
    transform_to_location,
)
from kinematics.types import IDENTITY_LOC, Loc
from robotsocket.client import MotionDesc, RobotClient
from spec.client import ConnectionClosed
from spec.errors import ProtocolError, RemoteError, error_text
from spec.params import Location as Location6
from spec.registry import CommandId
from spec.wire import MoveOutcome
from welding.job import Item, Job, Line, Location, Path, Pause, Stitch, Via
from welding.tools import Tables, ToolDBError
from welding.track_loop import RobotLink, TrackedWeld, weld_tracked
from welding.tracking import (
    MIN_AHEAD_MM,
    TOLERANCE_MM,
    CornerError,
    PolylineWeld,
    Tracker,
    check_sensor_view,
)

__all__ = [
    "ARC_TOLERANCE_MM",
    "Dwell",
    "JobAborted",
    "JobCancelled",
    "JobRunner",
    "LogEntry",
    "Mark",
    "MoveJ",
    "MoveL",
    "Output",
    "PlanError",
    "Progress",
    "SeamLost",
    "Step",
    "Track",
    "Wait",
    "arc_points",
    "plan",
    "steps_summary",
]

#: Largest distance (mm) between an arc and the chords it is run as.
ARC_TOLERANCE_MM = 0.005
OUTPUTS = ("laser", "crossjet", "gas")


class PlanError(ValueError):
    """The job cannot be run as written (an arc through collinear points, ...)."""


# --- steps ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class MoveJ:
    loc: Loc
    tool: Loc
    frame: Loc
    speed: float  # % of the joint speed


@dataclass(frozen=True)
class MoveL:
    loc: Loc
    tool: Loc
    frame: Loc
    velocity: float  # mm/s
    blend: float = 0.0  # mm into the next move (between an arc's chords only)


@dataclass(frozen=True)
class Wait:
    """Wait for the end of the queued motion."""


@dataclass(frozen=True)
class Output:
    name: str
    value: bool


@dataclass(frozen=True)
class Dwell:
    seconds: float


@dataclass(frozen=True)
class Mark:
    """Item ``index`` (in processing order) named ``item`` enters ``phase``."""

    index: int
    item: str
    phase: str


@dataclass(frozen=True)
class Track:
    """A tracked weld (:mod:`welding.track_loop`): the nominal ``weld`` of the laser
    ``tool`` in the base frame, the sensor ``look_ahead_mm`` ahead, the laser on from
    ``laser_from_mm`` to ``laser_to_mm`` of arc length (never when ``laser`` is False)."""

    weld: PolylineWeld
    tool: Loc
    look_ahead_mm: float
    laser_from_mm: float
    laser_to_mm: float
    laser: bool
    sensor_tool: Loc | None  # ^N_S T the robot's synchronisation computes seam points with


Step = MoveJ | MoveL | Wait | Output | Dwell | Mark | Track


def _loc6(v: tuple[float, ...]) -> Loc:
    return (v[0], v[1], v[2], v[3], v[4], v[5])


def _resolve(loc: Location, tables: Tables) -> tuple[Loc, Loc, Loc]:
    return loc.values, tables.tool(loc.tool).location, tables.frame(loc.frame).location


def arc_points(a: Loc, m: Loc, b: Loc, tolerance: float = ARC_TOLERANCE_MM) -> list[Loc]:
    """Locations along the circle from ``a`` through ``m`` to ``b`` (mm, deg), ``b`` last and
    ``a`` left out, so close that each chord stays within ``tolerance`` mm of the arc; the
    orientation turns uniformly from a's to b's."""
    pa, pm, pb = (np.array(p[:3], dtype=np.float64) for p in (a, m, b))
    n = np.cross(pm - pa, pb - pa)
    if np.linalg.norm(n) < 1e-9 * max(1.0, float(np.linalg.norm(pb - pa)) ** 2):
        raise PlanError("arc: start, middle and end lie on one line")
    n /= np.linalg.norm(n)
    # circumcentre of the triangle a, m, b
    ab, am = pb - pa, pm - pa
    c = pa + (np.dot(am, am) * np.cross(ab, n) - np.dot(ab, ab) * np.cross(am, n)) / (
        2.0 * np.dot(np.cross(am, ab), n)
    )
    r = float(np.linalg.norm(pa - c))
    u = (pa - c) / r
    v = np.cross(n, u)

    def angle(p: np.ndarray[Any, Any]) -> float:
        return math.atan2(float(np.dot(p - c, v)), float(np.dot(p - c, u))) % (2 * math.pi)

    total = angle(pb)
    if angle(pm) > total:  # cannot happen with n = (m - a) x (b - a), kept as a guard
        raise PlanError("arc: the middle point is not between start and end")
    step = 2.0 * math.acos(max(-1.0, 1.0 - tolerance / r)) if tolerance < r else math.pi / 2
    count = max(1, math.ceil(total / step))
    Ra, Rb = location_to_transform(a)[:3, :3], location_to_transform(b)[:3, :3]
    w = rotvec_from_matrix(Ra.T @ Rb)
    out: list[Loc] = []
    for k in range(1, count + 1):
        s = k / count
        T = np.eye(4)
        T[:3, :3] = Ra @ matrix_from_rotvec(s * w)
        th = s * total
        T[:3, 3] = c + r * (math.cos(th) * u + math.sin(th) * v)
        x, y, z, rx, ry, rz = (float(q) for q in transform_to_location(T))
        out.append((x, y, z, rx, ry, rz))
    bx, by, bz, brx, bry, brz = (float(q) for q in b)
    out[-1] = (bx, by, bz, brx, bry, brz)  # the end exactly as written
    return out


def _angle_deg(a: np.ndarray[Any, Any], b: np.ndarray[Any, Any]) -> float:
    return math.degrees(float(np.linalg.norm(rotvec_from_matrix(a[:3, :3].T @ b[:3, :3]))))


def _track_step(path: Path, tables: Tables, sensor_tool: str | None, laser: bool) -> Track:
    """The :class:`Track` of a tracked path; :class:`PlanError` when it cannot be tracked."""
    name = path.name
    if any(not isinstance(seg, Line) for seg in path.segments):
        raise PlanError(f"path {name!r}: a tracked path takes <line> segments only")
    locs = list(path.locations())
    if len({loc.tool for loc in locs}) != 1:
        raise PlanError(f"path {name!r}: a tracked path keeps one tool")
    tool = tables.tool(path.start.tool).location
    poses = [
        location_to_transform(tables.frame(loc.frame).location) @ location_to_transform(loc.values)
        for loc in locs
    ]
    for k, pose in enumerate(poses[1:], 2):
        if _angle_deg(poses[0], pose) > 0.01:
            raise PlanError(
                f"path {name!r}: point {k} turns the tool; a tracked path keeps the start's "
                "orientation (the sensor stays ahead of the laser)"
            )
    vertices = np.array([p[:3, 3] for p in poses])
    d0 = vertices[1] - vertices[0]
    d0 /= max(float(np.linalg.norm(d0)), 1e-12)
    d1 = vertices[-1] - vertices[-2]
    d1 /= max(float(np.linalg.norm(d1)), 1e-12)
    look_ahead = 0.0
    sensor2base = np.eye(4)
    sensor_loc: Loc | None = None
    if sensor_tool is not None:
        try:
            sensor_loc = tables.tool(sensor_tool).location
            sensor2flange = location_to_transform(sensor_loc)
        except ToolDBError:
            raise PlanError(
                f"path {name!r}: a tracked path needs the sensor tool {sensor_tool!r} in the "
                "tool database"
            ) from None
        sensor2base = poses[0] @ invert(location_to_transform(tool)) @ sensor2flange
        look_ahead = float((sensor2base[:3, 3] - vertices[0]) @ d0)
        if look_ahead < MIN_AHEAD_MM + 5.0:
            raise PlanError(
                f"path {name!r}: the sensor is {look_ahead:.1f} mm ahead of the laser along "
                f"the first line; tracking needs it at least {MIN_AHEAD_MM + 5.0:g} mm ahead"
            )
    speed = path.velocity
    run_out = speed * speed / (2.0 * 2500.0) + 1.0
    lead_in = max(look_ahead, run_out)
    ext = np.vstack([vertices[0] - lead_in * d0, vertices, vertices[-1] + run_out * d1])
    angles = np.array(transform_to_location(poses[0])[3:], dtype=np.float64)
    try:
        weld = PolylineWeld(ext, angles, speed)
        if sensor_tool is not None:
            check_sensor_view(
                weld, sensor2base[:3, 3] - vertices[0], sensor2base[:3, 0], sensor2base[:3, 1]
            )
    except CornerError as exc:
        point = min(max(exc.corner, 1), len(locs))  # the job's point (the lead-in is 0)
        raise PlanError(f"path {name!r}, point {point} of the path: {exc}") from None
    except ValueError as exc:
        raise PlanError(f"path {name!r}: {exc}") from None
    laser_to = weld.length_mm - run_out
    return Track(weld, tool, look_ahead, lead_in, laser_to, laser, sensor_loc)


def _item_steps(
    index: int, item: Item, tables: Tables, dry_run: bool, sensor_tool: str | None
) -> Iterator[Step]:
    def out(name: str, value: bool, wanted: bool = True) -> Iterator[Step]:
        if wanted and not dry_run:
            yield Output(name, value)

    if isinstance(item, Pause):
        yield Mark(index, item.name, "pause")
        yield Dwell(item.duration)
        return
    if isinstance(item, Via):
        yield Mark(index, item.name, "move")
        yield MoveJ(*_resolve(item.at, tables), item.speed)
        yield Wait()
        return
    at = item.at if isinstance(item, Stitch) else item.start
    track = None
    if isinstance(item, Path) and item.tracked:
        track = _track_step(item, tables, sensor_tool, item.laser and not dry_run)
    yield Mark(index, item.name, "approach")
    speed = item.speed if isinstance(item, Stitch) else 10.0
    if track is None:
        yield MoveJ(*_resolve(at, tables), speed)
    else:  # to the lead-in's start, in the base frame
        p0 = track.weld.point(0.0)
        start = (*(float(v) for v in p0), *(float(v) for v in track.weld.angles))
        yield MoveJ(_loc6(start), track.tool, IDENTITY_LOC, speed)
    yield Wait()
    yield Mark(index, item.name, "preflow")
    yield from out("gas", True, item.gas)
    if item.gas and item.preflow > 0:
        yield Dwell(item.preflow)
    yield from out("crossjet", True, item.crossjet)
    laser = item.laser if isinstance(item, Path) else True
    yield from out("laser", True, laser and track is None)  # a Track switches it itself
    yield Mark(index, item.name, "weld")
    if isinstance(item, Stitch):
        yield Dwell(item.duration)
    elif track is not None:
        yield track
    else:
        prev = item.start
        for seg in item.segments:
            if isinstance(seg, Line):
                yield MoveL(*_resolve(seg.to, tables), item.velocity)
            else:
                if not (prev.tool == seg.mid.tool == seg.to.tool) or not (
                    prev.frame == seg.mid.frame == seg.to.frame
                ):
                    raise PlanError(
                        f"path {item.name!r}: an arc's points must share the tool and frame "
                        "of the point before it"
                    )
                _, tool, frame = _resolve(seg.to, tables)
                points = arc_points(prev.values, seg.mid.values, seg.to.values)
                # Blending the chords into each other keeps the speed near the velocity (the
                # arm would stop at every chord) and stays within the chords' sag; the arc's
                # end is reached exactly.
                chord = math.dist(prev.values[:3], points[0][:3])
                for k, p in enumerate(points):
                    blend = chord / 2 if k + 1 < len(points) else 0.0
                    yield MoveL(p, tool, frame, item.velocity, blend)
            prev = seg.to
        yield Wait()
    yield from out("laser", False, laser and track is None)
    yield from out("crossjet", False, item.crossjet)
    yield Mark(index, item.name, "postflow")
    if item.gas and item.postflow > 0:
        yield Dwell(item.postflow)
    yield from out("gas", False, item.gas)


def plan(
    job: Job, tables: Tables, *, dry_run: bool = False, sensor_tool: str | None = "sensor"
) -> list[Step]:
    """The steps of ``job`` with the tools and frames of ``tables``; raises
    :class:`PlanError` or :class:`~welding.tools.ToolDBError` before anything moves.
    ``sensor_tool``: the tool database's name of ^N_S T, which tracked paths need (None:
    skip the checks that need it, e.g. a job checked without a database)."""
    steps: list[Step] = [Output(n, False) for n in OUTPUTS]  # a known start: all off
    for index, item in enumerate(job.sequence()):
        steps.extend(_item_steps(index, item, tables, dry_run, sensor_tool))
    steps.append(Mark(len(job.sequence()), "", "done"))
    return steps


# --- running -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Progress:
    index: int
    total: int
    item: str
    phase: str


@dataclass
class LogEntry:
    """One line of the run log; ``t`` on the robot clock (s), NaN when it could not be read."""

    t: float
    event: str
    item: str = ""
    detail: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"t": None if math.isnan(self.t) else self.t, "event": self.event,
                "item": self.item, **self.detail}  # fmt: skip


class SeamLost(Exception):
    """A tracked weld stopped: the tracker lost the seam (the laser is already off)."""


class OutOfTolerance(Exception):
    """A tracked weld ended, but the tracker's own verdict is that it is not within the
    tolerance (the laser is already off): the job stops there, as for a lost seam."""


class MoveStopped(Exception):
    """A move was stopped short of its target (an emergency stop, control taken away) or
    failed, with the robot's reason [RS-5.50]."""


class JobAborted(Exception):
    """The job stopped before its end: ``reason`` ("interrupted", "cancelled", "connection
    lost", "error reply", "timeout", "move stopped", "seam lost", "out of tolerance" or
    "error"), ``log`` up to and including the safe stop."""

    def __init__(self, reason: str, message: str, log: list[LogEntry]) -> None:
        super().__init__(f"job aborted ({reason}): {message}")
        self.reason = reason
        self.message = message
        self.log = log


class JobCancelled(Exception):
    """:meth:`JobRunner.cancel` was called."""


class JobRunner:
    """Runs jobs on ``robot`` (a :class:`RobotClient` that holds control, arm powered).

    ``dwell(seconds)`` waits on the robot's time base (default ``time.sleep``);
    ``on_progress`` is called at each item's phase; ``move_timeout`` bounds each wait for
    the end of a move (s); ``poll`` (s), when given, splits each wait for the end of a move
    into pieces that long, so :meth:`cancel` from another thread takes effect within one
    piece (the client sends one request at a time; a whole wait would hold it). Tracked
    paths: ``sensor_endpoint`` is the sensor's trigger address (None: as configured on the
    robot), ``real_time`` whether the robot runs on the wall clock (False: a simulated clock
    advanced by WaitEndMove), ``rate_hz`` the trigger rate, ``tolerance_mm`` the tracked
    weld's (its verdict outside it stops the job)."""

    def __init__(
        self,
        robot: RobotClient,
        tables: Tables,
        *,
        dry_run: bool = False,
        dwell: Callable[[float], None] = time.sleep,
        on_progress: Callable[[Progress], None] | None = None,
        move_timeout: float = 300.0,
        sensor_endpoint: tuple[str, int] | None = None,
        real_time: bool = True,
        rate_hz: float = 200.0,
        poll: float | None = None,
        tolerance_mm: float = TOLERANCE_MM,
    ) -> None:
        self.robot = robot
        self.tolerance_mm = tolerance_mm
        self.sensor_endpoint = sensor_endpoint
        self.real_time = real_time
        self.rate_hz = rate_hz
        self.tables = tables
        self.dry_run = dry_run
        self.dwell = dwell
        self.on_progress = on_progress
        self.move_timeout = move_timeout
        self.poll = poll
        self.log: list[LogEntry] = []
        self._cancel = threading.Event()

    def cancel(self) -> None:
        """Stop the running job at its next step or wait piece: laser off first, then the
        controlled stop (:meth:`safe_stop`); :meth:`run` raises :class:`JobAborted`
        ("cancelled")."""
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def _now(self) -> float:
        try:
            return self.robot.get_time()
        except (OSError, ProtocolError, RemoteError):
            return math.nan

    def _note(self, event: str, item: str = "", **detail: Any) -> None:
        self.log.append(LogEntry(self._now(), event, item, detail))

    def run(self, job: Job, *, sensor_tool: str = "sensor") -> list[LogEntry]:
        """Run ``job``; returns the log. Raises :class:`JobAborted` (after the safe stop)."""
        steps = plan(job, self.tables, dry_run=self.dry_run, sensor_tool=sensor_tool)
        total = len(job.sequence())
        self.log = []
        self._cancel.clear()
        self._note("start", job=job.name, dry_run=self.dry_run, items=total)
        desc = self.robot.motion_desc()
        sent = desc  # sent again only when it changes: one round trip less per chord
        item = ""
        try:
            for step in steps:
                if self._cancel.is_set():
                    raise JobCancelled("cancelled by the operator")
                if isinstance(step, Mark):
                    item = step.item
                    if step.phase != "done":
                        self._note(step.phase, item)
                    if self.on_progress is not None:
                        self.on_progress(Progress(step.index, total, step.item, step.phase))
                elif isinstance(step, Output):
                    self.robot.set_output(step.name, step.value)
                    self._note("output", item, output=step.name, value=step.value)
                elif isinstance(step, Dwell):
                    self.dwell(step.seconds)
                elif isinstance(step, MoveJ):
                    sent = self._desc(sent, replace(desc, joint_speed=step.speed, blend=0.0))
                    self.robot.tool_move_j(step.loc, step.tool, step.frame)
                elif isinstance(step, MoveL):
                    wanted = replace(desc, tool_speed=step.velocity, blend=step.blend)
                    sent = self._desc(sent, wanted)
                    self.robot.tool_move_l(step.loc, step.tool, step.frame)
                elif isinstance(step, Track):
                    self._track(step, item)
                else:
                    self._wait_end_move()
            self.robot.set_motion_desc(desc)
        except BaseException as exc:
            reason = _reason(exc)
            message = error_text(exc) or type(exc).__name__
            self._note("abort", item, reason=reason, message=message)
            self.safe_stop()
            raise JobAborted(reason, message, self.log) from exc
        self._note("end", job=job.name)
        return self.log

    def _track(self, step: Track, item: str) -> None:
        if step.sensor_tool is not None:
            self.robot.call(CommandId.SET_SENSOR_TOOL, Location6(*step.sensor_tool))
        tracker = Tracker(step.weld, step.look_ahead_mm, seam_end_mm=step.laser_to_mm)
        link = RobotLink(self.robot, self.sensor_endpoint, real_time=self.real_time)
        weld = TrackedWeld(
            tracker, step.tool, step.laser_from_mm, step.laser_to_mm, self.rate_hz,
            laser=step.laser, tolerance_mm=self.tolerance_mm,
        )  # fmt: skip
        outcome = weld_tracked(link, weld, cancelled=self._cancel.is_set)
        verdict = outcome.verdict
        self._note(
            "tracked",
            item,
            cycles=outcome.cycles,
            corrections=outcome.corrections,
            seam_points=tracker.model.count,
            delta_t_ms=link.delta_t() * 1e3,
            verdict=verdict.line() if verdict is not None else "",
        )
        if self._cancel.is_set():
            raise JobCancelled("cancelled by the operator")
        if outcome.stopped:
            raise SeamLost(outcome.stopped)
        if verdict is not None and not verdict.within and step.laser:
            raise OutOfTolerance(verdict.line())

    def _wait_end_move(self) -> None:
        """Wait for the queued moves to reach their target, in pieces of ``poll`` s that
        let the operator cancel; a move stopped short or failed ends the wait at once, with
        the robot's reason (not as a timeout after ``move_timeout``)."""
        waited = 0.0
        while True:
            piece = self.move_timeout - waited
            if self.poll is not None:
                piece = min(self.poll, piece)
            result = self.robot.wait_move(piece)
            if result.reached:
                return
            if result.outcome is not MoveOutcome.MOVING:
                raise MoveStopped(f"the move {result.outcome}: {result.reason}")
            waited += piece
            if waited >= self.move_timeout - 1e-9:
                raise TimeoutError(f"the move did not end within {self.move_timeout:g} s")
            if self._cancel.is_set():
                raise JobCancelled("cancelled by the operator")

    def _desc(self, sent: MotionDesc, wanted: MotionDesc) -> MotionDesc:
        if wanted != sent:
            self.robot.set_motion_desc(wanted)
        return wanted

    def safe_stop(self) -> None:
        """Laser off first, then stop and drop the motion, then crossjet and gas off. Each
        step is tried on its own; a lost connection leaves it to the server [RS-7.10]. A
        second Ctrl-C meanwhile is ignored: it must not cut the stop short."""
        with _no_interrupts():
            self._safe_stop()

    def _safe_stop(self) -> None:
        robot = self.robot
        actions: list[tuple[str, Callable[[], None]]] = [
            ("laser off", lambda: robot.set_output("laser", False)),
            ("motion reset", robot.reset_motion),
            ("crossjet off", lambda: robot.set_output("crossjet", False)),
            ("gas off", lambda: robot.set_output("gas", False)),
        ]
        for what, action in actions:
            try:
                action()
                self._note("safe stop", step=what)
            except (OSError, ProtocolError, RemoteError) as exc:
                self.log.append(
                    LogEntry(math.nan, "safe stop failed", detail={"step": what, "error": str(exc)})
                )
                if isinstance(exc, OSError | ConnectionClosed):
                    return  # the server's controlled stop takes over


@contextmanager
def _no_interrupts() -> Iterator[None]:
    if threading.current_thread() is not threading.main_thread():
        yield  # signals only reach the main thread
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _reason(exc: BaseException) -> str:
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    if isinstance(exc, JobCancelled):
        return "cancelled"
    if isinstance(exc, ConnectionClosed | ConnectionError):
        return "connection lost"
    if isinstance(exc, RemoteError):
        return "error reply"
    if isinstance(exc, TimeoutError):
        return "timeout"
    if isinstance(exc, MoveStopped):
        return "move stopped"
    if isinstance(exc, SeamLost):
        return "seam lost"
    if isinstance(exc, OutOfTolerance):
        return "out of tolerance"
    return "error"


def steps_summary(steps: list[Step]) -> dict[str, int]:
    """Counts of each step kind (for ``job show``)."""
    out: dict[str, int] = {}
    for s in steps:
        out[type(s).__name__] = out.get(type(s).__name__, 0) + 1
    return out
