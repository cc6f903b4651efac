"""Move planning: limits, refusals before anything moves (no I/O)."""

from __future__ import annotations

import numpy as np
import pytest

from kinematics.robot import get_model
from robotsocket.interface import MotionDesc, OutOfRangeError, SingularityError, UnreachableError
from robotsocket.paths import nominal_limits, plan_joint, plan_linear

MODEL = get_model("RX90B")
Q0 = np.array([0.0, 10.0, 90.0, 0.0, 30.0, 0.0])


def test_joint_move_outside_limits_is_rejected() -> None:
    with pytest.raises(OutOfRangeError, match="J2"):
        plan_joint(1, MODEL, Q0, np.array([0.0, 150.0, 0.0, 0.0, 0.0, 0.0]), MotionDesc())


def test_unreachable_and_singular_paths_fail_before_moving() -> None:
    far = MODEL.flange2base(Q0).copy()
    far[:3, 3] = [1500.0, 0.0, 0.0]
    with pytest.raises(UnreachableError):
        plan_linear(1, MODEL, Q0, far, np.eye(4), MotionDesc())
    flip = MODEL.flange2base(np.array([0.0, 10.0, 90.0, 0.0, -30.0, 0.0]))
    with pytest.raises(SingularityError):
        plan_linear(1, MODEL, Q0, flip, np.eye(4), MotionDesc())


def test_nominal_limits_are_per_model() -> None:
    v, a = nominal_limits("RX90B")
    assert v[5] == 1125.0 and np.all(a > v)
