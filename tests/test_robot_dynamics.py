"""The emulator with and without --dynamics elastic: off is bit for bit what it was, on
reports the motor side and moves the tool with the link side."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cell.options
import kinematics.dynamics
from cell.cell import CellError, EmulatedCell
from kinematics.dynamics import RX90B, ElasticArm
from robotsocket.emulator import RobotEmulator
from welding.emulate import run_tracking

ROOT = Path(__file__).resolve().parents[1]
TARGET = np.array([10.0, 5.0, 80.0, 3.0, 80.0, 10.0])


def _joint_log_digest(robot: RobotEmulator) -> tuple[str, int]:
    robot.enable_power()
    robot.joint_move(TARGET)
    assert robot.wait_end_move(10.0)
    t, q = robot.joint_log(-1.0)
    return hashlib.sha256(t.tobytes() + q.tobytes()).hexdigest()[:16], len(t)


def test_default_output_is_unchanged_bit_for_bit() -> None:
    """Recorded before the dynamics existed (main at 040cb29): the joint log of a joint move
    and a tracked sine weld's errors against the truth, to the last bit (the rms to 1e-12)."""
    assert _joint_log_digest(RobotEmulator(encoder_latency=0.0028)) == ("86987ee7dd98bd38", 93)
    run = run_tracking("sine", 250.0, weld_mm=40.0, delta_t_ms=4.9)
    # 119 cycles since a move ending on a cycle ends on it (TIME_EPS_S), not one cycle later
    assert (run.tracking_error_max_mm, run.cycles) == (0.021200697373859004, 119)
    # The rms is a numpy sum, whose SIMD order follows the CPU (AVX2 and AVX-512 machines
    # differ in the last bits): the same to 1e-12, which no change of the model would keep.
    assert run.tracking_error_rms_mm == pytest.approx(0.01186464895474902, rel=1e-12, abs=0)


def test_a_rigid_arm_is_where_its_setpoint_is() -> None:
    robot = RobotEmulator()
    robot.enable_power()
    robot.joint_move(TARGET)
    for _ in range(30):
        robot.step()
        assert robot.true_joints() is robot._setpoint  # the same array: nothing recomputed
    assert robot.dynamics is None


def test_an_elastic_arm_reports_its_motor_and_moves_its_link() -> None:
    """During the move the measured joints (motor side) lag the setpoint and the link side
    differs from both; WaitEndMove returns once the link stands on the target."""
    robot = RobotEmulator(dynamics=RX90B)
    robot.enable_power()
    robot.joint_move(TARGET)
    lag, swing = 0.0, 0.0
    for _ in range(60):
        robot.step()
        sp, motor, link = robot.setpoint(), robot.herej(), robot.true_joints()
        lag = max(lag, float(np.abs(sp - motor).max()))
        swing = max(swing, float(np.abs(link - motor).max()))
    assert lag > 0.05 and swing > 1e-3  # deg
    assert robot.wait_end_move(10.0)
    np.testing.assert_allclose(robot.true_joints(), TARGET, atol=ElasticArm.REST_DEG)
    np.testing.assert_allclose(robot.herej(), TARGET, atol=ElasticArm.REST_DEG)
    assert robot.dynamics is RX90B


def test_the_cell_camera_and_laser_follow_the_link_side() -> None:
    cell = EmulatedCell(dynamics="elastic")
    robot = cell.robot
    robot.enable_power()
    robot.joint_move(np.array(cell.ready_joints) + 2.0)
    for _ in range(40):
        robot.step()
    _, q = cell.motion.truth.since(-1.0)
    np.testing.assert_array_equal(q[-1], robot.true_joints())
    assert float(np.abs(q[-1] - robot.setpoint()).max()) > 1e-3


def test_the_option_names_agree_and_bad_combinations_are_refused() -> None:
    assert cell.options.DYNAMICS == kinematics.dynamics.DYNAMICS
    with pytest.raises(CellError, match="no elastic-joint parameters for the TX90"):
        EmulatedCell(model="TX90", dynamics="elastic")
    done = subprocess.run(
        [sys.executable, "-m", "robotsocket", "serve", "--clock", "sim", "--port", "0",
         "--model", "RX160", "--dynamics", "elastic"],
        capture_output=True, text=True, timeout=60, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        "error: no elastic-joint parameters for the RX160: --dynamics elastic has them for RX90B"
    ]
