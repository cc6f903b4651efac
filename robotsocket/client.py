"""RobotClient: one method per RobotSocket command, VAL3 units, typed exceptions.

Example::

    with RobotClient("127.0.0.1", 4000) as robot:
        robot.take_control()
        robot.enable_power()
        robot.joint_move((0, -30, 90, 0, 60, 0))
        robot.wait_end_move(30.0)
        print(robot.herej())

Results, one type per kind of value (the same rule in :class:`sensorsocket.client.SensorClient`
and in :class:`robotsocket.interface.RobotInterface`, so code runs against either):

* a VAL3 **location** (``here()``) is a :data:`kinematics.types.Loc`: a tuple of six Python
  floats (x, y, z mm; rx, ry, rz deg), immutable and hashable, what the tool database and job
  files hold; its angles do not add like a vector's components, so it is no array;
* **joints, matrices and point sets** (``herej()``, ``joint_limits()``, ``joint_log()``) are
  float64 numpy arrays: joints (6,) degrees, limits (6, 2), a log's times (N,) and joints (N, 6);
* a reply of **several values** is a named result: a frozen dataclass (``status()``,
  ``motion_desc()``), or a :class:`~typing.NamedTuple` where unpacking it is the natural use
  (``times, joints = robot.joint_log()`` or ``log.times``; ``list_io()``); a measurement's
  data with its index is an ``(index, data)`` pair (the sensor's ``get_image()``);
* one number, flag or name is a Python ``int``, ``float``, ``bool`` or ``str``.

Values are the wire's float64 as the server computed them, not rounded:
``here()`` may show ``59.99999999999999`` for 60; round for display, not for computing.

Every error packet raises a :class:`RobotRemoteError` subclass chosen by its error code
(``NotPoweredError``, ``NotInControlError``, ...) carrying ``code`` and ``message``. Where the
robot API has the same failure, the class is also that :mod:`robotsocket.interface` error
(``except interface.NotPoweredError`` catches it from an emulator and from a server alike).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from kinematics.types import IDENTITY_LOC, FloatArray, Loc
from robotsocket import interface
from robotsocket.interface import MotionDesc
from spec import wire
from spec.client import (
    ClientTimeout,
    ConnectionClosed,
    FramedClient,
    MoveResult,
    wait_end_move,
    wait_move,
)
from spec.errors import ErrorCode, RemoteError
from spec.messages import (
    GetJointLimitsReply,
    GetJointLogReply,
    GetMotionDescReply,
    HerejReply,
    HereReply,
    JointMoveReply,
    ListIOReply,
    ReadIOReply,
    RobotStatusReply,
    ToolMoveJReply,
    ToolMoveLReply,
)
from spec.params import Joints, Location
from spec.registry import CommandId


class RobotRemoteError(RemoteError):
    """An error packet from the robot server; ``code`` (ErrorCode) and ``message``."""


class NotPoweredError(RobotRemoteError, interface.NotPoweredError):
    pass


class NotInControlError(RobotRemoteError):
    pass


class EmergencyStopError(RobotRemoteError, interface.EmergencyStopError):
    pass


class OutOfRangeError(RobotRemoteError, interface.OutOfRangeError):
    pass


class UnreachableError(RobotRemoteError, interface.UnreachableError):
    pass


class SingularityError(RobotRemoteError, interface.SingularityError):
    pass


class BusyError(RobotRemoteError, interface.BusyError):
    pass


class BadStateError(RobotRemoteError, interface.BadStateError):
    pass


class AuthError(RobotRemoteError):
    pass


class BadParametersError(RobotRemoteError, interface.InvalidArgumentError):
    pass


class UnknownCommandError(RobotRemoteError):
    pass


class NotSupportedError(UnknownCommandError):
    """A command of the robot service that this robot does not offer [RS-5.62]: to a client
    as absent as an unknown one (a 1.2 robot answered UNKNOWN_COMMAND)."""


_ERRORS: dict[int, type[RobotRemoteError]] = {
    ErrorCode.NOT_POWERED: NotPoweredError,
    ErrorCode.NOT_IN_CONTROL: NotInControlError,
    ErrorCode.EMERGENCY_STOP: EmergencyStopError,
    ErrorCode.OUT_OF_RANGE: OutOfRangeError,
    ErrorCode.UNREACHABLE: UnreachableError,
    ErrorCode.SINGULARITY: SingularityError,
    ErrorCode.BUSY: BusyError,
    ErrorCode.BAD_STATE: BadStateError,
    ErrorCode.AUTH_FAILED: AuthError,
    ErrorCode.BAD_PARAMETERS: BadParametersError,
    ErrorCode.UNKNOWN_COMMAND: UnknownCommandError,
    ErrorCode.NOT_SUPPORTED: NotSupportedError,
}


#: GetStatus reply (powered, estop, moving, queue, in_control, controlled, last_error,
#: last_message, time on the robot clock in s): the registry's message class.
Status = RobotStatusReply


class JointLog(NamedTuple):
    """GetJointLog reply: ``times`` (N,) s on the robot clock, ``joints`` (N, 6) degrees."""

    times: FloatArray
    joints: FloatArray


class IoNames(NamedTuple):
    """ListIO reply: the names of the outputs and of the inputs."""

    outputs: list[str]
    inputs: list[str]


def _location(values: Sequence[float] | Location) -> Location:
    return values if isinstance(values, Location) else Location.of(values)


class RobotClient(FramedClient):
    """Blocking client of a RobotSocket server (see :class:`spec.client.FramedClient` for
    ``timeout``, ``auto_reconnect``, ``reconnect()`` and the context manager)."""

    DEFAULT_PORT = wire.ROBOT_PORT
    CLIENT_NAME = "robotsocket-client/0.1"

    def __enter__(self) -> RobotClient:
        return self

    def _remote_error(self, code: int, message: str, command: int, request_id: int) -> RemoteError:
        cls = _ERRORS.get(code, RobotRemoteError)
        return cls(code, message, command, request_id)

    # --- state -------------------------------------------------------------------------------

    def status(self) -> Status:
        return RobotStatusReply.decode(self.call(_ROBOT_STATUS))

    def herej(self) -> FloatArray:
        """Measured joints (6,) in degrees."""
        return np.array(HerejReply.decode(self.call(_HEREJ)).joints.values, dtype=np.float64)

    def here(
        self,
        tool: Sequence[float] | Location = IDENTITY_LOC,
        frame: Sequence[float] | Location = IDENTITY_LOC,
    ) -> Loc:
        """Location of ``tool`` (relative to the flange) in ``frame`` (relative to the base)."""
        reply = HereReply.decode(self.call(_HERE, _location(tool), _location(frame)))
        return reply.location.as_tuple()

    def joint_limits(self) -> FloatArray:
        """(6, 2) degrees, [lower, upper]."""
        m = GetJointLimitsReply.decode(self.call(CommandId.GET_JOINT_LIMITS)).limits
        return np.array(m.values, dtype=np.float64).reshape(m.rows, m.cols)

    def joint_log(self, since: float = -1.0) -> JointLog:
        """Samples with t_k > since (s): times (N,) robot clock, measured joints (N, 6)."""
        m = GetJointLogReply.decode(self.call(CommandId.GET_JOINT_LOG, float(since))).log
        rows = np.array(m.values, dtype=np.float64).reshape(m.rows, m.cols)
        return JointLog(rows[:, 0].copy(), rows[:, 1:].copy())

    # --- power and motion --------------------------------------------------------------------

    def enable_power(self) -> None:
        self.call(CommandId.ENABLE_POWER)

    def disable_power(self) -> None:
        self.call(CommandId.DISABLE_POWER)

    def joint_move(self, joints: Sequence[float]) -> int:
        """Queue a joint move to ``joints`` (6,) degrees; returns the move ID at once."""
        return JointMoveReply.decode(self.call(CommandId.JOINT_MOVE, Joints(joints))).move_id

    def tool_move_j(
        self,
        loc: Sequence[float] | Location,
        tool: Sequence[float] | Location = IDENTITY_LOC,
        frame: Sequence[float] | Location = IDENTITY_LOC,
    ) -> int:
        reply = self.call(CommandId.TOOL_MOVE_J, _location(loc), _location(tool), _location(frame))
        return ToolMoveJReply.decode(reply).move_id

    def tool_move_l(
        self,
        loc: Sequence[float] | Location,
        tool: Sequence[float] | Location = IDENTITY_LOC,
        frame: Sequence[float] | Location = IDENTITY_LOC,
    ) -> int:
        reply = self.call(CommandId.TOOL_MOVE_L, _location(loc), _location(tool), _location(frame))
        return ToolMoveLReply.decode(reply).move_id

    def set_motion_desc(self, desc: MotionDesc) -> None:
        self.call(
            CommandId.SET_MOTION_DESC,
            float(desc.joint_speed),
            float(desc.joint_accel),
            float(desc.joint_decel),
            float(desc.tool_speed),
            float(desc.tool_rot_speed),
            float(desc.blend),
        )

    def motion_desc(self) -> MotionDesc:
        d = GetMotionDescReply.decode(self.call(CommandId.GET_MOTION_DESC))
        return MotionDesc(
            d.joint_speed, d.joint_accel, d.joint_decel, d.tool_speed, d.tool_rot_speed, d.blend
        )

    def wait_end_move(self, timeout: float = 60.0) -> bool:
        """True only when the last move reached its target and the arm settled; False when
        it was stopped or failed, or ``timeout`` s passed first (:meth:`wait_move` says
        which) [RS-5.50]. While control is held the wait goes out in pieces shorter than the
        control lease [RS-7.13]."""
        return wait_end_move(self, timeout)

    def wait_move(self, timeout: float = 60.0) -> MoveResult:
        """How the last move ended: reached, stopped or failed (with the reason), or still
        moving after ``timeout`` s [RS-5.50]."""
        return wait_move(self, timeout)

    def stop_move(self) -> None:
        self.call(CommandId.STOP_MOVE)

    def restart_move(self) -> None:
        self.call(CommandId.RESTART_MOVE)

    def reset_motion(self) -> None:
        self.call(CommandId.RESET_MOTION)

    def emergency_stop(self) -> None:
        self.call(CommandId.EMERGENCY_STOP)

    def reset_emergency_stop(self) -> None:
        self.call(CommandId.RESET_EMERGENCY_STOP)

    # --- I/O ---------------------------------------------------------------------------------

    def set_output(self, name: str, value: bool) -> None:
        self.call(CommandId.SET_OUTPUT, name, bool(value))

    def read_io(self, name: str) -> bool:
        return ReadIOReply.decode(self.call(CommandId.READ_IO, name)).value

    def list_io(self) -> IoNames:
        names = ListIOReply.decode(self.call(CommandId.LIST_IO))
        outputs, inputs = names.outputs, names.inputs
        return IoNames([n for n in outputs.split(",") if n], [n for n in inputs.split(",") if n])


# Enum members as ints: an enum attribute look-up is slow in Python 3.11 (~10x a global).
_HEREJ, _HERE = int(CommandId.HEREJ), int(CommandId.HERE)
_ROBOT_STATUS = int(CommandId.ROBOT_STATUS)


__all__ = [
    "AuthError",
    "BadParametersError",
    "BadStateError",
    "BusyError",
    "ClientTimeout",
    "ConnectionClosed",
    "EmergencyStopError",
    "IoNames",
    "JointLog",
    "MotionDesc",
    "MoveResult",
    "NotInControlError",
    "NotPoweredError",
    "NotSupportedError",
    "OutOfRangeError",
    "RobotClient",
    "RobotRemoteError",
    "SingularityError",
    "Status",
    "UnknownCommandError",
    "UnreachableError",
]
