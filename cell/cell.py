"""The emulated work cell: robot emulator, camera emulator and seam scene on one clock.

One object runs what the paper's lab had on the bench: a Stäubli arm (default RX90B) with the
seam-tracking sensor on its flange (^N_S T, and a laser tool ^N_L T), a workpiece with a seam
under the sensor, the RobotSocket and SensorSocket servers, and the UDP trigger/data link of
section V. The camera sees the arm's *true* motion (the setpoints, interpolated between
cycles); the robot reports *measured* joints delayed by the encoder latency. So the delay the
ΔT experiment must find is known from the timing parameters (:meth:`CellTiming.true_delta_t_s`)
and, per acquisition, from the sensor's own records (:meth:`EmulatedCell.measured_delta_t`).

Clocks:

- ``"sim"``: the robot clock advances only when the robot is made to wait (WaitEndMove
  through the protocol, or :meth:`EmulatedCell.advance`); every 4 ms cycle the cell sends
  the due triggers through a modelled network (:class:`~sync.udp.DelayLink`), lets the
  sensor acquire once the arm's motion over the exposure is known, delivers the data
  datagrams and runs the matcher. Deterministic for a seed; as fast as the CPU allows.
- ``"real"``: the robot's real-time 4 ms thread, a real UDP trigger listener on the sensor
  side and a real UDP endpoint on the robot side. Exposures that reach past the latest
  setpoint see the arm's motion extrapolated (quadratic over the last three setpoints).
"""

from __future__ import annotations

import bisect
import dataclasses
import logging
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kinematics.transforms import location_to_transform, transform_to_location
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from robotsocket.sync_service import SyncService, flange2base_for
from sensorsocket.emulator import CameraEmulator
from sensorsocket.scene import CornerPath, Joint, Scene, SeamPath, rot_x
from sensorsocket.sensor import Reading, Sensor
from sensorsocket.service import SensorService
from sensorsocket.timing import TimingModel
from sensorsocket.udp import TriggerHandler, TriggerListener
from spec.server import FramedServer
from spec.wire import SensorStatus
from sync.interpolate import InterpStatus, interpolate_joints
from sync.joint_buffer import JointBuffer
from sync.udp import DelayLink, RobotSyncCore, UdpSyncEndpoint

__all__ = [
    "DEFAULT_LASER_TOOL",
    "DEFAULT_SENSOR_TOOL",
    "READY_JOINTS",
    "CellError",
    "CellTiming",
    "EmulatedCell",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
Loc = tuple[float, float, float, float, float, float]

#: ^N_S T: the sensor's measuring point 200 mm out along the flange axis, 40 mm ahead of the
#: laser focus in the welding direction (mm, deg).
DEFAULT_SENSOR_TOOL: Loc = (40.0, 0.0, 200.0, 0.0, 0.0, 0.0)
#: ^N_L T: the laser focus on the flange axis (mm, deg).
DEFAULT_LASER_TOOL: Loc = (0.0, 0.0, 200.0, 0.0, 0.0, 0.0)
#: Start joints (deg): flange pointing down, sensor over the seam in front of the robot.
READY_JOINTS = (0.0, 30.0, 100.0, 0.0, 50.0, 0.0)


class CellError(ValueError):
    """A cell parameter is out of range."""


@dataclass(frozen=True)
class CellTiming:
    """Timing of the cell (seconds, Hz, mm); defaults give the paper's ΔT ≈ 4.9 ms.

    encoder_latency_s: measured joints lag the true motion by this much.
    poll_rate_hz: the sensor's trigger loop (4 kHz: 0..0.25 ms).
    start_jitter_s: uniform extra delay before the exposure starts (0..0.25 ms).
    start_latency_s: fixed extra delay before the exposure starts.
    acquisition_s: readout of the full 512 columns (3.5 ms).
    processing_s: image processing after the readout.
    network_delay_s, network_jitter_s: one-way UDP delay, mean and uniform width (sim only;
        in real time the network is real).
    sensor_noise_mm: Gaussian noise added to the seam's y and z in the data datagrams, on
        top of the detector's own noise.
    """

    encoder_latency_s: float = 2.8e-3
    poll_rate_hz: float = 4000.0
    start_jitter_s: float = 0.25e-3
    start_latency_s: float = 0.0
    acquisition_s: float = 3.5e-3
    processing_s: float = 1.0e-3
    network_delay_s: float = 0.1e-3
    network_jitter_s: float = 0.1e-3
    sensor_noise_mm: float = 0.010

    def __post_init__(self) -> None:
        for name in (
            "encoder_latency_s",
            "start_jitter_s",
            "start_latency_s",
            "processing_s",
            "network_delay_s",
            "network_jitter_s",
            "sensor_noise_mm",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise CellError(f"{name} must be >= 0, got {v}")
        if not (math.isfinite(self.poll_rate_hz) and self.poll_rate_hz > 0):
            raise CellError("poll_rate_hz must be > 0")
        if not (math.isfinite(self.acquisition_s) and 0 < self.acquisition_s <= 0.1):
            raise CellError("acquisition_s must be in (0, 0.1] s")
        if self.network_jitter_s > 2 * self.network_delay_s:
            raise CellError("network_jitter_s must be <= 2 x network_delay_s")

    def true_delta_t_s(self, seam_time_s: float | None = None) -> float:
        """ΔT the experiment should find: encoder latency + mean network delay + mean poll
        wait + mean start jitter + start latency + the time from exposure start to the seam
        column (half the acquisition for a centred seam on the full chip, the default)."""
        seam = self.acquisition_s / 2.0 if seam_time_s is None else seam_time_s
        return (
            self.encoder_latency_s
            + self.network_delay_s
            + 0.5 / self.poll_rate_hz
            + self.start_jitter_s / 2.0
            + self.start_latency_s
            + seam
        )

    def jitter_width_s(self) -> float:
        """Total width of the trigger-to-exposure jitter (s): poll + start + network."""
        return 1.0 / self.poll_rate_hz + self.start_jitter_s + self.network_jitter_s


class _NoisySensor:
    """The sensor as the trigger handler sees it, with extra Gaussian noise on the seam y, z
    of FOUND readings: the noise goes in before the reply is encoded (no decode and
    re-encode of the datagram). The sensor's own records and latest reading stay noiseless."""

    def __init__(self, sensor: Sensor, noise_mm: float, rng: np.random.Generator) -> None:
        self.sensor = sensor
        self.noise_mm = noise_mm
        self._rng = rng

    def busy(self, t_arrival: float) -> bool:
        return self.sensor.busy(t_arrival)

    def acquire(
        self,
        t_arrival: float | None = None,
        *,
        index: int | None = None,
        t_trigger: float = math.nan,
    ) -> Reading:
        r = self.sensor.acquire(t_arrival, index=index, t_trigger=t_trigger)
        if self.noise_mm <= 0 or r.status is not SensorStatus.FOUND:
            return r
        dy, dz = self._rng.normal(0.0, self.noise_mm, 2)
        s = r.seam
        return dataclasses.replace(r, seam=(s[0], s[1] + dy, s[2] + dz, s[3], s[4], s[5]))


class _NoisyHandler(TriggerHandler):
    """The sensor's trigger handler with extra Gaussian noise on the reported seam y, z."""

    def __init__(self, sensor: Sensor, *, network_delay_s: float, noise_mm: float,
                 rng: np.random.Generator) -> None:  # fmt: skip
        super().__init__(_NoisySensor(sensor, noise_mm, rng), network_delay_s=network_delay_s)
        self.noise_mm = noise_mm


class _SimTransport:
    """Trigger transport of the simulated cell: remembers the target; the cell's cycle hook
    sends through the modelled link."""

    def __init__(self) -> None:
        self.target: tuple[str, int] | None = None

    def set_target(self, host: str, port: int) -> None:
        self.target = (host, port)

    def wake(self) -> None:
        pass


class _TruePoses:
    """The cell's true sensor poses as the camera asks for them: per time
    (:meth:`EmulatedCell.sensor2base`) or as node poses and weights
    (:meth:`EmulatedCell.node_poses`, a :class:`~sensorsocket.scene.NodePoseProvider`)."""

    def __init__(self, cell: EmulatedCell) -> None:
        self.node_poses = cell.node_poses
        self._poses = cell.sensor2base

    def __call__(self, times: FloatArray) -> FloatArray:
        return self._poses(times)


@dataclass
class _Record:
    index: int
    t_trigger: float
    t_seam: float
    status: SensorStatus


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
        joint, seam: the workpiece: ``butt|fillet|lap`` and ``straight|sine``.
        seed: seeds every random draw of the cell.
        host: address of the servers; ports 0 pick free ones.
        delta_t_s: the robot's initial ΔT setting (the synchronisation commands change it).
    """

    clock: str = "sim"
    timing: CellTiming = field(default_factory=CellTiming)
    model: str = "RX90B"
    sensor_tool: Loc = DEFAULT_SENSOR_TOOL
    laser_tool: Loc = DEFAULT_LASER_TOOL
    sensor_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    laser_tool_error: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    joint: str = "butt"
    seam: str = "straight"
    seed: int = 0
    host: str = "127.0.0.1"
    robot_port: int = 0
    sensor_port: int = 0
    udp_port: int = 0
    delta_t_s: float = 0.0
    ready_joints: Sequence[float] = READY_JOINTS

    def __post_init__(self) -> None:
        if self.clock not in ("sim", "real"):
            raise CellError(f"clock must be 'sim' or 'real', got {self.clock!r}")
        t = self.timing
        seeds = np.random.SeedSequence(self.seed).spawn(4)
        rng_timing, rng_render, rng_noise, rng_net = (np.random.default_rng(s) for s in seeds)
        self.robot = RobotEmulator(
            self.model,
            clock=self.clock,
            encoder_latency=t.encoder_latency_s,
            home=self.ready_joints,
            buffer_seconds=60.0,
        )
        nominal = location_to_transform(np.array(self.sensor_tool, dtype=np.float64))
        # the true tools (what the camera and the laser do) and the nominal sensor tool (what
        # the robot's synchronisation computes with)
        self.sensor2flange = nominal @ _error_transform(self.sensor_tool_error, "sensor")
        self.laser2flange = location_to_transform(
            np.array(self.laser_tool, dtype=np.float64)
        ) @ _error_transform(self.laser_tool_error, "laser")
        self.nominal_sensor2flange = nominal
        self._truth_lock = threading.Lock()
        self._truth = JointBuffer(capacity=2000)
        self._truth.append(0.0, np.asarray(self.ready_joints, dtype=np.float64))
        # sensor poses at the latest frame's setpoints and mid-cycles, see _node_poses
        self._nodes: tuple[list[float], FloatArray, FloatArray] = (
            [], np.empty((0, 6)), np.empty((0, 16)),
        )  # fmt: skip
        self.scene = self._make_scene()
        # node coordinates 0, 1, 2, ... as a column, for node_poses
        self._node_at = np.arange(64, dtype=np.float64)[:, None]
        # per node (setpoint, mid-cycle, ...): the support's half width and the slope of the
        # weight's second factor, see node_poses
        self._node_cap = np.empty((2, 64, 1))
        self._node_cap[0] = np.where(np.arange(64) % 2, 1.0, 2.0)[:, None]
        self._node_cap[1] = np.where(np.arange(64) % 2, 1.0, -0.5)[:, None]
        self.camera_timing = TimingModel(
            rng=rng_timing,
            poll_rate_hz=t.poll_rate_hz,
            start_jitter_s=t.start_jitter_s,
            start_latency_s=t.start_latency_s,
            full_frame_time_s=t.acquisition_s,
            processing_time_s=t.processing_s,
        )
        camera = CameraEmulator(self.scene, _TruePoses(self), self.camera_timing, rng=rng_render)
        self.sensor = Sensor(camera, clock=self.robot.time, after_acquire=self._record)
        self.records: list[_Record] = []
        self.handler = _NoisyHandler(
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
        self.uplink: DelayLink | None = None
        self.downlink: DelayLink | None = None
        self._sim_transport: _SimTransport | None = None
        if self.clock == "sim":
            self.uplink = DelayLink(
                delay_s=t.network_delay_s, jitter_s=t.network_jitter_s, rng=rng_net
            )
            self.downlink = DelayLink()  # the handler already adds the reply's network delay
            self._sim_transport = _SimTransport()
            self.sync = SyncService(self.robot, self.core, self._sim_transport)
            self.udp_address = (self.host, self.udp_port or 2001)
        else:
            self.listener = TriggerListener(
                self.handler, self.host, self.udp_port, clock=self.robot.time, hold=True
            )
            self.udp_address = self.listener.address
            self.endpoint = UdpSyncEndpoint(
                self.core,
                clock=self.robot.time,
                joints_since=self.robot.joint_log,
                host=self.host,
                port=0,
            )
            self.sync = SyncService(self.robot, self.core, self.endpoint)
        robot_service = RobotService(self.robot)
        self.sync.install(robot_service)
        self.robot_server = FramedServer(robot_service, self.host, self.robot_port)
        self.sensor_server = FramedServer(
            SensorService(self.sensor, trigger_endpoint=self.udp_address),
            self.host,
            self.sensor_port,
        )
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
        if self.joint not in joints or self.seam not in paths:
            raise CellError("joint must be butt|fillet|lap and seam straight|sine|corner")
        s2b = self.ready_sensor2base()
        # Workpiece: seam along x_S through the sensor origin, surface normal towards the
        # sensor (z_W = -z_S); the seam height of the joint is subtracted so the seam point
        # lands on the sensor origin.
        w = s2b.copy()
        w[:3, :3] = s2b[:3, :3] @ rot_x(math.pi)
        joint = joints[self.joint]
        w[:3, 3] = s2b[:3, 3] - w[:3, 2] * joint.seam_height_mm
        return Scene(joint, paths[self.seam], w)

    def ready_sensor2base(self) -> FloatArray:
        """^B_S T at the ready joints (4, 4) mm."""
        q = np.asarray(self.ready_joints, dtype=np.float64)
        out: FloatArray = self.robot.model.flange2base(q) @ self.sensor2flange
        return out

    def sensor2base(self, times: FloatArray) -> FloatArray:
        """True sensor poses (N, 4, 4) at robot-clock ``times`` (N,) s: the setpoints,
        linear between cycles, extrapolated past the latest one."""
        t = np.asarray(times, dtype=np.float64)
        if not len(t):
            return np.empty((0, 4, 4))
        t_min, t_max = float(t.min()), float(t.max())
        with self._truth_lock:
            # Only the samples around the query: the interval of the earliest query time and
            # at least the last three samples (extrapolation), not the whole 8 s buffer.
            buf_t, buf_q = self._truth.covering(t_min - 2.0 * self.robot.period)
        if len(buf_t) >= 2 and buf_t[0] <= t_min and t_max <= buf_t[-1]:
            # The simulated cell's case, motion known: the exact DGM only at the 4 ms
            # setpoints that bracket the queries and at mid-cycle (5-7 configurations, not
            # 512), the poses quadratic between them. Against the DGM of the joint-space
            # interpolation the arm follows this differs by ~1e-11 mm over a 10 s run
            # (a linear pose would be off by ~1.2e-6 mm); tests/test_cell_delay.py
            # ::test_sensor2base_pose_interpolation_exact checks < 1e-6 mm.
            return self._pose_interp(buf_t, buf_q, t)
        q, status = interpolate_joints(buf_t, buf_q, t)
        old = status == InterpStatus.TOO_OLD
        if np.any(old):
            q[old] = buf_q[0]
        new = status == InterpStatus.NOT_YET
        if np.any(new):
            q[new] = _extrapolate(buf_t[-3:], buf_q[-3:], t[new])
        return self._setpoint_poses(q)

    def node_poses(self, times: FloatArray) -> tuple[FloatArray, FloatArray] | None:
        """The poses of :meth:`sensor2base` at ``times`` (N,) s as node poses (M, 16) and
        weights (M, N) (:class:`~sensorsocket.scene.NodePoseProvider`): the setpoints that
        bracket the times and the mid-cycles between them, with each time's quadratic
        Lagrange weights. None when a time lies outside the known setpoints."""
        t = np.asarray(times, dtype=np.float64)
        if not len(t):
            return None
        t_min, t_max = float(np.minimum.reduce(t)), float(np.maximum.reduce(t))
        with self._truth_lock:
            buf_t, buf_q = self._truth.covering(t_min - 2.0 * self.robot.period)
        bt = buf_t.tolist()  # a few samples: bisect on Python floats
        n = len(bt)
        if not (n >= 2 and bt[0] <= t_min and t_max <= bt[-1]):
            return None
        if t_max - t_min > 16 * self.robot.period:
            return None  # a long span: more nodes than _node_at holds
        # the cycles of the earliest and the latest time, as _pose_interp's k
        k0, k1 = bisect.bisect_right(bt, t_min), bisect.bisect_right(bt, t_max)
        lo, hi = min(max(k0 - 1, 0), n - 2), min(max(k1 - 1, 0), n - 2) + 2
        t0 = buf_t[lo:hi]
        nodes = self._node_poses(t0, buf_q[lo:hi])
        m = len(nodes)
        # node coordinate of each time: setpoint j at 2j, linear in time over each cycle (so
        # the mid-cycle at 2j + 1); b: distance to every node (M, N), capped at the support
        x = np.interp(t, t0, self._node_at[0 : m + 1 : 2, 0])
        b = np.subtract(x, self._node_at[:m])
        np.abs(b, out=b)
        at = self._node_cap[:, :m]
        np.minimum(b, at[0], out=b)
        # quadratic Lagrange weights of the nodes 2j, 2j + 1, 2j + 2 of a cycle in the
        # distance b: (1 - b)(1 - b/2) for a setpoint (b <= 2), (1 - b)(1 + b) for a
        # mid-cycle (b <= 1)
        w = np.subtract(1.0, b)
        b *= at[1]
        b += 1.0
        w *= b
        return nodes, w

    def _setpoint_poses(self, q: FloatArray) -> FloatArray:
        """^B_S T (N, 4, 4) mm at joints ``q`` (N, 6) deg."""
        f2b = self.robot.model.flange2base_batch(q)
        # one (4N, 4) @ (4, 4) product instead of N small ones
        out: FloatArray = (f2b.reshape(-1, 4) @ self.sensor2flange).reshape(-1, 4, 4)
        return out

    def _pose_interp(self, buf_t: FloatArray, buf_q: FloatArray, t: FloatArray) -> FloatArray:
        """Sensor poses (M, 4, 4) at ``t`` (M,) inside the samples ``buf_t`` (N >= 2,):
        exact at the bracketing samples and at the middle of each cycle, quadratic between
        (a linear pose would miss the bow of the joint-space path by ~1.2 nm)."""
        k = np.searchsorted(buf_t, t, side="right")
        k -= 1
        # ufuncs, not np.clip: its Python wrapper costs more than the work on 512 times
        np.maximum(k, 0, out=k)
        np.minimum(k, len(buf_t) - 2, out=k)
        lo, hi = int(np.minimum.reduce(k)), int(np.maximum.reduce(k)) + 2
        q = buf_q[lo:hi]
        t0 = buf_t[lo:hi]
        m = len(q)
        poses = self._node_poses(t0, q)
        k -= lo
        w = (t - t0[k]) / (t0[k + 1] - t0[k])
        # Lagrange weights of the nodes at w = 0, 1/2, 1 in a (M, nodes) matrix: one small
        # product instead of gathering three (M, 16) pose stacks
        n_nodes = 2 * m - 1
        basis = np.zeros((len(t), n_nodes))
        # flat positions of node 2k in each row: 1-D scatters, cheaper than (rows, cols) pairs
        at = np.arange(0, len(t) * n_nodes, n_nodes)
        at += 2 * k
        flat = basis.reshape(-1)
        flat[at] = 2.0 * (w - 0.5) * (w - 1.0)
        at += 1
        flat[at] = 4.0 * w * (1.0 - w)
        at += 1
        flat[at] = 2.0 * w * (w - 0.5)
        out: FloatArray = (basis @ poses).reshape(-1, 4, 4)
        return out

    def _node_poses(self, t0: FloatArray, q: FloatArray) -> FloatArray:
        """Poses (2m - 1, 16) at the setpoints ``q`` (m, 6) of times ``t0`` (m,) (node 2j)
        and at the middle of each cycle (node 2j + 1).

        Consecutive frames share most setpoints: the poses of the previous call are kept
        and only the nodes past them are computed (the DGM is row by row, so the values are
        the same as computing all of them at once)."""
        c_t, c_q, c_p = self._nodes
        times = t0.tolist()  # a few: bisect and compare on Python floats
        m = len(times)
        known = 0
        i = bisect.bisect_left(c_t, times[0])
        if i < len(c_t) and c_t[i] == times[0]:
            known = min(len(c_t) - i, m)
            # setpoints never change once appended; check anyway (a cleared buffer)
            if c_t[i : i + known] != times[:known] or not (c_q[i : i + known] == q[:known]).all():
                known = 0
        if known == m:
            out: FloatArray = c_p[2 * i : 2 * (i + m) - 1]
            return out
        if known:
            # the new nodes: the middle of the cycle after the last known setpoint, ...
            k0 = known - 1
            nodes = np.empty((2 * (m - known), q.shape[1]))
            nodes[1::2] = q[known:]
            nodes[0::2] = 0.5 * (q[k0:-1] + q[known:])
            new = np.concatenate(
                (c_p[2 * i : 2 * (i + k0) + 1], self._setpoint_poses(nodes).reshape(-1, 16))
            )
        else:
            nodes = np.empty((2 * m - 1, q.shape[1]))
            nodes[0::2] = q
            nodes[1::2] = 0.5 * (q[:-1] + q[1:])
            new = self._setpoint_poses(nodes).reshape(-1, 16)
        self._nodes = (times, q, new)  # one tuple: a reader never sees a half update
        return new

    # --- the clock ---------------------------------------------------------------------------

    def _on_cycle(self, t: float, q_sp: FloatArray, q_m: FloatArray) -> None:
        with self._truth_lock:
            self._truth.append(t, q_sp)
        if self.clock != "sim":
            return
        assert self.uplink is not None and self.downlink is not None
        core = self.core
        core.add_joint(t, q_m)
        target = self._sim_transport.target if self._sim_transport is not None else None
        # Triggers for another port go nowhere, as on a real network.
        reachable = target is not None and target[1] == self.udp_address[1]
        for index, t_send in core.due_triggers(t):
            data = core.sent(index, t_send)
            if reachable:
                self.uplink.send(t_send, data)
        # The sensor may acquire once the arm's motion over the whole exposure is known.
        s = self.sensor.settings
        horizon = (
            1.0 / self.timing.poll_rate_hz
            + self.timing.start_jitter_s
            + self.timing.start_latency_s
            + self.sensor.acquisition_time()
            + s.exposure_s
        )
        for t_arrival, datagram in self.uplink.deliver(t - horizon):
            reply = self.handler.process(datagram, t_arrival)
            if reply is not None:
                self.downlink.send(reply.t_send, reply.data)
        for t_arrival, datagram in self.downlink.deliver(t):
            core.on_datagram(datagram, t_arrival)
        core.poll(t)

    def advance(self, seconds: float) -> None:
        """Simulated clock: run the cell for ``seconds``."""
        self.robot.advance_to(self.robot.time() + seconds)

    def _record(self, reading: Reading) -> None:
        acq_first = self.sensor.settings.first_column
        dt = self.camera_timing.column_period_s
        t_seam = math.nan
        if reading.status is SensorStatus.FOUND:
            # CameraGeometry.project of (0, y, z) on Python floats: the same operations in
            # the same order as its numpy arithmetic, so the same u to the last bit
            cam = self.sensor.emulator.camera
            y, z = float(reading.seam[1]), float(reading.seam[2])
            th = math.radians(cam.triangulation_angle_deg)
            zc = cam.working_distance_mm + 0.0 * math.sin(th) + z * math.cos(th)
            u = cam.principal_point[0] + cam.focal_px * y / zc
            t_seam = (
                reading.t_exposure_start
                + (u - acq_first) * dt
                + self.sensor.settings.exposure_s / 2.0
            )
        self.records.append(_Record(reading.index, reading.t_trigger, t_seam, reading.status))

    # --- truth -------------------------------------------------------------------------------

    def true_delta_t_s(self) -> float:
        """ΔT from the timing parameters, for a centred seam on the current readout window."""
        s = self.sensor.settings
        cols = self.sensor.emulator.camera.columns
        seam = ((cols - 1) / 2.0 - s.first_column) * self.camera_timing.column_period_s
        return self.timing.true_delta_t_s(seam + s.exposure_s / 2.0)

    def measured_delta_t(self, first_index: int = 0) -> float:
        """ΔT from the sensor's own records of triggered acquisitions with index >=
        ``first_index``: encoder latency + mean(time of the seam column - t_i^T). NaN when
        none found a seam."""
        d = [
            r.t_seam - r.t_trigger
            for r in self.records
            if r.index >= first_index and math.isfinite(r.t_seam) and math.isfinite(r.t_trigger)
        ]
        if not d:
            return math.nan
        return self.timing.encoder_latency_s + float(np.mean(d))

    # --- lifecycle ---------------------------------------------------------------------------

    @property
    def robot_address(self) -> tuple[str, int]:
        return self.robot_server.address

    @property
    def sensor_address(self) -> tuple[str, int]:
        return self.sensor_server.address

    def start(self) -> EmulatedCell:
        if self._started:
            return self
        self._started = True
        self.robot.start()
        if self.listener is not None:
            self.listener.start()
        if self.endpoint is not None:
            self.endpoint.start()
        self.robot_server.start()
        self.sensor_server.start()
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
        self.robot_server.shutdown()
        self.sensor_server.shutdown()
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
    """The tool error as a transform, checked: finite, at most 50 mm and 30 deg per component
    (a mounting error, not another tool)."""
    v = np.array(error, dtype=np.float64)
    if v.shape != (6,) or not np.isfinite(v).all():
        raise CellError(f"{which} tool error must be 6 finite numbers (mm, deg)")
    if np.abs(v[:3]).max() > 50.0 or np.abs(v[3:]).max() > 30.0:
        raise CellError(f"{which} tool error must be within 50 mm and 30 deg per component")
    return location_to_transform(v)


def _as_loc(v: FloatArray) -> Loc:
    return (float(v[0]), float(v[1]), float(v[2]), float(v[3]), float(v[4]), float(v[5]))


def _lerp(t: FloatArray, q: FloatArray, query: FloatArray) -> FloatArray:
    """Joints (M, J) at ``query`` times (M,) inside the samples t (N >= 2,), q (N, J):
    :func:`~sync.interpolate.interpolate_joints` without its checks and status (same
    arithmetic, same values)."""
    k = np.clip(np.searchsorted(t, query, side="right") - 1, 0, len(t) - 2)
    t0, t1 = t[k], t[k + 1]
    w = ((query - t0) / (t1 - t0))[:, None]
    q0, q1 = q[k], q[k + 1]
    v = (1.0 - w) * q0 + w * q1
    out: FloatArray = np.clip(v, np.minimum(q0, q1), np.maximum(q0, q1), out=v)
    return out


def _extrapolate(t: FloatArray, q: FloatArray, query: FloatArray) -> FloatArray:
    """Joints at ``query`` times from the last samples (<= 3): quadratic in time."""
    n = len(t)
    if n == 1:
        return np.broadcast_to(q[0], (len(query), q.shape[1])).copy()
    tau = t - t[-1]
    x = query - t[-1]
    deg = min(n - 1, 2)
    out = np.empty((len(query), q.shape[1]))
    for j in range(q.shape[1]):
        c = np.polyfit(tau, q[:, j], deg)
        out[:, j] = np.polyval(c, x)
    return out
