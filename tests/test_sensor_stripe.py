"""Stage 1 of the detector: the stripe of every column and the light around given rows."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensorsocket.camera import StripeRenderer
from sensorsocket.detector import DetectorConfig
from sensorsocket.scene import Joint, Scene, fixed_pose
from sensorsocket.stripe import MAX_BEND_PX, StripeFinder


def _finder(h: int) -> StripeFinder:
    """A stripe finder with the detector's default thresholds and half window h."""
    cfg = DetectorConfig(half_window=h)
    return StripeFinder(h, cfg.noise_factor, cfg.min_contrast_dn, cfg.max_width_px)


def _frame(joint: Joint, seed: int = 1, **kw: float) -> np.ndarray:
    scene = Scene(joint)
    frame, _ = StripeRenderer(scene, rng=np.random.default_rng(seed)).render(
        0, np.zeros(512), fixed_pose(scene.sensor_over_seam(0.0, **kw))
    )
    return frame


def _naive_stripe(
    frame: np.ndarray, h: int, thr: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two-pass windowed centroid per column in plain Python loops (the documented method),
    given the threshold the detector estimated; returns (rows, mass, spread (px²))."""
    n, nrows = frame.shape
    w = 2 * h + 1
    rows, mass, spread = np.zeros(n), np.zeros(n), np.full(n, np.inf)
    for col in range(n):
        values = frame[col].astype(np.float64)
        start = min(max(int(np.argmax(values)) - h, 0), nrows - w)
        for _ in range(2):
            win = np.maximum(values[start : start + w] - thr, 0.0)
            m = win.sum()
            rel = (win @ np.arange(w)) / m if m > 0 else float(h)
            rows[col], mass[col] = start + rel, m
            if m > 0:
                spread[col] = (win @ np.arange(w) ** 2) / m - rel * rel
            start = min(max(int(np.rint(start + rel)) - h, 0), nrows - w)
    return rows, mass, spread


def _naive_smooth(rows: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The documented cross-column step in a plain loop: [1, 2, 3, 2, 1]/9 of the five centres
    where all five are valid and the three second differences about the column are small,
    else [1, 2, 1]/4 of the three where those are valid and the column's own is small."""
    out = rows.copy()
    n = len(rows)

    def bend(j: int) -> float:
        return float(rows[j - 1] - 2.0 * rows[j] + rows[j + 1])

    for i in range(1, n - 1):
        if (
            2 <= i < n - 2
            and valid[i - 2 : i + 3].all()
            and all(abs(bend(j)) <= MAX_BEND_PX for j in (i - 1, i, i + 1))
        ):
            out[i] = float(np.dot([1.0, 2.0, 3.0, 2.0, 1.0], rows[i - 2 : i + 3])) / 9.0
        elif valid[i - 1 : i + 2].all() and abs(bend(i)) <= MAX_BEND_PX:
            out[i] = float(np.dot([1.0, 2.0, 1.0], rows[i - 1 : i + 2])) / 4.0
    return out


@pytest.mark.parametrize("h", [3, 6])
def test_stripe_matches_a_per_column_loop(h: int) -> None:
    frame = _frame(Joint.lap(1.0), seed=21, seam_y_mm=1.3)[:200]
    stripe = _finder(h).stripe(frame)
    # background/noise estimate: checked below
    rows, mass, _ = _naive_stripe(frame, h, stripe.threshold)
    # background = median of the pixels at h+3 rows above and below each peak
    peak = frame.argmax(axis=1)
    ring = np.concatenate(
        [
            frame[np.arange(200), np.maximum(peak - h - 3, 0)],
            frame[np.arange(200), np.minimum(peak + h + 3, 255)],
        ]
    )
    assert stripe.background == pytest.approx(float(np.median(ring)))
    lit = mass > 0
    assert lit.mean() > 0.9
    smoothed = _naive_smooth(rows, stripe.valid)
    assert np.sum(smoothed != rows) > 50  # the lap's straight plates are smoothed
    np.testing.assert_allclose(stripe.rows[lit], smoothed[lit], atol=1e-3)
    np.testing.assert_allclose(stripe.mass, mass, rtol=1e-4, atol=1e-3)


def _pixel_mass(
    frame: np.ndarray, first: int, threshold: float, c: int, r: float, half: int
) -> float:
    """mass_at of one column, pixel by pixel: the plain reference."""
    want = 0.0
    if first <= c < first + frame.shape[0] and np.isfinite(r):
        centre = int(np.rint(r))
        for v in range(centre - half, centre + half + 1):
            if 0 <= v < frame.shape[1]:
                want += max(float(frame[c - first, v]) - threshold, 0.0)
    return want


def test_mass_at_matches_pixel_sums() -> None:
    frame = _frame(Joint.butt(0.4), seed=22).copy()
    frame[100, :8] = 250  # light at the image edges, where windows are cut off
    frame[250, 250:] = 240
    finder = _finder(DetectorConfig().half_window)
    stripe = finder.stripe(frame[100:300], first_column=100)
    cols = [50, 100, 150, 250, 299, 300, 400]  # some outside columns 100..299
    rows = [120.4, 3.0, np.nan, 254.6, 128.5, 128.0, 10.0]
    got = finder.mass_at(frame[100:300], stripe, cols, rows, 4)
    assert got[1] > 1000 and got[3] > 700
    assert finder.mass_at(frame[100:300], stripe, [], [], 4) == []
    for k, (c, r) in enumerate(zip(cols, rows, strict=True)):
        want = _pixel_mass(frame[100:300], 100, stripe.threshold, c, r, 4)
        assert got[k] == pytest.approx(want, abs=1e-9), (c, r)


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    half=st.integers(1, 12),
    first=st.integers(0, 300),
    k=st.integers(1, 30),
    layout=st.sampled_from(["c", "fortran", "float32"]),
)
def test_mass_at_fast_path_equals_the_pixel_sums(
    seed: int, half: int, first: int, k: int, layout: str
) -> None:
    """The one-gather path (windows inside a C-ordered frame) and the clipped path (edges,
    outside columns, NaN rows, other layouts) against the plain pixel loop."""
    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 256, (200, 256), dtype=np.uint8)
    stripe = _finder(6).stripe(frame, first_column=first)
    if layout == "fortran":
        frame = np.asfortranarray(frame)
    elif layout == "float32":
        frame = frame.astype(np.float32)
    cols = rng.integers(first - 5, first + 205, k).tolist()
    # mostly well inside; some at the edges, and a NaN now and then
    rows = rng.uniform(-3.0, 259.0, k) if rng.random() < 0.3 else rng.uniform(20, 230, k)
    rows = np.round(rows * 2) / 2 if rng.random() < 0.3 else rows  # ties round to even
    if rng.random() < 0.2:
        rows[0] = np.nan
    got = _finder(6).mass_at(frame, stripe, cols, rows.tolist(), half)
    for m, c, r in zip(got, cols, rows.tolist(), strict=True):
        assert m == pytest.approx(_pixel_mass(frame, first, stripe.threshold, c, r, half), abs=1e-9)


def test_stripe_centres_within_0_03_px_of_the_renderer_truth() -> None:
    """Butt and lap frames at the renderer's default noise: the centres of the columns that
    hold one stripe are within 0.03 px rms of where the renderer drew it (one column's plain
    centroid: about 0.043 px), and the step of the lap keeps its own centre."""
    finder = _finder(DetectorConfig().half_window)
    err = []
    for seed, joint in enumerate([Joint.butt(), Joint.lap()] * 3):
        scene = Scene(joint)
        frame, truth = StripeRenderer(scene, rng=np.random.default_rng(seed)).render(
            0, np.zeros(512), fixed_pose(scene.sensor_over_seam(0.0))
        )
        stripe = finder.stripe(frame)
        ok = truth.simple & stripe.valid
        assert ok.sum() > 400
        err.append(stripe.rows[ok] - truth.center_row[ok])
    e = np.concatenate(err)
    assert float(np.sqrt(np.mean(e * e))) <= 0.03
    assert float(np.max(np.abs(e))) < 0.2


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    h=st.integers(2, 8),
    n=st.integers(5, 60),
    extra_rows=st.integers(0, 40),
    saturate=st.booleans(),
)
def test_stripe_matches_the_per_column_loop_on_random_frames(
    seed: int, h: int, n: int, extra_rows: int, saturate: bool
) -> None:
    """Any frame shape and content: a wavy stripe of varying brightness and width, dark and
    clipped columns, noise; the vectorised finder (first pass for all columns, second pass
    only where the window moves, cross-column step) equals the plain loop."""
    rng = np.random.default_rng(seed)
    nrows = 2 * h + 1 + extra_rows
    centre = rng.uniform(-2, nrows + 1) + np.cumsum(rng.normal(0, 0.7, n))
    sigma = rng.uniform(0.6, 3.0, n)
    peak = rng.uniform(0, 400 if saturate else 200, n) * (rng.random(n) > 0.1)
    r = np.arange(nrows)
    light = peak[:, None] * np.exp(-0.5 * ((r[None, :] - centre[:, None]) / sigma[:, None]) ** 2)
    frame = np.clip(np.rint(light + rng.normal(8, 2, (n, nrows))), 0, 255).astype(np.uint8)
    finder = _finder(h)
    stripe = finder.stripe(frame)
    rows, mass, spread = _naive_stripe(frame, h, stripe.threshold)
    np.testing.assert_allclose(stripe.mass, mass, rtol=1e-4, atol=1e-3)
    top = frame.max(axis=1).astype(np.float64)
    contrast = max(finder.min_contrast_dn, 6.0 * stripe.noise)
    valid = (top >= stripe.background + contrast) & (mass > 0)
    valid &= spread <= finder.max_width_px**2
    # float32 against float64: a spread within rounding of the bound may go either way
    unsure = np.abs(spread - finder.max_width_px**2) < 1e-3
    np.testing.assert_array_equal(stripe.valid[~unsure], valid[~unsure])
    want = _naive_smooth(rows, stripe.valid)
    # a second difference within rounding of the bend limit may go either way, too
    bend = np.abs(rows[:-2] - 2 * rows[1:-1] + rows[2:])
    edge = np.flatnonzero(np.abs(bend - MAX_BEND_PX) < 1e-3) + 1
    sure = np.ones(n, dtype=bool)
    for k in edge:
        sure[max(k - 2, 0) : k + 3] = False
    lit = mass > 0
    np.testing.assert_allclose(stripe.rows[lit & sure], want[lit & sure], atol=1e-3)
