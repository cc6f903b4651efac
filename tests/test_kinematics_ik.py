"""The analytic IK: round trips, batch against single, configurations, turns, errors."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kinematics import (
    CONFIGS,
    JointLimitError,
    KinematicsError,
    UnreachableError,
    get_model,
    list_models,
    location_to_transform,
)
from kinematics.config import Config

MODELS = list_models()
SETTINGS = settings(max_examples=200, deadline=None, derandomize=True)


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


def _special_poses(name: str) -> list[list[float]]:
    """Joints on each singularity and on both wrist-degenerate branches, plus plain ones."""
    m = get_model(name)
    rng = np.random.default_rng(11)
    qs = [list(v) for v in rng.uniform(m.limits[:, 0], m.limits[:, 1], (40, 6))]
    for q in list(qs[:10]):
        qs.append([q[0], q[1], q[2], q[3], 0.0, q[5]])  # axes 4 and 6 aligned
        qs.append([q[0], q[1], -m.joint_offsets_deg[2], q[3], q[4], q[5]])  # stretched
    return qs


@pytest.mark.parametrize("name", MODELS)
@pytest.mark.parametrize("with_near", [False, True])
def test_scalar_ik_equals_the_batch_core_branch_by_branch(name: str, with_near: bool) -> None:
    """The single-pose fast path is the batch formula in Python floats: every branch, its
    reachability, joints (turn included) and singular flags agree."""
    m = get_model(name)
    for q in _special_poses(name):
        T = m.flange2base(q)
        ref = q if with_near else None
        batch = m.ik_batch(T[None], near=ref)
        branches = m._ik_one(T.tolist(), ref)
        assert len(branches) == len(CONFIGS)
        for k, (joints, reachable, singular) in enumerate(branches):
            assert reachable == bool(batch.reachable[0, k])
            if joints is None:
                assert not batch.valid[0, k] and singular is None
            else:
                assert batch.valid[0, k]
                assert singular == tuple(bool(f) for f in batch.singular[0, k])
                np.testing.assert_allclose(joints, batch.joints_deg[0, k], atol=1e-9)


@SETTINGS
@given(
    i=st.integers(0, 3),
    j=st.integers(0, 3),
    delta=st.sampled_from([0.0, 1e-7, -1e-7, 2e-6, -2e-6, 1e-3, np.nan, np.inf]),
)
def test_single_pose_check_rejects_what_check_transform_rejects(
    i: int, j: int, delta: float
) -> None:
    """ik()'s own check of one (4, 4) float64 accepts and rejects as check_transform."""
    from kinematics.transforms import check_transform

    m = get_model("RX90B")
    T = m.flange2base([10.0, 20.0, 30.0, 40.0, 50.0, 60.0])
    T[i, j] += delta
    try:
        check_transform(T, name="flange2base")
        expected = None
    except KinematicsError as exc:
        expected = str(exc)
    try:
        m.ik(T)
        got = None
    except KinematicsError as exc:
        got = str(exc)
    if expected is None:
        assert got is None or not got.startswith("flange2base:")
    else:
        assert got == expected


def test_single_pose_check_rejects_a_reflection() -> None:
    T = np.eye(4)
    T[2, 2] = -1.0
    with pytest.raises(KinematicsError, match="det"):
        get_model().ik(T)


@pytest.mark.parametrize("ulps", [-3, 0, 3])
def test_a_turn_tie_at_180_goes_above_the_target_in_both_paths(ulps: int) -> None:
    """Two turns 180° either side of the target tie; which one wins must not hang on the last
    bits of atan2 (numpy's and libm's differ), in the scalar and the batch pick alike."""
    from kinematics.ik import _pick_turn_one

    m = get_model("RX90B")
    target = 66.79407317732193
    q = np.nextafter(target - 180.0, np.inf * ulps) if ulps else target - 180.0
    for _ in range(abs(ulps) - 1):
        q = np.nextafter(q, np.inf * ulps)
    bounds = m._turn_bounds[3]  # ±270°: both turns inside
    assert not bounds[2]
    one = _pick_turn_one(float(q), bounds, target)
    qb = np.full((1, 8, 6), float(q))
    batch = m._pick_turn(qb, np.full((1, 6), target))[0, 0, 3]
    assert one == batch
    assert one is not None and abs(one - (target + 180.0)) < 1e-9


def _on_shoulder_singularity(name: str, q: list[float]) -> list[float] | None:
    """q with joint 2 turned so that the wrist centre lies on the shoulder singularity
    (r = 0), or None when that joint 2 is outside its limits."""
    m = get_model(name)
    off = m.joint_offsets_deg
    t3 = np.radians(q[2] + off[2])
    a2, d4 = m.upper_arm_mm, m.forearm_mm
    amp = np.hypot(a2 + d4 * np.cos(t3), d4 * np.sin(t3))
    if abs(m.shoulder_offset_mm) > amp:
        return None
    beta = np.arctan2(d4 * np.sin(t3), a2 + d4 * np.cos(t3))
    q2 = float(np.degrees(np.arcsin(-m.shoulder_offset_mm / amp) - beta)) - off[1]
    lo, hi = m.limits[1]
    return [q[0], q2, *q[2:]] if lo <= q2 <= hi else None


@pytest.mark.parametrize("name", MODELS)
@SETTINGS
@given(
    data=st.data(),
    special=st.sampled_from(["plain", "wrist", "elbow", "shoulder"]),
    start=st.sampled_from(["none", "q", "tie", "offset"]),
)
def test_single_ik_equals_the_batch_ik_on_random_poses(
    name: str, data: st.DataObject, special: str, start: str
) -> None:
    """ik() (math, inline turn picks) against the batch (numpy, the plain pick) as reference:
    the same errors, the same solutions with the same turns, in the same order, on random
    reachable poses, at the wrist, elbow and shoulder singularities, and with a start whose
    wrist joints lie 180° from the pose's (the turn ties)."""
    m = get_model(name)
    q = data.draw(_joints(name))
    if special == "wrist":
        q[4] = -m.joint_offsets_deg[4]
    elif special == "elbow":
        q[2] = -m.joint_offsets_deg[2]
    elif special == "shoulder":
        moved = _on_shoulder_singularity(name, q)
        if moved is not None:
            q = moved
    ref: list[float] | None = None
    if start == "q":
        ref = list(q)
    elif start == "tie":
        ref = [q[0], q[1], q[2], q[3] - 180.0, q[4], q[5] + 180.0]
    elif start == "offset":
        ref = [v + data.draw(st.floats(-30.0, 30.0)) for v in q]
    T = m.flange2base(q)
    batch = m.ik_batch(T[None], near=ref)
    try:
        sols = m.ik(T, near=ref)
    except UnreachableError:
        assert not batch.reachable.any()
        return
    except JointLimitError:
        assert batch.reachable.any() and not batch.valid.any()
        return
    # the reference: valid branches in CONFIGS order, a duplicate at a singularity once,
    # sorted by distance to the start
    expected: list[tuple[np.ndarray, Config]] = []
    for k, cfg in enumerate(CONFIGS):
        joints = batch.joints_deg[0, k]
        if batch.valid[0, k] and not any(np.max(np.abs(joints - e)) <= 1e-9 for e, _ in expected):
            expected.append((joints, cfg))
    assert len(sols) == len(expected) == len({s.config for s in sols})
    got = {s.config: s for s in sols}
    for joints, cfg in expected:
        sol = got[cfg]
        if "wrist" in sol.singularities:
            # θ4 and θ6 alone are ill-conditioned there (libm's and numpy's atan2 part ways,
            # as before this path was shared): the same arm and θ4 + θ6 (θ5 ≈ 0); both
            # paths reach the pose only to ~1e-5 there (the closed form's conditioning)
            arm = [0, 1, 2, 4]
            np.testing.assert_allclose(sol.joints_deg[arm], joints[arm], rtol=0, atol=1e-9)
            turn = (sol.joints_deg[3] + sol.joints_deg[5] - joints[3] - joints[5]) % 360.0
            assert min(turn, 360.0 - turn) < 1e-2
        else:
            np.testing.assert_allclose(sol.joints_deg, joints, rtol=0, atol=1e-9)
    if ref is not None:
        dist = [float(np.sum((s.joints_deg - ref) ** 2)) for s in sols]
        assert all(a <= b + 1e-6 for a, b in pairwise(dist))
    else:
        order = [cfg for _, cfg in expected]
        assert [s.config for s in sols] == order
