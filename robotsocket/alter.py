"""Path correction of a running motion (alter mode, PROTOCOL.md RS-5.32 ... RS-5.38), pure.

Modelled on Stäubli VAL3's ``alterBegin`` / ``alter`` / ``alterEnd`` and on the 4 ms
correction streams of KUKA RSI and ABB EGM: the client sends the *whole* correction in force
(absolute, not an increment, so a lost or late message costs nothing but time) and the robot
moves the applied correction towards it every cycle within a size, speed and acceleration
limit. A correction that stops coming is held, never extrapolated; after ``timeout`` seconds
without one the stream is declared lost (the emulator then switches the laser off, stops the
motion along its path and ramps the correction back to zero).

The correction is a translation (mm) and a rotation vector (deg) in the base frame, applied
to the tool: the tool point moves by the translation and the tool turns about its own point.
Nothing here reads a clock: :meth:`AlterState.step` takes the cycle time.
"""

from __future__ import annotations

import math

import numpy as np

from kinematics.transforms import invert
from kinematics.types import FloatArray
from robotsocket.alter_queue import CorrectionQueue, QueueReport, check_batch
from robotsocket.interface import BadStateError, OutOfRangeError

#: [RS-5.33] Largest correction: translation (mm) and rotation (deg).
MAX_OFFSET_MM = 10.0
MAX_ROTATION_DEG = 2.0
#: [RS-5.34] Largest speed and acceleration of the applied correction.
MAX_SPEED_MM_S = 100.0
MAX_ACCEL_MM_S2 = 10_000.0
MAX_ROT_SPEED_DEG_S = 40.0
MAX_ROT_ACCEL_DEG_S2 = 4_000.0
#: [RS-5.36] Accepted stream timeouts (s).
MIN_TIMEOUT = 0.008
MAX_TIMEOUT = 1.0
#: Below this (mm, deg) the applied correction counts as zero.
_EPS = 1e-9


def check_correction(correction: FloatArray) -> FloatArray:
    """The correction (6,) ``dx, dy, dz, rx, ry, rz`` (mm, deg), or OutOfRangeError [RS-5.33]."""
    c = np.asarray(correction, dtype=np.float64)
    if c.shape != (6,) or not np.all(np.isfinite(c)):
        raise OutOfRangeError("correction: expected 6 finite numbers")
    if np.linalg.norm(c[:3]) > MAX_OFFSET_MM + 1e-9:
        raise OutOfRangeError(
            f"correction translation {np.linalg.norm(c[:3]):.3f} mm exceeds {MAX_OFFSET_MM} mm"
        )
    if np.linalg.norm(c[3:]) > MAX_ROTATION_DEG + 1e-9:
        raise OutOfRangeError(
            f"correction rotation {np.linalg.norm(c[3:]):.3f} deg exceeds {MAX_ROTATION_DEG} deg"
        )
    return c


def _rotvec_matrix(r_deg: FloatArray) -> FloatArray:
    """Rotation matrix (3, 3) of a rotation vector in degrees (Rodrigues)."""
    theta = math.radians(float(np.linalg.norm(r_deg)))
    if theta < 1e-12:
        return np.eye(3)
    k = np.radians(r_deg) / theta
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    out: FloatArray = np.eye(3) + math.sin(theta) * K + (1.0 - math.cos(theta)) * (K @ K)
    return out


def corrected_flange(
    flange2base: FloatArray, tool2flange: FloatArray, correction: FloatArray
) -> FloatArray:
    """Flange pose (4, 4) that puts the tool where ``correction`` (6,) moves it: the tool
    point translated by correction[:3] (base frame) and the tool turned about its own point
    by the rotation vector correction[3:] (deg, base frame)."""
    tool2base = flange2base @ tool2flange
    moved = np.eye(4)
    moved[:3, :3] = _rotvec_matrix(correction[3:]) @ tool2base[:3, :3]
    moved[:3, 3] = tool2base[:3, 3] + correction[:3]
    out: FloatArray = moved @ invert(tool2flange)
    return out


def _limit(
    error: FloatArray, v: FloatArray, v_ff: FloatArray, vmax: float, amax: float, dt: float
) -> FloatArray:
    """Velocity (n,) for the next cycle: the target's own velocity ``v_ff`` (n,) plus a
    velocity towards what remains of ``error`` (n,), braking in time to stop at the target;
    no faster than vmax and with a speed change of at most amax * dt."""
    rest = error - v_ff * dt
    dist = float(np.linalg.norm(rest))
    if dist < _EPS:
        v_want = v_ff.copy()
    else:
        # fastest speed from which braking at amax (one cycle of reaction) stops by the
        # target on the 4 ms grid: v * dt + v^2 / (2 amax) = dist
        brake = -amax * dt + math.sqrt((amax * dt) ** 2 + 2.0 * amax * dist)
        speed = min(vmax, brake, dist / dt)
        v_want = v_ff + rest / dist * speed
    n_want = float(np.linalg.norm(v_want))
    if n_want > vmax:
        v_want = v_want * (vmax / n_want)
    dv = v_want - v
    n = float(np.linalg.norm(dv))
    if n > amax * dt:
        dv = dv * (amax * dt / n)
    out: FloatArray = v + dv
    return out


class AlterState:
    """Alter mode of one robot: commanded and applied correction, limits and the stream timer.

    ``period`` the controller cycle (s). Call :meth:`step` once per cycle with its time.
    """

    def __init__(self, period: float) -> None:
        self.period = period
        self.active = False  # between AlterBegin and AlterEnd (or a lost stream)
        self.tool2flange = np.eye(4)
        self.timeout = 0.1
        self.target = np.zeros(6)
        self.applied = np.zeros(6)
        self._v = np.zeros(6)
        self._last_target = np.zeros(6)
        self._last_rx = 0.0
        self.lost = 0  # streams declared lost (statistics)
        self.queue = CorrectionQueue()  # timed corrections [RS-5.39]

    @property
    def engaged(self) -> bool:
        """A correction is applied or still changing (the setpoint is corrected)."""
        # plain Python on six values: asked every cycle (the clock's idle test), where four
        # numpy reductions cost ~20 us
        return (
            self.active
            or max(map(abs, self.applied.tolist())) > _EPS
            or max(map(abs, self._v.tolist())) > _EPS
        )

    def begin(self, tool: FloatArray, timeout: float, now: float) -> None:
        """[RS-5.32] Start alter mode for ``tool`` (4, 4) with the stream ``timeout`` (s)."""
        if self.active:
            raise BadStateError("alter mode already active: AlterEnd first")
        if not (math.isfinite(timeout) and MIN_TIMEOUT <= timeout <= MAX_TIMEOUT):
            raise OutOfRangeError(
                f"alter timeout must be in [{MIN_TIMEOUT}, {MAX_TIMEOUT}] s, got {timeout}"
            )
        if self.engaged:
            raise BadStateError("the previous correction is still ramping back to zero")
        self.active = True
        self.tool2flange = np.array(tool, dtype=np.float64)
        self.timeout = timeout
        self.target = np.zeros(6)
        self._last_rx = now
        self.queue.clear()
        self.queue.applied_until = now  # entries for this cycle or before are late

    def command(self, correction: FloatArray, now: float) -> FloatArray:
        """[RS-5.33] A new correction in force; returns the applied correction (6,)."""
        if not self.active:
            raise BadStateError("alter mode is not active: AlterBegin first")
        if self.queue.depth:
            # [RS-5.46] the two would fight over the target
            raise BadStateError("timed corrections are queued: Alter is refused until AlterEnd")
        self.target = check_correction(correction)
        self._last_rx = now
        return self.applied.copy()

    def enqueue(self, times: FloatArray, corrections: FloatArray) -> QueueReport:
        """[RS-5.39] Queue timed corrections ``corrections`` (N, 6) for the robot-clock
        ``times`` (N,); an empty batch only reports the queue's state."""
        if not self.active:
            raise BadStateError("alter mode is not active: AlterBegin first")
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        c = np.asarray(corrections, dtype=np.float64)
        check_batch(t, c, MAX_OFFSET_MM, MAX_ROTATION_DEG)
        return self.queue.insert(t, c.reshape(len(t), 6))

    def end(self) -> None:
        """[RS-5.37] End alter mode: the correction ramps back to zero within the limits."""
        if not self.active:
            raise BadStateError("alter mode is not active")
        self.active = False
        self.target = np.zeros(6)
        self.queue.clear()

    def abandon(self) -> None:
        """Control lost or stream lost: end alter mode, ramp the correction back to zero."""
        self.active = False
        self.target = np.zeros(6)
        self.queue.clear()

    def fold(self) -> None:
        """Emergency stop: the arm stops where it is; the correction is dropped, not ramped
        (the caller keeps the corrected joints as the hold position)."""
        self.active = False
        self.target = np.zeros(6)
        self.applied = np.zeros(6)
        self._v = np.zeros(6)
        self._last_target = np.zeros(6)
        self.queue.clear()

    def step(self, now: float) -> bool:
        """Advance the applied correction one cycle; True when the stream was just declared
        lost [RS-5.36] (the caller stops the motion safely)."""
        if self.active:
            due = self.queue.due(now)  # [RS-5.44] the timed correction of this cycle
            if due is not None:
                self.target = due
        # [RS-5.36] [RS-5.44] a correction is in force while an Alter is fresh or a queued
        # entry is due: the stream is lost `timeout` after the later of the two
        lost = self.active and now - max(self._last_rx, self.queue.horizon) > self.timeout + 1e-9
        if lost:
            self.lost += 1
            self.abandon()
        dt = self.period
        err = self.target - self.applied
        # how far the target moved since the last cycle: a stream of corrections moving at
        # constant speed is followed without lag; a held target has none [RS-5.35]
        v_ff = (self.target - self._last_target) / dt
        self._last_target = self.target.copy()
        self._v[:3] = _limit(err[:3], self._v[:3], v_ff[:3], MAX_SPEED_MM_S, MAX_ACCEL_MM_S2, dt)
        self._v[3:] = _limit(
            err[3:], self._v[3:], v_ff[3:], MAX_ROT_SPEED_DEG_S, MAX_ROT_ACCEL_DEG_S2, dt
        )
        self.applied = self.applied + self._v * dt
        if (
            not self.active
            and np.all(np.abs(self.applied) < 1e-6)
            and np.all(np.abs(self._v) < 1e-6)
        ):
            self.applied = np.zeros(6)
            self._v = np.zeros(6)
        return lost
