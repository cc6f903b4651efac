"""The seqlocked robot state in shared memory (robotsocket.shared_state)."""

from __future__ import annotations

import subprocess
import sys
import threading
from collections.abc import Iterator

import pytest

from robotsocket.shared_state import SharedState, Snapshot, TornReadError

# A writer in another process: every field of record n carries n, so a record mixed from
# two writes is visible in any field.
_WRITER = """
import sys
from robotsocket.shared_state import SharedState, Snapshot
s = SharedState.attach(sys.argv[1])
print("ready", flush=True)
for n in range(1, int(sys.argv[2]) + 1):
    s.write(Snapshot(cycle=n, t=n * 0.004, measured=(float(n),) * 6, setpoint=(-float(n),) * 6,
                     queue=n, error_code=n % 7, error_message=str(n) * (n % 40)))
"""


def _consistent(s: Snapshot) -> bool:
    n = s.cycle
    return (
        s.t == n * 0.004
        and s.measured == (float(n),) * 6
        and s.setpoint == (-float(n),) * 6
        and s.queue == n
        and s.error_code == n % 7
        and s.error_message == str(n) * (n % 40)
    )


@pytest.fixture
def state() -> Iterator[SharedState]:
    s = SharedState.create(start_ns=123)
    yield s
    s.unlink()
    s.close()


def test_round_trip_through_another_mapping(state: SharedState) -> None:
    other = SharedState.attach(state.path)
    snap = Snapshot(
        cycle=7, t=0.028, measured=(1, 2, 3, 4, 5, 6), setpoint=(6, 5, 4, 3, 2, 1),
        powered=True, estop=False, moving=True, settled=False, queue=2, error_code=0x18,
        error_message="émergency stop engaged",
    )  # fmt: skip
    state.write(snap)
    assert other.read() == snap
    assert other.start_ns == 123
    other.close()


def test_a_long_message_is_cut_not_refused(state: SharedState) -> None:
    state.write(Snapshot(error_message="x" * 1000))
    assert state.read().error_message == "x" * 238


def test_no_torn_read_against_a_writer_in_another_process(state: SharedState) -> None:
    n = 20000
    writer = subprocess.Popen(
        [sys.executable, "-c", _WRITER, state.path, str(n)], stdout=subprocess.PIPE, text=True
    )
    assert writer.stdout is not None
    writer.stdout.readline()
    seen = set()
    try:
        while writer.poll() is None:
            snap = state.read()
            assert _consistent(snap), snap
            seen.add(snap.cycle)
    finally:
        writer.wait(30)
    assert writer.returncode == 0
    assert state.read().cycle == n
    assert len(seen) > 1  # the reader did run while the writer wrote


def test_a_read_waits_for_a_write_in_progress(state: SharedState) -> None:
    state.write(Snapshot(cycle=1))
    state.begin_write()  # the counter is odd: a writer is in the middle of a record
    got: list[Snapshot] = []
    reader = threading.Thread(target=lambda: got.append(state.read()))
    reader.start()
    reader.join(0.2)
    assert reader.is_alive() and not got  # it does not return the half-written record
    state.write(Snapshot(cycle=2))  # the write completes (counter even again)
    reader.join(5)
    assert got and got[0].cycle == 2


def test_a_writer_that_died_mid_write_is_an_error_not_a_hang(state: SharedState) -> None:
    state.begin_write()
    with pytest.raises(TornReadError):
        state.read()
