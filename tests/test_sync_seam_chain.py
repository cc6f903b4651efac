"""Tests for sync.seam_chain: eqs. 2-3, seam2base = flange2base(q) · sensor2flange · seam2sensor."""

from __future__ import annotations

import numpy as np
import pytest

from sync.seam_chain import seam2base, seam_positions


def _rz(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _trans(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def _toy_flange2base(q: np.ndarray) -> np.ndarray:
    """A stand-in DGM: translation (q1, q2, q3) mm, then a rotation q6 degrees about z."""
    out = np.empty((q.shape[0], 4, 4))
    for n, row in enumerate(q):
        out[n] = _trans(*row[:3]) @ _rz(row[5])
    return out


def test_hand_computed_point() -> None:
    # Flange at (10, 20, 30) turned 90° about z; sensor 100 mm along the flange z axis;
    # seam at (1, 2, 300) in the sensor frame. The flange x axis is base y, flange y is
    # base -x, so the seam is at (10 - 2, 20 + 1, 30 + 100 + 300) = (8, 21, 430).
    q = np.array([[10.0, 20.0, 30.0, 0.0, 0.0, 90.0]])
    p = seam_positions(q, _toy_flange2base, _trans(0, 0, 100), _trans(1, 2, 300)[None])
    np.testing.assert_allclose(p, [[8.0, 21.0, 430.0]], atol=1e-12)


def test_composition_order_is_left_to_right() -> None:
    # A rotated sensor tool: the seam offset must be turned by the sensor rotation, then by
    # the flange rotation. 90° + 90° about z maps x to -x.
    q = np.zeros((1, 6))
    q[0, 5] = 90.0
    out = seam2base(q, _toy_flange2base, _rz(90.0), _trans(5, 0, 0))
    np.testing.assert_allclose(out[0, :3, 3], [-5.0, 0.0, 0.0], atol=1e-12)


def test_batched_equals_one_by_one_and_shared_seam2sensor() -> None:
    rng = np.random.default_rng(7)
    q = rng.uniform(-90, 90, (50, 6))
    s2f = _trans(3, -4, 120) @ _rz(30)
    g2s = np.stack([_trans(*rng.normal(0, 5, 3)) @ _rz(rng.uniform(-10, 10)) for _ in q])
    out = seam2base(q, _toy_flange2base, s2f, g2s)
    for n in range(q.shape[0]):
        np.testing.assert_allclose(out[n], _toy_flange2base(q[n : n + 1])[0] @ s2f @ g2s[n])
    shared = seam2base(q, _toy_flange2base, s2f, g2s[0])
    np.testing.assert_allclose(shared[7], _toy_flange2base(q[7:8])[0] @ s2f @ g2s[0])


def test_shape_errors() -> None:
    q = np.zeros((3, 6))
    with pytest.raises(ValueError):
        seam2base(q, _toy_flange2base, np.eye(3), np.eye(4))
    with pytest.raises(ValueError):
        seam2base(q, _toy_flange2base, np.eye(4), np.zeros((2, 4, 4)))
    with pytest.raises(ValueError):
        seam2base(q, lambda x: np.zeros((1, 4, 4)), np.eye(4), np.eye(4))
    with pytest.raises(ValueError):
        seam2base(np.zeros(6), _toy_flange2base, np.eye(4), np.eye(4))


def test_with_the_rx90b_model() -> None:
    robot = pytest.importorskip("kinematics.robot")
    model = robot.get_model()
    # VAL3 zero: arm straight up, flange at (0, 0, 985) mm pointing up; a sensor 100 mm
    # further along the flange z axis sees the seam 200 mm ahead of it.
    q = np.zeros((1, 6))
    p = seam_positions(q, model.flange2base_batch, _trans(0, 0, 100), _trans(0, 0, 200))
    np.testing.assert_allclose(p, [[0.0, 0.0, 1285.0]], atol=1e-9)
    rng = np.random.default_rng(3)
    qs = rng.uniform(-90, 90, (20, 6))
    out = seam2base(qs, model.flange2base_batch, _rz(15) @ _trans(5, 0, 90), _trans(1, 2, 250))
    for n in range(20):
        np.testing.assert_allclose(
            out[n],
            model.flange2base(qs[n]) @ _rz(15) @ _trans(5, 0, 90) @ _trans(1, 2, 250),
            atol=1e-9,
        )
