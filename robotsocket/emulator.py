"""The robot emulator: a :class:`RobotInterface` over the kinematic model and the generator.

State: power, software emergency stop, motion queue (:class:`TrajectoryGenerator`), named
digital I/O, and the cyclic joint buffer of (t_k, q_k) (:class:`sync.joint_buffer.JointBuffer`,
default 10 s deep). Every cycle (T_r = 4 ms) produces a setpoint; the measured joints are the
setpoints delayed by ``encoder_latency`` seconds (linear interpolation between cycles) plus
optional Gaussian noise, and are what Herej, Here and the joint log report.

Dynamics (``dynamics``, default None: the arm is where its setpoint is): an elastic arm
(:class:`kinematics.dynamics.ElasticArm`) follows the setpoints through its servos; the
measured joints are then its MOTOR side (delayed as above), what a CS8 reports from its
motor encoders, and :meth:`RobotEmulator.true_joints` its LINK side, where the tool truly is
(what the cell's camera sees and its laser hits). A move has settled once the link stands.

Clocks: ``clock="sim"`` (default) never advances by itself: call :meth:`RobotEmulator.step`
or :meth:`RobotEmulator.advance_to`; :meth:`wait_end_move` *advances the simulated clock*
until the motion is done or the timeout (simulated seconds) expires. ``clock="real"`` runs a
:class:`~robotsocket.clock.RealTimeLoop` thread (call :meth:`start` and :meth:`close`); every
reader first runs the cycles that are due but not yet ticked (:meth:`RobotEmulator.catch_up`),
so a late clock thread never makes a sample stale or wrong.

Observers: callables in :attr:`RobotEmulator.cycle_hooks` are called every cycle with
(t_k, q_setpoint (6,), q_measured (6,)) while the emulator's lock is held; keep them short
(:meth:`RobotEmulator.true_joints` is that cycle's link side).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence

import numpy as np

from kinematics.dynamics import ElasticArm, ElasticParams
from kinematics.errors import KinematicsError
from kinematics.robot import RobotModel, get_model
from kinematics.transforms import (
    invert,
    location_to_transform,
    locations_to_transforms,
    transform_to_location,
)
from kinematics.types import IDENTITY_LOC, FloatArray, Loc
from robotsocket.alter import AlterState, corrected_flange
from robotsocket.alter_queue import QueueReport
from robotsocket.clock import RealTimeLoop, SimLoop, lateness_summary
from robotsocket.interface import (
    BadStateError,
    BusyError,
    EmergencyStopError,
    InvalidArgumentError,
    MotionDesc,
    NotPoweredError,
    OutOfRangeError,
    RobotError,
    RobotInfo,
    RobotInterface,
    RobotStatus,
    robot_error,
)
from robotsocket.paths import Move, plan_joint, plan_linear
from robotsocket.service import error_code
from robotsocket.shared_state import Snapshot
from robotsocket.timed_path import plan_timed
from robotsocket.trajectory import PERIOD, TrajectoryGenerator
from spec.clocks import ClockKind, check_clock_kind
from spec.wire import MoveOutcome
from sync.joint_buffer import JointBuffer

log = logging.getLogger(__name__)

#: Start joints (deg): upper arm up, forearm forward, flange pointing down; no singularity.
HOME = (0.0, 0.0, 90.0, 0.0, 90.0, 0.0)
OUTPUTS = ("laser", "gas", "crossjet")
INPUTS = ("laser_ready", "gas_pressure_ok", "door_closed")
#: Moves that may wait in the queue.
MAX_QUEUE = 256
#: Output changes kept in :attr:`RobotEmulator.io_log`.
IO_LOG_LENGTH = 10_000
#: Cycles a held simulated arm advances per lock hold (~4 ms of CPU).
_SIM_SLICE = 250

CycleHook = Callable[[float, FloatArray, FloatArray], None]


def _loc(values: Sequence[float], what: str) -> FloatArray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (6,) or not np.all(np.isfinite(arr)):
        raise InvalidArgumentError(f"{what}: expected 6 finite numbers (x, y, z, rx, ry, rz)")
    return location_to_transform(arr)


def here_at(
    model: RobotModel, q: FloatArray, tool: FloatArray | Loc, frame: FloatArray | Loc
) -> Loc:
    """[RS-5.16] Here: the tool's location in ``frame`` at joints ``q`` (6,) deg; ``tool`` and
    ``frame`` as 4x4 transforms or VAL3 locations (checked: BAD_PARAMETERS)."""
    tool_T = tool if isinstance(tool, np.ndarray) else _loc(tool, "tool")
    frame_T = frame if isinstance(frame, np.ndarray) else _loc(frame, "frame")
    T = invert(frame_T) @ model.flange2base(q) @ tool_T
    x, y, z, rx, ry, rz = (float(v) for v in transform_to_location(T))
    return (x, y, z, rx, ry, rz)


class RobotEmulator(RobotInterface):
    """An emulated Stäubli arm (default RX90B) behind the robot API.

    ``encoder_latency`` s (>= 0), ``noise_deg`` standard deviation of the measured joints
    (needs ``rng``), ``buffer_seconds`` depth of the joint log, ``home`` start joints (6,),
    ``dynamics`` the elastic arm's parameters (None: a rigid arm, exactly at its setpoints).
    """

    def __init__(
        self,
        model: str | RobotModel = "RX90B",
        *,
        clock: ClockKind = "sim",
        period: float = PERIOD,
        encoder_latency: float = 0.0,
        noise_deg: float = 0.0,
        rng: np.random.Generator | None = None,
        home: Sequence[float] = HOME,
        buffer_seconds: float = 10.0,
        serial: str = "EMU-0001",
        dynamics: ElasticParams | None = None,
    ) -> None:
        self.model = model if isinstance(model, RobotModel) else get_model(model)
        check_clock_kind(clock)
        if not (math.isfinite(encoder_latency) and encoder_latency >= 0.0):
            raise ValueError(f"encoder_latency must be >= 0 s, got {encoder_latency}")
        if noise_deg < 0.0 or (noise_deg > 0.0 and rng is None):
            raise ValueError("noise_deg must be >= 0 and needs an rng when > 0")
        self.period = period
        self.encoder_latency = encoder_latency
        self.noise_deg = noise_deg
        self._rng = rng
        self._serial = serial
        q0 = self.model.check_joints(home)
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._waiters = 0
        self._gen = TrajectoryGenerator(q0, period)
        self._desc = MotionDesc()
        self._powered = False
        #: [RS-7.22] control was lost: arm power goes off once the arm stands.
        self._power_off_at_rest = False
        #: [RS-5.50] the last queued move: MOVING until it reached its target (then it reads
        #: REACHED once the arm settled) or was stopped or failed, with the reason.
        self._outcome: tuple[MoveOutcome, str] = (MoveOutcome.REACHED, "")
        self._estop = False
        self._last_error: RobotError | None = None
        self._next_move_id = 1
        self._outputs = dict.fromkeys(OUTPUTS, False)
        self._inputs = dict.fromkeys(INPUTS, True)
        self._lag_cycles = math.ceil(encoder_latency / period) + 2
        # what the encoders read each cycle (the setpoints of a rigid arm), before the latency
        self._setpoints: deque[tuple[float, FloatArray]] = deque(maxlen=self._lag_cycles + 1)
        self._setpoints.append((0.0, q0))
        self._measured = q0.copy()
        self._arm = None if dynamics is None else ElasticArm(self.model, dynamics, q0, period)
        self._link = q0.copy()
        self._setpoint = q0.copy()
        self._buffer = JointBuffer(capacity=max(2, round(buffer_seconds / period)))
        self._buffer.append(0.0, q0)
        self._idle_since = 0.0
        self._sample_lateness: deque[float] = deque(maxlen=10000)
        self._alter = AlterState(period)
        self.cycle_hooks: list[CycleHook] = []
        #: (robot time s, output, value) of every SetOutput and every safety switch-off.
        self.io_log: deque[tuple[float, str, bool]] = deque(maxlen=IO_LOG_LENGTH)
        self._simclock: SimLoop | None = None
        self._loop: RealTimeLoop | None = None
        if clock == "sim":
            self._simclock = SimLoop(period, self._tick)
        else:
            self._loop = RealTimeLoop(period, self._tick, idle=self.at_rest)

    # --- clock -------------------------------------------------------------------------------

    @property
    def simulated(self) -> bool:
        return self._simclock is not None

    def start(self) -> RobotEmulator:
        """Start the real-time loop (no-op in simulated mode)."""
        if self._loop is not None and not self._loop.running:
            self._loop.start()
        return self

    def close(self) -> None:
        if self._loop is not None:
            self._loop.stop()

    @property
    def clock_start_ns(self) -> int:
        """Real clock: the robot clock's zero on ``time.monotonic_ns`` (any process can read
        the robot time from it)."""
        if self._loop is None:
            raise BadStateError("the simulated clock has no zero on the monotonic clock")
        return self._loop.start_ns

    def jitter(self) -> dict[str, float]:
        """Real-time tick lateness summary (s); empty counts in simulated mode."""
        if self._loop is None:
            return {"count": 0, "p50": 0.0, "p99": 0.0, "max": 0.0, "mean": 0.0}
        return self._loop.jitter()

    def sample_lateness(self) -> dict[str, float]:
        """Real clock, while the arm moves: how late each sample was computed after its grid
        time, by whichever thread ran it first (the clock thread, or a reader's
        :meth:`catch_up`); the same summary as :meth:`jitter`. This is when a sample became
        visible to clients; :meth:`jitter` is the clock thread's own lateness."""
        return lateness_summary(self._sample_lateness)

    def step(self, n_cycles: int = 1) -> None:
        """Simulated mode: run ``n_cycles`` controller cycles."""
        if self._simclock is None:
            raise BadStateError("step() is for the simulated clock; the real clock runs itself")
        with self._lock:
            self._simclock.advance(n_cycles)

    def advance_to(self, t: float) -> None:
        """Simulated mode: run cycles until the robot clock reaches ``t`` seconds."""
        if self._simclock is None:
            raise BadStateError("advance_to() is for the simulated clock")
        with self._lock:
            n = math.floor(t / self.period + 1e-9) - self._simclock.cycle
            if n > 0:
                self._simclock.advance(n)

    @property
    def cycle(self) -> int:
        return self._simclock.cycle if self._simclock is not None else self._gen.k

    def catch_up(self) -> None:
        """Real clock: run every cycle due by now in the calling thread, if the clock
        thread has not yet (a busy machine may not give it the CPU or the GIL in time).

        The sample of cycle k is a function of the motion and t_k = k * T_r, so it is the
        same whichever thread computes it and however late; readers (Herej, Here, status,
        the joint log, a new move, the cell's camera) call this first and never see a
        stale sample because the tick thread ran late (docs/REALTIME.md)."""
        loop = self._loop
        if loop is None:
            return
        # cycle k is due at start + k * T_r (RealTimeLoop's deadline); unlocked first look:
        # the usual case, nothing due, costs no lock
        k_now = math.floor(loop.now() / self.period + 1e-9)
        if k_now <= self._gen.k:
            return
        with self._lock:
            for k in range(self._gen.k + 1, k_now + 1):
                self._tick(k)

    def _tick(self, k: int) -> None:
        with self._lock:
            if k <= self._gen.k:
                return  # already run by a reader's catch_up
            t = k * self.period
            q_sp = self._gen.step(k)
            if self._alter.engaged:
                q_sp = self._altered(t, q_sp)
            self._setpoint = q_sp
            if self._arm is None:
                self._link = q_sp
            else:
                self._arm.cycle(q_sp)
                self._link = self._arm.link_deg
            self._setpoints.append((t, q_sp if self._arm is None else self._arm.motor_deg))
            q_m = self._delayed(t - self.encoder_latency)
            if self.noise_deg > 0.0 and self._rng is not None:
                q_m = q_m + self._rng.normal(0.0, self.noise_deg, q_m.shape)
            self._measured = q_m
            self._buffer.append(t, q_m)
            if self._loop is not None and self._gen.in_motion:
                self._sample_lateness.append(max(self._loop.now() - t, 0.0))
            if self._power_off_at_rest and self._gen.idle:
                self._power_down("controller lost: the arm stands")
            if self._gen.in_motion or self._alter.engaged:
                self._idle_since = math.inf
            elif self._idle_since == math.inf:
                self._idle_since = t
            for hook in self.cycle_hooks:
                hook(t, q_sp, q_m)
            if self._waiters:
                self._cond.notify_all()

    def at_rest(self) -> bool:
        """Nothing moves and nobody waits for a cycle: the clock thread may sleep (readers
        compute the due cycles, :meth:`catch_up`); a new move or waiter wakes it."""
        return (
            self._waiters == 0
            and not self._gen.in_motion
            and not self._alter.engaged
            and self._settled()
        )

    def _altered(self, t: float, q_nominal: FloatArray) -> FloatArray:
        """[RS-5.32] The nominal setpoint with the alter correction of this cycle applied
        (IK re-solved next to the nominal joints). A stream that stopped [RS-5.36] switches the
        laser off and stops the motion along its path; a correction the arm cannot follow
        stops the arm where it is."""
        alter = self._alter
        if alter.step(t):
            self._switch_off("laser", "alter stream lost")
            self._stopped(MoveOutcome.STOPPED, "alter stream lost")
            self._gen.reset()
            self._last_error = BadStateError(
                f"alter stream lost: no correction for {alter.timeout * 1000:.0f} ms"
            )
            log.warning("alter stream lost: laser off, motion stopped along the path")
        if not np.any(alter.applied):
            return q_nominal
        flange = corrected_flange(
            self.model.flange2base(q_nominal), alter.tool2flange, alter.applied
        )
        try:
            q: FloatArray = self.model.ik(flange, near=q_nominal)[0].joints_deg
        except KinematicsError as exc:
            self._last_error = robot_error(exc)
            self._switch_off("laser", "alter correction unreachable")
            self._stopped(MoveOutcome.FAILED, f"alter correction unreachable: {exc}")
            self._gen.halt()
            self._gen.hold_q = self._setpoint.copy()
            alter.fold()
            log.warning("alter correction unreachable: arm stopped (%s)", exc)
            return self._gen.hold_q
        return q

    def _switch_off(self, name: str, why: str) -> None:
        if self._outputs[name]:
            self._outputs[name] = False
            self.io_log.append((self.time(), name, False))
            log.warning("%s: %s off", why, name)

    def _stopped(self, kind: MoveOutcome, why: str) -> None:
        """[RS-5.50] Moves are being stopped or failed (``why``): the last one did not reach
        its target. Nothing queued or executing: the last outcome stands."""
        if not self._gen.idle and self._outcome[0] is MoveOutcome.MOVING:
            self._outcome = (kind, why)

    def move_outcome(self) -> tuple[MoveOutcome, str]:
        with self._lock:
            kind, why = self._outcome
            if kind is not MoveOutcome.MOVING:
                return kind, why
            if self._gen.held:
                return MoveOutcome.STOPPED, "StopMove (held: RestartMove goes on)"
            return (MoveOutcome.REACHED, "") if self._settled() else (MoveOutcome.MOVING, "")

    def _done_waiting(self) -> bool:
        """WaitEndMove ends when the arm settled, or stands held by StopMove."""
        return self._settled() or (self._gen.held and not self._gen.in_motion)

    def _power_down(self, why: str) -> None:
        """[RS-7.22] The end of a stop of category 1: power off once the arm stands."""
        self._power_off_at_rest = False
        if self._powered:
            self._powered = False
            log.warning("%s: arm power off", why)

    def _halt(self) -> None:
        """Immediate stop at the last (corrected) setpoint; any correction is folded in."""
        self._gen.halt()
        if self._alter.engaged:
            self._gen.hold_q = self._setpoint.copy()
            self._alter.fold()

    def _delayed(self, t: float) -> FloatArray:
        hist = self._setpoints
        if self.encoder_latency == 0.0 or t <= hist[0][0]:
            return hist[-1][1] if self.encoder_latency == 0.0 else hist[0][1]
        for i in range(len(hist) - 1, 0, -1):
            t0, q0 = hist[i - 1]
            t1, q1 = hist[i]
            if t0 <= t <= t1:
                w = (t - t0) / (t1 - t0)
                return q0 + w * (q1 - q0)
        return hist[-1][1]

    # --- RobotInterface ----------------------------------------------------------------------

    def info(self) -> RobotInfo:
        return RobotInfo("Staubli (emulated)", self.model.name, self._serial)

    def time(self) -> float:
        if self._loop is not None:
            return self._loop.now()
        assert self._simclock is not None
        return self._simclock.now()

    def _settled(self) -> bool:
        t = self._gen.k * self.period
        return (
            self._gen.idle
            and not self._alter.engaged  # alter mode moves the arm without a move queued
            and t >= self._idle_since + self.encoder_latency - 1e-12
            and (self._arm is None or self._arm.at_rest())
        )

    @property
    def dynamics(self) -> ElasticParams | None:
        """The elastic arm's parameters; None for a rigid arm."""
        return None if self._arm is None else self._arm.params

    def true_joints(self) -> FloatArray:
        """The link side (6,) deg at the latest cycle: where the arm truly is (the setpoint
        of a rigid arm). The emulator's truth, not part of the robot API; a new array each
        cycle, never written into."""
        return self._link

    def status(self) -> RobotStatus:
        self.catch_up()
        with self._lock:
            return RobotStatus(
                powered=self._powered,
                estop=self._estop,
                moving=self._moving(),
                queue=self._gen.queued,
                last_error=self._last_error,
                time=self.time(),
            )

    def _moving(self) -> bool:
        return self._gen.in_motion or (not self._settled() and not self._gen.held)

    def publish(self, write: Callable[[Snapshot], None]) -> None:
        """``write(self.snapshot())`` under the lock: writes from several threads arrive in
        the order of the states they show (a command's state never overwritten by an older
        cycle's)."""
        with self._lock:
            write(self.snapshot())

    def snapshot(self) -> Snapshot:
        """The state as of the latest cycle, without running due cycles (what the real-time
        process publishes each cycle, :mod:`robotsocket.shared_state`)."""
        with self._lock:
            err = self._last_error
            outcome, why = self.move_outcome()
            return Snapshot(
                cycle=self._gen.k,
                t=self._gen.k * self.period,
                measured=tuple(float(v) for v in self._measured),
                setpoint=tuple(float(v) for v in self._setpoint),
                powered=self._powered,
                estop=self._estop,
                moving=self._moving(),
                settled=self._settled(),
                queue=self._gen.queued,
                error_code=0 if err is None else int(error_code(err)),
                error_message="" if err is None else str(err),
                outcome=outcome.value,
                outcome_reason=why,
            )

    def herej(self) -> FloatArray:
        self.catch_up()
        # No lock: the tick replaces _measured with a new array (never writes into it), so
        # one reference read is a consistent sample; a reader holding the lock while it
        # waits for the GIL would stall the 4 ms tick (priority inversion).
        return np.array(self._measured)

    def herej_values(self) -> list[float]:
        self.catch_up()
        values: list[float] = self._measured.tolist()  # no lock and no copy, as in herej
        return values

    def setpoint(self) -> FloatArray:
        """Latest commanded joints (6,) degrees."""
        self.catch_up()
        with self._lock:
            return np.array(self._setpoint)

    def here(self, tool: Loc = IDENTITY_LOC, frame: Loc = IDENTITY_LOC) -> Loc:
        tool_T, frame_T = _loc(tool, "tool"), _loc(frame, "frame")
        self.catch_up()
        q = np.array(self._measured)  # no lock, as in herej
        return here_at(self.model, q, tool_T, frame_T)

    def joint_limits(self) -> FloatArray:
        return np.array(self.model.limits)

    def enable_power(self) -> None:
        with self._lock:
            if self._estop:
                raise EmergencyStopError("emergency stop engaged: reset it before power on")
            self._power_off_at_rest = False  # a new controller's power-on holds
            if not self._powered:
                self._powered = True
                log.info("arm power on")

    def disable_power(self) -> None:
        with self._lock:
            self._stopped(MoveOutcome.STOPPED, "DisablePower")
            self._halt()
            if self._powered:
                self._powered = False
                log.info("arm power off")

    def _check_can_move(self) -> None:
        if self._estop:
            raise EmergencyStopError("emergency stop engaged")
        if not self._powered:
            raise NotPoweredError("arm power is off: EnablePower first")
        if len(self._gen.queue) >= MAX_QUEUE:
            raise BusyError(f"motion queue full ({MAX_QUEUE} moves)")

    def _queue(self, plan: Callable[[int, FloatArray], object]) -> int:
        self.catch_up()  # the move starts after now, not after a late tick's cycle
        with self._lock:
            try:
                self._check_can_move()
                move_id = self._next_move_id
                move = plan(move_id, self._gen.planned_end())
            except RobotError as exc:
                self._last_error = exc
                raise
            except KinematicsError as exc:
                err = robot_error(exc)
                self._last_error = err
                raise err from None
            assert isinstance(move, Move)
            self._power_off_at_rest = False  # a new controller's move runs powered
            self._next_move_id += 1
            self._gen.enqueue(move)
            self._outcome = (MoveOutcome.MOVING, "")
            if self._loop is not None:
                self._loop.wake()
            self._idle_since = math.inf
            log.debug("queued %s move %d", move.kind, move_id)
            return move_id

    def joint_move(self, joints: FloatArray) -> int:
        q = np.asarray(joints, dtype=np.float64)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise InvalidArgumentError(f"joints: expected 6 finite values, got shape {q.shape}")
        return self._queue(lambda i, start: plan_joint(i, self.model, start, q, self._desc))

    def _tool_target(self, loc: Loc, tool: Loc, frame: Loc) -> tuple[FloatArray, FloatArray]:
        tool_T = _loc(tool, "tool")
        target = _loc(frame, "frame") @ _loc(loc, "location")
        return target, tool_T

    def tool_move_j(self, loc: Loc, tool: Loc = IDENTITY_LOC, frame: Loc = IDENTITY_LOC) -> int:
        target, tool_T = self._tool_target(loc, tool, frame)
        flange = target @ invert(tool_T)

        def plan(i: int, start: FloatArray) -> object:
            sols = self.model.ik(flange, near=start)
            return plan_joint(i, self.model, start, sols[0].joints_deg, self._desc)

        return self._queue(plan)

    def tool_move_l(self, loc: Loc, tool: Loc = IDENTITY_LOC, frame: Loc = IDENTITY_LOC) -> int:
        target, tool_T = self._tool_target(loc, tool, frame)
        return self._queue(
            lambda i, start: plan_linear(i, self.model, start, target, tool_T, self._desc)
        )

    def tool_move_trajectory(
        self, times: FloatArray, locations: FloatArray, tool: Loc, frame: Loc
    ) -> int:
        t = np.asarray(times, dtype=np.float64)
        locs = np.asarray(locations, dtype=np.float64)
        if locs.ndim != 2 or locs.shape[1] != 6:
            raise InvalidArgumentError(f"locations must be an N x 6 matrix, got {locs.shape}")
        if not np.all(np.isfinite(locs)):
            raise OutOfRangeError("locations must be finite")
        tool_T = _loc(tool, "tool")
        poses = _loc(frame, "frame") @ locations_to_transforms(locs)
        return self._queue(
            lambda i, start: plan_timed(i, self.model, start, t, poses, tool_T, period=self.period)
        )

    def set_motion_desc(self, desc: MotionDesc) -> None:
        desc.check()
        with self._lock:
            self._desc = desc

    def motion_desc(self) -> MotionDesc:
        with self._lock:
            return self._desc

    def wait_end_move(self, timeout: float) -> bool:
        if not (math.isfinite(timeout) and 0.0 < timeout <= 3600.0):
            raise OutOfRangeError(f"timeout must be in (0, 3600] s, got {timeout}")
        if self._simclock is not None:
            return self._advance_until_settled(timeout)
        with self._lock:
            self._waiters += 1
            if self._loop is not None:
                self._loop.wake()  # an idle clock thread: tick for the waiter
            try:
                return self._cond.wait_for(self._done_waiting, timeout)
            finally:
                self._waiters -= 1

    def _advance_until_settled(self, timeout: float) -> bool:
        """Simulated clock: waiting *is* advancing the clock. The lock is taken per slice
        of cycles, so other connections (EmergencyStop, a controller that is lost) get in
        between and a long wait never freezes the server."""
        assert self._simclock is not None
        clock = self._simclock
        with self._lock:
            end = clock.cycle + math.ceil(timeout / self.period)
        while True:
            with self._lock:
                if self._done_waiting() or clock.cycle >= end:
                    return self._done_waiting()
                if self._gen.held and not self._gen.in_motion:
                    # Held by StopMove: nothing changes until a command does.
                    n = min(end - clock.cycle, _SIM_SLICE)
                else:
                    n = 1
                clock.advance(n)
            # Hand the lock over: a thread blocked on it wakes, but without this the waiter
            # would take it again before that thread gets the interpreter.
            time.sleep(0)

    def stop_move(self) -> None:
        with self._lock:
            self._gen.stop()

    def restart_move(self) -> None:
        with self._lock:
            if self._estop:
                raise EmergencyStopError("emergency stop engaged")
            if not self._powered:
                raise NotPoweredError("arm power is off")
            self._gen.restart()

    def reset_motion(self) -> None:
        with self._lock:
            self._stopped(MoveOutcome.STOPPED, "ResetMotion")
            self._gen.reset()
            self._last_error = None

    def on_control_lost(self, why: str = "control lost") -> None:
        """[RS-7.10] The laser goes off before anything else, then the arm decelerates along
        its path and the queue is dropped, then crossjet and gas go off; arm power goes off
        once the arm stands [RS-7.22]."""
        with self._lock:
            self._switch_off("laser", "controller lost")
            if not self._gen.idle:
                log.warning("controller lost: decelerating along the path and dropping the queue")
            self._stopped(MoveOutcome.STOPPED, why)
            self._gen.reset()
            if self._alter.active:
                self._alter.abandon()  # [RS-5.38] the correction ramps back to zero
            for name in ("crossjet", "gas"):
                self._switch_off(name, "controller lost")
            if self._gen.idle:
                self._power_down("controller lost")
            else:
                self._power_off_at_rest = self._powered

    def on_control_released(self) -> None:
        """[RS-7.21] The process outputs need an owner: laser first, then crossjet and gas.
        Queued moves go on and power stays [RS-7.11] [RS-7.22]."""
        with self._lock:
            for name in ("laser", "crossjet", "gas"):
                self._switch_off(name, "control released")

    def emergency_stop(self) -> None:
        with self._lock:
            self._switch_off("laser", "EMERGENCY STOP")  # [RS-7.21] before anything else
            self._stopped(MoveOutcome.STOPPED, "emergency stop")
            self._halt()
            self._estop = True
            self._powered = False
            self._power_off_at_rest = False
            for name in ("crossjet", "gas"):
                self._switch_off(name, "EMERGENCY STOP")
            self._last_error = EmergencyStopError("emergency stop engaged")
            log.warning("EMERGENCY STOP: motion halted, power and outputs off")

    def reset_emergency_stop(self) -> None:
        with self._lock:
            if self._estop:
                self._estop = False
                self._last_error = None
                log.info("emergency stop reset (power stays off)")

    def set_output(self, name: str, value: bool) -> None:
        with self._lock:
            # [RS-5.21] a name the robot does not have (as an output) is out of range.
            if name in self._inputs:
                raise OutOfRangeError(f"{name!r} is an input and cannot be set")
            if name not in self._outputs:
                raise OutOfRangeError(
                    f"unknown output {name!r}; outputs: {', '.join(self._outputs)}"
                )
            if self._estop and value:
                raise EmergencyStopError("emergency stop engaged: outputs stay off")
            self._outputs[name] = bool(value)
            self.io_log.append((self.time(), name, bool(value)))
            log.info("output %s %s", name, "on" if value else "off")

    def set_input(self, name: str, value: bool) -> None:
        """Emulator side: change a digital input (what the cell's sensors would do)."""
        with self._lock:
            if name not in self._inputs:
                raise InvalidArgumentError(f"unknown input {name!r}")
            self._inputs[name] = bool(value)

    def read_io(self, name: str) -> tuple[bool, bool]:
        with self._lock:
            if name in self._outputs:
                return self._outputs[name], True
            if name in self._inputs:
                return self._inputs[name], False
        raise OutOfRangeError(f"unknown I/O {name!r}")  # [RS-5.21]

    def list_io(self) -> tuple[list[str], list[str]]:
        return list(self._outputs), list(self._inputs)

    def alter_begin(self, tool: Loc, timeout: float) -> None:
        tool_T = _loc(tool, "tool")
        self.catch_up()
        with self._lock:
            if self._estop:
                raise EmergencyStopError("emergency stop engaged")
            if not self._powered:
                raise NotPoweredError("arm power is off: EnablePower first")
            self._alter.begin(tool_T, timeout, self.time())
            if self._loop is not None:
                self._loop.wake()
            log.info("alter mode on (stream timeout %.0f ms)", timeout * 1000)

    def alter(self, correction: Sequence[float] | FloatArray) -> FloatArray:
        self.catch_up()
        with self._lock:
            return self._alter.command(np.asarray(correction, dtype=np.float64), self.time())

    def alter_end(self) -> None:
        self.catch_up()
        with self._lock:
            self._alter.end()
            log.info("alter mode off: the correction ramps back to zero")

    def alter_queue(
        self, times: FloatArray, corrections: FloatArray
    ) -> tuple[QueueReport, FloatArray, float]:
        self.catch_up()
        with self._lock:
            report = self._alter.enqueue(times, corrections)
            if self._loop is not None:
                self._loop.wake()
            return report, self._alter.applied.copy(), self._gen.k * self.period

    def alter_applied(self) -> FloatArray:
        """The correction (6,) applied at the last cycle (mm, deg, base frame)."""
        with self._lock:
            return self._alter.applied.copy()

    def joint_log(self, since: float) -> tuple[FloatArray, FloatArray]:
        self.catch_up()
        with self._lock:
            times, joints = self._buffer.since(since)
        keep = times > since
        return times[keep], joints[keep]
