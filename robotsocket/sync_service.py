"""The synchronisation commands 0x3001-0x3009 (PROTOCOL.md 5.5) as robot-service handlers.

:class:`SyncService` holds the robot's :class:`~sync.udp.RobotSyncCore` and a trigger
transport (the real :class:`~sync.udp.UdpSyncEndpoint`, or the emulated cell's modelled link
in simulated time) and plugs its handlers into a
:class:`~robotsocket.service.RobotService` with :meth:`SyncService.install`, before the server
is constructed. :func:`attach_udp_sync` wires the real-time variant in one call.
"""

from __future__ import annotations

import logging
import math
import secrets
from typing import Protocol

import numpy as np

from kinematics.errors import KinematicsError
from kinematics.robot import get_model
from kinematics.transforms import location_to_transform, transform_to_location
from kinematics.types import Loc
from robotsocket.interface import BadStateError, OutOfRangeError, RobotInterface
from robotsocket.service import RobotService
from spec import messages as M
from spec.params import Location, Matrix, Value
from spec.registry import SEAM_POINT_COLUMNS
from spec.server import SessionView
from sync.seam_chain import FlangeToBase
from sync.udp import RobotSyncCore, SyncStateError, UdpSyncEndpoint

__all__ = ["SyncService", "TriggerTransport", "attach_udp_sync", "flange2base_for"]

log = logging.getLogger(__name__)

#: Rows per GetSeamPoints reply (17 float64 columns: 2.7 MB, under the 4 MB payload limit).
MAX_ROWS = 20_000


class TriggerTransport(Protocol):
    """What the service needs from the thing that actually sends triggers."""

    def set_target(self, host: str, port: int) -> None: ...

    def wake(self) -> None: ...


def flange2base_for(robot: RobotInterface) -> FlangeToBase | None:
    """Batch DGM of the robot's model (by the name it reports), ``None`` if unknown."""
    model = getattr(robot, "model", None)
    if model is None:
        try:
            model = get_model(robot.info().model)
        except (KinematicsError, KeyError, ValueError):
            return None
    f: FlangeToBase = model.flange2base_batch
    return f


class SyncService:
    """Synchronisation settings, triggering and seam points of one robot.

    ``trigger_lead_s``: StartTriggers sends its first trigger this long after the command
    (s), so the rate triggers are not locked to the robot's sample instants.
    """

    def __init__(
        self,
        robot: RobotInterface,
        core: RobotSyncCore,
        transport: TriggerTransport,
        *,
        trigger_lead_s: float = 1.0e-3,
    ) -> None:
        self.robot = robot
        self.core = core
        self.transport = transport
        self.trigger_lead_s = trigger_lead_s
        self.endpoint: tuple[str, int] | None = None

    def install(self, service: RobotService) -> None:
        """Register the handlers of 0x3001-0x3009 on ``service``."""
        service.register(M.SetSensorEndpointRequest, self._set_endpoint)
        service.register(M.SetSyncDelayRequest, self._set_delay)
        service.register(M.SetSensorToolRequest, self._set_tool)
        service.register(M.GetSyncConfigRequest, self._get_config)
        service.register(M.StartTriggersRequest, self._start)
        service.register(M.ScheduleTriggersRequest, self._schedule)
        service.register(M.StopTriggersRequest, self._stop)
        service.register(M.GetSeamPointsRequest, self._points)
        service.register(M.GetSyncStatisticsRequest, self._statistics)
        # [RS-7.10] the triggers a lost controller started stop with the arm.
        service.control_lost_hooks.append(self.stop_on_control_lost)

    def stop_on_control_lost(self) -> None:
        if self.core.scheduler.active:
            log.warning("controller lost: triggers stopped")
        self.core.stop()

    # --- plain API (also used by the emulated cell) ------------------------------------------

    def set_endpoint(self, host: str, port: int) -> None:
        """Where triggers go; ("", 0), what GetSyncConfig reports before, clears it and stops
        the triggering [SY-5.8]."""
        if host == "" and port == 0:
            self.core.stop()
            self.endpoint = None
            self.transport.set_target("", 0)
            return
        if not host or not 0 < port < 65536:
            raise OutOfRangeError(f"bad sensor endpoint {host!r}:{port}")
        self.endpoint = (host, int(port))
        self.transport.set_target(host, int(port))
        log.info("sensor trigger endpoint %s:%d", host, port)

    def start(self, rate_hz: float, count: int) -> int:
        if self.endpoint is None:
            raise BadStateError("SetSensorEndpoint first")  # [SY-5.4]
        try:
            first = self.core.start_rate(rate_hz, count, self.robot.time() + self.trigger_lead_s)
        except SyncStateError as exc:
            raise OutOfRangeError(str(exc)) from None  # [SY-5.3]
        self.transport.wake()
        return first

    def schedule(self, times: list[float]) -> int:
        if self.endpoint is None:
            raise BadStateError("SetSensorEndpoint first")  # [SY-5.4]
        try:
            first = self.core.schedule(times)
        except SyncStateError as exc:
            raise OutOfRangeError(str(exc)) from None  # [SY-5.3]
        self.transport.wake()
        return first

    # --- handlers ----------------------------------------------------------------------------

    def _set_endpoint(
        self, session: SessionView, request: M.SetSensorEndpointRequest
    ) -> tuple[Value, ...]:
        self.set_endpoint(request.host, request.port)
        return ()

    def _set_delay(self, session: SessionView, request: M.SetSyncDelayRequest) -> tuple[Value, ...]:
        delta_t = request.delta_t
        if not (math.isfinite(delta_t) and abs(delta_t) <= 1.0):
            raise OutOfRangeError(f"delta_t must be within ±1 s, got {delta_t}")
        self.core.set_delay(delta_t)
        return ()

    def _set_tool(self, session: SessionView, request: M.SetSensorToolRequest) -> tuple[Value, ...]:
        sensor2flange = location_to_transform(np.array(request.sensor2flange.as_tuple()))
        with self.core.lock:
            self.core.sensor2flange = sensor2flange
        return ()

    def _get_config(
        self, session: SessionView, request: M.GetSyncConfigRequest
    ) -> tuple[Value, ...]:
        host, port = self.endpoint if self.endpoint is not None else ("", 0)
        with self.core.lock:
            s2f = transform_to_location(self.core.sensor2flange)
            triggering = self.core.scheduler.active
            rate = self.core.scheduler.rate
        return M.GetSyncConfigReply(
            host,
            port,
            float(self.core.delta_t_s),
            Location(*(float(v) for v in s2f)),
            triggering,
            float(rate),
        ).encode()

    def _start(self, session: SessionView, request: M.StartTriggersRequest) -> tuple[Value, ...]:
        return (self.start(request.rate, request.count),)

    def _schedule(
        self, session: SessionView, request: M.ScheduleTriggersRequest
    ) -> tuple[Value, ...]:
        return (self.schedule(list(request.times.values)),)

    def _stop(self, session: SessionView, request: M.StopTriggersRequest) -> tuple[Value, ...]:
        self.core.stop()
        return ()

    def _points(self, session: SessionView, request: M.GetSeamPointsRequest) -> tuple[Value, ...]:
        rows = self.core.points_since(request.since, MAX_ROWS)
        return (Matrix(rows.shape[0], len(SEAM_POINT_COLUMNS), rows.ravel().tolist()),)

    def _statistics(
        self, session: SessionView, request: M.GetSyncStatisticsRequest
    ) -> tuple[Value, ...]:
        s = self.core.statistics()
        return tuple(s[p.name] for p in M.GetSyncStatisticsReply.table)


def attach_udp_sync(
    service: RobotService,
    robot: RobotInterface,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    delta_t_s: float = 0.0,
    sensor2flange: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
) -> tuple[SyncService, UdpSyncEndpoint]:
    """Real-time synchronisation for ``robot``: a UDP endpoint on ``host:port`` fed from the
    robot's joint log, and the 0x3001-0x3009 handlers on ``service``. Call ``start()`` on
    the returned endpoint (and ``stop()`` when done)."""
    core = RobotSyncCore(
        delta_t_s=delta_t_s,
        flange2base=flange2base_for(robot),
        sensor2flange=location_to_transform(np.array(sensor2flange, dtype=np.float64)),
        # A random first index: a restarted robot is not taken for a repeat of its previous
        # run by a sensor that remembers answered indices [SY-2.2].
        first_index=secrets.randbelow(1 << 30),
    )
    endpoint = UdpSyncEndpoint(
        core, clock=robot.time, joints_since=robot.joint_log, host=host, port=port,
        simulated=bool(getattr(robot, "simulated", False)),  # [SY-5.7] stamps on its clock
    )  # fmt: skip
    sync = SyncService(robot, core, endpoint)
    sync.install(service)
    return sync, endpoint
