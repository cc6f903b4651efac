"""Radius of curvature of the sine seam of Fig. 10 (paper eqs. 8-9).

A sine motion of amplitude A (mm) and frequency f (Hz) performed while travelling at v (mm/s)
traces the seam y(x) = A sin(2π f x / v). Its curvature radius (eq. 9)

    R = (1 + y'^2)^(3/2) / |y''|

is smallest at the crests, where y' = 0 and |y''| = A k^2 with k = 2π f / v, so
R_min = 1 / (A k^2). The paper's case, A = 2 mm, 5 Hz, 250 mm/s, gives 31.66 mm (≈ 32 mm).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "radius_of_curvature",
    "sine_min_radius",
    "sine_min_radius_numeric",
    "sine_seam",
]


def _check_positive(**values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be positive and finite, got {value}")


def sine_seam(
    x_mm: ArrayLike, amplitude_mm: float, frequency_hz: float, speed_mm_s: float
) -> NDArray[np.float64]:
    """Eq. 8: lateral offset y (mm) of the seam at travel distance ``x_mm`` (mm), any shape."""
    k = 2.0 * math.pi * frequency_hz / speed_mm_s
    return amplitude_mm * np.sin(k * np.asarray(x_mm, dtype=np.float64))


def radius_of_curvature(dy_dx: ArrayLike, d2y_dx2: ArrayLike) -> NDArray[np.float64]:
    """Eq. 9 for a curve y = f(x): slope (1) and second derivative (1/mm) -> radius (mm).

    Where the second derivative is zero the radius is infinite.
    """
    d1 = np.asarray(dy_dx, dtype=np.float64)
    d2 = np.abs(np.asarray(d2y_dx2, dtype=np.float64))
    num = (1.0 + d1 * d1) ** 1.5
    with np.errstate(divide="ignore"):
        return np.where(d2 > 0, num / np.where(d2 > 0, d2, 1.0), np.inf)


def sine_min_radius(amplitude_mm: float, frequency_hz: float, speed_mm_s: float) -> float:
    """Analytic minimum radius of curvature (mm) of y = A sin(2π f x / v): 1 / (A k^2)."""
    _check_positive(amplitude_mm=amplitude_mm, frequency_hz=frequency_hz, speed_mm_s=speed_mm_s)
    k = 2.0 * math.pi * frequency_hz / speed_mm_s
    return 1.0 / (amplitude_mm * k * k)


def sine_min_radius_numeric(
    amplitude_mm: float, frequency_hz: float, speed_mm_s: float, *, points_per_period: int = 20001
) -> tuple[float, float]:
    """Numeric check of :func:`sine_min_radius` by finite differences over one period.

    Samples y(x) of eq. 8 over one wavelength v / f, differentiates with ``np.gradient``
    (second order) and evaluates eq. 9. Returns ``(R_min_mm, x_at_min_mm)``; the crest is
    at x = v / (4 f) (12.5 mm in the paper's case) or at 3 v / (4 f).
    """
    _check_positive(amplitude_mm=amplitude_mm, frequency_hz=frequency_hz, speed_mm_s=speed_mm_s)
    if points_per_period < 5:
        raise ValueError("points_per_period must be >= 5")
    wavelength = speed_mm_s / frequency_hz
    x = np.linspace(0.0, wavelength, points_per_period)
    y = sine_seam(x, amplitude_mm, frequency_hz, speed_mm_s)
    d1 = np.gradient(y, x, edge_order=2)
    d2 = np.gradient(d1, x, edge_order=2)
    r = radius_of_curvature(d1, d2)
    i = int(np.argmin(r))
    return float(r[i]), float(x[i])
