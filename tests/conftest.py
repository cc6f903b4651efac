"""Fixtures shared by the test modules.

``serve`` starts loopback servers on port 0 the way every server test needs them: in a
background thread, always shut down after the test, and with no handler exception left
unseen (a test that provokes one on purpose clears ``handler_errors`` after checking it).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from spec.server import FramedServer, ServerPolicy, Service
from spec.shells import collect

Serve = Callable[[Service, ServerPolicy | None], FramedServer]


@pytest.fixture
def serve() -> Iterator[Serve]:
    """``serve(service, policy)`` -> a started FramedServer on 127.0.0.1, port 0."""
    servers: list[FramedServer] = []

    def start(service: Service, policy: ServerPolicy | None = None) -> FramedServer:
        srv = FramedServer(service, "127.0.0.1", 0, policy)
        servers.append(srv)
        return srv.start()

    yield start
    for srv in servers:
        srv.shutdown()
    for srv in servers:
        assert not srv.handler_errors, srv.handler_errors


@pytest.fixture(autouse=True)
def _shell_errors_are_fatal() -> Iterator[None]:
    """Any exception a socket shell's loop caught and survived during a test fails it (a
    test that provokes one on purpose clears ``handler_errors`` after checking it)."""
    with collect() as shells:
        yield
    for shell in shells:
        assert not shell.handler_errors, (type(shell).__name__, shell.handler_errors)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Say loudly at the end when the browser tests could not run (no chromium)."""
    reasons = {
        str(r.longrepr[2])
        for r in terminalreporter.stats.get("skipped", [])
        if isinstance(r.longrepr, tuple) and "BROWSER TESTS SKIPPED" in str(r.longrepr[2])
    }
    for reason in sorted(reasons):
        terminalreporter.write_sep("!", reason.removeprefix("Skipped: "), red=True, bold=True)
