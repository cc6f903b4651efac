"""What the socket shells share beyond start / stop / ``with``: the exceptions their loops
caught and survived (``handler_errors``), and a registry of the live shells, so that tests
can make any such exception fatal (tests/conftest.py) instead of finding it only in a log.

The shells are :class:`spec.server.FramedServer`, :class:`sync.udp.UdpSyncEndpoint` and
:class:`sensorsocket.udp.TriggerListener`.
"""

from __future__ import annotations

import weakref
from typing import Protocol


class Shell(Protocol):
    handler_errors: list[BaseException]


_LIVE: weakref.WeakSet[Shell] = weakref.WeakSet()


def register(shell: Shell) -> None:
    """Called by a shell's constructor."""
    _LIVE.add(shell)


def live_shells() -> list[Shell]:
    """The shells created and not yet garbage-collected."""
    return list(_LIVE)


__all__ = ["Shell", "live_shells", "register"]
