"""The DGM: hand-checkable poses per model, literal values, batch forms, bad joints."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kinematics import KinematicsError, get_model

MODELS = ["RX90B", "RX130B", "RX160", "TX90"]
# (a1 shoulder offset, d lateral offset, a2 upper arm, d4 forearm, d6 wrist to flange), from
# DESIGN.md's manufacturer dimensions.
DIMS = {
    "RX90B": (0.0, 0.0, 450.0, 450.0, 85.0),
    "RX130B": (0.0, 0.0, 625.0, 625.0, 110.0),
    "RX160": (150.0, 0.0, 825.0, 625.0, 110.0),
    "TX90": (50.0, 50.0, 425.0, 425.0, 100.0),
}
I3 = np.eye(3)
RY90 = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
RZ90 = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])


def hand_poses(name: str) -> list[tuple[list[float], list[float], np.ndarray]]:
    """(joints, expected flange position, expected rotation) worked out on paper."""
    a1, d, a2, d4, d6 = DIMS[name]
    L = a2 + d4 + d6
    return [
        ([0, 0, 0, 0, 0, 0], [a1, d, L], I3),  # arm straight up
        ([90, 0, 0, 0, 0, 0], [-d, a1, L], RZ90),
        ([-90, 0, 0, 0, 0, 0], [d, -a1, L], RZ90.T),
        ([0, 90, 0, 0, 0, 0], [a1 + L, d, 0], RY90),  # whole arm horizontal, forward
        ([0, -90, 0, 0, 0, 0], [a1 - L, d, 0], RY90.T),
        ([0, 0, 90, 0, 0, 0], [a1 + d4 + d6, d, a2], RY90),  # forearm horizontal
        ([0, 0, -90, 0, 0, 0], [a1 - d4 - d6, d, a2], RY90.T),
        ([0, 0, 0, 90, 0, 0], [a1, d, L], RZ90),
        ([0, 0, 0, -90, 0, 0], [a1, d, L], RZ90.T),
        ([0, 0, 0, 0, 90, 0], [a1 + d6, d, a2 + d4], RY90),
        ([0, 0, 0, 0, -90, 0], [a1 - d6, d, a2 + d4], RY90.T),
        ([0, 0, 0, 0, 0, 90], [a1, d, L], RZ90),
        ([0, 0, 0, 0, 0, -90], [a1, d, L], RZ90.T),
        ([0, 90, -90, 0, 0, 0], [a1 + a2, d, d4 + d6], I3),  # upper arm horizontal
        # Usual work pose: forearm forward, flange pointing down.
        ([0, 0, 90, 0, 90, 0], [a1 + d4, d, a2 - d6], RY90 @ RY90),
    ]


@pytest.mark.parametrize("name", MODELS)
def test_hand_checkable_poses(name: str) -> None:
    m = get_model(name)
    for q, p, R in hand_poses(name):
        T = m.flange2base(q)
        np.testing.assert_allclose(T[:3, 3], p, atol=1e-9, err_msg=f"{name} {q}")
        np.testing.assert_allclose(T[:3, :3], R, atol=1e-12, err_msg=f"{name} {q}")
        np.testing.assert_allclose(T[3], [0, 0, 0, 1])


def test_rx90b_literal_values() -> None:
    m = get_model()
    assert m.name == "RX90B"
    np.testing.assert_allclose(m.flange2base([0] * 6)[:3, 3], [0, 0, 985], atol=1e-12)
    np.testing.assert_allclose(m.flange2base([0, 0, 90, 0, 90, 0])[:3, 3], [450, 0, 365])
    # J1 = 30 turns the work pose counter-clockwise seen from above.
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(
        m.flange2base([30, 0, 90, 0, 90, 0])[:3, 3], [450 * c, 450 * s, 365], atol=1e-9
    )


@pytest.mark.parametrize("name", MODELS)
def test_small_batches_bit_equal_to_large(name: str) -> None:
    # a few configurations take the Python-float path; they must give the numpy path's
    # numbers exactly (the emulated cell renders from them and its runs are reproducible)
    m = get_model(name)
    rng = np.random.default_rng(5)
    q = rng.uniform(-200.0, 200.0, (400, 6))
    big = m.flange2base_batch(q)
    start = 0
    for n in (1, 2, 3, 5, 7, 12, 0, 1):
        small = m.flange2base_batch(q[start : start + n])
        assert small.shape == (n, 4, 4)
        assert np.array_equal(small, big[start : start + n])
        start += n


@pytest.mark.parametrize(
    "bad",
    [[0, 0, 0], [0, 0, 0, 0, 0, float("nan")], "abcdef", [[0] * 6, [0] * 5]],
)
def test_bad_joints(bad: object) -> None:
    m = get_model()
    with pytest.raises(KinematicsError):
        m.flange2base(bad)
