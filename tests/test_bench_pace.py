"""Absolute figures timed at the machine's full speed (bench/pace.py); no timing asserted."""

from __future__ import annotations

import itertools
from collections.abc import Iterable

from bench.pace import FULL_SPEED, SpeedGauge, time_at_full_speed


class ScriptedGauge(SpeedGauge):
    """A gauge whose samples take the scripted times (s) instead of running the workload."""

    def __init__(self, times: Iterable[float]) -> None:
        super().__init__()
        self.times = iter(times)
        self.samples = 0

    def sample(self) -> float:
        t = next(self.times)
        self.samples += 1
        self.best = min(self.best, t)
        self.worst = max(self.worst, t)
        return t


def test_the_speed_is_the_gauge_time_against_its_best() -> None:
    gauge = ScriptedGauge([1e-3, 2e-3, 4e-3])
    for _ in range(3):
        gauge.sample()
    assert gauge.speed(2e-3) == 0.5
    assert gauge.slowest() == 0.25
    assert SpeedGauge().slowest() == 1.0  # nothing measured: nothing to report


def test_a_round_between_slow_samples_is_not_full_speed_and_rounds_go_on() -> None:
    # the first sample is fast (the best), every later one twice as slow
    gauge = ScriptedGauge(itertools.chain([1e-3], itertools.repeat(2e-3)))
    calls = 0

    def fn() -> None:
        nonlocal calls
        calls += 1

    timing = time_at_full_speed(fn, round_time=1e-4, rounds=3, budget=0.05, gauge=gauge)
    assert timing.speed <= 0.5 < FULL_SPEED
    assert timing.seconds > 0 and calls > 0
    rounds = (gauge.samples - 1) // 2  # one sample before, two around every round
    assert rounds >= 3


def test_without_a_budget_it_stops_after_the_rounds_asked_for() -> None:
    gauge = ScriptedGauge(itertools.cycle([1e-3, 3e-3]))
    timing = time_at_full_speed(lambda: None, round_time=1e-4, rounds=4, budget=0.0, gauge=gauge)
    assert gauge.samples == 1 + 2 * 4
    assert timing.speed <= 1 / 3 + 1e-12  # the slower bracket of every round
