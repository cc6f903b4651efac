"""Timed corrections (AlterQueue, PROTOCOL.md section 5.3, RS-5.39 ... RS-5.46).

Motion cases: the arm stands still and the queued table moves the flange by at most 0.5 mm
(z, base frame) and back. The application is checked at the robot's own cycles: every
AlterQueue reply carries the correction applied at the last cycle and that cycle's time, so
the case compares the one with the table's interpolation at the other.
"""

from __future__ import annotations

import math
import time

from conformance.cases.alter import _back_at, _expect, _here, _ramped_back
from conformance.cases.robot import MOTION, _Motion, _status
from conformance.connection import Conn
from conformance.context import Context
from conformance.model import Fail, case
from spec import messages as M
from spec.errors import ErrorCode
from spec.params import IDENTITY_LOCATION, FloatArray, Location, Matrix
from spec.registry import CommandId as C

QUEUE = [
    *MOTION,
    C.HERE,
    C.ROBOT_STATUS,
    C.RESET_MOTION,
    C.ALTER_BEGIN,
    C.ALTER,
    C.ALTER_END,
    C.ALTER_QUEUE,
    C.GET_TIME,
]
#: The robot cycle and the entries a batch may hold [RS-5.40] and a queue holds [RS-5.43].
PERIOD = 0.004
MAX_BATCH = 4096
MIN_CAPACITY = 16384


def _queue(conn: Conn, times: list[float], dz: list[float]) -> M.AlterQueueReply:
    """AlterQueue of z corrections ``dz`` at ``times``."""
    rows = [v for z in dz for v in (0.0, 0.0, z, 0.0, 0.0, 0.0)]
    return conn.ask(M.AlterQueueRequest(FloatArray(times), Matrix(len(times), 6, rows)))


def _now(conn: Conn) -> float:
    return conn.ask(M.GetTimeRequest()).time


def _grid(t0: float, n: int) -> list[float]:
    """``n`` times one cycle apart from the first cycle after ``t0``."""
    k0 = int(t0 / PERIOD) + 1
    return [(k0 + k) * PERIOD for k in range(n)]


@case(
    "robot.alter_queue.rules",
    requirements=["RS-5.39", "RS-5.40", "RS-5.42", "RS-5.43", "RS-5.46"],
    tags=["robot", "motion", "alter"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=QUEUE,
)
def alter_queue_rules(ctx: Context) -> str:
    """AlterQueue outside alter mode, bad batches, a batch over the robot's capacity and
    Alter while entries are queued are refused and leave the queue as it was; entries in the
    past are late; an empty batch reports."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        empty = (FloatArray([]), Matrix(0, 6, []))
        _expect(
            conn,
            ErrorCode.BAD_STATE,
            "AlterQueue outside alter mode",
            "RS-5.39",
            C.ALTER_QUEUE,
            *empty,
        )
        conn.ok(C.ALTER_BEGIN, IDENTITY_LOCATION, 1.0)
        try:
            far = _now(conn) + 30.0  # far ahead: nothing of this case is due while it runs
            base = _queue(conn, [far, far + 0.1], [0.0, 0.0])
            if (base.accepted, base.depth) != (2, 2):
                raise Fail(
                    "a batch of two is not queued",
                    "accepted 2, depth 2",
                    f"{base.accepted:g}, {base.depth:g}",
                    requirement="RS-5.39",
                )
            z6 = [0.0] * 6
            bad = [
                ("times that do not increase", [far + 1.0, far + 1.0], z6 * 2),
                ("an 11 mm correction", [far + 1.0], [0.0, 11.0, 0.0, 0.0, 0.0, 0.0]),
                ("a non-finite time", [float("nan")], z6),
                (
                    f"{MAX_BATCH + 1} entries",
                    [far + 1.0 + k * PERIOD for k in range(MAX_BATCH + 1)],
                    z6 * (MAX_BATCH + 1),
                ),
            ]
            for what, times, rows in bad:
                _expect(
                    conn,
                    ErrorCode.OUT_OF_RANGE,
                    what,
                    "RS-5.40",
                    C.ALTER_QUEUE,
                    FloatArray(times),
                    Matrix(len(times), 6, rows),
                )
            late = _queue(conn, [_now(conn) - 1.0, far + 0.2], [0.0, 0.0])
            if (late.late, late.accepted) != (1, 1):
                raise Fail(
                    "an entry a second in the past is not dropped as late",
                    "late 1, accepted 1",
                    f"late {late.late:g}, accepted {late.accepted:g}",
                    requirement="RS-5.42",
                )
            _expect(
                conn,
                ErrorCode.BAD_STATE,
                "Alter while entries are queued",
                "RS-5.46",
                C.ALTER,
                Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            )
            # fill the queue to the capacity every robot has, then one more batch
            depth = late.depth
            t = far + 1.0
            while depth < MIN_CAPACITY:
                n = int(min(MAX_BATCH, MIN_CAPACITY - depth))
                depth = _queue(conn, [t + k * PERIOD for k in range(n)], [0.0] * n).depth
                t += n * PERIOD
            over = conn.call(C.ALTER_QUEUE, FloatArray([t]), Matrix(1, 6, z6))
            held = _queue(conn, [], []).depth
            if over.error is None:
                capacity = f"holds more than {MIN_CAPACITY:.0f} entries"
            elif over.error[0] != ErrorCode.BUSY or held != depth:
                raise Fail(
                    "a batch over the queue's capacity is not refused whole",
                    f"BUSY, depth {depth:g}",
                    f"{over.error}, depth {held:g}",
                    requirement="RS-5.43",
                )
            else:
                capacity = f"holds {depth:g} entries"
        finally:
            conn.call(C.ALTER_END)
        _ramped_back(conn, "RS-5.37")
        return f"the queue {capacity}"


@case(
    "robot.alter_queue.applied",
    requirements=["RS-5.41", "RS-5.44", "RS-5.45"],
    tags=["robot", "motion", "alter"],
    service="robot",
    motion=True,
    budget=60.0,
    commands=QUEUE,
)
def alter_queue_applied(ctx: Context) -> str:
    """A 0.5 mm ramp sent ahead in two batches in reverse order plus a repeat: the correction
    applied at each cycle is the table's interpolation at that cycle's time, the last entry
    is held, and the stream is lost `timeout` after it."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        p0 = _here(conn)
        conn.ok(C.ALTER_BEGIN, IDENTITY_LOCATION, 0.2)
        checked = 0
        try:
            # entries every 5 cycles (gaps the robot interpolates), starting 0.3 s ahead: a
            # 0.5 mm cosine ramp over 0.6 s, within RS-5.34 at every cycle
            times = _grid(_now(conn) + 0.3, 151)[::5]
            t0, t1 = times[0], times[-1]
            dz = [0.25 * (1.0 - math.cos(math.pi * (t - t0) / (t1 - t0))) for t in times]
            half = len(times) // 2
            _queue(conn, times[half:], dz[half:])
            _queue(conn, times[: half + 1], dz[: half + 1])  # overlaps the first by one entry
            _queue(conn, times[3:9], dz[3:9])  # a repeat: changes nothing [RS-5.41]
            worst = 0.0
            while True:
                r = _queue(conn, [], [])
                t = r.time
                if t > t1 + 0.1:
                    break
                if t0 <= t:
                    want = _interp(times, dz, t)
                    worst = max(worst, abs(r.applied.z - want))
                    checked += 1
                    if abs(r.applied.z - want) > 1e-6:
                        raise Fail(
                            "the correction applied at a cycle is not the table's "
                            f"interpolation at its time {t:.3f} s",
                            f"{want:.6f} mm",
                            f"{r.applied.z:.6f} mm",
                            requirement="RS-5.44",
                        )
                time.sleep(0.007)
            if r.held_total < 1:
                raise Fail(
                    "cycles past the last entry are not counted as held",
                    ">= 1",
                    r.held_total,
                    requirement="RS-5.44",
                )
            conn.pause(0.5)  # past the 0.2 s timeout after the last entry
            answer = conn.call(C.ALTER_QUEUE, FloatArray([]), Matrix(0, 6, []))
            if answer.error is None or answer.error[0] != ErrorCode.BAD_STATE:
                raise Fail(
                    "alter mode goes on after its queue ran out for longer than the timeout",
                    "BAD_STATE (stream lost)",
                    "accepted" if answer.error is None else answer.error,
                    requirement="RS-5.45",
                )
            last = _status(conn).last_error
            if last != ErrorCode.BAD_STATE:
                raise Fail(
                    "the lost stream is not reported", "BAD_STATE", last, requirement="RS-5.45"
                )
        finally:
            conn.call(C.ALTER_END)
        _ramped_back(conn, "RS-5.45")
        _back_at(conn, p0, "the correction of a lost stream is not taken back", "RS-5.45")
        conn.ok(C.RESET_MOTION)  # clears last_error for the cases after this one
        return f"{checked} cycles checked against the table, worst {worst * 1e3:.4f} µm"


def _interp(times: list[float], values: list[float], t: float) -> float:
    if t >= times[-1]:
        return values[-1]
    i = max(k for k in range(len(times)) if times[k] <= t)
    w = (t - times[i]) / (times[i + 1] - times[i])
    return values[i] + w * (values[i + 1] - values[i])
