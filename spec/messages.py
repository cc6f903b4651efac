"""Typed messages: one request class and one reply class per command, from the registry.

hyperframe has one class per frame type; this module has one per command and direction, so a
reply is read by name (``status.moving``), not by position, and a reply of the wrong shape is
one clear error instead of an ``assert`` somewhere downstream::

    status = RobotStatusReply.decode(params)     # MessageError on the wrong shape
    params = RobotStatusReply(...).encode()      # the parameter tuple, as the wire carries it

The classes below the generated marker are written from ``spec/registry.py`` by
``python -m spec doc --write`` and checked by ``--check`` (a test fails when they drift): the
registry stays the one place a command is declared. The decoding and encoding themselves are
the base classes here; they read the registry's parameter table of each class, so the
generated part only names the fields and their Python types.

Encoding a message gives the very tuple the servers built by hand before (``encode()`` is the
fields in table order, trailing optional fields left unset are left off), so the bytes on the
wire do not change.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, TypeVar, cast

from spec.errors import ParameterError, UsageError
from spec.params import (
    CLASS_OF,
    FloatArray,
    Image,
    IntArray,
    Joints,
    Location,
    Matrix,
    Value,
    type_of,
)
from spec.registry import BY_ID, CommandId, ParamSpec

R = TypeVar("R", bound="Reply")
M = TypeVar("M", bound="Message")


class MessageError(ParameterError):
    """A parameter list that does not fit a command's request or reply table: it names the
    command (``what``: e.g. ``"GetStatus reply"``), the ``field`` (``""`` when the count is
    wrong), what the table ``expected`` and what came (``got``). A server answers a request's
    with BAD_PARAMETERS [RS-5.4]; for a reply it is the peer breaking [RS-5.5]."""

    def __init__(self, what: str, field: str, expected: str, got: str, index: int = -1) -> None:
        self.what = what
        self.field = field
        self.expected = expected
        self.got = got
        self.index = index
        if field:
            text = f"{what} parameter {index} ({field}) must be {expected}, got {got}"
        else:
            text = f"{what} takes {expected}, got {got}"
        super().__init__(text)


def _names(table: tuple[ParamSpec, ...]) -> str:
    return ", ".join(f"{p.name}:{p.type.name}" for p in table) or "none"


def _getter(names: tuple[str, ...]) -> Callable[[Any], tuple[Any, ...]]:
    """A function giving the named attributes of an object as a tuple (one C call)."""
    if not names:
        return lambda _obj: ()
    if len(names) == 1:
        name = names[0]
        return lambda obj: (getattr(obj, name),)
    return cast("Callable[[Any], tuple[Any, ...]]", operator.attrgetter(*names))


class Message:
    """Base of every request and reply class: ``decode`` a parameter tuple, ``encode`` one."""

    __slots__ = ()

    #: The command this message belongs to.
    command: ClassVar[CommandId]
    #: The registry's parameter table of this message (the request's or the reply's).
    table: ClassVar[tuple[ParamSpec, ...]] = ()
    #: ``"request"`` or ``"reply"``.
    side: ClassVar[str] = ""
    #: How messages name it: ``"GetStatus reply"``.
    what: ClassVar[str] = ""
    #: Trailing parameters beyond the table are ignored (replies [RS-5.6]), else refused.
    allow_extra: ClassVar[bool] = False
    #: The Python class of each field when every field is given (``None`` for a table whose
    #: last field repeats): parameters of exactly these classes are ``cls(*params)``.
    exact: ClassVar[tuple[type, ...] | None] = ()
    _required: ClassVar[int] = 0
    _get: ClassVar[Callable[[Any], tuple[Any, ...]]] = _getter(())
    _trim: ClassVar[bool] = False  # some trailing fields are optional
    _repeated: ClassVar[bool] = False  # the last field collects the rest

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        command = cls.__dict__.get("command")
        if command is None:
            return  # a base class (Request, Reply)
        spec = BY_ID[command]
        table = spec.params if cls.side == "request" else spec.reply
        cls.table = table
        cls.what = f"{spec.name} {cls.side}"
        cls._required = sum(1 for p in table if not p.optional and not p.repeated)
        cls._repeated = bool(table) and table[-1].repeated
        cls._trim = any(p.optional for p in table)
        # An exact-class tuple the fast path compares with; a repeated table never matches it.
        cls.exact = None if cls._repeated else tuple(CLASS_OF[p.type] for p in table)
        cls._get = _getter(tuple(p.name for p in table))

    @classmethod
    def decode(cls: type[M], params: Sequence[Value]) -> M:
        """The message of parameter tuple ``params``; :class:`MessageError` (naming the command,
        the field, the expected and the got type) when they do not fit its table."""
        if tuple(map(type, params)) == cls.exact:
            return cast("Callable[..., M]", cls)(*params)  # nearly always: the declared types
        return cast("Callable[..., M]", cls)(*cls._checked(params))

    @classmethod
    def _checked(cls, params: Sequence[Value]) -> list[object]:
        table = cls.table
        values = list(params)
        if cls.allow_extra and not cls._repeated and len(values) > len(table):
            del values[len(table) :]  # a newer minor version's additions [RS-5.6]
        if len(values) < cls._required or (not cls._repeated and len(values) > len(table)):
            required = cls._required
            count = f"{required}" if required == len(table) else f"{required}..{len(table)}"
            expected = f"{count} parameters ({_names(table)})"
            raise MessageError(cls.what, "", expected, str(len(values)))
        for i, value in enumerate(values):
            p = table[min(i, len(table) - 1)]
            try:
                actual = type_of(value).name
            except UsageError:
                actual = type(value).__name__
            if actual != p.type.name:
                raise MessageError(cls.what, p.name, p.type.name, actual, i)
        if cls._repeated:
            k = len(table) - 1
            return [*values[:k], tuple(values[k:])]
        return values + [None] * (len(table) - len(values))  # optional ones left off

    def __reduce__(self) -> tuple[Any, ...]:
        # Pickled as its class and its fields (the real-time pipe carries requests): a third
        # cheaper than the frozen dataclass's own state protocol.
        return (type(self), type(self)._get(self))

    def as_dict(self) -> dict[str, Any]:
        """The fields by name, in table order (e.g. for a JSON report)."""
        return {p.name: getattr(self, p.name) for p in self.table}

    def encode(self) -> tuple[Value, ...]:
        """The parameter tuple of this message, in table order; trailing optional fields that
        are None are left off (as an older peer sends them)."""
        values = type(self)._get(self)
        if self._repeated:
            values = (*values[:-1], *values[-1])
        elif self._trim:
            n = len(values)
            while n and values[n - 1] is None:
                n -= 1
            values = values[:n]
        return cast("tuple[Value, ...]", values)


class Reply(Message):
    """Base of the reply classes."""

    __slots__ = ()
    side = "reply"
    allow_extra = True


class Request(Message, Generic[R]):
    """Base of the request classes; ``Request[X]`` is answered by an ``X``."""

    __slots__ = ()
    side = "request"

    def reply_type(self) -> type[R]:
        """The class of this request's reply."""
        return cast("type[R]", REPLIES[self.command])


def reply_of(command: int, params: Sequence[Value]) -> Reply:
    """The typed reply of ``command`` (:class:`MessageError` on the wrong shape)."""
    return REPLIES[command].decode(params)


def request_of(command: int, params: Sequence[Value]) -> Request[Any]:
    """The typed request of ``command`` (:class:`MessageError` on the wrong shape)."""
    return REQUESTS[command].decode(params)


# fmt: off
# --- generated from spec/registry.py by `python -m spec doc --write`: do not edit below ---


@dataclass(frozen=True, slots=True)
class HelloRequest(Request["HelloReply"]):
    """Hello (0x0001, common) request."""

    command: ClassVar[CommandId] = CommandId.HELLO
    major: int
    minor: int
    client: str


@dataclass(frozen=True, slots=True)
class HelloReply(Reply):
    """Hello (0x0001, common) reply."""

    command: ClassVar[CommandId] = CommandId.HELLO
    version: str
    service: str
    vendor: str
    model: str
    serial: str
    software: str
    commands: IntArray
    max_payload: int  # bytes
    max_clients: int
    idle_timeout: float  # s
    frame_timeout: float  # s


@dataclass(frozen=True, slots=True)
class PingRequest(Request["PingReply"]):
    """Ping (0x0002, common) request."""

    command: ClassVar[CommandId] = CommandId.PING
    data: bytes | None = None


@dataclass(frozen=True, slots=True)
class PingReply(Reply):
    """Ping (0x0002, common) reply."""

    command: ClassVar[CommandId] = CommandId.PING
    data: bytes


@dataclass(frozen=True, slots=True)
class TakeControlRequest(Request["TakeControlReply"]):
    """TakeControl (0x0003, common) request."""

    command: ClassVar[CommandId] = CommandId.TAKE_CONTROL
    token: str
    watchdog: float | None = None  # s


@dataclass(frozen=True, slots=True)
class TakeControlReply(Reply):
    """TakeControl (0x0003, common) reply."""

    command: ClassVar[CommandId] = CommandId.TAKE_CONTROL
    watchdog: float | None = None  # s


@dataclass(frozen=True, slots=True)
class ReleaseControlRequest(Request["ReleaseControlReply"]):
    """ReleaseControl (0x0004, common) request."""

    command: ClassVar[CommandId] = CommandId.RELEASE_CONTROL


@dataclass(frozen=True, slots=True)
class ReleaseControlReply(Reply):
    """ReleaseControl (0x0004, common) reply."""

    command: ClassVar[CommandId] = CommandId.RELEASE_CONTROL


@dataclass(frozen=True, slots=True)
class GetTimeRequest(Request["GetTimeReply"]):
    """GetTime (0x0005, common) request."""

    command: ClassVar[CommandId] = CommandId.GET_TIME


@dataclass(frozen=True, slots=True)
class GetTimeReply(Reply):
    """GetTime (0x0005, common) reply."""

    command: ClassVar[CommandId] = CommandId.GET_TIME
    time: float  # s


@dataclass(frozen=True, slots=True)
class SetFrameCrcRequest(Request["SetFrameCrcReply"]):
    """SetFrameCrc (0x0006, common) request."""

    command: ClassVar[CommandId] = CommandId.SET_FRAME_CRC
    enabled: bool


@dataclass(frozen=True, slots=True)
class SetFrameCrcReply(Reply):
    """SetFrameCrc (0x0006, common) reply."""

    command: ClassVar[CommandId] = CommandId.SET_FRAME_CRC
    enabled: bool


@dataclass(frozen=True, slots=True)
class RobotStatusRequest(Request["RobotStatusReply"]):
    """GetStatus (0x1001, robot) request."""

    command: ClassVar[CommandId] = CommandId.ROBOT_STATUS


@dataclass(frozen=True, slots=True)
class RobotStatusReply(Reply):
    """GetStatus (0x1001, robot) reply."""

    command: ClassVar[CommandId] = CommandId.ROBOT_STATUS
    powered: bool
    estop: bool
    moving: bool
    queue: int
    in_control: bool
    controlled: bool
    last_error: int
    last_message: str
    time: float  # s


@dataclass(frozen=True, slots=True)
class HerejRequest(Request["HerejReply"]):
    """Herej (0x1002, robot) request."""

    command: ClassVar[CommandId] = CommandId.HEREJ


@dataclass(frozen=True, slots=True)
class HerejReply(Reply):
    """Herej (0x1002, robot) reply."""

    command: ClassVar[CommandId] = CommandId.HEREJ
    joints: Joints  # deg


@dataclass(frozen=True, slots=True)
class HereRequest(Request["HereReply"]):
    """Here (0x1003, robot) request."""

    command: ClassVar[CommandId] = CommandId.HERE
    tool: Location  # mm, deg
    frame: Location  # mm, deg


@dataclass(frozen=True, slots=True)
class HereReply(Reply):
    """Here (0x1003, robot) reply."""

    command: ClassVar[CommandId] = CommandId.HERE
    location: Location  # mm, deg


@dataclass(frozen=True, slots=True)
class EnablePowerRequest(Request["EnablePowerReply"]):
    """EnablePower (0x1004, robot) request."""

    command: ClassVar[CommandId] = CommandId.ENABLE_POWER


@dataclass(frozen=True, slots=True)
class EnablePowerReply(Reply):
    """EnablePower (0x1004, robot) reply."""

    command: ClassVar[CommandId] = CommandId.ENABLE_POWER


@dataclass(frozen=True, slots=True)
class DisablePowerRequest(Request["DisablePowerReply"]):
    """DisablePower (0x1005, robot) request."""

    command: ClassVar[CommandId] = CommandId.DISABLE_POWER


@dataclass(frozen=True, slots=True)
class DisablePowerReply(Reply):
    """DisablePower (0x1005, robot) reply."""

    command: ClassVar[CommandId] = CommandId.DISABLE_POWER


@dataclass(frozen=True, slots=True)
class JointMoveRequest(Request["JointMoveReply"]):
    """JointMove (0x1006, robot) request."""

    command: ClassVar[CommandId] = CommandId.JOINT_MOVE
    joints: Joints  # deg


@dataclass(frozen=True, slots=True)
class JointMoveReply(Reply):
    """JointMove (0x1006, robot) reply."""

    command: ClassVar[CommandId] = CommandId.JOINT_MOVE
    move_id: int


@dataclass(frozen=True, slots=True)
class ToolMoveJRequest(Request["ToolMoveJReply"]):
    """ToolMoveJ (0x1007, robot) request."""

    command: ClassVar[CommandId] = CommandId.TOOL_MOVE_J
    location: Location  # mm, deg
    tool: Location  # mm, deg
    frame: Location  # mm, deg


@dataclass(frozen=True, slots=True)
class ToolMoveJReply(Reply):
    """ToolMoveJ (0x1007, robot) reply."""

    command: ClassVar[CommandId] = CommandId.TOOL_MOVE_J
    move_id: int


@dataclass(frozen=True, slots=True)
class ToolMoveLRequest(Request["ToolMoveLReply"]):
    """ToolMoveL (0x1008, robot) request."""

    command: ClassVar[CommandId] = CommandId.TOOL_MOVE_L
    location: Location  # mm, deg
    tool: Location  # mm, deg
    frame: Location  # mm, deg


@dataclass(frozen=True, slots=True)
class ToolMoveLReply(Reply):
    """ToolMoveL (0x1008, robot) reply."""

    command: ClassVar[CommandId] = CommandId.TOOL_MOVE_L
    move_id: int


@dataclass(frozen=True, slots=True)
class SetMotionDescRequest(Request["SetMotionDescReply"]):
    """SetMotionDesc (0x1009, robot) request."""

    command: ClassVar[CommandId] = CommandId.SET_MOTION_DESC
    joint_speed: float  # %
    joint_accel: float  # %
    joint_decel: float  # %
    tool_speed: float  # mm/s
    tool_rot_speed: float  # deg/s
    blend: float  # mm


@dataclass(frozen=True, slots=True)
class SetMotionDescReply(Reply):
    """SetMotionDesc (0x1009, robot) reply."""

    command: ClassVar[CommandId] = CommandId.SET_MOTION_DESC


@dataclass(frozen=True, slots=True)
class GetMotionDescRequest(Request["GetMotionDescReply"]):
    """GetMotionDesc (0x100A, robot) request."""

    command: ClassVar[CommandId] = CommandId.GET_MOTION_DESC


@dataclass(frozen=True, slots=True)
class GetMotionDescReply(Reply):
    """GetMotionDesc (0x100A, robot) reply."""

    command: ClassVar[CommandId] = CommandId.GET_MOTION_DESC
    joint_speed: float  # %
    joint_accel: float  # %
    joint_decel: float  # %
    tool_speed: float  # mm/s
    tool_rot_speed: float  # deg/s
    blend: float  # mm


@dataclass(frozen=True, slots=True)
class WaitEndMoveRequest(Request["WaitEndMoveReply"]):
    """WaitEndMove (0x100B, robot) request."""

    command: ClassVar[CommandId] = CommandId.WAIT_END_MOVE
    timeout: float  # s


@dataclass(frozen=True, slots=True)
class WaitEndMoveReply(Reply):
    """WaitEndMove (0x100B, robot) reply."""

    command: ClassVar[CommandId] = CommandId.WAIT_END_MOVE
    done: bool
    outcome: str | None = None
    reason: str | None = None


@dataclass(frozen=True, slots=True)
class StopMoveRequest(Request["StopMoveReply"]):
    """StopMove (0x100C, robot) request."""

    command: ClassVar[CommandId] = CommandId.STOP_MOVE


@dataclass(frozen=True, slots=True)
class StopMoveReply(Reply):
    """StopMove (0x100C, robot) reply."""

    command: ClassVar[CommandId] = CommandId.STOP_MOVE


@dataclass(frozen=True, slots=True)
class RestartMoveRequest(Request["RestartMoveReply"]):
    """RestartMove (0x100D, robot) request."""

    command: ClassVar[CommandId] = CommandId.RESTART_MOVE


@dataclass(frozen=True, slots=True)
class RestartMoveReply(Reply):
    """RestartMove (0x100D, robot) reply."""

    command: ClassVar[CommandId] = CommandId.RESTART_MOVE


@dataclass(frozen=True, slots=True)
class ResetMotionRequest(Request["ResetMotionReply"]):
    """ResetMotion (0x100E, robot) request."""

    command: ClassVar[CommandId] = CommandId.RESET_MOTION


@dataclass(frozen=True, slots=True)
class ResetMotionReply(Reply):
    """ResetMotion (0x100E, robot) reply."""

    command: ClassVar[CommandId] = CommandId.RESET_MOTION


@dataclass(frozen=True, slots=True)
class EmergencyStopRequest(Request["EmergencyStopReply"]):
    """EmergencyStop (0x100F, robot) request."""

    command: ClassVar[CommandId] = CommandId.EMERGENCY_STOP


@dataclass(frozen=True, slots=True)
class EmergencyStopReply(Reply):
    """EmergencyStop (0x100F, robot) reply."""

    command: ClassVar[CommandId] = CommandId.EMERGENCY_STOP


@dataclass(frozen=True, slots=True)
class ResetEmergencyStopRequest(Request["ResetEmergencyStopReply"]):
    """ResetEmergencyStop (0x1010, robot) request."""

    command: ClassVar[CommandId] = CommandId.RESET_EMERGENCY_STOP


@dataclass(frozen=True, slots=True)
class ResetEmergencyStopReply(Reply):
    """ResetEmergencyStop (0x1010, robot) reply."""

    command: ClassVar[CommandId] = CommandId.RESET_EMERGENCY_STOP


@dataclass(frozen=True, slots=True)
class SetOutputRequest(Request["SetOutputReply"]):
    """SetOutput (0x1011, robot) request."""

    command: ClassVar[CommandId] = CommandId.SET_OUTPUT
    name: str
    value: bool


@dataclass(frozen=True, slots=True)
class SetOutputReply(Reply):
    """SetOutput (0x1011, robot) reply."""

    command: ClassVar[CommandId] = CommandId.SET_OUTPUT


@dataclass(frozen=True, slots=True)
class ReadIORequest(Request["ReadIOReply"]):
    """ReadIO (0x1012, robot) request."""

    command: ClassVar[CommandId] = CommandId.READ_IO
    name: str


@dataclass(frozen=True, slots=True)
class ReadIOReply(Reply):
    """ReadIO (0x1012, robot) reply."""

    command: ClassVar[CommandId] = CommandId.READ_IO
    value: bool
    is_output: bool


@dataclass(frozen=True, slots=True)
class ListIORequest(Request["ListIOReply"]):
    """ListIO (0x1013, robot) request."""

    command: ClassVar[CommandId] = CommandId.LIST_IO


@dataclass(frozen=True, slots=True)
class ListIOReply(Reply):
    """ListIO (0x1013, robot) reply."""

    command: ClassVar[CommandId] = CommandId.LIST_IO
    outputs: str
    inputs: str


@dataclass(frozen=True, slots=True)
class GetJointLogRequest(Request["GetJointLogReply"]):
    """GetJointLog (0x1014, robot) request."""

    command: ClassVar[CommandId] = CommandId.GET_JOINT_LOG
    since: float  # s


@dataclass(frozen=True, slots=True)
class GetJointLogReply(Reply):
    """GetJointLog (0x1014, robot) reply."""

    command: ClassVar[CommandId] = CommandId.GET_JOINT_LOG
    log: Matrix  # s, deg
    period: float  # s


@dataclass(frozen=True, slots=True)
class GetJointLimitsRequest(Request["GetJointLimitsReply"]):
    """GetJointLimits (0x1015, robot) request."""

    command: ClassVar[CommandId] = CommandId.GET_JOINT_LIMITS


@dataclass(frozen=True, slots=True)
class GetJointLimitsReply(Reply):
    """GetJointLimits (0x1015, robot) reply."""

    command: ClassVar[CommandId] = CommandId.GET_JOINT_LIMITS
    limits: Matrix  # deg


@dataclass(frozen=True, slots=True)
class ToolMoveTrajectoryRequest(Request["ToolMoveTrajectoryReply"]):
    """ToolMoveTrajectory (0x1016, robot) request."""

    command: ClassVar[CommandId] = CommandId.TOOL_MOVE_TRAJECTORY
    times: FloatArray  # s
    locations: Matrix  # mm, deg
    tool: Location  # mm, deg
    frame: Location  # mm, deg


@dataclass(frozen=True, slots=True)
class ToolMoveTrajectoryReply(Reply):
    """ToolMoveTrajectory (0x1016, robot) reply."""

    command: ClassVar[CommandId] = CommandId.TOOL_MOVE_TRAJECTORY
    move_id: int


@dataclass(frozen=True, slots=True)
class AlterBeginRequest(Request["AlterBeginReply"]):
    """AlterBegin (0x1017, robot) request."""

    command: ClassVar[CommandId] = CommandId.ALTER_BEGIN
    tool: Location  # mm, deg
    timeout: float  # s


@dataclass(frozen=True, slots=True)
class AlterBeginReply(Reply):
    """AlterBegin (0x1017, robot) reply."""

    command: ClassVar[CommandId] = CommandId.ALTER_BEGIN


@dataclass(frozen=True, slots=True)
class AlterRequest(Request["AlterReply"]):
    """Alter (0x1018, robot) request."""

    command: ClassVar[CommandId] = CommandId.ALTER
    correction: Location  # mm, deg


@dataclass(frozen=True, slots=True)
class AlterReply(Reply):
    """Alter (0x1018, robot) reply."""

    command: ClassVar[CommandId] = CommandId.ALTER
    applied: Location  # mm, deg


@dataclass(frozen=True, slots=True)
class AlterEndRequest(Request["AlterEndReply"]):
    """AlterEnd (0x1019, robot) request."""

    command: ClassVar[CommandId] = CommandId.ALTER_END


@dataclass(frozen=True, slots=True)
class AlterEndReply(Reply):
    """AlterEnd (0x1019, robot) reply."""

    command: ClassVar[CommandId] = CommandId.ALTER_END


@dataclass(frozen=True, slots=True)
class AlterQueueRequest(Request["AlterQueueReply"]):
    """AlterQueue (0x101A, robot) request."""

    command: ClassVar[CommandId] = CommandId.ALTER_QUEUE
    times: FloatArray  # s
    corrections: Matrix  # mm, deg


@dataclass(frozen=True, slots=True)
class AlterQueueReply(Reply):
    """AlterQueue (0x101A, robot) reply."""

    command: ClassVar[CommandId] = CommandId.ALTER_QUEUE
    accepted: int
    late: int
    depth: int
    horizon: float  # s
    late_total: int
    held_total: int
    applied: Location  # mm, deg
    time: float  # s


@dataclass(frozen=True, slots=True)
class SensorStatusRequest(Request["SensorStatusReply"]):
    """GetStatus (0x2001, sensor) request."""

    command: ClassVar[CommandId] = CommandId.SENSOR_STATUS


@dataclass(frozen=True, slots=True)
class SensorStatusReply(Reply):
    """GetStatus (0x2001, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.SENSOR_STATUS
    laser: bool
    frames: int
    last_index: int
    in_control: bool
    controlled: bool
    time: float  # s


@dataclass(frozen=True, slots=True)
class GetDataRequest(Request["GetDataReply"]):
    """GetData (0x2002, sensor) request."""

    command: ClassVar[CommandId] = CommandId.GET_DATA


@dataclass(frozen=True, slots=True)
class GetDataReply(Reply):
    """GetData (0x2002, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.GET_DATA
    index: int
    status: int
    seam: Location  # mm, deg
    quality: float
    t_arrival: float  # s
    t_exposure_start: float  # s
    t_exposure_end: float  # s


@dataclass(frozen=True, slots=True)
class GetImageRequest(Request["GetImageReply"]):
    """GetImage (0x2003, sensor) request."""

    command: ClassVar[CommandId] = CommandId.GET_IMAGE
    column: int | None = None  # px
    row: int | None = None  # px
    width: int | None = None  # px
    height: int | None = None  # px


@dataclass(frozen=True, slots=True)
class GetImageReply(Reply):
    """GetImage (0x2003, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.GET_IMAGE
    index: int
    image: Image


@dataclass(frozen=True, slots=True)
class GetProfileRequest(Request["GetProfileReply"]):
    """GetProfile (0x2004, sensor) request."""

    command: ClassVar[CommandId] = CommandId.GET_PROFILE


@dataclass(frozen=True, slots=True)
class GetProfileReply(Reply):
    """GetProfile (0x2004, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.GET_PROFILE
    index: int
    points: Matrix  # mm


@dataclass(frozen=True, slots=True)
class SetLaserRequest(Request["SetLaserReply"]):
    """SetLaser (0x2005, sensor) request."""

    command: ClassVar[CommandId] = CommandId.SET_LASER
    on: bool


@dataclass(frozen=True, slots=True)
class SetLaserReply(Reply):
    """SetLaser (0x2005, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.SET_LASER


@dataclass(frozen=True, slots=True)
class SetExposureRequest(Request["SetExposureReply"]):
    """SetExposure (0x2006, sensor) request."""

    command: ClassVar[CommandId] = CommandId.SET_EXPOSURE
    exposure: float  # s


@dataclass(frozen=True, slots=True)
class SetExposureReply(Reply):
    """SetExposure (0x2006, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.SET_EXPOSURE


@dataclass(frozen=True, slots=True)
class SetReadoutWindowRequest(Request["SetReadoutWindowReply"]):
    """SetReadoutWindow (0x2007, sensor) request."""

    command: ClassVar[CommandId] = CommandId.SET_READOUT_WINDOW
    first_column: int  # px
    columns: int  # px


@dataclass(frozen=True, slots=True)
class SetReadoutWindowReply(Reply):
    """SetReadoutWindow (0x2007, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.SET_READOUT_WINDOW
    acquisition_time: float  # s


@dataclass(frozen=True, slots=True)
class GetSettingsRequest(Request["GetSettingsReply"]):
    """GetSettings (0x2008, sensor) request."""

    command: ClassVar[CommandId] = CommandId.GET_SETTINGS


@dataclass(frozen=True, slots=True)
class GetSettingsReply(Reply):
    """GetSettings (0x2008, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.GET_SETTINGS
    laser: bool
    exposure: float  # s
    first_column: int  # px
    columns: int  # px
    acquisition_time: float  # s
    width: int  # px
    height: int  # px


@dataclass(frozen=True, slots=True)
class AcquireRequest(Request["AcquireReply"]):
    """Acquire (0x2009, sensor) request."""

    command: ClassVar[CommandId] = CommandId.ACQUIRE


@dataclass(frozen=True, slots=True)
class AcquireReply(Reply):
    """Acquire (0x2009, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.ACQUIRE
    index: int


@dataclass(frozen=True, slots=True)
class GetTriggerEndpointRequest(Request["GetTriggerEndpointReply"]):
    """GetTriggerEndpoint (0x200A, sensor) request."""

    command: ClassVar[CommandId] = CommandId.GET_TRIGGER_ENDPOINT


@dataclass(frozen=True, slots=True)
class GetTriggerEndpointReply(Reply):
    """GetTriggerEndpoint (0x200A, sensor) reply."""

    command: ClassVar[CommandId] = CommandId.GET_TRIGGER_ENDPOINT
    host: str
    port: int


@dataclass(frozen=True, slots=True)
class SetSensorEndpointRequest(Request["SetSensorEndpointReply"]):
    """SetSensorEndpoint (0x3001, sync) request."""

    command: ClassVar[CommandId] = CommandId.SET_SENSOR_ENDPOINT
    host: str
    port: int


@dataclass(frozen=True, slots=True)
class SetSensorEndpointReply(Reply):
    """SetSensorEndpoint (0x3001, sync) reply."""

    command: ClassVar[CommandId] = CommandId.SET_SENSOR_ENDPOINT


@dataclass(frozen=True, slots=True)
class SetSyncDelayRequest(Request["SetSyncDelayReply"]):
    """SetSyncDelay (0x3002, sync) request."""

    command: ClassVar[CommandId] = CommandId.SET_SYNC_DELAY
    delta_t: float  # s


@dataclass(frozen=True, slots=True)
class SetSyncDelayReply(Reply):
    """SetSyncDelay (0x3002, sync) reply."""

    command: ClassVar[CommandId] = CommandId.SET_SYNC_DELAY


@dataclass(frozen=True, slots=True)
class SetSensorToolRequest(Request["SetSensorToolReply"]):
    """SetSensorTool (0x3003, sync) request."""

    command: ClassVar[CommandId] = CommandId.SET_SENSOR_TOOL
    sensor2flange: Location  # mm, deg


@dataclass(frozen=True, slots=True)
class SetSensorToolReply(Reply):
    """SetSensorTool (0x3003, sync) reply."""

    command: ClassVar[CommandId] = CommandId.SET_SENSOR_TOOL


@dataclass(frozen=True, slots=True)
class GetSyncConfigRequest(Request["GetSyncConfigReply"]):
    """GetSyncConfig (0x3004, sync) request."""

    command: ClassVar[CommandId] = CommandId.GET_SYNC_CONFIG


@dataclass(frozen=True, slots=True)
class GetSyncConfigReply(Reply):
    """GetSyncConfig (0x3004, sync) reply."""

    command: ClassVar[CommandId] = CommandId.GET_SYNC_CONFIG
    host: str
    port: int
    delta_t: float  # s
    sensor2flange: Location  # mm, deg
    triggering: bool
    rate: float  # Hz


@dataclass(frozen=True, slots=True)
class StartTriggersRequest(Request["StartTriggersReply"]):
    """StartTriggers (0x3005, sync) request."""

    command: ClassVar[CommandId] = CommandId.START_TRIGGERS
    rate: float  # Hz
    count: int


@dataclass(frozen=True, slots=True)
class StartTriggersReply(Reply):
    """StartTriggers (0x3005, sync) reply."""

    command: ClassVar[CommandId] = CommandId.START_TRIGGERS
    first_index: int


@dataclass(frozen=True, slots=True)
class ScheduleTriggersRequest(Request["ScheduleTriggersReply"]):
    """ScheduleTriggers (0x3006, sync) request."""

    command: ClassVar[CommandId] = CommandId.SCHEDULE_TRIGGERS
    times: FloatArray  # s


@dataclass(frozen=True, slots=True)
class ScheduleTriggersReply(Reply):
    """ScheduleTriggers (0x3006, sync) reply."""

    command: ClassVar[CommandId] = CommandId.SCHEDULE_TRIGGERS
    first_index: int


@dataclass(frozen=True, slots=True)
class StopTriggersRequest(Request["StopTriggersReply"]):
    """StopTriggers (0x3007, sync) request."""

    command: ClassVar[CommandId] = CommandId.STOP_TRIGGERS


@dataclass(frozen=True, slots=True)
class StopTriggersReply(Reply):
    """StopTriggers (0x3007, sync) reply."""

    command: ClassVar[CommandId] = CommandId.STOP_TRIGGERS


@dataclass(frozen=True, slots=True)
class GetSeamPointsRequest(Request["GetSeamPointsReply"]):
    """GetSeamPoints (0x3008, sync) request."""

    command: ClassVar[CommandId] = CommandId.GET_SEAM_POINTS
    since: int


@dataclass(frozen=True, slots=True)
class GetSeamPointsReply(Reply):
    """GetSeamPoints (0x3008, sync) reply."""

    command: ClassVar[CommandId] = CommandId.GET_SEAM_POINTS
    points: Matrix


@dataclass(frozen=True, slots=True)
class GetSyncStatisticsRequest(Request["GetSyncStatisticsReply"]):
    """GetSyncStatistics (0x3009, sync) request."""

    command: ClassVar[CommandId] = CommandId.GET_SYNC_STATISTICS


@dataclass(frozen=True, slots=True)
class GetSyncStatisticsReply(Reply):
    """GetSyncStatistics (0x3009, sync) reply."""

    command: ClassVar[CommandId] = CommandId.GET_SYNC_STATISTICS
    sent: int
    received: int
    matched: int
    lost: int
    late: int
    duplicate: int
    reordered: int
    unknown: int
    expired: int
    malformed: int
    pending: int
    exposed_late: int | None = None


#: Each command's request class, by command ID.
REQUESTS: dict[int, type[Request[Any]]] = {
    CommandId.HELLO: HelloRequest,
    CommandId.PING: PingRequest,
    CommandId.TAKE_CONTROL: TakeControlRequest,
    CommandId.RELEASE_CONTROL: ReleaseControlRequest,
    CommandId.GET_TIME: GetTimeRequest,
    CommandId.SET_FRAME_CRC: SetFrameCrcRequest,
    CommandId.ROBOT_STATUS: RobotStatusRequest,
    CommandId.HEREJ: HerejRequest,
    CommandId.HERE: HereRequest,
    CommandId.ENABLE_POWER: EnablePowerRequest,
    CommandId.DISABLE_POWER: DisablePowerRequest,
    CommandId.JOINT_MOVE: JointMoveRequest,
    CommandId.TOOL_MOVE_J: ToolMoveJRequest,
    CommandId.TOOL_MOVE_L: ToolMoveLRequest,
    CommandId.SET_MOTION_DESC: SetMotionDescRequest,
    CommandId.GET_MOTION_DESC: GetMotionDescRequest,
    CommandId.WAIT_END_MOVE: WaitEndMoveRequest,
    CommandId.STOP_MOVE: StopMoveRequest,
    CommandId.RESTART_MOVE: RestartMoveRequest,
    CommandId.RESET_MOTION: ResetMotionRequest,
    CommandId.EMERGENCY_STOP: EmergencyStopRequest,
    CommandId.RESET_EMERGENCY_STOP: ResetEmergencyStopRequest,
    CommandId.SET_OUTPUT: SetOutputRequest,
    CommandId.READ_IO: ReadIORequest,
    CommandId.LIST_IO: ListIORequest,
    CommandId.GET_JOINT_LOG: GetJointLogRequest,
    CommandId.GET_JOINT_LIMITS: GetJointLimitsRequest,
    CommandId.TOOL_MOVE_TRAJECTORY: ToolMoveTrajectoryRequest,
    CommandId.ALTER_BEGIN: AlterBeginRequest,
    CommandId.ALTER: AlterRequest,
    CommandId.ALTER_END: AlterEndRequest,
    CommandId.ALTER_QUEUE: AlterQueueRequest,
    CommandId.SENSOR_STATUS: SensorStatusRequest,
    CommandId.GET_DATA: GetDataRequest,
    CommandId.GET_IMAGE: GetImageRequest,
    CommandId.GET_PROFILE: GetProfileRequest,
    CommandId.SET_LASER: SetLaserRequest,
    CommandId.SET_EXPOSURE: SetExposureRequest,
    CommandId.SET_READOUT_WINDOW: SetReadoutWindowRequest,
    CommandId.GET_SETTINGS: GetSettingsRequest,
    CommandId.ACQUIRE: AcquireRequest,
    CommandId.GET_TRIGGER_ENDPOINT: GetTriggerEndpointRequest,
    CommandId.SET_SENSOR_ENDPOINT: SetSensorEndpointRequest,
    CommandId.SET_SYNC_DELAY: SetSyncDelayRequest,
    CommandId.SET_SENSOR_TOOL: SetSensorToolRequest,
    CommandId.GET_SYNC_CONFIG: GetSyncConfigRequest,
    CommandId.START_TRIGGERS: StartTriggersRequest,
    CommandId.SCHEDULE_TRIGGERS: ScheduleTriggersRequest,
    CommandId.STOP_TRIGGERS: StopTriggersRequest,
    CommandId.GET_SEAM_POINTS: GetSeamPointsRequest,
    CommandId.GET_SYNC_STATISTICS: GetSyncStatisticsRequest,
}


#: Each command's reply class, by command ID.
REPLIES: dict[int, type[Reply]] = {
    CommandId.HELLO: HelloReply,
    CommandId.PING: PingReply,
    CommandId.TAKE_CONTROL: TakeControlReply,
    CommandId.RELEASE_CONTROL: ReleaseControlReply,
    CommandId.GET_TIME: GetTimeReply,
    CommandId.SET_FRAME_CRC: SetFrameCrcReply,
    CommandId.ROBOT_STATUS: RobotStatusReply,
    CommandId.HEREJ: HerejReply,
    CommandId.HERE: HereReply,
    CommandId.ENABLE_POWER: EnablePowerReply,
    CommandId.DISABLE_POWER: DisablePowerReply,
    CommandId.JOINT_MOVE: JointMoveReply,
    CommandId.TOOL_MOVE_J: ToolMoveJReply,
    CommandId.TOOL_MOVE_L: ToolMoveLReply,
    CommandId.SET_MOTION_DESC: SetMotionDescReply,
    CommandId.GET_MOTION_DESC: GetMotionDescReply,
    CommandId.WAIT_END_MOVE: WaitEndMoveReply,
    CommandId.STOP_MOVE: StopMoveReply,
    CommandId.RESTART_MOVE: RestartMoveReply,
    CommandId.RESET_MOTION: ResetMotionReply,
    CommandId.EMERGENCY_STOP: EmergencyStopReply,
    CommandId.RESET_EMERGENCY_STOP: ResetEmergencyStopReply,
    CommandId.SET_OUTPUT: SetOutputReply,
    CommandId.READ_IO: ReadIOReply,
    CommandId.LIST_IO: ListIOReply,
    CommandId.GET_JOINT_LOG: GetJointLogReply,
    CommandId.GET_JOINT_LIMITS: GetJointLimitsReply,
    CommandId.TOOL_MOVE_TRAJECTORY: ToolMoveTrajectoryReply,
    CommandId.ALTER_BEGIN: AlterBeginReply,
    CommandId.ALTER: AlterReply,
    CommandId.ALTER_END: AlterEndReply,
    CommandId.ALTER_QUEUE: AlterQueueReply,
    CommandId.SENSOR_STATUS: SensorStatusReply,
    CommandId.GET_DATA: GetDataReply,
    CommandId.GET_IMAGE: GetImageReply,
    CommandId.GET_PROFILE: GetProfileReply,
    CommandId.SET_LASER: SetLaserReply,
    CommandId.SET_EXPOSURE: SetExposureReply,
    CommandId.SET_READOUT_WINDOW: SetReadoutWindowReply,
    CommandId.GET_SETTINGS: GetSettingsReply,
    CommandId.ACQUIRE: AcquireReply,
    CommandId.GET_TRIGGER_ENDPOINT: GetTriggerEndpointReply,
    CommandId.SET_SENSOR_ENDPOINT: SetSensorEndpointReply,
    CommandId.SET_SYNC_DELAY: SetSyncDelayReply,
    CommandId.SET_SENSOR_TOOL: SetSensorToolReply,
    CommandId.GET_SYNC_CONFIG: GetSyncConfigReply,
    CommandId.START_TRIGGERS: StartTriggersReply,
    CommandId.SCHEDULE_TRIGGERS: ScheduleTriggersReply,
    CommandId.STOP_TRIGGERS: StopTriggersReply,
    CommandId.GET_SEAM_POINTS: GetSeamPointsReply,
    CommandId.GET_SYNC_STATISTICS: GetSyncStatisticsReply,
}


# --- end of generated code ---
# fmt: on
