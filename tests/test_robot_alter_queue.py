"""Timed corrections (RS-5.39 ... RS-5.46): the queue's arithmetic, without I/O.

The properties compare the robot's applied correction, cycle by cycle, with a plain
reference interpolation of the table kept here, whatever the arrival order of the batches,
duplicates, resends after their time, gaps and early arrival.
"""

from __future__ import annotations

import bisect
import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robotsocket.alter import (
    MAX_ACCEL_MM_S2,
    MAX_OFFSET_MM,
    MAX_ROTATION_DEG,
    MAX_SPEED_MM_S,
    AlterState,
)
from robotsocket.alter_queue import MAX_BATCH, CorrectionQueue, check_batch
from robotsocket.interface import BadStateError, BusyError, OutOfRangeError

PERIOD = 0.004


def reference(times: list[float], values: list[np.ndarray], t: float) -> np.ndarray:
    """The table's correction at ``t``: zero before its first entry, the last one held after
    its end, linear in between (RS-5.44)."""
    if not times or t < times[0]:
        return np.zeros(6)
    if t >= times[-1]:
        return values[-1]
    i = bisect.bisect_right(times, t) - 1
    w = (t - times[i]) / (times[i + 1] - times[i])
    out: np.ndarray = values[i] + w * (values[i + 1] - values[i])
    return out


@st.composite
def smooth_tables(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """(times (N,), corrections (N, 6)) whose interpolation stays within RS-5.34 on the
    4 ms grid: entries at least a cycle apart, starting at zero, the velocity a damped
    random walk (speed <= 40 mm/s, 12.5 deg/s; a change between segments <= 16 mm/s,
    5 deg/s, two of which fall in two adjacent cycles at most: < a_max * T_r)."""
    n = draw(st.integers(2, 40))
    gaps = draw(st.lists(st.floats(0.004, 0.04), min_size=n - 1, max_size=n - 1))
    t0 = draw(st.floats(0.001, 0.05))  # after the cycle of AlterBegin
    kicks = draw(
        st.lists(st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6), min_size=n, max_size=n)
    )
    times = t0 + np.concatenate([[0.0], np.cumsum(gaps)])
    v = np.zeros(6)
    c = np.zeros((n, 6))
    for j in range(1, n):
        u = np.array(kicks[j]) * np.array([4.6] * 3 + [1.44] * 3)
        v = 0.8 * v + u
        c[j] = c[j - 1] + v * (times[j] - times[j - 1])
    size = float(np.linalg.norm(c[:, :3], axis=1).max())
    turn = float(np.linalg.norm(c[:, 3:], axis=1).max())
    scale = min(
        1.0, 0.99 * MAX_OFFSET_MM / max(size, 1e-12), 0.99 * MAX_ROTATION_DEG / max(turn, 1e-12)
    )
    return times, c * scale


@st.composite
def deliveries(draw: st.DrawFn, times: np.ndarray, cycles: int) -> list[tuple[int, int, int]]:
    """(arrival cycle, first, end) of batches table[first:end]: a partition each of whose
    batches arrives before the cycle that first needs it (any order, any earlier cycle,
    gaps between arrivals), plus duplicates of any span arriving at any cycle, late or not."""
    n = len(times)
    cuts = sorted(draw(st.sets(st.integers(1, n - 1), max_size=min(8, n - 1))))
    bounds = [0, *cuts, n]
    out = []
    for a, b in itertools.pairwise(bounds):
        # entry a is needed from the cycle at or after times[a - 1] (times[0] for a = 0)
        need = times[max(a - 1, 0)]
        k_need = math.ceil(need / PERIOD)  # the first cycle at or after it
        if (k_need - 1) * PERIOD >= need:
            k_need -= 1
        # arrives with cycle `arrive`: before it runs, after cycle arrive - 1 (cycle 0 is
        # AlterBegin's)
        out.append((draw(st.integers(1, max(k_need, 1))), a, b))
    for _ in range(draw(st.integers(0, 4))):
        a = draw(st.integers(0, n - 1))
        b = draw(st.integers(a + 1, n))
        out.append((draw(st.integers(0, cycles + 5)), a, b))
    return out


def _begin(queue_capacity: int | None = None) -> AlterState:
    state = AlterState(PERIOD)
    state.begin(np.eye(4), 1.0, 0.0)  # the cycle at t = 0 is the last one applied
    if queue_capacity is not None:
        state.queue.capacity = queue_capacity
    return state


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_applied_correction_is_the_reference_interpolation(data: st.DataObject) -> None:
    """[RS-5.39] [RS-5.41] [RS-5.42] [RS-5.44] Batches in any order, early, duplicated,
    resent after their time: the applied correction at every cycle is the table's
    interpolation at the cycle's time (RS-5.34 passes a table within its limits unchanged)."""
    times, table = data.draw(smooth_tables())
    cycles = math.ceil(times[-1] / PERIOD) + 10  # and held past the end, short of the timeout
    plan = data.draw(deliveries(times, cycles))
    state = _begin()
    t_list, v_list = times.tolist(), list(table)
    late_expected = 0
    last_applied = 0.0
    held_expected = 0
    prev = np.zeros(6)
    for k in range(1, cycles + 1):
        for arrive, a, b in plan:
            if arrive == k:
                report = state.enqueue(times[a:b], table[a:b])
                late = int(np.count_nonzero(times[a:b] <= last_applied))
                assert report.late == late and report.accepted == (b - a) - late
                late_expected += late
        t = k * PERIOD
        assert not state.step(t)
        last_applied = t
        held_expected += t > times[-1]
        want = reference(t_list, v_list, t)
        np.testing.assert_allclose(state.applied, want, atol=1e-9, rtol=0)
        # and RS-5.34 held throughout
        v = (state.applied - prev) / PERIOD
        assert np.linalg.norm(v[:3]) <= MAX_SPEED_MM_S + 1e-6
        prev = state.applied.copy()
    report = state.enqueue(np.zeros(0), np.zeros((0, 6)))
    assert report.late_total == late_expected
    assert report.held_total == held_expected


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_queue_target_matches_a_plain_model(data: st.DataObject) -> None:
    """[RS-5.41] [RS-5.42] [RS-5.44] Any batches (overlapping, out of order, late, any size
    within RS-5.33) at any cycle: the queue's correction each cycle is the interpolation of
    a plain model of the rules (a dict of entries; late ones dropped; a batch replaces what
    lies in its span)."""
    n_cycles = data.draw(st.integers(1, 60))
    queue = CorrectionQueue()
    model: dict[float, np.ndarray] = {}
    applied = -math.inf
    for k in range(1, n_cycles + 1):
        for _ in range(data.draw(st.integers(0, 2))):
            ticks = sorted(data.draw(st.sets(st.integers(0, 4 * n_cycles + 20), max_size=12)))
            t = np.array(ticks, dtype=np.float64) * 0.001  # 1 ms steps: off the 4 ms grid
            c = np.array(
                data.draw(
                    st.lists(
                        st.lists(st.floats(-5.0, 5.0), min_size=6, max_size=6),
                        min_size=len(t),
                        max_size=len(t),
                    )
                ),
                dtype=np.float64,
            ).reshape(len(t), 6)
            c[:, 3:] *= 0.2  # within 2 deg
            report = queue.insert(t, c)
            fresh = [i for i in range(len(t)) if t[i] > applied]
            assert report.late == len(t) - len(fresh)
            if fresh:
                lo, hi = t[fresh[0]], t[fresh[-1]]
                model = {x: v for x, v in model.items() if not lo <= x <= hi}
                model.update({float(t[i]): c[i] for i in fresh})
        now = k * PERIOD
        got = queue.due(now)
        applied = now
        keys = sorted(model)
        if not keys or now < keys[0]:
            assert got is None
        else:
            assert got is not None
            np.testing.assert_allclose(
                got, reference(keys, [model[x] for x in keys], now), atol=1e-12, rtol=0
            )


def test_a_bad_batch_is_refused_whole() -> None:
    """[RS-5.40] Unsorted, duplicate, non-finite, oversized or out-of-range batches: refused,
    the queue unchanged."""
    state = _begin()
    state.enqueue(np.array([0.1, 0.2]), np.zeros((2, 6)))
    bad: list[tuple[np.ndarray, np.ndarray, str]] = [
        (np.array([0.3, 0.3]), np.zeros((2, 6)), "increase strictly"),
        (np.array([0.4, 0.3]), np.zeros((2, 6)), "increase strictly"),
        (np.array([0.3, math.nan]), np.zeros((2, 6)), "finite"),
        (np.array([0.3]), np.zeros((2, 6)), "1 x 6"),
        (np.array([0.3]), np.array([[0.0, 10.5, 0, 0, 0, 0]]), "translation"),
        (np.array([0.3]), np.array([[0.0, 0, 0, 0, 2.5, 0]]), "rotation"),
        (
            np.arange(MAX_BATCH + 1, dtype=np.float64) * 0.004 + 1.0,
            np.zeros((MAX_BATCH + 1, 6)),
            "at most",
        ),
    ]
    for t, c, why in bad:
        with pytest.raises(OutOfRangeError, match=why):
            state.enqueue(t, c)
    assert state.queue.depth == 2 and state.queue.horizon == pytest.approx(0.2)


def test_a_full_queue_refuses_the_batch_and_keeps_what_it_has() -> None:
    """[RS-5.43] A batch that would overflow is refused whole (BUSY); once the queue has
    drained the same batch is accepted; a batch replacing its own span needs no room."""
    state = _begin(queue_capacity=10)
    state.enqueue(np.arange(1, 9, dtype=np.float64) * 0.004, np.zeros((8, 6)))
    with pytest.raises(BusyError, match="full"):
        state.enqueue(np.arange(9, 12, dtype=np.float64) * 0.004, np.ones((3, 6)) * 0.1)
    assert state.queue.depth == 8
    # the same span: replaced
    state.enqueue(np.arange(1, 9, dtype=np.float64) * 0.004, np.ones((8, 6)) * 0.1)
    for k in range(1, 6):
        state.step(k * PERIOD)
    report = state.enqueue(np.arange(9, 12, dtype=np.float64) * 0.004, np.ones((3, 6)) * 0.1)
    assert report.accepted == 3 and report.depth <= 10


def test_entries_already_past_are_late_and_dropped() -> None:
    """[RS-5.42] The entry for the cycle just applied and older ones are dropped and counted;
    the rest of the batch applies."""
    state = _begin()
    for k in range(1, 4):
        state.step(k * PERIOD)
    report = state.enqueue(np.array([0.004, 0.012, 0.016, 0.020]), np.full((4, 6), 0.01))
    assert (report.accepted, report.late, report.depth) == (2, 2, 2)
    assert report.late_total == 2
    assert report.horizon == pytest.approx(0.020)


def test_queue_held_past_its_end_then_the_stream_is_lost() -> None:
    """[RS-5.44] [RS-5.36] Past the last entry it is held (counted as held cycles), never
    extrapolated; `timeout` after the last entry's time with no Alter the stream is lost and
    the correction ramps back to zero."""
    state = AlterState(PERIOD)
    state.begin(np.eye(4), 0.04, 0.0)
    ramp = np.arange(1, 26, dtype=np.float64) * PERIOD
    c = np.zeros((25, 6))
    c[:, 1] = np.minimum(np.arange(1, 26, dtype=np.float64) * 0.01, 0.2)
    state.enqueue(ramp, c)
    k = 0
    lost_at = None
    while lost_at is None and k < 200:
        k += 1
        if state.step(k * PERIOD):
            lost_at = k * PERIOD
        elif k > 25:
            assert state.applied[1] == pytest.approx(0.2, abs=1e-9)  # held, not extrapolated
    assert lost_at == pytest.approx(ramp[-1] + 0.04 + PERIOD, abs=1e-9)
    assert not state.active and state.queue.depth == 0
    for j in range(k + 1, k + 100):
        state.step(j * PERIOD)
    assert not np.any(state.applied)


def test_a_whole_table_sent_ahead_keeps_the_stream_alive_to_its_end() -> None:
    """[RS-5.36] [RS-5.39] A table covering 2 s, sent before the run in frames of
    MAX_BATCH, with a 0.1 s timeout and no message afterwards: no loss before its end."""
    state = AlterState(PERIOD)
    state.begin(np.eye(4), 0.1, 0.0)
    t = np.arange(1, 501, dtype=np.float64) * PERIOD
    c = np.zeros((500, 6))
    c[:, 0] = 2.0 * np.sin(2 * np.pi * t) * np.minimum(t / 0.5, 1.0) ** 2
    for a in reversed(range(0, 500, 128)):  # the frames in reverse order
        state.enqueue(t[a : a + 128], c[a : a + 128])
    for k in range(1, 501):
        assert not state.step(k * PERIOD)
    assert state.active


def test_alter_and_the_queue_do_not_mix() -> None:
    """[RS-5.46] Alter while timed corrections are queued is BAD_STATE; AlterEnd drops the
    queue; AlterQueue outside alter mode is BAD_STATE."""
    state = _begin()
    state.command(np.array([0.0, 0.1, 0, 0, 0, 0]), 0.0)
    state.enqueue(np.array([0.1]), np.zeros((1, 6)))
    with pytest.raises(BadStateError, match="queued"):
        state.command(np.zeros(6), 0.0)
    state.end()
    assert state.queue.depth == 0
    with pytest.raises(BadStateError, match="not active"):
        state.enqueue(np.array([0.1]), np.zeros((1, 6)))


def test_an_out_of_limit_table_is_followed_within_rs_5_34() -> None:
    """[RS-5.34] A table asking for a 5 mm step between two cycles: the applied correction
    gets there no faster than the limits allow."""
    state = _begin()
    state.enqueue(np.array([0.008, 0.012]), np.array([[0.0] * 6, [0.0, 5.0, 0, 0, 0, 0]]))
    y = [0.0]
    for k in range(1, 100):
        state.step(k * PERIOD)
        y.append(float(state.applied[1]))
    v = np.diff(y) / PERIOD
    assert np.abs(v).max() <= MAX_SPEED_MM_S * (1 + 1e-9)
    assert np.abs(np.diff(v) / PERIOD).max() <= MAX_ACCEL_MM_S2 * (1 + 1e-9)
    assert y[-1] == pytest.approx(5.0, abs=1e-9)


def test_check_batch_accepts_an_empty_batch() -> None:
    check_batch(np.zeros(0), np.zeros((0, 6)), MAX_OFFSET_MM, MAX_ROTATION_DEG)
