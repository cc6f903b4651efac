"""Shared helpers for benchmarks: the result record and a small timing loop."""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import NotRequired, TypedDict


class Result(TypedDict):
    name: str
    value: float
    unit: str
    baseline_name: str
    baseline: float
    ratio: float
    # absolute figures: the CPU's speed in the round that gave the value (bench.pace)
    machine_speed: NotRequired[float]


def result(
    name: str,
    value: float,
    unit: str,
    baseline_name: str,
    baseline: float,
    *,
    machine_speed: float | None = None,
) -> Result:
    """One benchmark figure beside its baseline; ``ratio`` is value / baseline."""
    ratio = value / baseline if baseline else float("inf")
    r = Result(
        name=name,
        value=float(value),
        unit=unit,
        baseline_name=baseline_name,
        baseline=float(baseline),
        ratio=float(ratio),
    )
    if machine_speed is not None:
        r["machine_speed"] = round(float(machine_speed), 3)
    return r


def time_per_call(fn: Callable[[], object], *, min_time: float = 0.2, repeat: int = 5) -> float:
    """Best-of-``repeat`` mean time of one call of ``fn`` in seconds."""
    n = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        dt = time.perf_counter() - t0
        if dt >= min_time / repeat or n >= 1 << 24:
            break
        n *= 2
    best = dt / n
    for _ in range(repeat - 1):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def percentile(samples: list[float], p: float) -> float:
    """The p-th percentile (0..100) of ``samples`` by linear interpolation."""
    if not samples:
        raise ValueError("no samples")
    if len(samples) == 1:
        return samples[0]
    q = statistics.quantiles(samples, n=1000, method="inclusive")
    index = min(max(round(p * 10) - 1, 0), len(q) - 1)
    return q[index]


@contextmanager
def one_cpu() -> Iterator[bool]:
    """Run the calling thread, and every thread it starts meanwhile, on one CPU.

    Round-trip benchmarks (client and server threads in one process) use it for the
    measurement and its baseline alike: on a virtual machine a wake-up across CPUs costs
    30-60 µs, and whether the scheduler places the two threads on one CPU or two then decides
    the result (bimodal, 15 vs 80 µs for the same echo). Yields False where affinity cannot
    be set (the figures are then unpinned).
    """
    get = getattr(os, "sched_getaffinity", None)
    put = getattr(os, "sched_setaffinity", None)
    if get is None or put is None:
        yield False
        return
    before = get(0)
    put(0, {min(before)})
    try:
        yield True
    finally:
        put(0, before)
