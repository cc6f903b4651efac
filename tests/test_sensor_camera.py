"""Triangulation geometry, stripe renderer, frame layout, PGM files and the emulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kinematics.types import FloatArray
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
from sensorsocket.scene import Joint, Scene, SeamPath, fixed_pose, rot_x, scripted_pose
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
    times = np.arange(512, dtype=np.float64) * 3.5e-3 / 512
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
        times = 0.5e-3 + np.arange(n, dtype=np.float64) * 3.5e-3 / 512
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
        r.render(0, np.arange(512, dtype=np.float64) * 1e-5, provider)


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
