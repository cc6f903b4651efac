"""Scene model: joints, seam paths, truth seam frames and pose providers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensorsocket.scene import (
    JogPath,
    Joint,
    JointType,
    Scene,
    SceneError,
    SeamPath,
    fixed_pose,
    invert_transforms,
    scripted_pose,
)


def _pose(rx: float, ry: float, rz: float, t: tuple[float, float, float]) -> np.ndarray:
    def r(axis: int, a: float) -> np.ndarray:
        c, s = math.cos(a), math.sin(a)
        m = np.eye(3)
        i, j = [k for k in range(3) if k != axis]
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    out = np.eye(4)
    out[:3, :3] = r(0, rx) @ r(1, ry) @ r(2, rz)
    out[:3, 3] = t
    return out


def test_paper_sine_min_radius_is_32_mm() -> None:
    # paper section VI: y = 2 sin(2π·5x/250), minimum radius of curvature ≈ 32 mm
    assert SeamPath.paper_sine().min_radius_mm() == pytest.approx(31.66, abs=0.01)
    x = np.array([12.5, 37.5])
    np.testing.assert_allclose(SeamPath.paper_sine().y(x), [2.0, -2.0], atol=1e-12)


@pytest.mark.parametrize("kind", list(JointType))
@pytest.mark.parametrize("path", [SeamPath.straight(), SeamPath.paper_sine()])
def test_sensor_over_seam_places_the_seam_where_asked(kind: JointType, path: SeamPath) -> None:
    workpiece = _pose(0.1, -0.2, 0.7, (400.0, -50.0, 30.0))
    scene = Scene(Joint(kind), path, workpiece)
    for x, y, z, roll in [(0.0, 0.0, 0.0, 0.0), (12.5, 1.5, -2.0, 5.0), (31.0, -3.0, 1.0, -8.0)]:
        pose = scene.sensor_over_seam(x, seam_y_mm=y, seam_z_mm=z, roll_deg=roll)
        truth = scene.seam2sensor(pose[None])[0]
        np.testing.assert_allclose(truth[:3, 3], [0.0, y, z], atol=1e-9)
        # independent check: the seam point in the base frame lies on the seam curve
        p_b = pose @ truth[:, 3]
        p_w = invert_transforms(workpiece) @ p_b
        assert p_w[1] == pytest.approx(float(path.y(np.array(p_w[0]))), abs=1e-9)
        assert p_w[2] == pytest.approx(scene.joint.seam_height_mm, abs=1e-9)
        # roll about x_S shows as the seam frame's rotation about x
        assert math.degrees(math.atan2(truth[2, 1], truth[1, 1])) == pytest.approx(-roll)


def test_joint_validation() -> None:
    with pytest.raises(SceneError):
        Joint.butt(gap_mm=-1)
    with pytest.raises(SceneError):
        Joint.fillet(opening_deg=5)
    with pytest.raises(SceneError):
        Joint.lap(thickness_mm=0)
    with pytest.raises(SceneError):
        Scene(Joint.butt(), workpiece2base=np.ones((4, 4)))
    with pytest.raises(SceneError):
        fixed_pose(np.eye(3))


def test_joint_profiles() -> None:
    lap = Joint.lap(2.0, upper_side=1).pieces()
    assert [(p.a, p.b) for p in lap] == [(0.0, 0.0), (2.0, 0.0)]
    fillet = Joint.fillet(90.0).pieces()
    assert fillet[0].b == pytest.approx(-1.0) and fillet[1].b == pytest.approx(1.0)
    butt = Joint.butt(0.4, mismatch_mm=0.2)
    assert butt.pieces()[0].hi == pytest.approx(-0.2) and butt.seam_height_mm == 0.1


def test_fixed_and_scripted_poses() -> None:
    start = _pose(math.pi, 0.0, 0.3, (10.0, 20.0, 30.0))
    times = np.linspace(0.0, 2.0, 41)
    fixed = fixed_pose(start)(times)
    assert fixed.shape == (41, 4, 4)
    np.testing.assert_array_equal(fixed[17], start)
    moving = scripted_pose(
        start,
        velocity_mm_s=(250.0, 0.0, 0.0),
        sine_amplitude_mm=2.0,
        sine_frequency_hz=1.5,
        t0_s=0.5,
    )(times)
    dt = times - 0.5
    y_axis = start[:3, 1]
    expected = start[:3, 3] + dt[:, None] * [250.0, 0.0, 0.0]
    expected += (2.0 * np.sin(2 * np.pi * 1.5 * dt))[:, None] * y_axis
    np.testing.assert_allclose(moving[:, :3, 3], expected, atol=1e-9)
    np.testing.assert_array_equal(moving[:, :3, :3], np.broadcast_to(start[:3, :3], (41, 3, 3)))


@settings(max_examples=100, deadline=None)
@given(
    st.floats(-3, 3),
    st.floats(-3, 3),
    st.floats(-3, 3),
    st.tuples(st.floats(-500, 500), st.floats(-500, 500), st.floats(-500, 500)),
)
def test_invert_transforms_round_trip(
    rx: float, ry: float, rz: float, t: tuple[float, float, float]
) -> None:
    m = _pose(rx, ry, rz, t)
    np.testing.assert_allclose(invert_transforms(m) @ m, np.eye(4), atol=1e-9)


def test_corner_path_has_two_straight_legs_at_90_degrees() -> None:
    from sensorsocket.scene import CornerPath

    path = CornerPath(corner_x_mm=30.0)
    x = np.array([0.0, 20.0, 30.0, 40.0])
    np.testing.assert_allclose(path.y(x), [0.0, 20.0, 30.0, 20.0])
    legs = np.array([[1.0, s] for s in path.slope(np.array([10.0, 50.0]))])
    assert legs[0] @ legs[1] == 0.0  # perpendicular
    # lateral: the distance to the leg on the same side of the corner
    assert path.lateral(np.array([10.0]), np.array([12.0]))[0] == pytest.approx(math.sqrt(2))
    assert path.lateral(np.array([50.0]), np.array([12.0]))[0] == pytest.approx(math.sqrt(2))
    scene = Scene(Joint.butt(), path, _pose(0.1, -0.2, 0.7, (400.0, -50.0, 30.0)))
    for station in (12.5, 45.0):
        truth = scene.seam2sensor(scene.sensor_over_seam(station, seam_y_mm=1.0)[None])[0]
        np.testing.assert_allclose(truth[:3, 3], [0.0, 1.0, 0.0], atol=1e-9)


def test_jog_path_is_continuous_with_its_slope_and_radius() -> None:
    jog = JogPath()
    x = np.linspace(0.0, 100.0, 100_001)
    y = jog.y(x)
    assert np.abs(np.diff(y)).max() < 1e-3  # no step anywhere
    assert np.allclose(np.gradient(y, x)[1:-1], jog.slope(x)[1:-1], atol=2e-3)
    assert y[0] == 0.0 and y[-1] == pytest.approx(jog.offset_mm)
    assert 4.0 < jog.offset_mm < 6.0 and jog.min_radius_mm() == 32.0
