"""Tests for sync.delay: the ΔT estimator of section VI and the residual of Fig. 9.

Synthetic data with the paper's timing: robot samples every 4 ms, triggers at 250 Hz at a
phase unrelated to the robot samples, true delay 4.9 ms, trigger-to-exposure jitter
U(0, 0.5 ms) + N(0, 0.1 ms), sensor noise 10 µm, 2 mm sine for 10 s.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sync.delay import (
    DEFAULT_GRID_STEP_S,
    DelayEstimate,
    DelayEstimateError,
    NoInteriorMinimumError,
    ResidualReport,
    SineExperiment,
    Verdict,
    _interp_sorted,
    _mse_curve_masked,
    _parabola,
    assess_run,
    estimate_delay,
    residual_after_sync,
    simulate_sine_experiment,
    sine_amplitude,
    upsample,
    window_delays,
)
from sync.mse_curve import mse_curve

TOL_S = 0.06e-3


def _estimate(ex: SineExperiment, **kw: Any) -> DelayEstimate:
    return estimate_delay(ex.t_robot, ex.y_robot, ex.t_trigger, ex.y_sensor, **kw)


@pytest.mark.parametrize("freq", [1.5, 5.0])
@pytest.mark.parametrize("seed", [11, 12])
def test_estimate_is_delay_plus_mean_jitter(freq: float, seed: int) -> None:
    ex = simulate_sine_experiment(np.random.default_rng(seed), frequency_hz=freq)
    assert ex.mean_jitter_s == pytest.approx(0.25e-3)
    est = _estimate(ex)
    assert not est.at_edge
    assert abs(est.delta_t_s - (4.9e-3 + 0.25e-3)) < TOL_S
    # the grid minimum is the 0.2 ms grid point nearest to the truth
    assert abs(est.shifts_s[est.min_index] - 5.15e-3) <= 0.1e-3 + TOL_S
    assert est.shifts_s[0] == 0.0 and est.shifts_s[-1] == pytest.approx(20e-3)
    assert est.shifts_s[1] - est.shifts_s[0] == pytest.approx(0.2e-3)


@pytest.mark.parametrize("shift_ms", [-3.0, 1.7, 6.3])
def test_shifting_the_true_delay_shifts_the_estimate(shift_ms: float) -> None:
    base = simulate_sine_experiment(np.random.default_rng(5), frequency_hz=1.5)
    moved = simulate_sine_experiment(
        np.random.default_rng(5), frequency_hz=1.5, delay_s=4.9e-3 + shift_ms * 1e-3
    )
    e0 = _estimate(base).delta_t_s
    e1 = _estimate(moved).delta_t_s
    assert abs((e1 - e0) - shift_ms * 1e-3) < TOL_S


def test_drifting_trigger_phase() -> None:
    # triggers 0.03 % slower than the robot: the phase sweeps through the whole 4 ms
    ex = simulate_sine_experiment(
        np.random.default_rng(3), frequency_hz=1.5, trigger_period_s=4.0012e-3
    )
    assert abs(_estimate(ex).delta_t_s - ex.expected_delta_t_s) < TOL_S


def test_residual_after_sync_at_1_5_hz() -> None:
    ex = simulate_sine_experiment(np.random.default_rng(21), frequency_hz=1.5)
    est = _estimate(ex)
    rep = residual_after_sync(
        ex.t_robot, ex.y_robot, ex.t_trigger, ex.y_sensor, est.delta_t_s, frequency_hz=1.5
    )
    s, u = rep.synced, rep.unsynced
    assert s.max_um <= 50.0 and s.rms_um <= 15.0
    assert u.rms_um >= 3 * s.rms_um and u.max_um >= 3 * s.max_um
    # no sine left at the motion frequency after synchronisation (Fig. 9), a clear one without
    expected_unsynced = 2000.0 * 2 * math.pi * 1.5 * ex.expected_delta_t_s  # A·ω·ΔT in µm
    assert u.sine_amplitude_um == pytest.approx(expected_unsynced, rel=0.05)
    assert s.sine_amplitude_um < 2.0
    assert s.delta_t_s == est.delta_t_s and u.delta_t_s == 0.0
    assert s.residual_um.shape == s.times_s.shape


def test_residual_after_sync_at_5_hz() -> None:
    # Jitter matters more at 5 Hz: A·ω = 63 mm/s turns ±0.25 ms into ±16 µm, so the bounds
    # are wider than at 1.5 Hz (the paper reports ≈ 40 µm at 5 Hz).
    ex = simulate_sine_experiment(np.random.default_rng(22), frequency_hz=5.0)
    est = _estimate(ex)
    rep = residual_after_sync(
        ex.t_robot, ex.y_robot, ex.t_trigger, ex.y_sensor, est.delta_t_s, frequency_hz=5.0
    )
    assert rep.synced.max_um <= 65.0 and rep.synced.rms_um <= 18.0
    assert rep.unsynced.rms_um >= 3 * rep.synced.rms_um
    # What remains at 5 Hz is mostly the robot's linear interpolation between 4 ms samples,
    # about A·ω²·T_r²/12 ≈ 2.6 µm, in phase with the motion; ~1 % of the unsynchronised sine.
    assert rep.synced.sine_amplitude_um < 6.0
    assert rep.synced.sine_amplitude_um < 0.02 * rep.unsynced.sine_amplitude_um


def test_mse_is_normalised_per_overlap() -> None:
    # Noise-free signals with the delay exactly on the grid: the MSE at the true shift is 0
    # and every value is a mean (bounded by the peak-to-peak squared), whatever the overlap.
    ex = simulate_sine_experiment(
        np.random.default_rng(0),
        jitter_uniform_s=0.0,
        jitter_normal_s=0.0,
        sensor_noise_mm=0.0,
        delay_s=5.0e-3,
        trigger_phase_s=0.0,
        robot_period_s=0.2e-3,
        trigger_period_s=0.2e-3,
        duration_s=2.0,
    )
    est = _estimate(ex, search_max_s=200e-3)
    assert est.shifts_s[est.min_index] == pytest.approx(5.0e-3)
    # zero up to the round-off of Σys² + Σyr² - 2Σys·yr on a 2 mm signal (~1e-14 mm²)
    assert est.mse[est.min_index] < 1e-12
    assert np.all(est.mse <= 16.0)
    assert est.overlap[0] > est.overlap[-1]
    assert abs(est.delta_t_s - 5.0e-3) < 1e-6


def test_parabola_resolves_below_the_grid() -> None:
    ex = simulate_sine_experiment(
        np.random.default_rng(0),
        jitter_uniform_s=0.0,
        jitter_normal_s=0.0,
        sensor_noise_mm=0.0,
        delay_s=4.93e-3,
        robot_period_s=1e-3,
        trigger_period_s=1e-3,
    )
    est = _estimate(ex)
    assert abs(est.delta_t_s - 4.93e-3) < 5e-6
    est5 = _estimate(ex, fit_half_width=3)
    assert abs(est5.delta_t_s - 4.93e-3) < 5e-6


def test_minimum_at_the_edge() -> None:
    ex = simulate_sine_experiment(np.random.default_rng(1), delay_s=25e-3)
    with pytest.raises(NoInteriorMinimumError) as info:
        _estimate(ex)
    assert info.value.estimate.at_edge
    est = _estimate(ex, require_interior=False)
    assert est.at_edge and est.delta_t_s == pytest.approx(20e-3)
    # a wider range finds it; negative delays can be searched too
    assert abs(_estimate(ex, search_max_s=40e-3).delta_t_s - 25.25e-3) < TOL_S
    neg = simulate_sine_experiment(np.random.default_rng(1), delay_s=-3e-3)
    assert abs(_estimate(neg, search_min_s=-10e-3).delta_t_s + 2.75e-3) < TOL_S


def test_input_errors() -> None:
    with pytest.raises(DelayEstimateError):
        estimate_delay([0.0, 1.0], [0.0], [0.0, 1.0], [0.0, 1.0])
    with pytest.raises(DelayEstimateError):
        estimate_delay([0.0, 1.0, 0.5], [0, 0, 0], [0.0, 1.0], [0.0, 1.0])
    with pytest.raises(DelayEstimateError):  # no overlap at all
        estimate_delay([0.0, 0.1], [0, 1], [5.0, 5.1], [0, 1])
    j0, y = upsample([0.0003, 0.0011], [0.0, 8.0])
    assert j0 == 2 and y.tolist() == pytest.approx([1.0, 3.0, 5.0, 7.0])


@pytest.mark.parametrize(
    ("bad", "message"),
    [
        ("nan_time", "times and values must be finite"),
        ("inf_last_time", "times and values must be finite"),
        ("inf_value", "times and values must be finite"),
        ("repeated_time", "times must be strictly increasing"),
        ("one_sample", "need at least 2 samples"),
    ],
)
@pytest.mark.parametrize("who", ["robot", "sensor"])
def test_input_errors_name_the_fault(bad: str, message: str, who: str) -> None:
    t = np.arange(100) * 4e-3
    y = np.sin(2 * np.pi * 1.5 * t)
    tb, yb = t.copy(), y.copy()
    if bad == "nan_time":
        tb[50] = np.nan
    elif bad == "inf_last_time":
        tb[-1] = np.inf
    elif bad == "inf_value":
        yb[5] = np.inf
    elif bad == "repeated_time":
        tb[5] = tb[4]
    else:
        tb, yb = tb[:1], yb[:1]
    args = (tb, yb, t, y) if who == "robot" else (t, y, tb, yb)
    with pytest.raises(DelayEstimateError, match=f"^{who}: {message}"):
        estimate_delay(*args, require_interior=False)


def test_cramer_rao_sanity() -> None:
    """Informative: the spread over seeds is near σ/(A·ω·√(N/2)) with the effective noise."""
    f, amp = 1.5, 2.0
    w = 2 * math.pi * f
    errors = []
    for seed in range(24):
        ex = simulate_sine_experiment(np.random.default_rng(100 + seed), frequency_hz=f)
        errors.append(_estimate(ex).delta_t_s - ex.expected_delta_t_s)
    # noise plus the jitter seen through the slope: 10 µm ⊕ A·ω·(0.5 ms/√12 ⊕ 0.1 ms)
    sigma = math.hypot(0.01, amp * w * math.hypot(0.5e-3 / math.sqrt(12), 0.1e-3))
    bound = sigma / (amp * w * math.sqrt(2500 / 2))
    std = float(np.std(errors, ddof=1))
    assert 0.5 * bound < std < 2.0 * bound
    assert abs(float(np.mean(errors))) < 3 * bound


def test_unbiased_on_windows_that_do_not_start_on_a_zero_crossing() -> None:
    """Windows cut at a crest (and at a random phase) of the sine: the estimate stays at the
    bound and unbiased. Maximising the overlap-normalised cross-correlation instead (the MSE
    without its Σ y_r² term) is 0.56 ms off here, 35 times the bound."""
    f, amp = 1.5, 2.0
    w = 2 * math.pi * f
    sigma = math.hypot(0.01, amp * w * math.hypot(0.5e-3 / math.sqrt(12), 0.1e-3))
    errors = []
    for seed in range(24):
        ex = simulate_sine_experiment(np.random.default_rng(300 + seed), frequency_hz=f)
        t0 = 0.25 / f + (0.0 if seed % 2 else float(np.random.default_rng(seed).uniform(0, 1)))
        keep = (ex.t_trigger >= t0) & (ex.t_trigger < t0 + 6.0)
        est = estimate_delay(ex.t_robot, ex.y_robot, ex.t_trigger[keep], ex.y_sensor[keep])
        errors.append(est.delta_t_s - ex.expected_delta_t_s)
    bound = sigma / (amp * w * math.sqrt(int(np.count_nonzero(keep)) / 2))
    std = float(np.std(errors, ddof=1))
    assert 0.5 * bound < std < 2.0 * bound
    assert abs(float(np.mean(errors))) < 3 * bound


# --- quality gates of a run (issue 12) -------------------------------------------------------


def _sine_run(
    delay_of_t: Any, *, duration_s: float = 8.0, freq: float = 1.5, noise_mm: float = 0.01
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A recorded run whose sensor sees the sine ``delay_of_t(t)`` s after the trigger."""
    rng = np.random.default_rng(4)
    w = 2 * math.pi * freq
    t_r = np.arange(0, int(duration_s / 4e-3) + 1) * 4e-3
    y_r = 2.0 * np.sin(w * t_r)
    t_t = np.arange(0.0013, duration_s - 0.05, 4e-3)
    y_s = 2.0 * np.sin(w * (t_t + delay_of_t(t_t))) + rng.normal(0, noise_mm, t_t.shape)
    return t_r, y_r, t_t, y_s


def _assess(
    run: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    stats: dict[str, int] | None = None,
    search_max_s: float = 20e-3,
) -> Verdict:
    t_r, y_r, t_t, y_s = run
    est = estimate_delay(t_r, y_r, t_t, y_s, search_max_s=search_max_s, require_interior=False)
    res = residual_after_sync(t_r, y_r, t_t, y_s, est.delta_t_s, frequency_hz=1.5)
    windows = window_delays(
        t_r, y_r, t_t, y_s, (0.5, 7.5), period_s=1 / 1.5, search_max_s=search_max_s
    )
    return assess_run(est, res, stats or {"sent": t_t.size, "lost": 0, "late": 0}, windows)


def test_a_clean_run_is_trusted() -> None:
    v = _assess(_sine_run(lambda t: 4.9e-3))
    assert v.ok and v.reasons == () and v.reason == ""
    assert len(v.window_delta_t_s) == 5 and v.spread_s < 0.2e-3
    assert v.to_json()["ok"] is True


def test_drifting_delay_fails_with_the_spread() -> None:
    # ΔT creeps from 4 to 8 ms over the run: the mean looks plausible, the windows do not
    v = _assess(_sine_run(lambda t: 4e-3 + 0.5e-3 * t))
    assert not v.ok
    assert len(v.reasons) == 1 and v.reasons[0].startswith("ΔT drifted by ")
    assert v.spread_s > 2e-3
    assert v.to_json()["spread_ms"] == pytest.approx(v.spread_s * 1e3)


def test_minimum_at_the_edge_fails() -> None:
    v = _assess(_sine_run(lambda t: 4.9e-3), search_max_s=3e-3)
    assert not v.ok
    assert v.reasons[0].startswith("MSE minimum at the edge of the search range [0.00, 3.00]")
    # every window hits the edge too: the drift gate says so instead of a spread
    assert any("window's MSE minimum is at the edge" in r for r in v.reasons)


def test_lost_and_late_data_fail_and_are_told_apart() -> None:
    run = _sine_run(lambda t: 4.9e-3)
    v = _assess(run, {"sent": 2000, "lost": 300, "late": 260})
    assert not v.ok and v.lost_on_wire == 40 and v.dropped_late == 260
    assert v.reason == (
        "300 of 2000 triggers (15.0%) got no data in time (40 lost on the wire, 260 arrived "
        "after the loss timeout); limit 2.0%"
    )
    assert _assess(run, {"sent": 2000, "lost": 40, "late": 0}).ok  # 2.0 %: at the limit


def test_residual_not_better_than_without_fails() -> None:
    t_r, y_r, t_t, y_s = _sine_run(lambda t: 4.9e-3)
    est = estimate_delay(t_r, y_r, t_t, y_s)
    good = residual_after_sync(t_r, y_r, t_t, y_s, est.delta_t_s, frequency_hz=1.5)
    swapped = ResidualReport(synced=good.unsynced, unsynced=good.synced)
    v = assess_run(est, swapped, {"sent": 10, "lost": 0}, [])
    assert not v.ok and len(v.reasons) == 1
    assert v.reasons[0].startswith("residual after synchronisation (rms ")
    assert math.isnan(v.spread_s) and v.to_json()["spread_ms"] is None  # drift not judged


def test_sine_amplitude_of_a_shifted_noisy_sine() -> None:
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 4.0, 0.004)
    y = 5.0 + 2.0 * np.sin(2 * np.pi * 1.5 * (t + 4.9e-3)) + rng.normal(0, 0.01, t.shape)
    assert sine_amplitude(t, y, 1.5) == pytest.approx(2.0, abs=2e-3)
    assert sine_amplitude(t, y, 4.0) < 0.01  # another frequency: nothing there
    assert sine_amplitude(t[:2], y[:2], 1.5) == 0.0


def test_a_sensor_that_never_saw_the_motion_says_so_first() -> None:
    # two servers sharing no scene: the sensor reads a still seam while the robot moves 2 mm
    t_r, y_r, t_t, _ = _sine_run(lambda t: 4.9e-3)
    y_still = np.random.default_rng(1).normal(0, 0.005, t_t.shape)
    est = estimate_delay(t_r, y_r, t_t, y_still, require_interior=False)
    res = residual_after_sync(t_r, y_r, t_t, y_still, est.delta_t_s, frequency_hz=1.5)
    motion = (sine_amplitude(t_t, y_still, 1.5), sine_amplitude(t_r, y_r, 1.5), 1.5)
    v = assess_run(est, res, {"sent": t_t.size, "lost": 0}, [], motion=motion)
    assert not v.ok and v.reasons[0].startswith("the sensor never saw the robot's motion")
    assert "while the robot moved 2000 µm" in v.reasons[0]
    # the same gate passes a sensor that follows the motion
    t_r, y_r, t_t, y_s = _sine_run(lambda t: 4.9e-3)
    est = estimate_delay(t_r, y_r, t_t, y_s)
    res = residual_after_sync(t_r, y_r, t_t, y_s, est.delta_t_s, frequency_hz=1.5)
    motion = (sine_amplitude(t_t, y_s, 1.5), sine_amplitude(t_r, y_r, 1.5), 1.5)
    assert assess_run(est, res, {"sent": t_t.size, "lost": 0}, [], motion=motion).ok


def test_short_run_has_no_windows() -> None:
    t_r, y_r, t_t, y_s = _sine_run(lambda t: 4.9e-3)
    assert window_delays(t_r, y_r, t_t, y_s, (0.5, 1.5), period_s=1 / 1.5) == []
    assert window_delays(t_r, y_r, t_t, y_s, (2.0, 1.0), period_s=1 / 1.5) == []


def test_bursts_of_lost_data_leave_the_estimate_right() -> None:
    """Half the readings lost in 100 ms bursts (a starved sensor): the readings that came
    are still right, and the grid points inside the gaps are left out rather than
    interpolated across, so the estimate stays on the delay."""
    ex = simulate_sine_experiment(np.random.default_rng(8), duration_s=10.0)
    burst = (np.floor(ex.t_trigger / 0.1).astype(int) % 2) == 1
    keep = ~burst
    est = estimate_delay(ex.t_robot, ex.y_robot, ex.t_trigger[keep], ex.y_sensor[keep])
    assert np.count_nonzero(keep) < 0.55 * keep.size
    # interpolated across the gaps it was 0.14 ms off
    assert abs(est.delta_t_s - ex.expected_delta_t_s) < 2 * TOL_S
    # the MSE averaged only the grid points inside the data, about half of the span
    span = (ex.t_trigger[keep][-1] - ex.t_trigger[keep][0]) / est.grid_step_s
    assert est.overlap.max() < 0.6 * span


@settings(max_examples=60, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**32 - 1),
    robot_period=st.sampled_from([0.2e-3, 1e-3, 4e-3, 4.1e-3]),
    jitter=st.floats(0.0, 0.9),
    offset=st.floats(-5.0, 5.0),
    m_lo=st.integers(-200, 50),
    span=st.integers(2, 150),
)
def test_mse_curve_equals_the_definition(
    seed: int, robot_period: float, jitter: float, offset: float, m_lo: int, span: int
) -> None:
    """The prefix-sum / robot-piece form of the MSE curve is the plain per-shift mean, for
    robot samples on and off the grid, jittered, far from zero, shifts beyond the overlap."""
    rng = np.random.default_rng(seed)
    n_r = int(0.4 / robot_period)
    t_r = rng.uniform(0.0, 0.05) + robot_period * (
        np.arange(n_r) + jitter * rng.uniform(-0.5, 0.5, n_r)
    )
    y_r = offset + np.sin(2 * np.pi * 3.0 * t_r) + 0.01 * rng.standard_normal(n_r)
    t_s = np.sort(rng.uniform(0.0, 0.45, 90))
    t_s = t_s[np.concatenate([[True], np.diff(t_s) > 1e-6])]
    y_s = offset + np.sin(2 * np.pi * 3.0 * (t_s + 0.005)) + 0.01 * rng.standard_normal(len(t_s))
    step = DEFAULT_GRID_STEP_S
    jr, yr = upsample(t_r, y_r, step)
    js, ys = upsample(t_s, y_s, step)
    shifts = np.arange(m_lo, m_lo + span + 1, dtype=np.int64)
    mse, overlap = mse_curve((t_s, y_s), (t_r, y_r), shifts, step)
    # the plain per-shift mean (the path of runs with lost data), every point kept
    ref, ref_overlap = _mse_curve_masked(jr, yr, js, ys, shifts, np.ones(len(ys)))
    np.testing.assert_array_equal(overlap, ref_overlap)
    finite = np.isfinite(ref)
    np.testing.assert_array_equal(np.isfinite(mse), finite)
    scale = 1.0 + offset * offset
    np.testing.assert_allclose(mse[finite], ref[finite], rtol=1e-9, atol=1e-11 * scale)


def test_mse_curve_with_samples_that_snap_onto_one_grid_point() -> None:
    """Two samples a hair apart on one grid point (the sensor at 5 kHz, stamped twice) count
    once, and the curve is still the plain per-shift mean."""
    rng = np.random.default_rng(3)
    step = DEFAULT_GRID_STEP_S
    t_r = np.arange(120, dtype=np.float64) * 4e-3
    y_r: npt.NDArray[np.float64] = np.sin(2 * np.pi * 3.0 * t_r)
    t_s = np.sort(np.concatenate([rng.uniform(0.01, 0.45, 60), np.arange(5, 2000, 400) * step]))
    t_s = np.insert(t_s, np.searchsorted(t_s, 805 * step) + 1, 805 * step * (1 + 1e-15))
    assert np.min(np.diff(t_s)) < 1e-12 * step
    y_s: npt.NDArray[np.float64] = np.sin(2 * np.pi * 3.0 * (t_s + 0.005))
    shifts = np.arange(-20, 40, dtype=np.int64)
    mse, overlap = mse_curve((t_s, y_s), (t_r, y_r), shifts, step)
    jr, yr = upsample(t_r, y_r, step)
    js, ys = upsample(t_s, y_s, step)
    ref, ref_overlap = _mse_curve_masked(jr, yr, js, ys, shifts, np.ones(len(ys)))
    np.testing.assert_array_equal(overlap, ref_overlap)
    np.testing.assert_allclose(mse, ref, rtol=1e-9, atol=1e-12)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    seed=st.integers(0, 2**32 - 1),
    n_knots=st.integers(2, 40),
    n_points=st.integers(0, 300),
    on_knots=st.booleans(),
)
def test_grid_interpolation_is_np_interp_bit_for_bit(
    seed: int, n_knots: int, n_points: int, on_knots: bool
) -> None:
    """The one-search-per-knot interpolation is np.interp exactly, points outside the knots,
    on a knot and on the last knot included."""
    rng = np.random.default_rng(seed)
    xp = np.cumsum(rng.uniform(1e-6, 1.0, n_knots)) + rng.uniform(-5.0, 5.0)
    fp = rng.normal(0.0, 3.0, n_knots)
    x = rng.uniform(xp[0] - 1.0, xp[-1] + 1.0, n_points)
    if on_knots:
        x = np.concatenate([x, xp])
    x.sort()
    np.testing.assert_array_equal(_interp_sorted(x, xp, fp), np.interp(x, xp, fp))


@settings(max_examples=100, deadline=None, derandomize=True)
@given(
    h=st.integers(1, 5),
    y=st.lists(st.floats(-1e3, 1e3), min_size=11, max_size=11),
)
def test_parabola_is_the_least_squares_fit(h: int, y: list[float]) -> None:
    """The closed-form fit through the minimum and its neighbours is np.polyfit's."""
    ys = y[: 2 * h + 1]
    a, b = _parabola(ys)
    ref_a, ref_b, _ = np.polyfit(np.arange(-h, h + 1, dtype=np.float64), ys, 2)
    scale = 1.0 + max(abs(v) for v in ys)
    assert a == pytest.approx(ref_a, rel=1e-9, abs=1e-9 * scale)
    assert b == pytest.approx(ref_b, rel=1e-9, abs=1e-9 * scale)
