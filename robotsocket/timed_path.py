"""Timed Cartesian paths for ToolMoveTrajectory (PROTOCOL.md RS-5.23/5.24), pure.

The client gives times t_k (s, from the start of the move) and tool locations L_k in a frame;
the tool passes L_k at t_k, linear in between (e.g. the sine of the ΔT experiment, paper
section VI). Planning solves the IK for every location in the start configuration, unwraps
the joints continuously from the start joints and checks the whole path before anything
moves: times start at 0 and increase, one location per time, the first location is where
the tool is now, every point reachable and inside the joint limits, no singularity, and the
joint speeds and accelerations sampled at the controller period within the model's nominal
limits (100 %: the path's timing is explicit, so the mdesc percentages do not apply).

Execution reuses the generator's machinery: the timing law is s = t / T (a trapezoid with
infinite acceleration), and the path maps s to joints by linear interpolation of the
solved joints in time, so a path sampled on the 4 ms grid is tracked exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinematics.config import CONFIGS
from kinematics.robot import RobotModel
from kinematics.types import FloatArray
from robotsocket.interface import OutOfRangeError, SingularityError, UnreachableError
from robotsocket.paths import (
    MAX_GRID_STEP_DEG,
    SINGULAR_MARGIN,
    Move,
    nominal_limits,
    singular_measures,
    wrap180,
)
from robotsocket.trajectory import PERIOD

__all__ = ["START_TOLERANCE_DEG", "TimedPath", "plan_timed"]

START_TOLERANCE_DEG = 0.01
"""The first location must give joints this close (deg) to where the arm is."""


@dataclass(frozen=True)
class TimedPath:
    """Joints (N, 6) deg at times (N,) s; s in [0, 1] maps to t = s · times[-1]."""

    times: FloatArray
    joints: FloatArray

    @property
    def start(self) -> FloatArray:
        out: FloatArray = self.joints[0]
        return out

    @property
    def target(self) -> FloatArray:
        out: FloatArray = self.joints[-1]
        return out

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def at_times(self, t: FloatArray) -> FloatArray:
        """Joints (M, 6) at times t (M,) s, clamped to the path's ends."""
        tt = np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration)
        times = self.times
        k = np.clip(np.searchsorted(times, tt, side="right") - 1, 0, len(times) - 2)
        t0, t1 = times[k], times[k + 1]
        w = ((tt - t0) / (t1 - t0))[:, None]
        out: FloatArray = (1.0 - w) * self.joints[k] + w * self.joints[k + 1]
        return out

    def q_at(self, s: FloatArray, q_prev: FloatArray) -> FloatArray:
        return self.at_times(np.asarray(s, dtype=np.float64) * self.duration)


def plan_timed(
    move_id: int,
    model: RobotModel,
    start: FloatArray,
    times: FloatArray,
    tool2base: FloatArray,
    tool2flange: FloatArray,
    *,
    period: float = PERIOD,
) -> Move:
    """Plan a timed tool path from joints ``start`` (6,) deg.

    Args:
        times: (N,) s, times[0] == 0, strictly increasing, N >= 2.
        tool2base: (N, 4, 4) tool poses in the base frame (mm).
        tool2flange: (4, 4) the tool.

    Raises OutOfRangeError (times, counts, start mismatch, joint limits, speed or
    acceleration), UnreachableError or SingularityError.
    """
    t = np.asarray(times, dtype=np.float64)
    poses = np.asarray(tool2base, dtype=np.float64)
    if t.ndim != 1 or t.size < 2:
        raise OutOfRangeError("ToolMoveTrajectory needs at least 2 times")
    if poses.shape != (t.size, 4, 4):
        raise OutOfRangeError(f"{t.size} times but {poses.shape[0]} locations")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(poses))):
        raise OutOfRangeError("times and locations must be finite")
    if t[0] != 0.0 or not np.all(np.diff(t) > 0):
        raise OutOfRangeError("times must start at 0 and increase")
    if t[-1] > 3600.0:
        raise OutOfRangeError("a timed path may last at most 3600 s")
    start = np.asarray(start, dtype=np.float64)
    flange = poses @ np.linalg.inv(tool2flange)
    branch = CONFIGS.index(model.config_of(start))
    batch = model.ik_batch(flange, near=start)
    q = np.array(batch.joints_deg[:, branch, :])
    if not np.all(batch.reachable[:, branch]):
        k = int(np.argmin(batch.reachable[:, branch]))
        raise UnreachableError(f"location {k} (t = {t[k]:.3f} s) is out of reach")
    if not np.all(batch.valid[:, branch]):
        k = int(np.argmin(batch.valid[:, branch]))
        raise OutOfRangeError(f"location {k} (t = {t[k]:.3f} s) needs joints outside the limits")
    steps = wrap180(np.diff(np.vstack([start, q]), axis=0))
    q = start + np.cumsum(steps, axis=0)
    if float(np.max(np.abs(q[0] - start))) > START_TOLERANCE_DEG:
        raise OutOfRangeError("the path must start at the tool's current location")
    q[0] = start
    if not bool(np.all(model.within_limits(q))):
        raise OutOfRangeError("the path needs joints outside the limits")
    if q.shape[0] > 1 and float(np.max(np.abs(np.diff(q, axis=0)))) > MAX_GRID_STEP_DEG:
        raise SingularityError("the path flips the wrist between two locations")
    s5, s3, rr = singular_measures(model, q)
    if min(float(s5.min()), float(s3.min()), float(rr.min())) < SINGULAR_MARGIN:
        raise SingularityError("the path crosses a singularity")
    path = TimedPath(t, q)
    # Speeds and accelerations as the generator will produce them: on the controller grid,
    # at rest before the start and after the end.
    n = math.ceil(path.duration / period - 1e-9)
    grid = np.minimum(np.arange(n + 1) * period, path.duration)
    qg = path.at_times(grid)
    qg = np.vstack([qg[:1], qg, qg[-1:]])
    vel = np.diff(qg, axis=0) / period
    acc = np.diff(vel, axis=0) / period
    vmax, amax = nominal_limits(model.name)
    v_ratio = np.max(np.abs(vel), axis=0) / vmax
    a_ratio = np.max(np.abs(acc), axis=0) / amax
    if float(v_ratio.max()) > 1.0:
        j = int(np.argmax(v_ratio))
        raise OutOfRangeError(f"the path needs {v_ratio[j]:.2f} x the speed limit of joint {j + 1}")
    if float(a_ratio.max()) > 1.0:
        j = int(np.argmax(a_ratio))
        raise OutOfRangeError(
            f"the path needs {a_ratio[j]:.2f} x the acceleration limit of joint {j + 1}"
        )
    length = float(np.sum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)))
    # s = t / T: a trapezoid with unbounded acceleration is exactly linear in time.
    return Move(move_id, "timed", path, 1.0 / path.duration, math.inf, math.inf, length, 0.0)
