"""Seam detector: accuracy against the scene's truth, timing of the seam column, robustness."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sensorsocket.camera import CameraGeometry, StripeRenderer
from sensorsocket.detector import DetectorConfig, SeamDetector, SeamStatus
from sensorsocket.emulator import CameraEmulator
from sensorsocket.scene import Joint, JointType, Scene, SeamPath, fixed_pose, scripted_pose
from sensorsocket.timing import TimingModel

CAM = CameraGeometry()
JOINTS = [Joint.butt(0.4), Joint.fillet(90.0), Joint.lap(1.0), Joint.lap(0.5, upper_side=1)]


def _detector(kind: JointType) -> SeamDetector:
    return SeamDetector(CAM, DetectorConfig(joint=kind))


@pytest.mark.parametrize("joint", JOINTS, ids=lambda j: f"{j.kind.value}-{j.upper_side}")
@pytest.mark.parametrize("path", [SeamPath.straight(), SeamPath.paper_sine()], ids=["line", "sine"])
def test_static_seam_accuracy(joint: Joint, path: SeamPath) -> None:
    """Seam position error ≤ 10 µm rms in S over random static poses, per joint type."""
    rng = np.random.default_rng(11)
    scene = Scene(joint, path)
    renderer = StripeRenderer(scene, rng=rng)
    det = _detector(joint.kind)
    errors, rolls = [], []
    for _ in range(25):
        pose = scene.sensor_over_seam(
            rng.uniform(0, 50),
            seam_y_mm=rng.uniform(-3, 3),
            seam_z_mm=rng.uniform(-2, 2),
            roll_deg=rng.uniform(-5, 5),
        )
        truth = scene.seam2sensor(pose[None])[0]
        frame, _ = renderer.render(0, np.zeros(512), fixed_pose(pose))
        d = det.detect(frame)
        assert d.status is SeamStatus.FOUND, d.status
        assert 0.5 < d.quality <= 1.0
        errors.append(d.seam2sensor[:3, 3] - truth[:3, 3])
        # roll about x_S: the measured surface normal against the true one
        rolls.append(np.arctan2(d.seam2sensor[2, 1], d.seam2sensor[1, 1]))
        rolls[-1] -= np.arctan2(truth[2, 1], truth[1, 1])
        # the reported column is where the seam is in the image
        assert d.column == pytest.approx(float(CAM.project(truth[:3, 3])[0]), abs=0.5)
    e = np.array(errors)
    assert np.sqrt(np.mean(np.sum(e**2, axis=1))) <= 0.010
    assert np.degrees(np.sqrt(np.mean(np.square(rolls)))) < 0.5


@pytest.mark.parametrize("joint", JOINTS[:3], ids=lambda j: j.kind.value)
def test_moving_sensor_seam_belongs_to_its_column_time(joint: Joint) -> None:
    """Sensor crossing the seam at 250 mm/s: the seam matches the pose at its column's time."""
    rng = np.random.default_rng(12)
    scene = Scene(joint, SeamPath.straight())
    start = scene.sensor_over_seam(0.0, seam_y_mm=1.5)
    across = start[:3, 1] * 250.0  # along y_S, perpendicular to the seam
    motion = scripted_pose(start, velocity_mm_s=across)
    emu = CameraEmulator(scene, motion, TimingModel(rng=rng), rng=rng)
    checked = 0
    for t in np.arange(0.0, 0.012, 0.002):
        m = emu.measure(emu.acquire(float(t)))
        assert m.found
        at_column = scene.seam2sensor(motion(np.array([m.t_seam])))[0, :3, 3]
        at_start = scene.seam2sensor(motion(np.array([m.t_exposure_start])))[0, :3, 3]
        at_end = scene.seam2sensor(motion(np.array([m.t_exposure_end])))[0, :3, 3]
        assert abs(m.seam2sensor[1, 3] - at_column[1]) < 0.015
        # the readout lasts 3.5 ms = 0.875 mm of motion: start and end are far off
        assert abs(at_start[1] - at_end[1]) == pytest.approx(0.875, rel=0.01)
        assert abs(m.seam2sensor[1, 3] - at_start[1]) > 0.2
        assert m.t_exposure_start < m.t_seam < m.t_exposure_end
        checked += 1
    assert checked == 6


def _frame(joint: Joint, seed: int = 1, **kw: float) -> np.ndarray:
    scene = Scene(joint)
    frame, _ = StripeRenderer(scene, rng=np.random.default_rng(seed)).render(
        0, np.zeros(512), fixed_pose(scene.sensor_over_seam(0.0, **kw))
    )
    return frame


def test_no_stripe() -> None:
    rng = np.random.default_rng(13)
    dark = np.clip(rng.normal(8, 2, (512, 256)), 0, 255).astype(np.uint8)
    for kind in JointType:
        d = _detector(kind).detect(dark)
        assert d.status is SeamStatus.NO_STRIPE and not d.found and d.quality == 0.0
        np.testing.assert_array_equal(d.seam2sensor, np.eye(4))
    d = _detector(JointType.BUTT).detect(np.zeros((512, 256), dtype=np.uint8))
    assert d.status is SeamStatus.NO_STRIPE


def test_saturated_stripe_still_measures() -> None:
    scene = Scene(Joint.lap(1.0))
    pose = scene.sensor_over_seam(0.0, seam_y_mm=0.7)
    frame, truth = StripeRenderer(scene, rng=np.random.default_rng(14)).render(
        0, np.zeros(512), fixed_pose(pose), exposure_s=4 * 3.5e-3 / 512
    )
    assert (frame == 255).sum(axis=1).mean() >= 2  # flat-topped, clipped stripe
    det = _detector(JointType.LAP)
    stripe = det.stripe(frame)
    use = truth.simple & (truth.coverage == 1) & stripe.valid
    assert use.sum() > 450
    assert np.sqrt(np.mean((stripe.rows - truth.center_row)[use] ** 2)) < 0.15
    d = det.detect(frame)
    assert d.found
    assert d.seam2sensor[1, 3] == pytest.approx(0.7, abs=0.03)


def test_stripe_leaving_the_image() -> None:
    # fillet seam far to the side: one plate leaves the field of view -> no corner
    d = _detector(JointType.FILLET).detect(_frame(Joint.fillet(), seam_y_mm=9.8))
    assert d.status in (SeamStatus.NO_FEATURE, SeamStatus.NO_STRIPE)
    # whole profile beyond the depth range
    d = _detector(JointType.BUTT).detect(_frame(Joint.butt(0.4), seam_z_mm=12.0))
    assert d.status is SeamStatus.NO_STRIPE


def test_wrong_joint_type_reports_no_feature() -> None:
    d = _detector(JointType.LAP).detect(_frame(Joint.fillet()))
    assert d.status is SeamStatus.NO_FEATURE
    d = _detector(JointType.BUTT).detect(_frame(Joint.lap(1.0)))
    assert d.status is SeamStatus.NO_FEATURE


def test_reflections_are_ignored_or_reported() -> None:
    frame = _frame(Joint.fillet(), seam_y_mm=0.5).copy()
    rng = np.random.default_rng(15)
    # specular glints: short bright streaks at wrong rows in a few columns
    for u in rng.choice(np.arange(20, 490), 12, replace=False):
        frame[u, 20:26] = 250
    d = _detector(JointType.FILLET).detect(frame)
    assert d.found and d.seam2sensor[1, 3] == pytest.approx(0.5, abs=0.02)


def test_missing_stretch_of_stripe() -> None:
    # lap joint with the stripe missing over 40 columns away from the step: still found
    frame = _frame(Joint.lap(1.0), seam_y_mm=-2.0).copy()
    frame[350:390] = 8
    d = _detector(JointType.LAP).detect(frame)
    assert d.found and d.seam2sensor[1, 3] == pytest.approx(-2.0, abs=0.02)
    # fillet with the corner itself missing: refuse to extrapolate
    frame = _frame(Joint.fillet(), seam_y_mm=0.0).copy()
    frame[230:282] = 8
    d = _detector(JointType.FILLET).detect(frame)
    assert d.status is SeamStatus.NO_FEATURE
    # butt joint plus a dropout as wide as the gap: two candidate gaps
    frame = _frame(Joint.butt(0.4), seam_y_mm=-2.0).copy()
    frame[400:410] = 8
    d = _detector(JointType.BUTT).detect(frame)
    assert d.status is SeamStatus.AMBIGUOUS


def test_bad_images_give_a_status() -> None:
    det = _detector(JointType.BUTT)
    for bad in (
        np.zeros((512,), dtype=np.uint8),
        np.zeros((512, 5), dtype=np.uint8),
        np.zeros((0, 256), dtype=np.uint8),
        np.array([["a"] * 20] * 20),
    ):
        assert det.detect(bad).status is SeamStatus.BAD_IMAGE
    nan_frame = np.full((512, 256), np.nan)
    assert det.detect(nan_frame).status is SeamStatus.NO_STRIPE
    # uint16 and float images from elsewhere work too
    frame = _frame(Joint.butt(0.4), seam_y_mm=1.0)
    for other in (frame.astype(np.uint16) * 256, frame.astype(np.float32) / 255.0):
        d = det.detect(other)
        assert d.found and d.seam2sensor[1, 3] == pytest.approx(1.0, abs=0.01)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(list(JointType)), st.integers(1, 512))
def test_random_images_never_raise(seed: int, kind: JointType, n_columns: int) -> None:
    rng = np.random.default_rng(seed)
    style = seed % 4
    if style == 0:
        img = rng.integers(0, 256, (n_columns, 256), dtype=np.uint8)
    elif style == 1:
        img = np.full((n_columns, 256), rng.integers(0, 256), dtype=np.uint8)
    elif style == 2:  # sparse bright blobs
        img = (rng.random((n_columns, 256)) > 0.995).astype(np.uint8) * 255
    else:  # random stripe rows with random brightness
        img = np.zeros((n_columns, 256), dtype=np.uint8)
        rows = rng.integers(0, 256, n_columns)
        img[np.arange(n_columns), rows] = rng.integers(0, 256, n_columns)
    d = _detector(kind).detect(img, first_column=int(rng.integers(0, 512 - n_columns + 1)))
    assert isinstance(d.status, SeamStatus)
    assert 0.0 <= d.quality <= 1.0
    assert d.seam2sensor.shape == (4, 4) and np.isfinite(d.seam2sensor).all()
    if style == 0:
        assert not d.found


@pytest.mark.parametrize("joint", JOINTS, ids=lambda j: f"{j.kind.value}-{j.upper_side}")
def test_frame_memory_layout_does_not_matter(joint: Joint) -> None:
    """A Fortran-ordered or strided frame gives the same detection as a C-ordered one."""
    frame = _frame(joint, seed=23, seam_y_mm=0.8)
    det = _detector(joint.kind)
    d = det.detect(frame)
    assert d.found
    padded = np.zeros((512, 512), dtype=np.uint8)
    padded[:, ::2] = frame
    for other in (np.asfortranarray(frame), padded[:, ::2]):
        e = det.detect(other)
        assert e.status is d.status
        np.testing.assert_allclose(e.seam2sensor, d.seam2sensor, atol=1e-9)
        assert e.column == pytest.approx(d.column, abs=1e-9)


@settings(max_examples=100, deadline=None)
@given(
    st.integers(0, 500),
    st.integers(1, 20),
    st.floats(-3.0, 3.0),
    st.floats(-0.5, 0.5),
)
def test_line_rows_equal_the_calibration_per_column(u0: int, n: int, a: float, b: float) -> None:
    """The rows where a plate's line crosses a run of columns, from the two end columns
    (the image of a line is a line), equal the calibration's line_row at every column."""
    from sensorsocket.detector import _Line

    det = SeamDetector()
    cols = list(range(u0, min(u0 + n, 512)))
    rows = det._line_rows(cols, _Line(a=a, b=b, rms=0.0, n=10))
    u = np.array(cols, dtype=np.float64)
    exact = det.camera.line_row(u, np.full(u.size, a), np.full(u.size, b))
    np.testing.assert_allclose(rows, exact, rtol=0.0, atol=1e-9)
    assert det._line_rows([], _Line(a=a, b=b, rms=0.0, n=10)) == []


def _plain_robust_line(
    y: np.ndarray, z: np.ndarray, iterations: int = 2
) -> tuple[float, float, float, int]:
    """The documented robust fit in plain numpy: polyfit, drop points beyond 3.5 robust
    sigma (at least 10 µm) of the residuals of the points fitted, refit, until the kept set
    repeats; returns (a, b, rms, points in the last fit)."""
    keep = np.ones(y.size, dtype=bool)
    a = b = rms = 0.0
    for it in range(iterations + 1):
        b, a = np.polyfit(y[keep], z[keep], 1)
        rms = float(np.sqrt(np.mean((z[keep] - a - b * y[keep]) ** 2)))
        if it == iterations:
            break
        res = np.abs(z - a - b * y)
        limit = max(3.5 * 1.4826 * float(np.median(res[keep])), 0.01)
        new_keep = res <= limit
        if (new_keep == keep).all():
            break
        keep = new_keep
    return float(a), float(b), rms, int(keep.sum())


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(20, 400),
    slope=st.floats(-0.5, 0.5),
    noise=st.floats(0.002, 0.05),
    outliers=st.floats(0.0, 0.2),
    subset=st.booleans(),
)
def test_robust_line_equals_a_plain_fit(
    seed: int, n: int, slope: float, noise: float, outliers: float, subset: bool
) -> None:
    """The fits from moment rows (one matrix-vector product per fit) against polyfit on the
    same points, for a slice of the profile or a subset given as a mask."""
    from sensorsocket.detector import _centred, _robust_line

    rng = np.random.default_rng(seed)
    y = np.sort(rng.uniform(-8.0, 8.0, n))
    z = 1.5 + slope * y + rng.normal(0.0, noise, n)
    bad = rng.random(n) < outliers
    z[bad] += rng.choice([-1.0, 1.0], int(bad.sum())) * rng.uniform(0.3, 2.0, int(bad.sum()))
    mask = rng.random(n) < 0.7 if subset else np.ones(n, dtype=bool)
    line = _robust_line(_centred(y, z), mask if subset else slice(None))
    a, b, rms, kept = _plain_robust_line(y[mask], z[mask])
    assert line is not None
    assert line.n == kept
    assert line.a == pytest.approx(a, abs=1e-9)
    assert line.b == pytest.approx(b, abs=1e-9)
    assert line.rms == pytest.approx(rms, abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-10.0, 10.0), min_size=1, max_size=60),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(0.0, 2.0),
)
def test_fillet_sides_as_slices_equal_the_masks(
    ys: list[float], split: float, margin: float
) -> None:
    """Where the profile's y ascends, the fillet's sides are slices from two binary
    searches: the same points as the plain masks y < split - margin and y > split + margin
    (ties, NaN and infinite bounds included)."""
    from sensorsocket.detector import _beside, _same

    y = np.sort(np.array(ys))
    lo, hi = split - margin, split + margin
    left, right = _beside(y, True, lo, hi)
    mask_l, mask_r = _beside(y, False, lo, hi)
    assert isinstance(left, slice) and isinstance(right, slice)
    assert isinstance(mask_l, np.ndarray) and isinstance(mask_r, np.ndarray)
    np.testing.assert_array_equal(np.arange(y.size)[left], np.flatnonzero(mask_l))
    np.testing.assert_array_equal(np.arange(y.size)[right], np.flatnonzero(mask_r))
    assert _same(left, _beside(y, True, lo, hi)[0]) and _same(mask_r, y > hi)


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(3, 80),
    glints=st.integers(0, 4),
    step=st.booleans(),
    tol=st.sampled_from([0.15, 0.0, -0.1]),
)
def test_outlier_mask_equals_the_running_median(
    seed: int, n: int, glints: int, step: bool, tol: float
) -> None:
    """The outliers' quick test (no two large neighbouring steps) and the full test give
    the plain rule: keep a point within tol of the median of itself and its neighbours."""
    from sensorsocket.detector import _not_isolated_outliers

    rng = np.random.default_rng(seed)
    z = 1.0 + 0.02 * np.arange(n) + rng.normal(0.0, 0.01, n)
    if step:  # a lap's step: one large jump, no outlier
        z[n // 2 :] += 1.0
    z[rng.integers(0, n, glints)] += rng.uniform(-2.0, 2.0, glints)
    med = np.median(np.stack([z[:-2], z[1:-1], z[2:]]), axis=0)
    want = np.ones(n, dtype=bool)
    want[1:-1] = np.abs(z[1:-1] - med) <= tol
    got = _not_isolated_outliers(z, np.abs(np.diff(z)), tol)
    np.testing.assert_array_equal(want, np.ones(n, dtype=bool) if got is None else got)
