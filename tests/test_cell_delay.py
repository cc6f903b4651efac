"""The ΔT experiment on the full emulated chain: robot emulator -> joint log; camera emulator
renders and detects -> UDP data; everything through RobotSocket/SensorSocket."""

from __future__ import annotations

import sys
from dataclasses import replace

import numpy as np
import pytest

from cell.cell import CellTiming, EmulatedCell
from cell.rtcell import CellProcess
from sensorsocket.camera import StripeRenderer
from sensorsocket.scene import node_poses_of
from spec.client import FramedClient
from spec.errors import ErrorCode, RemoteError
from spec.params import FloatArray, Location, Matrix
from spec.registry import SEAM_POINT_COLUMNS, CommandId
from sync.experiment import ExperimentError, ExperimentSettings, run_delay_experiment
from sync.interpolate import lerp_inside
from sync.network import DelayLink

PAPER = CellTiming()  # 4 ms samples, 0.6 ms jitter, 10 µm noise


@pytest.mark.slow
def test_paper_timing_full_chain() -> None:
    with EmulatedCell(clock="sim", seed=1, timing=PAPER) as cell:
        r = run_delay_experiment(
            cell.robot_address, cell.sensor_address, ExperimentSettings(duration_s=10.0)
        )
        truth = cell.true_delta_t_s()
    assert truth == pytest.approx(4.9e-3, abs=1e-9)
    assert abs(r.estimate.delta_t_s - truth) <= 0.06e-3
    syn, uns = r.residual.synced, r.residual.unsynced
    assert syn.max_um <= 50.0 and syn.rms_um <= 15.0
    assert uns.max_um >= 3 * syn.max_um and uns.rms_um >= 3 * syn.rms_um
    assert syn.sine_amplitude_um < 2.0  # no sine left at 1.5 Hz
    assert r.data.statistics["lost"] == 0 and r.data.statistics["matched"] > 2400


@pytest.mark.slow
def test_encoder_latency_moves_the_estimate_by_the_same_amount() -> None:
    s = ExperimentSettings(duration_s=3.0)
    est = []
    for latency in (2.8e-3, 3.8e-3):
        timing = replace(PAPER, encoder_latency_s=latency)
        with EmulatedCell(clock="sim", seed=3, timing=timing) as cell:
            est.append(run_delay_experiment(cell.robot_address, cell.sensor_address, s))
    shift = est[1].estimate.delta_t_s - est[0].estimate.delta_t_s
    assert shift == pytest.approx(1.0e-3, abs=0.02e-3)


@pytest.mark.slow
def test_injected_faults_do_not_corrupt_the_seam_trajectory() -> None:
    cell = EmulatedCell(clock="sim", seed=5, timing=PAPER)
    rng = np.random.default_rng(11)
    cell.uplink = DelayLink(delay_s=1e-4, jitter_s=1e-4, rng=rng, loss=0.03)
    cell.downlink = DelayLink(rng=rng, duplicate=0.05, reorder=0.05, reorder_delay_s=0.02)
    with cell:
        r = run_delay_experiment(
            cell.robot_address, cell.sensor_address, ExperimentSettings(duration_s=3.0)
        )
        rows = cell.core.points_since(-1)
    st = r.data.statistics
    assert st["lost"] > 0 and st["duplicate"] > 0 and st["reordered"] > 0
    idx = rows[:, SEAM_POINT_COLUMNS.index("index")]
    assert np.all(np.diff(idx) > 0)
    assert abs(r.estimate.delta_t_s - 4.9e-3) < 0.1e-3
    assert r.residual.synced.rms_um <= 15.0


@pytest.mark.slow
@pytest.mark.realtime
def test_real_time_over_sockets() -> None:
    """Live, on the wall clock. What made this fail on a busy machine (a trigger's arrival
    stamped when the listener got the CPU, frames rendered from poses extrapolated past a
    late robot tick) is gone: arrivals are kernel stamps, the camera renders setpoints the
    robot computed for the exposure's own times. The truth is the sensor's own records, so
    load that delays a trigger shifts the truth with the estimate. The cell runs as
    ``cell serve`` runs it: its real-time part in a child process, out of reach of this
    process's threads (docs/REALTIME.md)."""
    with CellProcess(seed=2, timing=PAPER) as cell:
        first = cell.next_index()
        r = run_delay_experiment(
            cell.robot_address,
            cell.sensor_address,
            ExperimentSettings(duration_s=3.0, trigger_rate_hz=100.0),
        )
        truth = cell.measured_delta_t(first)
        stamped = cell.child.query("kernel_timestamps")
    st = r.data.statistics
    assert st["sent"] >= 300 and st["matched"] >= 0.9 * st["sent"]  # this run's own counts
    assert stamped or not sys.platform.startswith("linux")
    assert abs(r.estimate.delta_t_s - truth) <= 0.2e-3


def test_sync_commands_over_the_protocol() -> None:
    with EmulatedCell(clock="sim", seed=0) as cell, FramedClient(*cell.robot_address) as rc:
        rc.hello()
        rc.take_control("")
        with pytest.raises(RemoteError) as e:
            rc.call(CommandId.START_TRIGGERS, 100.0, 0)
        assert e.value.code == ErrorCode.BAD_STATE  # [SY-5.4]
        rc.call(CommandId.SET_SENSOR_ENDPOINT, *cell.udp_address)
        for bad in (0.0, 1001.0):
            with pytest.raises(RemoteError) as e:
                rc.call(CommandId.START_TRIGGERS, bad, 0)
            assert e.value.code == ErrorCode.OUT_OF_RANGE  # [SY-5.3]
        with pytest.raises(RemoteError) as e:
            rc.call(CommandId.SCHEDULE_TRIGGERS, FloatArray([0.2, 0.1]))
        assert e.value.code == ErrorCode.OUT_OF_RANGE
        rc.call(CommandId.SET_SYNC_DELAY, 0.0049)
        tool = Location(40.0, 0.0, 200.0, 0.0, 0.0, 0.0)
        rc.call(CommandId.SET_SENSOR_TOOL, tool)
        host, port, dt, s2f, triggering, _rate = rc.call(CommandId.GET_SYNC_CONFIG)
        assert (host, port) == cell.udp_address and dt == pytest.approx(0.0049)
        assert isinstance(s2f, Location) and s2f.as_tuple() == pytest.approx(tool.as_tuple())
        assert triggering is False
        # explicit, non-periodic trigger times; the arm stands still over the seam
        (first,) = rc.call(CommandId.SCHEDULE_TRIGGERS, FloatArray([0.0113, 0.0171, 0.05]))
        # the arm stands still, so WaitEndMove returns at once: let simulated time pass
        cell.advance(0.1)
        (pts,) = rc.call(CommandId.GET_SEAM_POINTS, -1)
        assert isinstance(pts, Matrix) and pts.rows == 3 and pts.cols == 17
        rows = np.array(pts.values).reshape(3, 17)
        np.testing.assert_allclose(rows[:, 1], [0.0113, 0.0171, 0.05])
        np.testing.assert_allclose(rows[:, 2] - rows[:, 1], 0.0049)
        # the seam in the base frame is where the cell put it: under the ready sensor pose
        seam_b = cell.ready_sensor2base()[:3, 3]
        np.testing.assert_allclose(rows[:, 11:14], np.tile(seam_b, (3, 1)), atol=0.05)
        stats = rc.call(CommandId.GET_SYNC_STATISTICS)
        assert stats[0] == 3 and stats[2] == 3 and first == 0


def test_tool_move_trajectory_tracks_and_refuses_bad_paths() -> None:
    with EmulatedCell(clock="sim", seed=0) as cell, FramedClient(*cell.robot_address) as rc:
        rc.hello()
        rc.take_control("")
        rc.call(CommandId.ENABLE_POWER)
        tool = Location(*cell.sensor_tool)
        world = Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        (loc0,) = rc.call(CommandId.HERE, tool, world)
        t = np.arange(0, 251) * 0.004
        y = 1.0 - np.cos(2 * np.pi * t)  # starts and ends at rest
        locs = np.zeros((t.size, 6))
        locs[:, 1] = y
        with pytest.raises(RemoteError) as e:  # times must start at 0 [RS-5.23]
            rc.call(
                CommandId.TOOL_MOVE_TRAJECTORY,
                FloatArray((t + 0.1).tolist()),
                Matrix(t.size, 6, locs.ravel().tolist()),
                tool,
                loc0,
            )
        assert e.value.code == ErrorCode.OUT_OF_RANGE
        with pytest.raises(RemoteError) as e:  # a 20 mm jump at once is too fast
            jump = locs.copy()
            jump[1:, 0] += 20.0
            rc.call(
                CommandId.TOOL_MOVE_TRAJECTORY,
                FloatArray(t.tolist()),
                Matrix(t.size, 6, jump.ravel().tolist()),
                tool,
                loc0,
            )
        assert e.value.code == ErrorCode.OUT_OF_RANGE
        t_start = cell.robot.time()
        rc.call(
            CommandId.TOOL_MOVE_TRAJECTORY,
            FloatArray(t.tolist()),
            Matrix(t.size, 6, locs.ravel().tolist()),
            tool,
            loc0,
        )
        rc.call(CommandId.WAIT_END_MOVE, 5.0)
        # setpoints vs the commanded path on the 4 ms grid [RS-5.24]
        times, q = cell.motion.truth.samples()
        sel = (times > t_start) & (times <= t_start + 1.0 + 1e-9)
        poses = cell.robot.model.flange2base_batch(q[sel]) @ cell.sensor2flange
        s0 = cell.ready_sensor2base()
        y_done = (poses[:, :3, 3] - s0[:3, 3]) @ s0[:3, 1]
        expect = 1.0 - np.cos(2 * np.pi * (times[sel] - t_start))
        assert np.max(np.abs(y_done - expect)) < 0.01


def test_sensor2base_pose_interpolation_exact() -> None:
    """The camera's column poses, interpolated between the exact poses at the 4 ms setpoints,
    match the DGM of the joint-space interpolation the robot follows to < 1e-6 mm."""
    with EmulatedCell(clock="sim", seed=2, timing=PAPER) as cell:
        run_delay_experiment(
            cell.robot_address, cell.sensor_address, ExperimentSettings(duration_s=1.5)
        )
        buf_t, buf_q = cell.motion.truth.covering(-1.0)
        t = np.linspace(buf_t[1], buf_t[-1], 20001)
        fast = cell.motion.sensor2base(t)
        exact = cell.motion.setpoint_poses(lerp_inside(buf_t, buf_q, t))
    # the arm moved (several mm), so the check is not vacuous
    assert np.ptp(exact[:, :3, 3], axis=0).max() > 1.0
    assert np.abs(fast[:, :3, 3] - exact[:, :3, 3]).max() < 1e-6  # mm
    assert np.abs(fast[:, :3, :3] - exact[:, :3, :3]).max() < 1e-8


def test_node_poses_hook_matches_column_poses() -> None:
    """The cell's node poses with weights give its column poses (to rounding), and the camera
    renders the same frames with them as with the 512 column poses (centre rows to 1e-9 px)."""
    with EmulatedCell(clock="sim", seed=2, timing=PAPER) as cell:
        run_delay_experiment(
            cell.robot_address, cell.sensor_address, ExperimentSettings(duration_s=1.0)
        )
        buf_t, _ = cell.motion.truth.covering(-1.0)
        rng = np.random.default_rng(5)
        emu = cell.sensor.emulator
        provider = emu.sensor2base
        hook = node_poses_of(provider)
        assert hook is not None
        for _ in range(20):
            t0 = rng.uniform(buf_t[0], buf_t[-1] - 4e-3)
            t = t0 + np.arange(512) * 3.5e-3 / 512 + rng.uniform(0.0, 1e-4)
            if rng.random() < 0.3:
                t = rng.permutation(t)  # any order of times
            nw = hook(t)
            assert nw is not None
            nodes, w = nw
            assert nodes.shape == (w.shape[0], 16) and w.shape == (nodes.shape[0], 512)
            assert np.abs(w.sum(axis=0) - 1.0).max() < 1e-12
            poses = cell.motion.sensor2base(t).reshape(-1, 16)
            assert np.abs(w.T @ nodes - poses).max() < 1e-9  # mm
            seed = int(rng.integers(1 << 30))
            frames = []
            for p in (provider, lambda x: provider(x)):
                r = StripeRenderer(cell.scene, emu.camera, rng=np.random.default_rng(seed))
                frames.append(r.render(0, np.sort(t), p))
            # same pixels, except where the stripe's window start rint(centre row) sits on a
            # tie: the ready pose sees the plate at row 127.5, and ~1e-12 px decide the side
            cols = np.unique(np.argwhere(frames[0][0] != frames[1][0])[:, 0])
            centre = frames[1][1].center_row[cols]
            assert np.all(np.abs(centre - np.floor(centre) - 0.5) < 1e-9)
            assert np.allclose(frames[0][1].center_row, frames[1][1].center_row, rtol=0.0,
                               atol=1e-9, equal_nan=True)  # fmt: skip
            assert np.isfinite(frames[0][1].center_row).sum() > 100
        # outside the known setpoints the hook declines
        assert hook(np.array([buf_t[-1] + 1e-3])) is None
        assert hook(np.array([buf_t[0] - 1.0])) is None


def test_a_delay_run_whose_control_is_taken_away_ends_with_the_reason(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The client stalls past its 0.25 s lease (its keep-alive with it) during the sine: the
    robot takes control away and stops the arm [RS-7.10]. The run ends with that reason
    (it once waited for the stopped move forever: a 600 s test timeout in a loaded run)."""
    import time

    from spec import client as spec_client
    from sync import experiment

    original = spec_client.wait_move
    calls = [0]

    def stalled(client: FramedClient, timeout: float) -> object:
        calls[0] += 1
        if calls[0] == 2:
            client._stop_keeper()
            time.sleep(1.0)  # four leases
        return original(client, timeout)

    monkeypatch.setattr(experiment, "wait_move", stalled)
    with EmulatedCell(clock="sim", seed=3, timing=PAPER) as cell:
        with pytest.raises(ExperimentError, match=r"the sine move stopped: .*control"):
            run_delay_experiment(
                cell.robot_address, cell.sensor_address, ExperimentSettings(duration_s=3.0)
            )
        assert not cell.robot.status().moving
