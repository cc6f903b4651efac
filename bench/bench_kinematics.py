"""Kinematics: single and batch DGM, batch IK, each against a textbook baseline.

Targets (issue 3, 2-core machine): single DGM <= 20 µs, batch DGM >= 1e6 configurations/s,
batch IK >= 1e5 poses/s with all 8 solutions.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from bench.common import Result, result, time_per_call
from kinematics.robot import RobotModel, get_model

Array = np.ndarray


def _links_single(m: RobotModel, q_deg: list[float]) -> list[Array]:
    """The six link transforms of the chain, one 4x4 numpy matrix each (textbook style)."""
    t = [math.radians(v + o) for v, o in zip(q_deg, m.joint_offsets_deg, strict=True)]
    a1, d = m.shoulder_offset_mm, m.lateral_offset_mm
    c, s = [math.cos(v) for v in t], [math.sin(v) for v in t]

    def rz(i: int, x: float, y: float, z: float) -> Array:
        return np.array(
            [
                [c[i], -s[i], 0.0, c[i] * x - s[i] * y],
                [s[i], c[i], 0.0, s[i] * x + c[i] * y],
                [0.0, 0.0, 1.0, z],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )

    def ry(i: int, z: float) -> Array:
        return np.array(
            [
                [c[i], 0.0, s[i], s[i] * z],
                [0.0, 1.0, 0.0, 0.0],
                [-s[i], 0.0, c[i], c[i] * z],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )

    return [
        rz(0, a1, d, 0.0),
        ry(1, m.upper_arm_mm),
        ry(2, m.forearm_mm),
        rz(3, 0.0, 0.0, 0.0),
        ry(4, 0.0),
        rz(5, 0.0, 0.0, m.wrist_to_flange_mm),
    ]


def textbook_dgm(m: RobotModel, q_deg: list[float]) -> Array:
    A = _links_single(m, q_deg)
    out: Array = A[0] @ A[1] @ A[2] @ A[3] @ A[4] @ A[5]
    return out


def textbook_dgm_batch(m: RobotModel, q_deg: Array) -> Array:
    """Six (N, 4, 4) link stacks and five batched matrix products."""
    n = q_deg.shape[0]
    t = np.radians(q_deg + np.asarray(m.joint_offsets_deg))
    c, s = np.cos(t), np.sin(t)

    def link(i: int, axis: str, x: float, y: float, z: float) -> Array:
        L = np.zeros((n, 4, 4))
        L[:, 3, 3] = 1.0
        if axis == "z":
            L[:, 0, 0], L[:, 0, 1], L[:, 1, 0], L[:, 1, 1] = c[:, i], -s[:, i], s[:, i], c[:, i]
            L[:, 2, 2] = 1.0
            L[:, 0, 3] = c[:, i] * x - s[:, i] * y
            L[:, 1, 3] = s[:, i] * x + c[:, i] * y
            L[:, 2, 3] = z
        else:
            L[:, 0, 0], L[:, 0, 2], L[:, 2, 0], L[:, 2, 2] = c[:, i], s[:, i], -s[:, i], c[:, i]
            L[:, 1, 1] = 1.0
            L[:, 0, 3] = s[:, i] * z
            L[:, 2, 3] = c[:, i] * z
        return L

    A = [
        link(0, "z", m.shoulder_offset_mm, m.lateral_offset_mm, 0.0),
        link(1, "y", 0.0, 0.0, m.upper_arm_mm),
        link(2, "y", 0.0, 0.0, m.forearm_mm),
        link(3, "z", 0.0, 0.0, 0.0),
        link(4, "y", 0.0, 0.0, 0.0),
        link(5, "z", 0.0, 0.0, m.wrist_to_flange_mm),
    ]
    out: Array = A[0] @ A[1] @ A[2] @ A[3] @ A[4] @ A[5]
    return out


def _rate(fn: Callable[[], object], n: int, repeat: int = 3) -> float:
    """Items per second of the fastest of ``repeat`` calls processing n items."""
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n / best


def run() -> list[Result]:
    m = get_model("RX90B")
    rng = np.random.default_rng(12345)
    q = [10.0, 20.0, 30.0, 40.0, 50.0, 60.0]
    # Both ways must agree, or the baseline is not a baseline.
    assert np.allclose(m.flange2base(q), textbook_dgm(m, q), atol=1e-9)
    ours = time_per_call(lambda: m.flange2base(q))
    base = time_per_call(lambda: textbook_dgm(m, q))
    out = [
        result(
            "DGM single pose RX90B (Robot.flange2base)",
            ours * 1e6,
            "µs",
            "six 4x4 numpy matmuls",
            base * 1e6,
        )
    ]

    n = 200_000
    Q = rng.uniform(m.limits[:, 0], m.limits[:, 1], (n, 6))
    assert np.allclose(m.flange2base_batch(Q[:1000]), textbook_dgm_batch(m, Q[:1000]), atol=1e-9)
    out.append(
        result(
            "DGM batch 200k RX90B (Robot.flange2base_batch)",
            _rate(lambda: m.flange2base_batch(Q), n),
            "configs/s",
            "batched 4x4 matmul chain",
            _rate(lambda: textbook_dgm_batch(m, Q), n),
        )
    )

    n_ik = 100_000
    T = m.flange2base_batch(Q[:n_ik])
    loop_n = 300
    out.append(
        result(
            "IK batch 100k, all solutions (Robot.ik_batch)",
            _rate(lambda: m.ik_batch(T), n_ik),
            "poses/s",
            "loop of single ik()",
            _rate(lambda: [_ik_or_none(m, T[i]) for i in range(loop_n)], loop_n),
        )
    )
    return out


def _ik_or_none(m: RobotModel, T: Array) -> object:
    try:
        return m.ik(T)
    except ValueError:
        return None
