"""A reading exposed late is placed by its extra lag [SY-3.8] (sync.exposure_lag and the
matcher), without sockets: a normal reading's t_S stays t_T + ΔT to the bit, a late one is
shifted by exactly its lag over the sensor's usual one."""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spec.datagrams import SensorData
from spec.wire import SensorStatus
from sync.experiment import reading_times
from sync.exposure_lag import DEFAULT_LAG_THRESHOLD_S, ExposureLag
from sync.joint_buffer import JointBuffer
from sync.matcher import SyncMatcher

DT = 0.0049
T0 = 1234.5678  # sensor clock: anything, never compared with the robot's
SEAM = (0.0, 1.0, 80.0, 0.0, 0.0, 0.0)


def _buffer() -> JointBuffer:
    buf = JointBuffer(capacity=2500)
    t = np.arange(0, 2501) * 0.004
    buf.extend(t, np.column_stack([t * k for k in range(1, 7)]))
    return buf


def _t_trigger(i: int) -> float:
    return 0.0013 + 0.004 * i


def _run(lags: list[float], threshold_s: float = DEFAULT_LAG_THRESHOLD_S) -> SyncMatcher:
    """Trigger i answered FOUND with exposure start = arrival + ``lags[i]`` (sensor clock)."""
    m = SyncMatcher(
        delta_t_s=DT, exposure_lag=ExposureLag(threshold_s=threshold_s), keep_trajectory=True
    )
    buf = _buffer()
    for i, lag in enumerate(lags):
        m.on_trigger(i, _t_trigger(i))
        t_arr = T0 + 0.004 * i
        d = SensorData(i, SensorStatus.FOUND, SEAM, 0.9, _t_trigger(i), t_arr, t_arr + lag, 0.0)
        m.on_data(d, _t_trigger(i) + 0.01)
        m.poll(_t_trigger(i) + 0.01, buf)
    m.poll(9.0, buf)
    return m


@settings(max_examples=60, deadline=None)
@given(
    base=st.floats(0.0, 5e-3),
    spread=st.floats(0.0, 0.45e-3),
    threshold=st.floats(0.5e-3, 1.0e-3),
    late_at=st.integers(10, 30),
    extra=st.floats(1.2e-3, 3.5e-3),
    seed=st.integers(0, 2**16),
)
def test_normal_readings_keep_t_t_plus_delta_t_and_a_late_one_moves_by_its_extra_lag(
    base: float, spread: float, threshold: float, late_at: int, extra: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    lags = (base + spread * rng.random(40)).tolist()
    lags[late_at] = base + spread / 2 + extra
    m = _run(lags, threshold)
    pts = m.trajectory()
    assert [p.index for p in pts] == list(range(40))
    for p in pts:
        if p.index != late_at:
            assert p.t_sensor == p.t_trigger + DT  # to the bit
            assert p.extra_lag_s == 0.0
    late = pts[late_at]
    # the reference: the median of the lags seen before, as the sensor stamped them
    seen = [(T0 + 0.004 * i + lags[i]) - (T0 + 0.004 * i) for i in range(late_at)]
    seen = seen[-64:]
    want = late.sensor_times[1] - late.sensor_times[0] - statistics.median(seen)
    assert late.extra_lag_s == want
    assert late.t_sensor == (late.t_trigger + DT) + want
    assert want == pytest.approx(extra, abs=spread + 1e-9)  # stamps ~1e3 s: ulp 1e-13
    assert m.counters.exposed_late == 1 and m.counters.points == 40


def test_constant_lag_moves_nothing() -> None:
    m = _run([2.0e-3] * 30)
    assert all(p.t_sensor == p.t_trigger + DT for p in m.trajectory())
    assert m.counters.exposed_late == 0


def test_no_reading_is_judged_before_the_reference_has_enough_readings() -> None:
    lag = ExposureLag(min_readings=8)
    assert [lag.extra(0.0, 3e-3 if i == 3 else 1e-4) for i in range(8)] == [0.0] * 8
    assert math.isfinite(lag.reference())
    assert lag.extra(0.0, 3e-3) == pytest.approx(3e-3 - 1e-4)


@pytest.mark.parametrize(
    ("arrival", "start"),
    [(0.0, -1e-3), (0.0, math.nan), (math.inf, 0.0), (0.0, 0.5)],
)
def test_stamps_out_of_order_or_beyond_the_timeout_are_not_believed(
    arrival: float, start: float
) -> None:
    lag = ExposureLag()
    for _ in range(10):
        lag.extra(0.0, 1e-4)
    ref = lag.reference()
    assert lag.extra(arrival, start) == 0.0
    assert lag.reference() == ref


def test_the_reference_follows_the_last_window_of_readings() -> None:
    lag = ExposureLag(window=16, min_readings=4)
    for _ in range(16):
        lag.extra(0.0, 1e-4)
    for _ in range(16):
        lag.extra(0.0, 2e-3)  # the sensor's usual lag changed (another readout window)
    assert lag.reference() == 2e-3
    assert lag.extra(0.0, 2.2e-3) == 0.0


def test_bad_settings_raise() -> None:
    for kw in ({"threshold_s": -1.0}, {"window": 0}, {"min_readings": 65}, {"max_lag_s": 0.0}):
        with pytest.raises(ValueError):
            ExposureLag(**kw)


def test_the_delay_experiment_puts_a_reading_placed_later_at_its_exposure() -> None:
    """sync.experiment.reading_times: t_T, plus the extra lag where the robot's t_S says it
    placed the reading later; t_T to the bit for the others (and for a robot that places
    every reading at t_T + ΔT)."""
    m = _run([1e-4] * 12 + [2.6e-3] + [1e-4] * 7)
    pts = m.trajectory()
    rows = np.zeros((len(pts), 17))
    rows[:, 1] = [p.t_trigger for p in pts]
    rows[:, 2] = [p.t_sensor for p in pts]
    t = reading_times(rows, DT)
    assert [a == b for a, b in zip(t, rows[:, 1], strict=True)] == [i != 12 for i in range(20)]
    assert t[12] == pytest.approx(rows[12, 1] + 2.5e-3, abs=1e-12)
    plain = rows.copy()
    plain[:, 2] = plain[:, 1] + DT
    assert (reading_times(plain, DT) == plain[:, 1]).all()
