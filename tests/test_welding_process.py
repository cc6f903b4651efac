"""Job processing: the plan (pure) and runs on the emulated cell, checked against the
robot emulator's I/O log and its setpoints: the laser is never on off a welding path, and
every abort switches the laser off first."""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from kinematics.transforms import invert, location_to_transform
from welding import job as J
from welding.emulate import EmulatedSession
from welding.process import (
    Dwell,
    JobAborted,
    JobRunner,
    MoveL,
    Output,
    PlanError,
    arc_points,
    plan,
)
from welding.tools import Tables, ToolDBError

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
    return np.minimum(np.minimum(d_line, d_arc), d_spot)


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
    for (l0, l1), (g0, g1), (c0, c1), item in zip(lasers, gases, jets, (SEAM, SPOT), strict=True):
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
    real_wait = robot.wait_end_move
    stopped_at: list[float] = []

    def wait(timeout: float = 60.0) -> bool:
        if robot.read_io("laser"):
            real_wait(1.0)
            stopped_at.append(robot.get_time())
            if isinstance(exc, ConnectionError):
                assert robot._sock is not None
                robot._sock.shutdown(socket.SHUT_RDWR)
                return real_wait(timeout)
            raise exc
        return real_wait(timeout)

    robot.wait_end_move = wait  # type: ignore[method-assign]
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
    real_wait = robot.wait_end_move
    runner = JobRunner(robot, session.tables, dwell=session.dwell, poll=0.1)
    pieces: list[float] = []
    cancelled_at: list[int] = []

    def wait(timeout: float = 60.0) -> bool:
        pieces.append(timeout)
        if robot.read_io("laser") and not runner.cancelled:
            # the operator's abort arrives from another thread during the seam
            t = threading.Thread(target=runner.cancel)
            t.start()
            t.join()
            cancelled_at.append(len(pieces))
        return real_wait(timeout)

    robot.wait_end_move = wait  # type: ignore[method-assign]
    with pytest.raises(JobAborted) as info:
        runner.run(JOB)
    assert info.value.reason == "cancelled"
    # the wait goes in pieces: the abort is seen after the piece it came in, mid-seam
    assert max(pieces) == 0.1 and cancelled_at == [len(pieces)]
    assert [e.item for e in info.value.log if e.event == "abort"] == ["seam"]
    check_stopped_safely(session, info.value)


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
