"""Tool calibration: the least squares on exact geometry, refusals, the procedure on the
emulated cell (simulated clock), the command line and the effect on seam teaching."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kinematics.transforms import invert, location_to_transform, transform_to_location
from kinematics.types import Loc
from spec.params import Location, Matrix
from spec.registry import CommandId
from spec.wire import SensorStatus
from welding.calibrate_cli import NoisySeams
from welding.calibration import (
    CalibrationError,
    EmulatedSpotDetector,
    GaussianBeam,
    LaserObservation,
    LaserToolCalibration,
    Limits,
    SensorObservation,
    SensorToolCalibration,
    SpotMeasurement,
    error_vs_true,
    laser_plan,
    sensor_plan,
    solve_laser_tool,
    solve_sensor_tool,
    spot_on_plate,
)
from welding.cli import main
from welding.emulate import EmulatedSession, run_tracking
from welding.teach import SeamTeacher
from welding.tools import ToolDB

NOMINAL: Loc = (40.0, 0.0, 200.0, 0.0, 0.0, 0.0)
SEAM_POINT = np.array([570.0, 0.0, 15.0])
SEAM_DIR = np.array([1.0, 0.0, 0.0])

errors = st.tuples(
    *([st.floats(-5.0, 5.0)] * 3), *([st.floats(-3.0, 3.0)] * 3)
)  # the target range: 5 mm / 3 deg in every component


def _loc(v: object) -> Loc:
    a = [float(x) for x in np.asarray(v, dtype=np.float64)]
    return (a[0], a[1], a[2], a[3], a[4], a[5])


def _rot(axis: int, deg: float) -> np.ndarray:
    loc = [0.0] * 6
    loc[3 + axis] = deg
    return location_to_transform(loc)[:3, :3]


def _observations(
    error: Loc, rng: np.random.Generator, noise_mm: float, *, turn: bool = True
) -> list[SensorObservation]:
    """Exact geometry: the plan's poses commanded with the nominal tool over a straight
    seam along x_B, the laser plane of the true sensor cut with the seam line."""
    true_tool = location_to_transform(NOMINAL) @ location_to_transform(error)
    r0 = np.diag([1.0, -1.0, -1.0])  # x along the seam, z down
    out = []
    for yaw, pitch, roll, station, y, z in sensor_plan(30):
        R = r0 @ _rot(2, yaw) @ _rot(1, pitch) @ _rot(0, roll) if turn else r0
        pose = np.eye(4)
        pose[:3, :3] = R
        pose[:3, 3] = SEAM_POINT + station * SEAM_DIR - R @ np.array([0.0, y, z])
        flange = pose @ invert(location_to_transform(NOMINAL))
        sensor = flange @ true_tool
        n = sensor[:3, 0]
        t = -(n @ (SEAM_POINT - sensor[:3, 3])) / (n @ SEAM_DIR)
        p = (invert(sensor) @ np.append(SEAM_POINT + t * SEAM_DIR, 1.0))[:3]
        p[1:] += rng.normal(0.0, noise_mm, 2)
        out.append(SensorObservation(flange, p))
    return out


def _true(error: Loc) -> Loc:
    return _loc(
        transform_to_location(location_to_transform(NOMINAL) @ location_to_transform(error))
    )


@settings(max_examples=25, deadline=None)
@given(error=errors, seed=st.integers(0, 2**32 - 1))
def test_exact_geometry_recovers_any_error_in_range(error: Loc, seed: int) -> None:
    # 2.5 µm: 10 µm averaged over the procedure's 16 measurements per pose
    obs = _observations(error, np.random.default_rng(seed), 0.0025)
    est = solve_sensor_tool(obs, NOMINAL, direction=SEAM_DIR)
    e = error_vs_true(est.tool, _true(error))
    assert e["position_mm"] < 0.05 and e["orientation_deg"] < 0.05
    # The residual sees the noise that went in, but not all of it: the part along the seam
    # does not show, so its noise estimate is about 0.85 x 2.5 µm with an 11 % spread (60
    # residuals, 10 unknowns; 1500 seeds: 2.11 ± 0.23 µm, 1.28 to 2.86 µm). The bounds lie
    # 4.8 and 8 spreads away: a property test must not fail on an unlucky seed.
    assert 0.0010 < est.noise_mm < 0.0040


def test_without_noise_the_tool_is_exact() -> None:
    error = (3.0, -2.0, 4.0, 2.0, -1.5, 2.5)
    est = solve_sensor_tool(_observations(error, np.random.default_rng(0), 0.0), NOMINAL)
    e = error_vs_true(est.tool, _true(error))
    assert e["position_mm"] < 1e-6 and e["orientation_deg"] < 1e-6


def test_one_orientation_is_refused_as_degenerate() -> None:
    obs = _observations(
        (1.0, 1.0, 1.0, 1.0, 1.0, 1.0), np.random.default_rng(0), 0.0025, turn=False
    )
    with pytest.raises(CalibrationError, match="degenerate pose set"):
        solve_sensor_tool(obs, NOMINAL, direction=SEAM_DIR)


def test_too_few_observations_are_refused() -> None:
    obs = _observations(NOMINAL, np.random.default_rng(0), 0.0)[:5]
    with pytest.raises(CalibrationError, match="at least 6"):
        solve_sensor_tool(obs, NOMINAL)


def test_an_uncertain_result_is_refused() -> None:
    # 0.1 mm noise on single measurements: the rotations cannot be told to 0.0167 deg
    obs = _observations((1.0, 0.0, 0.0, 0.0, 0.0, 0.0), np.random.default_rng(0), 0.1)
    with pytest.raises(CalibrationError, match="uncertain by"):
        solve_sensor_tool(obs, NOMINAL, direction=SEAM_DIR, limits=Limits())


def _calibrate(session: EmulatedSession, seed: int) -> Loc:
    session.sensor.take_control()
    noisy = NoisySeams(session.sensor, 0.010, np.random.default_rng(seed))
    est = SensorToolCalibration(session.robot, noisy, session.cell.sensor_tool).run()
    assert est.poses <= 30
    return est.tool


def test_calibration_with_the_sensor_laser_off_says_so() -> None:
    # issue 35 item 1: not "the sensor does not see the seam at the start pose"
    with EmulatedSession(seed=3) as session:
        session.sensor.take_control()
        session.sensor.set_laser(False)
        noisy = NoisySeams(session.sensor, 0.010, np.random.default_rng(0))
        with pytest.raises(CalibrationError, match=r"^the sensor's laser is off .*SetLaser on"):
            SensorToolCalibration(session.robot, noisy, session.cell.sensor_tool).run()


@pytest.mark.slow  # three emulated calibrations
@settings(
    max_examples=3, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(error=errors)
def test_emulated_cell_recovers_random_tool_errors(error: Loc) -> None:
    with EmulatedSession(sensor_tool_error=error, seed=3) as session:
        tool = _calibrate(session, 3)
        e = error_vs_true(tool, session.cell.true_sensor_tool)
    assert e["position_mm"] < 0.05 and e["orientation_deg"] < 0.05


def _tracked_error(session: EmulatedSession, tool: Loc) -> float:
    """Largest error (mm) of the synchronised seam points (eq. 2-4, computed by the robot
    with ``tool`` as ^N_S T) over a 40 mm move along the seam: what seam tracking corrects
    the weld path to."""
    r = session.robot
    host, port = session.sensor.get_trigger_endpoint()
    r.call(CommandId.SET_SENSOR_ENDPOINT, host, port)
    r.call(CommandId.SET_SYNC_DELAY, float(session.cell.true_delta_t_s()))
    r.call(CommandId.SET_SENSOR_TOOL, Location(*tool))
    start = r.herej()
    here = location_to_transform(r.here(tool))
    end = here.copy()
    end[:3, 3] += 40.0 * here[:3, 0]
    (first,) = r.call(CommandId.START_TRIGGERS, 100.0, 0)
    r.tool_move_l(_loc(transform_to_location(end)), tool)
    assert r.wait_end_move(30.0)
    r.call(CommandId.STOP_TRIGGERS)
    assert isinstance(first, int)
    (m,) = r.call(CommandId.GET_SEAM_POINTS, first - 1)
    assert isinstance(m, Matrix)
    rows = np.array(m.values).reshape(m.rows, m.cols)
    rows = rows[rows[:, 3] == int(SensorStatus.FOUND)]
    assert len(rows) >= 20
    r.joint_move([float(q) for q in start])
    assert r.wait_end_move(30.0)
    return session.seam_error_mm([location_to_transform(row[11:17]) for row in rows[::2]])


def _taught_error(session: EmulatedSession, tool: Loc) -> float:
    start = session.robot.herej()
    points = SeamTeacher(session.robot, session.sensor, tool, max_length_mm=40.0).teach().points
    session.robot.joint_move([float(q) for q in start])
    assert session.robot.wait_end_move(30.0)
    return session.seam_error_mm([p.seam2base for p in points])


def test_calibration_corrects_teaching_and_tracking() -> None:
    """1 mm / 1 deg of sensor tool error: with the nominal tool the taught seam, the
    tracked seam points and the tracked weld (the laser against the true seam, the sine at
    250 mm/s) are off by more than the 0.1 mm budget; with the calibrated tool the taught
    seam is within 0.05 mm and the tracked points and the tracked weld within 0.1 mm (their
    own residual: 10 µm noise and the synchronisation)."""
    error = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    with EmulatedSession(sensor_tool_error=error, seed=5) as session:
        session.sensor.take_control()
        nominal = session.cell.sensor_tool
        before = _taught_error(session, nominal), _tracked_error(session, nominal)
        tool = _calibrate(session, 5)
        after = _taught_error(session, tool), _tracked_error(session, tool)
    assert min(before) > 0.1
    assert after[0] < 0.05
    assert after[1] < 0.1
    welds = [
        run_tracking("sine", 250.0, weld_mm=60.0, seed=3, sensor_tool_error=error, sensor_tool=t)
        for t in (None, tool)
    ]
    assert all(w.stopped == "" for w in welds)
    assert welds[0].tracking_error_max_mm > 1.0  # the weld follows the wrongly placed points
    assert welds[1].tracking_error_max_mm <= 0.1


def test_cli_writes_json_and_saves_the_tool(tmp_path: Path) -> None:
    out, db = tmp_path / "cal.json", tmp_path / "tools.json"
    argv = ["calibrate", "sensor-tool", "--emulate", "--tools", str(db), "--json", str(out)]
    argv += ["--sensor-tool-error", "2,-1,3,1,-2,0.5", "--save", "sensor_cal"]
    assert main(argv) == 0
    data = json.loads(out.read_text())
    assert data["poses"] <= 30
    assert set(data["uncertainty"]) == {"x", "y", "z", "rx", "ry", "rz"}
    assert data["error_vs_true"]["position_mm"] < 0.05
    assert data["error_vs_true"]["orientation_deg"] < 0.05
    saved = ToolDB(db).read().tool("sensor_cal")
    assert saved.kind == "sensor"
    assert np.allclose(saved.location, data["tool"], atol=1e-6)
    assert not math.isclose(saved.location[0], 40.0, abs_tol=1.0)


@pytest.mark.parametrize(
    ("extra", "message"), [(["--poses", "31"], "at most 30"), (["--seam", "sine"], "straight seam")]
)
def test_cli_refusals(
    extra: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["calibrate", "sensor-tool", "--emulate", "--tools", str(tmp_path / "t.json")]
    assert main([*argv, *extra]) == 1
    assert message in capsys.readouterr().err


@settings(
    max_examples=3, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(error=errors, seed=st.integers(0, 2**32 - 1))
def test_emulated_cell_recovers_random_laser_tool_errors(error: Loc, seed: int) -> None:
    with EmulatedSession(laser_tool_error=error, seed=seed % 1000) as session:
        detector = EmulatedSpotDetector(session.cell, np.random.default_rng(seed))
        est = LaserToolCalibration(session.robot, detector, session.cell.laser_tool).run()
        e = error_vs_true(est.tool, session.cell.true_laser_tool, beam_only=True)
    assert est.poses <= 30
    assert e["position_mm"] < 0.05 and e["orientation_deg"] < 0.05
    assert math.isnan(est.sigma[5])  # the roll about the beam is not found


def test_laser_poses_at_one_orientation_and_height_are_refused() -> None:
    laser = location_to_transform((0.0, 0.0, 200.0, 0.0, 0.0, 0.0))
    down = location_to_transform((0.0, 0.0, 0.0, 180.0, 0.0, 0.0))
    obs = []
    # the flange straight down at one height, moved across only: a tilt of the beam and an
    # offset of the focus move every spot alike
    for k in range(10):
        flange = location_to_transform((k % 3, k % 2, 210.0, 0.0, 0.0, 0.0)) @ down
        xy, s = spot_on_plate(flange @ laser, _Plate.plate2base)
        spot = SpotMeasurement(float(xy[0]), float(xy[1]), float(GaussianBeam().radius(s)))
        obs.append(LaserObservation(flange, spot))
    with pytest.raises(CalibrationError, match="degenerate pose set"):
        solve_laser_tool(obs, (0.0, 0.0, 200.0, 0.0, 0.0, 0.0), _Plate())


def test_cli_laser_tool_needs_the_emulated_detector(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["calibrate", "laser-tool", "--robot", "127.0.0.1:1", "--tools", str(tmp_path / "t")]
    assert main(argv) == 1
    assert "spot detector" in capsys.readouterr().err


class _Plate:
    """A spot detector on exact geometry: the plate z = 0 of base, readings with noise."""

    plate2base = np.eye(4)
    beam = GaussianBeam()
    sigma_centre_mm = sigma_radius_mm = 0.005

    def measure(self) -> SpotMeasurement:
        raise AssertionError("the observations are made by the test")


@settings(max_examples=20, deadline=None)
@given(error=errors, seed=st.integers(0, 2**32 - 1))
def test_laser_exact_geometry_recovers_any_error_in_range(error: Loc, seed: int) -> None:
    rng = np.random.default_rng(seed)
    nominal: Loc = (0.0, 0.0, 200.0, 0.0, 0.0, 0.0)
    n_tool = location_to_transform(nominal)
    true_tool = n_tool @ location_to_transform(error)
    r0 = np.diag([1.0, -1.0, -1.0])  # the beam down into the plate
    obs = []
    for yaw, pitch, roll, s, x, y in laser_plan(30):
        R = r0 @ _rot(2, yaw) @ _rot(1, pitch) @ _rot(0, roll)
        pose = np.eye(4)
        pose[:3, :3] = R
        pose[:3, 3] = np.array([x, y, 0.0]) - s / abs(R[2, 2]) * R[:, 2]
        flange = pose @ invert(n_tool)
        xy, dist = spot_on_plate(flange @ true_tool, _Plate.plate2base)
        # 16 readings averaged: 5 µm / 4
        nx, ny, nr = rng.normal(0.0, 0.00125, 3)
        spot = SpotMeasurement(
            float(xy[0] + nx), float(xy[1] + ny), float(GaussianBeam().radius(dist) + nr)
        )
        obs.append(LaserObservation(flange, spot))
    plate = _Plate()
    plate.sigma_centre_mm = plate.sigma_radius_mm = 0.00125
    est = solve_laser_tool(obs, nominal, plate)
    true = _loc(transform_to_location(true_tool))
    e = error_vs_true(est.tool, true, beam_only=True)
    assert e["position_mm"] < 0.05 and e["orientation_deg"] < 0.05
