"""Robot-side trigger/data bookkeeping of the synchronisation (paper section V), pure.

The robot sends trigger i at t_i^T and logs it; sensor data for i arrives later. Once the
joint buffer covers t_i^S = t_i^T + ΔT (eq. 4), the joints are interpolated (eq. 5) and the
seam point is formed (eqs. 2-3). Nothing here opens a socket or reads a clock: the caller
passes ``now`` (seconds, robot clock) and the joint buffer.

Defined behaviour per datagram (the paper: "if a packet does not arrive it is ignored"):

=============  ==========================================================  ================
case           rule                                                        counter
=============  ==========================================================  ================
accepted       data for a sent index, within ``timeout_s`` of its trigger  ``accepted``
reordered      accepted data for i after data for a higher index           ``reordered``
not found      accepted data whose status is not FOUND: no seam, no        ``not_found``
               point in the trajectory (the index is resolved, a gap)
lost           no data within ``timeout_s`` of the trigger                 ``lost``
late           data for an index already declared lost: dropped            ``late``
duplicate      second data for an index: dropped, the first one counts     ``duplicate``
unknown        data for an index never sent: dropped                       ``unknown``
stale          data for an index older than the retained history, so it    ``stale``
               cannot be told apart as late or duplicate: dropped
expired        t_i^S has already left the joint buffer: dropped            ``expired``
invalid        FOUND status with a non-finite seam pose: dropped (the      ``invalid``
               index stays open and may still become lost)
=============  ==========================================================  ================

Data with t_i^S newer than the latest joint sample waits (it is never extrapolated).

Late exposures [SY-3.8]. A found reading whose sensor-clock lag from trigger arrival to
exposure start exceeds the sensor's usual lag (the median of recent readings,
:class:`~sync.exposure_lag.ExposureLag`) by more than its threshold was exposed late (the
chip was still busy with the previous frame): it is placed at t_i^T + ΔT + that extra lag,
counted as ``exposed_late``. Every other reading keeps t_i^T + ΔT exactly.

Ordering. Points are released strictly in index order: a point waits until every lower index
is resolved (point, not found, lost or expired), so the concatenated output of :meth:`poll`
is the seam trajectory ordered by index whatever the arrival order ("only the order of
incoming seam locations needs to be known"). A lost datagram delays release by at most
``timeout_s``.

Index wrap-around. Indices are u32 on the wire. They are unwrapped to a 64-bit sequence
number by serial-number arithmetic (RFC 1982): an index is read as the one nearest to the
last trigger sent, within ±2^31. Triggers must be sent with increasing serial indices.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinematics.transforms import location_to_transform
from spec.datagrams import INDEX_MODULUS, SensorData, serial_diff
from spec.wire import SensorStatus
from sync.exposure_lag import ExposureLag
from sync.interpolate import InterpStatus, interpolate_joints, lerp_inside
from sync.joint_buffer import JointBuffer
from sync.seam_chain import FlangeToBase, seam2base

__all__ = [
    "DataOutcome",
    "MatcherCounters",
    "MatcherError",
    "SeamPoint",
    "SyncMatcher",
    "TriggerLog",
]

# interpolation outcomes as plain ints: IntEnum member access costs ~1 µs a time
_OK, _TOO_OLD, _NOT_YET = int(InterpStatus.OK), int(InterpStatus.TOO_OLD), int(InterpStatus.NOT_YET)


class MatcherError(ValueError):
    """A caller mistake: bad trigger order, bad shapes or times. Peer mistakes never raise."""


def _location_transform(seam: Sequence[float]) -> NDArray[np.float64] | None:
    """^S_G T (4, 4) of a data datagram's VAL3 location (mm, deg); None when not finite (a
    peer fault, counted as invalid: a peer's data never raises)."""
    if len(seam) != 6:
        raise MatcherError(f"a seam location has 6 values, got {len(seam)}")
    # A decoded datagram's location is 6 Python floats: checked without numpy.
    if all(type(v) is float for v in seam):
        return location_to_transform(seam) if all(math.isfinite(v) for v in seam) else None
    loc = np.asarray(seam, dtype=np.float64)
    return location_to_transform(loc) if np.isfinite(loc).all() else None


@dataclass(frozen=True)
class SeamPoint:
    """One synchronised seam measurement.

    ``joints`` (6,) degrees at ``t_sensor`` = t_i^T + ΔT (+ ``extra_lag_s``) (s);
    ``seam2sensor`` and ``seam2base`` (4, 4) mm; ``seam2base`` is ``None`` when the matcher
    has no kinematics. ``sensor_times``: the datagram's (trigger arrival, exposure start,
    exposure end), s on the sensor's clock (only their difference is used, for the extra lag
    of a late exposure [SY-3.8]: the sensor clock is not the robot's). ``extra_lag_s``: 0.0,
    or for a reading exposed late the lag it was placed later by.
    """

    index: int
    t_trigger: float
    t_sensor: float
    joints: NDArray[np.float64]
    seam2sensor: NDArray[np.float64]
    seam2base: NDArray[np.float64] | None
    quality: float
    sensor_times: tuple[float, ...]
    extra_lag_s: float = 0.0


class DataOutcome(Enum):
    """What :meth:`SyncMatcher.on_data` did with a datagram."""

    ACCEPTED = "accepted"
    DUPLICATE = "duplicate"
    LATE = "late"
    UNKNOWN = "unknown"
    STALE = "stale"
    INVALID = "invalid"


@dataclass
class MatcherCounters:
    """Exact counts since the matcher was created (see the module table).

    Invariant: ``triggers == points + not_found + lost + expired + pending``, where pending
    is triggers not yet resolved; and ``data == accepted + duplicate + late + unknown +
    stale + invalid``.
    """

    triggers: int = 0
    data: int = 0
    accepted: int = 0
    points: int = 0
    not_found: int = 0
    lost: int = 0
    late: int = 0
    duplicate: int = 0
    unknown: int = 0
    stale: int = 0
    reordered: int = 0
    expired: int = 0
    invalid: int = 0
    #: points placed later than t_i^T + ΔT by their extra exposure lag [SY-3.8] (included in
    #: ``points``, not a resolution of their own)
    exposed_late: int = 0


class _State(Enum):
    AWAITING = 0  # trigger sent, no data yet
    READY = 1  # data accepted, waiting for joints
    POINT = 2  # point formed, maybe not yet released
    NOT_FOUND = 3
    LOST = 4
    EXPIRED = 5


_RESOLVED = (_State.POINT, _State.NOT_FOUND, _State.LOST, _State.EXPIRED)


@dataclass(slots=True)
class _Entry:
    t_trigger: float
    state: _State = _State.AWAITING
    data: SensorData | None = None
    seam2sensor: NDArray[np.float64] | None = None
    point: SeamPoint | None = None
    extra_lag_s: float = 0.0


class TriggerLog:
    """Sent triggers by unwrapped sequence number, with u32 serial-number unwrapping."""

    def __init__(self) -> None:
        self.entries: dict[int, _Entry] = {}
        self.last_seq: int | None = None
        self.first_seq: int = 0
        self.last_t: float = -math.inf

    def unwrap(self, index: int) -> int | None:
        """Sequence number of u32 ``index`` nearest to the last trigger (None before any)."""
        if self.last_seq is None:
            return None
        return self.last_seq + serial_diff(index, self.last_seq)

    def add(self, index: int, t_trigger: float) -> int:
        """Record trigger ``index`` sent at ``t_trigger`` (s); returns its sequence number."""
        if not 0 <= index < INDEX_MODULUS:
            raise MatcherError(f"index must be a u32, got {index}")
        if not math.isfinite(t_trigger):
            raise MatcherError("trigger time must be finite")
        if t_trigger < self.last_t:
            raise MatcherError(f"trigger time {t_trigger} is before the previous {self.last_t}")
        if self.last_seq is None:
            seq = self.first_seq = index
        else:
            seq = self.last_seq + serial_diff(index, self.last_seq)
            if seq <= self.last_seq:
                raise MatcherError(f"trigger index {index} is not after the previous one")
        self.entries[seq] = _Entry(t_trigger)
        self.last_seq = seq
        self.last_t = t_trigger
        return seq


@dataclass(eq=False)
class SyncMatcher:
    """Matches sensor data to sent triggers and joint samples; releases points in order.

    Args:
        delta_t_s: ΔT of eq. 4, seconds.
        timeout_s: data later than this after its trigger counts as lost (then late).
        flange2base: optional batch DGM (M, 6) degrees -> (M, 4, 4); with ``sensor2flange``
            it gives each point its ``seam2base`` (eqs. 2-3).
        sensor2flange: ^N_S T (4, 4), mm.
        history: resolved indices remembered for duplicate/late detection.
        keep_trajectory: also keep every released point for :meth:`trajectory`. Off by
            default: a long-running matcher would otherwise grow by one point per trigger
            (about 1 GB an hour at 250 Hz); turn it on only for a bounded recording.
        exposure_lag: the sensor's usual trigger-to-exposure lag and its threshold, which
            tell a reading exposed late [SY-3.8] (default :class:`ExposureLag`: 0.5 ms over
            the median of the last 64 found readings; its ``max_lag_s`` is the loss timeout).
    """

    delta_t_s: float
    timeout_s: float = 0.1
    flange2base: FlangeToBase | None = None
    sensor2flange: ArrayLike | None = None
    history: int = 4096
    keep_trajectory: bool = False
    counters: MatcherCounters = field(default_factory=MatcherCounters)
    exposure_lag: ExposureLag | None = None

    def __post_init__(self) -> None:
        if not math.isfinite(self.delta_t_s):
            raise MatcherError("delta_t_s must be finite")
        if not (math.isfinite(self.timeout_s) and self.timeout_s > 0):
            raise MatcherError("timeout_s must be positive")
        if self.history < 1:
            raise MatcherError("history must be >= 1")
        if (self.flange2base is None) != (self.sensor2flange is None):
            raise MatcherError("give both flange2base and sensor2flange, or neither")
        if self.exposure_lag is None:
            self.exposure_lag = ExposureLag(max_lag_s=self.timeout_s)
        self._lag = self.exposure_lag
        self._sensor2flange: NDArray[np.float64] | None = None
        if self.sensor2flange is not None:
            sensor2flange = np.asarray(self.sensor2flange, dtype=np.float64)
            if sensor2flange.shape != (4, 4):
                raise MatcherError(f"sensor2flange must be 4x4, got {sensor2flange.shape}")
            self._sensor2flange = sensor2flange
        self._log = TriggerLog()
        self._release_seq: int | None = None  # lowest sequence number not yet released
        self._awaiting: dict[int, None] = {}  # ordered set, by trigger time = by seq
        self._ready: dict[int, None] = {}
        self._max_data_seq: int | None = None
        self._trajectory: list[SeamPoint] = []

    # -- inputs ------------------------------------------------------------------------------

    def on_trigger(self, index: int, t_trigger: float) -> None:
        """Log trigger ``index`` (u32) sent at ``t_trigger`` (s, robot clock)."""
        seq = self._log.add(index, t_trigger)
        if self._release_seq is None:
            self._release_seq = seq
        self._awaiting[seq] = None
        self.counters.triggers += 1

    def on_data(self, data: SensorData, now: float) -> DataOutcome:
        """Take one sensor data datagram received at ``now`` (s, robot clock). Only a FOUND
        one's ``seam`` is read; the sensor's timestamps are carried through to the point."""
        seam2sensor = None
        finite = True
        if data.status == SensorStatus.FOUND:
            seam2sensor = _location_transform(data.seam)
            finite = seam2sensor is not None
        self._expire_lost(now)
        self.counters.data += 1
        if not finite:
            # A peer fault, not a caller one: count and drop; the index may still be lost.
            self.counters.invalid += 1
            return DataOutcome.INVALID
        seq = self._log.unwrap(data.index % INDEX_MODULUS)
        outcome = self._classify(seq)
        if outcome is not DataOutcome.ACCEPTED:
            return outcome
        assert seq is not None
        entry = self._log.entries[seq]
        del self._awaiting[seq]
        self.counters.accepted += 1
        if self._max_data_seq is not None and seq < self._max_data_seq:
            self.counters.reordered += 1
        else:
            self._max_data_seq = seq
        entry.data = data
        if seam2sensor is None:
            entry.state = _State.NOT_FOUND
            self.counters.not_found += 1
        else:
            entry.seam2sensor = seam2sensor
            entry.extra_lag_s = self._lag.extra(data.t_arrival, data.t_exposure_start)
            entry.state = _State.READY
            self._ready[seq] = None
        return DataOutcome.ACCEPTED

    def _classify(self, seq: int | None) -> DataOutcome:
        counters = self.counters
        log = self._log
        if seq is None or log.last_seq is None or seq > log.last_seq or seq < log.first_seq:
            counters.unknown += 1
            return DataOutcome.UNKNOWN
        entry = log.entries.get(seq)
        if entry is None:
            counters.stale += 1
            return DataOutcome.STALE
        if entry.state is _State.AWAITING:
            return DataOutcome.ACCEPTED
        if entry.state is _State.LOST:
            counters.late += 1
            return DataOutcome.LATE
        counters.duplicate += 1
        return DataOutcome.DUPLICATE

    def _expire_lost(self, now: float) -> None:
        if not math.isfinite(now):
            raise MatcherError("now must be finite")
        entries = self._log.entries
        for seq in list(self._awaiting):
            entry = entries[seq]
            # Awaiting entries are in trigger-time order: stop at the first one still in time.
            if now - entry.t_trigger <= self.timeout_s:
                break
            entry.state = _State.LOST
            self.counters.lost += 1
            del self._awaiting[seq]

    # -- processing --------------------------------------------------------------------------

    def poll(self, now: float, joints: JointBuffer) -> list[SeamPoint]:
        """Declare lost triggers, match ready data against ``joints``, release points.

        Returns the newly released points in index order (possibly empty).
        """
        self._expire_lost(now)
        if self._ready:
            self._match(joints)
        return self._release()

    def _match(self, joints: JointBuffer) -> None:
        entries = self._log.entries
        seqs = list(self._ready)
        d = self.delta_t_s
        t_list = [entries[s].t_trigger + d for s in seqs]  # eq. 4
        for i, s in enumerate(seqs):
            if entries[s].extra_lag_s:  # exposed late [SY-3.8]: the data is late, not wrong
                t_list[i] += entries[s].extra_lag_s
        t_lo, t_hi = min(t_list), max(t_list)
        t_s = np.array(t_list)
        times, q = joints.covering(t_lo)
        status: list[int]
        if len(times) >= 2 and times[0] <= t_lo and t_hi <= times[-1]:
            # the usual case, every t_i^S inside the buffer: the same interpolation without
            # the checks and status bookkeeping (per datagram these cost more than the maths)
            values = lerp_inside(times, q, t_s)
            status = [_OK] * len(seqs)
            ok = list(range(len(seqs)))
        else:
            values, status_arr = interpolate_joints(times, q, t_s)
            status = status_arr.tolist()
            ok = [i for i, st in enumerate(status) if st == _OK]
        in_base: NDArray[np.float64] | None = None  # seam2base of the OK queries (eqs. 2-3)
        if ok and self.flange2base is not None and self._sensor2flange is not None:
            if len(ok) == 1:  # one datagram per cycle, the usual: no np.stack
                seam2sensor = self._seam2sensor(entries[seqs[ok[0]]])[None]
            else:
                seam2sensor = np.stack([self._seam2sensor(entries[seqs[i]]) for i in ok])
            in_base = seam2base(values[ok], self.flange2base, self._sensor2flange, seam2sensor)
        row = 0
        for i, st in enumerate(status):
            if st == _NOT_YET:
                continue
            seq = seqs[i]
            entry = entries[seq]
            del self._ready[seq]
            if st == _TOO_OLD:
                entry.state = _State.EXPIRED
                self.counters.expired += 1
                continue
            data = entry.data
            assert data is not None and entry.seam2sensor is not None
            entry.point = SeamPoint(
                index=data.index % INDEX_MODULUS,
                t_trigger=entry.t_trigger,
                t_sensor=t_list[i],
                joints=values[i],
                seam2sensor=entry.seam2sensor,
                seam2base=None if in_base is None else in_base[row],
                quality=float(data.quality),
                sensor_times=(data.t_arrival, data.t_exposure_start, data.t_exposure_end),
                extra_lag_s=entry.extra_lag_s,
            )
            row += 1
            entry.state = _State.POINT
            self.counters.points += 1
            if entry.extra_lag_s:
                self.counters.exposed_late += 1

    @staticmethod
    def _seam2sensor(entry: _Entry) -> NDArray[np.float64]:
        assert entry.seam2sensor is not None  # READY entries always carry one
        return entry.seam2sensor

    def _release(self) -> list[SeamPoint]:
        out: list[SeamPoint] = []
        entries = self._log.entries
        seq = self._release_seq
        if seq is None:
            return out
        while True:
            entry = entries.get(seq)
            if entry is None or entry.state not in _RESOLVED:
                break
            if entry.point is not None:
                out.append(entry.point)
            # Released: only the state stays, for duplicate and late detection.
            entry.point = entry.data = entry.seam2sensor = None
            seq += 1
        self._release_seq = seq
        # Forget resolved entries beyond the history; never an unresolved one.
        while len(entries) > self.history:
            oldest = next(iter(entries))
            if oldest >= seq:
                break
            del entries[oldest]
        if self.keep_trajectory:
            self._trajectory.extend(out)
        return out

    # -- outputs -----------------------------------------------------------------------------

    @property
    def pending(self) -> int:
        """Triggers not yet resolved (awaiting data or waiting for joints)."""
        return len(self._awaiting) + len(self._ready)

    def retained(self) -> dict[str, int]:
        """Items held by the long-lived structures: logged triggers (at most ``history``
        resolved ones plus the unresolved) and kept trajectory points."""
        return {"trigger_log": len(self._log.entries), "trajectory": len(self._trajectory)}

    def trajectory(self) -> list[SeamPoint]:
        """Every released point so far, in index order (needs ``keep_trajectory``)."""
        return list(self._trajectory)

    def trajectory_arrays(
        self,
    ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        """Released points as arrays: indices (M,), t_sensor (M,) s, seam2base (M, 4, 4) mm.

        Without kinematics the transforms are NaN.
        """
        pts: Sequence[SeamPoint] = self._trajectory
        idx = np.array([p.index for p in pts], dtype=np.int64)
        ts = np.array([p.t_sensor for p in pts], dtype=np.float64)
        base = np.full((len(pts), 4, 4), np.nan)
        for n, p in enumerate(pts):
            if p.seam2base is not None:
                base[n] = p.seam2base
        return idx, ts, base
