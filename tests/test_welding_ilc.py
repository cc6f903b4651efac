"""The ILC: the lifted update on a known linear system (converges exactly where the criterion
says), the lifted model against the arm it models, the table file, and end to end over the
emulated cell's sockets (the truth error falls at every trial)."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from cell.cell import EmulatedCell
from kinematics import get_model, location_to_transform, transform_to_location
from kinematics.dynamics import RX90B, link_inertia, simulate
from welding import job as J
from welding.__main__ import main
from welding.ilc import (
    IlcTable,
    check_convergence,
    ilc_update,
    learning_matrix,
    lifted_model,
    q_filter,
)
from welding.ilc_emulate import job_table, run_ilc_emulated
from welding.ilc_loop import AVERAGE_WINDOW, IlcSettings

PERIOD = 0.004


def _first_order(n: int, a: float, b: float) -> np.ndarray:
    """Lifted G of y_k = a y_{k-1} + b u_k (a known linear system)."""
    h = b * a ** np.arange(n)
    k = np.arange(n)
    lag = k[:, None] - k[None, :]
    return np.where(lag >= 0, h[np.clip(lag, 0, n - 1)], 0.0)


@settings(max_examples=60, deadline=None)
@given(
    gain=st.floats(0.05, 4.0),
    cutoff=st.floats(5.0, 120.0),
    beta=st.floats(1e-6, 1e-1),
    a=st.floats(0.2, 0.95),
    model_error=st.floats(0.5, 1.5),
)
def test_lifted_ilc_converges_exactly_where_the_criterion_says(
    gain: float, cutoff: float, beta: float, a: float, model_error: float
) -> None:
    """u_{j+1} = Q(u_j + L e_j) on a true system G, L from a model off by ``model_error``:
    the criterion of the true loop, Q(I − L G), predicts it. A spectral radius below 1: the
    correction reaches the fixed point (and with a norm below 1, monotonically); above 1: it
    grows without bound."""
    n = 30
    G = _first_order(n, a, 1.0 - a)
    model = model_error * G
    Q = q_filter(n, cutoff, PERIOD, channels=1)
    L = learning_matrix(model, gain, np.ones(n), beta)
    conv = check_convergence(Q, L, G, channels=1)
    assume(abs(conv.radius - 1.0) > 0.05)
    r = np.sin(np.linspace(0.0, 3.0, n))
    M = Q @ (np.eye(n) - L @ G)
    u = np.zeros(n)
    if conv.radius < 1.0:
        u_star = np.linalg.solve(np.eye(n) - M, Q @ L @ r)
        last = np.linalg.norm(u - u_star)
        for _ in range(2000):
            u = ilc_update(u, r - G @ u, Q, L)
            now = np.linalg.norm(u - u_star)
            if conv.norm < 1.0:
                assert now <= last * (1 + 1e-9) + 1e-12
            last = now
        assert last <= 1e-6 * max(float(np.linalg.norm(u_star)), 1e-9)
    else:
        bound = 1e3 * np.linalg.norm(Q @ L @ r)
        for _ in range(5000):
            u = ilc_update(u, r - G @ u, Q, L)
            if np.linalg.norm(u) > bound:
                break
        assert np.linalg.norm(u) > bound


@settings(max_examples=40, deadline=None)
@given(
    gain=st.floats(0.05, 1.9),
    a=st.floats(0.2, 0.95),
    model_error=st.floats(0.6, 1.4),
    weights=st.lists(st.floats(0.05, 1.0), min_size=5, max_size=40),
)
def test_an_averaging_update_keeps_the_laws_fixed_point_and_its_monotony(
    gain: float, a: float, model_error: float, weights: list[float]
) -> None:
    """Any weights in (0, 1] (the averaging table's): where Norrlöf's norm is below 1 the
    correction approaches the law's own fixed point at every trial."""
    n = 30
    G = _first_order(n, a, 1.0 - a)
    Q = q_filter(n, 40.0, PERIOD, channels=1)
    L = learning_matrix(model_error * G, gain, np.ones(n), 1e-3)
    M = Q @ (np.eye(n) - L @ G)
    assume(check_convergence(Q, L, G, channels=1).norm < 0.999)
    r = np.sin(np.linspace(0.0, 3.0, n))
    u_star = np.linalg.solve(np.eye(n) - M, Q @ L @ r)
    u = np.zeros(n)
    last = np.linalg.norm(u - u_star)
    for w in weights:
        u = ilc_update(u, r - G @ u, Q, L, w)
        now = np.linalg.norm(u - u_star)
        assert now <= last * (1 + 1e-9) + 1e-12
        last = now


def test_averaging_the_updates_averages_the_sensors_trial_to_trial_error() -> None:
    """A measurement whose error changes from trial to trial (noise, jitter): learned anew
    every trial (weight 1) it stays in the correction at its full size; averaged from
    trial 3 on (IlcSettings.average_from) it falls as 1/√trials, up to the window's 8. The
    laser's error against the law's own fixed point (what no measurement error would
    leave), rms over trials 31-40, exact model."""
    n, sigma = 60, 0.01
    G = _first_order(n, 0.8, 0.2)
    Q = q_filter(n, 50.0, PERIOD, channels=1)
    L = learning_matrix(G, 1.0, np.ones(n), 1e-6)
    r = np.sin(np.linspace(0.0, 6.0, n))
    u_star = np.linalg.solve(np.eye(n) - Q @ (np.eye(n) - L @ G), Q @ L @ r)
    noise = np.random.default_rng(7).normal(0.0, sigma, (40, n))
    spread = {}
    for average_from in (0, 3):
        plan = IlcSettings(average_from=average_from, trials=40)
        u = np.zeros(n)
        off = []
        for j in range(1, 41):
            off.append(float(np.sqrt(np.mean((G @ (u - u_star)) ** 2))))
            u = ilc_update(u, r - G @ u + noise[j - 1], Q, L, plan.weight_after(j))
        spread[average_from] = float(np.mean(off[-10:]))
    assert spread[0] > 0.3 * sigma, spread  # learned anew: the noise through Q
    assert spread[3] < spread[0] / 2, spread  # √8 ≈ 2.8 expected


def test_the_averaging_weights() -> None:
    plan = IlcSettings(average_from=3)
    assert [plan.weight_after(j) for j in range(1, 7)] == [1.0, 1.0, 1 / 2, 1 / 3, 1 / 4, 1 / 5]
    assert plan.weight_after(50) == 1 / AVERAGE_WINDOW
    assert IlcSettings(average_from=0).weight_after(9) == 1.0
    with pytest.raises(ValueError, match="average_from"):
        IlcSettings(average_from=-1).check()
    with pytest.raises(ValueError, match="weight"):
        ilc_update(np.zeros(3), np.zeros(3), np.eye(3), np.eye(3), 0.0)


def test_a_gain_on_the_exact_model_converges_up_to_two() -> None:
    """Model inverse with the model exact: 1 − L·G = 1 − γ (β → 0), so the norm is |1 − γ|
    under Q <= 1: below 2 converges, above 2 does not (Norrlöf's criterion)."""
    n = 30
    G = _first_order(n, 0.8, 0.2)
    Q = q_filter(n, 100.0, PERIOD, channels=1)
    assert check_convergence(Q, learning_matrix(G, 1.5, np.ones(n), 1e-9), G, 1).converges
    assert not check_convergence(Q, learning_matrix(G, 2.5, np.ones(n), 1e-9), G, 1).converges


def test_q_filter_is_zero_phase_and_never_amplifies() -> None:
    n = 200
    Q = q_filter(n, 20.0, PERIOD, channels=1)
    np.testing.assert_allclose(Q, Q.T, atol=1e-15)  # zero phase: symmetric
    assert np.linalg.norm(Q, 2) <= 1.0 + 1e-12
    assert Q[100].sum() == pytest.approx(1.0, abs=1e-9)  # unit gain at 0 Hz inside
    with pytest.raises(ValueError, match="cutoff"):
        q_filter(n, 200.0, PERIOD)


def test_the_lifted_model_predicts_the_arm() -> None:
    """G·u against the elastic arm itself for a small lateral correction at one pose: the
    laser's motion agrees within 2 % (the model is linearised, the arm is not)."""
    model = get_model("RX90B")
    q = np.array([0.0, 30.0, 100.0, 0.0, 50.0, 0.0])
    tool = location_to_transform(np.array([0.0, 0.0, 200.0, 0.0, 0.0, 0.0]))
    n = 80
    G = lifted_model(RX90B, model, q, tool, n, PERIOD)
    u = np.zeros((n, 3))
    u[5:, 1] = 0.5 * np.sin(2 * math.pi * 5.0 * PERIOD * np.arange(n - 5))  # mm, base y
    predicted = (G @ u.ravel()).reshape(n, 3)
    J = model.jacobian(q, tool=tool)
    dq = np.linalg.solve(J, np.column_stack([u, np.zeros((n, 3))]).T).T  # rad
    r = np.radians(q) + np.vstack([np.zeros(6), dq])
    _, link = simulate(RX90B, link_inertia(model, q, RX90B), r, period=PERIOD)
    f2b = model.flange2base_batch(np.degrees(link)) @ tool
    actual = f2b[:, :3, 3] - (model.flange2base(q) @ tool)[:3, 3]
    assert np.abs(actual - predicted).max() < 0.02 * np.abs(actual).max()


def test_a_table_round_trips_and_a_bad_one_is_named(tmp_path: Path) -> None:
    t = IlcTable(0.004, 250.0, np.ones((4, 3)), np.array([[0.0, 1, 2, 3], [1.0, 2, 3, 4]]),
                 "seam", 3)  # fmt: skip
    path = tmp_path / "t.json"
    t.save(path)
    back = IlcTable.load(path)
    np.testing.assert_array_equal(back.correction, t.correction)
    np.testing.assert_allclose(back.offsets(np.array([0.5])), [[1.5, 2.5, 3.5]])
    (tmp_path / "bad.json").write_text(json.dumps({"version": 1, "period": 0.004}))
    with pytest.raises(ValueError, match=r"bad\.json: not an ILC table"):
        IlcTable.load(tmp_path / "bad.json")


def test_a_diverging_gain_is_refused_before_the_first_trial(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    out = tmp_path / "ilc.json"
    code = main(["ilc", "--emulate", "--dynamics", "elastic", "--gain", "2.5", "--json",
                 str(out)])  # fmt: skip
    stdout, err = capsys.readouterr()
    assert code == 2
    assert err.count("\n") == 1 and "the learning would diverge" in err
    assert "trial" not in stdout and not out.exists()


def test_ilc_over_the_sockets_lowers_the_truth_error_every_trial(tmp_path: Path) -> None:
    """The end-effector ILC on the elastic arm, sine seam, 250 mm/s, simulated clock: the
    laser's error against the emulator's truth falls at every trial; the saved table, reused,
    starts where the learning left off."""
    saved: list[IlcTable] = []
    settings_ = IlcSettings(weld_mm=60.0, trials=3)
    result = run_ilc_emulated(settings_, save=saved.append)
    errors = [t["error_max_mm"] for t in result["trials"]]
    assert [t["trial"] for t in result["trials"]] == [1, 2, 3]
    assert all(b < a for a, b in itertools.pairwise(errors)), errors
    assert errors[-1] < errors[0] / 3
    path = tmp_path / "table.json"
    saved[-1].save(path)
    again = run_ilc_emulated(IlcSettings(weld_mm=60.0, trials=1), table=IlcTable.load(path))
    (trial,) = again["trials"]
    assert trial["trial"] == 4
    assert trial["error_max_mm"] < errors[0] / 3


def test_ilc_track_ends_with_one_tracked_weld_in_the_json(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """``--track``: the learned trials, then one tracked weld with the learned table, listed
    last and marked ``tracked`` (the ILC measures nothing on it: ``measured_max_mm`` null);
    on the workpiece it learned, that weld stays within 0.1 mm of the truth."""
    out = tmp_path / "ilc.json"
    code = main(["ilc", "--emulate", "--dynamics", "elastic", "--length", "60", "--trials",
                 "3", "--track", "--json", str(out)])  # fmt: skip
    stdout, _ = capsys.readouterr()
    assert code == 0
    result = json.loads(out.read_text())
    trials = result["trials"]
    assert [(t["trial"], t["tracked"]) for t in trials] == [
        (1, False), (2, False), (3, False), (4, True)
    ]  # fmt: skip
    learned, tracked = trials[:3], trials[3]
    assert all(isinstance(t["measured_max_mm"], float) for t in learned)
    assert tracked["measured_max_mm"] is None and not tracked["stopped"]
    assert tracked["error_max_mm"] < 0.1
    assert "trial 4 (tracked, with the table)" in stdout
    assert f"tracked with the table {tracked['error_max_mm']:.4f} mm" in stdout


def test_the_tracked_weld_with_the_table_follows_a_workpiece_placed_otherwise() -> None:
    """ILC + tracking over the sockets, simulated clock: the table learned on one workpiece
    (elastic arm, sine seam, 250 mm/s), then the next one placed 0.5 mm to the side and
    turned 0.3°. Welded with the table alone it is off by that placement; tracked with the
    table (``--trials 0 --track``) it stays within 0.1 mm of the truth."""
    learned = run_ilc_emulated(IlcSettings(weld_mm=60.0, trials=3))
    table = learned["table"]
    moved = (0.0, 0.5, 0.0, 0.0, 0.0, 0.3)
    untracked = run_ilc_emulated(
        IlcSettings(weld_mm=60.0, trials=1), table=table, workpiece_error=moved
    )
    tracked = run_ilc_emulated(
        IlcSettings(weld_mm=60.0, trials=0, track=True), table=table, workpiece_error=moved
    )
    (plain,) = untracked["trials"]
    (weld,) = tracked["trials"]
    assert not plain["tracked"] and weld["tracked"] and not weld["stopped"]
    assert plain["error_max_mm"] > 0.3  # the table alone follows the seam it was taught
    assert weld["error_max_mm"] < 0.1
    assert weld["error_max_mm"] < plain["error_max_mm"] / 5


def test_no_trial_and_no_tracked_weld_is_refused() -> None:
    with pytest.raises(ValueError, match="0 trials weld nothing without track"):
        IlcSettings(trials=0).check()


def _cell_pass_job(path: Path, shift_mm: float = 0.0) -> None:
    """A job of one path: the cell's 60 mm pass along the sensor's x axis at 250 mm/s (tool
    ``laser``, base frame), starting where the sensor stands at the ready pose (``shift_mm``
    further along)."""
    cell = EmulatedCell(clock="sim", seam="sine")
    laser2base = cell.ready_flange2base() @ location_to_transform(np.array(cell.laser_tool))
    s2b = cell.ready_sensor2base()
    d = s2b[:3, 0]
    start = laser2base[:3, 3] + ((s2b[:3, 3] - laser2base[:3, 3]) @ d + shift_mm) * d
    angles = transform_to_location(laser2base)[3:]

    def at(p: np.ndarray) -> J.Location:
        x, y, z, rx, ry, rz = (float(v) for v in (*p, *angles))
        return J.Location(x, y, z, rx, ry, rz, tool="laser", frame="world")

    seam = J.Path("seam", at(start), (J.Line(at(start + 60.0 * d)),), 250.0, tracked=False)
    J.save(J.Job("ilc-pass", (seam,)), path)


def test_ilc_learns_a_jobs_path_and_keeps_the_table_beside_the_job(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """``welding ilc JOB.xml``: the job's path learned, its table written beside the job and
    reused by the next run (the trials go on from there); a table learned on the path
    before it moved is refused, not welded with."""
    job = tmp_path / "pass.xml"
    _cell_pass_job(job)
    table = job_table(job, "seam")
    assert table == tmp_path / "pass.seam.ilc.json"
    args = ["ilc", str(job), "--emulate", "--dynamics", "elastic"]
    out = tmp_path / "first.json"
    assert main([*args, "--trials", "2", "--json", str(out)]) == 0
    first = json.loads(out.read_text())
    assert (first["job"], first["path"], first["speed_mm_s"]) == ("ilc-pass", "seam", 250.0)
    e1, e2 = (t["error_max_mm"] for t in first["trials"])
    assert e2 < e1 / 3
    assert IlcTable.load(table).trials == 2
    capsys.readouterr()
    out = tmp_path / "again.json"
    assert main([*args, "--trials", "1", "--json", str(out)]) == 0
    assert f"reusing the table of {table} (2 trials learned)" in capsys.readouterr().out
    (again,) = json.loads(out.read_text())["trials"]
    assert again["trial"] == 3 and again["error_max_mm"] < e1 / 3
    assert IlcTable.load(table).trials == 3
    _cell_pass_job(job, shift_mm=5.0)
    assert main([*args, "--trials", "1"]) == 2
    assert "the table was learned on line" in capsys.readouterr().err


def _at(x: float, y: float, tool: str = "laser") -> J.Location:
    return J.Location(x, y, 300.0, 180.0, 0.0, 0.0, tool=tool, frame="world")


def test_a_path_that_changes_tool_is_refused_in_one_line_before_any_cell(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """The ILC learns a path of one tool, so ``welding ilc JOB.xml`` names the change in one
    line and exits 2 (USAGE) before it builds a cell (no table, no JSON). Lines, corners and
    arcs are learned (tests/test_welding_ilc_path.py)."""
    segments = (J.Line(_at(600.0, 0.0)), J.Line(_at(600.0, 60.0, tool="sensor")))
    job = tmp_path / "two.xml"
    J.save(J.Job("two", (J.Path("p", _at(500.0, 0.0), segments, 100.0),)), job)
    out = tmp_path / "ilc.json"
    code = main(["ilc", str(job), "--emulate", "--clock", "real", "--json", str(out)])
    _, err = capsys.readouterr()
    assert code == 2
    assert err == (
        "python -m welding: error: path 'p' changes tool (laser to sensor): the ILC learns a"
        " path of one tool\n"
    )
    assert not out.exists() and not job_table(job, "p").exists()
