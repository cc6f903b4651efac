"""The UDP socket both synchronisation endpoints use (robot side and sensor side), and the
kernel's receive timestamps.

A datagram's arrival time is when the kernel received it, not when a Python thread got
around to reading it (on a busy machine that can be tens of milliseconds later). Linux
stamps every datagram with ``SO_TIMESTAMPNS`` (CLOCK_REALTIME, nanoseconds) when asked to;
:func:`recv_stamped` returns that stamp and :func:`arrival_time` turns it into the caller's
clock by subtracting the datagram's age from the clock's current reading, so it works for any
clock that runs at real-time rate (the robot clock, ``time.monotonic``). Where the platform
has no such option (:func:`enable_kernel_timestamps` returns False) the stamp is ``None``
and the arrival time is the clock read just after the receive (the fallback documented in
PROTOCOL.md section 9 and docs/REALTIME.md). Sent datagrams can be stamped likewise
(:func:`enable_send_timestamps`, :func:`sent_stamp`: the time the kernel sent it, however
long the sending thread waited between reading its clock and the ``sendto``).
"""

from __future__ import annotations

import math
import socket
import struct
import sys
import time
from collections.abc import Callable
from typing import Any

__all__ = [
    "MAX_STAMP_AGE_S",
    "arrival_time",
    "bind_udp",
    "enable_kernel_timestamps",
    "enable_send_timestamps",
    "recv_stamped",
    "sent_stamp",
]

# Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS) and SO_TIMESTAMPING (= SCM_TIMESTAMPING) with
# the flags for software send timestamps, reported alone on the error queue; the socket
# module names none of them.
_LINUX = sys.platform.startswith("linux")
_SO_TIMESTAMPNS = 35 if _LINUX else None
_SO_TIMESTAMPING = 37 if _LINUX else None
_SOF_TX_SOFTWARE = 1 << 1
_SOF_SOFTWARE = 1 << 4
_SOF_OPT_TSONLY = 1 << 11
_MSG_ERRQUEUE: int = getattr(socket, "MSG_ERRQUEUE", 0)
_TIMESPEC = struct.Struct("@ll")
_ANCILLARY = socket.CMSG_SPACE(_TIMESPEC.size) if hasattr(socket, "CMSG_SPACE") else 0

_PAIR_S = 50e-6
MAX_STAMP_AGE_S = 10.0
"""A kernel stamp older than this (or in the future) is not trusted: the wall clock was
stepped between the stamp and the read; the arrival time falls back to the clock."""


def bind_udp(host: str, port: int) -> socket.socket:
    """A non-blocking UDP socket bound to ``host:port`` (IPv4 or IPv6; port 0 = any free)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.setblocking(False)
    return sock


def enable_kernel_timestamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp every datagram ``sock`` receives; False where it cannot.

    Linux switches receive stamping on for the whole system a moment after the first socket
    asks (a deferred static key): a datagram received in that moment is stamped when it is
    read. Our endpoints ask when they are built, long before the first trigger."""
    if _SO_TIMESTAMPNS is None or not _ANCILLARY:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def enable_send_timestamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp every datagram ``sock`` sends (read with :func:`sent_stamp`);
    False where it cannot."""
    if _SO_TIMESTAMPING is None or not _MSG_ERRQUEUE or not _ANCILLARY:
        return False
    try:
        sock.setsockopt(
            socket.SOL_SOCKET, _SO_TIMESTAMPING, _SOF_TX_SOFTWARE | _SOF_SOFTWARE | _SOF_OPT_TSONLY
        )
    except OSError:
        return False
    return True


def sent_stamp(sock: socket.socket) -> int | None:
    """The kernel's send time (CLOCK_REALTIME ns) of the newest datagram ``sock`` sent since
    the last call, read from its error queue (never blocks); None when there is none."""
    newest = None
    while True:
        try:
            _, ancillary, _, _ = sock.recvmsg(1, 512, _MSG_ERRQUEUE | socket.MSG_DONTWAIT)
        except OSError:  # BlockingIOError: the queue is empty
            return newest
        for level, kind, payload in ancillary:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPING and len(payload) >= 16:
                sec, nsec = _TIMESPEC.unpack_from(payload)  # the first timespec: software
                newest = sec * 1_000_000_000 + nsec


def recv_stamped(
    sock: socket.socket, bufsize: int, flags: int = 0
) -> tuple[bytes, Any, int | None]:
    """One datagram: ``(data, source address, kernel receive time in CLOCK_REALTIME ns or
    None)``. Raises what ``recvfrom`` raises (BlockingIOError, TimeoutError, OSError)."""
    if not _ANCILLARY:
        data, source = sock.recvfrom(bufsize, flags)
        return data, source, None
    data, ancillary, _, source = sock.recvmsg(bufsize, _ANCILLARY, flags)
    for level, kind, payload in ancillary:
        if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS:
            sec, nsec = _TIMESPEC.unpack_from(payload)
            return data, source, sec * 1_000_000_000 + nsec
    return data, source, None


def arrival_time(clock: Callable[[], float], stamp_ns: int | None) -> float:
    """The arrival time on ``clock`` (s) of a datagram the kernel stamped at ``stamp_ns``
    (CLOCK_REALTIME): ``clock()`` minus the datagram's age; ``clock()`` without a stamp."""
    if stamp_ns is None:
        return clock()
    # The two clocks are read as one pair: a thread preempted between the reads would add
    # the preemption to the arrival time, so the pair is read up to three times and the
    # tightest kept (on an idle machine the first is a few hundred ns wide and is kept).
    best = math.inf
    before = now = 0.0
    wall_ns = 0
    for _ in range(3):
        b0 = clock()
        w = time.time_ns()
        b1 = clock()
        if b1 - b0 < best:
            best, before, wall_ns, now = b1 - b0, b0, w, b1
        if best <= _PAIR_S:
            break
    age = (wall_ns - stamp_ns) / 1e9
    if not 0.0 <= age <= MAX_STAMP_AGE_S:
        return now
    return 0.5 * (before + now) - age  # off by at most half the pair's width
