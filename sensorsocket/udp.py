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
import threading
from collections import Counter, OrderedDict, deque
from collections.abc import Hashable
from dataclasses import dataclass, field
from typing import Any, Protocol

from sensorsocket.sensor import NAN_LOCATION, Clock, Reading
from spec.datagrams import INDEX_MODULUS, SensorData, Trigger, decode_datagram, encode_data
from spec.errors import DatagramError
from spec.udp import bind_udp
from spec.wire import SensorStatus

log = logging.getLogger(__name__)

#: Indices remembered for duplicate detection [SY-2.2].
HISTORY = 1024
MAX_SOURCES = 64  # trigger senders remembered at once (least recently heard forgotten first)
_HALF = INDEX_MODULUS // 2


def serial_newer(a: int, b: int) -> bool:
    """True when index ``a`` is after ``b`` in serial-number arithmetic (RFC 1982) [SY-1.3]."""
    d = (a - b) % INDEX_MODULUS
    return 0 < d < _HALF


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


@dataclass(frozen=True)
class TriggerReply:
    """The data datagram for one trigger and when to send it (s, sensor clock)."""

    data: bytes
    t_send: float
    index: int
    status: SensorStatus


_COUNTERS = (
    "datagrams",  # every datagram handed in
    "malformed",  # dropped silently [SY-1.4]
    "unexpected",  # well-formed but not a trigger (e.g. a data datagram): dropped
    "triggers",  # valid triggers (including duplicates)
    "duplicates",  # same index answered before: no reply [SY-2.2]
    "reordered",  # older than the newest served: OVERRUN [SY-2.3]
    "overruns",  # OVERRUN replies (reordered + busy) [SY-2.8]
    "replies",
    "found",
    "not_found",
    "laser_off",
    "errors",
)


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
        self._counts: Counter[str] = Counter()

    def statistics(self) -> dict[str, int]:
        with self._lock:
            return {k: self._counts.get(k, 0) for k in _COUNTERS}

    def handle(self, datagram: bytes, t_arrival: float, source: Hashable = None) -> bytes | None:
        """The reply datagram for ``datagram`` arriving at ``t_arrival`` from ``source`` (the
        sender's address), or None."""
        reply = self.process(datagram, t_arrival, source)
        return None if reply is None else reply.data

    def process(
        self, datagram: bytes, t_arrival: float, source: Hashable = None
    ) -> TriggerReply | None:
        """Like :meth:`handle`, with the modelled send time of the reply."""
        with self._lock:
            self._counts["datagrams"] += 1
            try:
                decoded = decode_datagram(datagram)
            except DatagramError as exc:
                # [SY-1.4] a malformed datagram is dropped silently and counted.
                self._counts["malformed"] += 1
                log.debug("dropped malformed datagram: %s", exc)
                return None
            if not isinstance(decoded, Trigger):
                self._counts["unexpected"] += 1
                return None
            self._counts["triggers"] += 1
            index = decoded.index
            history = self._history(source)
            if index in history.answered:
                # [SY-2.2] a duplicate starts no acquisition and gets no second reply.
                self._counts["duplicates"] += 1
                return None
            history.remember(index)
            newest = history.newest
            if newest is not None and not serial_newer(index, newest):
                # [SY-2.3] an older index than one already served: OVERRUN, never silence.
                self._counts["reordered"] += 1
                return self._overrun(decoded, t_arrival)
            history.newest = index
            if self.sensor.busy(t_arrival):
                # [SY-2.8] the chip is still busy with earlier triggers: OVERRUN.
                return self._overrun(decoded, t_arrival)
        # Acquire outside the handler lock; the sensor serialises acquisitions itself.
        reading = self.sensor.acquire(t_arrival, index=index, t_trigger=decoded.t_trigger)
        status = reading.status
        # [SY-2.7] a status other than FOUND carries a NaN location.
        seam = reading.seam if status is SensorStatus.FOUND else NAN_LOCATION
        data = SensorData(
            index=index,
            status=status,
            seam=seam,
            quality=reading.quality,
            t_trigger=decoded.t_trigger,  # [SY-2.1] echo t_i^T
            # [SY-2.6] the timing model gives t_arrival <= exposure start <= exposure end.
            t_arrival=reading.t_arrival,
            t_exposure_start=reading.t_exposure_start,
            t_exposure_end=reading.t_exposure_end,
        )
        with self._lock:
            self._count_reply(status)
        return TriggerReply(encode_data(data), reading.t_done + self.network_delay_s, index, status)

    def _history(self, source: Hashable) -> _History:
        history = self._sources.get(source)
        if history is None:
            history = self._sources[source] = _History()
            if len(self._sources) > MAX_SOURCES:
                self._sources.popitem(last=False)
        else:
            self._sources.move_to_end(source)
        return history

    def _overrun(self, trigger: Trigger, t_arrival: float) -> TriggerReply:
        self._counts["overruns"] += 1
        self._count_reply(SensorStatus.OVERRUN)
        data = SensorData(
            trigger.index,
            SensorStatus.OVERRUN,
            NAN_LOCATION,
            0.0,
            trigger.t_trigger,
            t_arrival,
            t_arrival,
            t_arrival,
        )
        return TriggerReply(
            encode_data(data), t_arrival + self.network_delay_s, trigger.index, data.status
        )

    def _count_reply(self, status: SensorStatus) -> None:
        self._counts["replies"] += 1
        key = {
            SensorStatus.FOUND: "found",
            SensorStatus.NOT_FOUND: "not_found",
            SensorStatus.LASER_OFF: "laser_off",
            SensorStatus.ERROR: "errors",
        }.get(status)
        if key is not None:
            self._counts[key] += 1


class TriggerListener:
    """A thread that feeds trigger datagrams from a UDP socket to a :class:`TriggerHandler`
    and sends each reply to the trigger's source address.

    ``hold=True`` (real time) sends a reply no earlier than its modelled time ``t_send`` on
    ``clock``; while holding, the thread keeps reading triggers, so arrival stamps stay
    accurate. ``hold=False`` sends as soon as the frame is processed.
    """

    def __init__(
        self,
        handler: TriggerHandler,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        clock: Clock,
        hold: bool = True,
    ) -> None:
        self.handler = handler
        self.clock = clock
        self.hold = hold
        self._sock = bind_udp(host, port)
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pending: list[tuple[float, int, bytes, Any]] = []
        self._seq = 0
        self._send_errors = 0
        self._sent = 0

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
        return stats

    def _run(self) -> None:
        while not self._stop.is_set():
            timeout = 0.2
            if self._pending:
                timeout = min(timeout, max(0.0, self._pending[0][0] - self.clock()))
            try:
                readable, _, _ = select.select([self._sock], [], [], timeout)
            except (OSError, ValueError):
                return  # socket closed under us by stop()
            if readable:
                self._receive_all()
            self._send_due()

    def _receive_all(self) -> None:
        while True:
            try:
                datagram, source = self._sock.recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                # e.g. ICMP port unreachable of an earlier reply on some systems
                log.debug("recvfrom: %s", exc)
                return
            t_arrival = self.clock()
            try:
                reply = self.handler.process(datagram, t_arrival, source)
            except Exception:  # the listener must survive any sensor failure
                log.exception("trigger handling failed")
                continue
            if reply is None:
                continue
            if not self.hold or reply.t_send <= self.clock():
                self._send(reply.data, source)  # due now: skip the queue
                continue
            self._seq += 1
            heapq.heappush(self._pending, (reply.t_send, self._seq, reply.data, source))

    def _send_due(self) -> None:
        now = self.clock()
        while self._pending and self._pending[0][0] <= now:
            _, _, data, target = heapq.heappop(self._pending)
            self._send(data, target)

    def _send(self, data: bytes, target: Any) -> None:
        try:
            self._sock.sendto(data, target)
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
