"""Triangulation geometry, stripe renderer, frame layout, PGM files and the emulator."""

from __future__ import annotations

from pathlib import Path
from statistics import NormalDist

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensorsocket.camera import (
    CameraError,
    CameraGeometry,
    RenderSettings,
    StripeRenderer,
    frame_from_image,
    image_rows,
)
from sensorsocket.detector import SeamDetector, SeamStatus
from sensorsocket.emulator import CameraEmulator, SettingsError
from sensorsocket.pgm import PgmError, parse_pgm, read_frame, read_pgm, write_frame
from sensorsocket.scene import (
    FloatArray,
    Joint,
    Scene,
    SeamPath,
    fixed_pose,
    rot_x,
    scripted_pose,
)
from sensorsocket.timing import TimingModel

CAM = CameraGeometry()


def _scene_and_pose(joint: Joint, **kw: float) -> tuple[Scene, np.ndarray]:
    scene = Scene(joint, SeamPath.straight())
    return scene, scene.sensor_over_seam(0.0, **kw)


def test_frame_layout_is_column_major() -> None:
    scene, pose = _scene_and_pose(Joint.lap(1.0), seam_y_mm=2.0)
    r = StripeRenderer(scene, rng=np.random.default_rng(1))
    frame, truth = r.render(0, np.zeros(512), fixed_pose(pose))
    assert frame.shape == (512, 256) and frame.dtype == np.uint8
    assert frame.flags.c_contiguous
    assert frame.strides == (256, 1)  # one column = 256 contiguous bytes
    # the stripe's brightest row in column u is the truth row of column u
    u = 100
    assert abs(int(frame[u].argmax()) - truth.center_row[u]) <= 1.0
    rows = image_rows(frame)
    assert rows.shape == (256, 512) and np.shares_memory(rows, frame)
    np.testing.assert_array_equal(rows[:, u], frame[u])
    np.testing.assert_array_equal(frame_from_image(rows), frame)


def test_readout_window_and_laser_off() -> None:
    scene, pose = _scene_and_pose(Joint.butt(0.5))
    r = StripeRenderer(scene, rng=np.random.default_rng(2))
    frame, _ = r.render(100, np.zeros(200), fixed_pose(pose))
    assert not frame[:100].any() and not frame[300:].any()
    assert frame[100:300].max() > 100
    dark, _ = r.render(0, np.zeros(512), fixed_pose(pose), laser_on=False)
    assert dark.max() < 40  # background and read noise only
    with pytest.raises(CameraError):
        r.render(500, np.zeros(20), fixed_pose(pose))


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
    pool = np.asarray(r._normals, dtype=np.float64)
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


@pytest.mark.parametrize("read_noise", [0.5, 1.5, 2.5])
def test_stripe_centre_accuracy(read_noise: float) -> None:
    """Sub-pixel stripe centre ≤ 0.05 px rms, bias ≤ 0.01 px, against the rendered truth."""
    rng = np.random.default_rng(int(read_noise * 10))
    scene = Scene(Joint.lap(1.0))
    r = StripeRenderer(scene, settings=RenderSettings(read_noise_dn=read_noise), rng=rng)
    det = SeamDetector()
    errors = []
    for _ in range(20):
        pose = scene.sensor_over_seam(
            0.0,
            seam_y_mm=rng.uniform(-2, 2),
            seam_z_mm=rng.uniform(-3, 3),
            roll_deg=rng.uniform(-8, 8),
        )
        frame, truth = r.render(0, np.zeros(512), fixed_pose(pose))
        stripe = det.stripe(frame)
        use = truth.simple & (truth.coverage == 1.0)
        assert stripe.valid[use].mean() > 0.99
        errors.append((stripe.rows - truth.center_row)[use & stripe.valid])
    e = np.concatenate(errors)
    assert e.size > 9000
    assert np.sqrt(np.mean(e**2)) <= 0.05
    assert abs(e.mean()) <= 0.01


def test_motion_during_readout_shows_in_the_image() -> None:
    """Columns are exposed one after another: column u shows the pose at its own time."""
    scene = Scene(Joint.lap(1.0))
    pose = scene.sensor_over_seam(0.0, seam_y_mm=-8.0)
    times = np.arange(512) * 3.5e-3 / 512
    r = StripeRenderer(scene, rng=np.random.default_rng(4))
    away = pose[:3, 2] * -1000.0  # the sensor moves away from the plate at 1 m/s
    _, t_move = r.render(0, times, scripted_pose(pose, velocity_mm_s=away))
    for u in (40, 200, 450):
        # still sensor where the moving one was when column u was exposed
        still = pose.copy()
        still[:3, 3] += away * times[u]
        _, t_still = r.render(0, times, fixed_pose(still))
        assert t_move.center_row[u] == pytest.approx(t_still.center_row[u], abs=1e-9)
    # and the motion is visible: by column 450 the plate looks about 3 mm deeper
    _, t_start = r.render(0, times, fixed_pose(pose))
    assert t_move.center_row[450] - t_start.center_row[450] > 40.0


class _NodeProvider:
    """Poses linear in time between a few node poses (with small tilts about x_S), offered
    per time and as nodes with weights (NodePoseProvider); ``hook`` False hides the nodes."""

    def __init__(self, scene: Scene, rng: np.random.Generator, *, hook: bool = True) -> None:
        self.t_nodes = np.linspace(-1e-3, 5e-3, 6)
        nodes = []
        for t in self.t_nodes:
            pose = scene.sensor_over_seam(0.0, seam_y_mm=float(rng.uniform(-6.0, 6.0)))
            pose[:3, :3] = pose[:3, :3] @ rot_x(float(rng.uniform(-0.05, 0.05)))
            pose[:3, 3] += rng.uniform(-1.0, 1.0, 3) + 100.0 * t
            nodes.append(pose.reshape(16))
        self.nodes = np.array(nodes)
        self.hook = hook
        self.calls = 0

    def weights(self, times: FloatArray) -> FloatArray:
        eye = np.eye(len(self.t_nodes))
        return np.array([np.interp(times, self.t_nodes, row) for row in eye])

    def __call__(self, times: FloatArray) -> FloatArray:
        out: FloatArray = (self.weights(times).T @ self.nodes).reshape(-1, 4, 4)
        return out

    def node_poses(self, times: FloatArray) -> tuple[FloatArray, FloatArray] | None:
        self.calls += 1
        return (self.nodes, self.weights(times)) if self.hook else None


@pytest.mark.parametrize("joint", [Joint.butt(), Joint.fillet(), Joint.lap(2.0)], ids=str)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_node_pose_hook_renders_the_same_frames(joint: Joint, seed: int) -> None:
    """A provider that offers node poses and weights renders the same frame as the same
    poses given per column (mean rows within 1e-9 px); readout windows included."""
    scene = Scene(joint)
    for first, n in ((0, 512), (100, 300)):
        times = 0.5e-3 + np.arange(n) * 3.5e-3 / 512
        out = []
        for hook in (True, False):
            provider = _NodeProvider(scene, np.random.default_rng(seed), hook=hook)
            r = StripeRenderer(scene, rng=np.random.default_rng(seed))
            frame, truth = r.render(first, times, provider)
            assert provider.calls == 1  # asked once; without nodes it fell back to __call__
            out.append((frame, truth))
        (f_hook, t_hook), (f_plain, t_plain) = out
        assert np.array_equal(f_hook, f_plain)
        assert np.array_equal(t_hook.simple, t_plain.simple)
        assert np.array_equal(t_hook.coverage, t_plain.coverage)
        assert t_hook.simple.sum() > n // 4  # the stripe is in view, the check not vacuous
        assert np.allclose(t_hook.center_row, t_plain.center_row, rtol=0.0, atol=1e-9,
                           equal_nan=True)  # fmt: skip


def test_node_pose_hook_shapes_are_checked() -> None:
    scene = Scene(Joint.butt())
    provider = _NodeProvider(scene, np.random.default_rng(0))
    provider.nodes = provider.nodes[:, :12]
    r = StripeRenderer(scene, rng=np.random.default_rng(0))
    with pytest.raises(CameraError, match="node pose provider"):
        r.render(0, np.arange(512) * 1e-5, provider)


def test_pgm_round_trip(tmp_path: Path) -> None:
    scene, pose = _scene_and_pose(Joint.fillet())
    frame, _ = StripeRenderer(scene, rng=np.random.default_rng(5)).render(
        0, np.zeros(512), fixed_pose(pose)
    )
    path = tmp_path / "frame.pgm"
    write_frame(path, frame)
    data = path.read_bytes()
    assert data.startswith(b"P5\n512 256\n255\n") and len(data) == 15 + 512 * 256
    np.testing.assert_array_equal(read_frame(path), frame)
    assert read_pgm(path).shape == (256, 512)
    assert not list(tmp_path.glob("*.tmp"))
    plain = parse_pgm(b"P2\n# comment\n3 2\n15\n0 1 2\n3 4 15\n")
    np.testing.assert_array_equal(plain, [[0, 1, 2], [3, 4, 15]])
    for bad in (b"P6\n1 1\n255\n\x00", b"P5\n4 4\n255\n\x00", b"P5\nx 4\n255\n"):
        with pytest.raises(PgmError):
            parse_pgm(bad)


def _emulator(**kw: object) -> CameraEmulator:
    scene = Scene(Joint.butt(0.4))
    rng = np.random.default_rng(6)
    return CameraEmulator(
        scene,
        fixed_pose(scene.sensor_over_seam(0.0, seam_y_mm=1.0)),
        TimingModel(rng=rng),
        rng=rng,
    )


def test_emulator_acquire_and_measure() -> None:
    emu = _emulator()
    f0 = emu.acquire(1.0)
    f1 = emu.acquire(1.004)
    assert (f0.index, f1.index) == (0, 1)
    assert f0.image.shape == (512, 256) and f0.rows_view.shape == (256, 512)
    a = f1.acquisition
    assert 1.004 <= a.t_poll <= a.t_exposure_start <= 1.004 + 0.5e-3
    assert a.t_exposure_end - a.t_exposure_start == pytest.approx(3.5e-3)
    m = emu.measure(f1)
    assert m.found and m.status is SeamStatus.FOUND and 0.5 < m.quality <= 1.0
    assert m.seam2sensor[1, 3] == pytest.approx(1.0, abs=0.01)
    assert (m.t_arrival, m.t_exposure_start, m.t_exposure_end) == (
        1.004,
        a.t_exposure_start,
        a.t_exposure_end,
    )
    # the seam sits right of the centre column, so it was exposed after mid-readout
    assert a.t_exposure_start + 1.75e-3 < m.t_seam < a.t_exposure_end


def test_emulator_laser_off_and_settings() -> None:
    emu = _emulator()
    emu.set_laser(False)
    m = emu.measure(emu.acquire(0.0))
    assert not m.found and m.status is SeamStatus.NO_STRIPE
    emu.set_laser(True)
    s = emu.configure(first_column=200, n_columns=128, exposure_s=20e-6)
    assert (s.first_column, s.n_columns) == (200, 128)
    assert emu.acquisition_time() == pytest.approx(3.5e-3 / 4)
    f = emu.acquire(1.0)
    assert f.window.shape == (128, 256) and not f.image[:200].any()
    m = emu.measure(f)
    assert m.found and m.seam_column == pytest.approx(280.5, abs=0.5)
    with pytest.raises(SettingsError):
        emu.configure(first_column=500, n_columns=64)
    with pytest.raises(SettingsError):
        emu.configure(exposure_s=1.0)


def test_hits_of_any_column_set_match_the_full_window() -> None:
    """Columns are independent: hits() on scattered columns (own constants) equals the same
    columns of a full-window render pass (cached constants), for a moving sensor."""
    scene = Scene(Joint.lap(), SeamPath.paper_sine())
    pose = scripted_pose(
        scene.sensor_over_seam(3.0, 0.8, -0.4, 10.0), velocity_mm_s=(50.0, 0.0, 0.0)
    )
    renderer = StripeRenderer(scene, rng=np.random.default_rng(0))
    times = np.arange(512) * 6.8e-6
    hit_all, rows_all = renderer.hits(np.arange(512), times, pose)
    pick = np.array([3, 17, 200, 255, 256, 400, 511])
    hit, rows = renderer.hits(pick, times[pick], pose)
    assert hit.any()
    assert np.array_equal(hit, hit_all[pick])
    np.testing.assert_allclose(rows[hit], rows_all[pick][hit], rtol=0, atol=1e-9)
    # the cached window path gives the same rows as the public one
    win_hit, win_rows = renderer._hits(renderer._window(0, 512), times, pose)
    assert np.array_equal(win_hit, hit_all)
    assert np.array_equal(win_rows[win_hit], rows_all[hit_all])


@pytest.mark.parametrize(
    "joint", [Joint.butt(0.5), Joint.butt(0.5, 0.4), Joint.butt(0.5, -0.4), Joint.lap(1.0, 1)]
)
def test_skipped_shadow_tests_change_nothing(joint: Joint, monkeypatch: pytest.MonkeyPatch) -> None:
    """The renderer skips shadow tests a flat piece cannot pass (it is not above the lit one);
    with every test run the hits are the same."""
    import sensorsocket.camera as camera_module

    scene = Scene(joint, SeamPath.straight())
    times = np.arange(512) * 6.8e-6
    for roll in (-12.0, 0.0, 12.0):
        pose = scripted_pose(
            scene.sensor_over_seam(0.0, 0.3, -0.4, roll), velocity_mm_s=(50.0, 0.0, 0.0)
        )
        fast = StripeRenderer(scene, rng=np.random.default_rng(0)).hits(np.arange(512), times, pose)
        with monkeypatch.context() as m:
            m.setattr(camera_module, "_never_shadows", lambda *a: False)
            full = StripeRenderer(scene, rng=np.random.default_rng(0)).hits(
                np.arange(512), times, pose
            )
        assert np.array_equal(fast[0], full[0])
        np.testing.assert_array_equal(fast[1][fast[0]], full[1][full[0]])


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
    from sensorsocket.camera import _sub_column_stats

    scene = Scene(joint, SeamPath.straight())
    r = StripeRenderer(scene, settings=RenderSettings(subsamples=k), rng=np.random.default_rng(0))
    pose = scripted_pose(
        scene.sensor_over_seam(0.0, seam_y, seam_z, roll), velocity_mm_s=(80.0, -300.0, 400.0)
    )
    n = 512 - first
    times = np.linspace(0.0, 6.8e-6 * (n - 1), n)
    fast = r._stats(first, times, pose)
    hit, rows = r.hits(np.arange(first, 512), times, pose)
    coverage, mean, var = _sub_column_stats(hit, rows, k)
    np.testing.assert_array_equal(fast.coverage, coverage)
    lit = coverage > 0
    np.testing.assert_allclose(fast.mean[lit], mean[lit], rtol=0, atol=1e-8)
    np.testing.assert_allclose(fast.var[lit], var[lit], rtol=0, atol=1e-8)
    simple = lit & (var <= 0.3**2)
    np.testing.assert_array_equal(fast.simple, simple)
    complex_columns = np.flatnonzero(lit & ~simple)
    np.testing.assert_array_equal(fast.complex_columns, complex_columns)
    for got, c in zip(fast.complex_rows, complex_columns, strict=True):
        want = np.sort(rows[c][hit[c]])
        np.testing.assert_allclose(np.sort(got[got > -1e8]), want, rtol=0, atol=1e-8)
