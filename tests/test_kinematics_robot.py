"""Stäubli models: hand-checkable DGM poses, IK round trips, Jacobian, errors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics import (
    CONFIGS,
    JointLimitError,
    KinematicsError,
    RobotModel,
    SingularityError,
    UnknownModelError,
    UnreachableError,
    get_model,
    list_models,
    load_model,
    location_to_transform,
)

MODELS = ["RX90B", "RX130B", "RX160", "TX90"]
SETTINGS = settings(max_examples=200, deadline=None, derandomize=True)

# (a1 shoulder offset, d lateral offset, a2 upper arm, d4 forearm, d6 wrist to flange), from
# DESIGN.md's manufacturer dimensions.
DIMS = {
    "RX90B": (0.0, 0.0, 450.0, 450.0, 85.0),
    "RX130B": (0.0, 0.0, 625.0, 625.0, 110.0),
    "RX160": (150.0, 0.0, 825.0, 625.0, 110.0),
    "TX90": (50.0, 50.0, 425.0, 425.0, 100.0),
}

I3 = np.eye(3)
RY90 = np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
RZ90 = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])


def hand_poses(name: str) -> list[tuple[list[float], list[float], np.ndarray]]:
    """(joints, expected flange position, expected rotation) worked out on paper."""
    a1, d, a2, d4, d6 = DIMS[name]
    L = a2 + d4 + d6
    return [
        ([0, 0, 0, 0, 0, 0], [a1, d, L], I3),  # arm straight up
        ([90, 0, 0, 0, 0, 0], [-d, a1, L], RZ90),
        ([-90, 0, 0, 0, 0, 0], [d, -a1, L], RZ90.T),
        ([0, 90, 0, 0, 0, 0], [a1 + L, d, 0], RY90),  # whole arm horizontal, forward
        ([0, -90, 0, 0, 0, 0], [a1 - L, d, 0], RY90.T),
        ([0, 0, 90, 0, 0, 0], [a1 + d4 + d6, d, a2], RY90),  # forearm horizontal
        ([0, 0, -90, 0, 0, 0], [a1 - d4 - d6, d, a2], RY90.T),
        ([0, 0, 0, 90, 0, 0], [a1, d, L], RZ90),
        ([0, 0, 0, -90, 0, 0], [a1, d, L], RZ90.T),
        ([0, 0, 0, 0, 90, 0], [a1 + d6, d, a2 + d4], RY90),
        ([0, 0, 0, 0, -90, 0], [a1 - d6, d, a2 + d4], RY90.T),
        ([0, 0, 0, 0, 0, 90], [a1, d, L], RZ90),
        ([0, 0, 0, 0, 0, -90], [a1, d, L], RZ90.T),
        ([0, 90, -90, 0, 0, 0], [a1 + a2, d, d4 + d6], I3),  # upper arm horizontal
        # Usual work pose: forearm forward, flange pointing down.
        ([0, 0, 90, 0, 90, 0], [a1 + d4, d, a2 - d6], RY90 @ RY90),
    ]


@pytest.mark.parametrize("name", MODELS)
def test_hand_checkable_poses(name: str) -> None:
    m = get_model(name)
    for q, p, R in hand_poses(name):
        T = m.flange2base(q)
        np.testing.assert_allclose(T[:3, 3], p, atol=1e-9, err_msg=f"{name} {q}")
        np.testing.assert_allclose(T[:3, :3], R, atol=1e-12, err_msg=f"{name} {q}")
        np.testing.assert_allclose(T[3], [0, 0, 0, 1])


def test_rx90b_literal_values() -> None:
    m = get_model()
    assert m.name == "RX90B"
    np.testing.assert_allclose(m.flange2base([0] * 6)[:3, 3], [0, 0, 985], atol=1e-12)
    np.testing.assert_allclose(m.flange2base([0, 0, 90, 0, 90, 0])[:3, 3], [450, 0, 365])
    # J1 = 30 turns the work pose counter-clockwise seen from above.
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(
        m.flange2base([30, 0, 90, 0, 90, 0])[:3, 3], [450 * c, 450 * s, 365], atol=1e-9
    )


def test_models_are_listed_with_limits() -> None:
    assert set(MODELS) <= set(list_models())
    m = get_model("tx90")  # case-insensitive
    assert m.limits.shape == (6, 2)
    assert m.joint_limits_deg[1] == (-130.0, 147.5)


def test_encoder_offset_is_data(tmp_path: Path) -> None:
    data = get_model("RX90B").to_dict()
    data["name"] = "RX90B-cal"
    data["joint_offsets_deg"] = [0, 0.5, 0, 0, 0, 0]
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(data))
    m = load_model(path)
    ref = get_model("RX90B")
    q = [10, 20, 30, 40, 50, 60]
    np.testing.assert_allclose(m.flange2base(q), ref.flange2base([10, 20.5, 30, 40, 50, 60]))
    sols = m.ik(m.flange2base(q), near=q)
    np.testing.assert_allclose(sols[0].joints_deg, q, atol=1e-9)
    assert get_model(str(path)).name == "RX90B-cal"


def test_bad_model_data() -> None:
    with pytest.raises(UnknownModelError):
        get_model("KR16")
    data = get_model().to_dict()
    data["joint_limits_deg"] = data["joint_limits_deg"][:5]
    with pytest.raises(KinematicsError):
        RobotModel.from_dict(data)
    with pytest.raises(KinematicsError):
        RobotModel.from_dict({"name": "x"})


def _joints(name: str) -> st.SearchStrategy[list[float]]:
    lim = get_model(name).limits
    return st.tuples(*[st.floats(float(lo), float(hi)) for lo, hi in lim]).map(list)


def _away_from_singularities(name: str, q: list[float]) -> bool:
    m = get_model(name)
    r, s3, s5 = m._geometry(q)
    return abs(s3) > 0.02 and abs(s5) > 0.02 and abs(r) > 20.0


def _rad_close(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(np.radians(a - b))))


@pytest.mark.parametrize("name", MODELS)
@SETTINGS
@given(data=st.data())
def test_ik_contains_q_and_every_solution_maps_back(name: str, data: st.DataObject) -> None:
    m = get_model(name)
    q = data.draw(_joints(name).filter(lambda v: _away_from_singularities(name, v)))
    T = m.flange2base(q)
    sols = m.ik(T, near=q)
    assert 1 <= len(sols) <= 8
    assert _rad_close(sols[0].joints_deg, np.array(q)) < 1e-9  # nearest first
    assert sols[0].config == m.config_of(q)
    for s in sols:
        assert m.within_limits(s.joints_deg)
        assert m.config_of(s.joints_deg) == s.config
        Ts = m.flange2base(s.joints_deg)
        assert np.max(np.abs(Ts[:3, 3] - T[:3, 3])) < 1e-9  # mm
        assert np.max(np.abs(Ts[:3, :3] - T[:3, :3])) < 1e-12
    # q itself is away from singularities (other branches may meet one by coincidence).
    assert sols[0].singularities == ()
    # Without near: q is still among the solutions, J4/J6 possibly one turn away.
    plain = m.ik(T)
    diffs = [((s.joints_deg - q + 180.0) % 360.0) - 180.0 for s in plain]
    assert min(float(np.max(np.abs(np.radians(d)))) for d in diffs) < 1e-9


@pytest.mark.parametrize("name", MODELS)
def test_small_batches_bit_equal_to_large(name: str) -> None:
    # a few configurations take the Python-float path; they must give the numpy path's
    # numbers exactly (the emulated cell renders from them and its runs are reproducible)
    m = get_model(name)
    rng = np.random.default_rng(5)
    q = rng.uniform(-200.0, 200.0, (400, 6))
    big = m.flange2base_batch(q)
    start = 0
    for n in (1, 2, 3, 5, 7, 12, 0, 1):
        small = m.flange2base_batch(q[start : start + n])
        assert small.shape == (n, 4, 4)
        assert np.array_equal(small, big[start : start + n])
        start += n


@pytest.mark.parametrize("name", MODELS)
def test_batch_equals_single(name: str) -> None:
    m = get_model(name)
    rng = np.random.default_rng(3)
    q = rng.uniform(m.limits[:, 0], m.limits[:, 1], (300, 6))
    Tb = m.flange2base_batch(q)
    assert Tb.shape == (300, 4, 4)
    for i in range(0, 300, 7):
        np.testing.assert_allclose(Tb[i], m.flange2base(q[i]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.flange2base(q), Tb)  # (N, 6) dispatches to the batch
    batch = m.ik_batch(Tb, near=q)
    assert batch.joints_deg.shape == (300, 8, 6)
    for i in range(0, 300, 11):
        try:
            sols = m.ik(Tb[i], near=q[i])
        except (UnreachableError, JointLimitError):
            assert not batch.valid[i].any()
            continue
        got = {s.config: s.joints_deg for s in sols}
        for k, cfg in enumerate(CONFIGS):
            if cfg in got:
                np.testing.assert_allclose(batch.joints_deg[i, k], got[cfg], atol=1e-12)
            elif batch.valid[i, k]:
                # Dropped by ik() only as a duplicate at a singularity.
                assert any(np.allclose(batch.joints_deg[i, k], v, atol=1e-9) for v in got.values())


def test_config_selection() -> None:
    m = get_model("RX90B")
    q = [20.0, 30.0, 60.0, 10.0, 40.0, -30.0]
    T = m.flange2base(q)
    every = m.ik(T)
    assert len(every) == len({s.config for s in every})
    assert m.config_of(q).as_dict() == {
        "shoulder": "righty", "elbow": "epositive", "wrist": "wpositive"
    }  # fmt: skip
    only = m.ik(T, config="righty,epositive,wpositive")
    assert len(only) == 1
    np.testing.assert_allclose(only[0].joints_deg, q, atol=1e-9)
    neg = m.ik(T, config="enegative")
    assert neg and all(s.config.elbow == "enegative" and s.joints_deg[2] < 0 for s in neg)
    wneg = m.ik(T, config="wnegative")
    assert all(s.joints_deg[4] < 0 for s in wneg)
    lefty = m.ik(T, config="lefty")
    for s in lefty:  # lefty: wrist centre behind axis 1, J1 turned about 180° away
        assert abs(((s.joints_deg[0] - q[0]) % 360.0) - 180.0) < 1e-6
    same = m.ik(T, config="ssame,esame,wsame", near=q)
    assert len(same) == 1 and same[0].config == m.config_of(q)
    with pytest.raises(KinematicsError):
        m.ik(T, config="elbowup")
    with pytest.raises(KinematicsError):
        m.ik(T, config="ssame")  # needs near


def test_near_picks_the_turn_of_j4_j6() -> None:
    m = get_model("RX90B")
    q = [0.0, 30.0, 60.0, 200.0, 40.0, -250.0]
    T = m.flange2base(q)
    np.testing.assert_allclose(m.ik(T, near=q)[0].joints_deg, q, atol=1e-9)
    default = m.ik(T, config="righty,epositive,wpositive")[0].joints_deg
    np.testing.assert_allclose(default, [0, 30, 60, -160, 40, 110], atol=1e-9)


def test_unreachable_and_limit_errors() -> None:
    m = get_model("RX90B")
    far = location_to_transform([2000, 0, 0, 0, 0, 0])
    with pytest.raises(UnreachableError, match="unreachable"):
        m.ik(far)
    # Reachable geometrically, but only with J2 far beyond its ±137.5° limit:
    # the wrist centre straight below axis 2.
    below = location_to_transform([0, 0, -885, 0, 180, 0])
    with pytest.raises(JointLimitError):
        m.ik(below)
    batch = m.ik_batch(np.stack([far, below]))
    assert not batch.valid.any() and not batch.reachable[0].any() and batch.reachable[1].any()
    assert np.isnan(batch.joints_deg).all()
    with pytest.raises(JointLimitError):
        m.check_joints([0, 0, 0, 0, 130, 0])
    assert m.within_limits([0, 0, 0, 0, 120, 0])


def test_tx90_lateral_offset_unreachable_inside_cylinder() -> None:
    m = get_model("TX90")
    # Wrist centre on axis 1: closer than the 50 mm lateral offset.
    T = location_to_transform([0, 0, 700 + 100, 0, 0, 0])
    with pytest.raises(UnreachableError, match="lateral"):
        m.ik(T)


@pytest.mark.parametrize(
    "bad",
    [[0, 0, 0], [0, 0, 0, 0, 0, float("nan")], "abcdef", [[0] * 6, [0] * 5]],
)
def test_bad_joints(bad: object) -> None:
    m = get_model()
    with pytest.raises(KinematicsError):
        m.flange2base(bad)


def test_bad_ik_input() -> None:
    m = get_model()
    with pytest.raises(KinematicsError):
        m.ik(np.eye(3))
    T = np.eye(4)
    T[0, 3] = np.nan
    with pytest.raises(KinematicsError):
        m.ik(T)
    with pytest.raises(KinematicsError):
        m.ik_batch(np.eye(4))
    with pytest.raises(KinematicsError):
        m.flange2base_batch(np.zeros((3, 5)))


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
    a1, _, a2, d4, _ = DIMS[name]
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
