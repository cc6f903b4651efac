"""The camera geometry: the one calibration the renderer, the detector and the cell use."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from sensorsocket.geometry import CameraError, CameraGeometry

CAM = CameraGeometry()


def test_documented_field_of_view() -> None:
    fov = CAM.field_of_view()
    assert fov["width_mm"] == pytest.approx(20.48, abs=0.01)
    assert fov["depth_mm"] == pytest.approx(14.6, abs=0.1)
    assert fov["z_min_mm"] < 0 < fov["z_max_mm"]
    assert CAM.baseline_mm == pytest.approx(64 * np.sin(np.radians(45)))
    # the optical axis meets the laser plane at the sensor-frame origin (image centre)
    np.testing.assert_allclose(CAM.pixel_to_sensor(np.array(255.5), np.array(127.5)), 0, atol=1e-12)


def test_triangulation_by_hand() -> None:
    # a point at depth z on the laser line under the camera: the pinhole at
    # (-D sinθ, 0, -D cosθ) sees it at angle atan(z sinθ / (D + z cosθ)) off axis
    z = 3.0
    d, th = 64.0, np.radians(45.0)
    u, v = CAM.project(np.array([0.0, 0.0, z]))
    expected = 127.5 + 1600.0 * (z * np.sin(th)) / (d + z * np.cos(th))
    assert float(u) == pytest.approx(255.5)
    assert float(v) == pytest.approx(expected)


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.5, 511.5), st.floats(-0.5, 255.5))
def test_pixel_to_sensor_round_trip(u: float, v: float) -> None:
    p = CAM.pixel_to_sensor(np.array(u), np.array(v))
    assert float(p[0]) == 0.0
    uu, vv = CAM.project(p)
    assert float(uu) == pytest.approx(u, abs=1e-9)
    assert float(vv) == pytest.approx(v, abs=1e-9)


def test_bad_geometry_is_a_clear_error() -> None:
    for kw in ({"columns": 4}, {"triangulation_angle_deg": 90.0}, {"focal_length_mm": -1.0}):
        with pytest.raises(CameraError):
            CameraGeometry(**kw)


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.5, 511.5), st.floats(-0.5, 255.5))
def test_floats_and_arrays_give_the_same_bits(u: float, v: float) -> None:
    """Each formula runs on plain floats (the detector's few points) and on arrays (the
    profile, the renderer): the same operations, so the same values to the last bit."""
    y, z = CAM.plane_point(u, v)
    ya, za = CAM.plane_point(np.array([u]), np.array([v]))
    assert (y, z) == (ya[0], za[0])
    assert CAM.plane_column(y, z) == CAM.plane_column(ya, za)[0]
    a, b = z - 0.1 * y, 0.1
    assert CAM.line_point(u, a, b) == tuple(x[0] for x in CAM.line_point(*_arrays(u, a, b)))
    assert CAM.line_row(u, a, b) == CAM.line_row(*_arrays(u, a, b))[0]


def _arrays(*x: float) -> list[np.ndarray]:
    return [np.array([v]) for v in x]


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.5, 511.5), st.floats(-0.5, 255.5), st.floats(-1.0, 1.0))
def test_line_row_is_the_row_of_the_line_point(u: float, v: float, b: float) -> None:
    """The profile line z = a + b·y through the point seen at (u, v) is seen there: its
    point on column u is that point and its row is v (and project agrees)."""
    y, z = CAM.plane_point(u, v)
    a = z - b * y
    yl, zl = CAM.line_point(u, a, b)
    assert yl == pytest.approx(y, abs=1e-9) and zl == pytest.approx(z, abs=1e-9)
    assert CAM.line_row(u, a, b) == pytest.approx(v, abs=1e-9)
    uu, vv = CAM.project(np.array([0.0, yl, zl]))
    assert float(vv) == pytest.approx(v, abs=1e-9)
    # the seam's column is project's u to the last bit (the cell times the seam with it)
    assert CAM.plane_column(yl, zl) == float(uu)


def test_no_point_where_the_ray_is_parallel() -> None:
    """A profile line along column u's ray has no single point there: NaN, no exception
    (floats) and no warning (arrays)."""
    u = 383.5  # k = 1/12.5: the line of the column's rays has slope b = 1 / (k cos θ)
    k = (u - CAM.principal_point[0]) / CAM.focal_px
    b_par = 1.0 / (k * math.cos(math.radians(45.0)))
    assert math.isnan(CAM.line_point(u, 0.0, b_par)[0])
    assert math.isnan(CAM.line_row(u, 0.0, b_par))
    with np.errstate(all="raise"):
        assert np.isnan(CAM.line_point(np.array([u]), np.array([0.0]), np.array([b_par]))[0][0])
    # the camera centre's depth: no column
    g = CameraGeometry(triangulation_angle_deg=5.0)
    z = -g.working_distance_mm / math.cos(math.radians(5.0))
    assert g.working_distance_mm + z * math.cos(math.radians(5.0)) == 0.0  # exactly there
    assert math.isnan(g.plane_column(1.0, z))


def _plane_point_two_steps(g: CameraGeometry, u: float, v: float) -> tuple[float, float]:
    """The textbook ray-plane intersection (the docstring's first form), plain floats."""
    s, c = (
        math.sin(math.radians(g.triangulation_angle_deg)),
        math.cos(math.radians(g.triangulation_angle_deg)),
    )
    d = g.working_distance_mm
    k = (u - g.principal_point[0]) / g.focal_px
    t = (v - g.principal_point[1]) / g.focal_px
    z = t * d / (s - t * c)
    return k * (d + z * c), z


@settings(max_examples=300, deadline=None)
@given(
    st.floats(-0.5, 511.5),
    st.floats(-8.5, 263.5),
    st.sampled_from([45.0, 5.0, 30.0, 85.0]),
    st.sampled_from([16.0, 4.0]),
)
def test_plane_point_closed_form_equals_the_ray_intersection(
    u: float, v: float, angle: float, focal: float
) -> None:
    """plane_point's one-division closed form against the two-step intersection: within
    1e-12 mm on the default geometry, 1e-9 relative on others (up to far beyond the
    chip, where points lie metres away)."""
    g = CameraGeometry(triangulation_angle_deg=angle, focal_length_mm=focal)
    v1 = g.principal_point[1] + g.focal_px * math.tan(math.radians(angle))
    assume(abs(v - v1) > 0.01)  # both forms lose digits right next to the parallel ray
    y, z = g.plane_point(u, v)
    y0, z0 = _plane_point_two_steps(g, u, v)
    default = angle == 45.0 and focal == 16.0
    tol = 1e-12 if default else 1e-9 * max(1.0, abs(y0), abs(z0))
    assert abs(y - y0) <= tol and abs(z - z0) <= tol
    ya, za = g.plane_point(np.array([float(round(u))]), np.array([v]))
    assert (ya[0], za[0]) == g.plane_point(float(round(u)), v)


def test_plane_point_nan_where_the_ray_is_parallel_to_the_plane() -> None:
    """The row whose rays run parallel to the laser plane has no point: NaN, no exception
    (floats) and no warning (arrays), as in the two-step form."""
    g = CameraGeometry(triangulation_angle_deg=5.0, focal_length_mm=4.0)
    v1 = g.principal_point[1] + g.focal_px * math.tan(math.radians(5.0))
    y, z = g.plane_point(10.0, v1)
    assert math.isnan(y) and math.isnan(z)
    with np.errstate(all="raise"):
        ya, za = g.plane_point(np.array([10, 20]), np.array([v1, 3.0]))
    assert np.isnan(ya[0]) and np.isnan(za[0]) and np.isfinite(ya[1]) and np.isfinite(za[1])
