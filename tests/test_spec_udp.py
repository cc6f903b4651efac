"""Kernel receive timestamps (spec/udp.py): the path where the platform has them, and the
fallback where it does not."""

from __future__ import annotations

import socket
import sys
import time
from collections.abc import Iterator

import pytest

from spec import udp
from spec.udp import (
    MAX_STAMP_AGE_S,
    arrival_time,
    bind_udp,
    enable_kernel_timestamps,
    enable_send_timestamps,
    recv_stamped,
    sent_stamp,
)


@pytest.fixture
def pair() -> Iterator[tuple[socket.socket, socket.socket]]:
    rx = bind_udp("127.0.0.1", 0)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    yield rx, tx
    rx.close()
    tx.close()


def _wait_readable(sock: socket.socket) -> None:
    sock.settimeout(3.0)


def _late_read(rx: socket.socket, tx: socket.socket) -> tuple[float, float, float]:
    """Send one datagram, read it 50 ms later: (time before the send, its arrival time,
    the time of the read), all on the monotonic clock."""
    before = time.monotonic()
    tx.sendto(b"trigger", rx.getsockname())
    time.sleep(0.05)  # the reader is late: it gets the CPU 50 ms after the datagram came
    _wait_readable(rx)
    data, source, stamp = recv_stamped(rx, 2048)
    read_at = time.monotonic()
    assert data == b"trigger" and source[1] == tx.getsockname()[1]
    assert stamp is not None
    return before, arrival_time(time.monotonic, stamp), read_at


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_TIMESTAMPNS is Linux's")
def test_a_datagram_read_late_keeps_its_arrival_time(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    rx, tx = pair
    assert enable_kernel_timestamps(rx)
    # Linux switches receive stamping on system-wide a moment after the first socket asks
    # (a deferred static key); a datagram received in that moment is stamped when read. So
    # the first of a few tries may be; the next ones are stamped on arrival.
    tries = [_late_read(rx, tx) for _ in range(3)]
    before, t, read_at = tries[-1]
    # the kernel's time, carried onto the monotonic clock: before the late read (the lower
    # bound allows for a preempted conversion on a busy machine)
    assert before - 5e-3 <= t <= read_at - 0.045


def test_without_kernel_stamps_the_arrival_is_the_read(
    pair: tuple[socket.socket, socket.socket],
) -> None:
    rx, tx = pair  # timestamps not enabled: no ancillary data
    tx.sendto(b"x", rx.getsockname())
    _wait_readable(rx)
    data, _, stamp = recv_stamped(rx, 2048)
    assert data == b"x" and stamp is None
    assert arrival_time(lambda: 42.0, None) == 42.0


def test_platform_without_the_option(
    pair: tuple[socket.socket, socket.socket], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(udp, "_SO_TIMESTAMPNS", None)
    assert not enable_kernel_timestamps(pair[0])


def test_arrival_time_on_any_clock_and_untrusted_stamps() -> None:
    now_ns = time.time_ns()
    t = arrival_time(lambda: 100.0, now_ns - 5_000_000)  # a datagram 5 ms old
    assert 99.994 < t <= 99.995 + 1e-3
    # a wall clock stepped between stamp and read: the stamp is not used
    assert arrival_time(lambda: 100.0, now_ns + 60 * 10**9) == 100.0
    assert arrival_time(lambda: 100.0, now_ns - int((MAX_STAMP_AGE_S + 1) * 1e9)) == 100.0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_TIMESTAMPING is Linux's")
def test_the_kernel_stamps_what_we_send(pair: tuple[socket.socket, socket.socket]) -> None:
    rx, _ = pair
    tx = bind_udp("127.0.0.1", 0)
    try:
        assert enable_send_timestamps(tx)
        assert enable_kernel_timestamps(rx)
        assert sent_stamp(tx) is None  # nothing sent yet: never blocks
        before = time.time_ns()
        tx.sendto(b"trigger", rx.getsockname())
        after = time.time_ns()
        sent = sent_stamp(tx)
        assert sent is not None and before <= sent <= after
        assert sent_stamp(tx) is None  # each stamp is read once
        _wait_readable(rx)
        _, _, received = recv_stamped(rx, 2048)
        assert received is not None and 0 <= received - sent < 1_000_000  # loopback: < 1 ms
        with pytest.raises(BlockingIOError):
            tx.recvfrom(2048)  # the stamps never show up as received data
    finally:
        tx.close()


def test_no_send_stamps_without_the_option(
    pair: tuple[socket.socket, socket.socket], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(udp, "_SO_TIMESTAMPING", None)
    assert not enable_send_timestamps(pair[0])
