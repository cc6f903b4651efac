"""The RobotSocket service: registry commands -> robot interface calls -> reply parameters.

The :class:`~spec.server.FramedServer` shell has already checked the parameters against the
registry and control ownership when :meth:`RobotService.handle` runs. Handlers live in a dict
keyed by command ID; :meth:`RobotService.register` adds more (the synchronisation commands
0x3001-0x3009 plug in this way) and :meth:`implemented` lists exactly what is registered.
Register extra handlers *before* the server is constructed: the shell reads ``implemented()``
once, in its constructor. EmergencyStop, StopMove and ResetMotion are urgent (executed on
arrival; EmergencyStop also on reserved connections) and WaitEndMove blocking (runs on the
session's worker) [RS-7.12].
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from robotsocket.interface import (
    BadStateError,
    BusyError,
    EmergencyStopError,
    InvalidArgumentError,
    MotionDesc,
    NotPoweredError,
    OutOfRangeError,
    RobotError,
    RobotInterface,
    RobotStatus,
    SingularityError,
    UnreachableError,
)
from spec import messages as M
from spec.errors import ErrorCode, ProtocolError
from spec.params import Joints, Location, Matrix, Value
from spec.registry import CommandId
from spec.server import Handler, HandlerService, Identity, SessionView
from spec.wire import MoveOutcome

log = logging.getLogger(__name__)

#: Interface error class -> wire error code (most specific first).
ERROR_CODES: tuple[tuple[type[RobotError], ErrorCode], ...] = (
    (NotPoweredError, ErrorCode.NOT_POWERED),
    (EmergencyStopError, ErrorCode.EMERGENCY_STOP),
    (OutOfRangeError, ErrorCode.OUT_OF_RANGE),
    (UnreachableError, ErrorCode.UNREACHABLE),
    (SingularityError, ErrorCode.SINGULARITY),
    (BusyError, ErrorCode.BUSY),
    (BadStateError, ErrorCode.BAD_STATE),
    (InvalidArgumentError, ErrorCode.BAD_PARAMETERS),
)


def error_code(exc: RobotError) -> ErrorCode:
    """The wire code of an interface error (INTERNAL_ERROR for an unknown subclass)."""
    for cls, code in ERROR_CODES:
        if isinstance(exc, cls):
            return code
    return ErrorCode.INTERNAL_ERROR


def status_reply(
    st: RobotStatus, code: int, message: str, session: SessionView
) -> tuple[Value, ...]:
    """The RobotStatus reply parameters (the last error as its wire code and message)."""
    return M.RobotStatusReply(
        st.powered,
        st.estop,
        st.moving,
        st.queue,
        session.in_control,
        session.control_held,
        code,
        message,
        float(st.time),
    ).encode()


def wait_reply(outcome: MoveOutcome, why: str) -> tuple[Value, ...]:
    """[RS-5.50] WaitEndMove's reply: done only for a move that reached its target."""
    return M.WaitEndMoveReply(outcome is MoveOutcome.REACHED, outcome.value, why).encode()


class RobotService(HandlerService):
    """Serves a :class:`RobotInterface` (the emulator or an adapter for a real controller).

    ``control_lost_hooks`` run after the robot's own controlled stop when the controller is
    gone (the synchronisation service stops its triggers there)."""

    # Stopping never waits behind a pending WaitEndMove of the same connection [RS-7.12].
    urgent = frozenset(
        int(c) for c in (CommandId.EMERGENCY_STOP, CommandId.STOP_MOVE, CommandId.RESET_MOTION)
    )
    blocking = frozenset({int(CommandId.WAIT_END_MOVE)})

    def __init__(self, robot: RobotInterface, software: str = "0.1.0") -> None:
        super().__init__()
        self.robot = robot
        info = robot.info()
        self.identity = Identity("robot", info.vendor, info.model, info.serial, software)
        self.control_lost_hooks: list[Callable[[], None]] = []
        self.register(M.RobotStatusRequest, self._status)
        self.register(M.HerejRequest, self._herej)
        self.register(M.HereRequest, self._here)
        self.register(M.EnablePowerRequest, self._simple(robot.enable_power))
        self.register(M.DisablePowerRequest, self._simple(robot.disable_power))
        self.register(M.JointMoveRequest, self._joint_move)
        self.register(M.ToolMoveJRequest, self._tool_move_j)
        self.register(M.ToolMoveLRequest, self._tool_move_l)
        self.register(M.SetMotionDescRequest, self._set_mdesc)
        self.register(M.GetMotionDescRequest, self._get_mdesc)
        self.register(M.WaitEndMoveRequest, self._wait_end_move)
        self.register(M.StopMoveRequest, self._simple(robot.stop_move))
        self.register(M.RestartMoveRequest, self._simple(robot.restart_move))
        self.register(M.ResetMotionRequest, self._simple(robot.reset_motion))
        self.register(M.EmergencyStopRequest, self._estop)
        self.register(M.ResetEmergencyStopRequest, self._simple(robot.reset_emergency_stop))
        self.register(M.SetOutputRequest, self._set_output)
        self.register(M.ReadIORequest, self._read_io)
        self.register(M.ListIORequest, self._list_io)
        self.register(M.GetJointLogRequest, self._joint_log)
        self.register(M.GetJointLimitsRequest, self._joint_limits)
        self.register(M.ToolMoveTrajectoryRequest, self._tool_move_trajectory)
        # alter mode is optional: listed in Hello only when the robot implements it
        if type(robot).alter_begin is not RobotInterface.alter_begin:
            self.register(M.AlterBeginRequest, self._alter_begin)
            self.register(M.AlterRequest, self._alter)
            self.register(M.AlterEndRequest, self._alter_end)
        if type(robot).alter_queue is not RobotInterface.alter_queue:
            self.register(M.AlterQueueRequest, self._alter_queue)

    # --- Service -----------------------------------------------------------------------------

    def error_code(self, exc: Exception) -> ErrorCode | None:
        return error_code(exc) if isinstance(exc, RobotError) else None

    def clock(self) -> float:
        return self.robot.time()

    def on_control_lost(self, session: SessionView) -> None:
        # [RS-7.10] the robot first (laser off, controlled stop, outputs safe), then the rest.
        try:
            why = session.control_lost
            self.robot.on_control_lost(f"control lost ({why})" if why else "control lost")
        finally:
            for hook in self.control_lost_hooks:
                try:
                    hook()
                except Exception:
                    log.exception("control-lost hook failed")

    def on_control_released(self, session: SessionView) -> None:
        # [RS-7.21] the outputs go off (laser first); queued moves and triggers go on.
        self.robot.on_control_released()

    # --- handlers ----------------------------------------------------------------------------

    @staticmethod
    def _simple(fn: Callable[[], None]) -> Handler[Any]:
        """A handler of a command without parameters or reply: ``fn()``."""

        def handler(session: SessionView, request: Any) -> tuple[Value, ...]:
            fn()
            return ()

        return handler

    def _status(self, session: SessionView, request: M.RobotStatusRequest) -> tuple[Value, ...]:
        st = self.robot.status()
        err = st.last_error
        code, message = (0, "") if err is None else (int(error_code(err)), str(err))
        return status_reply(st, code, message, session)

    def _herej(self, session: SessionView, request: M.HerejRequest) -> tuple[Value, ...]:
        return (Joints(self.robot.herej_values()),)

    def _here(self, session: SessionView, request: M.HereRequest) -> tuple[Value, ...]:
        here = self.robot.here(request.tool.as_tuple(), request.frame.as_tuple())
        return (Location(*here),)

    def _joint_move(self, session: SessionView, request: M.JointMoveRequest) -> tuple[Value, ...]:
        joints = request.joints.values
        if len(joints) != 6:
            raise InvalidArgumentError(f"JointMove needs 6 joints, got {len(joints)}")
        return (self.robot.joint_move(np.array(joints)),)

    def _tool_move_j(self, session: SessionView, request: M.ToolMoveJRequest) -> tuple[Value, ...]:
        r = request
        return (
            self.robot.tool_move_j(r.location.as_tuple(), r.tool.as_tuple(), r.frame.as_tuple()),
        )

    def _tool_move_l(self, session: SessionView, request: M.ToolMoveLRequest) -> tuple[Value, ...]:
        r = request
        return (
            self.robot.tool_move_l(r.location.as_tuple(), r.tool.as_tuple(), r.frame.as_tuple()),
        )

    def _tool_move_trajectory(
        self, session: SessionView, request: M.ToolMoveTrajectoryRequest
    ) -> tuple[Value, ...]:
        locations = request.locations
        if locations.cols != 6:
            raise InvalidArgumentError(f"locations must have 6 columns, got {locations.cols}")
        locs = np.array(locations.values, dtype=np.float64).reshape(locations.rows, 6)
        try:
            move_id = self.robot.tool_move_trajectory(
                np.array(request.times.values, dtype=np.float64),
                locs,
                request.tool.as_tuple(),
                request.frame.as_tuple(),
            )
        except NotImplementedError:
            raise ProtocolError(
                "ToolMoveTrajectory not implemented", ErrorCode.NOT_SUPPORTED
            ) from None
        return (move_id,)

    def _alter_begin(self, session: SessionView, request: M.AlterBeginRequest) -> tuple[Value, ...]:
        try:
            self.robot.alter_begin(request.tool.as_tuple(), request.timeout)
        except NotImplementedError:
            raise ProtocolError("alter mode not implemented", ErrorCode.NOT_SUPPORTED) from None
        return ()

    def _alter(self, session: SessionView, request: M.AlterRequest) -> tuple[Value, ...]:
        try:
            applied = self.robot.alter(request.correction.as_tuple())
        except NotImplementedError:
            raise ProtocolError("alter mode not implemented", ErrorCode.NOT_SUPPORTED) from None
        return (Location(*(float(v) for v in applied)),)

    def _alter_end(self, session: SessionView, request: M.AlterEndRequest) -> tuple[Value, ...]:
        try:
            self.robot.alter_end()
        except NotImplementedError:
            raise ProtocolError("alter mode not implemented", ErrorCode.NOT_SUPPORTED) from None
        return ()

    def _alter_queue(self, session: SessionView, request: M.AlterQueueRequest) -> tuple[Value, ...]:
        table = request.corrections
        t = np.array(request.times.values, dtype=np.float64)
        c = np.array(table.values, dtype=np.float64).reshape(table.rows, table.cols)
        try:
            report, applied, now = self.robot.alter_queue(t, c)
        except NotImplementedError:
            raise ProtocolError("AlterQueue not implemented", ErrorCode.NOT_SUPPORTED) from None
        return M.AlterQueueReply(
            report.accepted,
            report.late,
            report.depth,
            report.horizon,
            report.late_total,
            report.held_total,
            Location(*(float(v) for v in applied)),
            float(now),
        ).encode()

    def _set_mdesc(
        self, session: SessionView, request: M.SetMotionDescRequest
    ) -> tuple[Value, ...]:
        r = request
        desc = MotionDesc(
            r.joint_speed, r.joint_accel, r.joint_decel, r.tool_speed, r.tool_rot_speed, r.blend
        )
        self.robot.set_motion_desc(desc)
        return ()

    def _get_mdesc(
        self, session: SessionView, request: M.GetMotionDescRequest
    ) -> tuple[Value, ...]:
        d = self.robot.motion_desc()
        return M.GetMotionDescReply(
            d.joint_speed,
            d.joint_accel,
            d.joint_decel,
            d.tool_speed,
            d.tool_rot_speed,
            d.blend,
        ).encode()

    def _wait_end_move(
        self, session: SessionView, request: M.WaitEndMoveRequest
    ) -> tuple[Value, ...]:
        ended = self.robot.wait_end_move(request.timeout)
        outcome, why = self.robot.move_outcome() if ended else (MoveOutcome.MOVING, "")
        return wait_reply(outcome, why)

    def _estop(self, session: SessionView, request: M.EmergencyStopRequest) -> tuple[Value, ...]:
        log.warning("emergency stop requested by session %d (%s)", session.id, session.peer[0])
        self.robot.emergency_stop()
        return ()

    def _set_output(self, session: SessionView, request: M.SetOutputRequest) -> tuple[Value, ...]:
        self.robot.set_output(request.name, request.value)
        return ()

    def _read_io(self, session: SessionView, request: M.ReadIORequest) -> tuple[Value, ...]:
        value, is_output = self.robot.read_io(request.name)
        return M.ReadIOReply(value, is_output).encode()

    def _list_io(self, session: SessionView, request: M.ListIORequest) -> tuple[Value, ...]:
        outputs, inputs = self.robot.list_io()
        return M.ListIOReply(",".join(outputs), ",".join(inputs)).encode()

    def _joint_log(self, session: SessionView, request: M.GetJointLogRequest) -> tuple[Value, ...]:
        since = request.since
        if math.isnan(since):
            # [RS-5.58] NaN is no time; ±inf are (the whole buffer, no sample).
            raise ProtocolError("GetJointLog since must be a time, got NaN", ErrorCode.OUT_OF_RANGE)
        times, joints = self.robot.joint_log(since)
        rows = np.column_stack([times, joints]) if len(times) else np.zeros((0, 7))
        log = Matrix(rows.shape[0], 7, rows.ravel().tolist())
        return M.GetJointLogReply(log, float(self.robot.period)).encode()

    def _joint_limits(
        self, session: SessionView, request: M.GetJointLimitsRequest
    ) -> tuple[Value, ...]:
        lim = self.robot.joint_limits()
        return (Matrix(6, 2, lim.ravel().tolist()),)
