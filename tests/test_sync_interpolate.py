"""Tests for sync.interpolate: eq. 5 and the TOO_OLD / NOT_YET outcomes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sync.interpolate import InterpStatus, interpolate_joints, lerp_inside

T = np.array([0.0, 0.004, 0.008])
Q = np.array(
    [
        [0.0, 10.0, -5.0, 0.0, 0.0, 90.0],
        [4.0, 10.0, -7.0, 1.0, 0.0, 90.0],
        [4.0, 20.0, -9.0, 3.0, 0.0, 90.0],
    ]
)


def test_hand_computed_values() -> None:
    # t = 1 ms: a quarter of the way from sample 0 to sample 1.
    v, s = interpolate_joints(T, Q, 0.001)
    assert s == InterpStatus.OK
    np.testing.assert_allclose(v, [1.0, 10.0, -5.5, 0.25, 0.0, 90.0])
    # t = 7 ms: three quarters of the way from sample 1 to sample 2.
    v, _ = interpolate_joints(T, Q, 0.007)
    np.testing.assert_allclose(v, [4.0, 17.5, -8.5, 2.5, 0.0, 90.0])


def test_batch_and_statuses() -> None:
    v, s = interpolate_joints(T, Q, [-0.001, 0.0, 0.002, 0.008, 0.0081])
    assert v.shape == (5, 6) and s.shape == (5,)
    assert s.tolist() == [
        InterpStatus.TOO_OLD,
        InterpStatus.OK,
        InterpStatus.OK,
        InterpStatus.OK,
        InterpStatus.NOT_YET,
    ]
    assert np.all(np.isnan(v[0])) and np.all(np.isnan(v[4]))
    np.testing.assert_array_equal(v[1], Q[0])
    np.testing.assert_array_equal(v[3], Q[2])  # the newest sample itself is OK, not NOT_YET
    np.testing.assert_allclose(v[2], (Q[0] + Q[1]) / 2)


def test_empty_and_single_sample_buffers() -> None:
    v, s = interpolate_joints(np.zeros(0), np.zeros((0, 6)), [0.0, 1.0])
    assert s.tolist() == [InterpStatus.NOT_YET] * 2
    v, s = interpolate_joints([1.0], Q[:1], [0.5, 1.0, 1.5])
    assert s.tolist() == [InterpStatus.TOO_OLD, InterpStatus.OK, InterpStatus.NOT_YET]
    np.testing.assert_array_equal(v[1], Q[0])


def test_bad_inputs() -> None:
    with pytest.raises(ValueError):
        interpolate_joints(T, Q[:2], 0.0)
    with pytest.raises(ValueError):
        interpolate_joints(T, Q, float("nan"))
    with pytest.raises(ValueError):
        interpolate_joints(T, Q, np.zeros((2, 2)))


@st.composite
def _buffers(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    n = draw(st.integers(2, 30))
    steps = draw(st.lists(st.floats(1e-4, 1.0), min_size=n, max_size=n))
    t0 = draw(st.floats(-100.0, 100.0))
    times = t0 + np.cumsum(steps)
    vals = draw(
        st.lists(st.floats(-360.0, 360.0, allow_subnormal=False), min_size=6 * n, max_size=6 * n)
    )
    return times, np.array(vals).reshape(n, 6)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(buf=_buffers())
def test_at_a_sample_returns_the_sample(buf: tuple[np.ndarray, np.ndarray]) -> None:
    t, q = buf
    v, s = interpolate_joints(t, q, t)
    assert np.all(s == InterpStatus.OK)
    np.testing.assert_array_equal(v, q)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(buf=_buffers(), data=st.data())
def test_between_two_samples_stays_in_their_range(
    buf: tuple[np.ndarray, np.ndarray], data: st.DataObject
) -> None:
    t, q = buf
    k = data.draw(st.integers(0, len(t) - 2))
    frac = data.draw(st.floats(0.0, 1.0))
    tq = min(t[k] + frac * (t[k + 1] - t[k]), t[k + 1])
    v, s = interpolate_joints(t, q, tq)
    assert s == InterpStatus.OK
    lo = np.minimum(q[k], q[k + 1])
    hi = np.maximum(q[k], q[k + 1])
    assert np.all(v >= lo) and np.all(v <= hi)
    # and it is eq. 5, up to rounding
    expected = ((tq - t[k]) * q[k + 1] + (t[k + 1] - tq) * q[k]) / (t[k + 1] - t[k])
    np.testing.assert_allclose(v, expected, atol=1e-6 * (1 + np.abs(q).max()))


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_unchecked_interpolation_equals_interpolate_joints(seed: int) -> None:
    """lerp_inside (what the matcher calls) gives interpolate_joints' values bit for bit, and
    its one-query path on Python floats gives the numpy path's values bit for bit."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 13))
    t = np.cumsum(rng.uniform(1e-3, 5e-3, n))
    q = rng.normal(0.0, 90.0, (n, 6))
    if n > 2:
        q[1] = q[0]  # a pause: the clip to the samples' range must hold
    queries = np.concatenate([rng.uniform(t[0], t[-1], 5), t[[0, n // 2, -1]]])
    want, status = interpolate_joints(t, q, queries)
    assert np.all(status == InterpStatus.OK)
    assert np.array_equal(lerp_inside(t, q, queries), want)
    for i, x in enumerate(queries):
        assert np.array_equal(lerp_inside(t, q, np.array([x])), want[i : i + 1])
