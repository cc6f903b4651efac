"""Timed tool paths for ToolMoveTrajectory: planning checks and exact tracking (no I/O)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kinematics.robot import get_model
from robotsocket.interface import OutOfRangeError, SingularityError, UnreachableError
from robotsocket.timed_path import START_TOLERANCE_DEG, TimedPath, plan_timed
from robotsocket.trajectory import PERIOD, TrajectoryGenerator

MODEL = get_model("RX90B")
Q0 = np.array([0.0, 10.0, 90.0, 0.0, 30.0, 0.0])
F0 = MODEL.flange2base(Q0)
TOOL = np.eye(4)


def sine_path(amp_mm: float = 2.0, freq_hz: float = 1.5, seconds: float = 1.0,
              dt: float = PERIOD) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The ΔT experiment's motion: the flange moves in a sine along y of the base frame."""
    times = np.arange(round(seconds / dt) + 1) * dt
    poses = np.repeat(F0[None], len(times), axis=0)
    poses[:, 1, 3] += amp_mm * np.sin(2.0 * math.pi * freq_hz * times)
    return times, poses


def test_timed_path_interpolates_linearly_in_time_and_clamps() -> None:
    path = TimedPath(np.array([0.0, 1.0, 3.0]), np.array([[0.0] * 6, [6.0] * 6, [2.0] * 6]))
    assert path.duration == 3.0
    assert np.array_equal(path.start, np.zeros(6)) and np.array_equal(path.target, [2.0] * 6)
    q = path.at_times(np.array([-1.0, 0.0, 0.5, 1.0, 2.0, 3.0, 9.0]))
    np.testing.assert_allclose(q[:, 0], [0.0, 0.0, 3.0, 6.0, 4.0, 2.0, 2.0])
    # s in [0, 1] is time over the duration.
    np.testing.assert_allclose(path.q_at(np.array([0.5]), np.zeros(6)), [[5.0] * 6])


def test_plan_is_a_linear_law_the_generator_tracks_on_the_4ms_grid() -> None:
    times, poses = sine_path()
    move = plan_timed(7, MODEL, Q0, times, poses, TOOL)
    assert move.id == 7 and move.kind == "timed" and move.blend_mm == 0.0
    assert move.vmax == pytest.approx(1.0 / times[-1]) and math.isinf(move.acc)
    # Path length: the sum of the chords between the given locations.
    chords = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum()
    assert move.length_mm == pytest.approx(chords) and 7.0 < chords < 13.0
    gen = TrajectoryGenerator(Q0)
    gen.enqueue(move)
    # The move starts at cycle 1 (its law at t_0, where the arm is): cycle k is location k.
    setpoints = [Q0] + [gen.step(k) for k in range(1, len(times) + 1)]
    assert np.array_equal(setpoints[-1], move.target)
    gen.step(len(times) + 1)
    assert gen.idle
    reached = MODEL.flange2base(np.array(setpoints[: len(times)]))
    np.testing.assert_allclose(reached[:, :3, 3], poses[:, :3, 3], atol=1e-6)
    np.testing.assert_allclose(reached[:, :3, :3], poses[:, :3, :3], atol=1e-9)


def test_times_and_counts_are_checked() -> None:
    times, poses = sine_path(seconds=0.1)
    bad_times = [
        times[:1],  # fewer than 2
        times + 0.004,  # does not start at 0
        np.r_[times[:5], times[4], times[6:]],  # not increasing
        np.r_[times[:-1], np.nan],
        times * 40_000.0,  # longer than an hour
    ]
    for t in bad_times:
        with pytest.raises(OutOfRangeError):
            plan_timed(1, MODEL, Q0, t, poses[: len(t)], TOOL)
    with pytest.raises(OutOfRangeError, match="times but"):
        plan_timed(1, MODEL, Q0, times, poses[:-1], TOOL)
    nan_pose = poses.copy()
    nan_pose[3, 0, 3] = np.nan
    with pytest.raises(OutOfRangeError, match="finite"):
        plan_timed(1, MODEL, Q0, times, nan_pose, TOOL)


def test_the_path_must_start_where_the_tool_is() -> None:
    times, poses = sine_path(seconds=0.1)
    shifted = poses.copy()
    shifted[:, 0, 3] += 1.0  # 1 mm off: several hundredths of a degree on some joint
    with pytest.raises(OutOfRangeError, match="current location"):
        plan_timed(1, MODEL, Q0, times, shifted, TOOL)
    near = poses.copy()
    near[:, 0, 3] += 1e-6  # well inside START_TOLERANCE_DEG: accepted, starts exactly at Q0
    move = plan_timed(1, MODEL, Q0, times, near, TOOL)
    assert START_TOLERANCE_DEG > 0 and np.array_equal(move.start, Q0)


def test_unreachable_limit_and_singular_paths_are_refused() -> None:
    times, poses = sine_path(seconds=0.1)
    far = poses.copy()
    far[-1, :3, 3] = (3000.0, 0.0, 0.0)
    with pytest.raises(UnreachableError, match="location 25"):
        plan_timed(1, MODEL, Q0, times, far, TOOL)
    # Straight up through the wrist singularity (J5 = 0) from a bent wrist.
    q_end = np.array([0.0, 10.0, 90.0, 0.0, 0.0, 0.0])
    t = np.linspace(0.0, 2.0, 501)
    q = Q0 + np.multiply.outer(t / 2.0, q_end - Q0)
    with pytest.raises(SingularityError):
        plan_timed(1, MODEL, Q0, t, MODEL.flange2base(q), TOOL)


def test_speed_and_acceleration_limits_are_checked_on_the_controller_grid() -> None:
    # 2 mm at 1.5 Hz is easy; 50 mm at 10 Hz needs far more than the nominal joint speeds.
    times, poses = sine_path(amp_mm=50.0, freq_hz=10.0, seconds=0.2)
    with pytest.raises(OutOfRangeError, match="speed limit of joint"):
        plan_timed(1, MODEL, Q0, times, poses, TOOL)
    # A step of 0.5 mm between two 4 ms samples after rest: slow, but an acceleration jump.
    step = np.repeat(F0[None], 3, axis=0)
    step[2, 1, 3] += 0.5
    with pytest.raises(OutOfRangeError, match="acceleration limit"):
        plan_timed(1, MODEL, Q0, np.array([0.0, 0.004, 0.008]), step, TOOL)


@pytest.mark.parametrize("k0", range(100, 200))
def test_a_path_queued_behind_a_stand_starts_on_the_cycle_the_stand_ends(k0: int) -> None:
    """The tracker's start (welding/track_loop.py): a 48 ms stand, then the path. The stand's
    end, k0·T + 0.048 summed in floats, is k0·T + 12·T to the last bit or one ulp past it
    (k0 = 136, 168, 174, …); the path must start on that cycle either way, not 4 ms later."""
    hold_s = 12 * PERIOD
    gen = TrajectoryGenerator(Q0)
    for k in range(1, k0 + 1):
        gen.step(k)
    stand = plan_timed(1, MODEL, Q0, np.array([0.0, hold_s]), np.array([F0, F0]), TOOL)
    times, poses = sine_path(seconds=0.2)
    path = plan_timed(2, MODEL, Q0, times, poses, TOOL)
    gen.enqueue(stand)
    gen.enqueue(path)
    setpoints = [gen.step(k) for k in range(k0 + 1, k0 + 12 + len(times))]
    # cycle k0 + 12 + j is the path's location j (as cycle 1 + j is a lone path's)
    reached = MODEL.flange2base(np.array(setpoints[11:]))
    np.testing.assert_allclose(reached[:, :3, 3], poses[:, :3, 3], atol=1e-6)
