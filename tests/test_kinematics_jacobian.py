"""The Jacobian against finite differences, in the tool frame, with a tool; manipulability."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kinematics import KinematicsError, RobotModel, get_model, list_models, location_to_transform

MODELS = list_models()


def _numeric_jacobian(m: RobotModel, q: list[float], h: float = 1e-6) -> np.ndarray:
    J = np.zeros((6, 6))
    T0 = m.flange2base(q)
    for i in range(6):
        dq = list(q)
        dq[i] += math.degrees(h)
        T1 = m.flange2base(dq)
        dq[i] -= 2 * math.degrees(h)
        Tm = m.flange2base(dq)
        J[:3, i] = (T1[:3, 3] - Tm[:3, 3]) / (2 * h)
        W = (T1[:3, :3] - Tm[:3, :3]) / (2 * h) @ T0[:3, :3].T
        J[3:, i] = [W[2, 1], W[0, 2], W[1, 0]]
    return J


@pytest.mark.parametrize("name", MODELS)
def test_jacobian_against_finite_differences(name: str) -> None:
    m = get_model(name)
    q = [15.0, 25.0, 50.0, -30.0, 60.0, 45.0]
    J = m.jacobian(q)
    np.testing.assert_allclose(J, _numeric_jacobian(m, q), atol=1e-5)
    Jt = m.jacobian(q, frame="tool")
    R = m.flange2base(q)[:3, :3]
    np.testing.assert_allclose(Jt[:3], R.T @ J[:3], atol=1e-9)
    np.testing.assert_allclose(Jt[3:], R.T @ J[3:], atol=1e-12)
    a1, a2, d4 = m.shoulder_offset_mm, m.upper_arm_mm, m.forearm_mm
    t = np.radians(q)
    r = a1 + a2 * math.sin(t[1]) + d4 * math.sin(t[1] + t[2])
    expected = a2 * d4 * abs(math.sin(t[2])) * abs(r) * abs(math.sin(t[4]))
    assert m.manipulability(q) == pytest.approx(expected, rel=1e-9)


def test_jacobian_with_tool_moves_the_reference_point() -> None:
    m = get_model()
    q = [15.0, 25.0, 50.0, -30.0, 60.0, 45.0]
    tool = location_to_transform([0, 0, 200, 0, 0, 0])
    J = m.jacobian(q, tool=tool)
    Jf = m.jacobian(q)
    lever = m.flange2base(q)[:3, :3] @ np.array([0, 0, 200.0])
    # v_tool = v_flange + w × lever
    np.testing.assert_allclose(J[:3], Jf[:3] + np.cross(Jf[3:].T, lever).T, atol=1e-9)
    with pytest.raises(KinematicsError):
        m.jacobian(q, frame="world")  # type: ignore[arg-type]
