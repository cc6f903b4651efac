"""Robot side of the UDP synchronisation (paper section V, PROTOCOL.md section 9).

Three layers, the lower ones pure (time is an input):

- :class:`TriggerScheduler` decides *when* triggers go out: at a fixed rate or at explicit
  robot-clock times, independent of the robot's 4 ms sample time (the paper stresses this).
- :class:`RobotSyncCore` is the robot's bookkeeping: it numbers and encodes triggers, records
  t_i^T, decodes data datagrams (counting malformed ones [SY-1.4]), feeds the
  :class:`~sync.matcher.SyncMatcher` (eq. 4-5, with its lost/late/duplicate/reordered/
  expired rules) and turns released points into rows of GetSeamPoints (eq. 2-3), kept in a
  bounded :class:`SeamRows`.
- :class:`UdpSyncEndpoint` is the thin thread: one UDP socket, triggers sent at their due
  time on a clock callable, data datagrams received and fed to the core.

The modelled network that drives the same core in simulated time is
:class:`sync.network.DelayLink`.
"""

from __future__ import annotations

import itertools
import logging
import math
import select
import socket
import threading
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kinematics.transforms import transforms_to_locations
from spec.auth import Network, address_allowed
from spec.datagrams import INDEX_MODULUS, SensorData, Trigger, decode_datagram, encode_trigger
from spec.errors import DatagramError
from spec.realtime import DEFAULT_RT_PRIORITY, promote_current_thread
from spec.registry import SEAM_POINT_COLUMNS
from spec.shells import register
from spec.udp import (
    arrival_time,
    bind_udp,
    enable_kernel_timestamps,
    enable_send_timestamps,
    recv_stamped,
    sent_stamp,
)
from spec.wire import SensorStatus
from sync.joint_buffer import JointBuffer
from sync.matcher import DataOutcome, SeamPoint, SyncMatcher
from sync.seam_chain import FlangeToBase, seam2base

__all__ = [
    "MAX_RATE_HZ",
    "RobotSyncCore",
    "SeamRows",
    "SyncStateError",
    "TriggerScheduler",
    "UdpSyncEndpoint",
]

log = logging.getLogger(__name__)

MAX_RATE_HZ = 1000.0
"""Highest trigger rate StartTriggers accepts [SY-5.3]."""

STAMP_TOLERANCE_S = 0.2e-3
"""A trigger whose send took longer than this after its stamp counts as an uncertain stamp
(:attr:`UdpSyncEndpoint.uncertain_stamps`)."""

_ROW_BATCH = 1024
"""Released points converted to seam-point rows in one batch at the latest."""

Clock = Callable[[], float]
JointSource = Callable[[float], tuple[NDArray[np.float64], NDArray[np.float64]]]
"""``joints_since(t) -> (times (N,) s, joints (N, 6) deg)`` with times > t."""


class SyncStateError(ValueError):
    """A caller mistake: a bad rate, non-increasing times, or triggering before an endpoint."""


class TriggerScheduler:
    """When to send triggers: a fixed rate (``count`` of them, 0 = until stopped) or explicit
    increasing times, seconds on the robot clock. Pure: :meth:`pop_due` takes ``now``."""

    def __init__(self) -> None:
        self._times: list[float] = []  # explicit schedule, increasing; consumed from _pos
        self._pos = 0
        self._rate = 0.0
        self._t_next = math.inf
        self._remaining = 0  # rate mode: triggers left, -1 = unlimited

    @property
    def active(self) -> bool:
        """True while triggers remain to be sent."""
        return self.next_due() is not None

    @property
    def rate(self) -> float:
        """The rate in force (Hz); 0 for an explicit schedule or when stopped."""
        return self._rate if self.active else 0.0

    def start_rate(self, rate_hz: float, count: int, t_first: float) -> None:
        """Send ``count`` triggers (0: until stopped) every 1/rate s from ``t_first`` (s)."""
        if not (math.isfinite(rate_hz) and 0.0 < rate_hz <= MAX_RATE_HZ):
            raise SyncStateError(f"rate must be in (0, {MAX_RATE_HZ:g}] Hz, got {rate_hz}")
        if count < 0:
            raise SyncStateError(f"count must be >= 0, got {count}")
        if not math.isfinite(t_first):
            raise SyncStateError("start time must be finite")
        self.stop()
        self._rate = float(rate_hz)
        self._t_first = float(t_first)
        self._n_sent = 0
        self._t_next = float(t_first)
        self._remaining = count if count > 0 else -1

    def schedule(self, times: Sequence[float]) -> None:
        """Send one trigger at each of ``times`` (s, strictly increasing); replaces any plan."""
        t = [float(x) for x in times]
        if not all(math.isfinite(x) for x in t):
            raise SyncStateError("trigger times must be finite")
        if any(b <= a for a, b in itertools.pairwise(t)):
            raise SyncStateError("trigger times must increase")
        self.stop()
        self._times = t

    def stop(self) -> None:
        """Drop every trigger not yet sent."""
        self._times = []
        self._pos = 0
        self._rate = 0.0
        self._t_next = math.inf
        self._remaining = 0

    def next_due(self) -> float | None:
        """Time (s) of the next trigger, ``None`` when nothing is planned."""
        if self._pos < len(self._times):
            return self._times[self._pos]
        if self._remaining != 0:
            return self._t_next
        return None

    def pop_due(self, now: float) -> list[float]:
        """Scheduled times <= ``now`` (s), in order; they count as sent."""
        out: list[float] = []
        while self._pos < len(self._times) and self._times[self._pos] <= now:
            out.append(self._times[self._pos])
            self._pos += 1
        while self._remaining != 0 and self._t_next <= now:
            out.append(self._t_next)
            self._n_sent += 1
            # t_first + n / rate, not repeated addition: no drift over long runs.
            self._t_next = self._t_first + self._n_sent / self._rate
            if self._remaining > 0:
                self._remaining -= 1
        return out


@dataclass
class _Stats:
    received: int = 0
    malformed: int = 0
    unexpected: int = 0


class SeamRows:
    """Seam-point rows (M, 17) (columns ``SEAM_POINT_COLUMNS``) in release order, which is
    index order, the newest ``capacity`` of them kept.

    Stored as the blocks of rows each flush makes (small ones merged up to ``_ROW_BATCH``),
    so a row costs its 17 floats, not an array object, and a read scans back over the
    blocks it returns instead of converting every row's index on each GetSeamPoints (which
    held the core's lock for milliseconds with 200,000 rows).
    """

    def __init__(self, capacity: int) -> None:
        if capacity < 0:
            raise SyncStateError(f"max_points must be >= 0, got {capacity}")
        self.capacity = capacity
        self._blocks: list[NDArray[np.float64]] = []
        self._count = 0

    def __len__(self) -> int:
        return self._count

    def append(self, rows: NDArray[np.float64]) -> None:
        """Add rows (M, 17) newer than every row held; drop the oldest beyond capacity."""
        if not len(rows):
            return
        blocks = self._blocks
        if blocks and len(blocks[-1]) + len(rows) <= _ROW_BATCH:
            blocks[-1] = np.concatenate((blocks[-1], rows))
        else:
            blocks.append(rows)
        self._count += len(rows)
        excess = self._count - self.capacity
        while excess > 0:
            first = blocks[0]
            if len(first) <= excess:
                del blocks[0]
                dropped = len(first)
            else:
                blocks[0] = first[excess:].copy()  # a copy frees the dropped rows
                dropped = excess
            self._count -= dropped
            excess -= dropped

    def since(self, since: int, limit: int) -> NDArray[np.float64]:
        """A copy of the rows with index > ``since``, oldest first, at most ``limit``."""
        blocks = self._blocks
        start = len(blocks)
        while start > 0 and blocks[start - 1][0, 0] > since:
            start -= 1
        parts: list[NDArray[np.float64]] = []
        if start > 0:  # the block before holds rows up to ``since`` and maybe a few after
            block = blocks[start - 1]
            k = int(np.searchsorted(block[:, 0], since, side="right"))
            parts.append(block[k:])
        parts.extend(blocks[start:])
        out: list[NDArray[np.float64]] = []
        need = max(limit, 0)
        for part in parts:
            if need <= 0:
                break
            if len(part):
                out.append(part[:need])
                need -= len(out[-1])
        if not out:
            return np.zeros((0, len(SEAM_POINT_COLUMNS)))
        return np.concatenate(out)


class RobotSyncCore:
    """The robot's synchronisation state, without I/O.

    Args:
        delta_t_s: ΔT of eq. 4 (s); change it with :meth:`set_delay`.
        flange2base: batch DGM (M, 6) deg -> (M, 4, 4) mm for the base-frame columns of the
            seam points (eq. 2-3); ``None`` leaves them NaN.
        sensor2flange: ^N_S T (4, 4) mm; settable attribute.
        timeout_s: loss timeout [SY-3.3].
        joint_capacity: samples of the joint buffer used for matching (10 s at 4 ms).
        max_points: seam points kept for GetSeamPoints (oldest dropped first).

    Thread-safe: every public method takes the core's lock.
    """

    def __init__(
        self,
        *,
        delta_t_s: float = 0.0,
        flange2base: FlangeToBase | None = None,
        sensor2flange: ArrayLike | None = None,
        timeout_s: float = 0.1,
        joint_capacity: int = 2500,
        max_points: int = 200_000,
        first_index: int = 0,
    ) -> None:
        self.lock = threading.RLock()
        self.scheduler = TriggerScheduler()
        self.matcher = SyncMatcher(delta_t_s=delta_t_s, timeout_s=timeout_s, history=8192)
        self.joints = JointBuffer(capacity=joint_capacity)
        self._flange2base = flange2base
        self._sensor2flange = (
            np.eye(4) if sensor2flange is None else np.asarray(sensor2flange, dtype=np.float64)
        )
        self._next_index = first_index % INDEX_MODULUS
        self._rows = SeamRows(max_points)
        # Released points not yet turned into rows: converted in one batch when rows are read
        # (or the batch is full), not one datagram at a time.
        self._pending: list[SeamPoint] = []
        self._stats = _Stats()
        self._joint_t = -math.inf

    @property
    def flange2base(self) -> FlangeToBase | None:
        return self._flange2base

    @flange2base.setter
    def flange2base(self, value: FlangeToBase | None) -> None:
        with self.lock:
            self._flush()  # points released so far keep the kinematics of their release
            self._flange2base = value

    @property
    def sensor2flange(self) -> NDArray[np.float64]:
        """^N_S T (4, 4) mm used for the base-frame columns of points released from now on."""
        return self._sensor2flange

    @sensor2flange.setter
    def sensor2flange(self, value: ArrayLike) -> None:
        with self.lock:
            self._flush()
            self._sensor2flange = np.asarray(value, dtype=np.float64)

    # --- configuration ------------------------------------------------------------------------

    @property
    def delta_t_s(self) -> float:
        return self.matcher.delta_t_s

    def set_delay(self, delta_t_s: float) -> None:
        """ΔT (s) for data synchronised from now on [SY-5.2]."""
        if not math.isfinite(delta_t_s):
            raise SyncStateError("delta_t must be finite")
        with self.lock:
            self.matcher.delta_t_s = float(delta_t_s)

    @property
    def next_index(self) -> int:
        return self._next_index

    # --- triggers ----------------------------------------------------------------------------

    def start_rate(self, rate_hz: float, count: int, t_first: float) -> int:
        """Plan rate triggering; returns the index the first trigger will carry."""
        with self.lock:
            self.scheduler.start_rate(rate_hz, count, t_first)
            return self._next_index

    def schedule(self, times: Sequence[float]) -> int:
        """Plan triggers at explicit times; returns the first index."""
        with self.lock:
            self.scheduler.schedule(times)
            return self._next_index

    def stop(self) -> None:
        with self.lock:
            self.scheduler.stop()

    def next_due(self) -> float | None:
        with self.lock:
            return self.scheduler.next_due()

    def due_triggers(self, now: float) -> list[tuple[int, float]]:
        """Triggers due by ``now`` as (index, scheduled time); call :meth:`sent` for each."""
        with self.lock:
            out = []
            for t in self.scheduler.pop_due(now):
                out.append((self._next_index, t))
                self._next_index = (self._next_index + 1) % INDEX_MODULUS
            return out

    def sent(self, index: int, t_trigger: float) -> bytes:
        """Record trigger ``index`` as sent at ``t_trigger`` (s, robot clock): t_i^T.

        Returns the datagram to put on the wire.
        """
        with self.lock:
            self.matcher.on_trigger(index, t_trigger)
            return encode_trigger(Trigger(index, t_trigger))

    # --- data --------------------------------------------------------------------------------

    def on_datagram(self, raw: bytes, now: float) -> DataOutcome | None:
        """One datagram received at ``now`` (s). Malformed ones are counted and dropped
        [SY-1.4] (``None``); a trigger sent back at us is counted as unexpected."""
        try:
            decoded = decode_datagram(raw)
        except DatagramError as exc:
            with self.lock:
                self._stats.malformed += 1
            log.debug("dropped malformed datagram: %s", exc)
            return None
        with self.lock:
            if not isinstance(decoded, SensorData):
                self._stats.unexpected += 1
                return None
            self._stats.received += 1
            return self.matcher.on_data(decoded, now)

    def add_joints(self, times: ArrayLike, joints: ArrayLike) -> None:
        """Append measured joint samples (N,) s, (N, 6) deg; samples not newer than the last
        one are skipped (a source may repeat its tail)."""
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        q = np.asarray(joints, dtype=np.float64).reshape(t.shape[0], -1)
        with self.lock:
            keep = t > self._joint_t
            if np.any(keep):
                self.joints.extend(t[keep], q[keep])
                self._joint_t = float(t[keep][-1])

    def add_joint(self, t: float, q: ArrayLike) -> None:
        """:meth:`add_joints` for one sample: time ``t`` (s), joints ``q`` (6,) deg (one
        per robot cycle: no batch arrays to build)."""
        t = float(t)
        with self.lock:
            if t > self._joint_t:
                self.joints.append(t, q)
                self._joint_t = t

    def poll(self, now: float) -> list[SeamPoint]:
        """Declare lost triggers, match data whose t_i^S the joints cover, store released
        points (in index order) as seam-point rows; returns the released points."""
        with self.lock:
            points = self.matcher.poll(now, self.joints)
            if points:
                self._store(points)
            return points

    def _store(self, points: list[SeamPoint]) -> None:
        self._pending.extend(points)
        if len(self._pending) >= _ROW_BATCH:
            self._flush()

    def _flush(self) -> None:
        """Turn the pending points into seam-point rows (caller holds the lock)."""
        points = self._pending
        if not points:
            return
        self._pending = []
        seam2sensor = np.stack([p.seam2sensor for p in points])
        rows = np.full((len(points), len(SEAM_POINT_COLUMNS)), np.nan)
        rows[:, 0] = [p.index for p in points]
        rows[:, 1] = [p.t_trigger for p in points]
        rows[:, 2] = [p.t_sensor for p in points]
        rows[:, 3] = SensorStatus.FOUND
        rows[:, 4] = [p.quality for p in points]
        rows[:, 5:11] = transforms_to_locations(seam2sensor)
        if self._flange2base is not None:
            joints = np.stack([p.joints for p in points])
            in_base = seam2base(joints, self._flange2base, self._sensor2flange, seam2sensor)
            rows[:, 11:17] = transforms_to_locations(in_base)
        self._rows.append(rows)

    def points_since(self, since: int, limit: int = 20_000) -> NDArray[np.float64]:
        """Seam-point rows (M, 17) (columns ``SEAM_POINT_COLUMNS``) with index > ``since``,
        in index order, at most ``limit`` of them."""
        with self.lock:
            self._flush()
            return self._rows.since(since, limit)

    def retained(self) -> dict[str, int]:
        """Items held by each long-lived structure; every one is bounded (by the matcher's
        history plus unresolved triggers, ``max_points``, the row batch and the joint
        capacity), so a robot server can trigger for ever."""
        with self.lock:
            return {
                **self.matcher.retained(),
                "rows": len(self._rows),
                "pending_points": len(self._pending),
                "joints": len(self.joints),
            }

    def statistics(self) -> dict[str, int]:
        """The GetSyncStatistics counters (stale data is counted as late; ``exposed_late``:
        points placed later by their extra exposure lag, SY-3.8 and SY-5.9), and some the
        wire does not carry: ``not_found``, ``invalid`` and ``unexpected``."""
        with self.lock:
            c = self.matcher.counters
            return {
                "sent": c.triggers,
                "received": self._stats.received,
                "matched": c.points,
                "lost": c.lost,
                "late": c.late + c.stale,
                "duplicate": c.duplicate,
                "reordered": c.reordered,
                "unknown": c.unknown,
                "expired": c.expired,
                "malformed": self._stats.malformed,
                "pending": self.matcher.pending,
                "not_found": c.not_found,
                "invalid": c.invalid,
                "unexpected": self._stats.unexpected,
                "exposed_late": c.exposed_late,
            }


class UdpSyncEndpoint:
    """The robot's UDP endpoint: a thread that sends due triggers to the sensor, receives
    data datagrams and keeps the core's joint buffer and matcher going.

    ``clock`` gives robot-clock seconds; t_i^T is read from it just before each ``sendto``
    (the time the trigger actually went out, however late the thread ran). A data datagram's
    arrival time, which the loss rule [SY-3.3] judges, is the kernel's receive timestamp
    where the platform has one (:func:`spec.udp.recv_stamped`), so data the thread reads late
    is not declared lost; a simulated ``clock`` must pass ``kernel_timestamps=False`` (the
    kernel's age of a datagram is real time). ``joints_since(t)`` supplies new measured
    joints (e.g. the robot's joint log). ``poll_interval_s`` bounds how long data waits for
    matching; with no trigger planned and nothing pending the thread blocks until a datagram
    or :meth:`wake` (no idle wake-ups). The thread asks for real-time scheduling at
    ``rt_priority`` (0: normal; :mod:`spec.realtime`).

    ``simulated=True`` (a simulated robot clock, which jumps ahead while the robot is made
    to wait): a trigger carries the robot-clock time it was due at, the moment it is sent on
    that clock, never the time the thread got to it, so triggers due in one jump are not a
    burst stamped with one time [SY-5.7]; the kernel's stamps (real time) are not used.
    """

    def __init__(
        self,
        core: RobotSyncCore,
        *,
        clock: Clock,
        joints_since: JointSource,
        host: str = "0.0.0.0",
        port: int = 0,
        poll_interval_s: float = 0.005,
        allow: Iterable[Network] = (),
        sensor_only: bool = True,
        rt_priority: int = DEFAULT_RT_PRIORITY,
        kernel_timestamps: bool = True,
        simulated: bool = False,
    ) -> None:
        self.core = core
        self.simulated = simulated
        kernel_timestamps = kernel_timestamps and not simulated
        self.clock = clock
        self.joints_since = joints_since
        self.poll_interval_s = poll_interval_s
        self.rt_priority = rt_priority
        self.scheduling = "not started"
        self.target: tuple[str, int] | None = None
        self._sock = bind_udp(host, port)
        self.kernel_timestamps = kernel_timestamps and enable_kernel_timestamps(self._sock)
        self.send_timestamps = kernel_timestamps and enable_send_timestamps(self._sock)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self._stop = threading.Event()
        self._wake_r, self._wake_w = socket.socketpair()
        self._thread: threading.Thread | None = None
        self.send_errors = 0
        #: Exceptions the loop caught and survived (tests make them fatal, spec.shells).
        self.handler_errors: list[BaseException] = []
        register(self)
        #: Networks datagrams may come from; empty: any [RS-7.7].
        self.allow: tuple[Network, ...] = tuple(allow)
        #: Accept datagrams only from the sensor endpoint the triggers go to [SY-3.7].
        self.sensor_only = sensor_only
        self._sources: frozenset[tuple[str, int]] = frozenset()
        #: Datagrams dropped unread: "refused_address" (outside ``allow``), "foreign" (not
        #: from the sensor endpoint).
        self.dropped: Counter[str] = Counter()
        self.uncertain_stamps = 0

    def set_target(self, host: str, port: int) -> None:
        """Where triggers go (the sensor's trigger listener); port 0: nowhere."""
        self.target = (host, port) if port else None
        self._sources = _addresses(host, port, self._sock.family) if port else frozenset()
        self.wake()

    def wake(self) -> None:
        """Re-read the schedule now (after StartTriggers / ScheduleTriggers)."""
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass

    def start(self) -> UdpSyncEndpoint:
        self._thread = threading.Thread(target=self._run, name="robot-sync-udp", daemon=True)
        self._thread.start()
        return self

    def __enter__(self) -> UdpSyncEndpoint:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        self.wake()
        if self._thread is not None:
            self._thread.join(timeout)
        self._sock.close()
        self._wake_r.close()
        self._wake_w.close()

    def _timeout(self) -> float | None:
        """How long the thread may wait: until the next trigger (at most a poll interval), a
        poll interval while data is pending, forever (None) when nothing is planned or
        pending."""
        due = self.core.next_due()
        if due is not None:
            # Bounded by the poll interval too: a simulated clock may jump past ``due``.
            return min(self.poll_interval_s, max(0.0, due - self.clock()))
        return self.poll_interval_s if self.core.matcher.pending else None

    def _run(self) -> None:
        self.scheduling = promote_current_thread(self.rt_priority)
        log.debug("robot sync endpoint: scheduling %s", self.scheduling)
        last_joint_t = -math.inf
        while not self._stop.is_set():
            try:
                readable, _, _ = select.select([self._sock, self._wake_r], [], [], self._timeout())
            except (OSError, ValueError):
                return
            if self._wake_r in readable:
                try:
                    self._wake_r.recv(4096)
                except OSError:
                    pass
            self._send_due()
            # Always drain the socket before the loss rule runs on the clock: a thread that
            # waited for the CPU or the GIL after select() would otherwise declare lost data
            # that came in time and waits in the socket (its kernel stamp says when).
            self._receive_all()
            try:
                t, q = self.joints_since(last_joint_t)
                if len(t):
                    self.core.add_joints(t, q)
                    last_joint_t = float(t[-1])
                self.core.poll(self.clock())
            except Exception as exc:  # the endpoint must survive a bad joint source
                self.handler_errors.append(exc)
                log.exception("synchronisation poll failed")

    def _send_due(self) -> None:
        for index, scheduled in self.core.due_triggers(self.clock()):
            if self.simulated:
                self._send_trigger(index, scheduled)
                continue
            target = self.target
            # Stamp, encode and send with nothing between that can block (the core's lock is
            # taken after the send): t_i^T is the time the trigger went out. The thread can
            # still lose the GIL between the stamp and the send (a busy process: a third of
            # the triggers, 1.3 ms on average, with 64 Herej clients): where the kernel stamps
            # sent datagrams, t_i^T is its send time, which the datagram's echo of the early
            # stamp does not change (the robot matches with its own record [SY-3.1]).
            t_send = self.clock()
            if target is not None:
                try:
                    self._sock.sendto(encode_trigger(Trigger(index, t_send)), target)
                except OSError as exc:
                    self.send_errors += 1
                    log.debug("trigger sendto %s: %s", target, exc)
                stamp = sent_stamp(self._sock) if self.send_timestamps else None
                if stamp is not None:
                    t_kernel = arrival_time(self.clock, stamp)
                    if t_kernel - t_send > STAMP_TOLERANCE_S:
                        self.uncertain_stamps += 1  # how often the early stamp was off
                    t_send = max(t_send, t_kernel)
                elif self.clock() - t_send > STAMP_TOLERANCE_S:
                    # The thread lost the CPU or the GIL between the stamp and the send.
                    self.uncertain_stamps += 1
            self.core.sent(index, t_send)

    def _send_trigger(self, index: int, t_trigger: float) -> None:
        """A trigger stamped with a given robot-clock time (simulated clock)."""
        if self.target is not None:
            try:
                self._sock.sendto(encode_trigger(Trigger(index, t_trigger)), self.target)
            except OSError as exc:
                self.send_errors += 1
                log.debug("trigger sendto %s: %s", self.target, exc)
        self.core.sent(index, t_trigger)

    def _receive_all(self) -> None:
        while True:
            try:
                raw, source, stamp = recv_stamped(self._sock, 2048)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                log.debug("recvfrom: %s", exc)
                return
            if self._accepts(source):
                stamp = stamp if self.kernel_timestamps else None
                self.core.on_datagram(raw, arrival_time(self.clock, stamp))

    def _accepts(self, source: Any) -> bool:
        host, port = source[0], source[1]
        if not address_allowed(self.allow, host):
            self.dropped["refused_address"] += 1
            return False
        if self.sensor_only and self._sources and (host, port) not in self._sources:
            # [SY-3.7] data from anyone but the sensor could forge seam points.
            self.dropped["foreign"] += 1
            return False
        return True


def _addresses(host: str, port: int, family: int) -> frozenset[tuple[str, int]]:
    """The (address, port) pairs ``host:port`` stands for, as recvfrom reports a source."""
    try:
        infos = socket.getaddrinfo(host, port, family, socket.SOCK_DGRAM)
    except (OSError, UnicodeError):
        return frozenset({(host, port)})
    return frozenset((str(info[4][0]), int(info[4][1])) for info in infos)
