"""Fixtures shared by the test modules, and the order the tests run in.

``serve`` starts loopback servers on port 0 the way every server test needs them: in a
background thread, always shut down after the test, and with no handler exception left
unseen (a test that provokes one on purpose clears ``handler_errors`` after checking it).

Order: ``make test`` runs two xdist workers with ``--dist worksteal``, which hands each worker
one contiguous slice of the collection (the first half, the second half) and later lets a worker
that runs dry take the back half of the other's queue. A long test must therefore start early
and the long tests must be shared: each slice starts with its share of the long tests, dealt
longest first to the slice with the fewest seconds so far, followed by short tests. "Long" is
what the last run measured (kept in pytest's cache), or the ``slow`` marker for a test not
measured yet (a clean clone, CI). The short tests keep their file order, so a module-scoped
fixture is set up about once per worker.
"""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Callable, Iterator
from itertools import islice

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


#: ``not_a_server(answer)`` -> "127.0.0.1:PORT" of a TCP server that is no robot or sensor.
NotAServer = Callable[[bytes | None], str]


@pytest.fixture
def not_a_server() -> Iterator[NotAServer]:
    """``not_a_server(answer)`` -> the address of a TCP server that answers whatever it
    receives with ``answer`` and closes (an HTTP server, say), or, with None, accepts and
    never answers (a hung one): what a user points a tool at by mistake."""
    listeners: list[socket.socket] = []
    conns: list[socket.socket] = []

    def start(answer: bytes | None) -> str:
        listener = socket.create_server(("127.0.0.1", 0))
        listeners.append(listener)

        def serve() -> None:
            while True:
                try:
                    conn, _ = listener.accept()
                except OSError:
                    return
                conns.append(conn)
                if answer is not None:
                    with contextlib.suppress(OSError):
                        conn.recv(4096)
                        conn.sendall(answer)
                        conn.close()

        threading.Thread(target=serve, daemon=True).start()
        return f"127.0.0.1:{listener.getsockname()[1]}"

    yield start
    for sock in listeners + conns:
        sock.close()


#: ``busy_port(udp)`` -> a port on 127.0.0.1 another socket holds until the test ends.
BusyPort = Callable[[bool], int]


@pytest.fixture
def busy_port() -> Iterator[BusyPort]:
    """``busy_port(udp)`` -> a TCP port that is listened on (or a UDP port that is bound):
    what a tool meets when another program, or a second copy of it, has the port."""
    held: list[socket.socket] = []

    def take(udp: bool) -> int:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM if udp else socket.SOCK_STREAM)
        held.append(sock)
        sock.bind(("127.0.0.1", 0))
        if not udp:
            sock.listen()
        port: int = sock.getsockname()[1]
        return port

    yield take
    for sock in held:
        sock.close()


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


DURATIONS_KEY = "rsf/durations"  # nodeid -> seconds (setup + call + teardown) of its last run
LONG_S = 1.0  # a test of at least this many seconds is moved to the front
UNMEASURED_SLOW_S = 10.0  # a slow-marked test not measured yet: long, after the measured giants


def _durations(config: pytest.Config) -> dict[str, float]:
    cache = getattr(config, "cache", None)  # None under -p no:cacheprovider
    return dict(cache.get(DURATIONS_KEY, {})) if cache is not None else {}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    measured = _durations(config)

    def seconds(item: pytest.Item) -> float:
        if item.nodeid in measured:
            return float(measured[item.nodeid])
        return UNMEASURED_SLOW_S if item.get_closest_marker("slow") else 0.0

    long = sorted((i for i in items if seconds(i) >= LONG_S), key=seconds, reverse=True)
    short = [i for i in items if seconds(i) < LONG_S]
    # the same order on every worker: xdist requires it
    items[:] = _slices(long, short, seconds, _workers(config))


def _workers(config: pytest.Config) -> int:
    """How many slices the collection is cut into: one per xdist worker (a worker cannot see
    the scheduler, its own ``--dist`` is "no"; ``make test`` uses worksteal)."""
    workerinput = getattr(config, "workerinput", None)
    return 1 if workerinput is None else int(workerinput["workercount"])


def _slices(
    long: list[pytest.Item],
    short: list[pytest.Item],
    seconds: Callable[[pytest.Item], float],
    workers: int,
) -> list[pytest.Item]:
    """``long`` (longest first) dealt to ``workers`` slices and the slices filled up with
    ``short`` to the sizes worksteal cuts (``xdist.scheduler.worksteal``: slice ``j`` holds
    ``remaining // (workers - j)`` items), so every worker starts with its share of long ones."""
    total = len(long) + len(short)
    sizes: list[int] = []
    for j in range(workers):
        sizes.append((total - sum(sizes)) // (workers - j))
    dealt: list[list[pytest.Item]] = [[] for _ in range(workers)]
    load = [0.0] * workers
    for item in long:
        j = min(range(workers), key=lambda j: (load[j], j))
        dealt[j].append(item)
        load[j] += seconds(item)
    out: list[pytest.Item] = []
    rest = iter(short)
    for size, mine in zip(sizes, dealt, strict=True):
        out += mine + list(islice(rest, max(0, size - len(mine))))
    return out + list(rest)


_ran: dict[str, float] = {}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if not isinstance(report, pytest.SubtestReport):  # the test's call report holds its time
        _ran[report.nodeid] = _ran.get(report.nodeid, 0.0) + report.duration


def pytest_sessionfinish(session: pytest.Session) -> None:
    config = session.config
    cache = getattr(config, "cache", None)
    # the controller sees every worker's reports; a worker would write only its share
    if cache is None or hasattr(config, "workerinput") or not _ran:
        return
    cache.set(DURATIONS_KEY, {**_durations(config), **_ran})
