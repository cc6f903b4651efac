"""What an ILC trial's data is worth (welding/ilc_loop.py: ``trial_trust``, ``placed_later``), from
the robot's stamps and counts only, and what the command line does with a trial it cannot
trust: reports it, does not learn from it, exits UNTRUSTED."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from kinematics import get_model, location_to_transform
from spec.exitcodes import ExitCode
from welding import ilc_loop
from welding.cli import main
from welding.ilc_loop import (
    IlcSettings,
    PassGeometry,
    placed_later,
    start_from_joint_log,
    trial_trust,
)
from welding.track_loop import TrackOutcome
from welding.tracking import NominalWeld, Verdict

PERIOD = 0.004
RATE = 200.0


def _geometry() -> PassGeometry:
    weld = NominalWeld(
        start=np.zeros(3),
        direction=np.array([1.0, 0.0, 0.0]),
        angles=np.zeros(3),
        length_mm=100.0,
        speed_mm_s=250.0,
    )
    times, _ = weld.timed_path(PERIOD)
    return PassGeometry(weld, (0.0,) * 6, np.eye(4), 40.0, 40.0, 90.0, times)


def _rows(t_trigger: np.ndarray, delta_t: float = 0.0049) -> np.ndarray:
    """GetSeamPoints rows (index, t_trigger, t_sync, status 0, ...) for these triggers."""
    rows = np.zeros((len(t_trigger), 17))
    rows[:, 0] = np.arange(len(t_trigger))
    rows[:, 1] = t_trigger
    rows[:, 2] = t_trigger + delta_t
    return rows


def _outcome(
    g: PassGeometry, rows: np.ndarray, *, late: int = 0, on_grid: bool = True
) -> TrackOutcome:
    verdict = Verdict(True, "", 0.1, 0.0, 0.0, 100, late, 0)
    return TrackOutcome("", len(g.times), len(g.times), on_grid, verdict, t0=1.0, rows=rows)


def _joint_log(t0: float, n: int, missing: tuple[int, ...] = ()) -> np.ndarray:
    t = t0 - 0.008 + PERIOD * np.arange(n + 6)
    keep = np.ones(len(t), dtype=bool)
    keep[list(missing)] = False
    return np.column_stack([t[keep], np.zeros((int(keep.sum()), 6))])


def test_a_trial_on_time_is_trusted() -> None:
    g = _geometry()
    triggers = 1.0 + np.arange(0.0, float(g.times[-1]) + 0.01, 1.0 / RATE)
    checks = trial_trust(
        _outcome(g, _rows(triggers)), g, IlcSettings(), _joint_log(1.0, len(g.times)), PERIOD
    )
    assert checks.reason == ""
    assert checks.summary() == {
        "late_corrections": 0,
        "held_cycles": 0,
        "start_on_grid": True,
        "joint_log_missing": 0,
        "reading_gap_ms": pytest.approx(5.0),
        "late_readings": 0,
        "start_found": None,
    }


def test_each_kind_of_untrustworthy_data_is_named() -> None:
    """Late corrections during the laser's part, a start off the known grid, a joint log
    sample missing, a gap of 20 ms (4 triggers) between readings over the laser's part."""
    g = _geometry()
    triggers = 1.0 + np.arange(0.0, float(g.times[-1]) + 0.01, 1.0 / RATE)
    # readings 60-63 lost: 1.300-1.315 s, under the laser (40..90 mm: 0.21..0.41 s)
    outcome = _outcome(g, _rows(np.delete(triggers, range(60, 64))), late=3, on_grid=False)
    checks = trial_trust(
        outcome, g, IlcSettings(), _joint_log(1.0, len(g.times), missing=(40,)), PERIOD
    )
    assert "3 corrections reached the robot after their cycle during the laser's part" in (
        checks.reason
    )
    assert "the cycle the move started on is not known exactly" in checks.reason
    found_late = trial_trust(
        outcome, g, IlcSettings(), _joint_log(1.0, len(g.times)), PERIOD, start_found=1
    )
    assert "the move started 1 cycles after the one its corrections were timed for" in (
        found_late.reason
    )
    found = trial_trust(
        _outcome(g, _rows(triggers), on_grid=False),
        g,
        IlcSettings(),
        _joint_log(1.0, len(g.times)),
        PERIOD,
        start_found=0,
    )
    assert found.reason == "" and found.start_found == 0
    assert "1 joint log samples missing over the move" in checks.reason
    assert "no sensor reading for 25 ms" in checks.reason
    short = _joint_log(1.0, len(g.times))[:-20]
    assert (
        "the joint log does not cover the move"
        in trial_trust(_outcome(g, _rows(triggers)), g, IlcSettings(), short, PERIOD).reason
    )


def test_readings_the_robot_placed_later_are_counted_not_left_out() -> None:
    """[SY-3.8] the robot places a reading its sensor exposed late at t_T + ΔT + its extra
    lag: the trial counts it (late_readings) and keeps it, at that t_S."""
    g = _geometry()
    triggers = 1.0 + np.arange(0.0, float(g.times[-1]) + 0.01, 1.0 / RATE)
    rows = _rows(triggers)
    assert not placed_later(rows).any()
    rows[70, 2] += 2.7e-3  # exposed 2.7 ms late, under the laser
    assert placed_later(rows).tolist() == [i == 70 for i in range(len(rows))]
    checks = trial_trust(_outcome(g, rows), g, IlcSettings(), _joint_log(1.0, len(g.times)), PERIOD)
    assert checks.reason == "" and checks.late_readings == 1


def test_an_untrusted_trial_is_not_learned_from_and_the_run_exits_untrusted(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Trial 2 made untrusted (as late data would): printed UNTRUSTED with its reason, its
    own measurement null in the JSON, the table not updated (trial 3 repeats trial 2's
    motion: the same truth error on the simulated clock), exit 4."""
    real = ilc_loop.trial_trust
    calls: list[int] = []

    def fake(*args: Any) -> ilc_loop.TrialChecks:
        checks = real(*args)
        calls.append(1)
        if len(calls) == 2:
            from dataclasses import replace

            return replace(checks, reason="2 corrections reached the robot after their cycle")
        return checks

    monkeypatch.setattr(ilc_loop, "trial_trust", fake)
    out = tmp_path / "ilc.json"
    code = main(["ilc", "--emulate", "--dynamics", "elastic", "--length", "20", "--trials",
                 "3", "--json", str(out)])  # fmt: skip
    stdout, err = capsys.readouterr()
    assert code == ExitCode.UNTRUSTED
    assert err == "trial 2: 2 corrections reached the robot after their cycle\n"
    trials = json.loads(out.read_text())["trials"]
    assert [t["trusted"] for t in trials] == [True, False, True]
    assert trials[1]["untrusted"] == "2 corrections reached the robot after their cycle"
    assert trials[1]["measured_max_mm"] is None
    # the same motion from where the last one left the arm (settled within 1e-4 deg)
    assert trials[2]["error_max_mm"] == pytest.approx(trials[1]["error_max_mm"], rel=1e-6)
    assert "trial 2 UNTRUSTED (not learned from): 2 corrections" in stdout
    last = stdout.strip().splitlines()[-1]
    assert last.startswith("UNTRUSTED: 1 of 3 trials (2)") and "->" not in last


def test_the_start_cycle_a_reply_did_not_tell_is_found_in_the_joint_log() -> None:
    """A joint log of the pass lagging the law by the encoder latency (2.8 ms): the start
    is found where the move's law really began, however many cycles (up to 3) after the
    earliest one it could have been; a log of an arm standing still tells nothing."""
    model = get_model("RX90B")
    weld = NominalWeld(
        start=np.array([500.0, -100.0, 300.0]),
        direction=np.array([0.0, 1.0, 0.0]),
        angles=np.array([180.0, 0.0, 0.0]),
        length_mm=150.0,
        speed_mm_s=250.0,
    )
    times, _ = weld.timed_path(PERIOD)
    g = PassGeometry(weld, (0.0,) * 6, np.eye(4), 40.0, 40.0, 90.0, times)
    t0, latency = 1.0, 0.0028
    t_log = t0 - 0.008 + PERIOD * np.arange(len(times) + 20)
    q = np.array(model.ik(location_to_transform(np.r_[weld.start, weld.angles]))[0].joints_deg)
    joints = []
    for t in t_log:
        p = weld.point(float(weld.s_at(t - t0 - latency)))
        q = model.ik(location_to_transform(np.r_[p, weld.angles]), near=q)[0].joints_deg
        joints.append(q)
    log = np.column_stack([t_log, joints])
    for m in range(3):
        outcome = _outcome(g, np.zeros((0, 17)), on_grid=False)
        early = TrackOutcome("", 0, 0, False, outcome.verdict, t0=t0 - m * PERIOD)
        assert start_from_joint_log(early, g, log, model, latency, PERIOD) == m
    still = np.column_stack([t_log, np.tile(joints[0], (len(t_log), 1))])
    assert start_from_joint_log(early, g, still, model, latency, PERIOD) is None
