"""The ILC along a path with corners: the time-varying lifted model against the arm it models,
the sensor's reading turned into the laser's error where the seam crosses the sensor's plane
obliquely, and end to end over the emulated cell a job's lines with rounded corners (the
cell's jog seam) learned, its table refused on another path, and what cannot be learned
refused in one line."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from cell.cell import EmulatedCell
from kinematics import get_model, location_to_transform, transform_to_location
from kinematics.dynamics import RX90B, link_inertia, simulate
from sensorsocket.scene import JogPath
from welding import job as J
from welding.cli import main
from welding.ilc import IlcTable, lifted_model, lifted_model_along
from welding.ilc_emulate import job_table, run_ilc_emulated
from welding.ilc_loop import IlcSettings, PassGeometry, PathPass, _seam_error
from welding.track_loop import TrackOutcome
from welding.tracking import PolylineWeld

PERIOD = 0.004
TOOL = location_to_transform(np.array([0.0, 0.0, 200.0, 0.0, 0.0, 0.0]))
Q_READY = np.array([0.0, 30.0, 100.0, 0.0, 50.0, 0.0])


def test_the_time_varying_model_at_one_pose_is_the_lifted_model() -> None:
    """With the arm at one pose every cycle the time-varying G is :func:`lifted_model`'s, on
    the link and on the (delayed) motor side, whatever the inertia blocks."""
    model = get_model("RX90B")
    n = 60
    poses = np.tile(Q_READY, (n, 1))
    for side, latency in (("link", 0.0), ("motor", 0.0028)):
        lti = lifted_model(RX90B, model, Q_READY, TOOL, n, PERIOD, side=side, latency_s=latency)
        for block in (None, 7):
            ltv = lifted_model_along(
                RX90B, model, poses, TOOL, PERIOD, side=side, latency_s=latency, block=block
            )
            np.testing.assert_allclose(ltv, lti, rtol=0, atol=1e-15)


def _corner_pass() -> tuple[PolylineWeld, np.ndarray]:
    """A pass from the ready pose: 120 mm along x, a 60° corner (R 32 mm), 120 mm on, at
    250 mm/s; and the joints (N, 6) at each of its cycles."""
    model = get_model("RX90B")
    start = model.flange2base(Q_READY) @ TOOL
    p0 = start[:3, 3]
    turn = math.radians(60.0)
    p1 = p0 + np.array([120.0, 0.0, 0.0])
    p2 = p1 + 120.0 * np.array([math.cos(turn), math.sin(turn), 0.0])
    weld = PolylineWeld(np.array([p0, p1, p2]), transform_to_location(start)[3:], 250.0)
    _, locs = weld.timed_path(PERIOD)
    q = np.empty((len(locs), 6))
    near = Q_READY
    for k, loc in enumerate(locs):
        near = model.ik(location_to_transform(loc) @ np.linalg.inv(TOOL), near=near)[0].joints_deg
        q[k] = near
    return weld, q


@pytest.mark.parametrize("pulse_at", ["start", "corner"])
def test_a_column_of_the_time_varying_model_is_a_pulse_simulated_along_a_corner(
    pulse_at: str,
) -> None:
    """One column of G against the elastic arm itself moving along a cornered pass (its link
    inertia changing every cycle): a 0.1 mm correction in one cycle, the laser's motion
    from the difference of two simulations through the arm's kinematics. The time-varying
    model with its axis responses per block of 25 cycles is within 3 %; one pose's model
    (the middle's, with or without the Jacobian along the path) is not, away from it: the
    arm's reach, and with it axis 1's inertia, changes threefold along 240 mm."""
    model = get_model("RX90B")
    weld, q = _corner_pass()
    n = len(q)
    times = np.arange(n, dtype=np.float64) * PERIOD
    ((_, s_corner),) = weld.corner_s()
    m = 30 if pulse_at == "start" else int(np.argmin(np.abs(weld.s_at(times) - s_corner)))
    jl = np.array([link_inertia(model, qk, RX90B) for qk in q])
    r = np.radians(np.vstack([q[:1], q]))  # setpoints (N + 1, 6): at rest at the start
    _, nominal = simulate(RX90B, jl, r, period=PERIOD)
    blocks = lifted_model_along(RX90B, model, q, TOOL, PERIOD, block=25)
    middle = lifted_model_along(RX90B, model, q, TOOL, PERIOD)
    one_pose = lifted_model(RX90B, model, q[n // 2], TOOL, n, PERIOD)
    for dp in np.eye(3) * 0.1:
        dq = np.linalg.solve(model.jacobian(q[m], tool=TOOL), np.concatenate([dp, np.zeros(3)]))
        pulsed = r.copy()
        pulsed[m + 1] += dq  # the correction of cycle m
        _, link = simulate(RX90B, jl, pulsed, period=PERIOD)
        laser = [(model.flange2base_batch(np.degrees(x)) @ TOOL)[:, :3, 3] for x in (link, nominal)]
        direct = laser[0] - laser[1]

        def off(G: np.ndarray, direct: np.ndarray = direct, dp: np.ndarray = dp) -> float:
            column = (G[:, 3 * m : 3 * m + 3] @ dp).reshape(n, 3)
            return float(np.abs(column - direct).max() / np.abs(direct).max())

        assert off(blocks) < 0.03
        if pulse_at == "start":
            assert off(middle) > 0.15 and off(one_pose) > 0.15


def test_the_sensor_reading_through_a_corner_is_the_lasers_error_across_its_path() -> None:
    """The laser off its reference across its path (0.3 mm lateral, -0.1 mm height) on a
    pass with a 15° corner: the sensor 40 mm ahead reads the seam where it crosses its plane,
    obliquely on the second line, which moves the reading by more than the laser moved;
    :func:`_seam_error` gives back the laser's error in every cycle it was seen."""
    turn = math.radians(15.0)
    v = np.array(
        [[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [100 + 100 * math.cos(turn), 100 * math.sin(turn), 0]]
    )
    weld = PolylineWeld(v, np.zeros(3), 250.0)
    times, _ = weld.timed_path(PERIOD)
    s2b = np.eye(4)
    s2b[:3, 3] = [40.0, 0.0, 0.0]  # the sensor 40 mm ahead along x, its plane across x
    g = PassGeometry(weld, (0.0,) * 6, s2b, 40.0, 40.0, weld.length_mm - 50.0, times)
    t0 = 2.0
    t = np.arange(0.01, weld.duration - 0.3, 0.005)  # exposures, s since the move's start
    s_l = weld.s_at(t)
    frames = g.frames_at(s_l)
    actual = 0.3 * frames[:, :, 1] - 0.1 * frames[:, :, 2]  # across the path
    sensor = weld.point(s_l) + actual + s2b[:3, 3]
    s_fine = np.linspace(0.0, weld.length_mm, 400001)
    path_x = weld.point(s_fine)[:, 0]  # increases along this path
    s_seen = np.interp(sensor[:, 0], path_x, s_fine)
    rows = np.zeros((len(t), 17))
    rows[:, 2] = t0 + t
    rows[:, 5:8] = weld.point(s_seen) - sensor  # ^S_G T: the sensor frame is the base's
    outcome = TrackOutcome("", len(times), len(times), True, t0=t0, rows=rows)

    def none(x: np.ndarray) -> np.ndarray:
        return np.zeros((len(x), 3))

    e = _seam_error(g, outcome, none, none, 0.0, np.zeros((len(times), 3)))
    seen = (times >= t[0]) & (times <= t[-1])
    expected = np.array([np.interp(times[seen], t, -actual[:, c]) for c in range(3)]).T
    oblique = seen & (weld.s_at(times) + 40.0 > 110.0)
    assert np.count_nonzero(oblique) > 50
    np.testing.assert_allclose(e[seen], expected, atol=2e-5)
    # read at the laser's arc length plus the look-ahead, as on a straight line: off by
    # as much as the error itself where the seam turns
    lateral = np.einsum(
        "kc,kc->k", rows[:, 5:8] - (weld.point(s_l + 40.0) - sensor), frames[:, :, 1]
    )
    assert np.abs(np.abs(lateral) - 0.3).max() > 0.1


def _jog_job(path: Path, tail_mm: float, *, moved_mm: float = 0.0, arcs: bool = False) -> None:
    """A job of one path over the cell's ``arc`` seam (the workpiece frame, the laser's
    height at the ready pose), ``tail_mm`` on after the jog, the last point ``moved_mm``
    along y: lines whose corners, rounded with R 32 mm, are the seam's two 15° arcs, or with
    ``arcs`` the seam itself, its arcs as ``<arc>`` segments."""
    cell = EmulatedCell(clock="sim", seam="jog")
    laser2base = cell.ready_flange2base() @ location_to_transform(np.array(cell.laser_tool))
    z = float((np.linalg.inv(cell.scene.workpiece2base) @ laser2base)[2, 3])

    def at(x: float, y: float) -> J.Location:
        return J.Location(x, y, z, 180.0, 0.0, 0.0, "laser", "workpiece")

    jog = JogPath()
    x1, y1, x2, y2, x3, h = jog._knots()
    end = at(x3 + tail_mm, h + moved_mm)
    segments: tuple[J.Line | J.Arc, ...]
    if arcs:
        r, a, half = jog.radius_mm, jog.start_x_mm, math.radians(jog.angle_deg / 2)
        segments = (
            J.Line(at(a, 0.0)),
            J.Arc(at(a + r * math.sin(half), r - r * math.cos(half)), at(x1, y1)),
            J.Line(at(x2, y2)),
            J.Arc(at(x3 - r * math.sin(half), h - r + r * math.cos(half)), at(x3, h)),
            J.Line(end),
        )
    else:
        t = math.tan(math.radians(jog.angle_deg))
        segments = (J.Line(at(x1 - y1 / t, 0.0)), J.Line(at(x2 + (h - y2) / t, h)), J.Line(end))
    J.save(J.Job("jog", (J.Path("seam", at(0.0, 0.0), segments, 250.0, tracked=False),)), path)


def test_ilc_learns_a_job_with_corners_and_refuses_its_table_on_another_path(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """``welding ilc JOB.xml`` over the arc seam, the job's path three lines with two 15°
    corners, elastic arm, 250 mm/s, simulated clock: the error against the truth falls at
    every trial; the table beside the job names the whole path, and after the job's last
    point moved by 1 mm it is refused (exit 2), not welded with."""
    job = tmp_path / "jog.xml"
    _jog_job(job, 30.0)
    out = tmp_path / "ilc.json"
    args = ["ilc", str(job), "--emulate", "--dynamics", "elastic", "--seam", "arc"]
    assert main([*args, "--trials", "3", "--json", str(out)]) == 0
    errors = [t["error_max_mm"] for t in json.loads(out.read_text())["trials"]]
    assert all(b < a for a, b in itertools.pairwise(errors)), errors
    assert errors[-1] < errors[0] / 6, errors
    table = IlcTable.load(job_table(job, "seam"))
    assert table.key.startswith("path ") and len(table.key.split()) == 1 + 4 * 3 + 3 + 1
    capsys.readouterr()
    _jog_job(job, 30.0, moved_mm=1.0)
    assert main([*args, "--trials", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "the table was learned on path" in err


def test_ilc_learns_a_job_with_arcs(tmp_path: Path) -> None:
    """The same seam as the job's own ``<line> <arc> <line> <arc> <line>`` (the seam's R 32 mm
    arcs): each ``<arc>`` is an arc of the pass, and the error falls at every trial."""
    job_file = tmp_path / "jog.xml"
    _jog_job(job_file, 30.0, arcs=True)
    job = J.load(job_file, has_tool=lambda n: True, has_frame=lambda n: True)
    result = run_ilc_emulated(IlcSettings(trials=3), seam="arc", job=job)
    errors = [t["error_max_mm"] for t in result["trials"]]
    assert all(b < a for a, b in itertools.pairwise(errors)), errors
    assert errors[-1] < errors[0] / 6, errors
    assert len(result["table"].key.split()) == 1 + (6 + 2) * 3 + 3 + 1  # vertices, middles


def test_an_arc_that_kinks_is_refused_in_one_line(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """An ``<arc>`` is not rounded: one that leaves its line at an angle is refused, exit 2,
    naming the job's point, before control is taken."""
    cell = EmulatedCell(clock="sim", seam="straight")
    laser2base = cell.ready_flange2base() @ location_to_transform(np.array(cell.laser_tool))
    z = float((np.linalg.inv(cell.scene.workpiece2base) @ laser2base)[2, 3])

    def at(x: float, y: float) -> J.Location:
        return J.Location(x, y, z, 180.0, 0.0, 0.0, "laser", "workpiece")

    segments = (J.Line(at(60.0, 0.0)), J.Arc(at(80.0, 3.0), at(100.0, 4.0)))
    job = tmp_path / "kink.xml"
    J.save(J.Job("k", (J.Path("p", at(0.0, 0.0), segments, 250.0),)), job)
    assert main(["ilc", str(job), "--emulate", "--dynamics", "elastic"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "path 'p', point 2: the path kinks by" in err and "an arc must be tangent" in err


def test_a_path_key_names_every_vertex() -> None:
    v = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [200.0, 10.0, 0.0]])
    a = PathPass(v, np.zeros(3), 250.0)
    moved = v.copy()
    moved[1, 1] = 0.02
    assert a.key != PathPass(moved, np.zeros(3), 250.0).key
    assert PathPass(v[:2], np.zeros(3), 250.0).key == "line " + " ".join(
        f"{x:.2f}" for x in [*v[:2].ravel(), 0, 0, 0, 250]
    )


def test_a_corner_the_sensor_cannot_follow_is_refused_in_one_line(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """A job's 90° corner: the tool keeps its orientation, so the sensor 40 mm ahead would
    lose the second line; refused before control is taken, exit 2, naming the job's point."""
    cell = EmulatedCell(clock="sim", seam="straight")
    laser2base = cell.ready_flange2base() @ location_to_transform(np.array(cell.laser_tool))
    z = float((np.linalg.inv(cell.scene.workpiece2base) @ laser2base)[2, 3])
    locs = [J.Location(x, y, z, 180.0, 0.0, 0.0, "laser", "workpiece") for x, y in
            [(0.0, 0.0), (80.0, 0.0), (80.0, 80.0)]]  # fmt: skip
    job = tmp_path / "corner.xml"
    J.save(J.Job("c", (J.Path("p", locs[0], tuple(J.Line(p) for p in locs[1:]), 250.0),)), job)
    assert main(["ilc", str(job), "--emulate", "--dynamics", "elastic"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "path 'p', point 2 of the path: the corner turns too sharply for the sensor" in err


def test_the_cells_corner_seam_is_refused_in_one_line_after_teaching(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Without a job, the cell's pass keeps the tool's orientation along the sensor's x axis;
    the corner seam's legs run at 45° to it, so the teaching pass loses the seam: refused,
    exit 2, before the first trial."""
    code = main(["ilc", "--emulate", "--dynamics", "elastic", "--seam", "corner", "--length", "60"])
    out, err = capsys.readouterr()
    assert code == 2 and "trial" not in out
    assert err.count("\n") == 1
    assert "the sensor did not see the seam over" in err and "keeps the tool's orientation" in err
