"""What the seam sensor tells the ILC: the laser went where the sensor went only where the
tool did not turn (:func:`welding.ilc.lever_error` against the arm simulated plainly), a
tracked weld does not take the arm's repeatable error at the sensor for the workpiece's
(:attr:`welding.tracking.Tracker.expected`), the table keeps it, and the run-up's setting."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from kinematics import get_model, location_to_transform
from kinematics.dynamics import RX90B, link_inertia, simulate
from welding.ilc import IlcTable, lever_error
from welding.ilc_loop import IlcSettings
from welding.tracking import NominalWeld, OffsetWeld, Tracker

PERIOD = 0.004
LASER = location_to_transform(np.array([0.0, 0.0, 250.0, 0.0, 0.0, 0.0]))
SENSOR = location_to_transform(np.array([40.0, 0.0, 230.0, 0.0, 0.0, 0.0]))


def _commanded(n: int, swing_deg: float) -> np.ndarray:
    """Joints (n + 1, 6) deg: every axis swung by a smooth start-stop of ``swing_deg``."""
    q0 = np.array([0.0, 30.0, 100.0, 0.0, 50.0, 0.0])
    x = np.linspace(0.0, 1.0, n + 1)
    shape = swing_deg * (x - np.sin(2 * math.pi * x) / (2 * math.pi))
    out: np.ndarray = q0 + shape[:, None] * np.array([1.0, 0.5, -0.5, 1.0, 1.0, 1.0])
    return out


def test_lever_error_is_the_laser_error_less_the_sensors() -> None:
    """Against the arm simulated plainly: the laser's and the sensor's points through the
    link side and through the command, their errors subtracted. An accelerating wrist turns
    the tool, so the two differ by more than the sensor's noise; an arm that stands still
    has no lever error."""
    model = get_model("RX90B")
    n = 60
    q = _commanded(n, 3.0)
    got = lever_error(RX90B, model, q, LASER, SENSOR, PERIOD)
    jl = np.array([link_inertia(model, qk, RX90B) for qk in q[1:]])
    _, link = simulate(RX90B, jl, np.radians(q), period=PERIOD)
    real = model.flange2base_batch(np.degrees(link))
    cmd = model.flange2base_batch(q[1:])
    laser_error = (real @ LASER)[:, :3, 3] - (cmd @ LASER)[:, :3, 3]
    sensor_error = (real @ SENSOR)[:, :3, 3] - (cmd @ SENSOR)[:, :3, 3]
    np.testing.assert_allclose(got, laser_error - sensor_error, atol=1e-9)
    assert np.abs(got).max() > 0.01  # mm: the sensor's noise is 10 µm
    standing = lever_error(RX90B, model, _commanded(n, 0.0), LASER, SENSOR, PERIOD)
    assert np.abs(standing).max() < 1e-9


def _line() -> NominalWeld:
    return NominalWeld(
        start=np.zeros(3),
        direction=np.array([1.0, 0.0, 0.0]),
        angles=np.zeros(3),
        length_mm=100.0,
        speed_mm_s=100.0,
    )


def _rows(lateral: float) -> np.ndarray:
    s = np.arange(0.0, 100.5, 0.5)
    return np.column_stack([s, np.zeros_like(s), np.full_like(s, lateral), np.zeros_like(s)])


def test_a_tracker_takes_the_seam_as_the_arm_sees_it_for_the_taught_one() -> None:
    """Taught 0.3 mm to the side; this arm's sensor, with the table, sees that seam 0.05 mm
    further (its repeatable error where it looks). Readings on that seen seam are the taught
    workpiece: the correction is the taught offset. Without ``expected`` the tracker would
    add the arm's 0.05 mm as the workpiece's; a workpiece really 0.1 mm further is followed."""
    weld = _line()
    taught, seen = OffsetWeld(weld, _rows(0.3)), OffsetWeld(weld, _rows(0.35))
    s = np.arange(10.0, 90.0, 1.25)
    for extra, want in ((0.0, 0.3), (0.1, 0.4)):
        with_seen = Tracker(weld, 40.0, fit_half_width_mm=25.0, taught=taught, expected=seen)
        plain = Tracker(weld, 40.0, fit_half_width_mm=25.0, taught=taught)
        points = seen.point(s) + np.array([0.0, extra, 0.0])
        for t in (with_seen, plain):
            t.model.add(points)
        assert with_seen.correction_at(50.0)[1] == pytest.approx(want, abs=1e-9)
        assert plain.correction_at(50.0)[1] == pytest.approx(want + 0.05, abs=1e-9)


def test_a_table_keeps_what_the_sensor_saw_and_an_older_one_still_loads(tmp_path: Path) -> None:
    seam = np.array([[0.0, 1, 2, 3], [1.0, 2, 3, 4]])
    seen = np.array([[0.0, 0.0, 0.01, 0.0], [1.0, 0.0, 0.02, 0.0]])
    t = IlcTable(0.004, 250.0, np.ones((4, 3)), seam, "seam", 3, "", seen)
    path = tmp_path / "t.json"
    t.save(path)
    np.testing.assert_array_equal(IlcTable.load(path).seen, seen)
    data = json.loads(path.read_text())
    del data["seen"]  # a table written before the field existed
    path.write_text(json.dumps(data))
    assert IlcTable.load(path).seen.shape == (0, 4)
    data["seen"] = [[1.0, 0, 0, 0], [0.0, 0, 0, 0]]  # arc lengths must increase
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="not an ILC table"):
        IlcTable.load(path)


def test_a_negative_run_up_is_refused() -> None:
    with pytest.raises(ValueError, match=r"run-up must be 0\.\.500 mm"):
        IlcSettings(run_up_mm=-1.0).check()
