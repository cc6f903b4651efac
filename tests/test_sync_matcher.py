"""Tests for sync.matcher: trigger/data bookkeeping, fault counters and in-order release."""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spec.datagrams import INDEX_MODULUS, SensorData
from spec.wire import SensorStatus
from sync.joint_buffer import JointBuffer
from sync.matcher import DataOutcome, MatcherError, SeamPoint, SyncMatcher

DT = 0.0049  # ΔT, s
TIMEOUT = 0.05  # s
A = np.array([10.0, -20.0, 30.0, 5.0, 45.0, -60.0])  # joint offsets, degrees
B = np.array([12.0, 3.0, -7.0, 40.0, -25.0, 90.0])  # joint rates, degrees/s


def q_true(t: np.ndarray | float) -> np.ndarray:
    """Joints linear in time, so eq. 5 reproduces them exactly."""
    return A + B * np.asarray(t, dtype=np.float64)[..., None]


def _trans(x: float, y: float, z: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def toy_flange2base(q: np.ndarray) -> np.ndarray:
    """Stand-in DGM: flange at (q1, q2, q3) mm, no rotation."""
    out = np.tile(np.eye(4), (q.shape[0], 1, 1))
    out[:, :3, 3] = q[:, :3]
    return out


S2F = _trans(0.0, 0.0, 100.0)


def full_buffer(t_end: float = 2.0) -> JointBuffer:
    buf = JointBuffer(capacity=2500)
    t = np.arange(0, int(t_end / 0.004) + 1) * 0.004
    buf.extend(t, q_true(t))
    return buf


def trig_time(i: int) -> float:
    return 0.0013 + 0.004 * i  # trigger phase unrelated to the robot's 4 ms samples


FOUND, NOT_FOUND = SensorStatus.FOUND, SensorStatus.NOT_FOUND


def sensor_data(
    index: int, seam: Sequence[float], status: SensorStatus = FOUND, quality: float = 0.9
) -> SensorData:
    """A data datagram's fields: ``seam`` a VAL3 location (mm, deg), sensor times 0."""
    loc = cast(tuple[float, float, float, float, float, float], tuple(seam))
    return SensorData(index, status, loc, quality, 0.0, 0.0, 0.0, 0.0)


def data(i: int, status: SensorStatus = FOUND) -> SensorData:
    # seam offset depends on the index so a mix-up between indices shows
    return sensor_data(i % INDEX_MODULUS, (0.01 * i, 1.0, 200.0, 0.0, 0.0, 0.0), status)


def make_matcher(
    timeout_s: float = TIMEOUT, history: int = 4096, *, keep_trajectory: bool = False
) -> SyncMatcher:
    return SyncMatcher(
        delta_t_s=DT,
        timeout_s=timeout_s,
        flange2base=toy_flange2base,
        sensor2flange=S2F,
        history=history,
        keep_trajectory=keep_trajectory,
    )


def check_points(points: list[SeamPoint], indices: list[int]) -> None:
    assert [p.index for p in points] == indices
    for p in points:
        ts = trig_time(p.index) + DT
        assert p.t_sensor == pytest.approx(ts, abs=1e-12)
        np.testing.assert_allclose(p.joints, q_true(ts), atol=1e-9)
        expected = q_true(ts)[:3] + np.array([0.01 * p.index, 1.0, 300.0])
        assert p.seam2base is not None
        np.testing.assert_allclose(p.seam2base[:3, 3], expected, atol=1e-9)


def test_in_order_happy_path() -> None:
    m, buf = make_matcher(keep_trajectory=True), full_buffer()
    for i in range(50):
        m.on_trigger(i, trig_time(i))
        assert m.on_data(data(i), trig_time(i) + 0.012) is DataOutcome.ACCEPTED
    out = m.poll(1.0, buf)
    check_points(out, list(range(50)))
    assert m.trajectory() == out
    c = m.counters
    assert (c.triggers, c.data, c.accepted, c.points, c.reordered) == (50, 50, 50, 50, 0)
    idx, _, base = m.trajectory_arrays()
    assert idx.tolist() == list(range(50)) and base.shape == (50, 4, 4)


def test_memory_is_bounded_by_history_without_a_kept_trajectory() -> None:
    """A long-running matcher (the default) holds at most ``history`` resolved triggers and
    no released points, however many indices pass through it."""
    m, buf = make_matcher(history=64), full_buffer(t_end=5.0)
    for i in range(1000):
        m.on_trigger(i, trig_time(i))
        m.on_data(data(i), trig_time(i) + 0.012)
        if i % 10 == 9:
            assert len(m.poll(trig_time(i) + 0.012, buf)) > 0
            assert m.retained()["trigger_log"] <= 64 + m.pending
    assert m.counters.points > 900
    assert m.retained()["trajectory"] == 0 and m.trajectory() == []


def test_waits_when_data_is_newer_than_the_joints() -> None:
    m = make_matcher()
    buf = JointBuffer()
    buf.extend([0.0, 0.004], q_true(np.array([0.0, 0.004])))
    m.on_trigger(0, 0.0013)  # t_S = 6.2 ms, after the newest joint sample (4 ms)
    m.on_data(data(0), 0.010)
    assert m.poll(0.010, buf) == []
    assert m.pending == 1
    buf.append(0.008, q_true(0.008))
    out = m.poll(0.012, buf)
    assert [p.index for p in out] == [0]
    np.testing.assert_allclose(out[0].joints, q_true(0.0013 + DT), atol=1e-9)


def test_expired_when_joints_have_left_the_buffer() -> None:
    m = make_matcher()
    buf = JointBuffer(capacity=3)
    for k in range(10):
        buf.append(k * 0.004, q_true(k * 0.004))  # keeps 28..36 ms
    m.on_trigger(0, 0.0013)
    m.on_data(data(0), 0.02)
    m.on_trigger(1, 0.026)  # t_S = 30.9 ms: inside
    m.on_data(data(1), 0.03)
    out = m.poll(0.035, buf)
    assert [p.index for p in out] == [1]
    assert m.counters.expired == 1 and m.counters.points == 1


def test_not_found_is_a_counted_gap() -> None:
    m, buf = make_matcher(), full_buffer()
    for i in range(5):
        m.on_trigger(i, trig_time(i))
    for i in range(5):
        m.on_data(data(i, status=NOT_FOUND if i == 2 else FOUND), 0.03)
    out = m.poll(0.03, buf)
    check_points(out, [0, 1, 3, 4])
    assert m.counters.not_found == 1 and m.counters.points == 4
    # a second datagram for the not-found index is a duplicate
    assert m.on_data(data(2), 0.03) is DataOutcome.DUPLICATE


def test_release_waits_for_a_missing_index_until_it_is_lost() -> None:
    m, buf = make_matcher(), full_buffer()
    for i in range(3):
        m.on_trigger(i, trig_time(i))
    m.on_data(data(0), 0.02)
    m.on_data(data(2), 0.02)
    assert [p.index for p in m.poll(0.02, buf)] == [0]  # 2 waits for 1
    assert [p.index for p in m.poll(trig_time(1) + TIMEOUT + 1e-6, buf)] == [2]
    assert m.counters.lost == 1
    assert m.on_data(data(1), 1.0) is DataOutcome.LATE
    assert m.counters.late == 1


def test_data_exactly_at_the_timeout_is_accepted() -> None:
    m = make_matcher(timeout_s=0.0625)  # binary fractions: now - t_T is exactly the timeout
    m.on_trigger(0, 0.5)
    m.on_trigger(1, 0.5)
    assert m.on_data(data(0), 0.5625) is DataOutcome.ACCEPTED
    assert m.on_data(data(1), 0.5625 + 1e-9) is DataOutcome.LATE


def test_unknown_stale_invalid_and_caller_errors() -> None:
    m, buf = make_matcher(history=8), full_buffer()
    assert m.on_data(data(0), 0.0) is DataOutcome.UNKNOWN  # nothing sent yet
    for i in range(100, 120):
        m.on_trigger(i, trig_time(i))
        m.on_data(data(i), trig_time(i) + 0.01)
        m.poll(trig_time(i) + 0.01, buf)
    assert m.on_data(data(121), 1.0) is DataOutcome.UNKNOWN  # not sent yet
    assert m.on_data(data(99), 1.0) is DataOutcome.UNKNOWN  # before the first trigger
    assert m.on_data(data(101), 1.0) is DataOutcome.STALE  # forgotten (history 8)
    assert m.on_data(data(118), 1.0) is DataOutcome.DUPLICATE
    m.on_trigger(120, 0.6)
    bad = sensor_data(120, [0.0, 0.0, float("nan"), 0.0, 0.0, 0.0])
    assert m.on_data(bad, 0.6) is DataOutcome.INVALID
    c = m.counters
    assert (c.unknown, c.stale, c.duplicate, c.invalid) == (3, 1, 1, 1)
    assert c.data == c.accepted + c.duplicate + c.late + c.unknown + c.stale + c.invalid
    with pytest.raises(MatcherError):
        m.on_trigger(120, 0.7)  # not after the previous index
    with pytest.raises(MatcherError):
        m.on_trigger(121, 0.1)  # time goes backwards
    with pytest.raises(MatcherError):
        m.on_data(sensor_data(121, [0.0] * 5), 0.7)
    with pytest.raises(MatcherError):
        SyncMatcher(delta_t_s=DT, flange2base=toy_flange2base)


def test_location_tuple_of_floats_as_any_location() -> None:
    """A decoded datagram's location (a tuple of 6 floats) gives the same point as the same
    location in numpy floats; a non-finite one is INVALID, as in any other form."""
    from kinematics.transforms import location_to_transform

    loc = (1.5, -2.25, 201.0, 3.0, -4.5, 179.0)
    points = []
    for seam in (loc, tuple(np.array(loc))):
        m, buf = make_matcher(), full_buffer()
        m.on_trigger(7, trig_time(7))
        assert m.on_data(sensor_data(7, seam), trig_time(7) + 0.01) is (DataOutcome.ACCEPTED)
        (p,) = m.poll(trig_time(7) + 0.01, buf)
        points.append(p)
    for p in points:
        assert p.seam2base is not None and points[0].seam2base is not None
        assert np.array_equal(p.seam2sensor, location_to_transform(np.array(loc)))
        assert np.array_equal(p.seam2base, points[0].seam2base)
    for bad in ((0.0, 0.0, float("nan"), 0.0, 0.0, 0.0), (float("inf"), 0.0, 0.0, 0.0, 0.0, 0.0)):
        m = make_matcher()
        m.on_trigger(8, trig_time(8))
        assert m.on_data(sensor_data(8, bad), trig_time(8)) is DataOutcome.INVALID
        assert m.counters.invalid == 1 and m.pending == 1  # the index may still be lost
        # a NOT_FOUND datagram's location is ignored, finite or not
        assert m.on_data(sensor_data(8, bad, NOT_FOUND), trig_time(8)) is DataOutcome.ACCEPTED


def test_index_wraps_around_u32() -> None:
    m, buf = make_matcher(), full_buffer()
    first = INDEX_MODULUS - 5
    indices = [(first + n) % INDEX_MODULUS for n in range(10)]
    for n, i in enumerate(indices):
        m.on_trigger(i, 0.0013 + 0.004 * n)
    for i in reversed(indices):
        assert m.on_data(sensor_data(i, [0.0] * 6), 0.05) is DataOutcome.ACCEPTED
    out = m.poll(0.05, buf)
    assert [p.index for p in out] == indices
    assert m.counters.reordered == 9


def test_val3_location_is_rx_ry_rz() -> None:
    m = SyncMatcher(delta_t_s=0.0, flange2base=toy_flange2base, sensor2flange=np.eye(4))
    buf = full_buffer(0.1)
    m.on_trigger(0, 0.0)
    # R = Rx(90)·Ry(0)·Rz(90) maps x to z (Rz(90)·Rx(90) would map x to y).
    m.on_data(sensor_data(0, [1.0, 2.0, 3.0, 90.0, 0.0, 90.0]), 0.01)
    (p,) = m.poll(0.01, buf)
    np.testing.assert_allclose(p.seam2sensor[:3, 0], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(p.seam2sensor[:3, 3], [1.0, 2.0, 3.0])


def _run_scenario(seed: int, n: int = 300) -> tuple[SyncMatcher, dict[str, object]]:
    """Triggers every 4 ms; data after 6-30 ms, with injected faults. Returns expectations
    computed from the injection plan, not from the matcher's rules."""
    rng = np.random.default_rng(seed)
    fate = rng.choice(
        ["ok", "lost", "late", "dup", "notfound"], size=n, p=[0.75, 0.08, 0.05, 0.07, 0.05]
    )
    events: list[tuple[float, int, str, int]] = []  # (time, order, kind, index)
    for i in range(n):
        t = trig_time(i)
        events.append((t, 0, "trigger", i))
        if fate[i] == "lost":
            continue
        lat = rng.uniform(0.006, 0.030) if fate[i] != "late" else TIMEOUT + rng.uniform(1e-3, 0.1)
        events.append((t + lat, 1, "data", i))
        if fate[i] == "dup":
            events.append((t + lat + rng.uniform(0.0, 0.02), 1, "data", i))
    n_unknown = 7
    for u in range(n_unknown):
        events.append((trig_time(50 * u) + 0.001, 1, "data", 10 * n + u))
    events.sort()
    m, buf = make_matcher(), full_buffer(trig_time(n) + 0.2)
    released: list[SeamPoint] = []
    accepted_order: list[int] = []
    for t, _, kind, i in events:
        if kind == "trigger":
            m.on_trigger(i, t)
        else:
            status = NOT_FOUND if fate[i % n] == "notfound" and i < n else FOUND
            if m.on_data(data(i, status), t) is DataOutcome.ACCEPTED:
                accepted_order.append(i)
        released += m.poll(t, buf)
    released += m.poll(trig_time(n) + 1.0, buf)
    reordered = sum(1 for k, i in enumerate(accepted_order) if i < max(accepted_order[:k] or [-1]))
    expect = {
        "indices": [i for i in range(n) if fate[i] in ("ok", "dup")],
        "lost": int(np.sum((fate == "lost") | (fate == "late"))),
        "late": int(np.sum(fate == "late")),
        "duplicate": int(np.sum(fate == "dup")),
        "not_found": int(np.sum(fate == "notfound")),
        "unknown": n_unknown,
        "reordered": reordered,
        "released": released,
    }
    return m, expect


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_injected_faults_never_corrupt_the_trajectory(seed: int) -> None:
    m, e = _run_scenario(seed)
    check_points(e["released"], e["indices"])  # type: ignore[arg-type]
    c = m.counters
    assert c.lost == e["lost"] and c.late == e["late"]
    assert c.duplicate == e["duplicate"] and c.unknown == e["unknown"]
    assert c.not_found == e["not_found"] and c.reordered == e["reordered"]
    assert c.reordered > 0 and c.expired == 0 and c.stale == 0
    assert c.points == len(e["indices"])  # type: ignore[arg-type]
    assert c.triggers == c.points + c.not_found + c.lost + c.expired + m.pending
    assert m.pending == 0


@settings(max_examples=40, deadline=None, derandomize=True)
@given(perm=st.permutations(list(range(40))), drop=st.sets(st.integers(0, 39), max_size=8))
def test_arrival_order_does_not_change_the_trajectory(perm: list[int], drop: set[int]) -> None:
    buf = full_buffer(0.5)
    outputs: list[list[SeamPoint]] = []
    for order in (sorted(perm), perm):
        m = make_matcher(timeout_s=1.0)
        for i in range(40):
            m.on_trigger(i, trig_time(i))
        got: list[SeamPoint] = []
        for i in order:
            if i not in drop:
                m.on_data(data(i), trig_time(39) + 0.001)
                got += m.poll(trig_time(39) + 0.001, buf)
        got += m.poll(10.0, buf)
        assert m.counters.lost == len(drop)
        outputs.append(got)
    expected = [i for i in range(40) if i not in drop]
    check_points(outputs[0], expected)
    check_points(outputs[1], expected)
    for a, b in zip(*outputs, strict=True):
        assert a.seam2base is not None and b.seam2base is not None
        np.testing.assert_array_equal(a.seam2base, b.seam2base)


def test_location_convention_matches_the_kinematics_package() -> None:
    transforms = pytest.importorskip("kinematics.transforms")
    m = SyncMatcher(delta_t_s=0.0)
    buf = full_buffer(0.1)
    rng = np.random.default_rng(4)
    locs = np.column_stack([rng.normal(0, 50, (5, 3)), rng.uniform(-180, 180, (5, 3))])
    for i, loc in enumerate(locs):
        m.on_trigger(i, 0.004 * i)
        m.on_data(sensor_data(i, loc.tolist()), 0.03)
    for p, loc in zip(m.poll(0.03, buf), locs, strict=True):
        np.testing.assert_allclose(p.seam2sensor, transforms.location_to_transform(loc), atol=1e-12)


@pytest.mark.parametrize(("delta_t_s", "max_um"), [(5.15e-3, 50.0), (0.0, None)])
def test_straight_seam_seen_from_a_sine_motion(delta_t_s: float, max_um: float | None) -> None:
    """Section VI through the matcher: the flange moves y = 2 sin(2π·1.5 t) mm across a
    straight seam at y = 0; the sensor sees the seam at -y(exposure). With the right ΔT the
    seam comes out straight in the base frame; without it, it comes out as a sine."""
    rng = np.random.default_rng(8)
    w = 2 * np.pi * 1.5

    def flange_y(t: np.ndarray | float) -> np.ndarray:
        return 2.0 * np.sin(w * np.asarray(t))

    buf = JointBuffer()
    tk = np.arange(0, 2501) * 0.004
    joints = np.zeros((tk.size, 6))
    joints[:, 1] = flange_y(tk)
    joints[:, 2] = 500.0
    buf.extend(tk[:2500], joints[:2500])
    m = SyncMatcher(delta_t_s=delta_t_s, flange2base=toy_flange2base, sensor2flange=np.eye(4))
    out: list[SeamPoint] = []
    for i in range(2400):
        t_t = 0.0021 + 0.004 * i
        t_x = t_t + 4.9e-3 + rng.uniform(0, 0.5e-3) + rng.normal(0, 0.1e-3)
        m.on_trigger(i, t_t)
        seen = (0.0, -float(flange_y(t_x)) + rng.normal(0, 0.01), -500.0, 0.0, 0.0, 0.0)
        m.on_data(sensor_data(i, seen), t_t + 0.02)
        out += m.poll(t_t + 0.02, buf)
    y_um = np.array([p.seam2base[1, 3] for p in out if p.seam2base is not None]) * 1000
    assert len(y_um) >= 2390
    if max_um is not None:
        assert np.max(np.abs(y_um)) <= max_um and np.sqrt(np.mean(y_um**2)) <= 15.0
    else:
        # a sine of amplitude A·ω·ΔT ≈ 97 µm (rms 69 µm) plus the noise
        assert np.max(np.abs(y_um)) > 90.0 and np.sqrt(np.mean(y_um**2)) > 55.0
