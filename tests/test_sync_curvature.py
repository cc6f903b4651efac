"""Tests for sync.curvature: eqs. 8-9 and the paper's R ≈ 32 mm."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sync.curvature import radius_of_curvature, sine_min_radius, sine_min_radius_numeric


def test_paper_case_is_about_32_mm() -> None:
    k = 2 * math.pi * 5 / 250
    assert sine_min_radius(2.0, 5.0, 250.0) == pytest.approx(1 / (2 * k * k), rel=1e-12)
    assert sine_min_radius(2.0, 5.0, 250.0) == pytest.approx(31.66, abs=0.01)
    r, x = sine_min_radius_numeric(2.0, 5.0, 250.0)
    assert r == pytest.approx(31.663, rel=1e-5)
    assert x == pytest.approx(12.5, abs=0.01) or x == pytest.approx(37.5, abs=0.01)


def test_circle_has_its_own_radius() -> None:
    # Upper half of a circle of radius 40 mm: y = sqrt(R^2 - x^2).
    radius = 40.0
    x = np.linspace(-30, 30, 13)
    y = np.sqrt(radius**2 - x**2)
    d1 = -x / y
    d2 = -(radius**2) / y**3
    np.testing.assert_allclose(radius_of_curvature(d1, d2), radius)


def test_straight_line_is_infinite_and_slower_is_tighter() -> None:
    assert np.isinf(radius_of_curvature(0.3, 0.0))
    assert sine_min_radius(2.0, 5.0, 100.0) < sine_min_radius(2.0, 5.0, 250.0)
    with pytest.raises(ValueError):
        sine_min_radius(0.0, 5.0, 250.0)
