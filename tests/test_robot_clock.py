"""The robot clocks (robotsocket/clock.py): the real-time loop's catch-up, on a fake clock."""

from __future__ import annotations

import pytest

from robotsocket.clock import RealTimeLoop, SimLoop

PERIOD_NS = 4_000_000


class FakeTime:
    """A monotonic clock that moves only when the loop waits or a tick works."""

    def __init__(self) -> None:
        self.ns = 1_000_000_000

    def clock(self) -> int:
        return self.ns


def _loop(work_ns: dict[int, int], stop_after: int) -> tuple[RealTimeLoop, list[tuple[int, int]]]:
    """A loop whose tick k takes ``work_ns[k]`` and that stops after ``stop_after`` ticks;
    returns it with the (k, fake time) each tick ran at."""
    fake = FakeTime()
    ran: list[tuple[int, int]] = []

    def tick(k: int) -> None:
        ran.append((k, fake.ns))
        fake.ns += work_ns.get(k, 100_000)

    def sleep(ns: int) -> bool:
        fake.ns += ns
        return len(ran) >= stop_after

    loop = RealTimeLoop(
        0.004, tick, rt_priority=0, switch_interval_s=None, clock_ns=fake.clock, sleep_ns=sleep
    )
    return loop, ran


def test_every_cycle_once_in_order_on_its_deadline() -> None:
    loop, ran = _loop({}, stop_after=20)
    start = loop._start_ns
    loop.run()
    assert [k for k, _ in ran] == list(range(1, 21))
    assert all(t == start + k * PERIOD_NS for k, t in ran)  # woken exactly on the deadline
    j = loop.jitter()
    assert j["count"] == 20 and j["max"] == 0.0 and loop.overruns == 0


def test_an_overrun_is_caught_up_back_to_back() -> None:
    # tick 3 takes 5 cycles (a busy machine): ticks 4..8 are due at once and run at once
    loop, ran = _loop({3: 5 * PERIOD_NS}, stop_after=12)
    start = loop._start_ns
    loop.run()
    assert [k for k, _ in ran] == list(range(1, 13))  # none skipped, none repeated
    t3 = start + 3 * PERIOD_NS
    late = {k: t - (start + k * PERIOD_NS) for k, t in ran}
    assert late[4] == t3 + 5 * PERIOD_NS - (start + 4 * PERIOD_NS)  # 16 ms late
    assert all(late[k] > 0 for k in range(4, 8))
    assert late[9] == 0  # back on the grid once caught up
    assert loop.overruns == 4  # ticks 4-7 started more than a period late (7: 4.3 ms)
    assert loop.jitter()["max"] == pytest.approx(0.016)


def test_a_failing_tick_does_not_stop_the_clock() -> None:
    fake = FakeTime()
    ran: list[int] = []

    def tick(k: int) -> None:
        ran.append(k)
        if k == 2:
            raise RuntimeError("boom")

    def sleep(ns: int) -> bool:
        fake.ns += ns
        return len(ran) >= 4

    loop = RealTimeLoop(0.004, tick, rt_priority=0, switch_interval_s=None,
                        clock_ns=fake.clock, sleep_ns=sleep)  # fmt: skip
    loop.run()
    assert ran == [1, 2, 3, 4] and loop.errors == 1


def test_sim_clock_never_advances_by_itself() -> None:
    ticks: list[int] = []
    clock = SimLoop(0.004, ticks.append)
    assert clock.now() == 0.0 and ticks == []
    clock.advance(3)
    assert ticks == [1, 2, 3] and clock.now() == pytest.approx(0.012)


def test_at_rest_the_thread_sleeps_and_then_runs_what_it_slept_through() -> None:
    fake = FakeTime()
    ran: list[int] = []
    waits: list[int] = []
    rest = [True]

    def sleep(ns: int) -> bool:
        waits.append(ns)
        fake.ns += ns
        if len(waits) == 3:
            rest[0] = False  # something moves: back to the 4 ms grid
        return len(ran) >= 80

    loop = RealTimeLoop(0.004, ran.append, rt_priority=0, switch_interval_s=None,
                        clock_ns=fake.clock, sleep_ns=sleep, idle=lambda: rest[0],
                        idle_wait_s=0.1)  # fmt: skip
    loop.run()
    assert waits[:3] == [100_000_000] * 3  # three idle waits of 100 ms, not 75 ticks
    assert ran == list(range(1, 81))  # every cycle once, in order
    assert loop.jitter()["count"] == 80 - 75  # only the ticks run on their deadline are timed
