"""The abstract robot API the RobotSocket server calls.

"Robots from different manufacturers can be used as long as they follow the API" (paper,
section III): an adapter for a real controller subclasses :class:`RobotInterface`; the
emulator (:mod:`robotsocket.emulator`) is one implementation. Methods take and return plain
Python and numpy values in VAL3 units (mm, degrees, seconds); no wire types appear here.

Failures raise a :class:`RobotError` subclass, the one family of robot errors: the service
maps each to its wire error code, :class:`~robotsocket.client.RobotClient` raises the same
classes (as remote errors) for the error packets it receives, and :func:`robot_error` says
which one a :class:`~kinematics.errors.KinematicsError` becomes.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from kinematics import errors as kin
from kinematics.types import IDENTITY_LOC, FloatArray, Loc
from spec.wire import MoveOutcome

if TYPE_CHECKING:
    from robotsocket.alter_queue import QueueReport

#: s the default controlled stop waits for the arm to stand before power goes off [RS-7.22].
STOP_WAIT_S = 10.0


class RobotError(Exception):
    """Base of every failure a robot reports; ``str()`` is the human message."""


class InvalidArgumentError(RobotError, ValueError):
    """An argument is malformed (wrong count, not finite, unknown I/O name, bad mdesc)."""


class OutOfRangeError(RobotError, ValueError):
    """A value is outside its allowed range, e.g. a joint limit."""


class UnreachableError(RobotError, ValueError):
    """The location (or a point of the path to it) cannot be reached by the arm."""


class SingularityError(RobotError, ValueError):
    """The path crosses or ends in a singularity."""


class NotPoweredError(RobotError):
    """Arm power is off."""


class EmergencyStopError(RobotError):
    """The emergency stop is engaged."""


class BusyError(RobotError):
    """The motion queue is full."""


class BadStateError(RobotError):
    """Not allowed in the current state."""


#: Kinematics errors and the robot error each is reported as (checked in this order).
_FROM_KINEMATICS: tuple[tuple[type[kin.KinematicsError], type[RobotError]], ...] = (
    (kin.UnreachableError, UnreachableError),
    (kin.SingularityError, SingularityError),
    (kin.JointLimitError, OutOfRangeError),
)


def robot_error(exc: kin.KinematicsError) -> RobotError:
    """The robot error for a kinematics error, same message: out of reach, singular, outside
    a joint limit; any other bad input (shape, NaN, non-rigid transform) is an invalid
    argument."""
    for kin_type, robot_type in _FROM_KINEMATICS:
        if isinstance(exc, kin_type):
            return robot_type(str(exc))
    return InvalidArgumentError(str(exc))


@dataclass(frozen=True, slots=True)
class MotionDesc:
    """Motion descriptor (VAL3 mdesc) for the moves queued after it.

    joint_speed, joint_accel, joint_decel: % of the model's nominal joint speed, acceleration
    and deceleration (0 < v <= 100). tool_speed: mm/s, tool_rot_speed: deg/s (Cartesian
    limits, also applied to ToolMoveL only). blend: mm; 0 stops at each target, > 0 blends
    into the next queued move once the remaining path is shorter than ``blend``.

    The same value travels through the client, the service and the robot. Building one
    checks nothing, so a client can send any descriptor; the robot that is given one checks
    it (:meth:`check`).
    """

    joint_speed: float = 10.0
    joint_accel: float = 100.0
    joint_decel: float = 100.0
    tool_speed: float = 250.0
    tool_rot_speed: float = 90.0
    blend: float = 0.0

    def check(self) -> MotionDesc:
        """``self`` when every field is inside its range, else OutOfRangeError."""
        for name in ("joint_speed", "joint_accel", "joint_decel"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and 0.0 < v <= 100.0):
                raise OutOfRangeError(f"{name} must be in (0, 100] %, got {v}")
        for name in ("tool_speed", "tool_rot_speed"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0.0):
                raise OutOfRangeError(f"{name} must be > 0, got {v}")
        if not (math.isfinite(self.blend) and self.blend >= 0.0):
            raise OutOfRangeError(f"blend must be >= 0 mm, got {self.blend}")
        return self


@dataclass(frozen=True, slots=True)
class RobotStatus:
    """Status snapshot. ``queue`` counts moves queued, including the one executing."""

    powered: bool
    estop: bool
    moving: bool
    queue: int
    last_error: RobotError | None
    time: float


@dataclass(frozen=True, slots=True)
class RobotInfo:
    """What Hello reports about the arm."""

    vendor: str
    model: str
    serial: str
    n_joints: int = 6


class RobotInterface(ABC):
    """The robot API the server dispatches to. Implementations must be thread-safe: the
    server calls them from one thread per connection."""

    period: float = 0.004  # s, controller cycle T_r of the joint log

    @abstractmethod
    def info(self) -> RobotInfo: ...

    @abstractmethod
    def time(self) -> float:
        """Robot clock in seconds: the time base of the joint log and of GetTime."""

    @abstractmethod
    def status(self) -> RobotStatus: ...

    @abstractmethod
    def herej(self) -> FloatArray:
        """Measured joints (6,) in degrees."""

    def herej_values(self) -> list[float]:
        """:meth:`herej` as plain floats, what the Herej reply carries: an implementation
        that holds them anyway overrides this and spares the server's request path an array."""
        values: list[float] = self.herej().tolist()
        return values

    @abstractmethod
    def here(self, tool: Loc = IDENTITY_LOC, frame: Loc = IDENTITY_LOC) -> Loc:
        """Measured location of ``tool`` (relative to the flange) in ``frame`` (relative to
        the base)."""

    @abstractmethod
    def joint_limits(self) -> FloatArray:
        """Joint limits (6, 2) in degrees, [lower, upper]."""

    @abstractmethod
    def enable_power(self) -> None: ...

    @abstractmethod
    def disable_power(self) -> None:
        """Stop at once, empty the queue, switch power off."""

    @abstractmethod
    def joint_move(self, joints: FloatArray) -> int:
        """Queue a joint-interpolated move to ``joints`` (6,) degrees; return its move ID."""

    @abstractmethod
    def tool_move_j(self, loc: Loc, tool: Loc = IDENTITY_LOC, frame: Loc = IDENTITY_LOC) -> int:
        """Queue a joint-interpolated move of ``tool`` to ``loc`` in ``frame``."""

    @abstractmethod
    def tool_move_l(self, loc: Loc, tool: Loc = IDENTITY_LOC, frame: Loc = IDENTITY_LOC) -> int:
        """Queue a straight-line move of ``tool`` to ``loc`` in ``frame``."""

    @abstractmethod
    def set_motion_desc(self, desc: MotionDesc) -> None:
        """Use ``desc`` for the moves queued after this; OutOfRangeError (``desc.check()``)
        when a field is outside its range."""

    @abstractmethod
    def motion_desc(self) -> MotionDesc: ...

    @abstractmethod
    def wait_end_move(self, timeout: float) -> bool:
        """Wait until the queue is empty and the arm settled; False when ``timeout`` (s)
        expired first."""

    def move_outcome(self) -> tuple[MoveOutcome, str]:
        """[RS-5.50] How the last queued move ended, with the reason when it was stopped or
        failed. This default reads the status; the emulator tracks each stop."""
        st = self.status()
        if st.moving or st.queue:
            return MoveOutcome.MOVING, ""
        if st.estop:
            return MoveOutcome.STOPPED, "emergency stop"
        return MoveOutcome.REACHED, ""

    @abstractmethod
    def stop_move(self) -> None:
        """Decelerate along the path and hold; the queue is kept."""

    @abstractmethod
    def restart_move(self) -> None: ...

    @abstractmethod
    def reset_motion(self) -> None:
        """Decelerate along the path, stop and empty the queue."""

    @abstractmethod
    def emergency_stop(self) -> None: ...

    @abstractmethod
    def reset_emergency_stop(self) -> None: ...

    @abstractmethod
    def set_output(self, name: str, value: bool) -> None: ...

    @abstractmethod
    def read_io(self, name: str) -> tuple[bool, bool]:
        """(value, is_output) of a named digital input or output."""

    @abstractmethod
    def list_io(self) -> tuple[list[str], list[str]]:
        """(output names, input names)."""

    @abstractmethod
    def joint_log(self, since: float) -> tuple[FloatArray, FloatArray]:
        """Logged samples with t_k > ``since`` (s): times (N,) and measured joints (N, 6)."""

    def tool_move_trajectory(
        self, times: FloatArray, locations: FloatArray, tool: Loc, frame: Loc
    ) -> int:
        """Queue a timed path: ``tool`` passes location k of ``locations`` (N, 6) (mm, deg,
        in ``frame``) at ``times[k]`` (N,) s after the move starts [RS-5.23]. Optional:
        a robot without it answers NOT_SUPPORTED [RS-5.62]."""
        raise NotImplementedError

    def alter_begin(self, tool: Loc, timeout: float) -> None:
        """[RS-5.32] Start correcting the running motion of ``tool``; a stream silent for
        ``timeout`` s is lost [RS-5.36]. Optional: a robot without it answers NOT_SUPPORTED
        [RS-5.62]."""
        raise NotImplementedError

    def alter(self, correction: Sequence[float] | FloatArray) -> FloatArray:
        """[RS-5.33] The whole correction in force (6,): dx, dy, dz (mm), rx, ry, rz (deg),
        base frame; returns the correction applied at the last cycle (6,)."""
        raise NotImplementedError

    def alter_end(self) -> None:
        """[RS-5.37] End alter mode; the correction ramps back to zero within the limits."""
        raise NotImplementedError

    def alter_queue(
        self, times: FloatArray, corrections: FloatArray
    ) -> tuple[QueueReport, FloatArray, float]:
        """[RS-5.39] Queue timed corrections (N, 6) for the robot-clock ``times`` (N,);
        (the queue's report, the correction applied at the last cycle (6,), that cycle's
        time). Optional (1.3): a robot without it answers NOT_SUPPORTED [RS-5.62]."""
        raise NotImplementedError

    def on_control_lost(self, why: str = "control lost") -> None:
        """[RS-7.10] The controlling client vanished (``why``: closed, lease expired, ...):
        laser off first, stop in a controlled way, then the other outputs; power off once
        the arm stands [RS-7.22]. A real controller's adapter overrides this with its own
        stop of category 1."""
        self._outputs_off(("laser",))
        self.reset_motion()
        self._outputs_off(("crossjet", "gas"))
        if self.wait_end_move(STOP_WAIT_S):
            self.disable_power()

    def on_control_released(self) -> None:
        """[RS-7.21] Control was given back: the process outputs go off, the laser first;
        queued moves go on and power stays [RS-7.11] [RS-7.22]."""
        self._outputs_off(("laser", "crossjet", "gas"))

    def _outputs_off(self, names: Sequence[str]) -> None:
        outputs = set(self.list_io()[0])
        for name in names:
            if name in outputs:
                self.set_output(name, False)
