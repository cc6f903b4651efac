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
(:func:`_cross`). The one sum that grows with the run (T, position-weighted) only sets the
cubic's constant term, the same for every shift, so the curve's shape near its minimum keeps
the rounding of the direct sums: seed 1 of the bench gives ΔT 1e-13 s from the grid-point
form.
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
    docstring). Knot k sits at ``x[k]`` (grid steps, increasing); piece k holds the ``n[k]``
    grid points e[k] .. e[k + 1] - 1 (none when two knots share a grid interval), where
    h = ``start[k] + slope[k]·(j - e[k])``. Grid positions are whole floats."""

    lo: int
    hi: int
    x: NDArray[np.float64]  # (K,)
    e: NDArray[np.float64]  # (K,) ceil(x)
    start: NDArray[np.float64]  # (K - 1,)
    slope: NDArray[np.float64]  # (K - 1,)
    n: NDArray[np.float64]  # (K - 1,)
    s1: NDArray[np.float64]  # (K - 1,) Σ w over w = 0 .. n - 1
    s2: NDArray[np.float64]  # (K - 1,) Σ w²
    bend: NDArray[np.float64]  # (K,) slope change at each knot (slope 0 outside)
    squares: NDArray[np.float64]  # (K,) Σ h(j)² over the grid points before e[k]


def _pieces(t: NDArray[np.float64], y: NDArray[np.float64], grid_step_s: float) -> _Pieces:
    lo, hi = grid_span(t, grid_step_s)
    x = t / grid_step_s
    near = np.rint(x)
    np.copyto(x, near, where=np.abs(x - near) < GRID_SNAP)
    ends = np.interp(np.array([lo, hi - 1], dtype=np.float64) * grid_step_s, t, y)
    if hi - lo == 1:
        xs = np.array([lo - 1.0, lo, lo + 1.0])
        hs = np.array([0.0, ends[0], 0.0])
    else:
        # samples strictly inside (lo, hi - 1): a slice of the sorted x
        a = int(np.searchsorted(x, lo, "right"))
        b = int(np.searchsorted(x, hi - 1))
        xs = np.empty(b - a + 4)
        hs = np.empty(b - a + 4)
        xs[0], xs[1], xs[-2], xs[-1] = lo - 1.0, lo, hi - 1.0, hi
        hs[0], hs[1], hs[-2], hs[-1] = 0.0, ends[0], ends[1], 0.0
        xs[2:-2] = x[a:b]
        hs[2:-2] = y[a:b]
    dx = xs[1:] - xs[:-1]
    if not dx.min() > 0:
        # two samples snapped onto one grid point: the first one counts
        inner = (x > lo) & (x < hi - 1)
        inner[1:] &= x[1:] > x[:-1]
        xs = np.concatenate([[lo - 1.0, lo], x[inner], [hi - 1.0, hi]])
        hs = np.concatenate([[0.0], ends[:1], y[inner], ends[1:], [0.0]])
        dx = xs[1:] - xs[:-1]
    slope = (hs[1:] - hs[:-1]) / dx
    e = np.ceil(xs)
    start = hs[:-1] + slope * (e[:-1] - xs[:-1])
    n = e[1:] - e[:-1]
    s1 = n * (n - 1.0) / 2.0
    s2 = s1 * (2.0 * n - 1.0) / 3.0
    squares = np.empty(xs.shape[0])
    squares[0] = 0.0
    np.cumsum(_square_sums(n, s1, s2, start, slope), out=squares[1:])
    bend = np.empty(xs.shape[0])
    bend[0] = slope[0]
    np.subtract(slope[1:], slope[:-1], out=bend[1:-1])
    bend[-1] = -slope[-1]
    return _Pieces(lo, hi, xs, e, start, slope, n, s1, s2, bend, squares)


def _square_sums(
    n: NDArray[np.float64],
    s1: NDArray[np.float64],
    s2: NDArray[np.float64],
    c: NDArray[np.float64],
    b: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Σ_{w=0}^{n-1} (c + b·w)² from the power sums s1 = Σ w and s2 = Σ w², elementwise."""
    out: NDArray[np.float64] = (n * c + 2.0 * b * s1) * c + b * b * s2
    return out


def _piece_at(p: _Pieces, j: NDArray[np.float64]) -> NDArray[np.int64]:
    """The piece holding each grid point j in [lo - 1, hi] (the last piece for hi)."""
    i: NDArray[np.int64] = np.searchsorted(p.e, j, side="right") - 1
    np.minimum(i, p.start.shape[0] - 1, out=i)
    return i


def _square_prefix(p: _Pieces, j: NDArray[np.float64]) -> NDArray[np.float64]:
    """Σ g[v]² over v < j, for j in [lo, hi]."""
    i = _piece_at(p, j)
    w = j - p.e.take(i)
    s1 = w * (w - 1.0) / 2.0
    s2 = s1 * (2.0 * w - 1.0) / 3.0
    out = _square_sums(w, s1, s2, p.start.take(i), p.slope.take(i))
    out += p.squares.take(i)
    return out


def _spikes(p: _Pieces) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Where the second difference of g is not zero, increasing, and its values there:
    (1 - frac)·bend on floor(x) of every knot, frac·bend on the next point for a knot off
    the grid (summed where two knots put a spike on one point)."""
    floor = np.floor(p.x)
    frac = p.x - floor
    off = np.flatnonzero(frac)
    if off.size == 0:
        return floor, p.bend
    at = np.concatenate([floor, floor.take(off) + 1.0])
    value = np.concatenate([p.bend * (1.0 - frac), p.bend.take(off) * frac.take(off)])
    at, where = np.unique(at, return_inverse=True)
    return at, np.bincount(where, weights=value).astype(np.float64, copy=False)


def _tails(s: _Pieces) -> NDArray[np.float64]:
    """Per piece k (rows): e, n, start, slope, and at the next knot the tail sums
    M = Σ_{j >= e} g[j] and T = Σ_{j >= e} g[j]·(j - e) and g itself. Rows, so that one
    gather of whole rows picks a piece's seven values."""
    whole0 = s.n * s.start + s.slope * s.s1  # Σ g over each piece
    whole1 = s.start * s.s1 + s.slope * s.s2  # Σ g·(j - e) over each piece
    k = s.e.shape[0]
    table = np.empty((k - 1, 7))
    table[:, 0] = s.e[:-1]
    table[:, 1] = s.n
    table[:, 2] = s.start
    table[:, 3] = s.slope
    # suffix sums from knot k + 1 on (0 from the last); positions relative to lo keep them small
    e_rel = s.e[:-1] - s.lo
    tail0 = np.cumsum(whole0[::-1])[::-1]
    tail1 = np.cumsum((whole1 + e_rel * whole0)[::-1])[::-1] - e_rel * tail0
    table[:-1, 4] = tail0[1:]
    table[:-1, 5] = tail1[1:]
    # g at the next knot's grid point, read from the last piece that starts there
    table[:-1, 6] = s.start[1:]
    table[-1, 4:] = 0.0
    same = s.e[1:] == s.e[:-1]
    if same.any():
        last = np.where(np.append(same, False), k, np.arange(k))
        last = np.minimum.accumulate(last[::-1])[::-1]
        table[:, 6] = np.append(s.start, 0.0).take(last[1:])
    return table


def _cross(s: _Pieces, r: _Pieces, shifts: NDArray[np.int64]) -> NDArray[np.float64]:
    """C(m) = Σ_j g_s[j]·g_r[j + m] for the consecutive shifts m."""
    q, wq = _spikes(r)
    first = int(shifts[0])
    count = shifts.shape[0] - 2  # lags first .. first + count - 1 reach the curve
    x = q - first
    # One search serves the tails and the pair windows: the robot spikes left of each sensor
    # knot, x < knot, i.e. x < e = ceil(knot) as x is whole (in integers: a quicker search).
    # The piece of a robot spike is then the number of knots at or left of it, less one;
    # -1 and the last knot are clipped below, as for a spike outside the span.
    xi = x.astype(np.intp)
    below = np.searchsorted(xi, s.e.astype(np.intp))
    i = np.cumsum(np.bincount(below, minlength=x.shape[0] + 1)[:-1])
    i -= 1
    # The pairs with lag q - p < first (p > x): tail sums of g_s from x (module docstring).
    # Ψk = Σ_q wq·σk(x) with σk(x) = Σ_{p > x} d_s[p]·binom(p - x, k): σ1 = g_s[x],
    # σ0 = g_s[x] - g_s[x + 1], σ2 = M - g, σ3 = T - M + g for M = Σ_{j >= x} g_s[j] and
    # T = Σ_{j >= x} g_s[j]·(j - x). Below the span M is constant and T linear, above both 0.
    xc = np.minimum(np.maximum(x, s.e[0]), s.e[-1])  # np.clip costs more
    e, n, start, b, tail0, tail1, g_e = _tails(s).take(i, axis=0, mode="clip").T
    w0 = xc - e
    left = n - w0  # grid points from xc to the end of its piece
    g = start + b * w0
    l1 = left * (left - 1.0) / 2.0
    l2 = l1 * (2.0 * left - 1.0) / 3.0
    sums = np.empty((4, x.shape[0]))
    sums[0] = g
    sums[1] = np.where(left > 1.0, g + b, g_e)
    sums[1] *= x == xc
    sums[2] = g * left + b * l1 + tail0
    sums[3] = g * l1 + b * l2 + tail1 + left * tail0 + (xc - x) * sums[2]
    # einsum: one pass, no (4, n) temporary and no BLAS threads
    g_sum, next_sum, m_sum, t_sum = np.einsum("ij,j->i", sums, wq)
    psi0, psi1, psi2, psi3 = g_sum - next_sum, g_sum, m_sum - g_sum, t_sum - m_sum + g_sum
    # C(m) gets Σ_k binom(d, k)·Ψ(3 - k) with d = m - first + 1, by Horner
    d = np.arange(1.0, shifts.shape[0] + 1.0)
    c: NDArray[np.float64] = psi1 + (d - 2.0) / 3.0 * psi0
    c = psi3 + d * (psi2 + (d - 1.0) / 2.0 * c)
    if count > 0:
        c[2:] += _window_sums(s, xi, wq, below, count)
    return c


def _knots_within(e: NDArray[np.float64] | NDArray[np.intp], count: int) -> int:
    """The most knots whose e lie in any count + 1 consecutive grid points: the smallest m
    with e[i + m] - e[i] > count for every i (all K knots when none is)."""
    k = e.shape[0]
    # e[i + m] - e[i] is m mean spacings on average, so m <= count / mean cannot do
    m: int = min(k, int(count * (k - 1) / max(float(e[-1] - e[0]), 1.0)) + 1)
    while m < k and not np.min(e[m:] - e[:-m]) > count:
        m += max(1, m // 4)
    return m


def _window_sums(
    s: _Pieces,
    x: NDArray[np.intp],
    wq: NDArray[np.float64],
    below: NDArray[np.intp],
    count: int,
) -> NDArray[np.float64]:
    """The pairs with lag q - p = l in first .. first + count - 1, summed per lag as F(l), reach
    C(m) with weight K(m - l) = 1, 4, 10, 20, ... from m = l + 2 on: four running sums of F.

    A sensor knot's two spikes are taken together: the one on floor(x_k) has lag q - floor,
    the other one less, so the robot spikes wanted (x = q - first, increasing, distinct) lie
    in [floor, floor + count]: at most ``most`` (:func:`_knots_within`) of them, from the
    first one at or right of floor, which is ``below`` (the spikes left of x_k) less one
    when the spike before that one is on floor. Each sensor knot is a column of that many
    robot spikes; the ones past its range land in an end bin that is dropped."""
    k = s.x.shape[0]
    n = x.shape[0]
    most = _knots_within(x, count)
    floor = np.floor(s.x)
    frac = s.x - floor
    at = floor.astype(np.intp)
    on_floor = s.bend * (1.0 - frac)
    after = s.bend * frac
    # robot spikes as x + 1, after one below every window and before `most` past every one
    pos = np.empty(n + 1 + most, dtype=np.intp)
    pos[0] = at[0]
    pos[1 : n + 1] = x
    pos[1 : n + 1] += 1
    pos[n + 1 :] = max(pos[n], at[-1]) + count + 2
    w = np.zeros(n + 1 + most)
    w[1 : n + 1] = wq
    begin = below + 1  # index in pos of the first spike at or right of the floor
    begin -= pos.take(below) == at + 1
    # Row o: spike o of every knot's window, a gather from the padded spikes' view from o on
    # (no index array; mode="clip" never clips, it only spares numpy a copy of `out`). Flat
    # calls per row: numpy buffers a row broadcast over a 2-d array, at several times the
    # cost. The widest window sets the rows, but the last one reaches a lag for few knots:
    # of it only those slots are summed.
    size = most * k
    bins = np.empty(size, dtype=np.intp)
    on = np.empty(size)
    off = np.empty(size)
    for o in range(most):
        row = slice(o * k, (o + 1) * k)
        np.take(pos[o:], begin, out=bins[row], mode="clip")
        bins[row] -= at  # bin = lag - first + 1 = (x + 1) - floor >= 1
        if o == most - 1:
            hit = np.flatnonzero(bins[row] <= count + 1)
            size = o * k + hit.shape[0]
            row = slice(o * k, size)
            bins[row] = bins.take(hit + o * k)
            begin = begin.take(hit)
            on_floor = on_floor.take(hit)
            after = after.take(hit)
        np.take(w[o:], begin, out=on[row], mode="clip")
        np.multiply(on[row], after, out=off[row])
        on[row] *= on_floor
    bins = bins[:size]
    # rows before the last can still pass the lags; bins far out (a long gap in the robot
    # data) would make bincount's output long
    if int(np.max(bins)) > 8 * (count + 2):
        np.minimum(bins, count + 2, out=bins)
    on = np.bincount(bins, weights=on[:size], minlength=count + 3)
    off = np.bincount(bins, weights=off[:size], minlength=count + 3)
    f: NDArray[np.float64] = np.add(on[1 : count + 1], off[2 : count + 2])
    for _ in range(4):
        np.cumsum(f, out=f)
    return f


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
    ends = np.concatenate([hi, lo]).astype(np.float64)
    sq = _square_prefix(s, ends)
    sq_s = sq[: shifts.shape[0]] - sq[shifts.shape[0] :]
    sq = _square_prefix(r, ends + np.concatenate([shifts, shifts]))
    sq_r = sq[: shifts.shape[0]] - sq[shifts.shape[0] :]
    cross = _cross(s, r, shifts)
    mse = np.full(shifts.shape[0], np.inf)
    ok = overlap >= 2
    mse[ok] = (sq_s[ok] + sq_r[ok] - 2.0 * cross[ok]) / overlap[ok]
    return mse, np.where(ok, overlap, 0).astype(np.int64)
