"""Trajectory generator: joint and Cartesian moves executed, limits, stop, blend (no I/O)."""

from __future__ import annotations

import numpy as np
import pytest

from kinematics.robot import get_model
from robotsocket.interface import MotionDesc
from robotsocket.paths import joint_limits_of, plan_joint, plan_linear
from robotsocket.trajectory import PERIOD, TrajectoryGenerator

MODEL = get_model("RX90B")
Q0 = np.array([0.0, 10.0, 90.0, 0.0, 30.0, 0.0])


def run(gen: TrajectoryGenerator, max_cycles: int = 20000) -> np.ndarray:
    """Step until idle; return the setpoints (N, 6) including the starting one."""
    out = [gen.last_q.copy()]
    k = gen.k
    for _ in range(max_cycles):
        k += 1
        out.append(gen.step(k).copy())
        if gen.idle:
            break
    else:
        raise AssertionError("generator did not finish")
    return np.array(out)


def test_joint_move_ends_exactly_on_target_with_synchronised_axes() -> None:
    target = np.array([40.0, -20.0, 60.0, 90.0, 50.0, -120.0])
    gen = TrajectoryGenerator(Q0)
    desc = MotionDesc(joint_speed=50.0)
    gen.enqueue(plan_joint(1, MODEL, Q0, target, desc))
    q = run(gen)
    assert np.array_equal(q[-1], target)  # exactly, not approximately
    # Synchronised: the fraction of the move done is the same on every moving axis.
    frac = (q - Q0) / (target - Q0)
    np.testing.assert_allclose(frac, np.repeat(frac[:, :1], 6, axis=1), atol=1e-9)
    vmax, amax, _ = joint_limits_of(MODEL, desc)
    speed = np.abs(np.diff(q, axis=0)) / PERIOD
    assert np.all(speed <= vmax * (1 + 1e-9))
    # Some axis actually reaches its limit (the profile is time-optimal for the slowest axis).
    assert np.max(speed / vmax) > 0.95
    acc = np.abs(np.diff(q, n=2, axis=0)) / PERIOD**2
    assert np.all(acc <= amax * 1.01)


def _line_deviation(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = (b - a) / np.linalg.norm(b - a)
    v = points - a
    out: np.ndarray = np.linalg.norm(v - np.outer(v @ d, d), axis=1)
    return out


@pytest.mark.parametrize(
    "offset",
    [(150.0, -80.0, 40.0, 0.0, 0.0, 0.0), (-100.0, 120.0, -60.0, 15.0, -10.0, 30.0)],
)
def test_tool_move_l_stays_on_the_straight_line(offset: tuple[float, ...]) -> None:
    tool = np.eye(4)
    tool[:3, 3] = [0.0, 30.0, 120.0]  # a laser tool 120 mm in front of the flange
    F0 = MODEL.flange2base(Q0)
    T0 = F0 @ tool
    from kinematics.transforms import location_to_transform, transform_to_location

    loc1 = transform_to_location(T0) + np.array(offset)
    T1 = location_to_transform(loc1)
    desc = MotionDesc(joint_speed=100.0, tool_speed=300.0, tool_rot_speed=60.0)
    gen = TrajectoryGenerator(Q0)
    gen.enqueue(plan_linear(1, MODEL, Q0, T1, tool, desc))
    q = run(gen)
    tcp = (MODEL.flange2base(q) @ tool)[:, :3, 3]
    assert _line_deviation(tcp, T0[:3, 3], T1[:3, 3]).max() < 0.01  # mm, every 4 ms sample
    np.testing.assert_allclose((MODEL.flange2base(q[-1]) @ tool), T1, atol=1e-9)
    speed = np.linalg.norm(np.diff(tcp, axis=0), axis=1) / PERIOD
    assert speed.max() <= 300.0 * (1 + 1e-6)
    vmax, _, _ = joint_limits_of(MODEL, desc)
    assert np.all(np.abs(np.diff(q, axis=0)) / PERIOD <= vmax * 1.001)


def test_tool_speed_limit_is_reached_when_joints_allow() -> None:
    T1 = MODEL.flange2base(Q0).copy()
    T1[:3, 3] += [0.0, 0.0, -200.0]
    gen = TrajectoryGenerator(Q0)
    gen.enqueue(plan_linear(1, MODEL, Q0, T1, np.eye(4), MotionDesc(joint_speed=100.0)))
    q = run(gen)
    speed = np.linalg.norm(np.diff(MODEL.flange2base(q)[:, :3, 3], axis=0), axis=1) / PERIOD
    assert 249.0 < speed.max() <= 250.0 * (1 + 1e-9)


def test_stop_decelerates_along_the_path_and_restart_finishes() -> None:
    target = np.array([60.0, -10.0, 70.0, 20.0, 60.0, 45.0])
    desc = MotionDesc(joint_speed=20.0)
    gen = TrajectoryGenerator(Q0)
    gen.enqueue(plan_joint(1, MODEL, Q0, target, desc))
    gen.enqueue(plan_joint(2, MODEL, target, Q0, desc))
    for k in range(1, 101):
        gen.step(k)
    gen.stop()
    q = [gen.step(k).copy() for k in range(101, 400)]
    q_arr = np.array(q)
    frac = (q_arr - Q0) / (target - Q0)
    np.testing.assert_allclose(frac, np.repeat(frac[:, :1], 6, axis=1), atol=1e-9)  # on path
    step = np.linalg.norm(np.diff(q_arr, axis=0), axis=1)
    assert np.all(np.diff(step) <= 1e-9)  # monotone deceleration
    assert step[-1] == 0.0 and not gen.in_motion and gen.queued == 2
    gen.restart()
    rest = run(gen)
    assert np.array_equal(rest[-1], Q0)


def test_reset_drops_the_queue_and_holds_where_it_stopped() -> None:
    target = np.array([60.0, -10.0, 70.0, 0.0, 60.0, 45.0])
    gen = TrajectoryGenerator(Q0)
    gen.enqueue(plan_joint(1, MODEL, Q0, target, MotionDesc()))
    gen.enqueue(plan_joint(2, MODEL, target, Q0, MotionDesc()))
    for k in range(1, 60):
        gen.step(k)
    gen.reset()
    stop_point = gen.planned_end().copy()
    q = run(gen)
    assert gen.idle and np.array_equal(q[-1], stop_point)
    assert 0.0 < (stop_point - Q0)[0] / (target - Q0)[0] < 1.0


def test_blending_does_not_stop_and_keeps_joint_speed_limits() -> None:
    # No joint reverses at the via point (joint 2 goes on upwards): a full blend is allowed.
    via = np.array([30.0, 20.0, 90.0, 0.0, 30.0, 0.0])
    end = np.array([30.0, 40.0, 60.0, 0.0, 30.0, 0.0])

    def go(blend: float) -> np.ndarray:
        desc = MotionDesc(joint_speed=30.0, blend=blend)
        gen = TrajectoryGenerator(Q0)
        gen.enqueue(plan_joint(1, MODEL, Q0, via, desc))
        gen.enqueue(plan_joint(2, MODEL, via, end, desc))
        return run(gen)

    sharp, blended = go(0.0), go(50.0)
    assert np.array_equal(blended[-1], end)
    assert len(blended) < len(sharp)
    speed = np.linalg.norm(np.diff(blended, axis=0), axis=1)
    moving = speed[3:-3]
    assert moving.min() > 0.0  # never at rest between the two moves
    vmax, _, _ = joint_limits_of(MODEL, MotionDesc(joint_speed=30.0))
    assert np.all(np.abs(np.diff(blended, axis=0)) / PERIOD <= vmax * (1 + 1e-9))
    _, amax, dmax = joint_limits_of(MODEL, MotionDesc(joint_speed=30.0))
    assert np.all(_joint_acc(blended) <= np.maximum(amax, dmax) * (1 + 1e-6))
    # The corner is cut: the blended path never passes through the via point.
    assert np.min(np.linalg.norm(blended - via, axis=1)) > 0.1


def _joint_acc(q: np.ndarray) -> np.ndarray:
    """Peak |second difference| per joint, deg/s^2."""
    out: np.ndarray = np.abs(np.diff(q, 2, axis=0)).max(axis=0) / PERIOD**2
    return out


def test_blending_a_reversal_never_exceeds_the_acceleration_limit() -> None:
    out = np.array([40.0, 10.0, 90.0, 0.0, 30.0, 0.0])  # joint 1 out ...
    desc = MotionDesc(joint_speed=50.0, joint_accel=50.0, joint_decel=50.0, blend=50.0)
    gen = TrajectoryGenerator(Q0)
    gen.enqueue(plan_joint(1, MODEL, Q0, out, desc))
    gen.enqueue(plan_joint(2, MODEL, out, Q0, desc))  # ... and straight back
    q = run(gen)
    _, amax, dmax = joint_limits_of(MODEL, desc)
    # Superposing the braking of the first move and the start of the second would ask joint 1
    # for twice its limit; the generator runs them one after the other instead.
    assert _joint_acc(q)[0] <= max(amax[0], dmax[0]) * (1 + 1e-6)
    assert np.array_equal(q[-1], Q0)
    assert np.min(np.linalg.norm(q - out, axis=1)) < 1e-9  # it reached the turning point


def test_blending_in_one_direction_still_blends_within_the_limits() -> None:
    mid = np.array([20.0, 10.0, 90.0, 0.0, 30.0, 0.0])
    end = np.array([40.0, 10.0, 90.0, 0.0, 30.0, 0.0])
    desc = MotionDesc(joint_speed=50.0, blend=50.0)
    gen = TrajectoryGenerator(Q0)
    gen.enqueue(plan_joint(1, MODEL, Q0, mid, desc))
    gen.enqueue(plan_joint(2, MODEL, mid, end, desc))
    q = run(gen)
    _, amax, dmax = joint_limits_of(MODEL, desc)
    speed = np.abs(np.diff(q[:, 0]))
    assert speed[3:-3].min() > 0.0  # no stop at the via point
    assert _joint_acc(q)[0] <= max(amax[0], dmax[0]) * (1 + 1e-6)
