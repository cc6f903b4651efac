"""The ILC trials through the protocol only: teach the seam, repeat the pass, learn.

One pass is the ``track`` pass over the cell's seam (the laser's straight nominal line along
the sensor's x axis, the laser on over ``weld_mm``) or a job's path of lines (its corners
rounded, :class:`~welding.tracking.PolylineWeld`; the tool keeps its orientation), a
ToolMoveTrajectory with a timed correction for every 4 ms cycle (AlterQueue, RS-5.39): the
reference the laser should follow plus the learned correction u_j (:mod:`welding.ilc`; the
lifted model time-varying along the path, the error in each cycle's frame of the path:
along, lateral, height). The reference is the seam as
the sensor measured it on a slow teaching pass first (at 50 mm/s the arm's own error is a
few µm), saved with the table; with ``track`` the tracker corrects the workpiece live and
the table learns only the arm's repeatable error on top of it.

The error each trial learns from, both through the protocol:

- ``joints``: the laser's path from the measured joints (GetJointLog: the motor encoders)
  against the reference, every cycle: the joint ILC of the paper's ref. [10]; it cannot see
  the gearbox's deflection between motor and tool.
- ``seam``: the seam sensor's own measurement ^S_G T (in the sensor frame, so no joint
  reading is in it) against what it would read if the tool were on the reference: where
  the tool really went, across the seam (lateral and height; along it the sensor sees
  nothing). The end-effector ILC.

The caller scores each trial against the emulator's truth (``judge``): this module never
sees it.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
import numpy.typing as npt

from kinematics.dynamics import RX90B, ElasticParams
from kinematics.robot import RobotModel, get_model
from kinematics.transforms import location_to_transform, transform_to_location
from kinematics.types import FloatArray, Loc
from spec import wire
from spec.client import FramedClient
from spec.params import IDENTITY_LOCATION, Joints, Location, Matrix
from spec.registry import CommandId
from welding import job as J
from welding.ilc import (
    Convergence,
    IlcTable,
    LearningDiverges,
    check_convergence,
    ilc_update,
    learning_matrix,
    lever_error,
    lifted_model_along,
    q_filter,
)
from welding.tools import Tables
from welding.track_loop import RobotLink, TrackedWeld, TrackOutcome, laser_path, weld_tracked
from welding.tracking import (
    CornerError,
    NominalWeld,
    OffsetWeld,
    PolylineWeld,
    SeamModel,
    Tracker,
    TrackingError,
    WeldPath,
    check_sensor_view,
)

__all__ = [
    "IlcSettings",
    "IlcTrial",
    "PassGeometry",
    "PathPass",
    "SeamNotTaught",
    "TrialChecks",
    "check_learnable",
    "job_path",
    "path_pass",
    "placed_later",
    "run_ilc",
    "start_from_joint_log",
    "trial_trust",
]

log = logging.getLogger(__name__)


SOURCES = ("seam", "joints")
#: The control lease (s, RS-7.13) the trials take: between two passes the arm stands while
#: the table is judged and learned (a second or two of numpy on a busy machine), longer
#: than the 0.25 s default a moving controller should keep.
LEASE_S = 3.0
#: A trial is not trusted where the sensor's readings over the laser's part are further apart
#: than this many trigger periods (at 200 Hz 15 ms, 3.75 mm at 250 mm/s): its seam error
#: there would be a line drawn across what was not measured.
GAP_TRIGGERS = 3.0
#: A seam point's t_S - t_T beyond the trial's usual (ΔT) by more than this (s) was placed
#: later by the robot for an exposure its sensor started late [SY-3.8] (0.5 ms and more);
#: below it, the rounding of t_T + ΔT.
PLACED_LATER_FLOOR_S = 1e-6


#: the most trials the averaging table is the mean of (IlcSettings.average_from)
AVERAGE_WINDOW = 8


@dataclass(frozen=True)
class IlcSettings:
    """What to learn and how. ``gain`` γ, ``q_hz`` the Q-filter's cutoff, ``beta`` the
    regularisation of the model inverse, ``model_payload_kg`` the payload the ILC's model
    assumes (the arm's is 5 kg), ``latency_s`` the joint log's lag behind the motors the
    joint source's model allows for."""

    speed_mm_s: float = 250.0
    weld_mm: float = 200.0
    trials: int = 5
    source: str = "seam"
    gain: float = 1.0
    q_hz: float = 50.0
    beta: float = 1e-3
    rate_hz: float = 200.0
    teach_speed_mm_s: float = 50.0
    track: bool = False
    #: after the trials, a tracked weld with the learned table: the half width (mm) of the
    #: tracker's fit of the workpiece's deviation from the taught seam
    track_fit_mm: float = 25.0
    model_payload_kg: float = RX90B.payload_kg
    latency_s: float = 0.0028
    params: ElasticParams = RX90B
    #: the pass starts this far (mm) before the sensor's look-ahead does: the move's
    #: constant-acceleration ramp rings the elastic arm at its first resonance (19.5 Hz,
    #: decaying over 1/(ζω) ≈ 0.16 s), and without it the weld's first 20 mm would be
    #: welded in that ringing, the part a learned table reaches worst (trial 5 0.059-0.072 mm
    #: there against 0.037-0.038 with 40 mm, simulated, seeds 0 and 3)
    run_up_mm: float = 40.0
    #: the model's axis responses for the link inertia at the pass's middle (0), or per
    #: block of this many cycles along it (:func:`~welding.ilc.lifted_model_along`)
    model_block_cycles: int = 0
    #: from this trial on the table averages (0: never): after trial j >= average_from the
    #: table moves 1/(j − average_from + 2) of the way to the trial's update
    #: (:func:`~welding.ilc.ilc_update`), so it is the running mean of the updates learned
    #: since trial average_from − 1: the trial-to-trial part of the sensor's error (its
    #: trigger-to-exposure jitter, its noise) falls as 1/√trials instead of being learned
    #: anew in every trial; over at most AVERAGE_WINDOW trials, so a table reused for
    #: weeks still follows an arm that changes
    average_from: int = 3

    def weight_after(self, trial: int) -> float:
        """How far (0..1] the table moves to the update learned from ``trial`` (1-based,
        counted over the table's life)."""
        if self.average_from <= 0 or trial < self.average_from:
            return 1.0
        return 1.0 / min(trial - self.average_from + 2, AVERAGE_WINDOW)

    def check(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"source must be {' or '.join(SOURCES)}, got {self.source!r}")
        if not (0.0 <= self.run_up_mm <= 500.0):
            raise ValueError(f"run-up must be 0..500 mm, got {self.run_up_mm}")
        if not (0 <= self.trials <= 100):
            raise ValueError(f"trials must be 0..100, got {self.trials}")
        if self.average_from < 0:
            raise ValueError(f"average_from must be >= 0, got {self.average_from}")
        if self.model_block_cycles < 0:
            raise ValueError(f"model_block_cycles must be >= 0, got {self.model_block_cycles}")
        if self.trials == 0 and not self.track:
            raise ValueError("0 trials weld nothing without track (the tracked weld)")


@dataclass
class IlcTrial:
    """One trial: the laser's error against the truth (max, rms, mm; the caller's judge)
    and against the ILC's own measurement (max over the window, mm), the largest learned
    correction it ran with (mm), and the truth error along the path (arc length, error)."""

    trial: int
    error_max_mm: float
    error_rms_mm: float
    measured_max_mm: float
    correction_max_mm: float
    stopped: str
    profile: FloatArray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    #: the tracked weld with the learned table after the learning (``track``): not learned
    tracked: bool = False
    #: why the trial's measurement cannot be trusted (:func:`trial_trust`; "" when it can):
    #: such a trial is reported, not learned from
    untrusted: str = ""
    checks: TrialChecks | None = None

    def summary(self) -> dict[str, object]:
        return {
            "trial": self.trial,
            "error_max_mm": self.error_max_mm,
            "error_rms_mm": self.error_rms_mm,
            "measured_max_mm": None if math.isnan(self.measured_max_mm) else self.measured_max_mm,
            "correction_max_mm": self.correction_max_mm,
            "stopped": self.stopped,
            "tracked": self.tracked,
            "trusted": not self.untrusted,
            "untrusted": self.untrusted,
            "checks": None if self.checks is None else self.checks.summary(),
        }


@dataclass(frozen=True)
class PassGeometry:
    """The pass: the nominal laser path (``weld``: the cell's line, or a job's lines with
    their corners rounded), the laser tool, the sensor's pose at the start (^B_S T, nominal
    tool; the tool keeps its orientation along the pass), the look-ahead (mm), the laser
    window, the grid."""

    weld: NominalWeld | PolylineWeld
    laser_tool: Loc
    sensor2base: FloatArray
    look_ahead_mm: float
    laser_from_mm: float
    laser_to_mm: float
    times: FloatArray  # (N,) s since the move's start, one per cycle

    def frames_at(self, s: FloatArray) -> FloatArray:
        """(M, 3, 3) at arc lengths ``s`` (M,), columns: along the path (its tangent), across
        it (lateral), the third (height)."""
        d = _tangents(self.weld, np.asarray(s, dtype=np.float64))
        up = self.sensor2base[:3, 2]
        lat = np.cross(up, d)
        lat /= np.linalg.norm(lat, axis=1)[:, None]
        out: FloatArray = np.stack([d, lat, np.cross(d, lat)], axis=-1)
        return out

    def frames(self) -> FloatArray:
        """(N, 3, 3): :meth:`frames_at` the laser's nominal place at each cycle."""
        return self.frames_at(self.weld.s_at(self.times))

    def window(self) -> FloatArray:
        """(N,) bool: the cycles with the laser on."""
        s = self.weld.s_at(self.times)
        return np.asarray((s >= self.laser_from_mm) & (s <= self.laser_to_mm))


@dataclass(frozen=True)
class PathPass:
    """A job's path to learn: the laser through ``vertices`` (K, 3) (base frame, mm) with the
    tool's ``angles`` (3,) (deg) throughout, at ``speed_mm_s``; ``arcs`` (K - 1, 3) the
    middle point of each segment that is an ``<arc>`` (NaN rows for lines; None: lines
    only). Corners between lines are rounded with R 32 mm, an arc is tangent to what is
    beside it (:class:`~welding.tracking.PolylineWeld`)."""

    vertices: FloatArray
    angles: FloatArray
    speed_mm_s: float
    name: str = ""
    arcs: FloatArray | None = None

    @property
    def start(self) -> FloatArray:
        out: FloatArray = self.vertices[0]
        return out

    @property
    def straight(self) -> bool:
        """One line."""
        return len(self.vertices) == 2 and (self.arcs is None or bool(np.isnan(self.arcs).all()))

    def weld(self) -> PolylineWeld:
        """The path itself at its speed (CornerError when it cannot be rounded or kinks)."""
        return PolylineWeld(self.vertices, self.angles, self.speed_mm_s, arcs=self.arcs)

    @property
    def length_mm(self) -> float:
        """The laser's path length (mm), corners rounded."""
        if self.straight:
            return float(np.linalg.norm(self.vertices[1] - self.vertices[0]))
        return self.weld().length_mm

    @property
    def key(self) -> str:
        """What a table learned on this pass is for (:attr:`IlcTable.key`): every vertex (and
        every arc's middle point), the angles and the speed, 0.01 mm, deg (``line …`` for one
        line, ``path …``)."""
        mids = np.zeros(0) if self.arcs is None else self.arcs[~np.isnan(self.arcs[:, 0])].ravel()
        nums = [*self.vertices.ravel(), *mids, *self.angles, self.speed_mm_s]
        kind = "line" if self.straight else "path"
        return f"{kind} " + " ".join(f"{v:.2f}" for v in nums)


def job_path(job: J.Job, name: str | None) -> J.Path:
    """The path ``name`` of ``job``, default its only path; ValueError naming the paths."""
    paths = [it for it in job.items if isinstance(it, J.Path)]
    found = paths if name is None else [p for p in paths if p.name == name]
    if len(found) != 1:
        names = ", ".join(p.name for p in paths) or "none"
        what = "name the path to learn (--path)" if name is None else f"no path {name!r}"
        raise ValueError(f"job {job.name!r}: {what}; its paths: {names}")
    return found[0]


def check_learnable(path: J.Path) -> None:
    """ValueError, one line naming what is not supported, when the ILC cannot learn ``path``:
    it learns ``<line>`` and ``<arc>`` segments (the corners between lines rounded as a
    tracked path's, :class:`~welding.tracking.PolylineWeld`) with one tool. Needs no tool
    table: checked before a cell is built or control taken."""
    if not path.segments:
        raise ValueError(f"path {path.name!r} has no segment: no pass to learn")
    for loc in path.locations():
        if loc.tool != path.start.tool:
            raise ValueError(
                f"path {path.name!r} changes tool ({path.start.tool} to {loc.tool}): the ILC"
                " learns a path of one tool"
            )


def path_pass(path: J.Path, tables: Tables) -> PathPass:
    """A job's ``path`` as a :class:`PathPass`, its tool and frame from ``tables``;
    ValueError when it changes tool or orientation (:func:`check_learnable`) or cannot be
    followed (:class:`~welding.tracking.CornerError`: a corner whose rounding does not fit, an
    arc not tangent to what is beside it; naming the job's point)."""
    check_learnable(path)

    def pose(loc: J.Location) -> FloatArray:
        out: FloatArray = location_to_transform(
            np.array(tables.frame(loc.frame).location, dtype=np.float64)
        ) @ location_to_transform(np.array(loc.values, dtype=np.float64))
        return out

    first = pose(path.start)
    locations = list(path.locations())
    for k, loc in enumerate(locations[1:], 2):
        _check_orientation(path.name, first, pose(loc), k, len(locations) == 2)
    vertices = [first[:3, 3]] + [pose(seg.to)[:3, 3] for seg in path.segments]
    arcs = [
        pose(seg.mid)[:3, 3] if isinstance(seg, J.Arc) else np.full(3, np.nan)
        for seg in path.segments
    ]
    angles = transform_to_location(first)[3:]
    one = PathPass(
        np.array(vertices),
        np.asarray(angles),
        path.velocity,
        path.name,
        np.array(arcs) if any(isinstance(seg, J.Arc) for seg in path.segments) else None,
    )
    try:
        length = one.length_mm
    except CornerError as exc:
        raise ValueError(f"path {path.name!r}, point {exc.corner + 1}: {exc}") from None
    if length < 1.0:
        raise ValueError(f"path {path.name!r}: {length:.2f} mm is no pass to learn")
    return one


def _check_orientation(name: str, first: FloatArray, pose: FloatArray, k: int, one: bool) -> None:
    """ValueError unless ``pose`` (point ``k`` of path ``name``) keeps ``first``'s
    orientation."""
    turn = first[:3, :3].T @ pose[:3, :3]
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(turn) - 1.0) / 2.0))))
    if angle > 0.01:
        where = "along it" if one else f"to point {k}"
        raise ValueError(
            f"path {name!r}: the tool turns {angle:.2f} deg {where}; the ILC learns a"
            " path that keeps the orientation"
        )


Judge = Callable[[TrackOutcome, PassGeometry], tuple[float, float, FloatArray]]


def run_ilc(
    client: FramedClient,
    sensor_endpoint: tuple[str, int],
    settings: IlcSettings,
    judge: Judge,
    *,
    laser_tool: Loc,
    sensor_tool: Loc,
    table: IlcTable | None = None,
    save: Callable[[IlcTable], None] | None = None,
    progress: Callable[[IlcTrial], None] | None = None,
    record: Callable[[], None] | None = None,
    job_pass: PathPass | None = None,
    real_time: bool = False,
) -> tuple[list[IlcTrial], Convergence, IlcTable]:
    """Run the trials on the robot of ``client`` (its sensor's trigger address
    ``sensor_endpoint``): refuse a learning that diverges (:class:`LearningDiverges`,
    before control is taken), take control, teach the seam unless ``table`` brings it, then
    ``trials`` passes, each judged by ``judge(outcome, geometry)`` -> (truth max, truth rms,
    profile) after ``record()`` was called before it; the table is handed to ``save`` after
    every trial. With ``track``, one tracked weld with the learned table follows (none after
    a stopped trial), the last of the trials returned. ``job_pass``: a job's path (its speed
    and length, not ``settings``'); without it, the cell's pass from where the arm stands.
    ``real_time``: the robot runs on the wall clock (:class:`RobotLink`). A trial whose
    measurement cannot be trusted (:func:`trial_trust`) is returned with the reason and not
    learned from: the next repeats its table."""
    settings.check()
    period = 0.004
    link = RobotLink(client, sensor_endpoint, period=period, real_time=real_time)
    info = client.call(CommandId.HELLO, wire.VERSION_MAJOR, wire.VERSION_MINOR, "ilc")
    model = get_model(str(info[3]))
    geometry = _geometry(link, laser_tool, sensor_tool, settings, job_pass)
    key = "" if job_pass is None else job_pass.key
    speed = geometry.weld.speed_mm_s
    n = len(geometry.times)
    q_start = client.call(CommandId.HEREJ)[0]
    assert isinstance(q_start, Joints)
    laser2flange = location_to_transform(np.array(laser_tool, dtype=np.float64))
    sensor2flange = location_to_transform(np.array(sensor_tool, dtype=np.float64))
    q_path = _joints_along(model, geometry, laser2flange, np.array(q_start.values))
    params = settings.params.with_payload(settings.model_payload_kg)
    side = "link" if settings.source == "seam" else "motor"
    G = lifted_model_along(
        params,
        model,
        q_path,
        laser2flange,
        period,
        side=side,
        latency_s=settings.latency_s,
        block=settings.model_block_cycles or None,
    )
    R = geometry.frames()  # (N, 3, 3): each cycle's (along, lateral, height)
    Gp = _in_frames(G, R)
    # learned over the whole pass (the lead-in onto the seam matters for the weld's start),
    # from the cycles where the error was measured
    mask = np.ones(3 * n)
    if settings.source == "seam":
        mask[0::3] = 0.0  # the sensor sees nothing along the seam
    L = learning_matrix(Gp, settings.gain, mask, settings.beta)
    Q = q_filter(n, settings.q_hz, period)
    conv = check_convergence(Q, L, Gp)
    if not conv.converges:
        raise LearningDiverges(
            f"the learning would diverge: |Q(1 - L·G)| = {conv.norm:.3f} >= 1 for the model"
            f" (gain {settings.gain:g}, Q {settings.q_hz:g} Hz): lower --gain"
        )
    if table is not None:
        _check_table(table, n, speed, key)
        taught, u, seen_error = table.seam, table.correction.copy(), table.seen
        done = table.trials
    client.take_control(watchdog=LEASE_S)
    client.call(CommandId.ENABLE_POWER)
    if job_pass is not None:
        _back_to_start(client, geometry)  # the cell's pass starts where the arm stands
    if table is None:
        taught = _teach(link, geometry, settings)
        u = np.zeros((n, 3))
        seen_error = np.zeros((0, 4))
        done = 0
    first = done
    seam_of = IlcTable(period, speed, u, taught, settings.source, done, key)
    reference = seam_of.offsets(geometry.weld.s_at(geometry.times))
    trials: list[IlcTrial] = []
    for j in range(1, settings.trials + 1):
        _back_to_start(client, geometry)
        if record is not None:
            record()
        tracker = Tracker(geometry.weld, geometry.look_ahead_mm)
        plan = TrackedWeld(
            tracker,
            laser_tool,
            geometry.laser_from_mm,
            geometry.laser_to_mm,
            settings.rate_hz,
            False,
            feedforward=_feedforward(geometry.times, reference + u),
        )
        outcome = weld_tracked(link, plan)
        truth_max, truth_rms, profile = judge(outcome, geometry)
        checks, log_rows = _checked(client, model, outcome, geometry, settings, period)
        untrusted = checks.reason
        e_base = (
            _seam_error(
                geometry,
                outcome,
                seam_of.offsets,
                _along(geometry, seam_of.offsets),
                settings.latency_s,
                _lever_error(
                    model, params, geometry, reference + u, laser2flange, sensor2flange, q_path[0]
                ),
            )
            if settings.source == "seam"
            else _joint_error(model, geometry, outcome, reference, log_rows)
        )
        e_path = np.einsum("kc,kca->ka", e_base, R)  # rows in (along, lateral, height)
        seen = mask * np.repeat(np.any(e_base != 0.0, axis=1), 3)
        window = np.repeat(geometry.window(), 3) * seen
        measured = float(np.abs(e_path.ravel() * window).max()) if n else math.nan
        trial = IlcTrial(
            first + j,
            truth_max,
            truth_rms,
            math.nan if untrusted else measured,
            float(np.linalg.norm(u, axis=1).max()),
            outcome.stopped,
            profile,
            untrusted=untrusted,
            checks=checks,
        )
        trials.append(trial)
        if progress is not None:
            progress(trial)
        if outcome.stopped:
            break
        if untrusted:
            # the next trial repeats this one's table: a correction learned from data that
            # cannot be trusted would be a plausible wrong one
            continue
        seen_error = _seen_error(
            geometry, outcome, taught, _along(geometry, seam_of.offsets), settings.latency_s
        )
        up = np.einsum("kc,kca->ka", u, R).ravel()
        w = settings.weight_after(first + j)
        up = ilc_update(up, e_path.ravel() * seen, Q, L, w)
        u = np.einsum("ka,kca->kc", up.reshape(n, 3), R)
        learned = IlcTable(period, speed, u, taught, settings.source, first + j, key, seen_error)
        if save is not None:
            save(learned)
    if settings.track and not (trials and trials[-1].stopped):
        _back_to_start(client, geometry)
        if record is not None:
            record()
        plan = _tracked_plan(geometry, settings, taught, u, sensor_tool, seen_error)
        outcome = weld_tracked(link, plan)
        truth_max, truth_rms, profile = judge(outcome, geometry)
        checks, _ = _checked(client, model, outcome, geometry, settings, period)
        trials.append(
            IlcTrial(
                first + len(trials) + 1,
                truth_max,
                truth_rms,
                math.nan,
                float(np.linalg.norm(u, axis=1).max()),
                outcome.stopped,
                profile,
                tracked=True,
                untrusted=checks.reason,
                checks=checks,
            )
        )
        if progress is not None:
            progress(trials[-1])
    run = sum(1 for t in trials if not t.tracked)
    learned = IlcTable(period, speed, u, taught, settings.source, first + run, key, seen_error)
    return trials, conv, learned


@dataclass(frozen=True)
class TrialChecks:
    """What a trial's data is worth (:func:`trial_trust`): ``reason`` why it cannot be
    trusted ("" when it can), and the counts it was judged by."""

    reason: str
    #: corrections that reached the robot after their cycle during the laser's part
    late: int
    #: cycles the robot held a correction because the next had not come
    held: int
    start_on_grid: bool
    #: joint log samples missing over the move (-1: the log does not cover it)
    joint_log_missing: int
    #: the longest stretch of the laser's part without a sensor reading (ms; seam source)
    reading_gap_ms: float | None
    #: readings the robot placed later for a late exposure (:func:`placed_later`; seam
    #: source): counted, not left out, since their t_S is their exposure's [SY-3.8]
    late_readings: int = 0
    #: the start cycle, not known when the move was queued, found from the joint log
    #: (:func:`start_from_joint_log`): the cycles after the one the corrections were timed
    #: for (0: that one), None where not needed or not found
    start_found: int | None = None

    def summary(self) -> dict[str, object]:
        return {
            "late_corrections": self.late,
            "held_cycles": self.held,
            "start_on_grid": self.start_on_grid,
            "joint_log_missing": self.joint_log_missing,
            "reading_gap_ms": self.reading_gap_ms,
            "late_readings": self.late_readings,
            "start_found": self.start_found,
        }


def trial_trust(
    outcome: TrackOutcome,
    g: PassGeometry,
    settings: IlcSettings,
    joint_log: FloatArray,
    period: float,
    start_found: int | None = None,
) -> TrialChecks:
    """Whether a trial's data can be trusted, from the robot's stamps and counts only (never
    from when this process ran): not when corrections reached the robot after their cycle
    during the laser's part or it had to hold one, when the cycle the move started on is not
    known exactly (every error is placed on the grid from it), when joint log samples are
    missing over the move (``joint_log`` rows (t, q (6,))), or, for the seam source, when
    the sensor's readings over the laser's part are more than :data:`GAP_TRIGGERS` trigger
    periods apart somewhere. ``start_found``: where the queued move's start cycle was not
    known, the one :func:`start_from_joint_log` found (cycles after the one the corrections
    were timed for; 0 is that one), None for not found."""
    reasons: list[str] = []
    v = outcome.verdict
    late, held = (v.late, v.held) if v is not None else (0, 0)
    if late:
        reasons.append(f"{late} corrections reached the robot after their cycle during the"
                       " laser's part")  # fmt: skip
    if held:
        reasons.append(f"the robot held a correction for {held} cycles")
    if not outcome.start_on_grid and start_found is None:
        reasons.append("the cycle the move started on is not known exactly")
    elif not outcome.start_on_grid and start_found:
        reasons.append(f"the move started {start_found} cycles after the one its corrections"
                       " were timed for")  # fmt: skip
    t_end = outcome.t0 + float(g.times[-1])
    t = joint_log[:, 0] if len(joint_log) else np.zeros(0)
    if not len(t) or t[0] > outcome.t0 + 1e-6 or t[-1] < t_end - 1e-6:
        missing = -1
        reasons.append("the joint log does not cover the move")
    else:
        steps = np.round(np.diff(t[(t >= outcome.t0 - period) & (t <= t_end + period)]) / period)
        missing = int(np.sum(steps - 1))
        if missing:
            reasons.append(f"{missing} joint log samples missing over the move")
    gap_ms, dropped = None, 0
    if settings.source == "seam":
        if len(outcome.rows):
            dropped = int(np.count_nonzero(placed_later(outcome.rows)))
        gap, at = _reading_gap(outcome, g, settings.latency_s)
        gap_ms = round(gap * 1e3, 3)
        if gap > GAP_TRIGGERS / settings.rate_hz:
            reasons.append(f"no sensor reading for {gap * 1e3:.0f} ms at {at:.1f} mm of the weld")
    return TrialChecks(
        "; ".join(reasons),
        late,
        held,
        outcome.start_on_grid,
        missing,
        gap_ms,
        dropped,
        None if outcome.start_on_grid else start_found,
    )


#: The later start cycles :func:`start_from_joint_log` weighs (the stand's reply can be a few
#: cycles late; its send was not).
START_CYCLES = 4


def start_from_joint_log(
    outcome: TrackOutcome,
    g: PassGeometry,
    joint_log: FloatArray,
    model: RobotModel,
    latency_s: float,
    period: float,
) -> int | None:
    """The cycle a queued move started on when the robot's reply did not tell (a reply that
    came in a later cycle than the request was sent in: the robot took it in one of them),
    from the joint log's own grid stamps: how many cycles after ``outcome.t0`` (the earliest
    possible) it started, or None when the log does not tell.

    Along the line the motors follow their setpoint to within a small servo lag (velocity
    feedforward and an integral), and the log lags them by the encoder latency, so at the
    pass's constant speed the log is ``latency_s`` plus that lag behind the nominal law (2.3
    ms against 2.8 on the emulated elastic arm, scatter 0.7 ms); each cycle of start
    hypothesis moves that by 4 ms. The start whose lag lies within half a cycle of
    ``latency_s`` is the one; none or two: None."""
    if not len(joint_log):
        return None
    v = g.weld.speed_mm_s
    laser = laser_path(model, joint_log[:, 1:], g.laser_tool)
    s_meas = g.weld.project(laser)
    ramp = v / g.weld.accel_mm_s2
    found = []
    for m in range(START_CYCLES):
        t = joint_log[:, 0] - (outcome.t0 + m * period)
        steady = (t > ramp + 0.05) & (t < g.weld.duration - ramp - 0.05)
        if np.count_nonzero(steady) < 10:
            return None
        lag = float(np.mean(g.weld.s_at(t[steady]) - s_meas[steady])) / v
        if abs(lag - latency_s) < period / 2:
            found.append(m)
    return found[0] if len(found) == 1 else None


def placed_later(rows: FloatArray) -> npt.NDArray[np.bool_]:
    """(M,) bool: the seam points ``rows`` (GetSeamPoints) the robot placed later than t_T +
    ΔT, by the extra lag of an exposure their sensor started late [SY-3.8] (a trigger sent
    right after another reaches a sensor still busy with the last frame: up to 3.2 ms beside
    CPU hogs, 0.8 mm along the seam at 250 mm/s). ΔT is the median of t_S - t_T (most
    readings are on time). Such a reading's t_S is its exposure's, so it is used; this only
    counts them."""
    if not len(rows):
        return np.zeros(0, dtype=bool)
    lag = rows[:, 2] - rows[:, 1]
    later: npt.NDArray[np.bool_] = lag - float(np.median(lag)) > PLACED_LATER_FLOOR_S
    return later


def _readings(outcome: TrackOutcome) -> FloatArray:
    """The seam points of ``outcome`` that found the seam."""
    rows = outcome.rows
    if not len(rows):
        return rows
    kept: FloatArray = rows[rows[:, 3] == 0]
    return kept


def _reading_gap(outcome: TrackOutcome, g: PassGeometry, latency_s: float) -> tuple[float, float]:
    """The longest stretch (s) of the laser's part without a sensor reading (the readings at
    their exposure, as :func:`_seam_error` places them) and where it starts (mm of the
    weld)."""
    w = g.times[g.window()]
    if not len(w):
        return 0.0, 0.0
    rows = _readings(outcome)
    t = np.sort(rows[:, 2] - latency_s - outcome.t0) if len(rows) else np.zeros(0)
    pts = np.concatenate([[w[0]], t[(t > w[0]) & (t < w[-1])], [w[-1]]])
    gaps = np.diff(pts)
    i = int(np.argmax(gaps))
    return float(gaps[i]), float(g.weld.s_at(pts[i])) - g.laser_from_mm


def _check_table(table: IlcTable, n: int, speed_mm_s: float, key: str) -> None:
    """ValueError when ``table`` is not for this pass (``n`` cycles at ``speed_mm_s``,
    ``key``)."""
    if table.correction.shape != (n, 3) or not math.isclose(table.speed_mm_s, speed_mm_s):
        raise ValueError(
            f"the table is for {len(table.correction)} cycles at {table.speed_mm_s:g} mm/s,"
            f" this pass has {n} at {speed_mm_s:g} mm/s"
        )
    if table.key != key:
        raise ValueError(
            f"the table was learned on {table.key or 'the cell pass'}, this pass is"
            f" {key or 'the cell pass'}: remove it to learn this one"
        )


def _tracked_plan(
    g: PassGeometry,
    settings: IlcSettings,
    taught: FloatArray,
    u: FloatArray,
    sensor_tool: Loc,
    seen_error: FloatArray,
) -> TrackedWeld:
    """A tracked weld with the learned table: the tracker follows the workpiece's deviation
    from the seam as the sensor saw it in the last trial learned from (``seen_error`` off
    the taught one, :func:`_seen_error`; the taught seam where none was:
    :attr:`Tracker.expected`; a wide fit: a placement error is smooth, the arm's fast error
    is the table's), from the sensor's readings placed on the sensor's reference pose; the
    correction sent is the taught seam, that deviation and the table."""
    tracker = Tracker(
        g.weld,
        g.look_ahead_mm,
        fit_half_width_mm=settings.track_fit_mm,
        taught=OffsetWeld(g.weld, taught),
        expected=OffsetWeld(g.weld, _seen_seam(taught, seen_error)) if len(seen_error) else None,
    )
    return TrackedWeld(
        tracker,
        g.laser_tool,
        g.laser_from_mm,
        g.laser_to_mm,
        settings.rate_hz,
        True,
        feedforward=_feedforward(g.times, u),
        sensor_tool=sensor_tool,
        exposure_lag_s=settings.latency_s,
    )


def _geometry(
    link: RobotLink,
    laser_tool: Loc,
    sensor_tool: Loc,
    settings: IlcSettings,
    job_pass: PathPass | None = None,
) -> PassGeometry:
    """The ``track`` pass from where the arm stands (as :func:`welding.emulate._track_on`),
    or a job's path: the motion starts the sensor's look-ahead before the path's start
    (along its first line), so the sensor has seen the seam where the laser starts, and runs
    out along its last line. ValueError when the sensor would not see the path through one
    of its corners (:func:`~welding.tracking.check_sensor_view`, naming the job's point)."""
    if job_pass is None:
        start = np.array(link.here(laser_tool))
    else:
        start = np.concatenate([job_pass.start, job_pass.angles])
    laser2flange = location_to_transform(np.array(laser_tool, dtype=np.float64))
    sensor2laser = np.linalg.inv(laser2flange) @ location_to_transform(
        np.array(sensor_tool, dtype=np.float64)
    )
    s2b = location_to_transform(start) @ sensor2laser
    if job_pass is None:
        direction = s2b[:3, 0]
    elif job_pass.straight:
        v = job_pass.vertices
        direction = (v[1] - v[0]) / np.linalg.norm(v[1] - v[0])
    else:
        direction = job_pass.weld().direction
    look_ahead = float((s2b[:3, 3] - start[:3]) @ direction)
    weld_mm, speed = settings.weld_mm, settings.speed_mm_s
    if job_pass is not None:
        if look_ahead < 10.0:
            raise ValueError(
                f"the sensor is {look_ahead:.1f} mm ahead of the laser along the path: the"
                " ILC learns a path the sensor looks ahead on (10 mm at least)"
            )
        weld_mm, speed = job_pass.length_mm, job_pass.speed_mm_s
        before = look_ahead + settings.run_up_mm
        start = np.concatenate([job_pass.start - before * direction, job_pass.angles])
        s2b = location_to_transform(start) @ sensor2laser
    ramp_mm = speed**2 / (2.0 * 2500.0)
    laser_from = look_ahead + settings.run_up_mm
    weld: NominalWeld | PolylineWeld
    if job_pass is None or job_pass.straight:
        weld = NominalWeld(
            start=start[:3],
            direction=direction,
            angles=start[3:],
            length_mm=laser_from + weld_mm + ramp_mm + 1.0,
            speed_mm_s=speed,
        )
    else:
        weld = _polyline(job_pass, start[:3], ramp_mm + 1.0, s2b)
    times, _ = weld.timed_path(link.period)
    return PassGeometry(weld, laser_tool, s2b, look_ahead, laser_from, laser_from + weld_mm, times)


def _polyline(
    job_pass: PathPass, start: FloatArray, run_out_mm: float, sensor2base: FloatArray
) -> PolylineWeld:
    """The pass of a job's path: from ``start`` onto the path along its first tangent,
    through it, ``run_out_mm`` on along its last; the sensor (^B_S T at the start) must see
    the path all along."""
    own = job_pass.weld()
    h = min(1e-3, own.length_mm / 4)
    last = own.point(own.length_mm) - own.point(own.length_mm - h)
    last /= np.linalg.norm(last)
    v = job_pass.vertices
    arcs = None
    if job_pass.arcs is not None:
        none = np.full((1, 3), np.nan)
        arcs = np.vstack([none, job_pass.arcs, none])
    weld = PolylineWeld(
        np.vstack([start, v, v[-1] + run_out_mm * last]),
        job_pass.angles,
        job_pass.speed_mm_s,
        arcs=arcs,
    )
    try:
        check_sensor_view(weld, sensor2base[:3, 3] - start, sensor2base[:3, 0], sensor2base[:3, 1])
    except CornerError as exc:  # vertex k of the pass is the job's point k (the start is 0)
        point = min(max(exc.corner, 1), len(v))
        raise ValueError(f"path {job_pass.name!r}, point {point} of the path: {exc}") from None
    return weld


def _back_to_start(client: FramedClient, g: PassGeometry) -> None:
    """A straight move back to the pass's start (where the last pass, or teaching, ended)
    and the wait until the arm stands there."""
    start = np.concatenate([g.weld.start, g.weld.angles])
    client.call(
        CommandId.TOOL_MOVE_L,
        Location(*(float(v) for v in start)),
        Location(*g.laser_tool),
        IDENTITY_LOCATION,
    )
    client.call(CommandId.WAIT_END_MOVE, 60.0, timeout=120.0)


def _joints_along(
    model: RobotModel,
    g: PassGeometry,
    laser2flange: FloatArray,
    near: FloatArray,
    correction: FloatArray | None = None,
) -> FloatArray:
    """The joints (N, 6) with the laser on the nominal pass at each cycle, moved by
    ``correction`` (N, 3) where given (each solution the one nearest the last, the first
    nearest ``near``)."""
    pts = g.weld.point(g.weld.s_at(g.times))
    if correction is not None:
        pts = pts + correction
    tool2flange = np.linalg.inv(laser2flange)
    out = np.empty((len(pts), 6))
    q = near
    for k, p in enumerate(pts):
        flange = location_to_transform(np.concatenate([p, g.weld.angles])) @ tool2flange
        q = model.ik(flange, near=q)[0].joints_deg
        out[k] = q
    return out


def _in_frames(G: FloatArray, R: FloatArray) -> FloatArray:
    """G (3N, 3N) of base-frame translations in each cycle's frame ``R`` (N, 3, 3) instead:
    Rᵀ G R with R block-diagonal."""
    n = len(R)
    G4 = G.reshape(n, 3, n, 3)
    out: FloatArray = np.einsum("kca,kcmd,mdb->kamb", R, G4, R, optimize=True).reshape(G.shape)
    return out


def _tangents(weld: WeldPath, s: FloatArray) -> FloatArray:
    """Unit tangents (M, 3) of the nominal path at arc lengths ``s`` (M,): a line's
    direction, else a central difference over 0.01 mm."""
    if isinstance(weld, NominalWeld):
        return np.tile(weld.direction, (len(s), 1))
    h = 5e-3
    d = weld.point(s + h) - weld.point(s - h)
    out: FloatArray = d / np.linalg.norm(d, axis=1)[:, None]
    return out


def _lever_error(
    model: RobotModel,
    params: ElasticParams,
    g: PassGeometry,
    correction: FloatArray,
    laser2flange: FloatArray,
    sensor2flange: FloatArray,
    near: FloatArray,
) -> FloatArray:
    """:func:`welding.ilc.lever_error` (N, 3) of the pass commanded with ``correction``
    (N, 3): the laser on the nominal path plus it at each cycle, the path's orientation."""
    q = _joints_along(model, g, laser2flange, near, correction)
    period = float(g.times[1] - g.times[0])
    return lever_error(params, model, np.vstack([q[:1], q]), laser2flange, sensor2flange, period)


def _sampled(seam: SeamModel) -> FloatArray:
    """``seam``'s fit, rows (arc length, offset (3,)) every 0.5 mm where it is measured."""
    rows = []
    if seam.count:
        for s in np.arange(math.ceil(seam.first), seam.furthest, 0.5):
            with contextlib.suppress(TrackingError):
                rows.append([s, *seam.offset_at(float(s))])
    return np.array(rows, dtype=np.float64).reshape(-1, 4)


def _feedforward(times: FloatArray, table: FloatArray) -> Callable[[float], FloatArray]:
    """The correction (6,) at a time since the move's start: the table (N, 3) linear
    between its cycles, its ends held."""

    def at(t: float) -> FloatArray:
        out = np.zeros(6)
        for c in range(3):
            out[c] = np.interp(t, times, table[:, c])
        return out

    return at


def _along(
    g: PassGeometry, offsets: Callable[[FloatArray], FloatArray]
) -> Callable[[FloatArray], FloatArray]:
    """The laser's reference offsets (M, 3) at times (M,) s since the move's start: the
    seam ``offsets`` at the laser's nominal arc length."""

    def at(t: FloatArray) -> FloatArray:
        return offsets(g.weld.s_at(t))

    return at


def _teach(link: RobotLink, g: PassGeometry, settings: IlcSettings) -> FloatArray:
    """A dry pass at the teaching speed with the sensor measuring the seam (the laser off):
    the seam taught, rows (arc length, offset (3,)) every 0.5 mm where it was measured."""
    slow = replace(g.weld, speed_mm_s=settings.teach_speed_mm_s)
    tracker = Tracker(slow, g.look_ahead_mm)
    plan = TrackedWeld(
        tracker, g.laser_tool, g.laser_from_mm, g.laser_to_mm, settings.rate_hz,
        track=False, laser=False,
    )  # fmt: skip
    outcome = weld_tracked(link, plan)
    if outcome.stopped:
        raise TrackingError(f"teaching the seam failed: {outcome.stopped}")
    seam = SeamModel(slow)
    seam.add(_readings(outcome)[:, 11:14])
    rows = _sampled(seam)
    _check_taught(g, rows[:, 0])
    lead_in = np.array(_lead_in(rows), dtype=np.float64).reshape(-1, 4)
    log.info("seam taught from %d points over %.0f..%.0f mm", seam.count, seam.first,
             seam.furthest)  # fmt: skip
    return np.vstack([lead_in, rows])


#: The taught seam may miss this much (mm) of the laser's part at its start (the rows begin
#: on the next whole mm after the first reading) or inside it (two rows 0.5 mm apart).
TAUGHT_GAP_MM = 2.0


class SeamNotTaught(ValueError):
    """The teaching pass did not see the seam all along the laser's part of the pass."""


def _check_taught(g: PassGeometry, s: FloatArray) -> None:
    """:class:`SeamNotTaught`, one line, unless the taught seam's rows (arc lengths ``s``)
    cover the laser's part of the pass: the sensor lost the seam somewhere (the pass keeps
    the tool's orientation, so a seam turning away from the sensor's x axis leaves its
    field). Names the first stretch not seen."""
    inside = s[(s >= g.laser_from_mm) & (s <= g.laser_to_mm)]
    pts = np.concatenate([[g.laser_from_mm], inside, [g.laser_to_mm]])
    holes = np.nonzero(np.diff(pts) > TAUGHT_GAP_MM)[0]
    if len(holes):
        i = int(holes[0])
        raise SeamNotTaught(
            f"the sensor did not see the seam over {pts[i] - g.laser_from_mm:.1f} to"
            f" {pts[i + 1] - g.laser_from_mm:.1f} mm of the weld while teaching it: the pass"
            " keeps the tool's orientation, so the seam must stay within the sensor's field"
            f" {g.look_ahead_mm:.0f} mm ahead of the laser"
        )


#: The reference leaves the seam's start tangentially over this (mm) before the first point
#: the sensor measured (the laser's weld starts there): a path that takes up the seam's
#: slope with a bounded curvature instead of a kink the arm cannot follow.
LEAD_IN_MM = 20.0


def _lead_in(rows: FloatArray) -> list[list[float]]:
    """Rows before ``rows`` (arc length, offset (3,)): a parabola from a standstill offset
    LEAD_IN_MM before the first row to its offset and slope there."""
    s0, e0 = rows[0, 0], rows[0, 1:]
    slope = (rows[2, 1:] - rows[0, 1:]) / (rows[2, 0] - rows[0, 0])
    out = []
    for s in np.arange(s0 - LEAD_IN_MM, s0, 0.5):
        x = s - s0
        out.append([float(s), *(e0 + slope * x + slope / (2 * LEAD_IN_MM) * x * x)])
    return out


def _seam_error(
    g: PassGeometry,
    outcome: TrackOutcome,
    offsets: Callable[[FloatArray], FloatArray],
    reference: Callable[[FloatArray], FloatArray],
    latency_s: float,
    lever: FloatArray,
) -> FloatArray:
    """(N, 3) reference − actual of the laser, base frame, from the sensor's ^S_G T: what it
    read of the seam ``offsets`` (taught) against what it would read with the laser on its
    ``reference`` (offsets (M, 3) from the nominal path at times (M,) since the move's
    start; the tool keeps its orientation, so the laser moved as the sensor did); zero
    where it read nothing.

    The sensor reads the seam where it crosses its laser plane: a tool off by d moves that
    reading by P d, P the projection onto the plane along the seam's tangent there (a
    seam crossing the plane obliquely shows a move along the path as one across it). Along
    the path the laser's own error is not seen; the laser is taken to be off across its
    path (lateral, height at its cycle's frame) by what explains the reading. The sensor saw
    where it went, not the laser: ``lever`` (N, 3), the model's laser error less its
    sensor's (:func:`_lever_error`), is what the laser went further.
    ``latency_s``: the joint log's lag; a seam point's time (t_sync = trigger + ΔT, plus the
    extra lag of an exposure started late [SY-3.8]) is where the *measured* joints saw the
    image, the exposure itself was that much earlier."""
    n = len(g.times)
    reading = _sensor_reading(g, outcome, offsets, reference, latency_s)
    if reading is None:
        return np.zeros((n, 3))
    t, s_l, _, tangent, deviation = reading
    normal = g.sensor2base[:3, 0]
    # P = I - t nᵀ / (t·n); the laser's error across its path that P maps onto the reading
    frames = g.frames_at(s_l)[:, :, 1:]  # (M, 3, 2) lateral, height
    along = (frames.transpose(0, 2, 1) @ normal)[:, None, :]  # (M, 1, 2) n·lateral, n·height
    A = frames - tangent[:, :, None] * along / (tangent @ normal)[:, None, None]
    AtA = np.einsum("mci,mcj->mij", A, A)
    Atd = np.einsum("mci,mc->mi", A, deviation)
    across = np.linalg.solve(AtA, Atd[..., None])[..., 0]  # (M, 2) lateral, height
    actual = np.einsum("mci,mi->mc", frames, across)  # actual - reference, base frame
    out = np.zeros((n, 3))
    inside = (g.times >= t.min()) & (g.times <= t.max())
    for c in range(3):
        out[inside, c] = -np.interp(g.times[inside], t, actual[:, c]) - lever[inside, c]
    return out


def _sensor_reading(
    g: PassGeometry,
    outcome: TrackOutcome,
    offsets: Callable[[FloatArray], FloatArray],
    reference: Callable[[FloatArray], FloatArray],
    latency_s: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray] | None:
    """The sensor's readings of the trial against the seam ``offsets`` it would read with the
    laser on its ``reference`` (:func:`_seam_error`): (exposure times (M,) s since the move's
    start, the laser's arc lengths (M,), the seam's where it crossed the laser plane (M,),
    its tangents there (M, 3), expected − measured (M, 3), base frame), by exposure; None
    with fewer than two readings."""
    rows = _readings(outcome)
    rows = rows[rows[:, 2] >= outcome.t0]
    rows = rows[np.argsort(rows[:, 2], kind="stable")]  # by exposure, for the interpolation
    if len(rows) < 2:
        return None
    t = rows[:, 2] - latency_s - outcome.t0  # the exposure, robot clock, since the start
    s_l = g.weld.s_at(t)
    a = g.sensor2base[:3, 3] - g.weld.point(0.0)  # laser -> sensor, base frame
    sensor = g.weld.point(s_l) + reference(t) + a
    normal = g.sensor2base[:3, 0]  # of the sensor's laser plane

    def seam(s: FloatArray) -> FloatArray:
        out: FloatArray = g.weld.point(s) + offsets(s)
        return out

    s_c, tangent = _crossing(seam, sensor, normal, s_l + g.look_ahead_mm)
    expected = seam(s_c) - sensor
    measured = rows[:, 5:8] @ g.sensor2base[:3, :3].T
    return t, s_l, s_c, tangent, expected - measured  # P (actual - reference)


def _seen_error(
    g: PassGeometry,
    outcome: TrackOutcome,
    taught: FloatArray,
    reference: Callable[[FloatArray], FloatArray],
    latency_s: float,
) -> FloatArray:
    """Where a tracker placing the sensor's readings on its reference pose would see the
    seam off the ``taught`` one (rows (arc length, offset (3,))) in this trial: the reading
    less what the taught seam gives there (:func:`_sensor_reading`), fitted as the
    teaching's (rows (arc length, error (3,)) every 0.5 mm; empty when it read too little)."""
    on_taught = OffsetWeld(g.weld, taught)
    reading = _sensor_reading(g, outcome, on_taught.offsets, reference, latency_s)
    if reading is None:
        return np.zeros((0, 4))
    _, _, s_c, _, deviation = reading
    seam = SeamModel(on_taught)
    seam.add(on_taught.point(s_c) - deviation)
    return _sampled(seam)


def _seen_seam(taught: FloatArray, error: FloatArray) -> FloatArray:
    """The ``taught`` seam's rows moved by the sensor's ``error`` (:func:`_seen_error`,
    linear between its rows, its ends held): the seam as the sensor sees it on this arm."""
    rows = taught.copy()
    for c in range(3):
        rows[:, 1 + c] += np.interp(rows[:, 0], error[:, 0], error[:, 1 + c])
    return rows


#: Newton steps of :func:`_crossing` (from the look-ahead, a seam within the sensor's field
#: converges in two or three).
CROSSING_STEPS = 4


def _crossing(
    seam: Callable[[FloatArray], FloatArray], sensor: FloatArray, normal: FloatArray, s0: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Arc lengths (M,) where ``seam`` (points (M, 3) at arc lengths) crosses the laser plane
    (``normal`` (3,)) of sensors at ``sensor`` (M, 3), from ``s0`` (M,), and the seam's unit
    tangents (M, 3) there."""
    h = 5e-3
    s = np.asarray(s0, dtype=np.float64)
    for _ in range(CROSSING_STEPS):
        d = (seam(s + h) - seam(s - h)) / (2.0 * h)
        f = (seam(s) - sensor) @ normal
        s = s - f / np.maximum(d @ normal, 0.2)  # a seam at > 78° to the path is not seen
    d = seam(s + h) - seam(s - h)
    tangent: FloatArray = d / np.linalg.norm(d, axis=1)[:, None]
    return s, tangent


def _checked(
    client: FramedClient,
    model: RobotModel,
    outcome: TrackOutcome,
    g: PassGeometry,
    settings: IlcSettings,
    period: float,
) -> tuple[TrialChecks, FloatArray]:
    """The trial's checks (:func:`trial_trust`, the start found from the joint log where the
    reply did not tell it) and its joint log."""
    rows = _joint_log(client, outcome)
    found = None
    if not outcome.start_on_grid:
        found = start_from_joint_log(outcome, g, rows, model, settings.latency_s, period)
    return trial_trust(outcome, g, settings, rows, period, found), rows


def _joint_log(client: FramedClient, outcome: TrackOutcome) -> FloatArray:
    """The joint log (GetJointLog) from just before the trial's move: rows (t, q (6,))."""
    m = client.call(CommandId.GET_JOINT_LOG, float(outcome.t0 - 0.01))[0]
    assert isinstance(m, Matrix)
    return np.array(m.values, dtype=np.float64).reshape(m.rows, m.cols)


def _joint_error(
    model: RobotModel, g: PassGeometry, outcome: TrackOutcome, ref: FloatArray, rows: FloatArray
) -> FloatArray:
    """(N, 3) reference − the laser's path from the measured joints (the joint log's
    ``rows``), base."""
    t = rows[:, 0] - outcome.t0
    laser = laser_path(model, rows[:, 1:], g.laser_tool)
    actual = np.column_stack([np.interp(g.times, t, laser[:, c]) for c in range(3)])
    desired = g.weld.point(g.weld.s_at(g.times)) + ref
    out: FloatArray = desired - actual
    return out
