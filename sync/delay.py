"""Measuring the time delay ΔT (paper section VI, eqs. 6-7) and checking it (Fig. 9).

The experiment moves the sensor in a sine perpendicular to a straight seam. The robot gives
the lateral displacement y^R(t_k^R) of the sensor tool from its joints (every T_r = 4 ms);
the sensor gives y^S(t_i^T), stamped with the trigger send times. Both are upsampled to
5 kHz (t_j = j · 0.2 ms, linear interpolation) and the mean-squared error is evaluated for
each candidate delay on the 0.2 ms grid; a parabola through the minimum and its neighbours
gives the sub-grid estimate.

Sign convention. A reading stamped t_i^T was taken at t_i^S = t_i^T + ΔT (eq. 4), so it must
match the robot at t_i^T + ΔT. This module therefore minimises

    MSE(ΔT) = mean_j (y^S(t_j) - y^R(t_j + ΔT))^2,

which is eq. 6 with the shift moved to the robot signal; read literally, eq. 6
(y^S(t_j + ΔT) - y^R(t_j)) has its minimum at -ΔT. The estimate is positive for a sensor
that measures after the trigger was sent.

Each MSE value is a mean over the samples that overlap for that shift (the overlap shrinks
as the shift grows); a plain sum would be biased towards shifts with less overlap by a few
tenths of a millisecond. The estimate includes the *mean* trigger-to-exposure jitter: that
is the delay the synchronisation should apply.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sync.mse_curve import grid_span, mse_curve

__all__ = [
    "DEFAULT_GRID_STEP_S",
    "DelayEstimate",
    "DelayEstimateError",
    "NoInteriorMinimumError",
    "QualityLimits",
    "ResidualReport",
    "ResidualStats",
    "SineExperiment",
    "Verdict",
    "assess_run",
    "estimate_delay",
    "residual_after_sync",
    "simulate_sine_experiment",
    "sine_amplitude",
    "upsample",
    "window_delays",
]

DEFAULT_GRID_STEP_S = 0.2e-3
"""Common time grid of section VI: 5 kHz."""

GAP_FACTOR = 2.5
"""Sensor samples further apart than this many median intervals bound a gap (lost data):
the grid points inside it are left out of the MSE instead of interpolated across."""


class DelayEstimateError(ValueError):
    """The inputs cannot give a delay estimate (shapes, no overlap, too few samples)."""


@dataclass(frozen=True)
class DelayEstimate:
    """Result of :func:`estimate_delay`.

    Attributes:
        delta_t_s: estimated ΔT in seconds (parabola vertex; the grid value at an edge).
        shifts_s: candidate delays on the grid, shape (S,), seconds.
        mse: MSE(ΔT) per candidate, shape (S,), in squared input units (mm^2 for mm).
        overlap: number of grid samples averaged per candidate, shape (S,).
        min_index: index of the smallest MSE in ``shifts_s``.
        at_edge: the minimum lies at the edge of the search range (no interior minimum;
            widen the range).
        grid_step_s: the grid step (0.2 ms by default).
    """

    delta_t_s: float
    shifts_s: NDArray[np.float64]
    mse: NDArray[np.float64]
    overlap: NDArray[np.int64]
    min_index: int
    at_edge: bool
    grid_step_s: float


class NoInteriorMinimumError(DelayEstimateError):
    """The MSE minimum is at the edge of the search range; ``estimate`` holds the curve."""

    def __init__(self, estimate: DelayEstimate) -> None:
        lo, hi = estimate.shifts_s[0], estimate.shifts_s[-1]
        super().__init__(
            f"MSE minimum at the edge of the search range [{lo * 1e3:.2f}, {hi * 1e3:.2f}] ms"
            f" (at {estimate.shifts_s[estimate.min_index] * 1e3:.2f} ms): widen the range"
        )
        self.estimate = estimate


def _check_signal(name: str, t: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
    """Raise unless times (N,) and values (N,) are finite, N >= 2, times strictly increasing;
    return the intervals np.diff(t)."""
    if t.ndim != 1 or y.shape != t.shape:
        raise DelayEstimateError(f"{name}: expected times (N,) and values (N,), got {t.shape}")
    if t.size < 2:
        raise DelayEstimateError(f"{name}: need at least 2 samples, got {t.size}")
    dt = np.diff(t)
    # Increasing with finite ends means finite times (a NaN makes the minimum NaN); the
    # element-wise checks run only to name what is wrong.
    if dt.min() > 0 and math.isfinite(t[0]) and math.isfinite(t[-1]) and np.isfinite(y).all():
        return dt
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise DelayEstimateError(f"{name}: times and values must be finite")
    raise DelayEstimateError(f"{name}: times must be strictly increasing")


def upsample(
    times: ArrayLike, values: ArrayLike, grid_step_s: float = DEFAULT_GRID_STEP_S
) -> tuple[int, NDArray[np.float64]]:
    """Linearly interpolate a signal onto the grid t_j = j · step inside its time span.

    Returns ``(j0, y)``: the first grid index and the values at t_{j0}, t_{j0+1}, ...
    """
    t = np.asarray(times, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    _check_signal("signal", t, y)
    j0, end = _grid_span(t, grid_step_s)
    grid = np.arange(j0, end, dtype=np.float64) * grid_step_s
    return j0, _interp_sorted(grid, t, y)


def _interp_sorted(
    x: NDArray[np.float64], xp: NDArray[np.float64], fp: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``np.interp(x, xp, fp)`` for increasing x (a grid), bit for bit: the same
    slope·(x - xp[j]) + fp[j] per point, but the piece j of every x found by one search of
    the K knots in x, not one search per point (a 5 kHz grid has 20 points per piece)."""
    pos = np.searchsorted(x, xp)  # x[pos[j]:pos[j + 1]] lies in [xp[j], xp[j + 1])
    counts = np.diff(pos)
    slope = np.diff(fp) / np.diff(xp)
    first, last = int(pos[0]), int(pos[-1])
    out = np.empty(x.shape[0])
    # outside [xp[0], xp[-1]) np.interp gives the end values (at xp[-1] exactly fp[-1])
    out[:first] = fp[0]
    out[last:] = fp[-1]
    inner = out[first:last]
    np.subtract(x[first:last], np.repeat(xp[:-1], counts), out=inner)
    inner *= np.repeat(slope, counts)
    inner += np.repeat(fp[:-1], counts)
    return out


def _grid_span(t: NDArray[np.float64], grid_step_s: float) -> tuple[int, int]:
    """First grid index inside the span of the times ``t``, and one past the last."""
    try:
        return grid_span(t, grid_step_s)
    except ValueError as exc:
        raise DelayEstimateError(str(exc)) from None


def _gap_mask(
    times: NDArray[np.float64], dt: NDArray[np.float64], j0: int, n: int, grid_step_s: float
) -> NDArray[np.float64] | None:
    """1.0 on the grid points t_{j0} .. t_{j0+n-1} that lie between two samples at most
    ``GAP_FACTOR`` median intervals apart, 0.0 inside longer gaps (lost data: a straight line
    across a missing stretch of the sine is not a measurement); None when there is no gap.
    ``dt`` are the intervals np.diff(times)."""
    # the median is at least the shortest interval: no interval that long, no median needed
    if float(np.max(dt)) <= GAP_FACTOR * float(np.min(dt)):
        return None
    gap = dt > GAP_FACTOR * float(np.median(dt))
    if not np.any(gap):
        return None
    grid = np.arange(j0, j0 + n, dtype=np.float64) * grid_step_s
    k = np.clip(np.searchsorted(times, grid, side="right") - 1, 0, dt.size - 1)
    out: NDArray[np.float64] = np.where(gap[k], 0.0, 1.0)
    return out


def _mse_curve_masked(
    jr: int,
    yr: NDArray[np.float64],
    js: int,
    ys: NDArray[np.float64],
    shifts: NDArray[np.int64],
    mask: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The MSE curve over the sensor grid points a ``mask`` keeps (1.0 / 0.0 per point), by
    the plain per-shift sum on the upsampled robot signal ``yr`` (from grid index jr): the
    run with lost data, and the reference :func:`sync.mse_curve.mse_curve` is tested against."""
    mse = np.full(shifts.shape[0], np.inf)
    overlap = np.zeros(shifts.shape[0], dtype=np.int64)
    r_end = jr + yr.shape[0]
    s_end = js + ys.shape[0]
    work = np.empty(ys.shape[0])
    for n, m in enumerate(shifts.tolist()):
        lo = max(js, jr - m)
        hi = min(s_end, r_end - m)
        if hi - lo < 2:
            continue
        # One preallocated buffer: a fresh 400 kB array per shift costs more than the maths.
        e = np.subtract(ys[lo - js : hi - js], yr[lo + m - jr : hi + m - jr], out=work[: hi - lo])
        count = hi - lo
        if mask is not None:
            e *= mask[lo - js : hi - js]
            count = int(np.add.reduce(mask[lo - js : hi - js]))
            if count < 2:
                continue
        # Square and sum in numpy, not np.dot: OpenBLAS splits a long dot product over its
        # threads, and on a busy machine one call could wait 50-400 ms for a core.
        mse[n] = float(np.add.reduce(np.multiply(e, e, out=e))) / count
        overlap[n] = count
    return mse, overlap


def _parabola(y: list[float]) -> tuple[float, float]:
    """Least-squares a·x² + b·x + c through y at x = -h .. h (grid steps from the minimum, so
    the sums stay well scaled); returns (a, b). Odd powers of x sum to zero, which leaves
    b = Σxy / Σx² and two normal equations for a and c."""
    h = len(y) // 2
    xs = range(-h, h + 1)
    n = len(y)
    s2 = sum(x * x for x in xs)
    s4 = sum(x**4 for x in xs)
    sy = math.fsum(y)
    sxy = math.fsum(x * v for x, v in zip(xs, y, strict=True))
    sx2y = math.fsum(x * x * v for x, v in zip(xs, y, strict=True))
    return (n * sx2y - s2 * sy) / (n * s4 - s2 * s2), sxy / s2


def estimate_delay(
    t_robot: ArrayLike,
    y_robot: ArrayLike,
    t_trigger: ArrayLike,
    y_sensor: ArrayLike,
    *,
    search_min_s: float = 0.0,
    search_max_s: float = 20e-3,
    grid_step_s: float = DEFAULT_GRID_STEP_S,
    fit_half_width: int = 1,
    require_interior: bool = True,
) -> DelayEstimate:
    """Estimate ΔT from the sine experiment (eqs. 6-7 plus the parabola fit).

    Args:
        t_robot: robot sample times t_k^R, shape (K,), seconds, strictly increasing.
        y_robot: sensor-tool lateral displacement from the joints, shape (K,), e.g. mm.
        t_trigger: trigger send times t_i^T of the sensor readings, shape (I,), seconds.
        y_sensor: sensor readings y^S, shape (I,), same unit as ``y_robot``.
        search_min_s, search_max_s: searched delay range in seconds (negative allowed).
        grid_step_s: the common grid (0.2 ms = 5 kHz).
        fit_half_width: the parabola is fitted (least squares) through the minimum and this
            many grid neighbours on each side; 1 is the paper's three-point fit.
        require_interior: raise :class:`NoInteriorMinimumError` when the minimum is at the
            edge of the range; otherwise return with ``at_edge=True`` and the grid value.

    Returns:
        :class:`DelayEstimate` with the MSE curve.
    """
    tr = np.asarray(t_robot, dtype=np.float64)
    yr_in = np.asarray(y_robot, dtype=np.float64)
    ts = np.asarray(t_trigger, dtype=np.float64)
    ys_in = np.asarray(y_sensor, dtype=np.float64)
    _check_signal("robot", tr, yr_in)
    dt_s = _check_signal("sensor", ts, ys_in)
    if fit_half_width < 1:
        raise DelayEstimateError("fit_half_width must be >= 1")
    if not (math.isfinite(search_min_s) and math.isfinite(search_max_s)):
        raise DelayEstimateError("search range must be finite")
    m_lo = round(search_min_s / grid_step_s)
    m_hi = round(search_max_s / grid_step_s)
    if m_hi - m_lo < 2 * fit_half_width:
        raise DelayEstimateError("search range must span at least 2 * fit_half_width grid steps")
    _grid_span(tr, grid_step_s)
    js, s_end = _grid_span(ts, grid_step_s)
    shifts = np.arange(m_lo, m_hi + 1, dtype=np.int64)
    shifts_s = shifts.astype(np.float64) * grid_step_s
    mask = _gap_mask(ts, dt_s, js, s_end - js, grid_step_s)
    if mask is None:
        mse, overlap = mse_curve((ts, ys_in), (tr, yr_in), shifts, grid_step_s)
    else:
        # lost data: the grid points inside its gaps are left out, shift by shift
        jr, yr = upsample(tr, yr_in, grid_step_s)
        js, ys = upsample(ts, ys_in, grid_step_s)
        mse, overlap = _mse_curve_masked(jr, yr, js, ys, shifts, mask)
    if not np.all(np.isfinite(mse)):
        raise DelayEstimateError("robot and sensor signals do not overlap for every searched delay")
    i = int(np.argmin(mse))
    h = fit_half_width
    at_edge = i < h or i > shifts.shape[0] - 1 - h
    if at_edge:
        est = DelayEstimate(
            delta_t_s=float(shifts[i] * grid_step_s),
            shifts_s=shifts_s,
            mse=mse,
            overlap=overlap,
            min_index=i,
            at_edge=True,
            grid_step_s=grid_step_s,
        )
        if require_interior:
            raise NoInteriorMinimumError(est)
        return est
    a, b = _parabola(mse[i - h : i + h + 1].tolist())
    # Flat or concave around the grid minimum: keep the grid value.
    vertex = min(max(-b / (2.0 * a), -h), h) if a > 0 else 0.0
    return DelayEstimate(
        delta_t_s=float((shifts[i] + vertex) * grid_step_s),
        shifts_s=shifts_s,
        mse=mse,
        overlap=overlap,
        min_index=i,
        at_edge=False,
        grid_step_s=grid_step_s,
    )


@dataclass(frozen=True)
class ResidualStats:
    """Residual y^S(t_i^T) - y^R(t_i^T + ΔT) over the sensor readings inside the robot span.

    ``max_um``, ``rms_um`` and ``sine_amplitude_um`` are in µm when the inputs are in mm (the
    ``unit_to_um`` factor of :func:`residual_after_sync`). ``sine_amplitude_um`` is the
    amplitude of a least-squares sine at the experiment frequency (NaN without a frequency).
    """

    delta_t_s: float
    times_s: NDArray[np.float64]
    residual_um: NDArray[np.float64]
    max_um: float
    rms_um: float
    sine_amplitude_um: float


@dataclass(frozen=True)
class ResidualReport:
    """The residual with the estimated ΔT (Fig. 9) and without synchronisation (ΔT = 0)."""

    synced: ResidualStats
    unsynced: ResidualStats


def _sine_amplitude(t: NDArray[np.float64], r: NDArray[np.float64], frequency_hz: float) -> float:
    w = 2.0 * math.pi * frequency_hz
    basis = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(basis, r, rcond=None)
    return float(math.hypot(coef[0], coef[1]))


def _residual(
    tr: NDArray[np.float64],
    yr: NDArray[np.float64],
    ts: NDArray[np.float64],
    ys: NDArray[np.float64],
    delta_t_s: float,
    frequency_hz: float | None,
    scale: float,
) -> ResidualStats:
    t_s = ts + delta_t_s  # eq. 4
    inside = (t_s >= tr[0]) & (t_s <= tr[-1])
    if np.count_nonzero(inside) < 4:
        raise DelayEstimateError("fewer than 4 sensor readings fall inside the robot time span")
    t_in = t_s[inside]
    r = (ys[inside] - np.interp(t_in, tr, yr)) * scale
    amp = math.nan
    if frequency_hz is not None:
        amp = _sine_amplitude(t_in, r, frequency_hz)
    return ResidualStats(
        delta_t_s=float(delta_t_s),
        times_s=t_in,
        residual_um=r,
        max_um=float(np.max(np.abs(r))),
        rms_um=float(np.sqrt(np.mean(r * r))),
        sine_amplitude_um=amp,
    )


def residual_after_sync(
    t_robot: ArrayLike,
    y_robot: ArrayLike,
    t_trigger: ArrayLike,
    y_sensor: ArrayLike,
    delta_t_s: float,
    *,
    frequency_hz: float | None = None,
    unit_to_um: float = 1000.0,
) -> ResidualReport:
    """Apply ΔT (eq. 4) and compare each reading with the robot interpolated at t_i^T + ΔT.

    Args:
        t_robot, y_robot: robot times (K,) s and displacements (K,) (mm by default).
        t_trigger, y_sensor: trigger send times (I,) s and sensor readings (I,).
        delta_t_s: the delay to apply, seconds.
        frequency_hz: the sine frequency, for the residual's amplitude at that frequency
            (a remaining sine means a wrong ΔT).
        unit_to_um: factor from the input unit to µm (1000 for mm).

    Returns:
        :class:`ResidualReport`: the same figures with ``delta_t_s`` and with ΔT = 0.
    """
    tr = np.asarray(t_robot, dtype=np.float64)
    yr = np.asarray(y_robot, dtype=np.float64)
    ts = np.asarray(t_trigger, dtype=np.float64)
    ys = np.asarray(y_sensor, dtype=np.float64)
    _check_signal("robot", tr, yr)
    _check_signal("sensor", ts, ys)
    if not math.isfinite(delta_t_s):
        raise DelayEstimateError("delta_t_s must be finite")
    return ResidualReport(
        synced=_residual(tr, yr, ts, ys, delta_t_s, frequency_hz, unit_to_um),
        unsynced=_residual(tr, yr, ts, ys, 0.0, frequency_hz, unit_to_um),
    )


@dataclass(frozen=True)
class SineExperiment:
    """Synthetic data of the section VI experiment (see :func:`simulate_sine_experiment`).

    ``t_robot``/``y_robot``: robot times (K,) s and tool displacement (K,) mm;
    ``t_trigger``/``y_sensor``: trigger send times (I,) s and sensor readings (I,) mm;
    ``t_exposure``: the true measurement times (I,) s. ``expected_delta_t_s`` is the delay
    plus the mean jitter, i.e. what the estimator should return.
    """

    t_robot: NDArray[np.float64]
    y_robot: NDArray[np.float64]
    t_trigger: NDArray[np.float64]
    y_sensor: NDArray[np.float64]
    t_exposure: NDArray[np.float64]
    delay_s: float
    mean_jitter_s: float
    amplitude_mm: float
    frequency_hz: float

    @property
    def expected_delta_t_s(self) -> float:
        """True delay plus mean trigger-to-exposure jitter, seconds."""
        return self.delay_s + self.mean_jitter_s


def simulate_sine_experiment(
    rng: np.random.Generator,
    *,
    frequency_hz: float = 1.5,
    amplitude_mm: float = 2.0,
    duration_s: float = 10.0,
    delay_s: float = 4.9e-3,
    robot_period_s: float = 4e-3,
    trigger_period_s: float = 4e-3,
    trigger_phase_s: float | None = None,
    jitter_uniform_s: float = 0.5e-3,
    jitter_normal_s: float = 0.1e-3,
    sensor_noise_mm: float = 0.01,
    robot_noise_mm: float = 0.0,
) -> SineExperiment:
    """Generate the sine experiment with the paper's timing.

    The tool follows y(t) = A sin(2π f t) exactly. The robot samples it at k · T_r. Triggers
    are sent at phase + i · trigger_period (the phase is drawn uniformly in [0, period) when
    not given, so trigger and robot sample instants are unrelated); each image is taken at
    t_i^T + delay + U(0, jitter_uniform) + N(0, jitter_normal) and read with N(0, noise).
    """
    if not (duration_s > 0 and robot_period_s > 0 and trigger_period_s > 0):
        raise ValueError("duration and periods must be positive")
    if trigger_phase_s is None:
        trigger_phase_s = float(rng.uniform(0.0, trigger_period_s))
    w = 2.0 * math.pi * frequency_hz
    t_r = np.arange(0, int(duration_s / robot_period_s + 1e-9) + 1, dtype=np.float64)
    t_r *= robot_period_s
    y_r = amplitude_mm * np.sin(w * t_r)
    if robot_noise_mm > 0:
        y_r = y_r + rng.normal(0.0, robot_noise_mm, t_r.shape)
    n_trig = int((duration_s - trigger_phase_s) / trigger_period_s) + 1
    t_t = np.arange(n_trig, dtype=np.float64) * trigger_period_s + trigger_phase_s
    t_t = t_t[t_t <= duration_s]
    jitter = rng.uniform(0.0, jitter_uniform_s, t_t.shape)
    if jitter_normal_s > 0:
        jitter = jitter + rng.normal(0.0, jitter_normal_s, t_t.shape)
    t_x = t_t + delay_s + jitter
    y_s = amplitude_mm * np.sin(w * t_x) + rng.normal(0.0, sensor_noise_mm, t_t.shape)
    return SineExperiment(
        t_robot=t_r,
        y_robot=y_r,
        t_trigger=t_t,
        y_sensor=y_s,
        t_exposure=t_x,
        delay_s=delay_s,
        mean_jitter_s=jitter_uniform_s / 2.0,
        amplitude_mm=amplitude_mm,
        frequency_hz=frequency_hz,
    )


@dataclass(frozen=True)
class QualityLimits:
    """When a ΔT run cannot be trusted (the gates of :func:`assess_run`).

    max_lost_fraction: triggers without data in time (lost on the wire or dropped as late
        by the loss rule [SY-3.3]) per trigger sent, at most.
    max_spread_s: spread (max - min) of ΔT estimated per window, at most. With the
        paper's timing a 1.33 s window's estimate scatters by σ ≈ 0.07 ms (six windows of
        a 10 s run spread 0.10-0.18 ms on the emulated cell): 0.5 ms is about 7σ.
    window_s: shortest window for the per-window ΔT (it also spans >= 2 sine periods).
    max_windows: at most this many windows.
    """

    max_lost_fraction: float = 0.02
    max_spread_s: float = 0.5e-3
    window_s: float = 1.0
    max_windows: int = 8
    # the sensor's seam signal must move at the sine frequency by at least this fraction of the
    # robot's motion; a sensor that does not see the robot (two servers that share no scene)
    # moves by its noise alone, a few µm of 2 mm
    min_motion_seen: float = 0.25


def sine_amplitude(t: ArrayLike, y: ArrayLike, frequency_hz: float) -> float:
    """Amplitude (units of ``y``) of the least-squares fit a·sin(2πft) + b·cos(2πft) + c to the
    samples ``y`` (n,) at times ``t`` (n,) s; 0.0 for fewer than three samples."""
    ts = np.asarray(t, dtype=np.float64)
    ys = np.asarray(y, dtype=np.float64)
    if ts.size < 3:
        return 0.0
    w = 2.0 * math.pi * frequency_hz * ts
    basis = np.column_stack([np.sin(w), np.cos(w), np.ones_like(ts)])
    (a, b, _), *_ = np.linalg.lstsq(basis, ys, rcond=None)
    return float(math.hypot(a, b))


@dataclass(frozen=True)
class Verdict:
    """The quality verdict of one ΔT run: ``ok`` or the ``reasons`` it cannot be trusted
    (one line each, most important first), with the figures they were judged on."""

    ok: bool
    reasons: tuple[str, ...]
    lost_fraction: float
    lost_on_wire: int
    dropped_late: int
    window_delta_t_s: tuple[float, ...]
    spread_s: float

    @property
    def reason(self) -> str:
        """One line: every reason, ``; ``-separated ("" when ok)."""
        return "; ".join(self.reasons)

    def to_json(self) -> dict[str, object]:
        return {
            "ok": self.ok,
            "reasons": list(self.reasons),
            "lost_fraction": self.lost_fraction,
            "lost_on_wire": self.lost_on_wire,
            "dropped_late": self.dropped_late,
            "window_delta_t_ms": [d * 1e3 for d in self.window_delta_t_s],
            "spread_ms": self.spread_s * 1e3 if math.isfinite(self.spread_s) else None,
        }


def window_delays(
    t_robot: ArrayLike,
    y_robot: ArrayLike,
    t_trigger: ArrayLike,
    y_sensor: ArrayLike,
    span: tuple[float, float],
    *,
    period_s: float,
    limits: QualityLimits = QualityLimits(),
    search_min_s: float = 0.0,
    search_max_s: float = 20e-3,
) -> list[DelayEstimate]:
    """ΔT estimated on consecutive windows of ``span`` (t0, t1) s, the part of the run where
    the sine moves at full amplitude; each window at least ``limits.window_s`` and two sine
    periods (``period_s``) long. Fewer than two windows fit: an empty list (not judged)."""
    t0, t1 = span
    length = max(limits.window_s, 2.0 * period_s)
    n = min(int((t1 - t0) / length), limits.max_windows) if t1 > t0 else 0
    if n < 2:
        return []
    ts = np.asarray(t_trigger, dtype=np.float64)
    ys = np.asarray(y_sensor, dtype=np.float64)
    edges = np.linspace(t0, t1, n + 1)
    out = []
    for a, b in itertools.pairwise(edges.tolist()):
        sel = (ts >= a) & (ts < b)
        if np.count_nonzero(sel) < 10:
            raise DelayEstimateError(
                f"only {np.count_nonzero(sel)} sensor readings in the window {a:.2f}-{b:.2f} s"
            )
        out.append(
            estimate_delay(
                t_robot,
                y_robot,
                ts[sel],
                ys[sel],
                search_min_s=search_min_s,
                search_max_s=search_max_s,
                require_interior=False,
            )
        )
    return out


def assess_run(
    estimate: DelayEstimate,
    residual: ResidualReport,
    statistics: Mapping[str, int],
    windows: Sequence[DelayEstimate],
    limits: QualityLimits = QualityLimits(),
    *,
    motion: tuple[float, float, float] | None = None,
    min_duration_s: float | None = None,
) -> Verdict:
    """Judge one ΔT run: the gates of issue 12, each a one-line reason when it fails.

    - with ``min_duration_s`` (the shortest run of two windows), a run without windows is
      too short to judge ΔT's drift: not trusted, with the duration that would be;

    - the sensor never saw the robot's motion: ``motion`` = (sensor amplitude, robot
      amplitude, frequency) in mm and Hz (:func:`sine_amplitude`), the sensor's below
      ``limits.min_motion_seen`` of the robot's; then every other figure is meaningless, so
      this reason comes first;
    - the MSE minimum lies at the edge of the search range (no interior minimum);
    - more than ``max_lost_fraction`` of the triggers got no data in time (``statistics``
      are the run's own counters: ``sent``, ``lost`` (no data within the loss timeout) and
      ``late`` (data that came after it: dropped by policy, not lost on the wire));
    - the residual after synchronisation is not smaller (rms) than without it;
    - ΔT estimated per window (``windows``, :func:`window_delays`) spreads by more than
      ``max_spread_s`` or has a window minimum at the edge: ΔT drifted during the run.
    """
    reasons: list[str] = []
    if motion is not None and not motion[0] >= limits.min_motion_seen * motion[1]:
        seen, moved, frequency = motion
        reasons.append(
            f"the sensor never saw the robot's motion: its seam moved {seen * 1e3:.1f} µm at "
            f"{frequency:g} Hz while the robot moved {moved * 1e3:.0f} µm; do robot and sensor "
            "share one scene? (two separately started servers do not: serve them as one cell, "
            "python -m cell serve)"
        )
    lo, hi = estimate.shifts_s[0] * 1e3, estimate.shifts_s[-1] * 1e3
    if estimate.at_edge:
        reasons.append(
            f"MSE minimum at the edge of the search range [{lo:.2f}, {hi:.2f}] ms "
            f"(at {estimate.delta_t_s * 1e3:.2f} ms): widen the range or check the data"
        )
    sent = int(statistics.get("sent", 0))
    lost = int(statistics.get("lost", 0))
    late = int(statistics.get("late", 0))
    lost_fraction = lost / sent if sent else 0.0
    if lost_fraction > limits.max_lost_fraction:
        reasons.append(
            f"{lost} of {sent} triggers ({lost_fraction:.1%}) got no data in time "
            f"({lost - late} lost on the wire, {late} arrived after the loss timeout); "
            f"limit {limits.max_lost_fraction:.1%}"
        )
    syn, uns = residual.synced, residual.unsynced
    if not syn.rms_um < uns.rms_um:
        reasons.append(
            f"residual after synchronisation (rms {syn.rms_um:.1f} µm) is not smaller than "
            f"without it (rms {uns.rms_um:.1f} µm)"
        )
    deltas = tuple(w.delta_t_s for w in windows)
    spread = max(deltas) - min(deltas) if deltas else math.nan
    if not deltas and min_duration_s is not None:
        reasons.append(
            "too short to judge: ΔT per window needs two windows of full amplitude, a run "
            f"of at least {math.ceil(min_duration_s * 10) / 10:.1f} s at this frequency "
            "(--duration)"
        )
    if any(w.at_edge for w in windows):
        reasons.append(
            "ΔT drifted: a window's MSE minimum is at the edge of the search range "
            f"(per-window ΔT {', '.join(f'{d * 1e3:.2f}' for d in deltas)} ms)"
        )
    elif deltas and spread > limits.max_spread_s:
        reasons.append(
            f"ΔT drifted by {spread * 1e3:.3f} ms across the run (per-window ΔT "
            f"{', '.join(f'{d * 1e3:.2f}' for d in deltas)} ms); limit "
            f"{limits.max_spread_s * 1e3:.2f} ms"
        )
    return Verdict(
        ok=not reasons,
        reasons=tuple(reasons),
        lost_fraction=lost_fraction,
        lost_on_wire=max(lost - late, 0),
        dropped_late=late,
        window_delta_t_s=deltas,
        spread_s=spread,
    )
