"""The process outputs follow control (PROTOCOL.md section 7): laser, gas and crossjet go off
when control ends, the laser first [RS-7.21].

Switching a laser on is as dangerous on a real cell as moving the arm: these cases run only
with ``--allow-motion``, and switch on only the outputs the robot lists as laser, gas or
crossjet."""

from __future__ import annotations

import time

from conformance.cases._util import io_names
from conformance.connection import Conn
from conformance.context import Context
from conformance.model import Fail, NotApplicable, case
from spec import messages as M
from spec.errors import ErrorCode
from spec.registry import CommandId as C

#: The process outputs of RS-7.21, in the order they go off.
PROCESS_OUTPUTS = ("laser", "crossjet", "gas")


def _process_outputs(conn: Conn) -> list[str]:
    outputs = set(io_names(conn)[0])
    names = [n for n in PROCESS_OUTPUTS if n in outputs]
    if not names:
        raise NotApplicable("the robot lists none of the outputs laser, gas, crossjet")
    return names


def _on(conn: Conn, names: list[str]) -> dict[str, bool]:
    """Switch ``names`` on; return what ReadIO says of each."""
    for name in names:
        conn.ok(C.SET_OUTPUT, name, True)
    return {name: conn.ask(M.ReadIORequest(name)).value for name in names}


def _still_on(conn: Conn, names: list[str]) -> list[str]:
    """Those of ``names`` that ReadIO reads on."""
    return [name for name in names if conn.ask(M.ReadIORequest(name)).value]


def _laser(conn: Conn) -> bool:
    """Whether the sensor's laser is on (SensorStatus)."""
    return conn.ask(M.SensorStatusRequest()).laser


@case(
    "robot.outputs.off_on_release",
    requirements=["RS-7.21"],
    tags=["robot", "control", "io"],
    service="robot",
    motion=True,
    commands=[C.SET_OUTPUT, C.READ_IO, C.LIST_IO],
)
def off_on_release(ctx: Context) -> str:
    """After ReleaseControl every process output that was on reads off."""
    conn = ctx.connect()
    names = _process_outputs(conn)
    ctx.take_control(conn)
    try:
        was = _on(conn, names)
    finally:
        conn.ok(C.RELEASE_CONTROL)
    still = _still_on(conn, names)
    if still:
        raise Fail("outputs stayed on after ReleaseControl", "all off", f"on: {', '.join(still)}")
    return f"{', '.join(n for n in names if was[n])} on, off after the release"


@case(
    "robot.outputs.off_on_close",
    requirements=["RS-7.21", "RS-7.10"],
    tags=["robot", "control", "io"],
    service="robot",
    motion=True,
    commands=[C.SET_OUTPUT, C.READ_IO, C.LIST_IO],
)
def off_on_close(ctx: Context) -> str:
    """When the controlling connection closes with the outputs on, another connection reads
    them off (within the harness timeout)."""
    watcher = ctx.connect()
    names = _process_outputs(watcher)
    conn = ctx.connect()
    ctx.take_control(conn)
    _on(conn, names)
    conn.close()
    closed = time.monotonic()
    while True:
        still = _still_on(watcher, names)
        if not still:
            return f"off {time.monotonic() - closed:.3f} s after the close (harness clock)"
        if time.monotonic() > closed + ctx.timeout:
            raise Fail(
                "outputs stayed on after the controller's connection closed",
                "all off",
                f"on: {', '.join(still)}",
            )
        time.sleep(0.01)


@case(
    "robot.outputs.off_on_estop",
    requirements=["RS-7.21", "RS-5.55", "RS-5.20", "RS-5.53"],
    tags=["robot", "safety", "io"],
    service="robot",
    motion=True,
    commands=[C.SET_OUTPUT, C.READ_IO, C.LIST_IO, C.EMERGENCY_STOP, C.RESET_EMERGENCY_STOP],
)
def off_on_estop(ctx: Context) -> str:
    """EmergencyStop switches every process output off while control stays; under the
    engaged stop SetOutput to on is EMERGENCY_STOP and to off is executed; after
    ResetEmergencyStop an output can be switched on and off again (no arm power needed)."""
    conn = ctx.connect()
    names = _process_outputs(conn)
    ctx.take_control(conn)
    try:
        _on(conn, names)
        conn.ok(C.EMERGENCY_STOP)
        still = _still_on(conn, names)
        if still:
            raise Fail(
                "outputs stayed on after EmergencyStop",
                "all off",
                f"on: {', '.join(still)}",
                requirement="RS-7.21",
            )
        on = conn.call(C.SET_OUTPUT, names[-1], True)
        off = conn.call(C.SET_OUTPUT, names[-1], False)
        conn.ok(C.RESET_EMERGENCY_STOP)
        if on.error is None or on.error[0] != ErrorCode.EMERGENCY_STOP or off.error is not None:
            raise Fail(
                "SetOutput under an engaged emergency stop",
                "on: EMERGENCY_STOP, off: executed",
                f"on: {on.error or 'executed'}, off: {off.error or 'executed'}",
                requirement="RS-5.55",
            )
        # [RS-5.55] with power off (EmergencyStop switched it off) both directions work.
        again = conn.call(C.SET_OUTPUT, names[-1], True)
        off_again = conn.call(C.SET_OUTPUT, names[-1], False)
        if again.error is not None or off_again.error is not None:
            raise Fail(
                "SetOutput after ResetEmergencyStop (power is off; outputs need none)",
                "on: executed, off: executed",
                f"on: {again.error or 'executed'}, off: {off_again.error or 'executed'}",
                requirement="RS-5.55",
            )
    finally:
        conn.call(C.RELEASE_CONTROL)  # the outputs go off with control [RS-7.21]
    return f"{', '.join(names)} off at EmergencyStop"


@case(
    "sensor.laser.release_and_loss",
    requirements=["RS-7.23"],
    tags=["sensor", "control"],
    service="sensor",
    commands=[C.SET_LASER, C.SENSOR_STATUS],
)
def sensor_laser_release_and_loss(ctx: Context) -> str:
    """The measuring laser stays on over ReleaseControl and goes off when the controller's
    connection closes; the case leaves it as it found it."""
    watcher = ctx.connect()
    was = _laser(watcher)
    conn = ctx.connect()
    ctx.take_control(conn)
    conn.ok(C.SET_LASER, True)
    conn.ok(C.RELEASE_CONTROL)
    if not _laser(watcher):
        raise Fail("the sensor laser went off on ReleaseControl", "on", "off")
    ctx.take_control(conn)
    conn.close()
    closed = time.monotonic()
    while _laser(watcher):
        if time.monotonic() > closed + ctx.timeout:
            raise Fail("the sensor laser stayed on after its controller was lost", "off", "on")
        time.sleep(0.01)
    seen = time.monotonic() - closed
    ctx.take_control(watcher)
    try:
        watcher.ok(C.SET_LASER, was)
    finally:
        watcher.call(C.RELEASE_CONTROL)
    return f"on after the release, off {seen:.3f} s after the close (harness clock)"
