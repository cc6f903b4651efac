"""Linear interpolation of buffered joint samples at sensor times (paper eq. 5).

For a query time t_i^S, find k with t_k^R <= t_i^S < t_{k+1}^R and interpolate

    q(t_i^S) = ((t_i^S - t_k) q_{k+1} + (t_{k+1} - t_i^S) q_k) / (t_{k+1} - t_k).

A query outside the buffered span is never extrapolated; it gets a status instead.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["InterpStatus", "interpolate_joints"]


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
        tq_ok = flat[ok]
        if n == 1:
            values[ok] = q[0]
        else:
            # side="right" puts a query equal to t_k in interval k (weight 0 on q_{k+1}), so a
            # query at a sample time returns the sample exactly; the last sample is the right
            # end of the final interval (weight exactly 1).
            k = np.clip(np.searchsorted(t, tq_ok, side="right") - 1, 0, n - 2)
            t0, t1 = t[k], t[k + 1]
            w = ((tq_ok - t0) / (t1 - t0))[:, None]
            q0, q1 = q[k], q[k + 1]
            v = (1.0 - w) * q0 + w * q1
            # Rounding can push a convex combination one ulp outside [q0, q1]; clip it back.
            values[ok] = np.clip(v, np.minimum(q0, q1), np.maximum(q0, q1))
    if tq.ndim == 0:
        return values[0], status.reshape(())
    return values, status
