"""Job processing: the plan (pure) and runs on the emulated cell, checked against the
robot emulator's I/O log and its setpoints: the laser is never on off a welding path, and
every abort switches the laser off first."""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest

from kinematics.transforms import invert, location_to_transform
from robotsocket.client import RobotClient
from sensorsocket.scene import JogPath
from spec.client import MoveResult
from spec.registry import CommandId
from welding import job as J
from welding.emulate import EmulatedSession
from welding.process import (
    Dwell,
    JobAborted,
    JobRunner,
    MoveL,
    Output,
    PlanError,
    Track,
    arc_points,
    plan,
)
from welding.tools import Tables, ToolDBError
from welding.tracking import seam_error

W = "workpiece"


def L(x: float, y: float, z: float) -> J.Location:
    return J.Location(x, y, z, 180.0, 0.0, 0.0, "laser", W)


R = 10.0
ARC_MID = (-10 + R * math.sqrt(0.5), R - R * math.sqrt(0.5))
SEAM = J.Path(
    "seam",
    L(-40, 0, 0),
    (J.Line(L(-10, 0, 0)), J.Arc(L(*ARC_MID, 0), L(0, 10, 0))),
    velocity=20,
    power=1000,
    preflow=0.5,
    postflow=0.4,
)
SPOT = J.Stitch("spot", L(10, 10, 0), duration=0.2, preflow=0.1, postflow=0.1)
JOB = J.Job(
    "t",
    (
        J.Via("approach", L(-40, 0, 30)),
        SEAM,
        SPOT,
        J.Pause("cool", 0.5),
        J.Via("up", L(10, 10, 30)),
    ),
)


# --- the plan --------------------------------------------------------------------------------


def tables() -> Tables:
    t = Tables({}, {})
    from welding.tools import Entry

    t.add(Entry("laser", "laser", (0.0, 0.0, 200.0, 0.0, 0.0, 0.0)))
    t.add(Entry(W, "frame", (500.0, 0.0, -200.0, 0.0, 0.0, 180.0)))
    return t


def test_plan_switches_outputs_in_process_order() -> None:
    steps = plan(J.Job("p", (SEAM,)), tables())
    outs = [(s.name, s.value) for s in steps if isinstance(s, Output)]
    assert outs == [
        ("laser", False), ("crossjet", False), ("gas", False),  # a known start
        ("gas", True), ("crossjet", True), ("laser", True),
        ("laser", False), ("crossjet", False), ("gas", False),
    ]  # fmt: skip
    i_laser_on = steps.index(Output("laser", True))
    i_laser_off = steps.index(Output("laser", False), i_laser_on)
    welding = steps[i_laser_on:i_laser_off]
    assert all(m.velocity == 20 for m in welding if isinstance(m, MoveL))
    assert sum(isinstance(m, MoveL) for m in steps) == sum(isinstance(m, MoveL) for m in welding)
    assert Dwell(0.5) in steps[:i_laser_on] and Dwell(0.4) in steps[i_laser_off:]


def test_dry_run_plans_no_output_but_the_initial_off() -> None:
    steps = plan(JOB, tables(), dry_run=True)
    assert [s for s in steps if isinstance(s, Output)] == [
        Output("laser", False),
        Output("crossjet", False),
        Output("gas", False),
    ]
    assert sum(isinstance(s, MoveL) for s in steps) == sum(
        isinstance(s, MoveL) for s in plan(JOB, tables())
    )


def test_missing_tool_or_collinear_arc_is_refused_before_anything_moves() -> None:
    with pytest.raises(ToolDBError, match="no tool named 'torch'"):
        plan(J.Job("p", (J.Via("v", J.Location(0, 0, 0, 0, 0, 0, "torch", W)),)), tables())
    flat = J.Path("p", L(0, 0, 0), (J.Arc(L(1, 0, 0), L(2, 0, 0)),), velocity=5)
    with pytest.raises(PlanError, match="on one line"):
        plan(J.Job("p", (flat,)), tables())


def test_arc_chords_stay_within_tolerance_and_end_exactly() -> None:
    a, m, b = (-10.0, 0.0, 0.0, 180.0, 0.0, 0.0), (*ARC_MID, 0.0, 180.0, 0.0, 0.0), (
        0.0, 10.0, 0.0, 180.0, 0.0, 0.0
    )  # fmt: skip
    pts = np.array(arc_points(a, m, b, tolerance=0.005))
    assert tuple(pts[-1]) == b
    centre = np.array([-10.0, 10.0])
    assert np.allclose(np.linalg.norm(pts[:, :2] - centre, axis=1), R, atol=1e-9)
    chords = np.vstack([a[:2], pts[:, :2]])
    mids = 0.5 * (chords[1:] + chords[:-1])
    sag = R - np.linalg.norm(mids - centre, axis=1)
    assert sag.max() <= 0.005 and len(pts) > 10
    # a 3/4 circle goes the long way round, through the middle point
    long = arc_points((10, 0, 0, 0, 0, 0), (-10, 0, 0, 0, 0, 0), (0, -10, 0, 0, 0, 0))
    assert min(p[0] for p in long) == pytest.approx(-10, abs=0.01)


# --- runs on the emulated cell ---------------------------------------------------------------


@pytest.fixture
def session() -> Iterator[EmulatedSession]:
    with EmulatedSession() as s:
        s.setpoints = []  # type: ignore[attr-defined]
        s.cell.robot.cycle_hooks.append(
            lambda t, q, qm: s.setpoints.append((t, q.copy()))  # type: ignore[attr-defined]
        )
        yield s


def laser_positions(s: EmulatedSession, t0: float, t1: float) -> np.ndarray:
    """Laser focus (N, 3) in the workpiece frame at the setpoints with t0 <= t <= t1."""
    model = s.cell.robot.model
    tool = location_to_transform(s.tables.tool("laser").location)
    b2w = invert(location_to_transform(s.tables.frame(W).location))
    pts = [
        (b2w @ model.flange2base(q) @ tool)[:3, 3]
        for t, q in s.setpoints  # type: ignore[attr-defined]
        if t0 - 1e-9 <= t <= t1 + 1e-9
    ]
    return np.array(pts)


def on_intervals(io: list[tuple[float, str, bool]], name: str) -> list[tuple[float, float]]:
    out, start = [], None
    for t, n, v in io:
        if n != name:
            continue
        if v and start is None:
            start = t
        elif not v and start is not None:
            out.append((start, t))
            start = None
    assert start is None, f"{name} left on"
    return out


def distance_to_welds(p: np.ndarray) -> np.ndarray:
    """Distance (mm) of points (N, 3) to the seam (line + arc) or the spot."""
    a, b = np.array([-40.0, 0, 0]), np.array([-10.0, 0, 0])
    s = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
    d_line = np.linalg.norm(p - (a + s[:, None] * (b - a)), axis=1)
    th = np.linspace(-math.pi / 2, 0, 20001)
    arc = np.stack([-10 + R * np.cos(th), 10 + R * np.sin(th), 0 * th], axis=1)
    d_arc = np.min(np.linalg.norm(p[:, None, :] - arc[None, ::20, :], axis=2), axis=1)
    d_spot = np.linalg.norm(p - np.array([10.0, 10, 0]), axis=1)
    out: np.ndarray = np.minimum(np.minimum(d_line, d_arc), d_spot)
    return out


def test_laser_is_on_only_on_welding_paths(session: EmulatedSession) -> None:
    log = JobRunner(session.robot, session.tables, dwell=session.dwell).run(JOB)
    io = session.io_log
    lasers = on_intervals(io, "laser")
    assert len(lasers) == 2  # the seam and the spot
    for t0, t1 in lasers:
        p = laser_positions(session, t0, t1)
        assert len(p) and distance_to_welds(p).max() < 0.05
    # ... and it does weld them: the laser covers the whole seam
    seam_on = laser_positions(session, *lasers[0])
    assert np.linalg.norm(seam_on[0] - [-40, 0, 0]) < 1e-3
    assert np.linalg.norm(seam_on[-1] - [0, 10, 0]) < 1e-3
    # the arc's chords are blended: away from its ends the speed stays near the velocity
    centre = np.array([-10.0, 10.0])
    on_arc = (seam_on[:, 0] > -10.0) & (seam_on[:, 1] < 10.0)
    angle = np.arctan2(seam_on[on_arc, 1] - 10.0, seam_on[on_arc, 0] + 10.0)
    middle = seam_on[on_arc][(angle > -1.3) & (angle < -0.3)]
    assert len(middle) > 50 and np.allclose(np.linalg.norm(middle[:, :2] - centre, axis=1), R,
                                            atol=0.005)  # fmt: skip
    speed = np.linalg.norm(np.diff(middle, axis=0), axis=1) / session.cell.robot.period
    assert speed.min() > 0.8 * SEAM.velocity and speed.max() < 1.01 * SEAM.velocity
    # gas from pre-flow before the laser to post-flow after it; crossjet with the laser
    gases, jets = on_intervals(io, "gas"), on_intervals(io, "crossjet")
    items: tuple[J.Path | J.Stitch, ...] = (SEAM, SPOT)
    for (l0, l1), (g0, g1), (c0, c1), item in zip(lasers, gases, jets, items, strict=True):
        assert l0 - g0 == pytest.approx(item.preflow)
        assert g1 - l1 == pytest.approx(item.postflow)
        assert c0 <= l0 and c1 >= l1
    # the stitch lasts its duration; the log carries robot-clock times
    assert lasers[1][1] - lasers[1][0] == pytest.approx(SPOT.duration)
    events = [e.event for e in log]
    assert events[0] == "start" and events[-1] == "end"
    assert [e.t for e in log] == sorted(e.t for e in log)


def test_dry_run_moves_with_every_output_off(session: EmulatedSession) -> None:
    JobRunner(session.robot, session.tables, dry_run=True, dwell=session.dwell).run(JOB)
    assert all(not v for _, _, v in session.io_log)
    end = laser_positions(session, session.setpoints[-1][0], math.inf)  # type: ignore[attr-defined]
    assert np.linalg.norm(end[-1] - [10, 10, 30]) < 1e-3


def interrupt_mid_seam(session: EmulatedSession, exc: BaseException) -> list[float]:
    """Make the runner's wait during the seam end after 1 s of motion with ``exc``."""
    robot = session.robot
    real_wait = robot.wait_move
    stopped_at: list[float] = []

    def wait(timeout: float = 60.0) -> MoveResult:
        if robot.read_io("laser"):
            real_wait(1.0)
            stopped_at.append(robot.get_time())
            if isinstance(exc, ConnectionError):
                assert robot._sock is not None
                robot._sock.shutdown(socket.SHUT_RDWR)
                return real_wait(timeout)
            raise exc
        return real_wait(timeout)

    robot.wait_move = wait  # type: ignore[method-assign]
    return stopped_at


def check_stopped_safely(session: EmulatedSession, aborted: JobAborted) -> None:
    (t_abort,) = [e.t for e in aborted.log if e.event == "abort"]
    io = session.io_log
    last_on = max(i for i, (_, n, v) in enumerate(io) if n == "laser" and v)
    assert not io[last_on][0] > t_abort  # on when the job stopped (NaN: robot clock unread)
    after = [(n, v) for _, n, v in io[last_on + 1 :]]
    assert after[0] == ("laser", False)  # the laser goes off first
    assert {n for n, v in after if not v} >= {"laser", "crossjet", "gas"}
    assert not any(v for _, v in after)
    # the arm stops: the setpoints settle within a second of robot time
    session.cell.advance(1.0)
    state = session.cell.robot.status()
    assert not state.moving and state.queue == 0


def test_ctrl_c_switches_the_laser_off_first_and_stops(session: EmulatedSession) -> None:
    stopped = interrupt_mid_seam(session, KeyboardInterrupt())
    runner = JobRunner(session.robot, session.tables, dwell=session.dwell)
    with pytest.raises(JobAborted) as info:
        runner.run(JOB)
    assert info.value.reason == "interrupted"
    check_stopped_safely(session, info.value)
    assert stopped
    steps = [e.detail.get("step") for e in info.value.log if e.event == "safe stop"]
    assert steps == ["laser off", "motion reset", "crossjet off", "gas off"]


def test_cancel_from_another_thread_ends_the_wait_laser_off_first(
    session: EmulatedSession,
) -> None:
    robot = session.robot
    real_wait = robot.wait_move
    runner = JobRunner(robot, session.tables, dwell=session.dwell, poll=0.1)
    pieces: list[float] = []
    cancelled_at: list[int] = []

    def wait(timeout: float = 60.0) -> MoveResult:
        pieces.append(timeout)
        if robot.read_io("laser") and not runner.cancelled:
            # the operator's abort arrives from another thread during the seam
            t = threading.Thread(target=runner.cancel)
            t.start()
            t.join()
            cancelled_at.append(len(pieces))
        return real_wait(timeout)

    robot.wait_move = wait  # type: ignore[method-assign]
    with pytest.raises(JobAborted) as info:
        runner.run(JOB)
    assert info.value.reason == "cancelled"
    # the wait goes in pieces: the abort is seen after the piece it came in, mid-seam
    assert max(pieces) == 0.1 and cancelled_at == [len(pieces)]
    assert [e.item for e in info.value.log if e.event == "abort"] == ["seam"]
    check_stopped_safely(session, info.value)


def test_a_move_stopped_by_an_emergency_stop_aborts_at_once(session: EmulatedSession) -> None:
    """An emergency stop from another client mid-seam: the job aborts with the robot's
    reason as soon as the wait returns (it waited for its 120 s move timeout, then said
    "the move did not end")."""
    robot = session.robot
    real_wait = robot.wait_move
    calls: list[float] = []

    def wait(timeout: float = 60.0) -> MoveResult:
        calls.append(timeout)
        if robot.read_io("laser") and len(calls) < 100:
            real_wait(0.2)
            with RobotClient(*session.cell.robot_address, client_name="e-stop") as other:
                other.call(CommandId.EMERGENCY_STOP)
        return real_wait(timeout)

    robot.wait_move = wait  # type: ignore[method-assign]
    runner = JobRunner(robot, session.tables, dwell=session.dwell, poll=0.1)
    with pytest.raises(JobAborted) as info:
        runner.run(JOB)
    assert info.value.reason == "move stopped", info.value.message
    assert "stopped" in info.value.message and "emergency" in info.value.message.lower()
    assert len(calls) < 5  # no polling out the move timeout


def test_error_reply_switches_the_laser_off_first(session: EmulatedSession) -> None:
    far = J.Path("far", L(-40, 0, 0), (J.Line(L(-20, 0, 0)), J.Line(L(-4000, 0, 0))), velocity=20)
    with pytest.raises(JobAborted) as info:
        JobRunner(session.robot, session.tables, dwell=session.dwell).run(J.Job("f", (far,)))
    assert info.value.reason == "error reply"
    assert "reach" in info.value.message.lower() or "range" in info.value.message.lower()
    check_stopped_safely(session, info.value)


def test_lost_connection_leaves_a_controlled_stop_laser_first(session: EmulatedSession) -> None:
    stopped = interrupt_mid_seam(session, ConnectionError())
    with pytest.raises(JobAborted) as info:
        JobRunner(session.robot, session.tables, dwell=session.dwell).run(JOB)
    assert info.value.reason == "connection lost"
    # the server notices the closed connection on its own thread: wait for its stop
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and not any(
        n == "gas" and not v for t, n, v in session.io_log if t >= stopped[0]
    ):
        time.sleep(0.01)
    check_stopped_safely(session, info.value)


def test_a_second_ctrl_c_cannot_cut_the_safe_stop_short(session: EmulatedSession) -> None:
    import os
    import signal

    robot = session.robot
    real_set = robot.set_output
    before = signal.getsignal(signal.SIGINT)  # a test worker may run with SIGINT ignored

    def set_output(name: str, value: bool) -> None:
        if name == "laser" and not value and robot.read_io("laser"):
            os.kill(os.getpid(), signal.SIGINT)  # the operator presses Ctrl-C again
        real_set(name, value)

    robot.set_output = set_output  # type: ignore[method-assign]
    interrupt_mid_seam(session, KeyboardInterrupt())
    with pytest.raises(JobAborted) as info:
        JobRunner(session.robot, session.tables, dwell=session.dwell).run(JOB)
    check_stopped_safely(session, info.value)
    assert signal.getsignal(signal.SIGINT) is before  # the runner put the handler back


# --- tracked paths (seam tracking, welding.track_loop) ---------------------------------------


def tracking_tables() -> Tables:
    t = tables()
    from welding.tools import Entry

    t.add(Entry("sensor", "sensor", (40.0, 0.0, 200.0, 0.0, 0.0, 0.0)))
    return t


def tracked(*points: tuple[float, float], velocity: float = 100.0, z: float = 0.0) -> J.Job:
    start, *rest = (L(x, y, z) for x, y in points)
    path = J.Path("seam", start, tuple(J.Line(p) for p in rest), velocity, tracked=True)
    return J.Job("t", (path,))


def test_tracked_path_plans_lead_in_and_track_step() -> None:
    steps = plan(
        tracked((0, 0), (100, 0), (100 + 100 * math.cos(0.1), 100 * math.sin(0.1))),
        tracking_tables(),
    )
    (track,) = [s for s in steps if isinstance(s, Track)]
    # the sensor is 40 mm ahead of the laser: the motion starts 40 mm before the path, the
    # laser window is the path itself (its corner rounded with R 32 mm)
    assert track.look_ahead_mm == pytest.approx(40.0)
    assert track.laser_from_mm == pytest.approx(40.0)
    corner = 0.1 * 32.0 - 2 * 32.0 * math.tan(0.05)  # the arc minus the two cut corners
    assert track.laser_to_mm == pytest.approx(40.0 + 200.0 + corner)
    # the laser is switched by the Track step only, never by an Output step of this path
    assert not [s for s in steps if isinstance(s, Output) and s.name == "laser" and s.value]


@pytest.mark.parametrize(
    ("points", "pattern"),
    [
        (
            ((0, 0), (80, 0), (80 + 80 * math.cos(0.8), 80 * math.sin(0.8))),
            "point 2 .* too sharply",
        ),
        (((0, 0), (80, 0), (82, 0.5), (160, 0)), "point 3 .* rounding its corners with R 32"),
        (((0, 0), (80, 0), (0, 1)), "turns back on itself"),
    ],
)
def test_tracked_corner_too_sharp_is_refused(
    points: tuple[tuple[float, float], ...], pattern: str
) -> None:
    with pytest.raises(PlanError, match=pattern):
        plan(tracked(*points), tracking_tables())


def test_tracked_path_needs_lines_a_sensor_ahead_and_one_orientation() -> None:
    arc = J.Job("t", (replace(SEAM, tracked=True),))
    with pytest.raises(PlanError, match="<line> segments only"):
        plan(arc, tracking_tables())
    with pytest.raises(PlanError, match="sensor tool 'sensor'"):
        plan(tracked((0, 0), (100, 0)), tables())
    with pytest.raises(PlanError, match=r"-40\.0 mm ahead"):
        plan(tracked((100, 0), (0, 0)), tracking_tables())
    turned = J.Job(
        "t",
        (J.Path("p", L(0, 0, 0), (J.Line(replace(L(100, 0, 0), rz=5.0)),), 100.0, tracked=True),),
    )
    with pytest.raises(PlanError, match="point 2 turns the tool"):
        plan(turned, tracking_tables())


def _jog_polyline() -> list[tuple[float, float]]:
    """The corner points (workpiece frame) of the cell's jog seam: its R 32 mm arcs are the
    polyline's corners rounded, so the nominal path is the seam where it should be."""
    jog = JogPath()
    x1, y1, x2, y2, _x3, h = jog._knots()
    t = math.tan(math.radians(jog.angle_deg))
    return [(x1 - y1 / t, 0.0), (x2 + (h - y2) / t, h)]


def _laser_truth(s: EmulatedSession) -> list[tuple[np.ndarray, bool]]:
    robot = s.cell.robot
    truth: list[tuple[np.ndarray, bool]] = []
    robot.cycle_hooks.append(lambda t, q_sp, q_m: truth.append((q_sp, robot.read_io("laser")[0])))
    return truth


def _seam_error(s: EmulatedSession, q: np.ndarray) -> np.ndarray:
    pts = (s.cell.robot.model.flange2base_batch(q) @ s.cell.laser2flange)[:, :3, 3]
    scene = s.cell.scene
    lat, hgt = seam_error(pts, scene.base2workpiece, scene.path.lateral, scene.joint.seam_height_mm)
    return np.hypot(lat, hgt)


def _laser_z(s: EmulatedSession) -> float:
    """Height of the laser focus over the workpiece at the ready pose (on the seam)."""
    return s.robot.here(s.tables.tool("laser").location, s.tables.frame(W).location)[2]


def _runner(s: EmulatedSession) -> JobRunner:
    return JobRunner(
        s.robot, s.tables, dwell=s.dwell, sensor_endpoint=s.cell.udp_address, real_time=False
    )


def test_tracked_job_follows_the_misplaced_jog_seam_within_target() -> None:
    # workpiece 1.5 mm and 0.5 deg off where the job says; the path has two 15 deg corners
    with EmulatedSession("arc", seed=1, workpiece_error=(0.0, 1.5, 0.0, 0.0, 0.0, 0.5)) as s:
        points = [(0.0, 0.0), *_jog_polyline()]
        points.append((points[-1][0] + 60.0, points[-1][1]))
        job = tracked(*points, velocity=250.0, z=_laser_z(s))
        truth = _laser_truth(s)
        log = _runner(s).run(job)
        (entry,) = [e for e in log if e.event == "tracked"]
        q = np.array([qq for qq, on in truth if on])
        err = _seam_error(s, q)
        assert not s.cell.robot.read_io("laser")[0]
    assert entry.detail["corrections"] == entry.detail["cycles"]  # one per cycle
    assert entry.detail["verdict"].startswith("WITHIN TOLERANCE 0.1 mm")  # the tracker's own
    welded = len(q) * 0.004 * 250.0
    assert welded == pytest.approx(points[-1][0], abs=3.0)  # the 15 deg legs add 0.4 mm
    assert err.max() <= 0.1


def test_tracked_job_that_loses_the_seam_stops_with_the_laser_off() -> None:
    # the workpiece turned by 6 deg: the seam walks off the path by 0.1 mm per mm until it
    # is beyond the robot's 10 mm correction range
    with EmulatedSession("straight", seed=2, workpiece_error=(0.0, 0.0, 0.0, 0.0, 0.0, 6.0)) as s:
        job = tracked((0.0, 0.0), (200.0, 0.0), velocity=250.0, z=_laser_z(s))
        truth = _laser_truth(s)
        with pytest.raises(JobAborted) as info:
            _runner(s).run(job)
        io = s.io_log
        status = s.robot.status()
        q_on = np.array([qq for qq, on in truth if on])
        err = _seam_error(s, q_on)
    assert info.value.reason == "seam lost" and "off the path" in info.value.message
    assert not status.moving and status.queue == 0
    laser = [(t, v) for t, name, v in io if name == "laser"]
    assert laser[-1][1] is False
    t_off = laser[-1][0]
    assert not any(on for t, on in laser if t > t_off)
    assert 0 < len(q_on) * 0.004 * 250.0 < 200.0  # welded part of the way, tracked well
    assert err.max() <= 0.1


def test_tracked_job_out_of_its_tolerance_aborts_with_the_verdict() -> None:
    """A tracked path whose own verdict is outside the tolerance (here a 2 µm one no weld
    meets) stops the job there, as a lost seam does: the later items do not run."""
    with EmulatedSession("straight", seed=3) as s:
        job = tracked((0.0, 0.0), (80.0, 0.0), velocity=250.0, z=_laser_z(s))
        runner = JobRunner(
            s.robot, s.tables, dwell=s.dwell, sensor_endpoint=s.cell.udp_address,
            real_time=False, tolerance_mm=0.002,
        )  # fmt: skip
        with pytest.raises(JobAborted) as info:
            runner.run(job)
        laser_on = s.cell.robot.read_io("laser")[0]
    assert info.value.reason == "out of tolerance"
    assert info.value.message.startswith("OUT OF TOLERANCE 0.002 mm: estimated error")
    (entry,) = [e for e in info.value.log if e.event == "tracked"]
    assert entry.detail["verdict"] == info.value.message
    assert not laser_on
    events = [e.event for e in info.value.log]
    after = events[events.index("tracked") + 1 :]
    assert after[0] == "abort" and set(after[1:]) == {"safe stop"}  # no later item ran
