"""The robot's state in shared memory, behind a seqlock (docs/REALTIME.md).

The real-time process (:mod:`robotsocket.rtprocess`) is the only writer: every 4 ms cycle
and after every command it publishes the measured and commanded joints, the status and the
motion state. The request handlers of the server process read them without asking the
real-time process (a read costs a few microseconds and never blocks the writer).

Seqlock: the writer makes the sequence counter odd, writes the record, makes it even again;
a reader copies the record between two reads of the counter and retries when the counter
was odd or changed (it read a record being written). The record lives in a file under
/dev/shm (any directory works) mapped by both processes; the owner unlinks it once both
have it open, so a killed process leaves nothing behind.
"""

from __future__ import annotations

import mmap
import os
import struct
import tempfile
import threading
import time
from dataclasses import dataclass

__all__ = ["SharedState", "Snapshot", "TornReadError"]

#: Sequence counter (u64), then the start of the robot clock on CLOCK_MONOTONIC (ns, written
#: once, before the reader attaches).
_HEADER = struct.Struct("<Qq")
#: cycle, t_k (s), measured joints (6), setpoint (6), powered, estop, moving, settled,
#: queue length, last error code (0: none), message length, message (UTF-8), the last move's
#: outcome (UTF-8, [RS-5.50]), its reason's length and reason (UTF-8).
_RECORD = struct.Struct("<qd6d6d????iiH238s8sH238s")
_SIZE = _HEADER.size + _RECORD.size
MESSAGE_BYTES = 238
#: A reader that sees a write in progress for this long gives up (s; a writer that died in
#: the middle of a write: an error, never a hang). A write takes microseconds.
MAX_WAIT_S = 1.0


class TornReadError(RuntimeError):
    """No consistent record could be read (the writer died in the middle of a write)."""


@dataclass(frozen=True)
class Snapshot:
    """What the robot was at one instant. Joints in degrees, t in robot-clock seconds."""

    cycle: int = 0
    t: float = 0.0
    measured: tuple[float, ...] = (0.0,) * 6
    setpoint: tuple[float, ...] = (0.0,) * 6
    powered: bool = False
    estop: bool = False
    moving: bool = False
    settled: bool = True
    queue: int = 0
    error_code: int = 0
    error_message: str = ""
    outcome: str = "reached"
    outcome_reason: str = ""

    def pack(self) -> bytes:
        msg = self.error_message.encode()[:MESSAGE_BYTES]
        why = self.outcome_reason.encode()[:MESSAGE_BYTES]
        return _RECORD.pack(
            self.cycle, self.t, *self.measured, *self.setpoint, self.powered, self.estop,
            self.moving, self.settled, self.queue, self.error_code, len(msg), msg,
            self.outcome.encode(), len(why), why,
        )  # fmt: skip

    @classmethod
    def unpack(cls, raw: bytes) -> Snapshot:
        v = _RECORD.unpack(raw)
        return cls(
            v[0], v[1], tuple(v[2:8]), tuple(v[8:14]), v[14], v[15], v[16], v[17], v[18],
            v[19], v[21][: v[20]].decode(errors="replace"),
            v[22].rstrip(b"\0").decode(errors="replace"), v[24][: v[23]].decode(errors="replace"),
        )  # fmt: skip


class SharedState:
    """One seqlocked :class:`Snapshot` in a shared mapping: :meth:`create` (the writer's side,
    a new file) or :meth:`attach` (by path); :meth:`unlink` once both sides have it open."""

    def __init__(self, path: str, fd: int) -> None:
        self.path = path
        self._fd = fd
        self._mm = mmap.mmap(fd, _SIZE)
        self._write_lock = threading.Lock()  # one writer at a time: the seqlock's premise

    @classmethod
    def create(cls, start_ns: int | None = None) -> SharedState:
        base = "/dev/shm" if os.path.isdir("/dev/shm") else None
        fd, path = tempfile.mkstemp(prefix="robot-state-", dir=base)
        os.ftruncate(fd, _SIZE)
        state = cls(path, fd)
        _HEADER.pack_into(state._mm, 0, 0, time.monotonic_ns() if start_ns is None else start_ns)
        state._store(Snapshot())
        return state

    @classmethod
    def attach(cls, path: str) -> SharedState:
        return cls(path, os.open(path, os.O_RDWR))

    def unlink(self) -> None:
        try:
            os.unlink(self.path)
        except FileNotFoundError:
            pass

    def close(self) -> None:
        self._mm.close()
        os.close(self._fd)

    @property
    def start_ns(self) -> int:
        """The robot clock's zero on ``time.monotonic_ns`` (the same clock in every process)."""
        start: int = _HEADER.unpack_from(self._mm, 0)[1]
        return start

    def set_start_ns(self, start_ns: int) -> None:
        with self._write_lock:
            struct.pack_into("<q", self._mm, 8, start_ns)

    def now(self) -> float:
        """Robot-clock seconds, read in any process."""
        return (time.monotonic_ns() - self.start_ns) / 1e9

    # --- the seqlock -------------------------------------------------------------------------

    def write(self, snap: Snapshot) -> None:
        with self._write_lock:
            self._store(snap)

    def _store(self, snap: Snapshot) -> None:
        odd = struct.unpack_from("<Q", self._mm, 0)[0] | 1  # odd: a write is in progress
        struct.pack_into("<Q", self._mm, 0, odd)
        self._mm[_HEADER.size : _SIZE] = snap.pack()
        struct.pack_into("<Q", self._mm, 0, odd + 1)

    def begin_write(self) -> None:
        """Tests: leave the record as a writer killed mid-write would (counter odd)."""
        seq = struct.unpack_from("<Q", self._mm, 0)[0]
        struct.pack_into("<Q", self._mm, 0, seq | 1)

    def read(self) -> Snapshot:
        mm = self._mm
        tries = 0
        give_up = 0.0
        while True:
            before = struct.unpack_from("<Q", mm, 0)[0]
            if not before & 1:
                raw = mm[_HEADER.size : _SIZE]
                if struct.unpack_from("<Q", mm, 0)[0] == before:
                    return Snapshot.unpack(raw)
            tries += 1
            if tries > 100:  # not a write in progress on the other core: yield, and time it
                now = time.monotonic()
                give_up = give_up or now + MAX_WAIT_S
                if now > give_up:
                    raise TornReadError("the robot state is being written and never finishes")
                time.sleep(0)
