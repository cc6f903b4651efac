"""Image formation: background and read noise, the stripe's shot noise and speckle."""

from __future__ import annotations

from statistics import NormalDist

import numpy as np
import pytest

from sensorsocket.camera import StripeRenderer
from sensorsocket.exposure import RenderSettings
from sensorsocket.scene import Joint, Scene, SeamPath, fixed_pose


def _scene_and_pose(joint: Joint, **kw: float) -> tuple[Scene, np.ndarray]:
    scene = Scene(joint, SeamPath.straight())
    return scene, scene.sensor_over_seam(0.0, **kw)


def test_background_noise_statistics_are_honest() -> None:
    s = RenderSettings(background_dn=20.0, read_noise_dn=3.0, noise_refresh_frames=4)
    scene, pose = _scene_and_pose(Joint.butt(0.5))
    r = StripeRenderer(scene, settings=s, rng=np.random.default_rng(3))
    darks = np.stack(
        [r.render(0, np.zeros(512), fixed_pose(pose), laser_on=False)[0] for _ in range(8)]
    ).astype(float)
    assert darks.mean() == pytest.approx(20.0, abs=0.05)
    assert darks.std() == pytest.approx(3.0, abs=0.1)
    # different frames do not repeat the same noise pixel for pixel
    corr = np.corrcoef(darks[0].ravel(), darks[1].ravel())[0, 1]
    assert abs(corr) < 0.05


def test_stripe_noise_pool_is_standard_normal() -> None:
    """The pre-drawn unit normals: each 16-bit draw k maps to the standard normal quantile
    of (k + 0.5)/65536, so the pool has the normal's quantiles, mean 0 and variance 1."""
    r = StripeRenderer(Scene(Joint.butt()), rng=np.random.default_rng(8))
    r.render(0, np.zeros(512), fixed_pose(np.eye(4)))
    pool = np.asarray(r.exposure.normals, dtype=np.float64)
    assert pool.size >= 1 << 16
    assert abs(pool.mean()) < 0.02
    assert pool.var() == pytest.approx(1.0, abs=0.02)
    nd = NormalDist()
    for z in (-3.0, -1.5, -0.5, 0.0, 0.7, 2.0, 3.0):
        assert np.mean(pool <= z) == pytest.approx(nd.cdf(z), abs=0.005)
    assert np.abs(pool).max() < 4.4  # the 16-bit table's extreme quantile is 4.32


def test_stripe_noise_statistics_are_honest() -> None:
    """Shot noise and speckle of the stated variance s²·c² + g·s around the stripe signal s,
    zero-mean, and different from frame to frame (pre-drawn pool, random offsets)."""
    s = RenderSettings(
        background_dn=0.0, read_noise_dn=0.0, shot_gain_dn=0.5, speckle_contrast=0.05,
        noise_refresh_frames=16,
    )  # fmt: skip
    scene, pose = _scene_and_pose(Joint.lap(1.0), seam_y_mm=2.0)
    r = StripeRenderer(scene, settings=s, rng=np.random.default_rng(4))
    frames = [r.render(0, np.zeros(512), fixed_pose(pose)) for _ in range(96)]
    stack = np.stack([f for f, _ in frames]).astype(float)
    truth = frames[0][1]
    # noise-free signal: the renderer's own Gaussian without noise, from a zero-noise twin
    quiet = RenderSettings(background_dn=0.0, read_noise_dn=0.0, shot_gain_dn=0.0,
                           speckle_contrast=0.0)  # fmt: skip
    q = StripeRenderer(scene, settings=quiet, rng=np.random.default_rng(5))
    clean = q.render(0, np.zeros(512), fixed_pose(pose))[0].astype(float)
    cols = np.flatnonzero(truth.simple & (truth.coverage == 1.0))
    sel = np.zeros_like(clean, dtype=bool)
    sel[cols] = (clean[cols] > 30.0) & (clean[cols] < 200.0)
    signal = clean[sel]
    mean = stack[:, sel].mean(axis=0)
    var = stack[:, sel].var(axis=0)
    predicted = signal**2 * 0.05**2 + 0.5 * signal + 1.0 / 12.0  # + rounding
    assert sel.sum() > 1000
    assert abs((mean - signal).mean()) < 0.1  # zero-mean (clean is itself rounded)
    assert var.mean() / predicted.mean() == pytest.approx(1.0, abs=0.05)
    # not the same noise in two frames
    d0, d1 = stack[0][sel] - signal, stack[1][sel] - signal
    assert abs(np.corrcoef(d0, d1)[0, 1]) < 0.1
