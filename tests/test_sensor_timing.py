"""Trigger timing model: polling and start jitter, acquisition window, column times."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sensorsocket.timing import TimingError, TimingModel


def _uniform_ks(samples: np.ndarray, lo: float, hi: float) -> float:
    """Kolmogorov-Smirnov distance of samples from U(lo, hi)."""
    x = np.sort((samples - lo) / (hi - lo))
    n = x.size
    cdf = np.arange(1, n + 1) / n
    return float(max(np.max(cdf - x), np.max(x - (cdf - 1.0 / n))))


def test_poll_and_start_jitter_are_uniform() -> None:
    model = TimingModel(rng=np.random.default_rng(1))
    arrivals = np.random.default_rng(2).uniform(0, 100, 4000)
    acqs = [model.schedule(float(t)) for t in arrivals]
    poll = np.array([a.t_poll - a.t_arrival for a in acqs])
    start = np.array([a.t_exposure_start - a.t_poll for a in acqs])
    assert poll.min() >= 0 and poll.max() < 0.25e-3
    assert start.min() >= 0 and start.max() < 0.25e-3
    # 4000 samples: the 1 % KS critical value is 1.63/sqrt(n) ≈ 0.026
    assert _uniform_ks(poll, 0, 0.25e-3) < 0.026
    assert _uniform_ks(start, 0, 0.25e-3) < 0.026
    total = poll + start  # the paper's 0.5 ms trigger-to-exposure jitter: mean 0.25 ms
    assert total.mean() == pytest.approx(0.25e-3, abs=5e-6)
    assert total.max() - total.min() == pytest.approx(0.5e-3, abs=0.02e-3)


def test_grid_polling_is_on_the_sensor_clock() -> None:
    model = TimingModel(
        rng=np.random.default_rng(1), poll_mode="grid", poll_phase_s=0.1e-3, start_jitter_s=0
    )
    a = model.schedule(1.00001)
    assert a.t_poll == pytest.approx(1.0001)
    assert a.t_exposure_start == a.t_poll
    # an arrival exactly on a poll tick is seen at that tick
    assert model.schedule(0.0001).t_poll == pytest.approx(0.0001)


@pytest.mark.parametrize("n_columns", [512, 256, 100, 16])
def test_exposure_window_equals_acquisition_time(n_columns: int) -> None:
    model = TimingModel(rng=np.random.default_rng(3), processing_time_s=2e-3)
    a = model.schedule(5.0, first_column=512 - n_columns, n_columns=n_columns)
    assert a.t_exposure_end - a.t_exposure_start == pytest.approx(3.5e-3 * n_columns / 512)
    assert model.acquisition_time(n_columns) == pytest.approx(3.5e-3 * n_columns / 512)
    assert a.column_times.shape == (n_columns,)
    # each column is exposed for one column period, at its own time, in readout order
    dt = 3.5e-3 / 512
    np.testing.assert_allclose(np.diff(a.column_times), dt)
    assert a.column_times[0] == pytest.approx(a.t_exposure_start + dt / 2)
    assert a.column_times[-1] == pytest.approx(a.t_exposure_end - dt / 2)
    assert a.t_done == pytest.approx(a.t_exposure_end + 2e-3)
    mid = a.first_column + (n_columns - 1) / 2
    assert a.column_time(mid) == pytest.approx((a.t_exposure_start + a.t_exposure_end) / 2)
    assert math.isnan(a.column_time(a.first_column - 3))


def test_longer_exposure_and_busy_sensor() -> None:
    model = TimingModel(rng=np.random.default_rng(4), start_jitter_s=0.0)
    a = model.schedule(0.0, exposure_s=50e-6)
    assert a.t_exposure_end - a.t_exposure_start == pytest.approx(511 * 3.5e-3 / 512 + 50e-6)
    b = model.schedule(0.001, not_before=a.t_exposure_end)
    assert b.t_exposure_start == pytest.approx(a.t_exposure_end)


def test_invalid_parameters() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(TimingError):
        TimingModel(rng=rng, poll_rate_hz=0)
    with pytest.raises(TimingError):
        TimingModel(rng=rng, start_jitter_s=-1)
    model = TimingModel(rng=rng)
    with pytest.raises(TimingError):
        model.schedule(0.0, first_column=500, n_columns=20)
    with pytest.raises(TimingError):
        model.schedule(math.nan)
