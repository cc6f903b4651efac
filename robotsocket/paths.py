"""Geometric paths q(s) of moves and their planning, pure.

Joint-interpolated moves use the straight line in joint space (:class:`JointPath`);
Cartesian-linear moves interpolate the tool pose (straight line, slerp orientation) and solve
the IK for every cycle sample (:class:`CartesianPath`). Planning (:func:`plan_joint`,
:func:`plan_linear`) checks the whole path before anything moves and derives the limits of
the move's timing law (:mod:`robotsocket.profiles`) from the joint and tool limits of
:class:`~robotsocket.interface.MotionDesc`; all axes of a move follow the same s(t), so they
start and end together (synchronised axes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from kinematics.arm import BoolArray
from kinematics.config import CONFIGS
from kinematics.errors import KinematicsError
from kinematics.robot import RobotModel
from kinematics.types import FloatArray
from robotsocket.interface import (
    MotionDesc,
    OutOfRangeError,
    SingularityError,
    UnreachableError,
    robot_error,
)
from robotsocket.profiles import Trapezoid

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


def nominal_limits(model: str) -> tuple[FloatArray, FloatArray]:
    """(speed (6,) deg/s, acceleration (6,) deg/s^2) at 100 % for a model name."""
    speed = np.array(NOMINAL_JOINT_SPEED.get(model.upper(), NOMINAL_JOINT_SPEED["RX90B"]))
    return speed, ACCEL_FACTOR * speed


class Path(Protocol):
    @property
    def start(self) -> FloatArray: ...

    @property
    def target(self) -> FloatArray: ...

    def q_at(self, s: FloatArray, q_prev: FloatArray) -> FloatArray:
        """Joints (N, 6) at path parameters s (N,), continuing from q_prev (6,)."""
        ...


@dataclass(frozen=True)
class JointPath:
    """Straight line in joint space from start (6,) to target (6,) degrees."""

    start: FloatArray
    target: FloatArray

    def q_at(self, s: FloatArray, q_prev: FloatArray) -> FloatArray:
        q = self.start + np.multiply.outer(s, self.target - self.start)
        q[s >= 1.0] = self.target
        q[s <= 0.0] = self.start
        return q


def _rodrigues(axis: FloatArray, angles: FloatArray) -> FloatArray:
    """Rotations (N, 3, 3) by ``angles`` (N,) rad about the unit ``axis`` (3,)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angles), np.cos(angles)
    R: FloatArray = np.eye(3) + s[:, None, None] * K + (1.0 - c)[:, None, None] * (K @ K)
    return R


def wrap180(a: FloatArray) -> FloatArray:
    """Angles (deg) wrapped into [-180, 180)."""
    return np.asarray((a + 180.0) % 360.0 - 180.0)


@dataclass(frozen=True)
class CartesianPath:
    """Straight line of the tool from tool2base T0 to T1, orientation by slerp; joints by IK
    in one fixed configuration branch, unwrapped continuously from the start joints."""

    model: RobotModel
    start: FloatArray  # (6,) deg
    T0: FloatArray  # tool2base (4, 4) at s = 0
    T1: FloatArray  # tool2base (4, 4) at s = 1
    flange2tool: FloatArray  # inverse of tool2flange (4, 4)
    branch: int  # index into kinematics.config.CONFIGS
    target: FloatArray = field(default_factory=lambda: np.zeros(6))  # set by plan_linear
    length_mm: float = field(init=False)
    angle_deg: float = field(init=False)
    _axis: FloatArray = field(init=False, repr=False)

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

    def tool_poses(self, s: FloatArray) -> FloatArray:
        """tool2base (N, 4, 4) at path parameters s (N,)."""
        n = len(s)
        T = np.zeros((n, 4, 4))
        T[:, :3, :3] = self.T0[:3, :3] @ _rodrigues(self._axis, s * math.radians(self.angle_deg))
        T[:, :3, 3] = self.T0[:3, 3] + np.multiply.outer(s, self.T1[:3, 3] - self.T0[:3, 3])
        T[:, 3, 3] = 1.0
        return T

    def solve(self, s: FloatArray, q_prev: FloatArray) -> tuple[FloatArray, BoolArray, BoolArray]:
        """(joints (N, 6) unwrapped from q_prev, valid (N,), reachable (N,))."""
        F = self.tool_poses(s) @ self.flange2tool
        batch = self.model.ik_batch(F, near=q_prev)
        q = batch.joints_deg[:, self.branch, :]
        valid = batch.valid[:, self.branch]
        reach = batch.reachable[:, self.branch]
        if np.all(valid):
            steps = wrap180(np.diff(np.vstack([q_prev, q]), axis=0))
            q = q_prev + np.cumsum(steps, axis=0)
        return q, valid, reach

    def q_at(self, s: FloatArray, q_prev: FloatArray) -> FloatArray:
        q, valid, _ = self.solve(s, q_prev)
        if not np.all(valid):
            raise UnreachableError("Cartesian path left the workspace during the move")
        q[s >= 1.0] = self.target
        q[s <= 0.0] = self.start
        return q


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
    joint_acc: FloatArray | None = None

    @property
    def start(self) -> FloatArray:
        return self.path.start

    @property
    def target(self) -> FloatArray:
        return self.path.target

    def law(self, t0: float, s0: float = 0.0) -> Trapezoid:
        return Trapezoid(t0, s0, self.vmax, self.acc, self.dec)


def _s_limits(
    dq: FloatArray, vmax: FloatArray, amax: FloatArray, dmax: FloatArray
) -> tuple[float, float, float]:
    moving = np.abs(dq) > 1e-12
    if not np.any(moving):
        return math.inf, math.inf, math.inf
    a = np.abs(dq[moving])
    return (
        float(np.min(vmax[moving] / a)),
        float(np.min(amax[moving] / a)),
        float(np.min(dmax[moving] / a)),
    )


def joint_limits_of(
    model: RobotModel, desc: MotionDesc
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Joint (speed, accel, decel) limits (6,) deg/s, deg/s^2 under ``desc``."""
    v, a = nominal_limits(model.name)
    return v * desc.joint_speed / 100.0, a * desc.joint_accel / 100.0, a * desc.joint_decel / 100.0


def plan_joint(
    move_id: int, model: RobotModel, start: FloatArray, target: FloatArray, desc: MotionDesc
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


def singular_measures(
    model: RobotModel, q: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """|sin θ5|, |sin θ3| and |r| / reach (N,) of joints (N, 6) deg: the distances from
    the wrist, elbow and shoulder singularities that ``SINGULAR_MARGIN`` bounds."""
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
    start: FloatArray,
    tool2base_target: FloatArray,
    tool2flange: FloatArray,
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
    s5, s3, rr = singular_measures(model, q)
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
