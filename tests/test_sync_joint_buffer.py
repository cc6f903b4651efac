"""Tests for sync.joint_buffer: the robot's cyclic (t_k, q_k) buffer."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sync.joint_buffer import DEFAULT_CAPACITY, JointBuffer, JointBufferError


def _q(k: float) -> np.ndarray:
    return np.array([k, -k, 2 * k, 0.5, k * k, -3.0])


def test_default_is_ten_seconds_at_4ms() -> None:
    buf = JointBuffer()
    assert buf.capacity == DEFAULT_CAPACITY == 2500
    assert len(buf) == 0 and buf.latest_time is None and buf.oldest_time is None


def test_wraps_and_keeps_the_newest_in_time_order() -> None:
    buf = JointBuffer(capacity=5)
    for k in range(12):
        buf.append(k * 0.004, _q(k))
    t, q = buf.samples()
    assert len(buf) == 5
    np.testing.assert_allclose(t, [k * 0.004 for k in range(7, 12)])
    np.testing.assert_array_equal(q, np.stack([_q(k) for k in range(7, 12)]))
    assert buf.oldest_time == pytest.approx(7 * 0.004)
    assert buf.latest_time == pytest.approx(11 * 0.004)


def test_since_and_covering() -> None:
    buf = JointBuffer(capacity=8)
    for k in range(10):
        buf.append(float(k), _q(k))
    t, q = buf.since(5.5)
    np.testing.assert_array_equal(t, [6.0, 7.0, 8.0, 9.0])
    np.testing.assert_array_equal(q[0], _q(6))
    t, _ = buf.since(6.0)  # inclusive
    np.testing.assert_array_equal(t, [6.0, 7.0, 8.0, 9.0])
    t, _ = buf.covering(5.5)  # plus the sample on the left of 5.5
    np.testing.assert_array_equal(t, [5.0, 6.0, 7.0, 8.0, 9.0])
    t, _ = buf.since(100.0)
    assert t.shape == (0,)


def test_returned_arrays_are_copies() -> None:
    buf = JointBuffer(capacity=4)
    buf.append(0.0, _q(0))
    t, q = buf.samples()
    t[0] = 99.0
    q[0, 0] = 99.0
    t2, q2 = buf.samples()
    assert t2[0] == 0.0 and q2[0, 0] == 0.0


@pytest.mark.parametrize("t", [1.0, 0.5, float("nan"), float("inf")])
def test_rejects_non_increasing_or_non_finite_time(t: float) -> None:
    buf = JointBuffer(capacity=4)
    buf.append(1.0, _q(1))
    with pytest.raises(JointBufferError):
        buf.append(t, _q(2))
    assert len(buf) == 1


def test_rejects_bad_joints() -> None:
    buf = JointBuffer(capacity=4)
    with pytest.raises(JointBufferError):
        buf.append(0.0, np.zeros(5))
    with pytest.raises(JointBufferError):
        buf.append(0.0, [0, 0, 0, 0, 0, float("nan")])
    with pytest.raises(ValueError):
        JointBuffer(capacity=1)


def test_extend_is_all_or_nothing() -> None:
    buf = JointBuffer(capacity=4)
    buf.extend([0.0, 1.0], np.zeros((2, 6)))
    with pytest.raises(JointBufferError):
        buf.extend([2.0, 2.0], np.zeros((2, 6)))
    assert len(buf) == 2
    buf.extend(np.arange(2.0, 12.0), np.ones((10, 6)))
    t, _ = buf.samples()
    np.testing.assert_array_equal(t, [8.0, 9.0, 10.0, 11.0])


@settings(max_examples=100, deadline=None, derandomize=True)
@given(
    capacity=st.integers(2, 20),
    steps=st.lists(st.floats(1e-4, 10.0), min_size=0, max_size=60),
)
def test_matches_a_reference_deque(capacity: int, steps: list[float]) -> None:
    buf = JointBuffer(capacity=capacity)
    ref: deque[tuple[float, float]] = deque(maxlen=capacity)
    t = 0.0
    for n, dt in enumerate(steps):
        t += dt
        buf.append(t, np.full(6, float(n)))
        ref.append((t, float(n)))
    times, joints = buf.samples()
    assert len(buf) == len(ref)
    np.testing.assert_array_equal(times, [r[0] for r in ref])
    np.testing.assert_array_equal(joints[:, 3], [r[1] for r in ref])
