"""The command registry: every command's ID, parameters, reply and rules, as data.

PROTOCOL.md's command tables are generated from this registry (``python -m spec doc``) and a
test fails when they drift apart. Services dispatch on :class:`CommandId`; the conformance
harness, the decoder CLI and the clients read the same entries.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

from spec.errors import ParameterError
from spec.params import CLASS_OF, Value, type_of
from spec.wire import ParamType, SensorStatus

T = ParamType


class CommandId(IntEnum):
    """Stable command IDs (PROTOCOL.md section 5). Ranges: 0x0001-0x0FFF common,
    0x1000 robot, 0x2000 sensor, 0x3000 synchronisation (robot service), 0x8000-0xBFFF vendor,
    0xC000-0xFFFE experimental."""

    HELLO = 0x0001
    PING = 0x0002
    TAKE_CONTROL = 0x0003
    RELEASE_CONTROL = 0x0004
    GET_TIME = 0x0005
    SET_FRAME_CRC = 0x0006

    ROBOT_STATUS = 0x1001
    HEREJ = 0x1002
    HERE = 0x1003
    ENABLE_POWER = 0x1004
    DISABLE_POWER = 0x1005
    JOINT_MOVE = 0x1006
    TOOL_MOVE_J = 0x1007
    TOOL_MOVE_L = 0x1008
    SET_MOTION_DESC = 0x1009
    GET_MOTION_DESC = 0x100A
    WAIT_END_MOVE = 0x100B
    STOP_MOVE = 0x100C
    RESTART_MOVE = 0x100D
    RESET_MOTION = 0x100E
    EMERGENCY_STOP = 0x100F
    RESET_EMERGENCY_STOP = 0x1010
    SET_OUTPUT = 0x1011
    READ_IO = 0x1012
    LIST_IO = 0x1013
    GET_JOINT_LOG = 0x1014
    GET_JOINT_LIMITS = 0x1015
    TOOL_MOVE_TRAJECTORY = 0x1016
    ALTER_BEGIN = 0x1017
    ALTER = 0x1018
    ALTER_END = 0x1019
    ALTER_QUEUE = 0x101A

    SENSOR_STATUS = 0x2001
    GET_DATA = 0x2002
    GET_IMAGE = 0x2003
    GET_PROFILE = 0x2004
    SET_LASER = 0x2005
    SET_EXPOSURE = 0x2006
    SET_READOUT_WINDOW = 0x2007
    GET_SETTINGS = 0x2008
    ACQUIRE = 0x2009
    GET_TRIGGER_ENDPOINT = 0x200A

    SET_SENSOR_ENDPOINT = 0x3001
    SET_SYNC_DELAY = 0x3002
    SET_SENSOR_TOOL = 0x3003
    GET_SYNC_CONFIG = 0x3004
    START_TRIGGERS = 0x3005
    SCHEDULE_TRIGGERS = 0x3006
    STOP_TRIGGERS = 0x3007
    GET_SEAM_POINTS = 0x3008
    GET_SYNC_STATISTICS = 0x3009


#: An enum whose values an INT parameter takes (``type`` is a field name inside ParamSpec).
EnumType = type[IntEnum]


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One parameter of a request or reply."""

    name: str
    type: ParamType
    unit: str = ""
    doc: str = ""
    optional: bool = False  # may be left off (only trailing parameters)
    repeated: bool = False  # zero or more of this type (only the last parameter)
    enum: EnumType | None = None  # an INT whose values are this enum's (named by tools)


@dataclass(frozen=True, slots=True)
class CommandSpec:
    """A command: ID, service, request and reply parameters, and its rules."""

    id: CommandId
    name: str
    service: str  # "common", "robot", "sensor" ("sync" commands are served by the robot)
    summary: str
    params: tuple[ParamSpec, ...] = ()
    reply: tuple[ParamSpec, ...] = ()
    needs_control: bool = False
    moves: bool = False  # moves the arm or switches an output: conformance needs opt-in

    @property
    def services(self) -> tuple[str, ...]:
        if self.service == "common":
            return ("robot", "sensor")
        if self.service == "sync":
            return ("robot",)
        return (self.service,)


def P(
    name: str,
    type: ParamType,
    unit: str = "",
    doc: str = "",
    *,
    optional: bool = False,
    repeated: bool = False,
    enum: type[IntEnum] | None = None,
) -> ParamSpec:
    return ParamSpec(name, type, unit, doc, optional, repeated, enum)


_LOC_DOC = "VAL3 location x, y, z, rx, ry, rz"
_TOOL = P("tool", T.LOCATION, "mm, deg", "tool relative to the flange N (identity = flange)")
_FRAME = P("frame", T.LOCATION, "mm, deg", "reference frame relative to the base B")
_MOVE_ID = P("move_id", T.INT, "", "sequence number of the queued move")

COMMANDS: tuple[CommandSpec, ...] = (
    # --- common to both services --------------------------------------------------------
    CommandSpec(
        CommandId.HELLO,
        "Hello",
        "common",
        "Version and capability negotiation; the first request of a session.",
        params=(
            P("major", T.INT, "", "highest protocol major version the client speaks"),
            P("minor", T.INT, "", "its minor version"),
            P("client", T.STRING, "", "client name and version, free text"),
        ),
        reply=(
            P("version", T.STRING, "", 'protocol version the server speaks, e.g. "1.0"'),
            P("service", T.STRING, "", '"robot" or "sensor"'),
            P("vendor", T.STRING),
            P("model", T.STRING),
            P("serial", T.STRING),
            P("software", T.STRING, "", "server software version"),
            P("commands", T.INT_ARRAY, "", "every command ID the server implements"),
            P("max_payload", T.INT, "bytes", "largest payload the server accepts"),
            P("max_clients", T.INT, "", "simultaneous connections accepted"),
            P("idle_timeout", T.FLOAT, "s", "idle time after which the server closes"),
            P("frame_timeout", T.FLOAT, "s", "time allowed to finish a started frame"),
        ),
    ),
    CommandSpec(
        CommandId.PING,
        "Ping",
        "common",
        "Liveness probe; the reply echoes the bytes.",
        params=(P("data", T.BYTES, "", "any bytes, echoed", optional=True),),
        reply=(P("data", T.BYTES, "", "the request's bytes (empty if none)"),),
    ),
    CommandSpec(
        CommandId.TAKE_CONTROL,
        "TakeControl",
        "common",
        "Take control of the service for this connection (one holder at a time), as a lease "
        "kept by sending frames within the watchdog period (watchdog: 1.2).",
        params=(
            P("token", T.STRING, "", 'shared secret if the server requires one, else ""'),
            P(
                "watchdog",
                T.FLOAT,
                "s",
                "lease period asked for; server default if left off",
                optional=True,
            ),
        ),
        reply=(
            P(
                "watchdog",
                T.FLOAT,
                "s",
                "lease period in force (absent from 1.0 servers)",
                optional=True,
            ),
        ),
    ),
    CommandSpec(
        CommandId.RELEASE_CONTROL,
        "ReleaseControl",
        "common",
        "Give control back; harmless when this connection does not hold it.",
    ),
    CommandSpec(
        CommandId.GET_TIME,
        "GetTime",
        "common",
        "The server's clock: the time base of every timestamp it sends.",
        reply=(P("time", T.FLOAT, "s", "server clock, monotonic"),),
    ),
    CommandSpec(
        CommandId.SET_FRAME_CRC,
        "SetFrameCrc",
        "common",
        "Turn the CRC of the frames the server sends on this connection off or on (1.1).",
        params=(P("enabled", T.BOOL, "", "false: later frames carry NO_CRC and a zero trailer"),),
        reply=(P("enabled", T.BOOL, "", "the setting now in force"),),
    ),
    # --- robot --------------------------------------------------------------------------
    CommandSpec(
        CommandId.ROBOT_STATUS,
        "GetStatus",
        "robot",
        "Power, emergency stop, motion state, control and last error.",
        reply=(
            P("powered", T.BOOL),
            P("estop", T.BOOL, "", "emergency stop engaged"),
            P("moving", T.BOOL),
            P("queue", T.INT, "", "moves queued, including the one executing"),
            P("in_control", T.BOOL, "", "this connection holds control"),
            P("controlled", T.BOOL, "", "some connection holds control"),
            P("last_error", T.INT, "", "error code of the last motion error, 0 if none"),
            P("last_message", T.STRING),
            P("time", T.FLOAT, "s", "robot clock"),
        ),
    ),
    CommandSpec(
        CommandId.HEREJ,
        "Herej",
        "robot",
        "Current measured joint positions (paper: joints = Herej()).",
        reply=(P("joints", T.JOINTS, "deg"),),
    ),
    CommandSpec(
        CommandId.HERE,
        "Here",
        "robot",
        "Current location of tool relative to frame (paper: loc = Here(tool, frame)).",
        params=(_TOOL, _FRAME),
        reply=(P("location", T.LOCATION, "mm, deg", _LOC_DOC),),
    ),
    CommandSpec(
        CommandId.ENABLE_POWER,
        "EnablePower",
        "robot",
        "Switch arm power on.",
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.DISABLE_POWER,
        "DisablePower",
        "robot",
        "Stop any motion and switch arm power off.",
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.JOINT_MOVE,
        "JointMove",
        "robot",
        "Queue a joint-interpolated move to joints; returns at once.",
        params=(P("joints", T.JOINTS, "deg", "target, within the joint limits"),),
        reply=(_MOVE_ID,),
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.TOOL_MOVE_J,
        "ToolMoveJ",
        "robot",
        "Queue a joint-interpolated move bringing tool to location in frame.",
        params=(P("location", T.LOCATION, "mm, deg", "target of the tool"), _TOOL, _FRAME),
        reply=(_MOVE_ID,),
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.TOOL_MOVE_L,
        "ToolMoveL",
        "robot",
        "Queue a straight-line (Cartesian) move of tool to location in frame.",
        params=(P("location", T.LOCATION, "mm, deg", "target of the tool"), _TOOL, _FRAME),
        reply=(_MOVE_ID,),
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.SET_MOTION_DESC,
        "SetMotionDesc",
        "robot",
        "Motion descriptor for the moves queued after it (VAL3 mdesc).",
        params=(
            P("joint_speed", T.FLOAT, "%", "of nominal joint speed, 0 < v <= 100"),
            P("joint_accel", T.FLOAT, "%", "of nominal joint acceleration, 0 < a <= 100"),
            P("joint_decel", T.FLOAT, "%", "of nominal joint deceleration, 0 < d <= 100"),
            P("tool_speed", T.FLOAT, "mm/s", "Cartesian speed limit of the tool, > 0"),
            P("tool_rot_speed", T.FLOAT, "deg/s", "rotation speed limit of the tool, > 0"),
            P("blend", T.FLOAT, "mm", "blending distance to the next move, 0 = stop"),
        ),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.GET_MOTION_DESC,
        "GetMotionDesc",
        "robot",
        "The motion descriptor in force.",
        reply=(
            P("joint_speed", T.FLOAT, "%"),
            P("joint_accel", T.FLOAT, "%"),
            P("joint_decel", T.FLOAT, "%"),
            P("tool_speed", T.FLOAT, "mm/s"),
            P("tool_rot_speed", T.FLOAT, "deg/s"),
            P("blend", T.FLOAT, "mm"),
        ),
    ),
    CommandSpec(
        CommandId.WAIT_END_MOVE,
        "WaitEndMove",
        "robot",
        "Wait until the queue is empty and the arm settled (or stood stopped), at most timeout; "
        "say how the last move ended (outcome, reason: 1.3).",
        params=(P("timeout", T.FLOAT, "s", "maximum wait, 0 < timeout <= 3600"),),
        reply=(
            P("done", T.BOOL, "", "true only when the last move reached its target"),
            P(
                "outcome",
                T.STRING,
                "",
                "reached, moving, stopped or failed (absent from 1.2 servers)",
                optional=True,
            ),
            P("reason", T.STRING, "", "what stopped or failed it, else empty", optional=True),
        ),
    ),
    CommandSpec(
        CommandId.STOP_MOVE,
        "StopMove",
        "robot",
        "Decelerate along the path and hold; the queue is kept.",
        needs_control=True,
    ),
    CommandSpec(
        CommandId.RESTART_MOVE,
        "RestartMove",
        "robot",
        "Resume after StopMove.",
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.RESET_MOTION,
        "ResetMotion",
        "robot",
        "Decelerate along the path, stop and empty the queue.",
        needs_control=True,
    ),
    CommandSpec(
        CommandId.EMERGENCY_STOP,
        "EmergencyStop",
        "robot",
        "Software emergency stop: immediate stop, power off, queue emptied. Open to every client.",
    ),
    CommandSpec(
        CommandId.RESET_EMERGENCY_STOP,
        "ResetEmergencyStop",
        "robot",
        "Release the software emergency stop (power stays off).",
        needs_control=True,
    ),
    CommandSpec(
        CommandId.SET_OUTPUT,
        "SetOutput",
        "robot",
        "Switch a named digital output (e.g. laser, gas, crossjet).",
        params=(P("name", T.STRING), P("value", T.BOOL)),
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.READ_IO,
        "ReadIO",
        "robot",
        "Read a named digital input or output.",
        params=(P("name", T.STRING),),
        reply=(P("value", T.BOOL), P("is_output", T.BOOL)),
    ),
    CommandSpec(
        CommandId.LIST_IO,
        "ListIO",
        "robot",
        "Names of the digital I/O.",
        reply=(
            P("outputs", T.STRING, "", "comma-separated output names"),
            P("inputs", T.STRING, "", "comma-separated input names"),
        ),
    ),
    CommandSpec(
        CommandId.GET_JOINT_LOG,
        "GetJointLog",
        "robot",
        "Measured joints (t_k, q_k) from the cyclic buffer with t_k > since.",
        params=(P("since", T.FLOAT, "s", "robot clock; -1 for the whole buffer"),),
        reply=(
            P("log", T.MATRIX, "s, deg", "N x 7: t_k, q1..q6 (t_k = k * T_r)"),
            P("period", T.FLOAT, "s", "sample period T_r (0.004)"),
        ),
    ),
    CommandSpec(
        CommandId.GET_JOINT_LIMITS,
        "GetJointLimits",
        "robot",
        "Joint limits of the arm.",
        reply=(P("limits", T.MATRIX, "deg", "6 x 2: min, max per joint"),),
    ),
    CommandSpec(
        CommandId.TOOL_MOVE_TRAJECTORY,
        "ToolMoveTrajectory",
        "robot",
        "Queue a timed Cartesian path: the tool passes location k at times[k] after the move "
        "starts (e.g. the sine of the ΔT experiment); linear in between.",
        params=(
            P("times", T.FLOAT_ARRAY, "s", "increasing, from 0; at most 60 s"),
            P("locations", T.MATRIX, "mm, deg", "N x 6 tool locations x, y, z, rx, ry, rz"),
            _TOOL,
            _FRAME,
        ),
        reply=(_MOVE_ID,),
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.ALTER_BEGIN,
        "AlterBegin",
        "robot",
        "Start correcting the running motion (alter mode, as VAL3 alterBegin): corrections "
        "then move tool, applied from the next 4 ms cycle.",
        params=(
            _TOOL,
            P("timeout", T.FLOAT, "s", "a stream silent this long is lost; 0.008 to 1"),
        ),
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.ALTER,
        "Alter",
        "robot",
        "The whole correction in force (not an increment); the robot follows it within the "
        "size, speed and acceleration limits.",
        params=(
            P(
                "correction",
                T.LOCATION,
                "mm, deg",
                "dx, dy, dz and rotation vector rx, ry, rz of the tool, base frame",
            ),
        ),
        reply=(P("applied", T.LOCATION, "mm, deg", "the correction applied at the last cycle"),),
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.ALTER_END,
        "AlterEnd",
        "robot",
        "End alter mode: the correction ramps back to zero within the limits.",
        needs_control=True,
        moves=True,
    ),
    CommandSpec(
        CommandId.ALTER_QUEUE,
        "AlterQueue",
        "robot",
        "Queue timed corrections in alter mode: each for the cycle at a robot-clock time, "
        "interpolated in between; sent ahead (a window or a whole table in several frames), "
        "so a late client costs nothing. An empty batch reports the queue (1.3, optional).",
        params=(
            P("times", T.FLOAT_ARRAY, "s", "robot clock, strictly increasing; at most 4096"),
            P(
                "corrections",
                T.MATRIX,
                "mm, deg",
                "N x 6: dx, dy, dz and rotation vector rx, ry, rz per time, as Alter",
            ),
        ),
        reply=(
            P("accepted", T.INT, "", "entries of this batch queued"),
            P("late", T.INT, "", "entries of this batch for cycles already applied: dropped"),
            P("depth", T.INT, "", "entries queued now"),
            P("horizon", T.FLOAT, "s", "time of the last queued entry; -1 when empty"),
            P("late_total", T.INT, "", "late entries since AlterBegin"),
            P("held_total", T.INT, "", "cycles past the last entry since AlterBegin"),
            P("applied", T.LOCATION, "mm, deg", "the correction applied at the last cycle"),
            P("time", T.FLOAT, "s", "robot time of the last cycle applied"),
        ),
        needs_control=True,
        moves=True,
    ),
    # --- sensor -------------------------------------------------------------------------
    CommandSpec(
        CommandId.SENSOR_STATUS,
        "GetStatus",
        "sensor",
        "Laser, acquisition counters and control.",
        reply=(
            P("laser", T.BOOL),
            P("frames", T.INT, "", "acquisitions since start"),
            P("last_index", T.INT, "", "index of the latest measurement, -1 if none"),
            P("in_control", T.BOOL),
            P("controlled", T.BOOL),
            P("time", T.FLOAT, "s", "sensor clock"),
        ),
    ),
    CommandSpec(
        CommandId.GET_DATA,
        "GetData",
        "sensor",
        "Latest seam measurement relative to the sensor frame (paper: data = GetData()).",
        reply=(
            P("index", T.INT, "", "trigger index i, or the software acquisition number"),
            P(
                "status",
                T.INT,
                "",
                "0 found, 1 not found, 2 laser off, 3 overrun, 4 error",
                enum=SensorStatus,
            ),
            P("seam", T.LOCATION, "mm, deg", "seam frame G in sensor frame S"),
            P("quality", T.FLOAT, "", "0..1"),
            P("t_arrival", T.FLOAT, "s", "trigger arrival, sensor clock"),
            P("t_exposure_start", T.FLOAT, "s", "sensor clock"),
            P("t_exposure_end", T.FLOAT, "s", "sensor clock"),
        ),
    ),
    CommandSpec(
        CommandId.GET_IMAGE,
        "GetImage",
        "sensor",
        "The latest full frame (paper: image = GetImage()), or a region of it.",
        params=(
            P("column", T.INT, "px", "first column of the region", optional=True),
            P("row", T.INT, "px", "first row", optional=True),
            P("width", T.INT, "px", "columns", optional=True),
            P("height", T.INT, "px", "rows", optional=True),
        ),
        reply=(P("index", T.INT), P("image", T.IMAGE, "", "512 x 256 MONO8 when full")),
    ),
    CommandSpec(
        CommandId.GET_PROFILE,
        "GetProfile",
        "sensor",
        "Stripe points of the latest frame in the sensor frame.",
        reply=(P("index", T.INT), P("points", T.MATRIX, "mm", "N x 3: x, y, z in S")),
    ),
    CommandSpec(
        CommandId.SET_LASER,
        "SetLaser",
        "sensor",
        "Switch the laser on or off.",
        params=(P("on", T.BOOL),),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.SET_EXPOSURE,
        "SetExposure",
        "sensor",
        "Exposure time of one column.",
        params=(P("exposure", T.FLOAT, "s", "1e-6 <= exposure <= 0.01"),),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.SET_READOUT_WINDOW,
        "SetReadoutWindow",
        "sensor",
        "Columns read out (field of view); fewer columns, shorter acquisition.",
        params=(P("first_column", T.INT, "px"), P("columns", T.INT, "px")),
        reply=(P("acquisition_time", T.FLOAT, "s", "resulting acquisition time"),),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.GET_SETTINGS,
        "GetSettings",
        "sensor",
        "Acquisition settings in force.",
        reply=(
            P("laser", T.BOOL),
            P("exposure", T.FLOAT, "s"),
            P("first_column", T.INT, "px"),
            P("columns", T.INT, "px"),
            P("acquisition_time", T.FLOAT, "s"),
            P("width", T.INT, "px", "sensor width (512)"),
            P("height", T.INT, "px", "sensor height (256)"),
        ),
    ),
    CommandSpec(
        CommandId.ACQUIRE,
        "Acquire",
        "sensor",
        "Software trigger: acquire and process one frame now.",
        reply=(P("index", T.INT),),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.GET_TRIGGER_ENDPOINT,
        "GetTriggerEndpoint",
        "sensor",
        "Where the sensor listens for UDP trigger datagrams.",
        reply=(P("host", T.STRING), P("port", T.INT, "", "0 when UDP triggering is off")),
    ),
    # --- synchronisation (robot service) ------------------------------------------------
    CommandSpec(
        CommandId.SET_SENSOR_ENDPOINT,
        "SetSensorEndpoint",
        "sync",
        "UDP address of the sensor's trigger listener.",
        params=(P("host", T.STRING), P("port", T.INT)),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.SET_SYNC_DELAY,
        "SetSyncDelay",
        "sync",
        "The delay ΔT of eq. 4: t_i^S = t_i^T + ΔT.",
        params=(P("delta_t", T.FLOAT, "s", "-0.1 < ΔT < 0.1"),),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.SET_SENSOR_TOOL,
        "SetSensorTool",
        "sync",
        "Sensor tool ^N_S T used in eq. 2.",
        params=(P("sensor2flange", T.LOCATION, "mm, deg", "sensor frame S in flange frame N"),),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.GET_SYNC_CONFIG,
        "GetSyncConfig",
        "sync",
        "Synchronisation settings in force.",
        reply=(
            P("host", T.STRING),
            P("port", T.INT),
            P("delta_t", T.FLOAT, "s"),
            P("sensor2flange", T.LOCATION, "mm, deg"),
            P("triggering", T.BOOL),
            P("rate", T.FLOAT, "Hz", "0 when triggering at explicit times"),
        ),
    ),
    CommandSpec(
        CommandId.START_TRIGGERS,
        "StartTriggers",
        "sync",
        "Send trigger datagrams at a fixed rate, count of them (0 = until stopped).",
        params=(P("rate", T.FLOAT, "Hz", "0 < rate <= 1000"), P("count", T.INT)),
        reply=(P("first_index", T.INT),),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.SCHEDULE_TRIGGERS,
        "ScheduleTriggers",
        "sync",
        "Send trigger datagrams at explicit robot-clock times (need not be periodic).",
        params=(P("times", T.FLOAT_ARRAY, "s", "increasing robot-clock times"),),
        reply=(P("first_index", T.INT),),
        needs_control=True,
    ),
    CommandSpec(
        CommandId.STOP_TRIGGERS,
        "StopTriggers",
        "sync",
        "Stop sending triggers.",
        needs_control=True,
    ),
    CommandSpec(
        CommandId.GET_SEAM_POINTS,
        "GetSeamPoints",
        "sync",
        "Synchronised seam points with index > since, ordered by index.",
        params=(P("since", T.INT, "", "last index already fetched; -1 for all"),),
        reply=(
            P(
                "points",
                T.MATRIX,
                "",
                "N x 17: index, t_T (s), t_S (s), status, quality, seam in S (x, y, z mm, "
                "rx, ry, rz deg), seam in B (x, y, z mm, rx, ry, rz deg)",
            ),
        ),
    ),
    CommandSpec(
        CommandId.GET_SYNC_STATISTICS,
        "GetSyncStatistics",
        "sync",
        "Datagram counters of the synchronisation (exposed_late: 1.3).",
        reply=(
            P("sent", T.INT),
            P("received", T.INT),
            P("matched", T.INT),
            P("lost", T.INT),
            P("late", T.INT),
            P("duplicate", T.INT),
            P("reordered", T.INT),
            P("unknown", T.INT),
            P("expired", T.INT),
            P("malformed", T.INT),
            P("pending", T.INT),
            P(
                "exposed_late",
                T.INT,
                "",
                "seam points placed later by their extra exposure lag [SY-3.8] (absent from "
                "servers before it)",
                optional=True,
            ),
        ),
    ),
)

BY_ID: dict[int, CommandSpec] = {c.id: c for c in COMMANDS}

#: Columns of the GetSeamPoints matrix.
SEAM_POINT_COLUMNS = (
    "index", "t_trigger", "t_sync", "status", "quality",
    "sx", "sy", "sz", "srx", "sry", "srz",
    "bx", "by", "bz", "brx", "bry", "brz",
)  # fmt: skip


@dataclass(frozen=True)
class Profile:
    """A capability profile [issue 32]: commands an endpoint offers together. An endpoint
    claims a profile by listing every one of its commands in Hello's ``commands``; the
    conformance summary names the profiles claimed and the ones not covered."""

    name: str
    service: str  # "robot" or "sensor"
    summary: str
    commands: tuple[CommandId, ...]


_COMMON_CORE = (
    CommandId.HELLO,
    CommandId.PING,
    CommandId.TAKE_CONTROL,
    CommandId.RELEASE_CONTROL,
    CommandId.GET_TIME,
)

#: Every command of a service is in exactly one of its profiles (tests/test_spec_registry.py).
PROFILES: tuple[Profile, ...] = (
    Profile(
        "core",
        "robot",
        "negotiation, control, status, joints, motion descriptor, I/O reading, joint log",
        (
            *_COMMON_CORE,
            CommandId.ROBOT_STATUS,
            CommandId.HEREJ,
            CommandId.SET_MOTION_DESC,
            CommandId.GET_MOTION_DESC,
            CommandId.WAIT_END_MOVE,
            CommandId.STOP_MOVE,
            CommandId.RESET_MOTION,
            CommandId.READ_IO,
            CommandId.LIST_IO,
            CommandId.GET_JOINT_LOG,
            CommandId.GET_JOINT_LIMITS,
        ),
    ),
    Profile(
        "motion",
        "robot",
        "power, joint moves, emergency stop, outputs",
        (
            CommandId.ENABLE_POWER,
            CommandId.DISABLE_POWER,
            CommandId.JOINT_MOVE,
            CommandId.RESTART_MOVE,
            CommandId.EMERGENCY_STOP,
            CommandId.RESET_EMERGENCY_STOP,
            CommandId.SET_OUTPUT,
        ),
    ),
    Profile(
        "cartesian",
        "robot",
        "kinematics: Here and tool moves",
        (
            CommandId.HERE,
            CommandId.TOOL_MOVE_J,
            CommandId.TOOL_MOVE_L,
            CommandId.TOOL_MOVE_TRAJECTORY,
        ),
    ),
    Profile(
        "alter",
        "robot",
        "real-time path correction",
        (CommandId.ALTER_BEGIN, CommandId.ALTER, CommandId.ALTER_END),
    ),
    Profile(
        "alter-queue",
        "robot",
        "timed path corrections (1.3, with alter)",
        (CommandId.ALTER_QUEUE,),
    ),
    Profile(
        "sync",
        "robot",
        "UDP trigger/data synchronisation with a sensor",
        tuple(CommandId(c) for c in range(0x3001, 0x300A)),
    ),
    Profile("crc-off", "robot", "frames without CRC", (CommandId.SET_FRAME_CRC,)),
    Profile(
        "core",
        "sensor",
        "negotiation, control, status, seam data, image, settings",
        (
            *_COMMON_CORE,
            CommandId.SENSOR_STATUS,
            CommandId.GET_DATA,
            CommandId.GET_IMAGE,
            CommandId.GET_PROFILE,
            CommandId.SET_LASER,
            CommandId.SET_EXPOSURE,
            CommandId.SET_READOUT_WINDOW,
            CommandId.GET_SETTINGS,
            CommandId.ACQUIRE,
        ),
    ),
    Profile(
        "sync",
        "sensor",
        "UDP trigger endpoint",
        (CommandId.GET_TRIGGER_ENDPOINT,),
    ),
    Profile("crc-off", "sensor", "frames without CRC", (CommandId.SET_FRAME_CRC,)),
)


def profiles_for(service: str) -> tuple[Profile, ...]:
    """The capability profiles of a ``"robot"`` or ``"sensor"`` endpoint, core first."""
    return tuple(p for p in PROFILES if p.service == service)


def commands_for(service: str) -> tuple[CommandSpec, ...]:
    """Every command a ``"robot"`` or ``"sensor"`` server implements."""
    return tuple(c for c in COMMANDS if service in c.services)


def lookup(command: int, service: str) -> CommandSpec | None:
    spec = BY_ID.get(command)
    if spec is None or service not in spec.services:
        return None
    return spec


def check_params(
    specs: tuple[ParamSpec, ...],
    values: tuple[Value, ...],
    what: str = "request",
    *,
    allow_extra: bool = False,
) -> None:
    """:func:`check_params_reference`, with a fast path for the case of nearly every request
    and reply: the declared parameters (optional ones may be left off), each of its type's
    exact Python class."""
    entry = _exact.get(id(specs))
    if entry is None or entry[0] is not specs:
        if len(_exact) > 1024:  # lists built on the fly (not from COMMANDS): stay bounded
            _exact.clear()
        required = sum(1 for s in specs if not s.optional and not s.repeated)
        entry = _exact[id(specs)] = (specs, exact_classes(specs), required)
    types = tuple(map(type, values))
    classes = entry[1]
    if types == classes or (
        entry[2] <= len(types) < len(classes) and types == classes[: len(types)]
    ):
        return  # the declared parameters, or all that are required and some optional ones
    check_params_reference(specs, values, what, allow_extra=allow_extra)


def exact_classes(specs: tuple[ParamSpec, ...]) -> tuple[type, ...]:
    """The Python class of each declared parameter: a value list whose classes are exactly
    these passes :func:`check_params` (its fast path, which callers may take themselves)."""
    return tuple(CLASS_OF[s.type] for s in specs)


# The exact classes of each parameter list seen and how many are required, by identity (the
# lists live in COMMANDS; the entry keeps its key alive, so an id is never reused meanwhile).
_exact: dict[int, tuple[tuple[ParamSpec, ...], tuple[type, ...], int]] = {}


def check_params_reference(
    specs: tuple[ParamSpec, ...],
    values: tuple[Value, ...],
    what: str = "request",
    *,
    allow_extra: bool = False,
) -> None:
    """Raise :class:`ParameterError` unless ``values`` match ``specs`` in count and type
    [RS-5.4]. ``allow_extra`` accepts trailing parameters a newer minor version added
    (receivers of replies ignore them [RS-5.6])."""
    if len(values) == len(specs) and all(
        type_of(v) is s.type for v, s in zip(values, specs, strict=True)
    ):
        return  # the common case: exactly the declared parameters
    required = sum(1 for s in specs if not s.optional and not s.repeated)
    repeated = bool(specs) and specs[-1].repeated
    if allow_extra and len(values) > len(specs) and not repeated:
        values = values[: len(specs)]
    if len(values) < required or (not repeated and len(values) > len(specs)):
        names = ", ".join(f"{s.name}:{s.type.name}" for s in specs) or "none"
        raise ParameterError(
            f"{what} takes {required if required == len(specs) else f'{required}..{len(specs)}'}"
            f" parameters ({names}), got {len(values)}"
        )
    for i, value in enumerate(values):
        spec = specs[min(i, len(specs) - 1)]
        actual = type_of(value)
        if actual is not spec.type:
            raise ParameterError(
                f"{what} parameter {i} ({spec.name}) must be {spec.type.name}, got {actual.name}"
            )
