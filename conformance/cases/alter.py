"""Path correction (alter mode, PROTOCOL.md section 5.3, RS-5.32 ... RS-5.38).

Motion cases: the arm stands still and the correction moves the flange by at most 1 mm
(z, base frame) and back; the stream-lost case lets a 0.5 mm correction time out.
"""

from __future__ import annotations

import math
import time

from conformance.cases.robot import MOTION, _Motion, _status, _wait_still
from conformance.connection import Conn
from conformance.context import Context
from conformance.model import Fail, case
from spec import messages as M
from spec.errors import ErrorCode
from spec.params import IDENTITY_LOCATION, Location, Value
from spec.registry import CommandId as C

ALTER = [*MOTION, C.HERE, C.ROBOT_STATUS, C.RESET_MOTION, C.ALTER_BEGIN, C.ALTER, C.ALTER_END]
#: Time a correction of 1 mm needs at the limits of RS-5.34, with a wide margin.
SETTLE_S = 2.0


def _here(conn: Conn) -> tuple[float, ...]:
    return conn.ask(M.HereRequest(IDENTITY_LOCATION, IDENTITY_LOCATION)).location.as_tuple()


def _expect(
    conn: Conn, code: ErrorCode, what: str, requirement: str, command: int, *params: Value
) -> None:
    answer = conn.call(command, *params)
    if answer.error is None or answer.error[0] != code:
        raise Fail(
            f"{what} is not refused",
            code.name,
            "accepted" if answer.error is None else answer.error,
            requirement=requirement,
        )


def _stream(conn: Conn, dz: float, seconds: float) -> float:
    """Alter(dz) every 20 ms for ``seconds``; the applied z correction of the last reply."""
    applied = 0.0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        applied = conn.ask(M.AlterRequest(Location(0.0, 0.0, dz, 0.0, 0.0, 0.0))).applied.z
        time.sleep(0.02)
    return applied


@case(
    "robot.alter.rules",
    requirements=["RS-5.32", "RS-5.33", "RS-5.37"],
    tags=["robot", "motion", "alter"],
    service="robot",
    motion=True,
    budget=30.0,
    commands=ALTER,
)
def alter_rules(ctx: Context) -> str:
    """Alter outside alter mode, a second AlterBegin, a bad timeout and an 11 mm correction are
    refused; a 1 mm correction moves the standing tool by 1 mm; AlterEnd takes it back."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        p0 = _here(conn)
        zero = Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        _expect(conn, ErrorCode.BAD_STATE, "Alter outside alter mode", "RS-5.33", C.ALTER, zero)
        _expect(
            conn,
            ErrorCode.OUT_OF_RANGE,
            "AlterBegin with a 1 ms timeout",
            "RS-5.32",
            C.ALTER_BEGIN,
            IDENTITY_LOCATION,
            0.001,
        )
        conn.ok(C.ALTER_BEGIN, IDENTITY_LOCATION, 1.0)
        try:
            _expect(
                conn,
                ErrorCode.BAD_STATE,
                "a second AlterBegin",
                "RS-5.32",
                C.ALTER_BEGIN,
                IDENTITY_LOCATION,
                1.0,
            )
            big = Location(0.0, 11.0, 0.0, 0.0, 0.0, 0.0)
            _expect(conn, ErrorCode.OUT_OF_RANGE, "an 11 mm correction", "RS-5.33", C.ALTER, big)
            applied = _stream(conn, 1.0, SETTLE_S)
            if abs(applied - 1.0) > 1e-3:
                raise Fail(
                    "the applied correction does not reach the commanded one",
                    "1 mm",
                    f"{applied:.4f} mm",
                    requirement="RS-5.33",
                )
            moved = _here(conn)[2] - p0[2]
            if abs(moved - 1.0) > 0.01:
                raise Fail(
                    "a 1 mm z correction does not move the tool by 1 mm",
                    "1 mm",
                    f"{moved:.4f} mm",
                    requirement="RS-5.32",
                )
        finally:
            conn.call(C.ALTER_END)
        _expect(conn, ErrorCode.BAD_STATE, "AlterEnd outside alter mode", "RS-5.37", C.ALTER_END)
        _ramped_back(conn, "RS-5.37")
        back = _back_at(conn, p0, "the tool is not back after AlterEnd", "RS-5.37")
        return f"1 mm correction applied, back within {back * 1000:.1f} µm"


@case(
    "robot.alter.stream_lost",
    requirements=["RS-5.35", "RS-5.36"],
    tags=["robot", "motion", "alter", "safety"],
    service="robot",
    motion=True,
    budget=30.0,
    commands=ALTER,
)
def alter_stream_lost(ctx: Context) -> None:
    """A stream silent for longer than its 50 ms timeout is lost: alter mode ends (Alter is
    BAD_STATE), last_error is BAD_STATE and the correction ramps back to zero."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        p0 = _here(conn)
        conn.ok(C.ALTER_BEGIN, IDENTITY_LOCATION, 0.05)
        conn.ok(C.ALTER, Location(0.0, 0.0, 0.5, 0.0, 0.0, 0.0))
        conn.pause(0.5)  # no Alter: a Ping is no correction
        answer = conn.call(C.ALTER, Location(0.0, 0.0, 0.5, 0.0, 0.0, 0.0))
        if answer.error is None or answer.error[0] != ErrorCode.BAD_STATE:
            conn.call(C.ALTER_END)
            raise Fail(
                "alter mode goes on after 0.5 s without a correction",
                "BAD_STATE (stream lost)",
                "accepted" if answer.error is None else answer.error,
                requirement="RS-5.36",
            )
        last = _status(conn).last_error
        if last != ErrorCode.BAD_STATE:
            raise Fail("the lost stream is not reported", "BAD_STATE", last, requirement="RS-5.36")
        _ramped_back(conn, "RS-5.36")
        _back_at(conn, p0, "the correction of a lost stream is not taken back", "RS-5.36")
        conn.ok(C.RESET_MOTION)  # clears last_error for the cases after this one


@case(
    "robot.alter.limits",
    requirements=["RS-5.34"],
    tags=["robot", "motion", "alter", "limits"],
    service="robot",
    motion=True,
    budget=30.0,
    commands=[*ALTER, C.GET_TIME],
)
def alter_limits(ctx: Context) -> str:
    """A 5 mm step of the correction is applied no faster than 100 mm/s (robot clock, one
    cycle of slack) and never beyond 5 mm."""
    with _Motion(ctx) as m:
        conn = m.conn
        m.power()
        step = Location(0.0, 0.0, 5.0, 0.0, 0.0, 0.0)
        conn.ok(C.ALTER_BEGIN, IDENTITY_LOCATION, 1.0)
        fastest = 0.0
        try:
            t0 = conn.ask(M.GetTimeRequest()).time
            end = time.monotonic() + SETTLE_S
            while time.monotonic() < end:
                applied = conn.ask(M.AlterRequest(step)).applied
                now = conn.ask(M.GetTimeRequest()).time
                # the reply's correction was applied at a cycle no later than `now`
                allowed = 100.0 * (now - t0) + 100.0 * 0.004 + 1e-6
                if applied.z > allowed or applied.z > 5.0 + 1e-6:
                    raise Fail(
                        "the correction is applied too fast or overshoots",
                        f"<= {min(allowed, 5.0):.3f} mm after {now - t0:.3f} s",
                        f"{applied.z:.3f} mm",
                        requirement="RS-5.34",
                    )
                if now > t0:
                    fastest = max(fastest, applied.z / (now - t0))
                time.sleep(0.01)
        finally:
            conn.call(C.ALTER_END)
        _ramped_back(conn, "RS-5.37")
        return f"mean speed of the step at most {fastest:.0f} mm/s"


@case(
    "robot.alter.control_lost",
    requirements=["RS-5.38"],
    tags=["robot", "motion", "alter", "safety", "control"],
    service="robot",
    motion=True,
    budget=30.0,
    commands=ALTER,
)
def alter_control_lost(ctx: Context) -> None:
    """The controller closes its connection in alter mode: alter mode ends and the correction
    goes back to zero (a new controller finds it not active and the tool back)."""
    first = ctx.connect()
    ctx.take_control(first)
    if _status(first).moving:
        first.close()
        raise Fail("the arm is already moving", "still", "moving")
    first.ok(C.ENABLE_POWER)
    p0 = _here(first)
    first.ok(C.ALTER_BEGIN, IDENTITY_LOCATION, 1.0)
    _stream(first, 0.5, 0.3)
    first.close()  # control lost [RS-7.10]
    watcher = ctx.connect()
    _ramped_back(watcher, "RS-5.38")
    with _Motion(ctx) as m:
        conn = m.conn
        answer = conn.call(C.ALTER, Location(0.0, 0.0, 0.5, 0.0, 0.0, 0.0))
        if answer.error is None or answer.error[0] != ErrorCode.BAD_STATE:
            conn.call(C.ALTER_END)
            raise Fail(
                "alter mode survives the loss of its controller",
                "BAD_STATE for Alter",
                "accepted" if answer.error is None else answer.error,
                requirement="RS-5.38",
            )
        _back_at(conn, p0, "the correction outlives its controller", "RS-5.38")


def _ramped_back(conn: Conn, requirement: str) -> None:
    """The correction ramps back to zero: the arm comes to rest within 10 s."""
    if not _wait_still(conn, 10.0):
        raise Fail("the correction does not ramp back", "still", "moving", requirement=requirement)


def _back_at(conn: Conn, p0: tuple[float, ...], what: str, requirement: str) -> float:
    """The tool is back within 0.01 mm of ``p0`` (mm); the distance, or Fail saying ``what``."""
    back = math.dist(_here(conn)[:3], p0[:3])
    if back > 0.01:
        raise Fail(what, "<= 0.01 mm", f"{back:.4f} mm", requirement=requirement)
    return back
