"""The emulated work cell: robot emulator, camera emulator and seam scene on one clock.

One object runs what the paper's lab had on the bench: a Stäubli arm (default RX90B) with the
seam-tracking sensor on its flange (^N_S T, and a laser tool ^N_L T), a workpiece with a seam
under the sensor, the RobotSocket and SensorSocket servers, and the UDP trigger/data link of
section V. The camera sees the arm's *true* motion (the setpoints, or with ``dynamics``
the elastic arm's link side, interpolated between
cycles); the robot reports *measured* joints delayed by the encoder latency. So the delay the
ΔT experiment must find is known from the timing parameters (:meth:`CellTiming.true_delta_t_s`)
and, per acquisition, from the sensor's own records (:meth:`EmulatedCell.measured_delta_t`).

Clocks:

- ``"sim"``: the robot clock advances only when the robot is made to wait (WaitEndMove
  through the protocol, or :meth:`EmulatedCell.advance`); every 4 ms cycle the cell sends
  the due triggers through a modelled network (:class:`~sync.network.DelayLink`), lets the
  sensor acquire once the arm's motion over the exposure is known, delivers the data
  datagrams and runs the matcher. Deterministic for a seed; as fast as the CPU allows.
- ``"real"``: the robot's real-time 4 ms thread, a real UDP trigger listener on the sensor
  side and a real UDP endpoint on the robot side. Exposures that reach past the latest
  setpoint see the arm's motion extrapolated (quadratic over the last three setpoints).

This module wires the parts together; each lives in its own module: the timing parameters
(:mod:`cell.timing`), the arm's true motion as the camera sees it (:mod:`cell.motion`), the
sensor with extra seam noise as the trigger handler sees it (:mod:`cell.noisy`), the
simulated trigger/data link (:mod:`cell.sim_link`) and the ΔT bookkeeping
(:mod:`cell.delta_t`).
"""

from __future__ import annotations

import errno
import logging
import math
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from cell.delta_t import DeltaTBook
from cell.motion import TrueMotion
from cell.noisy import NoisyHandler
from cell.sim_link import SimulatedLink
from cell.timing import CellError, CellTiming
from kinematics.dynamics import dynamics_named
from kinematics.transforms import location_to_transform, transform_to_location
from kinematics.types import FloatArray, Loc
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from robotsocket.sync_service import SyncService, flange2base_for
from sensorsocket.emulator import CameraEmulator
from sensorsocket.scene import CornerPath, JogPath, Joint, Scene, SeamPath, rot_x
from sensorsocket.sensor import Sensor
from sensorsocket.service import SensorService
from sensorsocket.timing import TimingModel
from sensorsocket.udp import TriggerListener
from spec.clocks import CLOCK_KINDS, ClockKind, is_clock_kind
from spec.server import FramedServer, ServerPolicy
from sync.network import DelayLink
from sync.udp import RobotSyncCore, UdpSyncEndpoint

__all__ = [
    "DEFAULT_LASER_TOOL",
    "DEFAULT_SENSOR_TOOL",
    "READY_JOINTS",
    "CellError",
    "CellTiming",
    "EmulatedCell",
]

log = logging.getLogger(__name__)


_T = TypeVar("_T")


def bound(what: str, option: str, host: str, port: int, make: Callable[[], _T]) -> _T:
    """Bind one of the cell's ports with ``make``; a port in use is a CellError naming the
    port and the option that set it, a host this machine cannot listen on names --host."""
    try:
        return make()
    except OSError as exc:
        reason = exc.strerror or str(exc)
        if isinstance(exc, socket.gaierror) or exc.errno == errno.EADDRNOTAVAIL:
            msg = f"cannot listen on {host} (--host): {reason}"
        else:
            msg = f"cannot bind the {what} to {host}:{port} ({option}): {reason}"
        raise CellError(msg) from None


#: Longest wait of the real-time camera for the robot's setpoints to cover an exposure (s).
TRUTH_WAIT_S = 0.5

#: ^N_S T: the sensor's measuring point 200 mm out along the flange axis, 40 mm ahead of the
#: laser focus in the welding direction (mm, deg).
DEFAULT_SENSOR_TOOL: Loc = (40.0, 0.0, 200.0, 0.0, 0.0, 0.0)
#: ^N_L T: the laser focus on the flange axis (mm, deg).
DEFAULT_LASER_TOOL: Loc = (0.0, 0.0, 200.0, 0.0, 0.0, 0.0)
#: Start joints (deg): flange pointing down, sensor over the seam in front of the robot.
READY_JOINTS = (0.0, 30.0, 100.0, 0.0, 50.0, 0.0)


@dataclass
class EmulatedCell:
    """Robot + sensor + seam scene on one clock, served over TCP and UDP.

    Args:
        clock: ``"sim"`` or ``"real"``.
        timing: the cell's timing (:class:`CellTiming`).
        model: robot model name.
        sensor_tool, laser_tool: ^N_S T and ^N_L T as VAL3 locations (mm, deg): the nominal
            tools, the ones the robot and the application know.
        sensor_tool_error, laser_tool_error: how the true tools differ from the nominal ones,
            as locations in the nominal tool frame (true = nominal · error; mm, deg). The
            camera sees the scene through the true sensor tool and the laser spot lands where
            the true laser tool puts it; the robot's synchronisation uses the nominal tool.
        workpiece_error: where the workpiece really lies, as a location in the nominal
            workpiece frame (placement error; mm, deg): a seam tracker must find it.
        joint, seam: the workpiece: ``butt|fillet|lap`` and ``straight|sine``.
        seed: seeds every random draw of the cell.
        host: address of the servers; ports 0 pick free ones.
        delta_t_s: the robot's initial ΔT setting (the synchronisation commands change it).
        dynamics: the arm's dynamics, ``off`` or ``elastic``
            (:func:`kinematics.dynamics.dynamics_named`): with ``elastic`` the robot reports
            its motor side, and the camera and the laser follow its link side (the truth).
        serve: serve robot and sensor over TCP here; False leaves that to another process
            (:mod:`cell.rtcell`), with the services in :attr:`robot_service` and
            :attr:`sensor_service`.
    """

    clock: ClockKind = "sim"
    timing: CellTiming = field(default_factory=CellTiming)
    model: str = "RX90B"
    sensor_tool: Loc = DEFAULT_SENSOR_TOOL
    laser_tool: Loc = DEFAULT_LASER_TOOL
    sensor_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    laser_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    workpiece_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    joint: str = "butt"
    seam: str = "straight"
    seed: int = 0
    host: str = "127.0.0.1"
    robot_port: int = 0
    sensor_port: int = 0
    udp_port: int = 0
    delta_t_s: float = 0.0
    ready_joints: Sequence[float] = READY_JOINTS
    dynamics: str = "off"
    serve: bool = True
    policy: ServerPolicy | None = None  # the TCP servers' (None: the spec's defaults)

    def __post_init__(self) -> None:
        if not is_clock_kind(self.clock):
            raise CellError(f"clock must be one of {', '.join(CLOCK_KINDS)}, got {self.clock!r}")
        t = self.timing
        try:
            params = dynamics_named(self.dynamics, self.model)
        except ValueError as exc:
            raise CellError(str(exc)) from None
        seeds = np.random.SeedSequence(self.seed).spawn(4)
        rng_timing, rng_render, rng_noise, rng_net = (np.random.default_rng(s) for s in seeds)
        self.robot = RobotEmulator(
            self.model,
            clock=self.clock,
            encoder_latency=t.encoder_latency_s,
            home=self.ready_joints,
            buffer_seconds=60.0,
            dynamics=params,
        )
        nominal = location_to_transform(np.array(self.sensor_tool, dtype=np.float64))
        # the true tools (what the camera and the laser do) and the nominal sensor tool (what
        # the robot's synchronisation computes with)
        self.sensor2flange = nominal @ _error_transform(self.sensor_tool_error, "sensor")
        self.laser2flange = location_to_transform(
            np.array(self.laser_tool, dtype=np.float64)
        ) @ _error_transform(self.laser_tool_error, "laser")
        self.nominal_sensor2flange = nominal
        # the camera sees the arm's true motion (setpoints or link side), see cell.motion
        self.motion = TrueMotion(
            self.robot.model.flange2base_batch,
            self.sensor2flange,
            self.robot.period,
            self.ready_joints,
        )
        if self.clock != "sim":
            self.motion.before_read = self.wait_for_truth
        self.scene = self._make_scene()
        self.camera_timing = TimingModel(
            rng=rng_timing,
            poll_rate_hz=t.poll_rate_hz,
            start_jitter_s=t.start_jitter_s,
            start_latency_s=t.start_latency_s,
            full_frame_time_s=t.acquisition_s,
            processing_time_s=t.processing_s,
        )
        camera = CameraEmulator(self.scene, self.motion, self.camera_timing, rng=rng_render)
        self.delta_t = DeltaTBook(t, camera, self.camera_timing)
        self.sensor = Sensor(camera, clock=self.robot.time, after_acquire=self.delta_t.record)
        self.handler = NoisyHandler(
            self.sensor,
            network_delay_s=t.network_delay_s,
            noise_mm=t.sensor_noise_mm,
            rng=rng_noise,
        )
        flange2base = flange2base_for(self.robot)
        self.core = RobotSyncCore(
            delta_t_s=self.delta_t_s,
            flange2base=flange2base,
            sensor2flange=self.nominal_sensor2flange,
        )
        self.robot.cycle_hooks.append(self._on_cycle)
        self.listener: TriggerListener | None = None
        self.endpoint: UdpSyncEndpoint | None = None
        self.link: SimulatedLink | None = None
        if self.clock == "sim":
            self.udp_address = (self.host, self.udp_port or 2001)
            self.link = SimulatedLink(
                self.core, self.handler, self.sensor, t, self.udp_address[1], rng_net
            )
            self.sync = SyncService(self.robot, self.core, self.link.transport)
        else:
            self.listener = bound(
                "sensor's UDP trigger port", "--udp-port", self.host, self.udp_port,
                lambda: TriggerListener(
                    self.handler, self.host, self.udp_port, clock=self.robot.time, hold=True
                ),
            )  # fmt: skip
            self.udp_address = self.listener.address
            self.endpoint = UdpSyncEndpoint(
                self.core,
                clock=self.robot.time,
                joints_since=self.robot.joint_log,
                host=self.host,
                port=0,
            )
            self.sync = SyncService(self.robot, self.core, self.endpoint)
        self.robot_service = RobotService(self.robot)
        self.sync.install(self.robot_service)
        self.sensor_service = SensorService(self.sensor, trigger_endpoint=self.udp_address)
        # serve=False: another process serves the two services (cell.rtcell)
        self.robot_server: FramedServer | None = None
        self.sensor_server: FramedServer | None = None
        if self.serve:
            self.robot_server = bound(
                "robot's TCP port", "--robot-port", self.host, self.robot_port,
                lambda: FramedServer(self.robot_service, self.host, self.robot_port, self.policy),
            )  # fmt: skip
            self.sensor_server = bound(
                "sensor's TCP port", "--sensor-port", self.host, self.sensor_port,
                lambda: FramedServer(
                    self.sensor_service, self.host, self.sensor_port, self.policy
                ),
            )  # fmt: skip
        self._started = False

    # --- geometry ----------------------------------------------------------------------------

    @property
    def true_sensor_tool(self) -> Loc:
        """^N_S T the camera really has (mm, deg)."""
        return _as_loc(transform_to_location(self.sensor2flange))

    @property
    def true_laser_tool(self) -> Loc:
        """^N_L T the laser really has (mm, deg)."""
        return _as_loc(transform_to_location(self.laser2flange))

    def _make_scene(self) -> Scene:
        joints = {"butt": Joint.butt(), "fillet": Joint.fillet(), "lap": Joint.lap()}
        paths = {"straight": SeamPath.straight(), "sine": SeamPath.paper_sine()}
        paths["corner"] = CornerPath()
        paths["jog"] = JogPath()
        if self.joint not in joints or self.seam not in paths:
            raise CellError("joint must be butt|fillet|lap and seam straight|sine|corner|jog")
        s2b = self.ready_sensor2base()
        # Workpiece: seam along x_S through the sensor origin, surface normal towards the
        # sensor (z_W = -z_S); the seam height of the joint is subtracted so the seam point
        # lands on the sensor origin.
        w = s2b.copy()
        w[:3, :3] = s2b[:3, :3] @ rot_x(math.pi)
        joint = joints[self.joint]
        w[:3, 3] = s2b[:3, 3] - w[:3, 2] * joint.seam_height_mm
        w = w @ _error_transform(self.workpiece_error, "workpiece")
        return Scene(joint, paths[self.seam], w)

    def flange2base_now(self) -> FloatArray:
        """^B_N T of the arm's latest setpoint (4, 4) mm: where it truly is when at rest."""
        out: FloatArray = self.robot.model.flange2base(self.robot.setpoint())
        return out

    def ready_flange2base(self) -> FloatArray:
        """^B_N T at the ready joints (4, 4) mm."""
        out: FloatArray = self.robot.model.flange2base(
            np.asarray(self.ready_joints, dtype=np.float64)
        )
        return out

    def ready_sensor2base(self) -> FloatArray:
        """^B_S T at the ready joints (4, 4) mm."""
        q = np.asarray(self.ready_joints, dtype=np.float64)
        out: FloatArray = self.robot.model.flange2base(q) @ self.sensor2flange
        return out

    # --- the clock ---------------------------------------------------------------------------

    def _on_cycle(self, t: float, q_sp: FloatArray, q_m: FloatArray) -> None:
        # the camera sees where the arm truly is: the link side (the setpoint of a rigid arm)
        self.motion.append(t, self.robot.true_joints())
        if self.link is not None:
            self.link.cycle(t, q_m)

    def wait_for_truth(self, times: FloatArray) -> None:
        """Real clock: make the robot's setpoints reach the latest of ``times`` (s) so the
        camera renders the arm's motion, not a guess of it. An exposure that ends in the
        future is waited for (at most ``TRUTH_WAIT_S``); the setpoints up to now are then
        computed in this thread (:meth:`RobotEmulator.catch_up`), so a robot tick thread
        that runs late (a busy machine) delays nothing and falsifies nothing."""
        if not len(times):
            return
        period = self.robot.period
        t_cover = math.ceil(float(np.max(times)) / period - 1e-9) * period
        wait = t_cover - self.robot.time()
        if wait > 0:
            time.sleep(min(wait, TRUTH_WAIT_S))
        self.robot.catch_up()

    def advance(self, seconds: float) -> None:
        """Simulated clock: run the cell for ``seconds``."""
        self.robot.advance_to(self.robot.time() + seconds)

    @property
    def uplink(self) -> DelayLink | None:
        """The simulated trigger network (robot -> sensor); None in real time."""
        return self.link.uplink if self.link is not None else None

    @uplink.setter
    def uplink(self, link: DelayLink) -> None:
        if self.link is None:
            raise CellError("only the simulated cell has a modelled network")
        self.link.uplink = link

    @property
    def downlink(self) -> DelayLink | None:
        """The simulated data network (sensor -> robot); None in real time."""
        return self.link.downlink if self.link is not None else None

    @downlink.setter
    def downlink(self, link: DelayLink) -> None:
        if self.link is None:
            raise CellError("only the simulated cell has a modelled network")
        self.link.downlink = link

    # --- truth -------------------------------------------------------------------------------

    def true_delta_t_s(self) -> float:
        """ΔT from the timing parameters, for a centred seam on the current readout window."""
        return self.delta_t.true_delta_t_s()

    def measured_delta_t(self, first_index: int = 0) -> float:
        """ΔT from the sensor's own records of triggered acquisitions with index >=
        ``first_index`` (:meth:`~cell.delta_t.DeltaTBook.measured_delta_t`)."""
        return self.delta_t.measured_delta_t(first_index)

    # --- lifecycle ---------------------------------------------------------------------------

    @property
    def robot_address(self) -> tuple[str, int]:
        return self.robot_server.address if self.robot_server else (self.host, self.robot_port)

    @property
    def sensor_address(self) -> tuple[str, int]:
        return self.sensor_server.address if self.sensor_server else (self.host, self.sensor_port)

    def start(self) -> EmulatedCell:
        if self._started:
            return self
        self._started = True
        self.robot.start()
        if self.listener is not None:
            self.listener.start()
        if self.endpoint is not None:
            self.endpoint.start()
        for server in (self.robot_server, self.sensor_server):
            if server is not None:
                server.start()
        log.info(
            "cell (%s clock): robot %s:%d, sensor %s:%d, udp %s:%d, true ΔT %.3f ms",
            self.clock,
            *self.robot_address,
            *self.sensor_address,
            *self.udp_address,
            self.true_delta_t_s() * 1e3,
        )
        return self

    def close(self) -> None:
        for server in (self.robot_server, self.sensor_server):
            if server is not None:
                server.shutdown()
        if self.endpoint is not None:
            self.endpoint.stop()
        if self.listener is not None:
            self.listener.stop()
        self.robot.close()

    def __enter__(self) -> EmulatedCell:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def describe(self) -> dict[str, object]:
        """The cell's parameters and the true ΔT, for printing or JSON."""
        t = self.timing
        return {
            "clock": self.clock,
            "model": self.model,
            "dynamics": self.dynamics,
            "robot": f"{self.robot_address[0]}:{self.robot_address[1]}",
            "sensor": f"{self.sensor_address[0]}:{self.sensor_address[1]}",
            # The simulated cell carries triggers in-process: its address only names the
            # sensor endpoint (SetSensorEndpoint), no socket listens there.
            "udp": f"{self.udp_address[0]}:{self.udp_address[1]}"
            + (" (simulated in-process, no socket)" if self.clock == "sim" else ""),
            "sensor_tool": list(self.sensor_tool),
            "laser_tool": list(self.laser_tool),
            "sensor_tool_error": list(self.sensor_tool_error),
            "laser_tool_error": list(self.laser_tool_error),
            "workpiece_error": list(self.workpiece_error),
            "ready_sensor_location": [
                round(float(v), 4) for v in transform_to_location(self.ready_sensor2base())
            ],
            "encoder_latency_ms": t.encoder_latency_s * 1e3,
            "trigger_poll_hz": t.poll_rate_hz,
            "start_jitter_ms": t.start_jitter_s * 1e3,
            "acquisition_ms": t.acquisition_s * 1e3,
            "network_delay_ms": t.network_delay_s * 1e3,
            "network_jitter_ms": t.network_jitter_s * 1e3,
            "sensor_noise_um": t.sensor_noise_mm * 1e3,
            "jitter_width_ms": t.jitter_width_s() * 1e3,
            "true_delta_t_ms": self.true_delta_t_s() * 1e3,
        }


def _error_transform(error: Sequence[float], which: str) -> FloatArray:
    """The tool (or workpiece) error as a transform, checked: finite, at most 50 mm and
    30 deg per component (a mounting or placement error, not another tool)."""
    v = np.array(error, dtype=np.float64)
    if v.shape != (6,) or not np.isfinite(v).all():
        raise CellError(f"{which} tool error must be 6 finite numbers (mm, deg)")
    if np.abs(v[:3]).max() > 50.0 or np.abs(v[3:]).max() > 30.0:
        raise CellError(f"{which} tool error must be within 50 mm and 30 deg per component")
    return location_to_transform(v)


def _as_loc(v: FloatArray) -> Loc:
    return (float(v[0]), float(v[1]), float(v[2]), float(v[3]), float(v[4]), float(v[5]))
