"""Robot emulator in simulated time: power, e-stop, I/O, joint log, latency, hooks (no I/O)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from kinematics.robot import get_model
from kinematics.transforms import invert, location_to_transform, transform_to_location
from robotsocket.emulator import HOME, RobotEmulator
from robotsocket.interface import (
    EmergencyStopError,
    MotionDesc,
    NotPoweredError,
    OutOfRangeError,
    RobotInterface,
    UnreachableError,
)

MODEL = get_model("RX90B")
TARGET = np.array([30.0, -20.0, 100.0, 10.0, 45.0, -30.0])


def powered(**kw: object) -> RobotEmulator:
    robot = RobotEmulator(**kw)  # type: ignore[arg-type]
    robot.enable_power()
    return robot


def test_motion_needs_power_and_no_estop() -> None:
    robot = RobotEmulator()
    with pytest.raises(NotPoweredError):
        robot.joint_move(TARGET)
    assert isinstance(robot.status().last_error, NotPoweredError)
    robot.emergency_stop()
    with pytest.raises(EmergencyStopError):
        robot.enable_power()
    robot.reset_emergency_stop()
    robot.enable_power()
    assert robot.joint_move(TARGET) == 1


def test_wait_end_move_advances_the_simulated_clock_to_the_exact_target() -> None:
    robot = powered()
    robot.joint_move(TARGET)
    assert robot.status().moving and robot.time() == 0.0
    assert robot.wait_end_move(30.0)
    assert np.array_equal(robot.herej(), TARGET)
    st = robot.status()
    assert not st.moving and st.queue == 0 and st.time > 0.5


def test_estop_halts_at_once_and_switches_outputs_off() -> None:
    robot = powered()
    robot.set_output("laser", True)
    robot.joint_move(TARGET)
    robot.step(50)
    q = robot.herej()
    robot.emergency_stop()
    robot.step(50)
    assert np.array_equal(robot.herej(), q)
    st = robot.status()
    assert st.estop and not st.powered and st.queue == 0
    assert robot.read_io("laser") == (False, True)
    with pytest.raises(EmergencyStopError):
        robot.set_output("laser", True)


def test_disable_power_stops_motion() -> None:
    robot = powered()
    robot.joint_move(TARGET)
    robot.step(30)
    robot.disable_power()
    q = robot.herej()
    robot.step(30)
    assert np.array_equal(robot.herej(), q) and not robot.status().powered


def test_io_by_name() -> None:
    robot = RobotEmulator()
    outputs, inputs = robot.list_io()
    assert {"laser", "gas", "crossjet"} <= set(outputs) and inputs
    robot.set_output("gas", True)
    assert robot.read_io("gas") == (True, True)
    assert robot.read_io(inputs[0])[1] is False
    with pytest.raises(OutOfRangeError):  # [RS-5.21]
        robot.set_output(inputs[0], True)
    with pytest.raises(OutOfRangeError):
        robot.read_io("nope")


def test_joint_log_is_on_the_4ms_grid_and_10s_deep() -> None:
    robot = powered()
    robot.step(3000)
    t, q = robot.joint_log(-1.0)
    assert len(t) == 2500 and q.shape == (2500, 6)
    np.testing.assert_allclose(np.diff(t), 0.004, rtol=1e-9)
    assert t[-1] == pytest.approx(3000 * 0.004)
    t2, _ = robot.joint_log(t[-3])
    assert list(t2) == list(t[-2:])  # strictly after ``since``


def test_measured_joints_are_delayed_setpoints() -> None:
    latency = 0.010  # 2.5 cycles
    robot = powered(encoder_latency=latency)
    seen: list[tuple[float, np.ndarray, np.ndarray]] = []
    robot.cycle_hooks.append(lambda t, sp, m: seen.append((t, sp.copy(), m.copy())))
    robot.joint_move(TARGET)
    assert robot.wait_end_move(30.0)
    times = np.array([s[0] for s in seen])
    sp = np.array([s[1] for s in seen])
    meas = np.array([s[2] for s in seen])
    np.testing.assert_allclose(np.diff(times), 0.004)
    # Independent: interpolate the setpoint sequence at t - latency.
    expect = np.column_stack([np.interp(times - latency, times, sp[:, j]) for j in range(6)])
    k = times - latency >= times[0]
    np.testing.assert_allclose(meas[k], expect[k], atol=1e-9)
    assert np.array_equal(robot.herej(), TARGET)  # settled: waited for the latency too


def test_herej_values_are_herej_as_floats_mid_move() -> None:
    """The Herej reply's path (no array) reports what herej() does, also with noise and
    mid-move; herej() still hands out a copy of its own."""
    robot = powered(noise_deg=0.01, rng=np.random.default_rng(3))
    robot.joint_move(TARGET)
    for _ in range(5):
        assert not robot.wait_end_move(0.1)  # mid-move: the samples change
        q = robot.herej()
        values = robot.herej_values()
        assert values == q.tolist() == RobotInterface.herej_values(robot)
        assert all(type(v) is float for v in values)
        q[:] = 0.0
        assert robot.herej_values() == values


def test_noise_needs_rng_and_is_reproducible() -> None:
    with pytest.raises(ValueError):
        RobotEmulator(noise_deg=0.01)
    a = RobotEmulator(noise_deg=0.01, rng=np.random.default_rng(7))
    b = RobotEmulator(noise_deg=0.01, rng=np.random.default_rng(7))
    a.step(10)
    b.step(10)
    assert np.array_equal(a.herej(), b.herej()) and not np.array_equal(a.herej(), HOME)


def test_here_with_tool_and_frame_matches_the_dgm() -> None:
    robot = RobotEmulator()
    tool = (10.0, 20.0, 150.0, 0.0, 30.0, 0.0)
    frame = (500.0, -200.0, 100.0, 0.0, 0.0, 90.0)
    got = np.array(robot.here(tool, frame))
    T = invert(location_to_transform(frame)) @ MODEL.flange2base(np.array(HOME))
    want = transform_to_location(T @ location_to_transform(tool))
    np.testing.assert_allclose(got, want, atol=1e-9)


def same_pose(a: object, b: object) -> None:
    """Locations compared as transforms (angles are equal modulo 360)."""
    np.testing.assert_allclose(location_to_transform(a), location_to_transform(b), atol=1e-6)  # type: ignore[arg-type]


def test_tool_moves_reach_their_location() -> None:
    robot = powered()
    robot.set_motion_desc(MotionDesc(joint_speed=50.0))
    tool = (0.0, 0.0, 100.0, 0.0, 0.0, 0.0)
    start = np.array(robot.here(tool))
    goal = tuple(start + np.array([100.0, 50.0, -50.0, 0.0, 0.0, 10.0]))
    robot.tool_move_l(goal, tool)
    assert robot.wait_end_move(30.0)
    same_pose(robot.here(tool), goal)
    goal2 = tuple(start + np.array([-50.0, -150.0, 20.0, 0.0, 0.0, 0.0]))
    robot.tool_move_j(goal2, tool)
    assert robot.wait_end_move(30.0)
    same_pose(robot.here(tool), goal2)
    with pytest.raises(UnreachableError):
        robot.tool_move_j((3000.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(OutOfRangeError):
        robot.joint_move(np.array([170.0, 0.0, 90.0, 0.0, 90.0, 0.0]))
    with pytest.raises(OutOfRangeError):
        robot.wait_end_move(0.0)


def test_a_lost_controller_stops_the_arm_then_its_power_goes_off() -> None:
    """[RS-7.10] [RS-7.22] a stop of category 1: power stays while the arm decelerates and
    goes off in the cycle it stands."""
    robot = powered()
    robot.joint_move(TARGET)
    robot.joint_move(np.array(HOME))
    robot.step(40)
    robot.on_control_lost()
    robot.step(1)
    assert robot.status().powered and robot.status().moving  # decelerating, powered
    assert robot.wait_end_move(10.0)
    st = robot.status()
    assert not st.powered and st.queue == 0
    assert not np.allclose(robot.herej(), TARGET)


def test_a_new_controllers_power_on_during_the_stop_holds() -> None:
    """[RS-7.22] EnablePower by the next controller while the lost one's arm still
    decelerates cancels the pending power-off."""
    robot = powered()
    robot.joint_move(TARGET)
    robot.step(40)
    robot.on_control_lost()
    robot.enable_power()
    assert robot.wait_end_move(10.0)
    assert robot.status().powered


def test_a_release_switches_the_outputs_off_laser_first_and_the_move_goes_on() -> None:
    """[RS-7.21] [RS-7.11] released: outputs off (laser first), queue and power kept."""
    robot = powered()
    robot.set_output("gas", True)
    robot.set_output("laser", True)
    robot.joint_move(TARGET)
    robot.step(10)
    robot.on_control_released()
    assert [(n, v) for _, n, v in robot.io_log][-2:] == [("laser", False), ("gas", False)]
    assert robot.wait_end_move(30.0)
    st = robot.status()
    assert st.powered
    np.testing.assert_allclose(robot.herej(), TARGET)


def test_real_time_clock_ticks_and_reports_jitter() -> None:
    robot = RobotEmulator(clock="real").start()
    try:
        deadline = time.monotonic() + 5.0
        while robot.cycle < 25 and time.monotonic() < deadline:
            time.sleep(0.01)
        # at rest the clock thread sleeps: cycles are run by readers and by the thread's
        # wake-ups, none timed
        assert robot.jitter()["count"] == 0
        robot.enable_power()
        robot.joint_move(np.array([20.0, 0.0, 90.0, 0.0, 90.0, 0.0]))
        assert robot.wait_end_move(10.0)
        assert np.array_equal(robot.herej(), [20.0, 0.0, 90.0, 0.0, 90.0, 0.0])
        with pytest.raises(Exception, match="simulated"):
            robot.step(1)
    finally:
        robot.close()
    j = robot.jitter()  # the ticks of the move, each on its deadline
    assert j["count"] >= 25 and 0.0 <= j["p50"] <= j["p99"] <= j["max"]
    t, _ = robot.joint_log(-1.0)
    np.testing.assert_allclose(np.diff(t), 0.004, rtol=1e-9)


def test_io_log_records_every_output_change_on_the_robot_clock() -> None:
    r = powered()
    r.step(10)
    r.set_output("gas", True)
    r.set_output("laser", True)
    r.step(5)
    r.on_control_lost()
    r.set_output("crossjet", True)
    r.emergency_stop()
    t1, t2 = 10 * r.period, 15 * r.period
    assert list(r.io_log) == [
        (t1, "gas", True), (t1, "laser", True),
        (t2, "laser", False), (t2, "gas", False),  # control lost: laser first
        (t2, "crossjet", True), (t2, "crossjet", False),  # emergency stop
    ]  # fmt: skip


def test_emergency_stop_switches_the_laser_off_first() -> None:
    """[RS-7.21] laser before crossjet and gas."""
    r = powered()
    for name in ("crossjet", "gas", "laser"):
        r.set_output(name, True)
    r.emergency_stop()
    assert [n for _, n, v in r.io_log if not v] == ["laser", "crossjet", "gas"]
    assert r.read_io("laser") == (False, True)
    r.set_output("gas", False)  # switching off is allowed under the emergency stop
    with pytest.raises(EmergencyStopError):
        r.set_output("gas", True)


def test_readers_run_due_cycles_when_the_clock_thread_does_not() -> None:
    """A starved clock thread (here: never started) makes no sample stale or different: a
    reader computes the due cycles itself, with the values the simulated clock gives."""
    real = RobotEmulator(clock="real")  # the loop's thread is not started
    time.sleep(0.05)  # the reader comes 12 cycles after the start
    real.herej()
    c0 = real.cycle
    assert c0 >= 12
    real.enable_power()
    real.joint_move(TARGET)
    moved_at = real.cycle  # the move was queued after the due cycles ran
    time.sleep(0.1)
    t, q = real.joint_log(-1.0)
    assert t.size == real.cycle + 1 and np.array_equal(t, np.arange(t.size) * 0.004)
    sim = RobotEmulator()
    sim.step(moved_at)
    sim.enable_power()
    sim.joint_move(TARGET)
    sim.step(real.cycle - moved_at)
    t_sim, q_sim = sim.joint_log(-1.0)
    assert np.array_equal(t_sim, t) and np.array_equal(q_sim, q)
    assert not np.array_equal(q[-1], q[0])  # the arm moved: the comparison means something


def test_sample_lateness_says_when_a_reader_computed_the_samples() -> None:
    real = RobotEmulator(clock="real")  # no clock thread: readers compute every sample
    real.enable_power()
    real.joint_move(TARGET)
    time.sleep(0.05)
    real.herej()  # computes the ~12 cycles due, each late by up to 50 ms
    s = real.sample_lateness()
    assert s["count"] >= 10 and 0.0 <= s["p50"] <= s["max"] and s["max"] >= 0.04
    assert real.jitter()["count"] == 0  # the clock thread's own record: it never ran
    assert RobotEmulator().sample_lateness()["count"] == 0  # simulated: not recorded
