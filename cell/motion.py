"""The arm's true motion as the cell's camera sees it: sensor poses between setpoints (pure).

The robot emulator appends its setpoint every 4 ms cycle (:meth:`TrueMotion.append`); the
camera asks for the sensor pose ^B_S T at the time of each column it reads, per time
(:meth:`TrueMotion.sensor2base`) or as a few node poses with weights
(:meth:`TrueMotion.node_poses`, a :class:`~sensorsocket.scene.NodePoseProvider`). Between
setpoints the arm follows the joint-space line, so the exact pose is the DGM of the
linearly interpolated joints; the poses here are exact at the setpoints and at mid-cycle and
quadratic between (~1e-11 mm from the exact pose over a 10 s run). Past the latest setpoint
(the real-time cell) the joints are extrapolated.
"""

from __future__ import annotations

import bisect
import threading
from collections.abc import Callable, Sequence

import numpy as np

from kinematics.types import FloatArray
from sync.interpolate import InterpStatus, interpolate_joints
from sync.joint_buffer import JointBuffer

__all__ = ["TrueMotion"]


class TrueMotion:
    """Sensor poses of the arm's true motion (the setpoints, not the delayed measured
    joints); thread-safe: the robot's cycle appends while the camera reads.

    Args:
        flange2base: batch DGM, joints (N, 6) deg -> ^B_N T (N, 4, 4) mm.
        sensor2flange: ^N_S T (4, 4) mm.
        period_s: the robot's setpoint period (4 ms).
        start_joints: the joints at time 0 (deg).
    """

    def __init__(
        self,
        flange2base: Callable[[FloatArray], FloatArray],
        sensor2flange: FloatArray,
        period_s: float,
        start_joints: Sequence[float],
    ) -> None:
        self._flange2base = flange2base
        self.sensor2flange = sensor2flange
        #: Called with the query times before a read: the real-time cell waits there for
        #: the setpoints that cover an exposure (:meth:`cell.cell.EmulatedCell.wait_for_truth`).
        self.before_read: Callable[[FloatArray], None] | None = None
        self._period = period_s
        self._lock = threading.Lock()
        self.truth = JointBuffer(capacity=2000)
        self.truth.append(0.0, np.asarray(start_joints, dtype=np.float64))
        # sensor poses at the latest frame's setpoints and mid-cycles, see _node_poses
        self._nodes: tuple[list[float], FloatArray, FloatArray] = (
            [], np.empty((0, 6)), np.empty((0, 16)),
        )  # fmt: skip
        # node coordinates 0, 1, 2, ... as a column, for node_poses
        self._node_at = np.arange(64, dtype=np.float64)[:, None]
        # per node (setpoint, mid-cycle, ...): the support's half width and the slope of the
        # weight's second factor, see node_poses
        self._node_cap = np.empty((2, 64, 1))
        self._node_cap[0] = np.where(np.arange(64) % 2, 1.0, 2.0)[:, None]
        self._node_cap[1] = np.where(np.arange(64) % 2, 1.0, -0.5)[:, None]

    def append(self, t: float, q_setpoint: FloatArray) -> None:
        """The setpoint (6,) deg of the cycle at robot time ``t`` s."""
        with self._lock:
            self.truth.append(t, q_setpoint)

    def __call__(self, times: FloatArray) -> FloatArray:
        return self.sensor2base(times)

    def sensor2base(self, times: FloatArray) -> FloatArray:
        """True sensor poses (N, 4, 4) at robot-clock ``times`` (N,) s: the setpoints,
        linear between cycles, extrapolated past the latest one."""
        t = np.asarray(times, dtype=np.float64)
        if not len(t):
            return np.empty((0, 4, 4))
        if self.before_read is not None:
            self.before_read(t)
        t_min, t_max = float(t.min()), float(t.max())
        with self._lock:
            # Only the samples around the query: the interval of the earliest query time and
            # at least the last three samples (extrapolation), not the whole 8 s buffer.
            buf_t, buf_q = self.truth.covering(t_min - 2.0 * self._period)
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
        return self.setpoint_poses(q)

    def node_poses(self, times: FloatArray) -> tuple[FloatArray, FloatArray] | None:
        """The poses of :meth:`sensor2base` at ``times`` (N,) s as node poses (M, 16) and
        weights (M, N) (:class:`~sensorsocket.scene.NodePoseProvider`): the setpoints that
        bracket the times and the mid-cycles between them, with each time's quadratic
        Lagrange weights. None when a time lies outside the known setpoints."""
        t = np.asarray(times, dtype=np.float64)
        if not len(t):
            return None
        if self.before_read is not None:
            self.before_read(t)
        t_min, t_max = float(np.minimum.reduce(t)), float(np.maximum.reduce(t))
        with self._lock:
            buf_t, buf_q = self.truth.covering(t_min - 2.0 * self._period)
        bt = buf_t.tolist()  # a few samples: bisect on Python floats
        n = len(bt)
        if not (n >= 2 and bt[0] <= t_min and t_max <= bt[-1]):
            return None
        if t_max - t_min > 16 * self._period:
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

    def setpoint_poses(self, q: FloatArray) -> FloatArray:
        """^B_S T (N, 4, 4) mm at joints ``q`` (N, 6) deg."""
        f2b = self._flange2base(q)
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
                (c_p[2 * i : 2 * (i + k0) + 1], self.setpoint_poses(nodes).reshape(-1, 16))
            )
        else:
            nodes = np.empty((2 * m - 1, q.shape[1]))
            nodes[0::2] = q
            nodes[1::2] = 0.5 * (q[:-1] + q[1:])
            new = self.setpoint_poses(nodes).reshape(-1, 16)
        self._nodes = (times, q, new)  # one tuple: a reader never sees a half update
        return new


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
