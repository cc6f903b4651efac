"""Benchmarks of the synchronisation core: batch seam reconstruction and the ΔT estimator."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from bench.common import Result, result, time_per_call
from spec.datagrams import SensorData
from spec.wire import SensorStatus
from sync.delay import estimate_delay, simulate_sine_experiment
from sync.interpolate import interpolate_joints
from sync.joint_buffer import JointBuffer
from sync.matcher import SyncMatcher
from sync.seam_chain import seam2base

Batch = Callable[[NDArray[np.float64]], NDArray[np.float64]]


def _flange2base() -> tuple[str, Batch]:
    """The real RX90B DGM when the kinematics package is there, else a stand-in."""
    try:
        from kinematics.robot import get_model

        model = get_model()
        return "kinematics RX90B", model.flange2base_batch
    except ImportError:  # pragma: no cover - only before kinematics exists

        def standin(q: NDArray[np.float64]) -> NDArray[np.float64]:
            # Comparable cost: sin/cos of 6 angles and a product of 6 4x4 rotations.
            a = np.radians(q)
            c, s = np.cos(a), np.sin(a)
            out = np.tile(np.eye(4), (q.shape[0], 1, 1))
            for j in range(6):
                r = np.tile(np.eye(4), (q.shape[0], 1, 1))
                r[:, 0, 0], r[:, 0, 1], r[:, 1, 0], r[:, 1, 1] = c[:, j], -s[:, j], s[:, j], c[:, j]
                r[:, 2, 3] = 400.0
                out = out @ r
            return out

        return "vectorised stand-in DGM", standin


def _seam_batch(results: list[Result]) -> None:
    rng = np.random.default_rng(0)
    n_samples, m = 2500, 100_000
    buf = JointBuffer(capacity=n_samples)
    t = np.arange(n_samples) * 0.004
    buf.extend(t, rng.uniform(-90, 90, (n_samples, 6)))
    times, joints = buf.samples()
    query = rng.uniform(t[0], t[-1], m)
    g2s = np.tile(np.eye(4), (m, 1, 1))
    g2s[:, :3, 3] = rng.normal(0, 5, (m, 3))
    s2f = np.eye(4)
    s2f[2, 3] = 100.0
    name, f2b = _flange2base()

    def reconstruct() -> None:
        q, _ = interpolate_joints(times, joints, query)
        seam2base(q, f2b, s2f, g2s)

    a = np.tile(np.eye(4), (m, 1, 1))
    b = g2s.copy()

    def matmul() -> None:
        np.matmul(a, b)

    t_rec = time_per_call(reconstruct, min_time=1.0, repeat=3)
    t_mm = time_per_call(matmul, min_time=0.5, repeat=3)
    results.append(
        result(
            f"seam points, batch 100k: eq. 5 + {name} + eq. 2 (sync.seam_chain.seam2base)",
            m / t_rec,
            "points/s",
            "numpy matmul of 100k 4x4 pairs",
            m / t_mm,
        )
    )


def _matcher_stream(results: list[Result]) -> None:
    n = 2000
    buf = JointBuffer()
    t = np.arange(2500) * 0.004
    buf.extend(t, np.zeros((2500, 6)))
    found = SensorStatus.FOUND
    seam = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    times, joints = buf.samples()

    def stream() -> None:
        m = SyncMatcher(delta_t_s=0.0049, timeout_s=0.1)
        for i in range(n):
            ti = 0.0013 + 0.004 * i
            m.on_trigger(i, ti)
            m.on_data(SensorData(i, found, seam, 0.9, ti, ti, ti, ti), ti + 0.01)
            m.poll(ti + 0.01, buf)

    def single_interp() -> None:
        for i in range(n):
            interpolate_joints(times, joints, 0.0013 + 0.004 * i + 0.0049)

    t_stream = time_per_call(stream, min_time=1.0, repeat=3)
    t_interp = time_per_call(single_interp, min_time=1.0, repeat=3)
    results.append(
        result(
            "matcher: trigger + data + poll per index (sync.matcher.SyncMatcher)",
            n / t_stream,
            "indices/s",
            "one interpolate_joints call per index",
            n / t_interp,
        )
    )


def _estimator(results: list[Result]) -> None:
    ex = simulate_sine_experiment(np.random.default_rng(1), frequency_hz=1.5, duration_s=10.0)
    grid = np.arange(0, 50001) * 0.2e-3

    def estimate() -> None:
        estimate_delay(ex.t_robot, ex.y_robot, ex.t_trigger, ex.y_sensor)

    def interp() -> None:
        np.interp(grid, ex.t_robot, ex.y_robot)

    t_est = time_per_call(estimate, min_time=1.0, repeat=3)
    t_interp = time_per_call(interp, min_time=0.5, repeat=3)
    results.append(
        result(
            "ΔT estimate, 10 s synthetic experiment, lags 0..20 ms (sync.delay.estimate_delay)",
            t_est * 1e3,
            "ms",
            "one np.interp onto the 5 kHz grid",
            t_interp * 1e3,
        )
    )


def run() -> list[Result]:
    results: list[Result] = []
    _seam_batch(results)
    _matcher_stream(results)
    _estimator(results)
    return results
