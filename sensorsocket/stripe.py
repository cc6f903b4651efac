"""Stage 1 of the seam detector: the laser stripe of every column (pure numpy, vectorised).

Per column, the brightest row (argmax), then a fixed window of 2h+1 rows around it and its
intensity centroid after subtracting a threshold ``background + k·noise`` (background and
noise estimated per frame, robustly, from pixels just outside the windows). Second pass with
the window re-centred on the centroid. A column is valid when its peak clears the background
by ``max(min_contrast_dn, 6·noise)`` and the stripe is not wider than ``max_width_px`` (rms).
Last, each valid column whose two neighbours on either side are valid and in line with it
(second differences at most ``MAX_BEND_PX``) takes the [1, 2, 3, 2, 1]/9 average of the five
centres: the noise of one column's centroid is pixel noise (read, shot, speckle) independent
between columns, so averaging along a straight piece of stripe halves it without bias (a
symmetric kernel on a line), as a blur across columns does before a centre of gravity.
Next to an end, a gap or a corner, a column whose own neighbours are valid and in line takes
the [1, 2, 1]/4 average of three; the last column before an end or a corner keeps its own.
Frames are in readout layout ``(columns, rows)``, see :mod:`sensorsocket.camera`; the seam
stages are in :mod:`sensorsocket.detector`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinematics.types import FloatArray

#: Gaussian noise: σ = 1.4826 · median absolute deviation (robust against the stripe's tail).
MAD_TO_SIGMA = 1.4826
#: Background samples lie this many rows beyond either end of a column's stripe window.
_RING_GAP_ROWS = 3
#: Noise floor (DN): below half a DN the 8-bit rounding, not the noise, sets the threshold.
_MIN_NOISE_DN = 0.5
#: A valid column's peak clears the background by this many noise sigmas (or by
#: ``min_contrast_dn``): over 512 columns, noise alone then practically never passes.
_PEAK_SIGMAS = 6.0
#: Cross-column smoothing only where the stripe is locally straight: a second difference of
#: the rows above this (px) is an edge, step or corner, not noise (about 5 sigma of the
#: second difference of the centroid noise), and is left alone.
MAX_BEND_PX = 0.5
#: A phantom light at each window's centre: a power of two, so h·_TINY / _TINY is h exactly,
#: and far below half a float32 step of a window's mass and moments where it has light (at
#: least one step of a threshold >= 1 DN, 2^-23), so added to them it is rounded away.
_TINY = 2.0**-100
#: The spread (px²) of a dark window with the phantom's second moment: beyond any bound.
_DARK_SPREAD = 2.0**40


@dataclass(frozen=True)
class StripeProfile:
    """Per-column stripe of a frame (arrays (n,), column ``first_column + i``)."""

    first_column: int
    rows: FloatArray = field(repr=False)
    mass: FloatArray = field(repr=False)
    valid: NDArray[np.bool_] = field(repr=False)
    background: float
    noise: float
    threshold: float


@dataclass(frozen=True)
class _ShapeConstants:
    """Read-only arrays for frames (n, rows): flat offset of each column (n,) and twice
    (n, 2); the clamped background rows above and below a peak on row r (rows, 2); the
    clamped start of the window about row r (rows,); zeros (n·w,); the phantom's moments
    for every column (3, n)."""

    base: NDArray[np.intp]
    base2: NDArray[np.intp]
    ring_of_row: NDArray[np.intp]
    start_of_row: NDArray[np.intp]
    zeros: NDArray[np.float32]
    phantom: NDArray[np.float32]


class StripeFinder:
    """The stripe of every column of frames, with the detector's thresholds: window half
    width h (rows), threshold factor k on the noise, minimum peak contrast (DN) and maximum
    stripe width (rms, px)."""

    def __init__(
        self, half_window: int, noise_factor: float, min_contrast_dn: float, max_width_px: float
    ) -> None:
        self.half_window = half_window
        self.noise_factor = noise_factor
        self.min_contrast_dn = min_contrast_dn
        self.max_width_px = max_width_px
        win = np.arange(2 * half_window + 1, dtype=np.float32)
        # (3, w): a window's mass, first and second moment are one matrix product; the
        # first pass needs mass and first moment only
        self._win_moments = np.stack([np.ones_like(win), win, win * win])
        self._win_centroid = self._win_moments[:2].copy()
        # the moments of a phantom light _TINY at the window centre: a dark window's
        # centroid is its centre and its spread _DARK_SPREAD - h²; added to the moments of
        # light, rounded away (see _TINY)
        self._phantom = np.array(
            [_TINY, half_window * _TINY, _DARK_SPREAD * _TINY], dtype=np.float32
        )
        # a stripe wider than any window can hold is no bound: keep dark windows out
        self._max_spread = np.float32(min(max_width_px**2, 0.5 * _DARK_SPREAD))
        self._shape_cache: dict[tuple[int, int], _ShapeConstants] = {}
        self._windows: dict[int, tuple[NDArray[np.intp], FloatArray]] = {}

    def _shape_constants(self, n: int, nrows: int) -> _ShapeConstants:
        """Read-only index and bound arrays for frames (n, nrows), cached per shape: a
        detector sees one frame shape over and over. Never written, so thread-safe."""
        key = (n, nrows)
        c = self._shape_cache.get(key)
        if c is None:
            w = self._win_moments.shape[1]
            h = self.half_window
            r = np.arange(nrows)
            base = np.arange(0, n * nrows, nrows, dtype=np.intp)
            c = _ShapeConstants(
                base=base,
                base2=np.repeat(base, 2).reshape(n, 2),
                ring_of_row=np.stack(
                    [
                        np.maximum(r - (h + _RING_GAP_ROWS), 0),
                        np.minimum(r + (h + _RING_GAP_ROWS), nrows - 1),
                    ],
                    axis=1,
                ),
                start_of_row=np.clip(r - h, 0, nrows - w),
                zeros=np.zeros(n * w, dtype=np.float32),
                phantom=np.repeat(self._phantom, n).reshape(3, n),
            )
            for arr in (c.base, c.base2, c.ring_of_row, c.start_of_row, c.zeros, c.phantom):
                arr.setflags(write=False)
            self._shape_cache[key] = c
        return c

    def stripe(self, frame: NDArray[np.generic], first_column: int = 0) -> StripeProfile:
        """Sub-pixel stripe rows of every column of ``frame`` (n, rows)."""
        a = np.ascontiguousarray(frame)
        n, nrows = a.shape
        w = 2 * self.half_window + 1
        flat = a.reshape(-1)
        c = self._shape_constants(n, nrows)
        # numpy's argmax has no SIMD loop for 8-bit integers: on int32 it is 2x faster,
        # conversion included; ties resolve to the first maximum either way
        search = a.astype(np.int32) if a.dtype.itemsize == 1 else a
        peak_row = search.argmax(axis=1)
        # the rows just outside the window above and below the peak, clamped: (n, 2)
        ring = c.ring_of_row.take(peak_row, axis=0)
        ring += c.base2
        samples = flat.take(ring.reshape(-1)).astype(np.float32)
        # start of the window centred on row r, clamped to the frame: c.start_of_row[r]
        start = c.start_of_row.take(peak_row)
        peak_row += c.base
        peak = flat.take(peak_row)
        background = median_of_copy(samples)  # sorts samples: their order is not needed
        np.subtract(samples, background, out=samples)
        mad = median_of_copy(np.abs(samples, out=samples))
        noise = max(MAD_TO_SIGMA * mad, _MIN_NOISE_DN)
        # at least 1 DN above the background: its rounding alone must not count as light
        threshold = background + max(self.noise_factor * noise, 1.0)
        bright = np.float32(background + max(self.min_contrast_dn, _PEAK_SIGMAS * noise))
        if a.dtype == np.uint8:  # an integer reaches a bound where it reaches its ceiling
            valid = peak >= math.ceil(bright)
        else:
            valid = peak.astype(np.float32) >= bright
        thr32 = np.float32(threshold)
        windows = strided_runs(flat, w)
        moments = self._moments(a.dtype, windows[start + c.base], thr32, c)
        moments += c.phantom
        mass = moments[0]
        rel = np.divide(moments[1], mass)
        rows = rel + start.astype(np.float32)
        # re-centre on the first centroid (symmetric window, whole plateau): only the
        # windows that move, about one in nine, change
        centre = c.start_of_row.take(np.rint(rows).astype(np.intp))
        moved = np.flatnonzero(centre != start)
        if moved.size:
            start = centre
            sub = self._moments(a.dtype, windows[start.take(moved) + c.base.take(moved)], thr32, c)
            sub += self._phantom[:, None]
            moments[:, moved] = sub
            np.divide(moments[1], mass, out=rel)
            np.add(rel, start.astype(np.float32), out=rows)
        spread = np.divide(moments[2], mass)
        spread -= rel * rel
        valid &= spread <= self._max_spread
        if n >= 5:
            smooth_straight(rows, valid)
        mass -= _TINY  # the phantom: 0 in a dark window, rounded away elsewhere
        return StripeProfile(
            first_column=first_column,
            rows=rows.astype(np.float64),
            mass=mass.astype(np.float64),
            valid=valid,
            background=background,
            noise=noise,
            threshold=threshold,
        )

    def _moments(
        self,
        dtype: np.dtype[np.generic],
        windows: NDArray[np.void],
        thr32: np.float32,
        c: _ShapeConstants,
    ) -> NDArray[np.float32]:
        """Mass, first and second moment (3, k) of the light above the threshold in k
        windows (items of w pixels of ``dtype``)."""
        k, w = windows.size, self._win_moments.shape[1]
        vals = windows.view(dtype).astype(np.float32)
        vals -= thr32
        np.maximum(vals, c.zeros[: k * w], out=vals)  # an array operand takes the SIMD loop
        out: NDArray[np.float32] = self._win_moments @ vals.reshape(k, w).T
        return out

    def mass_at(
        self,
        frame: NDArray[np.generic],
        stripe: StripeProfile,
        columns: Sequence[int],
        rows: Sequence[float],
        half: int,
    ) -> list[float]:
        """Thresholded light in rows ``round(rows) ± half`` of chip ``columns`` (k,) of
        ``frame``; 0 for a column outside the frame or a row that is not finite, and rows
        beyond the frame's carry none."""
        if len(columns) == 0:
            return []
        f = np.asarray(frame)
        ncols, nrows = f.shape[0], f.shape[1]
        # the usual case (a few columns next to a seam, windows well inside the frame):
        # every window is one run of the flat frame, read in one gather
        lo, hi = float(half), float(nrows - 1 - half)  # float bounds: faster compares
        first = stripe.first_column
        base = -first * nrows - half
        starts = []
        if f.flags.c_contiguous:
            for c, r in zip(columns, rows, strict=True):
                if not (lo <= r <= hi and first <= c < first + ncols):  # NaN fails too
                    break
                starts.append(c * nrows + round(r) + base)  # round: half to even, as rint
        if len(starts) == len(columns):
            index = np.fromiter(starts, np.intp, len(starts))  # cheaper than a list index
            runs = strided_runs(f.reshape(-1), 2 * half + 1)[index]
            vals = runs.view(f.dtype).reshape(len(starts), -1).astype(np.float64)
        else:
            vals = self._clipped_windows(f, stripe, columns, rows, half)
        vals -= stripe.threshold
        np.maximum(vals, 0.0, out=vals)
        sums: list[float] = vals.dot(self._window(half)[1]).tolist()
        return sums

    def _clipped_windows(
        self,
        f: NDArray[np.generic],
        stripe: StripeProfile,
        columns: Sequence[int],
        rows: Sequence[float],
        half: int,
    ) -> FloatArray:
        """The (k, 2·half + 1) pixels of :meth:`mass_at`'s windows in any frame, as float64
        below the threshold where a window leaves the frame, a column lies outside it or a
        row is not finite (those contribute nothing)."""
        ncols, nrows = f.shape[0], f.shape[1]
        r = np.asarray(rows, dtype=np.float64)
        local = np.asarray(columns, dtype=np.intp) - stripe.first_column
        ok = np.isfinite(r) & (local >= 0) & (local < ncols)
        offsets = self._window(half)[0]
        idx = np.rint(np.where(ok, r, 0.0)).astype(np.intp)[:, None] + offsets
        rows_in = np.clip(idx, 0, nrows - 1)
        vals: FloatArray = f[np.where(ok, local, 0)[:, None], rows_in].astype(np.float64)
        vals[(rows_in != idx) | ~ok[:, None]] = -np.inf  # below any threshold: no light
        return vals

    def _window(self, half: int) -> tuple[NDArray[np.intp], FloatArray]:
        """Row offsets -half..half and ones of that length (read-only, cached per half)."""
        window = self._windows.get(half)
        if window is None:
            window = (np.arange(-half, half + 1), np.ones(2 * half + 1))
            for arr in window:
                arr.setflags(write=False)
            self._windows[half] = window
        return window


def strided_runs(flat: NDArray[np.generic], w: int) -> NDArray[np.void]:
    """Every run of ``w`` consecutive elements of 1-D ``flat`` (at least ``w`` long) as one
    item of a strided view (len - w + 1,), to read, never to write: a window of a frame is
    then one fancy index (its flat start), no (n, w) index array to build, and gathering k
    items of w elements costs a third of gathering k rows of a 2-d view. ``.view(dtype)``
    of a gather gives the elements back, k·w of them."""
    item = np.dtype((np.void, w * flat.itemsize))
    return np.ndarray((flat.size - w + 1,), item, flat, 0, (flat.itemsize,))


def smooth_straight(rows: NDArray[np.float32], valid: NDArray[np.bool_]) -> None:
    """[1, 2, 3, 2, 1]/9 across columns, in place, where a column and its two neighbours on
    either side are valid and the three second differences about it are at most
    ``MAX_BEND_PX``; else [1, 2, 1]/4 where the column and its two next neighbours are
    valid and its own second difference is at most that (next to ends, gaps and corners);
    rows (n,), n >= 5. Written as rows + (b[-1] + 4·b[0] + b[1])/9 and rows + b[0]/4 on
    the second differences b, the same weights."""
    mid = rows[1:-1]
    bend = rows[:-2] + rows[2:]
    bend -= mid + mid  # bend[k]: second difference at column k + 1
    straight = np.abs(bend) <= _F32_MAX_BEND
    straight &= valid[:-2]
    straight &= valid[1:-1]
    straight &= valid[2:]
    ok = straight[:-2] & straight[1:-1]
    ok &= straight[2:]
    step = bend[1:-1] * _F32_FOUR
    step += bend[:-2]
    step += bend[2:]
    step *= _F32_NINTH
    step *= ok
    # the three-column average where the five-column one does not apply: straight & ~ok
    np.greater(straight[1:-1], ok, out=straight[1:-1])
    bend *= _F32_QUARTER
    bend *= straight
    mid += bend
    rows[2:-2] += step


def _f32(x: float) -> NDArray[np.float32]:
    """x as a read-only 0-d float32 array: as an operand it costs less than a scalar."""
    out = np.array(x, dtype=np.float32)
    out.setflags(write=False)
    return out


_F32_MAX_BEND = _f32(MAX_BEND_PX)
_F32_FOUR = _f32(4.0)
_F32_NINTH = _f32(1.0 / 9.0)
_F32_QUARTER = _f32(0.25)


def to_dn(a: NDArray[np.generic]) -> NDArray[np.float32]:
    """Grey levels on the 8-bit scale the thresholds are in: 16-bit integers / 256, floats
    in [0, 1] × 255, other numbers as they are; NaN and infinities become 0."""
    f = np.nan_to_num(a.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    if a.dtype.itemsize >= 2 and np.issubdtype(a.dtype, np.integer) and f.max() > 255:
        f *= np.float32(1.0 / 256.0)
    elif np.issubdtype(a.dtype, np.floating) and f.size and f.min() >= 0.0 and f.max() <= 1.0:
        f *= np.float32(255.0)
    return f


def median_of_copy(x: NDArray[np.floating]) -> float:
    """Median of a non-empty 1-D array the caller no longer needs (sorted in place). A
    full sort: numpy's SIMD sort beats np.partition on these short arrays full of ties."""
    n = x.size
    k = n // 2
    x.sort()
    if n % 2:
        return float(x[k])
    return 0.5 * (float(x[k]) + float(x[k - 1]))
