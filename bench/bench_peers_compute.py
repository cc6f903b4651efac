"""Computation against peer libraries (issue 20): FK and single-pose IK against
roboticstoolbox (C extension ``ETS.eval``, C++ ``ik_LM``), the stripe stage against a
numpy and an OpenCV (Gaussian blur 5x5) centre of gravity, with accuracy against the
renderer's truth, and the ΔT estimate against ``scipy.signal.correlate`` at 250 Hz.

Ours and the peer alternate in rounds; each figure is the best round, timed at the machine's
full speed (``bench.pace``), and ours carries the speed it was measured at.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bench.common import Result, result
from bench.pace import PacedTiming, time_at_full_speed
from bench.peers import peer
from kinematics.robot import RobotModel, get_model
from sensorsocket.camera import StripeRenderer
from sensorsocket.detector import DetectorConfig
from sensorsocket.scene import Joint, Scene, fixed_pose
from sensorsocket.stripe import StripeFinder
from sync.delay import estimate_delay, simulate_sine_experiment

ROUNDS = 3


def _interleaved(
    ours: Callable[[], object], theirs: Callable[[], object]
) -> tuple[PacedTiming, PacedTiming]:
    """Best time per call of each, measured alike in alternating rounds."""
    a = b = PacedTiming(math.inf, 0.0)
    for _ in range(ROUNDS):
        a = min(a, _paced(ours), key=_seconds)
        b = min(b, _paced(theirs), key=_seconds)
    return a, b


def _paced(fn: Callable[[], object]) -> PacedTiming:
    return time_at_full_speed(fn, round_time=0.033, rounds=3, budget=1.0)


def _seconds(t: PacedTiming) -> float:
    return t.seconds


def _rtb_ets(rtb: Any, m: RobotModel) -> Any:
    """The arm as an rtb ETS in metres, joint angles θ = q + offset (radians)."""
    ET = rtb.ET
    a1, d = m.shoulder_offset_mm / 1e3, m.lateral_offset_mm / 1e3
    return rtb.ETS(
        [
            ET.Rz(),
            ET.tx(a1),
            ET.ty(d),
            ET.Ry(),
            ET.tz(m.upper_arm_mm / 1e3),
            ET.Ry(),
            ET.tz(m.forearm_mm / 1e3),
            ET.Rz(),
            ET.Ry(),
            ET.Rz(),
            ET.tz(m.wrist_to_flange_mm / 1e3),
        ]
    )


def _kinematics(results: list[Result]) -> None:
    rtb = peer("roboticstoolbox", "FK/IK vs roboticstoolbox")
    if rtb is None:
        return
    m = get_model("RX90B")
    ets = _rtb_ets(rtb, m)
    off = np.array(m.joint_offsets_deg)
    q = np.array([10.0, 20.0, 30.0, 40.0, 50.0, 60.0])
    theta = np.radians(q + off)
    T = m.flange2base(q)
    T_m = T.copy()
    T_m[:3, 3] /= 1e3
    # The same arm, or the comparison means nothing.
    if not np.allclose(ets.eval(theta), T_m, atol=1e-12):
        raise RuntimeError("the roboticstoolbox model is not the RX90B")
    a, b = _interleaved(lambda: m.flange2base(q), lambda: ets.eval(theta))
    results.append(
        result(
            "kinematics.fk single RX90B",
            a.seconds * 1e6,
            "µs",
            "rtb ETS.eval",
            b.seconds * 1e6,
            machine_speed=a.speed,
        )
    )

    n = 100_000
    Q = np.random.default_rng(1).uniform(m.limits[:, 0], m.limits[:, 1], (n, 6))
    TH = np.radians(Q + off)
    a, b = _interleaved(lambda: m.flange2base_batch(Q), lambda: ets.eval(TH))
    results.append(
        result(
            "kinematics.fk batch 100k",
            n / a.seconds,
            "configs/s",
            "rtb ETS.eval(Q)",
            n / b.seconds,
            machine_speed=a.speed,
        )
    )

    near = theta + 0.05  # a start close by, as a jog step or ToolMoveJ would give it
    sol = ets.ik_LM(T_m, q0=near, tol=1e-14)
    if not getattr(sol, "success", False):
        raise RuntimeError("rtb ik_LM did not converge")
    a, b = _interleaved(lambda: m.ik(T), lambda: ets.ik_LM(T_m, q0=near, tol=1e-14))
    results.append(
        result(
            "kinematics.ik single pose, all solutions",
            a.seconds * 1e6,
            "µs",
            "rtb C++ ik_LM (tol 1e-14), one solution",
            b.seconds * 1e6,
            machine_speed=a.speed,
        )
    )


def _centre_of_gravity(frame: NDArray[np.float32], threshold: float) -> NDArray[np.float64]:
    """Textbook stripe centre: per column, the thresholded intensity centroid of the rows
    within ±6 of the brightest (the detector's half window)."""
    h = DetectorConfig().half_window
    nrows = frame.shape[1]
    start = np.clip(frame.argmax(axis=1) - h, 0, nrows - 2 * h - 1)
    idx = start[:, None] + np.arange(2 * h + 1)
    light = np.maximum(np.take_along_axis(frame, idx, axis=1) - np.float32(threshold), 0.0)
    mass = light.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray((light * idx).sum(axis=1) / mass, dtype=np.float64)


def _stripe(results: list[Result]) -> None:
    cv2 = peer("cv2", "stripe vs OpenCV blur + CoG")
    cfg = DetectorConfig()
    finder = StripeFinder(cfg.half_window, cfg.noise_factor, cfg.min_contrast_dn, cfg.max_width_px)
    frames, truths = [], []
    # Butt and lap: every lit column holds one stripe (the fillet's corner columns hold two,
    # where no single centre is the truth).
    for seed, joint in enumerate((Joint.butt(), Joint.lap()) * 6):
        scene = Scene(joint)
        frame, truth = StripeRenderer(scene, rng=np.random.default_rng(seed)).render(
            0, np.zeros(512), fixed_pose(scene.sensor_over_seam(0.0))
        )
        frames.append(frame)
        truths.append(truth)

    def rms(centres: Callable[[NDArray[np.uint8]], NDArray[np.float64]], region: str = "") -> float:
        """rms error (px) over the simple columns our detector calls valid; ``region``
        "ends": only those within two columns of a column that is not (stripe ends, the
        lap's step), where a cross-column average has fewer neighbours."""
        err = []
        for f, t in zip(frames, truths, strict=True):
            c = centres(f)
            # the same columns for every method: simple ones our detector calls valid
            ok = t.simple & finder.stripe(f).valid
            if region == "ends":
                ok &= np.convolve(ok, np.ones(5), "same") < 5
            ok &= np.isfinite(c)
            err.append(c[ok] - t.center_row[ok])
        e = np.concatenate(err)
        return float(np.sqrt(np.mean(e * e)))

    def ours(f: NDArray[np.uint8]) -> NDArray[np.float64]:
        return finder.stripe(f).rows

    def numpy_cog(f: NDArray[np.uint8]) -> NDArray[np.float64]:
        thr = finder.stripe(f).threshold  # the same threshold: only the centre differs
        return _centre_of_gravity(f.astype(np.float32), thr)

    k = 0

    def next_frame() -> NDArray[np.uint8]:
        nonlocal k
        k = (k + 1) % len(frames)
        return frames[k]

    thr0 = finder.stripe(frames[0]).threshold
    a, b = _interleaved(
        lambda: finder.stripe(next_frame()),
        lambda: _centre_of_gravity(next_frame().astype(np.float32), thr0),
    )
    acc_ours = rms(ours)
    results.append(
        result(
            "sensor.stripe() 512x256 frames/s",
            1 / a.seconds,
            "frames/s",
            "numpy CoG",
            1 / b.seconds,
            machine_speed=a.speed,
        )
    )
    results.append(
        result("sensor.stripe() rms vs renderer truth", acc_ours, "px", "numpy CoG", rms(numpy_cog))
    )
    if cv2 is None:
        return

    def blurred(f: NDArray[np.uint8]) -> NDArray[np.float32]:
        out: NDArray[np.float32] = cv2.GaussianBlur(f.astype(np.float32), (5, 5), 0)
        return out

    def cv_cog(f: NDArray[np.uint8]) -> NDArray[np.float64]:
        return _centre_of_gravity(blurred(f), finder.stripe(f).threshold)

    a, b = _interleaved(
        lambda: finder.stripe(next_frame()),
        lambda: _centre_of_gravity(blurred(next_frame()), thr0),
    )
    peer_name = "OpenCV GaussianBlur 5x5 + CoG"
    results.append(
        result(
            "sensor.stripe() 512x256 frames/s",
            1 / a.seconds,
            "frames/s",
            peer_name,
            1 / b.seconds,
            machine_speed=a.speed,
        )
    )
    results.append(
        result("sensor.stripe() rms vs renderer truth", acc_ours, "px", peer_name, rms(cv_cog))
    )
    results.append(
        result(
            "sensor.stripe() rms near stripe ends/steps",
            rms(ours, "ends"),
            "px",
            peer_name,
            rms(cv_cog, "ends"),
        )
    )


def _delay(results: list[Result]) -> None:
    signal = peer("scipy.signal", "ΔT vs scipy.signal.correlate")
    if signal is None:
        return
    ex = simulate_sine_experiment(np.random.default_rng(1), frequency_hz=1.5, duration_s=10.0)
    step = 4e-3  # the robot's 250 Hz
    grid = np.arange(ex.t_trigger[0], ex.t_trigger[-1], step)
    max_lag = round(20e-3 / step) + 1

    def correlate() -> float:
        r = np.interp(grid, ex.t_robot, ex.y_robot)
        s = np.interp(grid, ex.t_trigger, ex.y_sensor)
        r = r - r.mean()
        s = s - s.mean()
        c = signal.correlate(r, s, mode="full", method="direct")
        mid = len(s) - 1
        lags = np.arange(-max_lag, max_lag + 1)
        i = int(np.argmax(c[mid + lags]))
        return float(lags[i] * step)

    a, b = _interleaved(
        lambda: estimate_delay(ex.t_robot, ex.y_robot, ex.t_trigger, ex.y_sensor), correlate
    )
    results.append(
        result(
            "sync.estimate_delay (10 s sine, 5 kHz grid)",
            a.seconds * 1e3,
            "ms",
            "scipy.signal.correlate at 250 Hz",
            b.seconds * 1e3,
            machine_speed=a.speed,
        )
    )


def run() -> list[Result]:
    results: list[Result] = []
    _kinematics(results)
    _stripe(results)
    _delay(results)
    return results
