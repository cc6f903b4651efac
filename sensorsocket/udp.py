"""Sensor side of the UDP synchronisation (PROTOCOL.md section 9, paper section V).

:class:`TriggerHandler` is the pure part: ``(datagram bytes, t_arrival) -> reply or None``.
It applies the rules of section 9 and the sensor's timing model and counts everything, so it
runs unchanged in a unit test, in the emulated work cell on a simulated clock, and behind
:class:`TriggerListener`, the thin socket thread.
"""

from __future__ import annotations

import heapq
import logging
import math
import select
import socket
import threading
from collections import OrderedDict, deque
from collections.abc import Hashable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

from sensorsocket.sensor import NAN_LOCATION, Clock, Reading
from spec.auth import Network, address_allowed
from spec.datagrams import decode_datagram, encode_data_fields, serial_newer, trigger_fields
from spec.errors import DatagramError
from spec.realtime import DEFAULT_RT_PRIORITY, promote_current_thread
from spec.shells import register
from spec.sockopt import set_kernel_timeouts
from spec.udp import arrival_time, bind_udp, enable_kernel_timestamps, recv_stamped
from spec.wire import SensorStatus

log = logging.getLogger(__name__)

#: Indices remembered for duplicate detection [SY-2.2].
HISTORY = 1024
MAX_SOURCES = 64  # trigger senders remembered at once (least recently heard forgotten first)


class Acquirer(Protocol):
    """What the handler needs from the sensor (:class:`~sensorsocket.sensor.Sensor`)."""

    def busy(self, t_arrival: float) -> bool: ...

    def acquire(
        self,
        t_arrival: float | None = None,
        *,
        index: int | None = None,
        t_trigger: float = math.nan,
    ) -> Reading: ...


@dataclass(slots=True)  # not frozen: a frozen __init__ costs 0.3 us more, on every trigger
class TriggerReply:
    """The data datagram for one trigger and when to send it (s, sensor clock); read-only by
    convention."""

    data: bytes
    t_send: float
    index: int
    status: SensorStatus


_COUNTERS = (  # the keys of TriggerHandler.statistics(), in order
    "datagrams",  # every datagram handed in
    "malformed",  # dropped silently [SY-1.4]
    "unexpected",  # well-formed but not a trigger (e.g. a data datagram): dropped
    "triggers",  # valid triggers (including duplicates)
    "duplicates",  # same index answered before: no reply [SY-2.2]
    "reordered",  # older than the newest served: OVERRUN [SY-2.3]
    "overruns",  # OVERRUN replies of the handler (reordered + busy) [SY-2.8]
    "replies",  # every reply, by status below (an OVERRUN the sensor reports is one too)
    "found",
    "not_found",
    "laser_off",
    "errors",
)
_FOUND = SensorStatus.FOUND
_OVERRUN = SensorStatus.OVERRUN


@dataclass
class _History:
    """The indices one trigger source has been answered for (the last :data:`HISTORY`)."""

    answered: set[int] = field(default_factory=set)
    order: deque[int] = field(default_factory=deque)
    newest: int | None = None

    def remember(self, index: int) -> None:
        self.answered.add(index)
        self.order.append(index)
        if len(self.order) > HISTORY:
            self.answered.discard(self.order.popleft())


class TriggerHandler:
    """Pure trigger logic: decode, deduplicate, acquire, encode the reply.

    ``network_delay_s`` models the sensor-to-robot transport: a reply is due at
    ``t_done + network_delay_s`` on the sensor clock.
    """

    def __init__(self, sensor: Acquirer, *, network_delay_s: float = 0.0) -> None:
        if not (network_delay_s >= 0 and math.isfinite(network_delay_s)):
            raise ValueError(f"network_delay_s must be >= 0, got {network_delay_s}")
        self.sensor = sensor
        self.network_delay_s = network_delay_s
        self._lock = threading.Lock()
        # Index history per trigger source: a restarted robot (a new socket) or a second
        # robot starts its own index sequence and must not be taken for duplicates.
        self._sources: OrderedDict[Hashable, _History] = OrderedDict()
        # The most recent source is the last of _sources already: a run of triggers from one
        # robot (the usual case) skips the lookup and the LRU update.
        self._last_source: Hashable = None
        self._last_history: _History | None = None
        # Plain integers, not a Counter: this is paid on every trigger.
        self._datagrams = 0
        self._malformed = 0
        self._unexpected = 0
        self._triggers = 0
        self._duplicates = 0
        self._reordered = 0
        self._overruns = 0
        self._by_status = [0] * (max(SensorStatus) + 1)  # replies by status value

    def statistics(self) -> dict[str, int]:
        with self._lock:
            by_status = self._by_status
            return {
                "datagrams": self._datagrams,
                "malformed": self._malformed,
                "unexpected": self._unexpected,
                "triggers": self._triggers,
                "duplicates": self._duplicates,
                "reordered": self._reordered,
                "overruns": self._overruns,
                "replies": sum(by_status),
                "found": by_status[SensorStatus.FOUND],
                "not_found": by_status[SensorStatus.NOT_FOUND],
                "laser_off": by_status[SensorStatus.LASER_OFF],
                "errors": by_status[SensorStatus.ERROR],
            }

    def handle(self, datagram: bytes, t_arrival: float, source: Hashable = None) -> bytes | None:
        """The reply datagram for ``datagram`` arriving at ``t_arrival`` from ``source`` (the
        sender's address), or None."""
        reply = self.process(datagram, t_arrival, source)
        return None if reply is None else reply.data

    def process(
        self, datagram: bytes, t_arrival: float, source: Hashable = None, *, stale: bool = False
    ) -> TriggerReply | None:
        """Like :meth:`handle`, with the modelled send time of the reply. ``stale``: the
        trigger waited too long before it could be handled (a backlog): answered OVERRUN
        [SY-2.8] without an acquisition, so the ones after it are answered in time."""
        # Runs once per trigger behind the listener: no Trigger/SensorData objects, one unpack
        # of the trigger, one pack of the reply.
        with self._lock:
            self._datagrams += 1
            fields = trigger_fields(datagram)
            if fields is None:
                self._not_a_trigger(datagram)
                return None
            self._triggers += 1
            index, t_trigger = fields
            history = self._last_history
            if history is None or source != self._last_source:
                history = self._history(source)
            if index in history.answered:
                # [SY-2.2] a duplicate starts no acquisition and gets no second reply.
                self._duplicates += 1
                return None
            history.remember(index)
            newest = history.newest
            if newest is not None and not serial_newer(index, newest):
                # [SY-2.3] an older index than one already served: OVERRUN, never silence.
                self._reordered += 1
                return self._overrun(index, t_trigger, t_arrival)
            history.newest = index
            if stale or self.sensor.busy(t_arrival):
                # [SY-2.8] the chip is still busy with earlier triggers: OVERRUN.
                return self._overrun(index, t_trigger, t_arrival)
        # Acquire outside the handler lock; the sensor serialises acquisitions itself.
        reading = self.sensor.acquire(t_arrival, index=index, t_trigger=t_trigger)
        status = reading.status
        data = encode_data_fields(
            index,
            status,
            # [SY-2.7] a status other than FOUND carries a NaN location.
            reading.seam if status is _FOUND else NAN_LOCATION,
            reading.quality,
            t_trigger,  # [SY-2.1] echo t_i^T
            # [SY-2.6] the timing model gives t_arrival <= exposure start <= exposure end.
            reading.t_arrival,
            reading.t_exposure_start,
            reading.t_exposure_end,
        )
        with self._lock:
            self._by_status[status] += 1
        return TriggerReply(data, reading.t_done + self.network_delay_s, index, status)

    def _not_a_trigger(self, datagram: bytes) -> None:
        """Count a datagram the trigger fast path did not take, by what the full decoder
        makes of it."""
        try:
            decode_datagram(datagram)
        except DatagramError as exc:
            # [SY-1.4] a malformed datagram is dropped silently and counted.
            self._malformed += 1
            log.debug("dropped malformed datagram: %s", exc)
            return
        self._unexpected += 1

    def _history(self, source: Hashable) -> _History:
        history = self._sources.get(source)
        if history is None:
            history = self._sources[source] = _History()
            if len(self._sources) > MAX_SOURCES:
                self._sources.popitem(last=False)
        else:
            self._sources.move_to_end(source)
        self._last_source, self._last_history = source, history
        return history

    def _overrun(self, index: int, t_trigger: float, t_arrival: float) -> TriggerReply:
        self._overruns += 1
        self._by_status[_OVERRUN] += 1
        data = encode_data_fields(
            index, _OVERRUN, NAN_LOCATION, 0.0, t_trigger, t_arrival, t_arrival, t_arrival
        )
        return TriggerReply(data, t_arrival + self.network_delay_s, index, _OVERRUN)


_TICK_S = 0.2  # longest wait for a datagram before stop() is seen (s)
MAX_BACKLOG_S = 0.02
"""A trigger read later than this after its arrival is answered OVERRUN (SY-2.5's 20 ms)."""
# Reads after select and all sends must not block; the socket itself blocks (see _run).
_DONTWAIT: int = getattr(socket, "MSG_DONTWAIT", 0)


def _block_with_tick(sock: socket.socket, seconds: float) -> None:
    """Make ``sock`` blocking with a receive timeout of ``seconds`` (BlockingIOError when it
    expires; one system call per recvfrom); the Python timeout where the kernel's is missing."""
    if not set_kernel_timeouts(sock, seconds, send=False):
        sock.settimeout(seconds)


class TriggerListener:
    """A thread that feeds trigger datagrams from a UDP socket to a :class:`TriggerHandler`
    and sends each reply to the trigger's source address.

    ``hold=True`` (real time) sends a reply no earlier than its modelled time ``t_send`` on
    ``clock``; while holding, the thread keeps reading triggers, so arrival stamps stay
    accurate. ``hold=False`` sends as soon as the frame is processed.

    A trigger read more than ``max_backlog_s`` after it arrived (the thread fell behind:
    a busy machine, or acquisitions slower than the trigger rate) is answered OVERRUN at once
    instead of acquired [SY-2.8] (counted in ``stale``), so the queue drains and the readings
    that are taken reach the robot in time [SY-2.5]; ``None`` acquires every trigger.

    A trigger's arrival time is the kernel's receive timestamp (``SO_TIMESTAMPNS``) carried
    onto ``clock`` (:func:`spec.udp.arrival_time`) when ``kernel_timestamps`` is True and
    the platform has it (:attr:`kernel_timestamps` says whether it is in use), so a thread
    that reads the trigger late still stamps when it arrived; otherwise the clock is read
    just after the receive. A simulated clock must pass ``kernel_timestamps=False``. The
    thread asks for real-time scheduling at ``rt_priority`` (0: normal; :mod:`spec.realtime`).
    """

    def __init__(
        self,
        handler: TriggerHandler,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        clock: Clock,
        hold: bool = True,
        allow: Iterable[Network] = (),
        kernel_timestamps: bool = True,
        rt_priority: int = DEFAULT_RT_PRIORITY,
        max_backlog_s: float | None = MAX_BACKLOG_S,
    ) -> None:
        self.handler = handler
        #: Networks triggers may come from; empty: any [RS-7.7].
        self.allow: tuple[Network, ...] = tuple(allow)
        self._refused = 0
        self.max_backlog_s = max_backlog_s
        self._stale = 0
        self.clock = clock
        self.hold = hold
        self.rt_priority = rt_priority
        self.scheduling = "not started"
        self._sock = bind_udp(host, port)
        self.kernel_timestamps = kernel_timestamps and enable_kernel_timestamps(self._sock)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pending: list[tuple[float, int, bytes, Any]] = []
        self._seq = 0
        self._send_errors = 0
        self._sent = 0
        #: Exceptions the loop caught and survived (tests make them fatal, spec.shells).
        self.handler_errors: list[BaseException] = []
        register(self)

    def start(self) -> TriggerListener:
        self._thread = threading.Thread(target=self._run, name="sensor-udp", daemon=True)
        self._thread.start()
        log.info("trigger listener on udp %s:%d", *self.address)
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._sock.close()

    def __enter__(self) -> TriggerListener:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def statistics(self) -> dict[str, int]:
        """The handler's counters plus datagrams sent and send errors."""
        stats = self.handler.statistics()
        stats["sent"] = self._sent
        stats["send_errors"] = self._send_errors
        stats["refused_address"] = self._refused
        stats["stale"] = self._stale
        return stats

    def _run(self) -> None:
        self.scheduling = promote_current_thread(self.rt_priority)
        log.debug("trigger listener: scheduling %s", self.scheduling)
        sock = self._sock
        stamped = self.kernel_timestamps
        # without kernel stamps the arrival is the read: a backlog cannot be seen
        backlog = self.max_backlog_s if stamped else None
        process = self.handler.process
        clock = self.clock
        pending = self._pending
        stop = self._stop
        hold = self.hold
        allow = self.allow
        # Idle, the thread blocks in recvfrom itself (one system call per trigger, as a bare
        # echo server); select is used only while replies are held for their send time.
        _block_with_tick(sock, _TICK_S)
        while not stop.is_set():
            flags = 0
            if pending:
                self._send_due()
                if pending:
                    wait = min(max(0.0, pending[0][0] - clock()), _TICK_S)
                    try:
                        readable, _, _ = select.select([sock], [], [], wait)
                    except (OSError, ValueError):
                        return  # socket closed under us by stop()
                    if not readable:
                        continue
                    flags = _DONTWAIT
            try:
                if stamped:
                    datagram, source, stamp = recv_stamped(sock, 2048, flags)
                else:
                    datagram, source = sock.recvfrom(2048, flags)
            except (BlockingIOError, InterruptedError, TimeoutError):
                continue  # a tick without a datagram: check stop and held replies
            except OSError as exc:
                if sock.fileno() < 0:
                    return  # closed under us by stop()
                # e.g. ICMP port unreachable of an earlier reply on some systems
                log.debug("recvfrom: %s", exc)
                continue
            t_arrival = arrival_time(clock, stamp) if stamped else clock()
            if allow and not address_allowed(allow, source[0]):
                self._refused += 1  # [RS-7.7] dropped unread and unanswered
                continue
            stale = backlog is not None and clock() - t_arrival > backlog
            self._stale += stale
            try:
                reply = process(datagram, t_arrival, source, stale=stale)
            except Exception as exc:  # the listener must survive any sensor failure
                self.handler_errors.append(exc)
                log.exception("trigger handling failed")
                continue
            if reply is None:
                continue
            t_send = reply.t_send
            if not hold or t_send <= t_arrival or t_send <= clock():
                self._send(reply.data, source)  # due now: skip the queue
                continue
            self._seq += 1
            heapq.heappush(pending, (t_send, self._seq, reply.data, source))

    def _send_due(self) -> None:
        now = self.clock()
        while self._pending and self._pending[0][0] <= now:
            _, _, data, target = heapq.heappop(self._pending)
            self._send(data, target)

    def _send(self, data: bytes, target: Any) -> None:
        try:
            self._sock.sendto(data, _DONTWAIT, target)  # never block behind a full buffer
            self._sent += 1
        except OSError as exc:
            self._send_errors += 1
            log.debug("sendto %s: %s", target, exc)


__all__ = [
    "HISTORY",
    "Acquirer",
    "TriggerHandler",
    "TriggerListener",
    "TriggerReply",
    "serial_newer",
]
