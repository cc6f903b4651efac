"""Robot-side synchronisation core, scheduler, delay link and the real UDP endpoint."""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spec.datagrams import SensorData, Trigger, decode_datagram, encode_data
from spec.registry import SEAM_POINT_COLUMNS
from spec.server import parse_networks
from spec.wire import SensorStatus
from sync.network import DelayLink
from sync.udp import RobotSyncCore, SeamRows, SyncStateError, TriggerScheduler, UdpSyncEndpoint

PERIOD = 0.004


def test_rate_schedule_is_drift_free_and_counts() -> None:
    s = TriggerScheduler()
    s.start_rate(250.0, 1000, 0.0013)
    times = s.pop_due(10.0)
    assert len(times) == 1000
    assert times[-1] == pytest.approx(0.0013 + 999 / 250.0, abs=1e-12)
    assert not s.active and s.next_due() is None


def test_schedule_rejects_non_increasing_and_bad_rates() -> None:
    s = TriggerScheduler()
    with pytest.raises(SyncStateError):
        s.schedule([0.1, 0.1])
    with pytest.raises(SyncStateError):
        s.start_rate(0.0, 1, 0.0)
    with pytest.raises(SyncStateError):
        s.start_rate(1001.0, 1, 0.0)
    s.schedule([0.3, 0.1 + 0.25, 0.9])  # need not be periodic
    assert s.pop_due(0.5) == [0.3, 0.35]
    s.stop()
    assert s.pop_due(5.0) == []


def _data(
    index: int, t_trigger: float, y: float, status: SensorStatus = SensorStatus.FOUND
) -> bytes:
    seam = (0.0, y, 0.0, 0.0, 0.0, 0.0) if status is SensorStatus.FOUND else (math.nan,) * 6
    return encode_data(SensorData(index, status, seam, 0.9, t_trigger, 0.0, 0.0, 0.0))


def _run_chain(
    rng: np.random.Generator,
    link: DelayLink,
    delta_t: float = 4.9e-3,
    duration: float = 2.0,
) -> tuple[RobotSyncCore, dict[int, float]]:
    """Triggers every 4 ms (phase 1.3 ms) through ``link``; the 'sensor' answers with the
    joint-1 value at t_T + ΔT as its seam y, 5 ms later. Returns the core and the truth."""
    core = RobotSyncCore(delta_t_s=delta_t)
    core.start_rate(250.0, 0, 0.0013)
    truth: dict[int, float] = {}
    k = 0
    while k * PERIOD < duration:
        k += 1
        t = k * PERIOD
        q = np.full(6, 10.0 * math.sin(2 * math.pi * t))
        core.add_joints(np.array([t]), q[None, :])
        for index, t_send in core.due_triggers(t):
            raw = core.sent(index, t_send)
            truth[index] = 10.0 * math.sin(2 * math.pi * (t_send + delta_t))
            link.send(t_send, _data(index, t_send, truth[index]))
            assert isinstance(decode_datagram(raw), Trigger)
        for t_arr, raw in link.deliver(t):
            core.on_datagram(raw, t_arr)
        core.poll(t)
    return core, truth


def test_clean_link_matches_every_point_exactly() -> None:
    rng = np.random.default_rng(1)
    core, truth = _run_chain(rng, DelayLink(delay_s=5e-3))
    rows = core.points_since(-1)
    st_ = core.statistics()
    assert st_["matched"] == rows.shape[0] >= len(truth) - 3
    idx = rows[:, SEAM_POINT_COLUMNS.index("index")].astype(int)
    assert np.all(np.diff(idx) == 1)
    # t_S = t_T + ΔT [SY-5.2]
    t_t = rows[:, SEAM_POINT_COLUMNS.index("t_trigger")]
    t_s = rows[:, SEAM_POINT_COLUMNS.index("t_sync")]
    np.testing.assert_allclose(t_s - t_t, 4.9e-3, atol=1e-12)
    assert st_["lost"] == st_["duplicate"] == st_["reordered"] == st_["malformed"] == 0


def test_faults_never_corrupt_the_trajectory() -> None:
    """Injected loss, duplication and reordering: points stay in index order, each once,
    each with its own data; the counters add up."""
    rng = np.random.default_rng(7)
    link = DelayLink(
        delay_s=5e-3, rng=rng, loss=0.05, duplicate=0.05, reorder=0.1, reorder_delay_s=0.012
    )
    core, truth = _run_chain(rng, link)
    rows = core.points_since(-1)
    idx = rows[:, SEAM_POINT_COLUMNS.index("index")].astype(int)
    assert np.all(np.diff(idx) > 0)  # strictly increasing: ordered, no duplicates
    sy = rows[:, SEAM_POINT_COLUMNS.index("sy")]
    np.testing.assert_allclose(sy, [truth[i] for i in idx], atol=1e-9)
    s = core.statistics()
    # every injected copy is dropped as a duplicate (12 ms extra delay < 100 ms timeout)
    assert s["duplicate"] == link.counts["duplicated"]
    assert s["reordered"] > 0 and s["lost"] > 0
    assert s["matched"] + s["lost"] + s["expired"] + s["pending"] + s["not_found"] == s["sent"]


def _flange_up(q: np.ndarray) -> np.ndarray:
    """A stand-in DGM: the flange 1000 mm above the base, translated by joint 1 along x."""
    out = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    out[:, 0, 3] = q[:, 0]
    out[:, 2, 3] = 1000.0
    return out


def test_rows_keep_the_sensor_tool_in_force_at_their_release() -> None:
    """Points released before a SetSensorTool keep the old ^N_S T in their base columns,
    however late the rows are read; the ones released after it use the new tool."""
    core = RobotSyncCore(delta_t_s=0.0, flange2base=_flange_up, sensor2flange=np.eye(4))
    core.schedule([0.0013 + PERIOD * i for i in range(50)])
    bz = SEAM_POINT_COLUMNS.index("bz")
    for k in range(1, 60):
        t = k * PERIOD
        if k == 30:
            tool = np.eye(4)
            tool[2, 3] = 200.0
            core.sensor2flange = tool
        core.add_joints(np.array([t]), np.full((1, 6), 5.0))
        for index, t_send in core.due_triggers(t):
            core.sent(index, t_send)
            core.on_datagram(_data(index, t_send, 0.25), t)
        core.poll(t)
    rows = core.points_since(-1)
    assert rows.shape[0] >= 45
    t_sync = rows[:, SEAM_POINT_COLUMNS.index("t_sync")]
    # a point is released in the cycle whose joints first cover its t_sync (ΔT = 0)
    after = t_sync > 29 * PERIOD
    assert 0 < np.count_nonzero(after) < len(rows)
    # seam at (0, 0.25, 0) in S: base z = 1000, + 200 once the new tool is in force
    np.testing.assert_allclose(rows[~after, bz], 1000.0, atol=1e-9)
    np.testing.assert_allclose(rows[after, bz], 1200.0, atol=1e-9)
    np.testing.assert_allclose(rows[:, SEAM_POINT_COLUMNS.index("by")], 0.25, atol=1e-9)


def test_memory_stays_bounded_over_many_triggers() -> None:
    """Every structure the core keeps is capped: 10,001 triggers with ``max_points`` 1000
    leave at most 1000 rows, no trajectory in the matcher and a trigger log within its
    history (the matcher used to keep every released point for ever)."""
    core = RobotSyncCore(max_points=1000, joint_capacity=100)
    core.start_rate(250.0, 10_001, 0.0013)
    t = 0.0
    core.add_joint(t, np.zeros(6))
    while core.next_due() is not None or core.statistics()["pending"]:
        t += PERIOD
        core.add_joint(t, np.zeros(6))
        for index, t_send in core.due_triggers(t):
            core.sent(index, t_send)
            core.on_datagram(_data(index, t_send, 0.0), t_send + 0.005)
        core.poll(t)
        if round(t / PERIOD) % 2000 == 0:
            kept = core.retained()
            assert kept["trajectory"] == 0 and kept["rows"] <= 1000
            assert kept["trigger_log"] <= 8192 + core.statistics()["pending"]
            assert kept["joints"] <= 100
    assert core.statistics()["matched"] == 10_001
    assert core.points_since(-1).shape[0] == 1000
    kept = core.retained()
    assert kept["rows"] == 1000 and kept["pending_points"] == 0 and kept["trigger_log"] == 8192


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.integers(0, 1500), min_size=1, max_size=12),
    st.integers(0, 3000),
    st.lists(st.tuples(st.integers(-2, 8000), st.integers(0, 2500)), min_size=1, max_size=5),
)
def test_seam_rows_keep_the_newest_and_read_like_a_list(
    batches: list[int], capacity: int, reads: list[tuple[int, int]]
) -> None:
    """Blocks of rows in, reads by index: the same rows as a plain list of every row with the
    oldest dropped beyond capacity (the store it replaces)."""
    store = SeamRows(capacity)
    plain: list[list[float]] = []
    index = 0
    for size in batches:
        rows = np.zeros((size, len(SEAM_POINT_COLUMNS)))
        rows[:, 0] = np.arange(index, index + size) * 2  # gaps, as lost triggers leave
        rows[:, 1] = np.arange(size) * 0.5
        index += size
        store.append(rows)
        plain.extend(rows.tolist())
        del plain[: max(len(plain) - capacity, 0)]
        assert len(store) == len(plain)
        for since, limit in reads:
            want = [r for r in plain if r[0] > since][:limit]
            got = store.since(since, limit)
            assert got.shape == (len(want), len(SEAM_POINT_COLUMNS))
            assert got.tolist() == want


def test_malformed_datagrams_are_counted_and_dropped() -> None:
    core = RobotSyncCore()
    assert core.on_datagram(b"garbage", 0.0) is None
    good = bytearray(_data(0, 0.0, 1.0))
    good[-1] ^= 0xFF  # CRC
    assert core.on_datagram(bytes(good), 0.0) is None
    assert core.statistics()["malformed"] == 2
    assert core.statistics()["unknown"] == 0


def test_data_newer_than_joints_waits_and_old_data_expires() -> None:
    core = RobotSyncCore(delta_t_s=0.01, joint_capacity=10)
    core.schedule([0.001, 0.2])
    for k in range(1, 4):  # joints at 4, 8, 12 ms
        core.add_joints([k * PERIOD], np.full((1, 6), float(k)))
    for index, t in core.due_triggers(0.25):
        core.sent(index, t)
    core.on_datagram(_data(0, 0.001, 0.0), 0.012)
    (p,) = core.poll(0.012)  # t_S = 11 ms lies inside the buffer: eq. 5
    np.testing.assert_allclose(p.joints, 2.75)
    core.on_datagram(_data(1, 0.2, 0.0), 0.25)
    assert core.poll(0.25) == []  # t_S = 210 ms, joints end at 12 ms: wait, no extrapolation
    assert core.statistics()["pending"] == 1
    for k in range(4, 80):  # the 10-sample buffer now starts at 280 ms
        core.add_joints([k * PERIOD], np.full((1, 6), float(k)))
    core.poll(0.33)
    s = core.statistics()
    assert s["expired"] == 1 and s["matched"] == 1  # t_S left the buffer: dropped [SY-3.5]


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=40, unique=True))
def test_explicit_times_are_sent_exactly_once_in_order(times: list[float]) -> None:
    s = TriggerScheduler()
    ordered = sorted(times)
    s.schedule(ordered)
    out: list[float] = []
    for now in np.linspace(0, 1.0, 17):
        out += s.pop_due(float(now))
    assert out == ordered


def test_udp_endpoint_over_loopback() -> None:
    """The real endpoint: triggers reach a socket, answers come back and are matched."""
    core = RobotSyncCore(delta_t_s=0.0)
    t0 = time.monotonic()

    def clock() -> float:
        return time.monotonic() - t0

    def joints_since(t: float) -> tuple[np.ndarray, np.ndarray]:
        now = clock()
        ks = np.arange(math.floor(max(t, 0) / PERIOD) + 1, math.floor(now / PERIOD) + 1)
        return ks * PERIOD, np.zeros((ks.size, 6))

    sensor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor.bind(("127.0.0.1", 0))
    sensor.settimeout(2.0)
    ep = UdpSyncEndpoint(core, clock=clock, joints_since=joints_since, host="127.0.0.1")
    ep.set_target(*sensor.getsockname()[:2])
    ep.start()
    try:
        core.start_rate(100.0, 10, clock() + 0.01)
        ep.wake()
        for _ in range(10):
            raw, src = sensor.recvfrom(2048)
            trig = decode_datagram(raw)
            assert isinstance(trig, Trigger)
            sensor.sendto(_data(trig.index, trig.t_trigger, 0.5), src)
            sensor.sendto(b"not a datagram", src)
        deadline = time.monotonic() + 3.0
        while core.statistics()["matched"] < 10 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        ep.stop()
        sensor.close()
    s = core.statistics()
    assert s["sent"] == 10 and s["matched"] == 10 and s["malformed"] == 10


def test_add_joint_matches_add_joints() -> None:
    """One sample at a time (the cell's per-cycle path) stores what add_joints stores and
    skips a sample that is not newer, as add_joints does."""
    rng = np.random.default_rng(5)
    ts = [0.0, 0.004, 0.004, 0.008, 0.006, 0.012]
    qs = rng.normal(size=(len(ts), 6))
    one, batch = RobotSyncCore(), RobotSyncCore()
    for t, q in zip(ts, qs, strict=True):
        one.add_joint(t, q)
        batch.add_joints(np.array([t]), q[None, :])
    t1, q1 = one.joints.samples()
    t2, q2 = batch.joints.samples()
    assert t1.tolist() == [0.0, 0.004, 0.008, 0.012]
    assert np.array_equal(t1, t2) and np.array_equal(q1, q2)


def _endpoint_with_sensor(**kwargs: object) -> tuple[UdpSyncEndpoint, socket.socket]:
    core = RobotSyncCore(delta_t_s=0.0)
    ep = UdpSyncEndpoint(
        core,
        clock=time.monotonic,
        joints_since=lambda t: (np.zeros(0), np.zeros((0, 6))),
        host="127.0.0.1",
        **kwargs,  # type: ignore[arg-type]
    )
    sensor = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sensor.bind(("127.0.0.1", 0))
    ep.set_target(*sensor.getsockname()[:2])
    return ep.start(), sensor


def _wait_for(predicate: Callable[[], bool]) -> None:
    deadline = time.monotonic() + 3.0
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.01)


def test_udp_endpoint_accepts_data_only_from_the_sensor_endpoint() -> None:
    """[SY-3.7] a datagram from another port than the sensor's is dropped unread and counted
    as foreign; the sensor's own gets to the matcher."""
    ep, sensor = _endpoint_with_sensor()
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    try:
        other.sendto(_data(7, 0.0, 0.5), ep.address)
        _wait_for(lambda: ep.dropped["foreign"] == 1)
        sensor.sendto(_data(7, 0.0, 0.5), ep.address)
        _wait_for(lambda: ep.core.statistics()["received"] == 1)
    finally:
        ep.stop()
        sensor.close()
        other.close()
    assert ep.dropped == {"foreign": 1}
    assert ep.core.statistics()["received"] == 1  # only the sensor's (an unknown index)


def test_udp_endpoint_takes_any_source_when_told() -> None:
    ep, sensor = _endpoint_with_sensor(sensor_only=False)
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    try:
        other.sendto(_data(7, 0.0, 0.5), ep.address)
        _wait_for(lambda: ep.core.statistics()["received"] == 1)
    finally:
        ep.stop()
        sensor.close()
        other.close()
    assert ep.core.statistics()["received"] == 1 and not ep.dropped


def test_udp_endpoint_honours_the_allow_list() -> None:
    """[RS-7.7] a source outside --allow is dropped and counted, even the sensor's port."""
    ep, sensor = _endpoint_with_sensor(allow=parse_networks(["10.0.0.0/8"]))
    try:
        sensor.sendto(_data(7, 0.0, 0.5), ep.address)
        _wait_for(lambda: ep.dropped["refused_address"] == 1)
    finally:
        ep.stop()
        sensor.close()
    assert ep.dropped == {"refused_address": 1}
    assert ep.core.statistics()["received"] == 0
