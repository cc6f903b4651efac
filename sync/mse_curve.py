"""The MSE(ΔT) curve of section VI in closed form, from the samples' linear pieces.

Upsampled to the 5 kHz grid (t_j = j · step), a signal is linear between its samples;
counted as zero outside its span, it is g[j] = h(j) at every integer j for a piecewise-linear
h whose knots are the samples strictly inside the span, the first and last grid point of the
span (with the interpolated values there) and one grid point beyond each end (value 0).

Per shift m the MSE needs Σ g_s² and Σ g_r² over the overlap (closed forms per piece) and the
cross term C(m) = Σ_j g_s[j]·g_r[j + m]. The second difference d[j] = g[j+1] - 2g[j] + g[j-1]
is zero except next to a knot: a knot at x whose slope changes by c puts (1 - frac(x))·c on
floor(x) and frac(x)·c on the point after. With g_s[j] = Σ_p d_s[p]·max(p - j, 0) and
g_r[v] = Σ_q d_r[q]·max(v - q, 0), summing over j first gives

    C(m) = Σ_{p, q} d_s[p]·d_r[q]·K(m - (q - p)),    K(L) = (L³ - L)/6 for L >= 0, else 0,

so only pairs of knots matter. Pairs whose lag q - p falls inside the searched range (about
five robot knots per sensor knot for 20 ms: ~12k pairs, not 5M products of grid points) are
summed per lag and spread by K; the pairs below the range add the same cubic in m to every
shift, whose four coefficients are tail sums of the sensor signal at each robot knot
(:func:`_outer_cubic`). Every sum is over a signal's own values and pieces, so the rounding is
that of the direct sums; there is no difference of large prefix sums.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["GRID_SNAP", "grid_span", "mse_curve"]

GRID_SNAP = 1e-9
"""A sample time within this many grid steps of a grid point is taken to lie on it."""


def grid_span(t: NDArray[np.float64], grid_step_s: float) -> tuple[int, int]:
    """First grid index inside the span of the times ``t``, and one past the last."""
    if not (math.isfinite(grid_step_s) and grid_step_s > 0):
        raise ValueError(f"grid step must be positive, got {grid_step_s}")
    j0 = math.ceil(t[0] / grid_step_s - GRID_SNAP)
    j1 = math.floor(t[-1] / grid_step_s + GRID_SNAP)
    if j1 < j0:
        raise ValueError("signal span is shorter than one grid step")
    return j0, j1 + 1


@dataclass(frozen=True)
class _Pieces:
    """A signal on the grid points [lo, hi), zero outside, as the knots of h (module
    docstring). Knot k sits at ``x[k]`` (grid steps, increasing); piece k holds the grid
    points e[k] .. e[k + 1] - 1 (none when two knots share a grid interval), where
    h = ``start[k] + slope[k]·(j - e[k])``."""

    lo: int
    hi: int
    x: NDArray[np.float64]  # (K,)
    e: NDArray[np.int64]  # (K,) ceil(x)
    start: NDArray[np.float64]  # (K - 1,)
    slope: NDArray[np.float64]  # (K - 1,)
    bend: NDArray[np.float64]  # (K,) slope change at each knot (slope 0 outside)
    squares: NDArray[np.float64]  # (K,) Σ h(j)² over the grid points before e[k]


def _pieces(t: NDArray[np.float64], y: NDArray[np.float64], grid_step_s: float) -> _Pieces:
    lo, hi = grid_span(t, grid_step_s)
    x = t / grid_step_s
    near = np.rint(x)
    x = np.where(np.abs(x - near) < GRID_SNAP, near, x)
    # samples strictly inside (lo, hi - 1); two that snapped onto one grid point count once
    inner = (x > lo) & (x < hi - 1)
    inner[1:] &= x[1:] > x[:-1]
    ends = np.interp(np.array([lo, hi - 1], dtype=np.float64) * grid_step_s, t, y)
    if hi - lo == 1:
        xs = np.array([lo - 1.0, lo, lo + 1.0])
        hs = np.array([0.0, ends[0], 0.0])
    else:
        xs = np.concatenate([[lo - 1.0, lo], x[inner], [hi - 1.0, hi]])
        hs = np.concatenate([[0.0], ends[:1], y[inner], ends[1:], [0.0]])
    slope = np.diff(hs) / np.diff(xs)
    e = np.ceil(xs).astype(np.int64)
    start = hs[:-1] + slope * (e[:-1] - xs[:-1])
    squares = np.empty(xs.shape[0])
    squares[0] = 0.0
    np.cumsum(_square_sums(np.diff(e), start, slope), out=squares[1:])
    bend = np.diff(slope, prepend=0.0, append=0.0)
    return _Pieces(lo, hi, xs, e, start, slope, bend, squares)


def _square_sums(
    n: NDArray[np.int64], c: NDArray[np.float64], b: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Σ_{w=0}^{n-1} (c + b·w)², elementwise."""
    nf = n.astype(np.float64)
    s1 = nf * (nf - 1.0) / 2.0
    s2 = s1 * (2.0 * nf - 1.0) / 3.0
    out: NDArray[np.float64] = nf * c * c + 2.0 * c * b * s1 + b * b * s2
    return out


def _piece_at(p: _Pieces, j: NDArray[np.int64]) -> NDArray[np.int64]:
    """The piece holding each grid point j in [lo - 1, hi] (the last piece for hi)."""
    i: NDArray[np.int64] = np.searchsorted(p.e, j, side="right") - 1
    np.minimum(i, p.start.shape[0] - 1, out=i)
    return i


def _square_prefix(p: _Pieces, j: NDArray[np.int64]) -> NDArray[np.float64]:
    """Σ g[v]² over v < j, for j in [lo, hi]."""
    i = _piece_at(p, j)
    out: NDArray[np.float64] = p.squares.take(i) + _square_sums(
        j - p.e.take(i), p.start.take(i), p.slope.take(i)
    )
    return out


def _spikes(p: _Pieces) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Where the second difference of g is not zero, and its values there: two per knot at
    most (one for a knot on the grid)."""
    floor = np.floor(p.x)
    frac = p.x - floor
    at = np.concatenate([floor, floor + 1.0]).astype(np.int64)
    value = np.concatenate([p.bend * (1.0 - frac), p.bend * frac])
    keep = value != 0.0
    return at[keep], value[keep]


def _outer_cubic(
    s: _Pieces, q: NDArray[np.int64], wq: NDArray[np.float64], first: int
) -> NDArray[np.float64]:
    """(Ψ0, Ψ1, Ψ2, Ψ3): the pairs of spikes with lag q - p < ``first`` add
    Σ_k binom(m - first + 1, k)·Ψ(3 - k) to C(m) for every m >= first.

    Ψk = Σ_q wq·σk(q - first) with σk(X) = Σ_{p > X} d_s[p]·binom(p - X, k): σ1 is g_s[X],
    σ0 = g_s[X] - g_s[X + 1], and σ2, σ3 follow from the tail sums of g_s from X,
    M(X) = Σ_{j >= X} g_s[j] and T(X) = Σ_{j >= X} g_s[j]·(j - X): σ2 = M - g, σ3 = T - M + g.
    """
    n = np.diff(s.e)
    nf = n.astype(np.float64)
    s1 = nf * (nf - 1.0) / 2.0
    s2 = s1 * (2.0 * nf - 1.0) / 3.0
    whole0 = nf * s.start + s.slope * s1  # Σ g over each piece
    whole1 = s.start * s1 + s.slope * s2  # Σ g·(j - e) over each piece
    # tail sums from each knot (0 from the last); positions relative to lo keep them small
    e_rel = (s.e - s.lo).astype(np.float64)
    tail0 = np.zeros(s.e.shape[0])
    tail0[:-1] = np.cumsum(whole0[::-1])[::-1]
    tail1 = np.zeros(s.e.shape[0])
    tail1[:-1] = np.cumsum((whole1 + e_rel[:-1] * whole0)[::-1])[::-1]
    tail1 -= e_rel * tail0
    # g at each knot's grid point e[k], read from the last piece starting there
    last = np.where(np.append(s.e[1:] != s.e[:-1], True), np.arange(s.e.shape[0]), s.e.shape[0])
    last = np.minimum.accumulate(last[::-1])[::-1]
    g_at_e = np.append(s.start, 0.0).take(last)

    x = q - first
    xc = np.clip(x, s.e[0], s.e[-1])  # g is 0 outside: below, M is constant, T linear
    i = _piece_at(s, xc)
    w0 = xc - s.e.take(i)
    left = n.take(i) - w0  # grid points from xc to the end of its piece
    b = s.slope.take(i)
    g = s.start.take(i) + b * w0
    lf = left.astype(np.float64)
    l1 = lf * (lf - 1.0) / 2.0
    l2 = l1 * (2.0 * lf - 1.0) / 3.0
    m0_next = tail0.take(i + 1)
    tail_m = g * lf + b * l1 + m0_next
    tail_t = g * l1 + b * l2 + tail1.take(i + 1) + lf * m0_next + (xc - x) * tail_m
    g_next = np.where((left > 1) & (x == xc), g + b, 0.0)
    g_next = np.where((left == 1) & (x == xc), g_at_e.take(i + 1), g_next)
    sigma = np.stack([g - g_next, g, tail_m - g, tail_t - tail_m + g])
    out: NDArray[np.float64] = np.add.reduce(sigma * wq, axis=1)
    return out


def _lag_sums(
    s: _Pieces, q: NDArray[np.int64], wq: NDArray[np.float64], first: int, count: int
) -> NDArray[np.float64]:
    """F(l) = Σ d_s[p]·d_r[q] over the spike pairs with q - p = l, for l = first ..
    first + count - 1. Each sensor knot's two spikes are handled together: the one on
    floor(x) has lag q - floor(x), the other one less."""
    floor = np.floor(s.x)
    frac = s.x - floor
    lo = np.searchsorted(floor, q - (first + count), side="left")
    hi = np.searchsorted(floor, q - first, side="right")
    width = int(np.max(hi - lo, initial=0))
    if width == 0:
        return np.zeros(count)
    # the knots of each robot spike's window as one row: rows of a sliding view, padded with
    # knots far to the right (weight 0) so every window fits
    k = s.x.shape[0]
    table = np.zeros((k + width, 3))
    table[:k, 0] = floor
    table[k:, 0] = float(np.max(q)) - first + 1.0  # beyond every window
    table[:k, 1] = s.bend * (1.0 - frac)
    table[:k, 2] = s.bend * frac
    rows = np.lib.stride_tricks.sliding_window_view(table, (width, 3))[lo, 0]
    lag = q[:, None] - rows[:, :, 0] - first  # of the spike on floor(x)
    use = (lag >= 0.0) & (lag <= count)
    at = np.where(use, lag, 0.0).astype(np.int64).ravel()
    w = np.where(use, wq[:, None], 0.0)
    on_floor = np.bincount(at, weights=(w * rows[:, :, 1]).ravel(), minlength=count + 1)
    after = np.bincount(at, weights=(w * rows[:, :, 2]).ravel(), minlength=count + 1)
    out: NDArray[np.float64] = np.add(on_floor[:count], after[1:], dtype=np.float64)
    return out


def _cross(s: _Pieces, r: _Pieces, shifts: NDArray[np.int64]) -> NDArray[np.float64]:
    """C(m) = Σ_j g_s[j]·g_r[j + m] for the consecutive shifts m."""
    q, wq = _spikes(r)
    first = int(shifts[0])
    psi = _outer_cubic(s, q, wq, first)
    d = np.arange(1, shifts.shape[0] + 1, dtype=np.float64)  # m - first + 1
    # Σ_k binom(d, k)·Ψ(3 - k), by Horner
    c: NDArray[np.float64] = psi[1] + (d - 2.0) / 3.0 * psi[0]
    c = psi[3] + d * (psi[2] + (d - 1.0) / 2.0 * c)
    if shifts.shape[0] > 2:
        # pairs at lags first .. last - 2 reach C(m) for m >= lag + 2 with weights
        # K(m - lag) = 1, 4, 10, 20, ...: four running sums
        f = _lag_sums(s, q, wq, first, shifts.shape[0] - 2)
        for _ in range(4):
            f = np.cumsum(f)
        c[2:] += f
    return c


def mse_curve(
    sensor: tuple[NDArray[np.float64], NDArray[np.float64]],
    robot: tuple[NDArray[np.float64], NDArray[np.float64]],
    shifts: NDArray[np.int64],
    grid_step_s: float,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """MSE(m) = mean_j (y^S(t_j) - y^R(t_{j + m}))² over the grid points j where both signals
    (times, values) are upsampled, per shift m (grid steps, consecutive), with the number of
    points averaged. Fewer than two points: MSE inf, count 0."""
    t_s, y_s = sensor
    t_r, y_r = robot
    # A common offset leaves every difference, hence the MSE, unchanged; centred, the sums
    # stay small and Σys² + Σyr² - 2Σys·yr keeps its digits.
    mean = float(np.add.reduce(y_r)) / y_r.shape[0]
    s = _pieces(t_s, y_s - mean, grid_step_s)
    r = _pieces(t_r, y_r - mean, grid_step_s)
    lo = np.maximum(s.lo, r.lo - shifts)
    hi = np.maximum(np.minimum(s.hi, r.hi - shifts), lo)
    overlap = hi - lo
    sq_s = _square_prefix(s, hi) - _square_prefix(s, lo)
    sq_r = _square_prefix(r, hi + shifts) - _square_prefix(r, lo + shifts)
    cross = _cross(s, r, shifts)
    mse = np.full(shifts.shape[0], np.inf)
    ok = overlap >= 2
    mse[ok] = (sq_s[ok] + sq_r[ok] - 2.0 * cross[ok]) / overlap[ok]
    return mse, np.where(ok, overlap, 0).astype(np.int64)
