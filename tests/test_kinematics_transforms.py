"""Transforms, VAL3 locations, quaternions, rotation vectors and interpolation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics import transforms as tf
from kinematics.errors import KinematicsError

SETTINGS = settings(max_examples=200, deadline=None, derandomize=True)


def rx(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


angle = st.floats(-180.0, 180.0)
pos = st.floats(-2000.0, 2000.0)
location = st.tuples(pos, pos, pos, angle, st.floats(-89.0, 89.0), angle)


def test_location_is_rx_ry_rz_product() -> None:
    T = tf.location_to_transform([10.0, -20.0, 30.0, 30.0, 45.0, -60.0])
    np.testing.assert_allclose(T[:3, :3], rx(30) @ ry(45) @ rz(-60), atol=1e-15)
    np.testing.assert_allclose(T[:3, 3], [10.0, -20.0, 30.0])
    np.testing.assert_allclose(T[3], [0, 0, 0, 1])


def test_tool_pointing_down_location() -> None:
    # A flange pointing down, x kept along base x: Ry(180) -> (rx, ry, rz) = (180, 0, 180)
    # or equivalently (0, 180, 0) with ry folded into [-90, 90].
    T = np.eye(4)
    T[:3, :3] = ry(180)
    loc = tf.transform_to_location(T)
    np.testing.assert_allclose(tf.location_to_transform(loc), T, atol=1e-12)
    assert -90.0 <= loc[4] <= 90.0
    assert abs(abs(loc[3]) - 180.0) < 1e-9 and abs(abs(loc[5]) - 180.0) < 1e-9


@SETTINGS
@given(location)
def test_location_round_trip(loc: tuple[float, ...]) -> None:
    T = tf.location_to_transform(loc)
    back = tf.transform_to_location(T)
    np.testing.assert_allclose(back[:3], loc[:3], atol=1e-9)
    # Angles: compare as rotations (±180 are the same angle).
    np.testing.assert_allclose(tf.location_to_transform(back), T, atol=1e-12)
    d = (back[3:] - np.array(loc[3:]) + 180.0) % 360.0 - 180.0
    np.testing.assert_allclose(d, 0.0, atol=1e-7)


@SETTINGS
@given(st.tuples(pos, pos, pos, angle, st.sampled_from([90.0, -90.0]), angle))
def test_gimbal_lock_reproduces_the_rotation(loc: tuple[float, ...]) -> None:
    T = tf.location_to_transform(loc)
    back = tf.transform_to_location(T)
    np.testing.assert_allclose(tf.location_to_transform(back), T, atol=1e-9)


def test_batch_locations_equal_single() -> None:
    rng = np.random.default_rng(7)
    locs = np.column_stack([rng.uniform(-1000, 1000, (50, 3)), rng.uniform(-180, 180, (50, 3))])
    Ts = tf.locations_to_transforms(locs)
    assert Ts.shape == (50, 4, 4)
    for loc, T in zip(locs, Ts, strict=True):
        np.testing.assert_allclose(T, tf.location_to_transform(loc), atol=1e-12)
    back = tf.transforms_to_locations(Ts)
    for T, b in zip(Ts, back, strict=True):
        np.testing.assert_allclose(b, tf.transform_to_location(T), atol=1e-12)


def test_single_location_bit_equal_to_batch() -> None:
    # the scalar form must give the batch form's numbers exactly (same checks, same float
    # steps), also at the gimbal lock and at multiples of 90 degrees
    rng = np.random.default_rng(11)
    locs = np.column_stack([rng.uniform(-1000, 1000, (600, 3)), rng.uniform(-180, 180, (600, 3))])
    locs[::5, 4] = 90.0
    locs[1::5, 4] = -90.0
    locs[2::5, 3:] = np.round(locs[2::5, 3:] / 90.0) * 90.0
    Ts = tf.locations_to_transforms(locs)
    batch = tf.transforms_to_locations(Ts)
    for T, b in zip(Ts, batch, strict=True):
        assert np.array_equal(tf.transform_to_location(T), b)


@pytest.mark.parametrize(
    "bad",
    [
        np.eye(3),
        np.eye(4)[None],
        np.diag([1.0, 1.0, 1.1, 1.0]),
        np.diag([1.0, 1.0, -1.0, 1.0]),
        np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0.5, 1.0]]),
        np.full((4, 4), np.nan),
    ],
)
def test_single_location_rejects_what_the_batch_rejects(bad: np.ndarray) -> None:
    with pytest.raises(KinematicsError):
        tf.transform_to_location(bad)


def test_invert_and_concat() -> None:
    A = tf.location_to_transform([100, 200, 300, 10, 20, 30])
    B = tf.location_to_transform([-5, 7, 11, -40, 50, 60])
    np.testing.assert_allclose(tf.concat(A, tf.invert(A)), np.eye(4), atol=1e-12)
    np.testing.assert_allclose(tf.concat(A, B), A @ B)
    np.testing.assert_allclose(tf.invert(tf.concat(A, B)), tf.concat(tf.invert(B), tf.invert(A)))
    # A point 10 mm along the flange z, seen from the base.
    p = tf.concat(A, tf.location_to_transform([0, 0, 10, 0, 0, 0]))[:3, 3]
    np.testing.assert_allclose(p, A[:3, 3] + 10 * A[:3, 2])
    batch = tf.invert(np.stack([A, B]))
    np.testing.assert_allclose(batch[1], np.linalg.inv(B), atol=1e-12)


def test_quaternion_known_values() -> None:
    T = np.eye(3)
    np.testing.assert_allclose(tf.quaternion_from_matrix(T), [1, 0, 0, 0])
    q = tf.quaternion_from_matrix(rz(90))
    np.testing.assert_allclose(q, [math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    q = tf.quaternion_from_matrix(rx(180))
    np.testing.assert_allclose(q, [0, 1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(tf.rotvec_from_matrix(ry(-30)), [0, -math.pi / 6, 0], atol=1e-15)
    np.testing.assert_allclose(tf.matrix_from_rotvec([0, 0, math.pi / 2]), rz(90), atol=1e-15)


@SETTINGS
@given(location)
def test_quaternion_and_rotvec_round_trips(loc: tuple[float, ...]) -> None:
    R = tf.location_to_transform(loc)[:3, :3]
    q = tf.quaternion_from_matrix(R)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12 and q[0] >= 0.0
    np.testing.assert_allclose(tf.matrix_from_quaternion(q), R, atol=1e-12)
    v = tf.rotvec_from_matrix(R)
    assert np.linalg.norm(v) <= math.pi + 1e-12
    np.testing.assert_allclose(tf.matrix_from_rotvec(v), R, atol=1e-12)


def test_tiny_rotvec_keeps_precision() -> None:
    v = np.array([1e-9, -2e-9, 3e-9])
    np.testing.assert_allclose(tf.rotvec_from_matrix(tf.matrix_from_rotvec(v)), v, rtol=1e-6)


def test_interpolate_endpoints_and_midpoint() -> None:
    T0 = tf.location_to_transform([0, 0, 0, 0, 0, 0])
    T1 = tf.location_to_transform([100, -50, 20, 0, 0, 90])
    np.testing.assert_allclose(tf.interpolate(T0, T1, 0.0), T0, atol=1e-12)
    np.testing.assert_allclose(tf.interpolate(T0, T1, 1.0), T1, atol=1e-12)
    mid = tf.interpolate(T0, T1, 0.5)
    np.testing.assert_allclose(mid[:3, 3], [50, -25, 10])
    np.testing.assert_allclose(mid[:3, :3], rz(45), atol=1e-12)
    many = tf.interpolate(T0, T1, np.linspace(0, 1, 5))
    assert many.shape == (5, 4, 4)
    np.testing.assert_allclose(many[2], mid, atol=1e-12)
    np.testing.assert_allclose(many[1][:3, :3], rz(22.5), atol=1e-12)


@SETTINGS
@given(location, location, st.floats(0.0, 1.0))
def test_interpolated_orientation_is_on_the_geodesic(
    a: tuple[float, ...], b: tuple[float, ...], s: float
) -> None:
    T0, T1 = tf.location_to_transform(a), tf.location_to_transform(b)
    Ts = tf.interpolate(T0, T1, s)
    tf.check_transform(Ts, tol=1e-9)
    total = np.linalg.norm(tf.rotvec_from_matrix(T0[:3, :3].T @ T1[:3, :3]))
    part = np.linalg.norm(tf.rotvec_from_matrix(T0[:3, :3].T @ Ts[:3, :3]))
    if total < math.pi - 1e-6:  # at exactly 180° the arc is ambiguous
        assert abs(part - s * total) < 1e-9


@pytest.mark.parametrize(
    "bad",
    [
        np.eye(3),
        np.full((4, 4), np.nan),
        np.diag([2.0, 1.0, 1.0, 1.0]),
        np.diag([-1.0, 1.0, 1.0, 1.0]),
        np.vstack([np.eye(4)[:3], [1.0, 0, 0, 1]]),
        "nope",
    ],
)
def test_check_transform_rejects(bad: object) -> None:
    with pytest.raises(KinematicsError):
        tf.check_transform(bad)


@pytest.mark.parametrize("bad", [[1, 2, 3], [0, 0, 0, 0, float("nan"), 0], [[1] * 6]])
def test_bad_locations(bad: object) -> None:
    with pytest.raises(ValueError):
        tf.location_to_transform(bad)  # type: ignore[arg-type]
    with pytest.raises(KinematicsError):
        tf.locations_to_transforms([[1, 2, 3]])
