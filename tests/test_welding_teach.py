"""Seam teaching on the emulated cell (simulated clock, fixed seeds) and its pure parts."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from welding import job as J
from welding.emulate import EmulatedSession
from welding.process import JobRunner
from welding.teach import (
    SeamTeacher,
    TeachError,
    TeachResult,
    _closest_between_lines,
    _predict,
    record_here,
    seam_path,
)


def test_prediction_follows_a_curve_and_is_exact_on_a_line() -> None:
    def f(s: float) -> np.ndarray:
        return np.array([s, 0.01 * s * s, 0.0])

    p, t = _predict([f(0), f(5), f(10)], 5.0, np.array([1.0, 0, 0]))
    assert abs(p[1] - 0.01 * p[0] ** 2) < 0.02  # on the curve, a step further
    assert 14.5 < p[0] < 15.0
    slope = 0.02 * p[0]
    assert math.degrees(math.acos(t @ (np.array([1, slope, 0]) / np.hypot(1, slope)))) < 0.5
    p, t = _predict([np.zeros(3), np.array([1.0, 1.0, 0])], math.sqrt(2), np.array([1.0, 0, 0]))
    np.testing.assert_allclose(p, [2, 2, 0])
    np.testing.assert_allclose(t, [math.sqrt(0.5), math.sqrt(0.5), 0])


def test_corner_is_where_the_legs_meet() -> None:
    c = _closest_between_lines(
        np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([5.0, 3, 0]), np.array([5.0, 4, 0])
    )
    np.testing.assert_allclose(c, [5, 0, 0], atol=1e-12)
    with pytest.raises(TeachError, match="parallel"):
        a0, a1, b0, b1 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
        _closest_between_lines(a0, a1, b0, b1)


@pytest.fixture(params=["straight", "sine", "corner"])
def taught(request: pytest.FixtureRequest) -> Iterator[tuple[EmulatedSession, TeachResult]]:
    with EmulatedSession(request.param, seed=3) as s:
        s.sensor.take_control()
        teacher = SeamTeacher(s.robot, s.sensor, s.tables.tool("sensor").location,
                              step_mm=5.0, max_length_mm=80.0)  # fmt: skip
        yield s, teacher.teach()


def test_taught_seam_matches_the_true_seam(taught: tuple[EmulatedSession, TeachResult]) -> None:
    session, result = taught
    assert session.seam_error_mm([q.seam2base for q in result.points]) < 0.05
    assert result.stop_reason == "length reached"
    assert 75.0 <= result.length_mm <= 80.0
    corners = [q for q in result.points if q.corner]
    if session.cell.seam == "corner":
        assert len(corners) == 1
        apex = (session.cell.scene.base2workpiece @ corners[0].seam2base)[:3, 3]
        assert np.linalg.norm(apex - [30.0, 30.0, 0.0]) < 0.05
    else:
        assert corners == []
    assert 0 < result.seconds_per_point < 1.0  # robot clock: moves of 5 mm at 50 mm/s


def test_taught_seam_becomes_a_job_that_runs_on_the_seam(
    taught: tuple[EmulatedSession, TeachResult],
) -> None:
    session, result = taught
    path = seam_path(result, "taught", tool="laser", frame="workpiece", tables=session.tables,
                     velocity=20.0, preflow=0.2, postflow=0.2)  # fmt: skip
    job = J.loads(J.dumps(J.Job("taught", (path,))), has_tool=session.tables.has_tool,
                  has_frame=session.tables.has_frame)  # fmt: skip
    assert job.item("taught") == path
    arcs = sum(isinstance(s, J.Arc) for s in path.segments)
    assert arcs > 0 if session.cell.seam == "sine" else arcs == 0
    JobRunner(session.robot, session.tables, dwell=session.dwell).run(job)
    on = [t for t, n, v in session.io_log if n == "laser"]
    assert len(on) == 3  # off at the start, on, off


def test_teaching_refuses_to_start_without_a_seam_in_view() -> None:
    with EmulatedSession("straight") as s:
        s.sensor.take_control()
        sensor_tool = s.tables.tool("sensor").location
        x, y, z, rx, ry, rz = s.robot.here(sensor_tool)
        s.robot.tool_move_l((x, y + 40.0, z, rx, ry, rz), sensor_tool)
        s.robot.wait_end_move(10.0)
        with pytest.raises(TeachError, match="does not see a seam"):
            SeamTeacher(s.robot, s.sensor, sensor_tool).teach()


def test_teaching_with_the_sensor_laser_off_says_so_not_no_seam() -> None:
    # issue 35 item 1: a laser left off by a controlled stop read as "does not see a seam"
    with EmulatedSession("straight") as s:
        s.sensor.take_control()
        s.sensor.set_laser(False)
        with pytest.raises(TeachError) as err:
            SeamTeacher(s.robot, s.sensor, s.tables.tool("sensor").location).teach()
        assert str(err.value) == (
            "the sensor's laser is off (status LASER_OFF): switch it on with "
            f"`python -m sensorsocket call {s.sensor.address} SetLaser on --token-file FILE`"
        )


def test_manual_teaching_records_the_current_location() -> None:
    with EmulatedSession("straight") as s:
        loc = record_here(s.robot, s.tables, "laser", "workpiece")
        assert (loc.tool, loc.frame) == ("laser", "workpiece")
        assert loc.x == pytest.approx(-40.0, abs=1e-6) and loc.z == pytest.approx(0.0, abs=1e-6)


def test_teaching_stops_where_the_seam_leaves_the_field_of_view() -> None:
    with EmulatedSession("corner", seed=1) as s:
        s.sensor.take_control()
        teacher = SeamTeacher(s.robot, s.sensor, s.tables.tool("sensor").location, corners=False)
        result = teacher.teach()
        assert result.stop_reason == "seam left the field of view"
        # the last point is on the first leg, the halved steps took it within 1 mm of the
        # corner (near the apex the laser line also crosses the second leg)
        last = (s.cell.scene.base2workpiece @ result.points[-1].seam2base)[:3, 3]
        assert last[0] < 30.0 and np.linalg.norm(last[:2] - [30.0, 30.0]) < 1.0
        assert s.seam_error_mm([q.seam2base for q in result.points]) < 0.05
