"""Trajectory generation: velocity profiles, paths, and the per-cycle generator (pure).

A move is a geometric path q(s), s in [0, 1], and a timing law s(t). Joint-interpolated moves
use the straight line in joint space; Cartesian-linear moves interpolate the tool pose
(straight line, slerp orientation) and solve the IK for every cycle sample. All axes of a
move follow the same s(t), so they start and end together (synchronised axes).

Timing laws are trapezoidal in s: accelerate, cruise, decelerate, with the limits derived
from the joint and tool limits of :class:`~robotsocket.interface.MotionDesc`. Stopping turns
the law into a deceleration from the current (s, ds/dt), so the arm stops *on its path*.
Blending superposes the next move's displacement onto the current one's deceleration
(overlap no longer than either ramp, so each joint's speed stays within the larger of the two
moves' speeds; accelerations may add up to twice the limit during the overlap).

Nothing here reads a clock: :meth:`TrajectoryGenerator.step` takes the cycle index k and
returns the setpoint at t_k = k * period.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from kinematics.errors import KinematicsError
from kinematics.robot import CONFIGS, BoolArray, RobotModel
from robotsocket.interface import (
    Array,
    MotionDesc,
    OutOfRangeError,
    SingularityError,
    UnreachableError,
    robot_error,
)

#: Controller cycle T_r in seconds (paper section V).
PERIOD = 0.004

#: Nominal joint speeds (deg/s) per model at 100 % mdesc speed (manufacturer data, rounded).
NOMINAL_JOINT_SPEED: dict[str, tuple[float, ...]] = {
    "RX90B": (356.0, 356.0, 296.0, 409.0, 480.0, 1125.0),
    "RX130B": (250.0, 200.0, 250.0, 300.0, 300.0, 600.0),
    "RX160": (200.0, 200.0, 255.0, 315.0, 360.0, 870.0),
    "TX90": (400.0, 400.0, 430.0, 540.0, 475.0, 760.0),
}
#: Nominal joint acceleration = this factor x nominal speed (deg/s^2 per deg/s).
ACCEL_FACTOR = 4.0
#: Tool acceleration at 100 % mdesc acceleration: mm/s^2 and deg/s^2.
NOMINAL_TOOL_ACCEL = 5000.0
NOMINAL_TOOL_ROT_ACCEL = 2000.0

#: Below these the Cartesian path is declared singular: |sin θ5|, |sin θ3|, r / reach.
SINGULAR_MARGIN = 2e-3
#: A joint step this large (deg) between neighbouring path samples means a branch flip.
MAX_GRID_STEP_DEG = 10.0
#: Joint-speed scaling below this fraction of the Cartesian speed means "too close to a
#: singularity to be useful".
MIN_SPEED_FRACTION = 1e-3
#: Cartesian IK chunk: cycles solved in one vectorised call.
CHUNK = 32


def nominal_limits(model: str) -> tuple[Array, Array]:
    """(speed (6,) deg/s, acceleration (6,) deg/s^2) at 100 % for a model name."""
    speed = np.array(NOMINAL_JOINT_SPEED.get(model.upper(), NOMINAL_JOINT_SPEED["RX90B"]))
    return speed, ACCEL_FACTOR * speed


# --- timing laws ----------------------------------------------------------------------------


class Law(Protocol):
    @property
    def t_end(self) -> float:
        """Time (s) from which the law stands still."""
        ...

    def at(self, t: float) -> tuple[float, float]:
        """(s, ds/dt) at time t (s)."""
        ...

    def s_array(self, t: Array) -> Array: ...


@dataclass(frozen=True)
class Trapezoid:
    """From rest at s0 (time t0) to rest at s = 1: accelerate with ``acc``, cruise at most
    ``vmax``, decelerate with ``dec`` (all in 1/s, 1/s^2)."""

    t0: float
    s0: float
    vmax: float
    acc: float
    dec: float
    vpeak: float = field(init=False)
    ta: float = field(init=False)
    tc: float = field(init=False)
    td: float = field(init=False)
    t_end: float = field(init=False)

    def __post_init__(self) -> None:
        dist = max(1.0 - self.s0, 0.0)
        vp = self.vmax
        if dist <= 0.0 or not math.isfinite(vp):
            vp = 0.0  # nothing to do, or no limit at all: jump at once
        elif vp * vp * (0.5 / self.acc + 0.5 / self.dec) > dist:
            vp = math.sqrt(2.0 * dist * self.acc * self.dec / (self.acc + self.dec))
        ta = vp / self.acc if vp > 0 else 0.0
        td = vp / self.dec if vp > 0 else 0.0
        tc = (dist - 0.5 * vp * ta - 0.5 * vp * td) / vp if vp > 0 else 0.0
        object.__setattr__(self, "vpeak", vp)
        object.__setattr__(self, "ta", ta)
        object.__setattr__(self, "tc", max(tc, 0.0))
        object.__setattr__(self, "td", td)
        object.__setattr__(self, "t_end", self.t0 + ta + max(tc, 0.0) + td)

    def at(self, t: float) -> tuple[float, float]:
        tau = t - self.t0
        vp = self.vpeak
        if tau <= 0.0:
            return self.s0, 0.0
        if t >= self.t_end:
            return 1.0, 0.0
        if tau < self.ta:
            return self.s0 + 0.5 * self.acc * tau * tau, self.acc * tau
        tau -= self.ta
        if tau < self.tc:
            return self.s0 + 0.5 * vp * self.ta + vp * tau, vp
        r = self.t_end - t  # time left
        return 1.0 - 0.5 * self.dec * r * r, self.dec * r

    def s_array(self, t: Array) -> Array:
        return np.array([self.at(float(x))[0] for x in t])


@dataclass(frozen=True)
class Decel:
    """Decelerate from (s0, v0) at t0 with ``dec`` until at rest."""

    t0: float
    s0: float
    v0: float
    dec: float
    t_end: float = field(init=False)
    s_end: float = field(init=False)

    def __post_init__(self) -> None:
        tb = self.v0 / self.dec if self.v0 > 0 else 0.0
        object.__setattr__(self, "t_end", self.t0 + tb)
        object.__setattr__(self, "s_end", min(self.s0 + 0.5 * self.v0 * tb, 1.0))

    def at(self, t: float) -> tuple[float, float]:
        if t >= self.t_end:
            return self.s_end, 0.0
        tau = max(t - self.t0, 0.0)
        return min(self.s0 + self.v0 * tau - 0.5 * self.dec * tau * tau, 1.0), self.v0 - (
            self.dec * tau
        )

    def s_array(self, t: Array) -> Array:
        return np.array([self.at(float(x))[0] for x in t])


@dataclass(frozen=True)
class Hold:
    """Stand still at s (after a StopMove)."""

    s: float
    t_end: float = -math.inf

    def at(self, t: float) -> tuple[float, float]:
        return self.s, 0.0

    def s_array(self, t: Array) -> Array:
        return np.full(len(t), self.s)


# --- paths ----------------------------------------------------------------------------------


class Path(Protocol):
    @property
    def start(self) -> Array: ...

    @property
    def target(self) -> Array: ...

    def q_at(self, s: Array, q_prev: Array) -> Array:
        """Joints (N, 6) at path parameters s (N,), continuing from q_prev (6,)."""
        ...


@dataclass(frozen=True)
class JointPath:
    """Straight line in joint space from start (6,) to target (6,) degrees."""

    start: Array
    target: Array

    def q_at(self, s: Array, q_prev: Array) -> Array:
        q = self.start + np.multiply.outer(s, self.target - self.start)
        q[s >= 1.0] = self.target
        q[s <= 0.0] = self.start
        return q


def _rodrigues(axis: Array, angles: Array) -> Array:
    """Rotations (N, 3, 3) by ``angles`` (N,) rad about the unit ``axis`` (3,)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angles), np.cos(angles)
    R: Array = np.eye(3) + s[:, None, None] * K + (1.0 - c)[:, None, None] * (K @ K)
    return R


def _wrap180(a: Array) -> Array:
    return np.asarray((a + 180.0) % 360.0 - 180.0)


@dataclass(frozen=True)
class CartesianPath:
    """Straight line of the tool from tool2base T0 to T1, orientation by slerp; joints by IK
    in one fixed configuration branch, unwrapped continuously from the start joints."""

    model: RobotModel
    start: Array  # (6,) deg
    T0: Array  # tool2base (4, 4) at s = 0
    T1: Array  # tool2base (4, 4) at s = 1
    flange2tool: Array  # inverse of tool2flange (4, 4)
    branch: int  # index into kinematics.robot.CONFIGS
    target: Array = field(default_factory=lambda: np.zeros(6))  # set by plan_linear
    length_mm: float = field(init=False)
    angle_deg: float = field(init=False)
    _axis: Array = field(init=False, repr=False)

    def __post_init__(self) -> None:
        rel = self.T0[:3, :3].T @ self.T1[:3, :3]
        cos = float(np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0))
        angle = math.acos(cos)
        w = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
        if angle < 1e-12:
            axis = np.array([0.0, 0.0, 1.0])
        elif math.pi - angle < 1e-6:
            # Half turn: the axis is the eigenvector of rel with eigenvalue 1.
            vals, vecs = np.linalg.eigh((rel + rel.T) / 2.0)
            axis = vecs[:, int(np.argmax(vals))]
        else:
            axis = w / (2.0 * math.sin(angle))
        object.__setattr__(self, "_axis", axis / np.linalg.norm(axis))
        object.__setattr__(
            self, "length_mm", float(np.linalg.norm(self.T1[:3, 3] - self.T0[:3, 3]))
        )
        object.__setattr__(self, "angle_deg", math.degrees(angle))

    def tool_poses(self, s: Array) -> Array:
        """tool2base (N, 4, 4) at path parameters s (N,)."""
        n = len(s)
        T = np.zeros((n, 4, 4))
        T[:, :3, :3] = self.T0[:3, :3] @ _rodrigues(self._axis, s * math.radians(self.angle_deg))
        T[:, :3, 3] = self.T0[:3, 3] + np.multiply.outer(s, self.T1[:3, 3] - self.T0[:3, 3])
        T[:, 3, 3] = 1.0
        return T

    def solve(self, s: Array, q_prev: Array) -> tuple[Array, BoolArray, BoolArray]:
        """(joints (N, 6) unwrapped from q_prev, valid (N,), reachable (N,))."""
        F = self.tool_poses(s) @ self.flange2tool
        batch = self.model.ik_batch(F, near=q_prev)
        q = batch.joints_deg[:, self.branch, :]
        valid = batch.valid[:, self.branch]
        reach = batch.reachable[:, self.branch]
        if np.all(valid):
            steps = _wrap180(np.diff(np.vstack([q_prev, q]), axis=0))
            q = q_prev + np.cumsum(steps, axis=0)
        return q, valid, reach

    def q_at(self, s: Array, q_prev: Array) -> Array:
        q, valid, _ = self.solve(s, q_prev)
        if not np.all(valid):
            raise UnreachableError("Cartesian path left the workspace during the move")
        q[s >= 1.0] = self.target
        q[s <= 0.0] = self.start
        return q


# --- planning -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Move:
    """A planned move: path, limits of its timing law (in s units), blending."""

    id: int
    kind: str  # "joint" or "linear"
    path: Path
    vmax: float  # 1/s
    acc: float  # 1/s^2
    dec: float  # 1/s^2
    length_mm: float  # flange (joint) or tool (linear) path length, for blending
    blend_mm: float
    #: Joint acceleration limits (6,) deg/s^2 of the motion descriptor, for blending.
    joint_acc: Array | None = None

    @property
    def start(self) -> Array:
        return self.path.start

    @property
    def target(self) -> Array:
        return self.path.target

    def law(self, t0: float, s0: float = 0.0) -> Trapezoid:
        return Trapezoid(t0, s0, self.vmax, self.acc, self.dec)


def _s_limits(dq: Array, vmax: Array, amax: Array, dmax: Array) -> tuple[float, float, float]:
    moving = np.abs(dq) > 1e-12
    if not np.any(moving):
        return math.inf, math.inf, math.inf
    a = np.abs(dq[moving])
    return (
        float(np.min(vmax[moving] / a)),
        float(np.min(amax[moving] / a)),
        float(np.min(dmax[moving] / a)),
    )


def joint_limits_of(model: RobotModel, desc: MotionDesc) -> tuple[Array, Array, Array]:
    """Joint (speed, accel, decel) limits (6,) deg/s, deg/s^2 under ``desc``."""
    v, a = nominal_limits(model.name)
    return v * desc.joint_speed / 100.0, a * desc.joint_accel / 100.0, a * desc.joint_decel / 100.0


def plan_joint(
    move_id: int, model: RobotModel, start: Array, target: Array, desc: MotionDesc
) -> Move:
    """Plan a synchronised joint move; raises OutOfRangeError outside the joint limits."""
    try:
        tgt = model.check_joints(target)
    except KinematicsError as exc:
        raise robot_error(exc) from None
    start = np.array(start, dtype=np.float64)
    vj, aj, dj = joint_limits_of(model, desc)
    vmax, acc, dec = _s_limits(tgt - start, vj, aj, dj)
    p0 = model.flange2base(start)[:3, 3]
    p1 = model.flange2base(tgt)[:3, 3]
    return Move(
        move_id,
        "joint",
        JointPath(start, tgt),
        vmax,
        acc,
        dec,
        float(np.linalg.norm(p1 - p0)),
        desc.blend,
        np.maximum(aj, dj),
    )


def _singular_measures(model: RobotModel, q: Array) -> tuple[Array, Array, Array]:
    t = np.radians(q + np.asarray(model.joint_offsets_deg))
    r = (
        model.shoulder_offset_mm
        + model.upper_arm_mm * np.sin(t[:, 1])
        + model.forearm_mm * np.sin(t[:, 1] + t[:, 2])
    )
    return np.abs(np.sin(t[:, 4])), np.abs(np.sin(t[:, 2])), np.abs(r) / model.reach_mm


def plan_linear(
    move_id: int,
    model: RobotModel,
    start: Array,
    tool2base_target: Array,
    tool2flange: Array,
    desc: MotionDesc,
) -> Move:
    """Plan a straight-line tool move from joints ``start`` (6,) to ``tool2base_target``.

    Every point of the path is checked before anything moves: UnreachableError when a point
    is out of reach, OutOfRangeError when it needs joints outside the limits,
    SingularityError when the path crosses or touches a singularity. The tool speed is
    lowered where the joints would otherwise exceed their speed limits.
    """
    start = np.array(start, dtype=np.float64)
    F0 = model.flange2base(start)
    T0 = F0 @ tool2flange
    flange2tool = np.asarray(np.linalg.inv(tool2flange), dtype=np.float64)
    branch = CONFIGS.index(model.config_of(start))
    path = CartesianPath(model, start, T0, tool2base_target, flange2tool, branch)
    n = int(np.clip(path.length_mm / 0.5 + path.angle_deg / 0.25, 200, 4000))
    grid = np.linspace(0.0, 1.0, n)
    q, valid, reach = path.solve(grid, start)
    if not np.all(reach):
        k = int(np.argmin(reach))
        what = "target" if k == n - 1 else f"path point at {100 * grid[k]:.1f} %"
        raise UnreachableError(f"{what} is out of reach in the start configuration")
    if not np.all(valid):
        k = int(np.argmin(valid))
        raise OutOfRangeError(f"path point at {100 * grid[k]:.1f} % needs joints outside limits")
    s5, s3, rr = _singular_measures(model, q)
    if min(float(s5.min()), float(s3.min()), float(rr.min())) < SINGULAR_MARGIN:
        which = ("wrist", "elbow", "shoulder")[int(np.argmin([s5.min(), s3.min(), rr.min()]))]
        raise SingularityError(f"the straight line crosses a {which} singularity")
    steps = np.abs(np.diff(q, axis=0))
    if steps.size and float(steps.max()) > MAX_GRID_STEP_DEG:
        raise SingularityError("the straight line flips the wrist (crosses a singularity)")
    if not bool(np.all(model.within_limits(q))):
        raise OutOfRangeError("the straight line needs joints outside the limits")
    target = q[-1].copy()
    object.__setattr__(path, "target", target)
    # Limits in s units: tool speed, rotation speed, then joint speed along the path.
    v_lim = [desc.tool_speed / path.length_mm if path.length_mm > 1e-9 else math.inf]
    v_lim.append(desc.tool_rot_speed / path.angle_deg if path.angle_deg > 1e-9 else math.inf)
    acc_t = NOMINAL_TOOL_ACCEL * desc.joint_accel / 100.0
    acc_r = NOMINAL_TOOL_ROT_ACCEL * desc.joint_accel / 100.0
    dec_t = NOMINAL_TOOL_ACCEL * desc.joint_decel / 100.0
    dec_r = NOMINAL_TOOL_ROT_ACCEL * desc.joint_decel / 100.0
    L, A = max(path.length_mm, 1e-9), max(path.angle_deg, 1e-9)
    acc = min(acc_t / L, acc_r / A)
    dec = min(dec_t / L, dec_r / A)
    vmax = min(v_lim)
    if not math.isfinite(vmax):
        vmax, acc, dec = math.inf, math.inf, math.inf
    else:
        vj, _, _ = joint_limits_of(model, desc)
        dqds = np.max(np.abs(np.diff(q, axis=0)), axis=0) * (n - 1)  # deg per unit s
        joint_v = float(np.min(np.where(dqds > 1e-12, vj / np.maximum(dqds, 1e-300), math.inf)))
        # 2 % margin: the finite-difference slope underestimates the peak between samples.
        joint_v *= 0.98
        if joint_v < vmax:
            if joint_v < MIN_SPEED_FRACTION * vmax:
                raise SingularityError("the path passes too close to a singularity")
            vmax = joint_v
    _, aj, dj = joint_limits_of(model, desc)
    return Move(
        move_id, "linear", path, vmax, acc, dec, path.length_mm, desc.blend, np.maximum(aj, dj)
    )


# --- the generator --------------------------------------------------------------------------


@dataclass
class Segment:
    """A move being executed: its timing law and the last joints on its own path."""

    move: Move
    law: Law
    last_q: Array
    cancelled: bool = False
    _cache_law: Law | None = None
    _cache_k0: int = 0
    _cache_q: Array | None = None

    def q(self, k: int, period: float) -> Array:
        """Joints (6,) of this segment's path at cycle k."""
        path = self.move.path
        if isinstance(path, JointPath):
            s, _ = self.law.at(k * period)
            if s >= 1.0:
                out: Array = path.target
            elif s <= 0.0:
                out = path.start
            else:
                out = path.start + s * (path.target - path.start)
            self.last_q = out
            return out
        # Cartesian: solve the IK for a chunk of upcoming cycles in one vectorised call.
        c = self._cache_q
        if c is None or self._cache_law is not self.law or not 0 <= k - self._cache_k0 < len(c):
            ks = np.arange(k, k + CHUNK)
            s_chunk = np.array([self.law.at(float(x) * period)[0] for x in ks])
            c = path.q_at(s_chunk, self.last_q)
            self._cache_q, self._cache_law, self._cache_k0 = c, self.law, k
        out = np.asarray(c[k - self._cache_k0], dtype=np.float64)
        self.last_q = out
        return out

    def q_at_s(self, s: float) -> Array:
        return np.asarray(self.move.path.q_at(np.array([s]), self.last_q)[0], dtype=np.float64)


class TrajectoryGenerator:
    """Per-cycle setpoints from a queue of planned moves (pure: the cycle index is input).

    ``step(k)`` must be called with k = previous k + 1. The first sample of a move started at
    cycle k already moves (its law starts at t_{k-1}, where the arm was).
    """

    def __init__(self, q0: Array, period: float = PERIOD) -> None:
        self.period = period
        self.hold_q = np.array(q0, dtype=np.float64)
        self.last_q = self.hold_q.copy()
        self.queue: deque[Move] = deque()
        self.active: list[Segment] = []
        self.held = False  # StopMove in force
        self.k = 0
        self._reset_point: Array | None = None
        self._blend_plan: tuple[tuple[int, int], float] | None = None

    # --- state -------------------------------------------------------------------------------

    @property
    def idle(self) -> bool:
        """No move queued or executing."""
        return not self.active and not self.queue

    @property
    def in_motion(self) -> bool:
        """The setpoint is changing now or will without a new command."""
        if self.idle:
            return False
        return not (self.held and all(isinstance(s.law, Hold) for s in self.active))

    @property
    def queued(self) -> int:
        """Moves queued, including the ones executing."""
        return len(self.queue) + sum(1 for s in self.active if not s.cancelled)

    def planned_end(self) -> Array:
        """Joints where the last queued move ends: the start of the next one."""
        if self.queue:
            return self.queue[-1].target
        if self.active:
            if all(s.cancelled for s in self.active) and self._reset_point is not None:
                return self._reset_point
            return self.active[-1].move.target
        return self.hold_q

    # --- commands ----------------------------------------------------------------------------

    def enqueue(self, move: Move) -> None:
        self.queue.append(move)

    def stop(self) -> None:
        """StopMove: decelerate every executing move along its path; keep the queue."""
        self.held = True
        self._decelerate()

    def restart(self) -> None:
        self.held = False

    def reset(self) -> None:
        """ResetMotion: decelerate along the path, then drop everything."""
        self.queue.clear()
        self.held = False
        if not self.active:
            return
        self._decelerate()
        for seg in self.active:
            seg.cancelled = True
        q = self.active[0].q_at_s(self.active[0].law.at(math.inf)[0])
        for seg in self.active[1:]:
            q = q + seg.q_at_s(seg.law.at(math.inf)[0]) - seg.move.start
        self._reset_point = q

    def halt(self) -> None:
        """Immediate stop at the last setpoint (emergency stop, power off)."""
        self.queue.clear()
        self.active.clear()
        self.held = False
        self.hold_q = self.last_q.copy()

    def _decelerate(self) -> None:
        t = self.k * self.period
        for seg in self.active:
            if isinstance(seg.law, Trapezoid):
                s, v = seg.law.at(t)
                dec = seg.move.dec if math.isfinite(seg.move.dec) else 1e9
                seg.law = Decel(t, s, v, dec)

    # --- the cycle ---------------------------------------------------------------------------

    def step(self, k: int) -> Array:
        """Setpoint joints (6,) degrees at t_k = k * period."""
        period = self.period
        t_prev = self.k * period
        self.k = k
        t = k * period
        self._start_segments(t_prev)
        if not self.active:
            self.last_q = self.hold_q
            return self.hold_q
        q = self.active[0].q(k, period)
        for seg in self.active[1:]:
            q = q + seg.q(k, period) - seg.move.start
        self._retire(t, q)
        if not self.active:
            q = self.hold_q
        self.last_q = q
        return q

    def _start_segments(self, t_prev: float) -> None:
        if self.held:
            return
        active = self.active
        if active and all(s.cancelled for s in active):
            return
        if active:
            front = active[0]
            if isinstance(front.law, Hold):
                front.law = front.move.law(t_prev, front.law.s)
            elif (
                len(active) == 1
                and self.queue
                and front.move.blend_mm > 0.0
                and isinstance(front.law, Trapezoid)
            ):
                nxt = self.queue[0]
                law = front.law
                law_next = nxt.law(0.0)
                overlap = min(law.td, law_next.ta)
                # Remaining distance (1-s)*L <= blend  <=>  (remaining time)^2 * dec * L / 2.
                if front.move.length_mm > 0.0 and law.dec > 0.0:
                    t_blend = math.sqrt(
                        2.0 * front.move.blend_mm / (law.dec * front.move.length_mm)
                    )
                    overlap = min(overlap, t_blend)
                if t_prev >= law.t_end - overlap and t_prev >= self._blend_start(
                    front, nxt, t_prev
                ):
                    self.queue.popleft()
                    active.append(Segment(nxt, nxt.law(t_prev), nxt.start))
            return
        if self.queue:
            nxt = self.queue.popleft()
            active.append(Segment(nxt, nxt.law(t_prev), nxt.start))

    def _blend_start(self, front: Segment, nxt: Move, t_first: float) -> float:
        """When ``nxt`` may start, superposed on the end of ``front``: ``t_first`` (the blend
        distance allows it from then), later, or ``front``'s end (no blend).

        Blending adds the two moves' joint motions. Where a joint reverses, the end of one
        move's braking and the start of the other's acceleration add up; the blend then starts
        late enough that no joint is asked for more than its acceleration limit (or more than
        either move alone asks). Decided once per pair by bisection on the start time.
        """
        key = (front.move.id, nxt.id)
        if self._blend_plan is not None and self._blend_plan[0] == key:
            return self._blend_plan[1]
        t_end = front.law.t_end
        start = t_first
        if not self._blend_within_limits(front, nxt, t_first):
            bad, good = t_first, t_end  # starting at the end is no blend at all
            for _ in range(6):
                mid = 0.5 * (bad + good)
                if self._blend_within_limits(front, nxt, mid):
                    good = mid
                else:
                    bad = mid
            start = good
        self._blend_plan = (key, start)
        return start

    def _blend_within_limits(self, front: Segment, nxt: Move, t0: float) -> bool:
        """Second differences of the blended setpoints against the joint limits, on copies of
        both segments (the real ones and their IK caches are untouched)."""
        period = self.period
        ks = range(round(t0 / period) - 1, math.ceil(front.law.t_end / period) + 3)
        a, b = copy.copy(front), Segment(nxt, nxt.law(t0), nxt.start)
        qa = np.array([a.q(k, period) for k in ks])
        qb = np.array([b.q(k, period) for k in ks]) - nxt.start
        acc_a = np.abs(np.diff(qa, 2, axis=0)).max(axis=0)
        acc_b = np.abs(np.diff(qb, 2, axis=0)).max(axis=0)
        acc_sum = np.abs(np.diff(qa + qb, 2, axis=0)).max(axis=0)
        allowed = np.maximum(acc_a, acc_b)
        for limit in (front.move.joint_acc, nxt.joint_acc):
            if limit is not None:
                allowed = np.maximum(allowed, limit * period * period)
        return bool(np.all(acc_sum <= allowed * (1.0 + 1e-6) + 1e-12))

    def _retire(self, t: float, q: Array) -> None:
        active = self.active
        if all(s.cancelled for s in active):
            if all(t >= s.law.t_end for s in active):
                self.hold_q = self._reset_point if self._reset_point is not None else q
                self._reset_point = None
                active.clear()
            return
        for seg in active:
            if isinstance(seg.law, Decel) and t >= seg.law.t_end:
                seg.law = Hold(seg.law.s_end)
        while active and isinstance(active[0].law, Trapezoid) and t >= active[0].law.t_end:
            done = active.pop(0)
            if not active:
                self.hold_q = done.move.target
