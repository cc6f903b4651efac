"""Kernel socket timeouts: a tiny timeout must never become "no timeout"."""

from __future__ import annotations

import socket
import struct

import pytest

from spec.sockopt import set_kernel_timeouts


def _rcvtimeo(sock: socket.socket) -> tuple[int, int]:
    raw = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, struct.calcsize("ll"))
    sec, usec = struct.unpack("ll", raw)
    return sec, usec


@pytest.mark.parametrize(
    ("seconds", "want"), [(9e-7, (0, 1)), (1e-9, (0, 1)), (0.25, (0, 250000)), (2.5, (2, 500000))]
)
def test_timeout_is_rounded_up_never_to_zero(seconds: float, want: tuple[int, int]) -> None:
    a, b = socket.socketpair()
    with a, b:
        assert set_kernel_timeouts(a, seconds)
        got = _rcvtimeo(a)
        # The kernel keeps timeouts in its own ticks: at least what was asked, never zero.
        assert got != (0, 0)
        assert got[0] * 1_000_000 + got[1] >= want[0] * 1_000_000 + want[1]


@pytest.mark.parametrize("seconds", [float("inf"), float("nan"), 1e300])
def test_impossible_timeouts_are_declined(seconds: float) -> None:
    a, b = socket.socketpair()
    with a, b:
        assert set_kernel_timeouts(a, seconds) is False
