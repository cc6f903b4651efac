"""Record what goes over the wire to a pcapng file Wireshark opens.

:class:`SessionRecorder` turns TCP connections (their bytes as they were sent and received)
and UDP datagrams into packets of a :class:`spec.pcapng.PcapngWriter`; the clients use it
(``RobotClient(..., record="session.pcapng")``) and so does the recording proxy:

``python -m spec record --listen PORT --to HOST:PORT -o session.pcapng`` accepts connections
on PORT, connects each to HOST:PORT, relays the bytes both ways unchanged and records them;
``--udp LPORT:HOST:PORT`` relays (and records) UDP datagrams too: what arrives at LPORT goes
to HOST:PORT, and what comes back goes to the last sender. The proxy adds nothing to the
stream, so what the endpoints see is what they would see directly, a few microseconds later.
"""

from __future__ import annotations

import logging
import os
import selectors
import socket
import threading
import time
from dataclasses import dataclass, field

from spec.pcapng import Address, PcapngWriter, TcpFlow, ip_of, same_family, udp_datagram

log = logging.getLogger(__name__)

Endpoint = tuple[str, int]


def _endpoint(host: str, port: int) -> tuple[Address, int]:
    return ip_of(host), port


def describe(endpoint: Endpoint) -> str:
    host, port = endpoint
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


class SessionRecorder:
    """A pcapng recording shared by any number of connections and threads.

    Each call writes whole packets under one lock, flushed at once (a killed process leaves a
    readable ``NAME.part``); :meth:`close` ends every open connection with a FIN and renames
    the file to ``NAME``."""

    def __init__(self, path: str | os.PathLike[str], comment: str, application: str) -> None:
        self._writer = PcapngWriter(path, comment, application=application)
        self._lock = threading.Lock()
        #: open connections: their packets and the sides that have closed
        self._flows: dict[int, tuple[TcpFlow, set[bool]]] = {}
        self._ids = iter(range(1, 1 << 62))
        self.path = self._writer.path
        self.partial = self._writer.partial

    @property
    def packets(self) -> int:
        return self._writer.packets

    def open_tcp(self, client: Endpoint, server: Endpoint) -> int:
        """A new connection from ``client`` to ``server`` (its handshake is recorded now);
        returns its handle for :meth:`tcp` and :meth:`close_tcp`."""
        c, s = _endpoint(*client), _endpoint(*server)
        ca, sa = same_family(c[0], s[0])
        flow = TcpFlow((ca, c[1]), (sa, s[1]))
        with self._lock:
            handle = next(self._ids)
            self._flows[handle] = (flow, set())
            self._writer.write_all(flow.handshake())
        return handle

    def tcp(self, handle: int, from_client: bool, data: bytes | memoryview) -> None:
        """Bytes of a connection, as they were sent (or received) at this moment."""
        stamp = time.time_ns()
        with self._lock:
            entry = self._flows.get(handle)
            if entry is not None:
                self._writer.write_all(entry[0].data(from_client, bytes(data)), stamp)

    def close_tcp(self, handle: int, from_client: bool) -> None:
        """One side closed (a FIN); the connection is forgotten when both have."""
        with self._lock:
            entry = self._flows.get(handle)
            if entry is None or from_client in entry[1]:
                return
            self._writer.write_all(entry[0].fin(from_client))
            entry[1].add(from_client)
            if len(entry[1]) == 2:
                del self._flows[handle]

    def forget_tcp(self, handle: int) -> None:
        """A connection that ended without its FINs seen (closed by us, reset)."""
        with self._lock:
            self._flows.pop(handle, None)

    def udp(self, src: Endpoint, dst: Endpoint, data: bytes) -> None:
        stamp = time.time_ns()
        s, d = _endpoint(*src), _endpoint(*dst)
        sa, da = same_family(s[0], d[0])
        with self._lock:
            self._writer.write(udp_datagram((sa, s[1]), (da, d[1]), data), stamp)

    def close(self) -> None:
        with self._lock:
            for flow, fins in self._flows.values():
                for side in (True, False):
                    if side not in fins:
                        self._writer.write_all(flow.fin(side))
            self._flows.clear()
            self._writer.close()

    @property
    def closed(self) -> bool:
        return self._writer.closed


# --- the recording proxy -------------------------------------------------------------------


@dataclass
class UdpRelay:
    """``listen`` ↔ ``target``: datagrams to ``listen`` go on to ``target``, datagrams from
    ``target`` go back to whoever sent last."""

    listen: Endpoint
    target: Endpoint
    sock: socket.socket = field(init=False)
    peer: Endpoint | None = None

    def __post_init__(self) -> None:
        family = socket.AF_INET6 if ":" in self.listen[0] else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self.sock.bind(self.listen)
        except OSError:
            self.sock.close()
            raise
        self.listen = self.sock.getsockname()[:2]
        # the numeric address datagrams from the target come from
        info = socket.getaddrinfo(*self.target, family, socket.SOCK_DGRAM)
        host, port = info[0][4][:2]
        self.target = (str(host), int(port))


class RecordingProxy:
    """The transparent TCP proxy (and optional UDP relays) of ``python -m spec record``."""

    def __init__(
        self,
        listener: socket.socket,
        target: Endpoint,
        recorder: SessionRecorder,
        relays: tuple[UdpRelay, ...] = (),
        *,
        connect_timeout: float = 5.0,
    ) -> None:
        self.listener = listener
        self.target = target
        self.recorder = recorder
        self.relays = relays
        self.connect_timeout = connect_timeout
        self.connections = 0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._sockets: set[socket.socket] = set()
        self._lock = threading.Lock()

    @property
    def address(self) -> Endpoint:
        host, port = self.listener.getsockname()[:2]
        return host, port

    def serve_forever(self) -> None:
        """Accept and relay until :meth:`shutdown`."""
        sel = selectors.DefaultSelector()
        sel.register(self.listener, selectors.EVENT_READ, None)
        for relay in self.relays:
            sel.register(relay.sock, selectors.EVENT_READ, relay)
        try:
            while not self._stop.is_set():
                for key, _ in sel.select(0.2):
                    if key.data is None:
                        self._accept()
                    else:
                        self._relay_datagram(key.data)
        finally:
            sel.close()

    def _accept(self) -> None:
        try:
            client, address = self.listener.accept()
        except OSError:
            return
        t = threading.Thread(target=self._connection, args=(client, address[:2]), daemon=True)
        self._threads.append(t)
        t.start()

    def _relay_datagram(self, relay: UdpRelay) -> None:
        try:
            data, source = relay.sock.recvfrom(65535)
        except OSError:
            return
        source = source[:2]
        if source == relay.target:
            dst = relay.peer
            if dst is None:
                return  # a reply before anything was relayed: nobody to give it to
            self.recorder.udp(relay.target, dst, data)
        else:
            relay.peer = source
            dst = relay.target
            self.recorder.udp(source, relay.target, data)
        try:
            relay.sock.sendto(data, dst)
        except OSError as exc:
            log.info("UDP relay to %s: %s", describe(dst), exc)

    def _connection(self, client: socket.socket, address: Endpoint) -> None:
        try:
            upstream = socket.create_connection(self.target, timeout=self.connect_timeout)
        except OSError as exc:
            log.warning("cannot reach %s for %s: %s", describe(self.target), describe(address), exc)
            client.close()
            return
        upstream.settimeout(None)
        for s in (client, upstream):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        server = upstream.getpeername()[:2]
        with self._lock:
            self.connections += 1
            self._sockets |= {client, upstream}
        handle = self.recorder.open_tcp(address, server)
        log.info("connection %s -> %s", describe(address), describe(server))
        back = threading.Thread(
            target=self._pump, args=(upstream, client, handle, False), daemon=True
        )
        back.start()
        self._pump(client, upstream, handle, True)
        back.join()
        with self._lock:
            self._sockets -= {client, upstream}
        client.close()
        upstream.close()

    def _pump(self, src: socket.socket, dst: socket.socket, handle: int, from_client: bool) -> None:
        buf = bytearray(1 << 18)
        view = memoryview(buf)
        while True:
            try:
                n = src.recv_into(buf)
            except OSError:
                n = 0
            if not n:
                break
            # recorded before it is passed on: a reply never precedes its request in the file
            self.recorder.tcp(handle, from_client, view[:n])
            try:
                dst.sendall(view[:n])
            except OSError:
                break
        self.recorder.close_tcp(handle, from_client)
        try:
            dst.shutdown(socket.SHUT_WR)
        except OSError:
            pass

    def shutdown(self) -> None:
        """Stop accepting, close every relayed connection, end the recording."""
        self._stop.set()
        with self._lock:
            for s in self._sockets:
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
        for t in self._threads:
            t.join(2.0)
        self.listener.close()
        for relay in self.relays:
            relay.sock.close()
        self.recorder.close()


__all__ = ["RecordingProxy", "SessionRecorder", "UdpRelay", "describe"]
