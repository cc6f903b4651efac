"""How fast the CPU runs right now, and timings taken only when it runs at full speed.

On a shared or virtual machine the CPU's speed itself moves: on the machine the README's table
was measured on, a fixed numpy loop took 120 ms of CPU time and, seconds later, 215 ms, with no
steal time shown. A ratio to a peer measured in alternating rounds cancels that; an absolute
figure (frames per second, µs per pose) does not, and best-of-five rounds inside 0.2 s fall
into one slow stretch whole. So each round of an absolute figure sits between two short runs of
a fixed workload (numpy calls on small arrays and Python bytecode, the mix the figures are made
of); the slower of the two, against the fastest run of the workload in this process, times the
share of the round's wall time the process got the CPU for (other processes on a busy machine)
is the machine's speed in that round. Rounds go on (within a time budget) until the figure's best
round ran at full speed, and the figure carries that speed, so a target missed on a slow
machine is reported as undecided, not as a plausible wrong number.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: A round whose gauge runs at least this fraction of the best speed counts as full speed:
#: the gauge's own spread on an idle machine is a few per cent.
FULL_SPEED = 0.9

_DATA = np.random.default_rng(0).standard_normal(512)


def _workload() -> None:
    """About 0.3 ms of the work the benchmarked code does: short numpy calls and bytecode."""
    x = _DATA
    total = 0.0
    for i in range(40):
        y = np.sort(x)
        total += float(y[i]) + sum(range(40))
    if math.isnan(total):  # keeps the loop's result alive; never true
        raise AssertionError


class SpeedGauge:
    """The CPU's speed relative to the fastest moment seen in this process (1.0 = that)."""

    def __init__(self) -> None:
        self.best = math.inf
        self.worst = 0.0

    def sample(self) -> float:
        """Run the workload twice; the faster run's time (s), remembered as best or worst."""
        t = math.inf
        for _ in range(2):
            t0 = time.perf_counter()
            _workload()
            t = min(t, time.perf_counter() - t0)
        self.best = min(self.best, t)
        self.worst = max(self.worst, t)
        return t

    def speed(self, t: float) -> float:
        """A sample time as a fraction of the best speed seen so far."""
        return self.best / t if t > 0 else 1.0

    def slowest(self) -> float:
        """The slowest speed seen in this process (1.0 when steady or nothing measured)."""
        return self.best / self.worst if math.isfinite(self.best) else 1.0


#: One gauge per process: "full speed" is the fastest moment of the whole run.
GAUGE = SpeedGauge()


@dataclass(frozen=True)
class PacedTiming:
    """Best time per call (s) and the machine's speed (0..1] in the round that gave it."""

    seconds: float
    speed: float


def time_at_full_speed(
    fn: Callable[[], object],
    *,
    round_time: float = 0.04,
    rounds: int = 5,
    budget: float = 4.0,
    gauge: SpeedGauge = GAUGE,
) -> PacedTiming:
    """Best mean time per call of ``fn`` over at least ``rounds`` rounds of ``round_time`` s,
    each between two gauge samples; more rounds, up to ``budget`` s, while the best round
    ran below :data:`FULL_SPEED`. Ends within the budget on a machine that stays slow."""
    gauge.sample()
    n = 1
    while True:  # calls per round
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        if time.perf_counter() - t0 >= round_time or n >= 1 << 24:
            break
        n *= 2
    deadline = time.perf_counter() + budget
    best, best_speed = math.inf, 0.0  # the best round's time per call and the speed in it
    done = 0
    while True:
        before = gauge.sample()
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(n):
            fn()
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c0
        after = gauge.sample()
        done += 1
        if wall / n < best:
            # another process took the CPU for part of the round (cpu < wall), or the CPU ran
            # slower (the gauge): the slower bracket, against the gauge's best so far
            best = wall / n
            best_speed = min(cpu / wall, 1.0) * gauge.speed(max(before, after))
        if done >= rounds and (best_speed >= FULL_SPEED or time.perf_counter() > deadline):
            return PacedTiming(best, best_speed)
