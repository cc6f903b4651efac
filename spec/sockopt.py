"""Kernel socket timeouts (SO_RCVTIMEO / SO_SNDTIMEO) on a blocking socket.

A Python socket timeout costs three system calls per receive (mode switch, poll, recv); a
blocking socket whose timeout lives in the kernel costs one. A receive that times out raises
:class:`BlockingIOError` instead of :class:`TimeoutError`. Used where every round trip counts:
the server's session loop and the client's reply wait.
"""

from __future__ import annotations

import math
import socket
import struct


def set_kernel_timeouts(sock: socket.socket, seconds: float, *, send: bool = True) -> bool:
    """Make ``sock`` blocking with a receive (and send) timeout of ``seconds`` (> 0); False
    where the platform does not take them (use Python timeouts there)."""
    try:
        # Rounded up to 1 µs: a zero timeval means "no timeout", a wait forever.
        micros = max(1, math.ceil(seconds * 1e6))
        timeval = struct.pack("ll", micros // 1_000_000, micros % 1_000_000)
        sock.settimeout(None)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, timeval)
        if send:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, timeval)
    except (OSError, OverflowError, ValueError, struct.error):
        return False
    return True


__all__ = ["set_kernel_timeouts"]
