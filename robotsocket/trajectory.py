"""The per-cycle trajectory generator, pure: planned moves in, one setpoint per cycle out.

Moves (:mod:`robotsocket.paths`: a path q(s) and the limits of its timing law) wait in a
queue; the generator runs each along its law (:mod:`robotsocket.profiles`). Stopping turns
the executing laws into decelerations, so the arm stops on its path. Blending superposes the
next move's displacement onto the current one's deceleration (overlap no longer than either
ramp, so each joint's speed stays within the larger of the two moves' speeds; accelerations
may add up to twice the limit during the overlap).

Nothing here reads a clock: :meth:`TrajectoryGenerator.step` takes the cycle index k and
returns the setpoint at t_k = k * period.
"""

from __future__ import annotations

import copy
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from kinematics.types import FloatArray
from robotsocket.paths import JointPath, Move
from robotsocket.profiles import TIME_EPS_S, Decel, Hold, Law, Trapezoid, ended

#: Controller cycle T_r in seconds (paper section V).
PERIOD = 0.004

#: Cartesian IK chunk: cycles solved in one vectorised call.
CHUNK = 32


@dataclass
class Segment:
    """A move being executed: its timing law and the last joints on its own path."""

    move: Move
    law: Law
    last_q: FloatArray
    cancelled: bool = False
    _cache_law: Law | None = None
    _cache_k0: int = 0
    _cache_q: FloatArray | None = None

    def q(self, k: int, period: float) -> FloatArray:
        """Joints (6,) of this segment's path at cycle k."""
        path = self.move.path
        if isinstance(path, JointPath):
            s, _ = self.law.at(k * period)
            if s >= 1.0:
                out: FloatArray = path.target
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

    def q_at_s(self, s: float) -> FloatArray:
        return np.asarray(self.move.path.q_at(np.array([s]), self.last_q)[0], dtype=np.float64)


class TrajectoryGenerator:
    """Per-cycle setpoints from a queue of planned moves (pure: the cycle index is input).

    ``step(k)`` must be called with k = previous k + 1. The first sample of a move started at
    cycle k already moves (its law starts at t_{k-1}, where the arm was).
    """

    def __init__(self, q0: FloatArray, period: float = PERIOD) -> None:
        self.period = period
        self.hold_q = np.array(q0, dtype=np.float64)
        self.last_q = self.hold_q.copy()
        self.queue: deque[Move] = deque()
        self.active: list[Segment] = []
        self.held = False  # StopMove in force
        self.k = 0
        self._reset_point: FloatArray | None = None
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

    def planned_end(self) -> FloatArray:
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

    def step(self, k: int) -> FloatArray:
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
                if t_prev >= law.t_end - overlap - TIME_EPS_S and t_prev >= self._blend_start(
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

    def _retire(self, t: float, q: FloatArray) -> None:
        active = self.active
        if all(s.cancelled for s in active):
            if all(ended(t, s.law.t_end) for s in active):
                self.hold_q = self._reset_point if self._reset_point is not None else q
                self._reset_point = None
                active.clear()
            return
        for seg in active:
            if isinstance(seg.law, Decel) and ended(t, seg.law.t_end):
                seg.law = Hold(seg.law.s_end)
        while active and isinstance(active[0].law, Trapezoid) and ended(t, active[0].law.t_end):
            done = active.pop(0)
            if not active:
                self.hold_q = done.move.target
