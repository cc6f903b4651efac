"""Timing laws: the trapezoidal profile (no I/O)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robotsocket.profiles import Decel, Hold, Trapezoid


@settings(max_examples=200, deadline=None)
@given(
    s0=st.floats(0.0, 0.99),
    vmax=st.floats(0.05, 20.0),
    acc=st.floats(0.5, 500.0),
    dec=st.floats(0.5, 500.0),
)
def test_trapezoid_reaches_one_within_limits(
    s0: float, vmax: float, acc: float, dec: float
) -> None:
    law = Trapezoid(0.0, s0, vmax, acc, dec)
    t = np.linspace(0.0, law.t_end, 2001)
    s = np.array([law.at(x)[0] for x in t])
    v = np.array([law.at(x)[1] for x in t])
    assert s[0] == pytest.approx(s0) and law.at(law.t_end + 1.0) == (1.0, 0.0)
    assert np.all(np.diff(s) >= -1e-12)
    assert v.max() <= vmax * (1 + 1e-9)
    # The velocity is the derivative of s (independent check by finite differences).
    dt = t[1] - t[0]
    np.testing.assert_allclose(np.gradient(s, dt)[5:-5], v[5:-5], atol=max(acc, dec) * dt * 2)


def test_decel_stops_on_the_path_and_hold_stays() -> None:
    law = Decel(1.0, 0.25, 2.0, 8.0)  # from s = 0.25 at 2 /s, braking at 8 /s^2
    assert law.t_end == 1.25 and law.s_end == 0.5
    assert law.at(0.5) == (0.25, 2.0) and law.at(1.125) == (0.4375, 1.0)
    assert law.at(9.0) == (0.5, 0.0)
    # Braking never overshoots the end of the path.
    assert Decel(0.0, 0.9, 2.0, 1.0).at(5.0) == (1.0, 0.0)
    np.testing.assert_array_equal(Hold(0.5).s_array(np.arange(3.0)), [0.5, 0.5, 0.5])
