"""Stage 1 of the detector: the stripe of every column and the light around given rows."""

from __future__ import annotations

import numpy as np
import pytest

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


def _naive_stripe(frame: np.ndarray, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Two-pass windowed centroid per column in plain Python loops (the documented method),
    given the threshold the detector estimated; returns (rows, mass)."""
    thr = _finder(h).stripe(frame).threshold  # background/noise estimate: checked separately
    n, nrows = frame.shape
    w = 2 * h + 1
    rows, mass = np.zeros(n), np.zeros(n)
    for col in range(n):
        values = frame[col].astype(np.float64)
        start = min(max(int(np.argmax(values)) - h, 0), nrows - w)
        for _ in range(2):
            win = np.maximum(values[start : start + w] - thr, 0.0)
            m = win.sum()
            rel = (win @ np.arange(w)) / m if m > 0 else float(h)
            rows[col], mass[col] = start + rel, m
            start = min(max(int(np.rint(start + rel)) - h, 0), nrows - w)
    return rows, mass


def _naive_smooth(rows: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The documented cross-column step in a plain loop: [1, 2, 3, 2, 1]/9 of the five centres
    where all five are valid and the three second differences about the column are small."""
    out = rows.copy()
    for i in range(2, len(rows) - 2):
        bends = [rows[j - 1] - 2.0 * rows[j] + rows[j + 1] for j in (i - 1, i, i + 1)]
        if valid[i - 2 : i + 3].all() and all(abs(b) <= MAX_BEND_PX for b in bends):
            out[i] = float(np.dot([1.0, 2.0, 3.0, 2.0, 1.0], rows[i - 2 : i + 3])) / 9.0
    return out


@pytest.mark.parametrize("h", [3, 6])
def test_stripe_matches_a_per_column_loop(h: int) -> None:
    frame = _frame(Joint.lap(1.0), seed=21, seam_y_mm=1.3)[:200]
    stripe = _finder(h).stripe(frame)
    rows, mass = _naive_stripe(frame, h)
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


def test_mass_at_matches_pixel_sums() -> None:
    frame = _frame(Joint.butt(0.4), seed=22).copy()
    frame[100, :8] = 250  # light at the image edges, where windows are cut off
    frame[250, 250:] = 240
    finder = _finder(DetectorConfig().half_window)
    stripe = finder.stripe(frame[100:300], first_column=100)
    cols = np.array([50, 100, 150, 250, 299, 300, 400])  # some outside columns 100..299
    rows = np.array([120.4, 3.0, np.nan, 254.6, 128.5, 128.0, 10.0])
    got = finder.mass_at(frame[100:300], stripe, cols, rows, 4)
    assert got[1] > 1000 and got[3] > 700
    for k, (c, r) in enumerate(zip(cols, rows, strict=True)):
        want = 0.0
        if 100 <= c < 300 and np.isfinite(r):
            centre = int(np.rint(r))
            for v in range(centre - 4, centre + 5):
                if 0 <= v < 256:
                    want += max(float(frame[c, v]) - stripe.threshold, 0.0)
        assert got[k] == pytest.approx(want, abs=1e-9), (c, r)


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
