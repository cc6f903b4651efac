"""Alter mode (path correction, RS-5.32 ... RS-5.38): the pure limiter and the emulator."""

from __future__ import annotations

import numpy as np
import pytest

from kinematics.transforms import location_to_transform
from robotsocket.alter import (
    MAX_ACCEL_MM_S2,
    MAX_SPEED_MM_S,
    AlterState,
    check_correction,
    corrected_flange,
)
from robotsocket.emulator import RobotEmulator
from robotsocket.interface import BadStateError, NotPoweredError, OutOfRangeError, RobotInterface
from robotsocket.service import RobotService
from spec.registry import CommandId

PERIOD = 0.004
TOOL = (0.0, 0.0, 150.0, 0.0, 0.0, 0.0)


def _run(state: AlterState, cycles: int, t0: float = 0.0) -> tuple[np.ndarray, float]:
    out = []
    t = t0
    for _ in range(cycles):
        t += PERIOD
        state.step(t)
        out.append(state.applied.copy())
    return np.array(out), t


def test_correction_size_is_limited() -> None:
    check_correction(np.array([6.0, 8.0, 0.0, 1.0, 1.0, 0.0]))  # exactly 10 mm, 1.41 deg
    with pytest.raises(OutOfRangeError, match="translation"):
        check_correction(np.array([6.0, 8.1, 0.0, 0.0, 0.0, 0.0]))
    with pytest.raises(OutOfRangeError, match="rotation"):
        check_correction(np.array([0.0, 0.0, 0.0, 0.0, 2.1, 0.0]))
    with pytest.raises(OutOfRangeError):
        check_correction(np.array([np.nan, 0.0, 0.0, 0.0, 0.0, 0.0]))


def test_step_is_reached_within_speed_and_acceleration_without_overshoot() -> None:
    state = AlterState(PERIOD)
    state.begin(np.eye(4), 1.0, 0.0)
    state.command(np.array([0.0, 5.0, 0.0, 0.0, 0.0, 0.0]), 0.0)
    y = np.concatenate([[0.0], _run(state, 100, 0.0)[0][:, 1]])
    v = np.diff(y) / PERIOD
    a = np.diff(v) / PERIOD
    assert y[-1] == pytest.approx(5.0, abs=1e-9)
    assert y.max() <= 5.0 + 1e-9  # brakes in time
    assert np.abs(v).max() <= MAX_SPEED_MM_S * (1 + 1e-9)
    assert np.abs(a).max() <= MAX_ACCEL_MM_S2 * (1 + 1e-9)
    # 5 mm at 100 mm/s needs >= 50 ms (12.5 cycles): the speed limit is really in force
    assert np.argmax(y >= 5.0 - 1e-9) >= 5.0 / MAX_SPEED_MM_S / PERIOD


def test_late_correction_is_held_then_the_stream_is_lost_and_ramps_to_zero() -> None:
    state = AlterState(PERIOD)
    state.begin(np.eye(4), 0.02, 0.0)
    state.command(np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0]), 0.0)
    applied, t = _run(state, 5)  # 20 ms: still within the timeout
    assert state.active and applied[-1, 0] > 0.0
    held, t = _run(state, 20, t)
    assert not state.active and state.lost == 1
    assert held[:, 0].max() <= 1.0 + 1e-9  # never extrapolated past the last command
    _, t = _run(state, 100, t)
    assert not state.engaged and np.all(state.applied == 0.0)
    with pytest.raises(BadStateError):
        state.command(np.zeros(6), t)


def test_begin_and_end_state_rules() -> None:
    state = AlterState(PERIOD)
    with pytest.raises(BadStateError):
        state.end()
    with pytest.raises(OutOfRangeError):
        state.begin(np.eye(4), 0.001, 0.0)
    state.begin(np.eye(4), 0.1, 0.0)
    with pytest.raises(BadStateError):
        state.begin(np.eye(4), 0.1, 0.0)
    state.command(np.array([0.0, 0.0, 2.0, 0.0, 0.0, 0.0]), 0.0)
    _run(state, 10)
    state.end()
    with pytest.raises(BadStateError, match="ramping"):
        state.begin(np.eye(4), 0.1, 0.04)


def test_corrected_flange_moves_the_tool_point_and_turns_about_it() -> None:
    flange = location_to_transform(np.array([500.0, 100.0, 400.0, 180.0, 0.0, 0.0]))
    tool = location_to_transform(np.array(TOOL))
    c = np.array([1.0, -2.0, 0.5, 0.0, 0.0, 1.5])
    moved = corrected_flange(flange, tool, c) @ tool
    before = flange @ tool
    assert np.allclose(moved[:3, 3], before[:3, 3] + c[:3])
    angle = np.degrees(np.arccos((np.trace(before[:3, :3].T @ moved[:3, :3]) - 1) / 2))
    assert angle == pytest.approx(1.5)


def _robot() -> RobotEmulator:
    robot = RobotEmulator()
    robot.enable_power()
    return robot


def _tool_point(robot: RobotEmulator) -> np.ndarray:
    return np.array(robot.here(TOOL)[:3])


def test_emulator_adds_the_correction_to_a_running_move() -> None:
    robot = _robot()
    start = _tool_point(robot)
    target = (*(start + np.array([0.0, 100.0, 0.0])), *robot.here(TOOL)[3:])
    robot.tool_move_l(target, TOOL)
    robot.alter_begin(TOOL, 0.1)
    correction = np.array([0.0, 0.0, 3.0, 0.0, 0.0, 0.0])
    for _ in range(60):
        robot.alter(correction)
        robot.step()
    # mid-move the tool is 3 mm above the nominal line (x, z of the start)
    p = _tool_point(robot)
    assert p[2] - start[2] == pytest.approx(3.0, abs=1e-6)
    assert p[0] == pytest.approx(start[0], abs=1e-6)
    assert np.allclose(robot.alter_applied(), correction)
    for _ in range(1000):  # the move takes ~0.6 s; alter mode keeps the arm "moving"
        if robot.status().queue == 0:
            break
        robot.alter(correction)
        robot.step()
    assert robot.status().moving  # the correction is still in force
    assert np.allclose(_tool_point(robot), start + np.array([0.0, 100.0, 3.0]), atol=1e-6)
    robot.alter_end()
    assert not robot.wait_end_move(0.02)  # still ramping back: not settled
    assert robot.wait_end_move(1.0)
    assert np.allclose(_tool_point(robot), start + np.array([0.0, 100.0, 0.0]), atol=1e-6)


def test_emulator_stopped_stream_switches_the_laser_off_and_stops_the_motion() -> None:
    robot = _robot()
    start = _tool_point(robot)
    target = (*(start + np.array([0.0, 200.0, 0.0])), *robot.here(TOOL)[3:])
    robot.tool_move_l(target, TOOL)
    robot.set_output("laser", True)
    robot.alter_begin(TOOL, 0.02)
    for _ in range(25):
        robot.alter([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        robot.step()
    robot.step(10)  # 40 ms silent > 20 ms timeout
    assert robot.read_io("laser") == (False, True)
    assert isinstance(robot.status().last_error, BadStateError)
    with pytest.raises(BadStateError):
        robot.alter([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    assert robot.wait_end_move(5.0)
    end = _tool_point(robot)
    assert end[1] - start[1] < 150.0  # stopped on the way, queue dropped
    assert end[2] == pytest.approx(start[2], abs=1e-6)  # correction ramped back to zero


def test_emulator_alter_rules_and_emergency_stop_without_a_jump() -> None:
    robot = RobotEmulator()
    with pytest.raises(NotPoweredError):
        robot.alter_begin(TOOL, 0.1)
    robot.enable_power()
    with pytest.raises(BadStateError):
        robot.alter([0.0] * 6)
    robot.alter_begin(TOOL, 0.1)
    with pytest.raises(OutOfRangeError):
        robot.alter([0.0, 11.0, 0.0, 0.0, 0.0, 0.0])
    for _ in range(100):
        robot.alter([0.0, 4.0, 0.0, 0.0, 0.0, 0.0])
        robot.step()
    before = _tool_point(robot)
    robot.emergency_stop()
    robot.step(10)
    assert np.allclose(_tool_point(robot), before, atol=1e-9)
    assert np.all(robot.alter_applied() == 0.0)


def test_emulator_control_loss_ends_alter_mode() -> None:
    robot = _robot()
    robot.alter_begin(TOOL, 0.5)
    robot.alter([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    robot.step(50)
    robot.on_control_lost()
    with pytest.raises(BadStateError):
        robot.alter([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    robot.step(100)
    assert np.all(robot.alter_applied() == 0.0)


def test_a_moving_target_is_followed_without_lag() -> None:
    state = AlterState(PERIOD)
    state.begin(np.eye(4), 1.0, 0.0)
    t = 0.0
    lag = []
    for k in range(1, 200):
        # a 2 mm, 5 Hz sine: 63 mm/s, 2000 mm/s^2 at most (the paper's seam at 250 mm/s)
        y = 2.0 * np.sin(2 * np.pi * 5.0 * (k + 1) * PERIOD)
        state.command(np.array([0.0, y, 0.0, 0.0, 0.0, 0.0]), t)
        t += PERIOD
        state.step(t)
        lag.append(state.applied[1] - y)
    assert np.abs(lag[50:]).max() < 1e-9


def test_alter_commands_are_listed_only_by_a_robot_that_has_them() -> None:
    class NoAlter(RobotEmulator):
        alter_begin = RobotInterface.alter_begin

    alter = {CommandId.ALTER_BEGIN, CommandId.ALTER, CommandId.ALTER_END}
    assert alter <= set(RobotService(RobotEmulator()).implemented())
    assert not alter & set(RobotService(NoAlter()).implemented())


def test_alter_mode_keeps_a_settled_arm_from_counting_as_settled() -> None:
    robot = _robot()
    robot.step(10)
    assert robot.wait_end_move(0.1)  # settled: returns at once
    t = robot.time()
    robot.alter_begin(TOOL, 0.5)
    assert not robot.wait_end_move(0.004)  # one cycle: the clock advances
    assert robot.time() == pytest.approx(t + 0.004)


def test_emulator_applies_a_timed_table_at_its_cycles() -> None:
    """[RS-5.39] [RS-5.44] A table sent ahead in one batch, then nothing: the tool point at
    each cycle is the nominal one plus the table's value for that cycle's time."""
    robot = _robot()
    robot.alter_begin(TOOL, 0.05)
    start = _tool_point(robot)
    t0 = robot.time()
    times = t0 + np.arange(1, 101, dtype=np.float64) * PERIOD
    c = np.zeros((100, 6))
    c[:, 2] = np.linspace(0.0, 1.0, 100) ** 2  # 1 mm, within RS-5.34 at every cycle
    report, applied, now = robot.alter_queue(times, c)
    assert (report.accepted, report.late, report.depth) == (100, 0, 100)
    assert now == pytest.approx(t0) and not np.any(applied)
    for k in range(100):
        robot.step()
        assert robot.time() == pytest.approx(times[k])
        assert _tool_point(robot)[2] - start[2] == pytest.approx(c[k, 2], abs=1e-6)
    for _ in range(12):  # held past the end (never extrapolated) until the stream is lost
        robot.step()
        assert robot.alter_applied()[2] == pytest.approx(1.0, abs=1e-9)
    robot.step(2)  # 50 ms after the last entry's time: lost, alter mode over
    with pytest.raises(BadStateError, match="not active"):
        robot.alter_queue(np.zeros(0), np.zeros((0, 6)))


def test_emulator_alter_queue_rules() -> None:
    """[RS-5.39] outside alter mode BAD_STATE; [RS-5.46] no Alter while queued."""
    robot = _robot()
    with pytest.raises(BadStateError):
        robot.alter_queue(np.array([1.0]), np.zeros((1, 6)))
    robot.alter_begin(TOOL, 0.1)
    robot.alter_queue(np.array([robot.time() + 0.1]), np.zeros((1, 6)))
    with pytest.raises(BadStateError, match="queued"):
        robot.alter([0.0] * 6)


def test_alter_queue_is_listed_only_by_a_robot_that_has_it() -> None:
    class NoQueue(RobotEmulator):
        alter_queue = RobotInterface.alter_queue

    assert CommandId.ALTER_QUEUE in RobotService(RobotEmulator()).implemented()
    assert CommandId.ALTER_QUEUE not in RobotService(NoQueue()).implemented()
