"""Singularities: reported (by name and by the IK), not jumped."""

from __future__ import annotations

import numpy as np
import pytest

from kinematics import SingularityError, get_model


def test_wrist_singularity_is_reported_not_jumped() -> None:
    m = get_model()
    q = [10.0, 20.0, 70.0, 35.0, 0.0, -15.0]
    T = m.flange2base(q)
    sols = m.ik(T, near=q)
    assert "wrist" in sols[0].singularities
    # J4 is kept where it was; J6 takes the rest (J4 + J6 is what the pose fixes).
    np.testing.assert_allclose(sols[0].joints_deg, q, atol=1e-9)
    for s in sols:
        np.testing.assert_allclose(m.flange2base(s.joints_deg), T, atol=1e-9)
    with pytest.raises(SingularityError) as info:
        m.ik(T, raise_on_singularity=True)
    assert info.value.kind == "wrist"
    assert m.singularities(q) == ("wrist",)


def test_elbow_and_shoulder_singularities() -> None:
    m = get_model()
    assert set(m.singularities([0, 0, 0, 0, 0, 0])) == {"wrist", "elbow", "shoulder"}
    stretched = [0.0, 45.0, 0.0, 0.0, 30.0, 0.0]
    assert m.singularities(stretched) == ("elbow",)
    sols = m.ik(m.flange2base(stretched))
    assert all("elbow" in s.singularities for s in sols)
    # Wrist centre right above axis 1: r = 450 sin(-45°) + 450 sin(45°) = 0.
    over = [0.0, -45.0, 90.0, 0.0, 30.0, 0.0]
    assert m.singularities(over) == ("shoulder",)
    assert m.manipulability(over) < 1e-6
    with pytest.raises(SingularityError) as info:
        m.ik(m.flange2base(over), near=over, raise_on_singularity=True)
    assert info.value.kind == "shoulder"
    sols = m.ik(m.flange2base(over), near=over)
    np.testing.assert_allclose(sols[0].joints_deg, over, atol=1e-9)
