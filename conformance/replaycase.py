"""A recorded session as a conformance case (``--replay FILE``): a field failure turned into a
regression test.

The case ``replay.<file stem>`` sends the requests of every recorded connection of the
service again (spec.replay, as ``python -m spec replay`` does) and fails when an answer
differs from the recorded one. It judges the endpoint against the recording, not against a
rule of PROTOCOL.md: its requirement column says ``recording``.
"""

from __future__ import annotations

from pathlib import Path

from conformance.context import Context
from conformance.model import Case, EndpointGone, Fail, add_case
from spec import replay
from spec.pcapng import PcapError

__all__ = ["RECORDING", "ReplayUsageError", "add_replay_case"]

#: The requirement a replay case names: the recorded answers, not a rule of the spec.
RECORDING = "recording"
#: Differences named in the case's message; the rest are counted.
SHOWN = 5


class ReplayUsageError(ValueError):
    """The recording cannot be used (unreadable, or nothing of the service in it)."""


def add_replay_case(path: str, service: str) -> Case:
    """Register the case that replays ``path`` against the ``service`` endpoint."""
    try:
        connections = replay.load(path)
    except PcapError as exc:
        raise ReplayUsageError(str(exc)) from None
    # a connection whose service the capture does not tell is taken as the one tested
    mine = [c for c in connections if c.service in (service, None) and c.exchanges]
    if not mine:
        raise ReplayUsageError(f"{path} holds no requests to a {service} endpoint")
    requests = sum(len(c.exchanges) for c in mine)
    moving = replay.motion_commands(mine)

    def replay_recording(ctx: Context) -> str:
        different: list[str] = []
        number = 0
        for conn in mine:
            try:
                results = replay.replay(conn, (ctx.host, ctx.port), timeout=ctx.timeout)
            except replay.EndpointLost as exc:
                raise EndpointGone(str(exc)) from None
            for r in results:
                number += 1
                if r.differences:
                    x = r.exchange
                    different.append(
                        f"#{number} {x.name} id={x.request.request_id}: {'; '.join(r.differences)}"
                    )
        if different:
            more = len(different) - SHOWN
            shown = "\n".join(different[:SHOWN]) + (f"\n… and {more} more" if more > 0 else "")
            raise Fail(
                f"{len(different)} of {number} answers differ from the recording",
                expected="the recorded answers",
                actual=shown,
            )
        over = f"{len(mine)} connection" + ("s" if len(mine) > 1 else "")
        return f"{number} requests over {over}: every answer as recorded"

    case = Case(
        id=f"replay.{Path(path).stem}",
        fn=replay_recording,
        requirements=(RECORDING,),
        level="MUST",
        tags=("replay",),
        profiles=(),
        budget=30.0 + 2.0 * requests,
        motion=bool(moving),
        service=service,
        commands=(),
        title=f"replay {Path(path).name}: {requests} recorded requests answer as recorded"
        + (f" (moves: {', '.join(moving)})" if moving else ""),
        order=90,
    )
    add_case(case)
    return case
