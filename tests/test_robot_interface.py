"""The robot API's values and its one error family: MotionDesc, robot_error, client errors."""

from __future__ import annotations

import math

import pytest

from kinematics import errors as kin
from kinematics.types import IDENTITY_LOC
from robotsocket import client, interface
from robotsocket.interface import (
    BadStateError,
    BusyError,
    EmergencyStopError,
    InvalidArgumentError,
    MotionDesc,
    NotPoweredError,
    OutOfRangeError,
    RobotError,
    SingularityError,
    UnreachableError,
    robot_error,
)
from spec.errors import ErrorCode, RemoteError


@pytest.mark.parametrize(
    ("kin_error", "expected"),
    [
        (kin.UnreachableError("too far"), UnreachableError),
        (kin.SingularityError("wrist", kind="wrist"), SingularityError),
        (kin.JointLimitError("J2 outside"), OutOfRangeError),
        (kin.KinematicsError("joints: contains NaN"), InvalidArgumentError),
        (kin.UnknownModelError("KR16"), InvalidArgumentError),
    ],
)
def test_robot_error_of_each_kinematics_error(
    kin_error: kin.KinematicsError, expected: type[RobotError]
) -> None:
    err = robot_error(kin_error)
    assert type(err) is expected and str(err) == str(kin_error)


def test_motion_desc_is_checked_by_the_robot_not_when_built() -> None:
    assert MotionDesc().check() == MotionDesc()
    assert MotionDesc(joint_speed=100.0, blend=0.0).check().joint_speed == 100.0
    bad = [
        {"joint_speed": 0.0},
        {"joint_speed": 100.5},
        {"joint_accel": -1.0},
        {"joint_decel": math.nan},
        {"tool_speed": 0.0},
        {"tool_rot_speed": math.inf},
        {"blend": -0.1},
        {"blend": math.nan},
    ]
    for fields in bad:
        desc = MotionDesc(**fields)  # a client may build it, to let the server judge
        with pytest.raises(OutOfRangeError, match=next(iter(fields))):
            desc.check()


def test_client_errors_are_robot_errors() -> None:
    """A caller catching the robot API's error catches the client's remote one too."""
    pairs = {
        ErrorCode.NOT_POWERED: NotPoweredError,
        ErrorCode.EMERGENCY_STOP: EmergencyStopError,
        ErrorCode.OUT_OF_RANGE: OutOfRangeError,
        ErrorCode.UNREACHABLE: UnreachableError,
        ErrorCode.SINGULARITY: SingularityError,
        ErrorCode.BUSY: BusyError,
        ErrorCode.BAD_STATE: BadStateError,
        ErrorCode.BAD_PARAMETERS: InvalidArgumentError,
    }
    for code, robot_type in pairs.items():
        remote_type = client._ERRORS[code]
        assert issubclass(remote_type, robot_type) and issubclass(remote_type, RemoteError)
        exc = remote_type(int(code), "from the server", 0x0101, 7)
        assert exc.code == code and exc.message == "from the server"
    # Protocol-level refusals have no robot counterpart.
    for code in (ErrorCode.NOT_IN_CONTROL, ErrorCode.AUTH_FAILED, ErrorCode.UNKNOWN_COMMAND):
        assert not issubclass(client._ERRORS[code], RobotError)
    assert client.MotionDesc is interface.MotionDesc
    assert client.RobotClient.here.__defaults__ == (IDENTITY_LOC,) * 2
