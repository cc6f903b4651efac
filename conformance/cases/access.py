"""Access control (PROTOCOL.md sections 7 and 9): token guessing is slowed [RS-7.20]; the robot
takes data datagrams only from its sensor endpoint [SY-3.7]."""

from __future__ import annotations

import time

from conformance.cases.sync import ROBOT_SYNC, _int, _sink, playing_sensor
from conformance.connection import UdpConn
from conformance.context import Context
from conformance.model import Fail, Informational, NotApplicable, case
from spec import messages as M
from spec.datagrams import SensorData, Trigger, decode_datagram, encode_data
from spec.errors import DatagramError, ErrorCode
from spec.registry import CommandId as C
from spec.wire import PacketKind, SensorStatus

#: [RS-7.20] the back-off starts after at most this many failures in a row.
FAILURES_BEFORE_BACKOFF = 3
#: [RS-7.20] the back-off may grow to this before the right token is taken again.
LONGEST_BACKOFF = 15.0  # s: the spec's 10 s cap plus slack


@case(
    "control.token_backoff",
    requirements=["RS-7.20", "RS-7.26"],
    tags=["control", "security"],
    budget=LONGEST_BACKOFF + 5.0,
)
def token_backoff(ctx: Context) -> str:
    """After three wrong tokens in a row, even the right token is refused with AUTH_FAILED
    for a while (the back-off); later it is accepted again, although it was tried every 50 ms
    meanwhile."""
    conn = ctx.connect()
    wrong = ctx.options.token + "-wrong-conformance-token"
    first = conn.call(C.TAKE_CONTROL, wrong)
    if first.error is None:
        conn.call(C.RELEASE_CONTROL)
        raise NotApplicable("the endpoint has no control token (any token is accepted)")
    if not ctx.options.token:
        raise NotApplicable("a token is configured; pass it with --token to check the back-off")
    # The last wrong token and the right one go out in one write: the right one reaches the
    # server right after the failure that starts the back-off, however slow the network.
    for _ in range(FAILURES_BEFORE_BACKOFF - 2):
        conn.error(C.TAKE_CONTROL, ErrorCode.AUTH_FAILED, wrong)
    conn.request(C.TAKE_CONTROL, wrong)
    conn.request(C.TAKE_CONTROL, ctx.options.token)
    last_wrong, right = conn.recv_packet(), conn.recv_packet()
    if last_wrong.error is None or last_wrong.error[0] != ErrorCode.AUTH_FAILED:
        raise Fail("a wrong token was not refused", "AUTH_FAILED", last_wrong.error)
    if right.kind is not PacketKind.ERROR:
        conn.call(C.RELEASE_CONTROL)
        raise Fail(
            f"the right token was accepted right after {FAILURES_BEFORE_BACKOFF} wrong ones",
            "AUTH_FAILED during the back-off",
            "control granted",
        )
    if right.error is None or right.error[0] != ErrorCode.AUTH_FAILED:
        raise Fail("wrong error during the back-off", "AUTH_FAILED", right.error)
    t0 = time.monotonic()
    deadline = t0 + ctx.scaled(LONGEST_BACKOFF)
    # The back-off ends; the right token works again (and resets the count). The attempts
    # refused meanwhile, every 50 ms, must not extend it [RS-7.26].
    while True:
        answer = conn.call(C.TAKE_CONTROL, ctx.options.token)
        if answer.error is None:
            break
        if time.monotonic() > deadline:
            raise Fail(
                "the right token stayed refused after the back-off (attempts refused during"
                " it must not extend it)",
                f"accepted within {LONGEST_BACKOFF:g} s",
                answer.error,
                requirement="RS-7.26",
            )
        time.sleep(0.05)
    conn.ok(C.RELEASE_CONTROL)
    return f"back-off ended after {time.monotonic() - t0:.2f} s; message: {right.error[1]!r}"


@case(
    "robot.sync.foreign_data",
    requirements=["SY-3.7"],
    level="SHOULD",
    tags=["sync", "robot", "security"],
    service="robot",
    commands=[*ROBOT_SYNC, C.GET_SYNC_STATISTICS, C.GET_SEAM_POINTS],
    budget=10.0,
)
def foreign_data(ctx: Context) -> str:
    """Two triggers: the first answered from another port than the sensor endpoint, the second
    from the sensor endpoint. Only the second may become a seam point."""
    answered: list[int] = []
    with (
        playing_sensor(ctx, 98) as (conn, u),
        _sink(ctx, conn.sock.getsockname()[0]) as stranger,
    ):
        other = UdpConn(stranger, ("", 0), ctx.log, 97)
        before = conn.ask(M.GetSyncStatisticsRequest()).as_dict()
        first = conn.ask(M.StartTriggersRequest(50.0, 2)).first_index
        deadline = time.monotonic() + ctx.scaled(2.0)
        while len(answered) < 2 and time.monotonic() < deadline:
            conn.keep_alive()
            got = u.recv(0.05)
            if got is None:
                continue
            raw, source, t = got
            try:
                trig = decode_datagram(raw)
            except DatagramError:
                continue  # the sync cases judge the robot's triggers
            if not isinstance(trig, Trigger):
                continue
            data = encode_data(
                SensorData(
                    trig.index,
                    SensorStatus.FOUND,
                    (0.0, 1.25, 80.0, 0.0, 0.0, 0.0),
                    0.9,
                    trig.t_trigger,
                    t,
                    t + 1e-4,
                    t + 3.6e-3,
                )
            )
            sender = other if not answered else u
            sender.target = source
            sender.send(
                data, f"data {trig.index} from {'another port' if not answered else 'the sensor'}"
            )
            answered.append(trig.index)
        conn.pause(0.3)  # the robot matches data once the joint samples around t_S are in
        after = conn.ask(M.GetSyncStatisticsRequest()).as_dict()
        points = conn.ask(M.GetSeamPointsRequest(first - 1)).points
    if len(answered) < 2:
        raise Informational(f"the robot sent {len(answered)} of 2 triggers; cannot judge")
    got_idx = {int(r[0]) for r in points.to_rows()}
    ctx.details["received_delta"] = _int(after["received"]) - _int(before["received"])
    if answered[0] in got_idx:
        raise Fail(
            "data from another port than the sensor endpoint became a seam point",
            "dropped and counted",
            f"seam point for index {answered[0]}",
        )
    if answered[1] not in got_idx:
        raise Informational("the sensor's own data made no seam point either; cannot judge")
    return "data from another port dropped; the sensor's own matched"
