"""The straight-seam fast path of the renderer against the plain per-sub-column model."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sensorsocket.camera import StripeRenderer
from sensorsocket.columns import SIMPLE_SPREAD_PX, UNLIT_ROW, sub_column_stats
from sensorsocket.exposure import RenderSettings
from sensorsocket.scene import Joint, Scene, SeamPath, scripted_pose

_STATS_JOINTS = [
    Joint.butt(0.5), Joint.butt(1.5, 0.8), Joint.butt(0.2, -2.5), Joint.fillet(60.0),
    Joint.fillet(140.0), Joint.lap(1.0, -1), Joint.lap(3.0, 1),
]  # fmt: skip


@settings(max_examples=150, deadline=None)
@given(
    st.sampled_from(_STATS_JOINTS),
    st.integers(1, 8),
    st.floats(-8.0, 8.0),
    st.floats(-6.0, 6.0),
    st.floats(-50.0, 50.0),
    st.integers(0, 300),
)
def test_straight_seam_statistics_equal_every_sub_column(
    joint: Joint, k: int, seam_y: float, seam_z: float, roll: float, first: int
) -> None:
    """The straight-seam renderer takes the mean and spread of a column lit by one piece
    from its outer sub-columns (rows affine in u there); against the statistics of all K
    sub-columns' hits (``hits``): the same lit, simple and complex columns, rows to 1e-8 px."""
    scene = Scene(joint, SeamPath.straight())
    r = StripeRenderer(scene, settings=RenderSettings(subsamples=k), rng=np.random.default_rng(0))
    pose = scripted_pose(
        scene.sensor_over_seam(0.0, seam_y, seam_z, roll), velocity_mm_s=(80.0, -300.0, 400.0)
    )
    n = 512 - first
    times = np.linspace(0.0, 6.8e-6 * (n - 1), n)
    assert r.straight is not None
    fast = r.straight.stats(first, times, pose)
    hit, rows = r.hits(np.arange(first, 512), times, pose)
    coverage, mean, var = sub_column_stats(hit, rows, k)
    np.testing.assert_array_equal(fast.coverage, coverage)
    lit = coverage > 0
    np.testing.assert_allclose(fast.mean[lit], mean[lit], rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast.var[lit], var[lit], rtol=0, atol=1e-8)
    simple = lit & (var <= SIMPLE_SPREAD_PX**2)
    np.testing.assert_array_equal(fast.simple, simple)
    complex_columns = np.flatnonzero(lit & ~simple)
    np.testing.assert_array_equal(fast.complex_columns, complex_columns)
    for got, c in zip(fast.complex_rows, complex_columns, strict=True):
        want = np.sort(rows[c][hit[c]])
        np.testing.assert_allclose(np.sort(got[got != UNLIT_ROW]), want, rtol=0, atol=1e-8)
