"""What each read column sees: sub-column hits, shadows and the column statistics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sensorsocket import columns, straight_seam
from sensorsocket.camera import StripeRenderer
from sensorsocket.scene import Joint, Scene, SeamPath, scripted_pose


def test_hits_of_any_column_set_match_the_full_window() -> None:
    """Columns are independent: hits() on scattered columns (own constants) equals the same
    columns of a full-window render pass (cached constants), for a moving sensor."""
    scene = Scene(Joint.lap(), SeamPath.paper_sine())
    pose = scripted_pose(
        scene.sensor_over_seam(3.0, 0.8, -0.4, 10.0), velocity_mm_s=(50.0, 0.0, 0.0)
    )
    renderer = StripeRenderer(scene, rng=np.random.default_rng(0))
    times = np.arange(512, dtype=np.float64) * 6.8e-6
    hit_all, rows_all = renderer.hits(np.arange(512), times, pose)
    pick = np.array([3, 17, 200, 255, 256, 400, 511])
    hit, rows = renderer.hits(pick, times[pick], pose)
    assert hit.any()
    assert np.array_equal(hit, hit_all[pick])
    np.testing.assert_allclose(rows[hit], rows_all[pick][hit], rtol=0, atol=1e-9)
    # the cached window path gives the same rows as the public one
    win_hit, win_rows = renderer.reference.hits(renderer.reference.window(0, 512), times, pose)
    assert np.array_equal(win_hit, hit_all)
    assert np.array_equal(win_rows[win_hit], rows_all[hit_all])


@pytest.mark.parametrize(
    "joint", [Joint.butt(0.5), Joint.butt(0.5, 0.4), Joint.butt(0.5, -0.4), Joint.lap(1.0, 1)]
)
def test_skipped_shadow_tests_change_nothing(joint: Joint, monkeypatch: pytest.MonkeyPatch) -> None:
    """The renderer skips shadow tests a flat piece cannot pass (it is not above the lit one);
    with every test run the hits and the straight-seam statistics are the same."""
    scene = Scene(joint, SeamPath.straight())
    times = np.arange(512, dtype=np.float64) * 6.8e-6
    for roll in (-12.0, 0.0, 12.0):
        pose = scripted_pose(
            scene.sensor_over_seam(0.0, 0.3, -0.4, roll), velocity_mm_s=(50.0, 0.0, 0.0)
        )
        out = []
        for skip in (True, False):
            with monkeypatch.context() as m:
                if not skip:
                    for module in (columns, straight_seam):
                        m.setattr(module, "shadow_free_above", lambda *a: math.inf)
                r = StripeRenderer(scene, rng=np.random.default_rng(0))
                assert r.straight is not None
                out.append((r.hits(np.arange(512), times, pose), r.straight.stats(0, times, pose)))
        (fast, fast_stats), (full, full_stats) = out
        assert np.array_equal(fast[0], full[0])
        np.testing.assert_array_equal(fast[1][fast[0]], full[1][full[0]])
        for name in ("coverage", "mean", "var", "simple", "complex_columns", "complex_rows"):
            np.testing.assert_array_equal(getattr(fast_stats, name), getattr(full_stats, name))
