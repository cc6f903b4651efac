"""Soak: an hour of simulated triggering at 250 Hz through the robot's synchronisation core.

A long-running robot server triggers for hours; every structure it keeps must stay flat. This
runs the server's :class:`~sync.udp.RobotSyncCore` (its default ``max_points``, joint
capacity and history, the RX90B kinematics) for one simulated hour in simulated time: a joint
sample every 4 ms, a trigger every 4 ms through a modelled network with loss, duplication and
reordering, and a synthetic sensor that answers each trigger with a data datagram (no image
is rendered: the full cell renders a few hundred frames a second, so an hour would take
hours; the core sees the same datagrams either way). A client reads the new seam points once
a simulated second, as GetSeamPoints would.

Two measurements:

- the hour, every ``SAMPLE_S`` of simulated time: the deep size of each long-lived
  structure (matcher, seam-point rows, joint buffer, scheduler, network model) and the
  interpreter's allocated blocks (anything else that grows), each as a slope over the part of
  the run after the ``max_points`` rows have filled, in MB (blocks) per hour. tracemalloc is
  off here: it slows this loop five-fold, which would make the hour take half an hour;
- :mod:`tracemalloc`'s traced total over ``TRACED_S`` with ``max_points`` 1000 (full after
  4 s; the slope from ``TRACED_STEADY_S``), for the core as it is and for the core with the
  matcher keeping its trajectory (the defect this soak guards against, whose growth is the
  baseline of every slope).
"""

from __future__ import annotations

import gc
import math
import sys
import time
import tracemalloc
from dataclasses import dataclass, field
from types import FunctionType, MethodType, ModuleType

import numpy as np

from bench.common import Result, result
from kinematics.robot import get_model
from spec.datagrams import encode_data_fields, trigger_fields
from spec.wire import SensorStatus
from sync.network import DelayLink
from sync.udp import RobotSyncCore

PERIOD_S = 0.004
"""Robot cycle and trigger period (250 Hz)."""
DURATION_S = 3600.0
SAMPLE_S = 300.0
"""Simulated time between two memory measurements."""
STEADY_FROM_S = 1200.0
"""The slope is fitted from here on: the 200,000 rows fill in 800 s at 250 Hz."""
TRACED_S = 90.0
"""Simulated length of each tracemalloc run."""
TRACED_STEADY_S = 45.0
"""Its slope is fitted from here on: the matcher's 8192-trigger history fills in 33 s."""
READY = (0.0, 30.0, 100.0, 0.0, 50.0, 0.0)
SENSOR2FLANGE = np.array(
    [[1.0, 0.0, 0.0, 40.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 200.0], [0.0, 0.0, 0.0, 1.0]]
)

_SKIP = (type, ModuleType, FunctionType, MethodType)


def deep_size(root: object) -> int:
    """Bytes held by ``root`` and everything it references (numpy views count their base;
    classes, modules and functions are shared, not held)."""
    seen: set[int] = set()
    stack = [root]
    total = 0
    while stack:
        obj = stack.pop()
        if id(obj) in seen or isinstance(obj, _SKIP):
            continue
        seen.add(id(obj))
        total += sys.getsizeof(obj)
        if isinstance(obj, np.ndarray):
            if obj.base is not None:
                stack.append(obj.base)
            continue
        stack.extend(gc.get_referents(obj))
    return total


class _Soak:
    """The core, its network and a synthetic sensor, stepped one 4 ms cycle at a time."""

    def __init__(self, *, keep_trajectory: bool, max_points: int) -> None:
        self.core = RobotSyncCore(
            delta_t_s=4.9e-3,
            flange2base=get_model("RX90B").flange2base_batch,
            sensor2flange=SENSOR2FLANGE,
            max_points=max_points,
        )
        self.core.matcher.keep_trajectory = keep_trajectory
        rng = np.random.default_rng(1)
        self.uplink = DelayLink(delay_s=2e-4, jitter_s=2e-4, rng=rng, loss=0.01)
        self.downlink = DelayLink(
            delay_s=1e-3, rng=rng, duplicate=0.01, reorder=0.01, reorder_delay_s=0.02
        )
        self.core.start_rate(1.0 / PERIOD_S, 0, 0.0013)
        self.cycle = 0
        self.last_index = -1
        self.read = 0

    def step(self) -> None:
        self.cycle += 1
        t = self.cycle * PERIOD_S
        core = self.core
        wave = 2.0 * math.sin(2.0 * math.pi * 1.5 * t)
        core.add_joint(t, [READY[0] + wave, *READY[1:]])
        for index, t_send in core.due_triggers(t):
            self.uplink.send(t_send, core.sent(index, t_send))
        for t_arr, raw in self.uplink.deliver(t):
            fields = trigger_fields(raw)
            assert fields is not None
            index, t_trigger = fields
            seam = (0.0, 0.1 * wave, 1.0, 0.0, 0.0, 0.0)
            data = encode_data_fields(
                index, SensorStatus.FOUND, seam, 0.9, t_trigger, t_arr, t_arr, t_arr + 3.5e-3
            )
            self.downlink.send(t_arr + 4e-3, data)
        for t_arr, raw in self.downlink.deliver(t):
            core.on_datagram(raw, t_arr)
        core.poll(t)
        if self.cycle % 250 == 0:  # a client's GetSeamPoints, once a second
            self.read_points()

    def read_points(self) -> None:
        """What a GetSeamPoints client does: fetch the rows after the last index it has."""
        rows = self.core.points_since(self.last_index)
        if len(rows):
            self.last_index = int(rows[-1, 0])
            self.read += len(rows)

    def structures(self) -> dict[str, int]:
        """Deep size (bytes) of each long-lived structure."""
        core = self.core
        # the core's private stores, named here as the structures this soak is about
        return {
            "matcher": deep_size(core.matcher),
            "seam-point rows": deep_size((core._rows, core._pending)),
            "joint buffer": deep_size(core.joints),
            "scheduler": deep_size(core.scheduler),
            "network model": deep_size((self.uplink, self.downlink)),
        }


@dataclass
class _Series:
    """Memory measurements of one run: simulated times (s) and sizes (bytes) per structure."""

    soak: _Soak
    wall_s: float
    times: list[float] = field(default_factory=list)
    sizes: dict[str, list[int]] = field(default_factory=dict)

    def slope_per_hour(self, name: str, since_s: float) -> float:
        """Least-squares growth of ``name`` per simulated hour, from ``since_s`` on."""
        keep = [i for i, t in enumerate(self.times) if t >= since_s]
        t = np.array([self.times[i] for i in keep])
        size = np.array([self.sizes[name][i] for i in keep], dtype=np.float64)
        return float(np.polyfit(t, size, 1)[0]) * 3600.0


def _run(
    duration_s: float, sample_s: float, *, traced: bool, keep_trajectory: bool, max_points: int
) -> _Series:
    gc.collect()
    if traced:
        tracemalloc.start()
    try:
        series = _Series(_Soak(keep_trajectory=keep_trajectory, max_points=max_points), 0.0)
        soak = series.soak
        base = tracemalloc.get_traced_memory()[0] if traced else 0
        per_sample = round(sample_s / PERIOD_S)
        t0 = time.perf_counter()
        for _ in range(round(duration_s / sample_s)):
            for _ in range(per_sample):
                soak.step()
            series.times.append(soak.cycle * PERIOD_S)
            if traced:
                traced_b = tracemalloc.get_traced_memory()[0] - base
                series.sizes.setdefault("tracemalloc total", []).append(traced_b)
            else:
                for name, size in soak.structures().items():
                    series.sizes.setdefault(name, []).append(size)
                series.sizes.setdefault("allocated blocks", []).append(sys.getallocatedblocks())
        series.wall_s = time.perf_counter() - t0
    finally:
        if traced:
            tracemalloc.stop()
    return series


def run() -> list[Result]:
    # tracemalloc over the same short run, max_points 1000: the defect, then the core as is
    runs = [
        _run(TRACED_S, TRACED_S / 9, traced=True, keep_trajectory=keep, max_points=1000)
        for keep in (True, False)
    ]
    defect, fixed = (r.slope_per_hour("tracemalloc total", TRACED_STEADY_S) / 1e6 for r in runs)
    out = [
        result(
            f"soak tracemalloc growth, {TRACED_S:.0f} s, max_points 1000",
            fixed,
            "MB/h",
            "matcher keeping its trajectory",
            defect,
        )
    ]
    soak = _run(DURATION_S, SAMPLE_S, traced=False, keep_trajectory=False, max_points=200_000)
    soak.soak.core.stop()  # let the last second resolve, then read it
    for _ in range(round(1.0 / PERIOD_S)):
        soak.soak.step()
    soak.soak.read_points()
    stats = soak.soak.core.statistics()
    # the run exercised the fault paths, and the client read every released point
    assert stats["lost"] > 0 and stats["duplicate"] > 0 and stats["reordered"] > 0
    assert stats["pending"] == 0 and soak.soak.read == stats["matched"], (soak.soak.read, stats)
    out.append(result("soak 1 h @250 Hz (sim): wall", soak.wall_s, "s", "simulated", DURATION_S))
    steady = next(i for i, t in enumerate(soak.times) if t >= STEADY_FROM_S)
    for name, sizes in soak.sizes.items():
        blocks = name == "allocated blocks"
        scale = 1.0 if blocks else 1e6  # blocks are counted, structures weighed in MB
        out.append(
            result(
                f"soak growth after {STEADY_FROM_S / 60:.0f} min: {name}",
                soak.slope_per_hour(name, STEADY_FROM_S) / scale,
                "blocks/h" if blocks else "MB/h",
                "matcher keeping its trajectory (MB/h)",
                defect,
            )
        )
        out.append(
            result(
                f"soak size at 1 h: {name}",
                sizes[-1] / scale,
                "blocks" if blocks else "MB",
                f"at {STEADY_FROM_S / 60:.0f} min",
                sizes[steady] / scale,
            )
        )
    return out
