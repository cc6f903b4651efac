"""What the socket shells share beyond start / stop / ``with``: the exceptions their loops
caught and survived (``handler_errors``), and a way for tests to collect every shell created
while they run, so that any such exception fails the test (tests/conftest.py) instead of
being found only in a log.

The shells are :class:`spec.server.FramedServer`, :class:`sync.udp.UdpSyncEndpoint` and
:class:`sensorsocket.udp.TriggerListener`.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Protocol


class Shell(Protocol):
    handler_errors: list[BaseException]


_collectors: list[list[Shell]] = []


def register(shell: Shell) -> None:
    """Called by a shell's constructor: every active :func:`collect` sees it."""
    for shells in _collectors:
        shells.append(shell)


@contextmanager
def collect() -> Iterator[list[Shell]]:
    """The shells created inside the ``with`` block (kept alive until it ends)."""
    shells: list[Shell] = []
    _collectors.append(shells)
    try:
        yield shells
    finally:
        _collectors.remove(shells)


__all__ = ["Shell", "collect", "register"]
