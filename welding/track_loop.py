"""The seam-tracking loop, one pass per 4 ms controller cycle, shared by ``welding track``
and the processing of a tracked job path (``<path tracked="on">``).

The loop talks to the robot through a :class:`TrackLink`: :class:`RobotLink` is any
RobotSocket server (GetSeamPoints, Alter, ...), on a simulated clock (WaitEndMove of one
cycle advances it) or on a real one (the loop waits for the next cycle on the robot's
clock); the emulated cell also has an in-process link (:mod:`welding.emulate`).

Sequence: triggers on, alter mode on; the arm stands while the sensor measures the seam
where it looks and the laser is brought onto it (``settle_s``); the nominal path starts on
the cycle grid; every cycle the seam points since the last ones, the correction for the
cycle that applies it, the laser on only inside the weld window and only while the tracker
has a valid correction. A lost seam or a silent sensor: laser off first, then the motion is
reset (the arm stops along its path), and the reason is returned.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from kinematics.robot import RobotModel, get_model
from kinematics.transforms import location_to_transform
from kinematics.types import FloatArray, Loc
from spec import params as wire_params
from spec import wire
from spec.errors import ErrorCode, RemoteError
from spec.params import IDENTITY_LOCATION, IntArray, Location, Matrix, Value
from spec.registry import CommandId
from welding.tracking import (
    FIT_HALF_WIDTH_MM,
    MIN_FIT_POINTS,
    TOLERANCE_MM,
    Tracker,
    TrackingError,
    Verdict,
    WeldPath,
    estimate_errors,
    judge,
)

__all__ = ["QueueState", "RobotLink", "TrackLink", "TrackOutcome", "TrackedWeld", "weld_tracked"]

log = logging.getLogger(__name__)

#: The stand before a real-clock tracked path (s, a whole number of 4 ms cycles): long
#: enough for the path to reach the robot and be planned meanwhile (about 15 ms for 1000
#: samples here), short against the 0.1 s alter timeout the loop pauses for.
HOLD_S = 0.048
#: A timed correction is sent once the seam is measured this far beyond its laser point
#: (mm): the whole fit window and a point's spacing, so each cycle's correction is computed
#: once, from the same points as it would be at its cycle.
FINAL_MARGIN_MM = FIT_HALF_WIDTH_MM + 1.0
#: Past the laser's end the seam is followed on this far (mm) where it is measured, then the
#: correction is held: far more than the ~0.2 mm RS-5.34 needs to brake a 63 mm/s one.
FOLLOW_ON_MM = 10.0
#: Timed corrections go on past the move's end this long (s): the robot holds none of the
#: move's cycles, and the counts read just after it are of the weld alone.
TAIL_S = 0.2
#: An untracked weld's corrections (zero, or a learned table) are known before the move: they
#: are queued this far ahead of their cycle (s; 250 entries of the 16 384 RS-5.43 holds), so a
#: loop that stalls for less than this makes none of them late (the real-clock ILC).
UNTRACKED_AHEAD_S = 1.0


@dataclass(frozen=True)
class QueueState:
    """The robot's timed-correction queue as AlterQueue reports it (RS-5.45)."""

    late_total: int
    held_total: int
    horizon: float
    time: float
    #: entries of this batch dropped as late: its first ones (the times increase)
    late: int = 0


class TrackLink(Protocol):
    """What the tracking loop needs of the robot (and its sync service)."""

    period: float
    timed: bool  # the robot takes timed corrections (AlterQueue): set by start()

    def delta_t(self) -> float: ...
    def here(self, tool: Loc) -> Loc: ...
    def start(self, tool: Loc, rate_hz: float) -> int: ...
    def time(self) -> float: ...
    def next_cycle(self) -> float: ...
    def points(self, since: int) -> FloatArray: ...
    def alter(self, correction: FloatArray) -> None: ...
    def queue(self, times: FloatArray, corrections: FloatArray) -> QueueState: ...
    def laser_points(self, tool: Loc, since: float) -> FloatArray: ...
    def step(self) -> None: ...
    def move(self, times: FloatArray, locs: FloatArray, tool: Loc) -> tuple[float, bool]: ...
    def queued(self) -> int: ...
    def set_laser(self, on: bool) -> None: ...
    def reset_motion(self) -> None: ...
    def stop_triggers(self) -> None: ...
    def finish(self) -> None: ...
    def close(self) -> None: ...


@dataclass(frozen=True)
class TrackedWeld:
    """One tracked weld: the tracker (nominal path, look-ahead), the laser tool (flange,
    mm, deg) the path is in (base frame), and the laser window: on from ``laser_from_mm``
    to ``laser_to_mm`` of arc length. ``laser=False`` keeps it off (a dry run);
    ``track=False`` runs the nominal path uncorrected (the baseline). ``feedforward``: a
    correction (6,) at each time (s since the move's start) added to the tracker's (a
    learned table, :mod:`welding.ilc`); during the stand before the move, its value at 0."""

    tracker: Tracker
    laser_tool: Loc
    laser_from_mm: float
    laser_to_mm: float
    rate_hz: float = 200.0
    track: bool = True
    laser: bool = True
    settle_s: float = 0.25
    tolerance_mm: float = TOLERANCE_MM
    feedforward: Callable[[float], FloatArray] | None = None
    #: None: the seam points are the robot's (^B_G T from its measured joints, columns
    #: 11-13 of GetSeamPoints). A sensor tool (flange, mm, deg): the sensor's own reading
    #: ^S_G T placed on the pose the path asks of the sensor at the exposure (the nominal
    #: path plus the tracker's own correction, not the feedforward): on an elastic arm the
    #: motor encoders miss the gearbox's deflection, and a feedforward that makes the arm
    #: follow its reference (a learned table) makes that pose the one the sensor had.
    sensor_tool: Loc | None = None
    #: the exposure is this long (s) before a seam point's t_sync (the joint log's latency:
    #: t_sync is where the measured joints saw the image); with ``sensor_tool`` only
    exposure_lag_s: float = 0.0


@dataclass(frozen=True)
class TrackOutcome:
    """``stopped``: why the weld stopped early ("" when completed); ``cycles``: controller
    cycles of the move; ``corrections``: corrections sent during it (one per cycle when the
    loop keeps up); ``start_on_grid``: the cycle the move started on is known exactly."""

    stopped: str
    cycles: int
    corrections: int
    start_on_grid: bool
    verdict: Verdict | None = None
    #: timed mode: the table sent, rows (robot time s, correction 6); else empty
    sent: FloatArray = field(default_factory=lambda: np.zeros((0, 7)))
    timed: bool = False
    #: the verdict's estimate along the weld: rows (arc length mm, estimated error mm)
    estimate: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    #: robot time (s) the move's law started at
    t0: float = math.nan
    #: the seam points of the weld as GetSeamPoints gave them (M, 17)
    rows: FloatArray = field(default_factory=lambda: np.zeros((0, 17)))
    #: timed mode: robot times (s) of the corrections that reached the robot after their
    #: cycle, the laser's cycles or not (the verdict counts those of the laser's cycles)
    late_times: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: when the weld stopped early: seconds into the move (robot clock); else nan
    stopped_at_s: float = math.nan


# C901 allowed: the 4 ms tracking loop shares its state between phases in locals; splitting it
# is a refactoring of its own, not a lint fix
def weld_tracked(  # noqa: C901
    link: TrackLink,
    weld: TrackedWeld,
    *,
    sensor_silent_after_mm: float | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> TrackOutcome:
    """Run ``weld`` on ``link``; ``sensor_silent_after_mm`` stops the triggers once the laser
    is that far past ``laser_from_mm`` (a dropped sensor, for tests); ``cancelled`` true (the
    operator's abort, asked every cycle) stops the weld as a lost seam does.

    A robot that takes timed corrections (AlterQueue, RS-5.39) gets each cycle's correction
    ahead of its cycle, as soon as the seam around its laser point is measured (the sensor
    looks ahead: ~140 ms at 250 mm/s), so a loop late by tens of milliseconds costs nothing;
    otherwise the correction for the next cycle is sent every cycle (Alter)."""
    tracker = weld.tracker
    nominal = tracker.weld
    period = link.period
    last_index = -1
    stopped = ""
    stopped_at = math.nan
    laser_on = False
    track = weld.track
    ff = weld.feedforward or (lambda _t: np.zeros(6))
    margin = tracker.model.half_width_mm - FIT_HALF_WIDTH_MM  # a wider fit waits for more
    seen: list[FloatArray] = []
    # the tracker's own correction (3,) by the robot time of the cycle it applies at, and
    # the robot time the move's law starts at (unknown during the stand): the sensor's
    # reference pose (``weld.sensor_tool``)
    hist_t: list[float] = []
    hist_c: list[FloatArray] = []
    t_law = math.inf
    to_sensor = (
        None
        if weld.sensor_tool is None
        else np.linalg.inv(location_to_transform(np.array(weld.laser_tool, dtype=np.float64)))
        @ location_to_transform(np.array(weld.sensor_tool, dtype=np.float64))
    )

    def own(t: float, correction: FloatArray) -> None:
        if not hist_t or t > hist_t[-1]:
            hist_t.append(t)
            hist_c.append(correction[:3].copy())

    def seam_points(rows: FloatArray) -> FloatArray:
        if to_sensor is None:
            out: FloatArray = rows[:, 11:14]
            return out
        t = rows[:, 2] - weld.exposure_lag_s
        # the first half of the stand brings the arm onto the seam: it is not on its
        # reference pose yet
        keep = t >= t_first + 0.5 * weld.settle_s
        t = t[keep]
        return reference_points(
            nominal, to_sensor, t - t_law, rows[keep, 5:8], _own_at(t, hist_t, hist_c)
        )

    def fetch() -> None:
        nonlocal last_index
        rows = link.points(last_index)
        if len(rows):
            last_index = int(rows[-1, 0])
            tracker.model.add(seam_points(rows))
            seen.append(rows)

    # points of earlier runs (the ΔT measurement, another weld) are not this seam's
    last_index = link.start(weld.laser_tool, weld.rate_hz) - 1
    timed = link.timed
    t_first = t0 = link.time()
    on_grid = False
    corrections = 0
    sent_t: list[float] = []
    sent_c: list[FloatArray] = []
    late_t: list[float] = []
    state = QueueState(0, 0, -1.0, t0)
    try:
        # the arm stands still while the sensor measures the seam's start and the laser is
        # brought onto it
        t_go = t0 + weld.settle_s
        while link.time() < t_go - 1e-9:
            _check_cancelled(cancelled)
            fetch()
            ready = track and tracker.model.count >= MIN_FIT_POINTS
            c_stand = tracker.correction(0.0) if ready else tracker.base_correction(0.0)
            own(link.next_cycle(), c_stand)
            link.alter(c_stand + ff(0.0))
            link.step()
        times, locs = nominal.timed_path(period)
        t_send = link.time()
        t0, on_grid = link.move(times, locs, weld.laser_tool)  # the law's start, a cycle
        t_law = t0
        log.info("tracked move queued in %.1f ms: %d cycles (%s corrections)",
                 (link.time() - t_send) * 1e3, len(times),
                 "timed" if timed else "per-cycle")  # fmt: skip
        held = np.zeros(6)
        n = 0
        # timed: the next cycle without a queued correction, and the last one to queue
        # (on the real clock two cycles on: the stand before the move is still on, and the
        # Alter in force covers it while the first batch is on its way)
        k_next = round(link.next_cycle() / period)
        if t0 > link.next_cycle() + 2 * period:
            k_next += 2
        k_last = math.ceil((t0 + float(times[-1]) + TAIL_S) / period)
        while link.queued():
            _check_cancelled(cancelled)
            t_cycle = link.next_cycle()
            t_move = t_cycle - t0  # the correction applies at the next cycle
            s = float(nominal.s_at(t_move))
            if (
                sensor_silent_after_mm is not None
                and s > weld.laser_from_mm + sensor_silent_after_mm
            ):
                link.stop_triggers()  # no more seam points: the sensor has dropped out
            if timed:
                if track and s <= weld.laser_to_mm:
                    try:
                        tracker.check_ahead(t_move)  # a silent sensor stops the weld
                    except TrackingError:
                        # not before the points measured meanwhile are read: a loop that
                        # was late (a stalled PC) judges the sensor by what it measured
                        fetch()
                        tracker.check_ahead(t_move)
                ready_s = tracker.model.furthest - FINAL_MARGIN_MM - margin
                batch_t: list[float] = []
                while k_next <= k_last:
                    t_k = k_next * period
                    s_k = float(nominal.s_at(t_k - t0))
                    due = t_k <= t_cycle + period + 1e-9
                    beyond = s_k > weld.laser_to_mm + FOLLOW_ON_MM
                    if not track:
                        if t_k > t_cycle + UNTRACKED_AHEAD_S:
                            break  # known now, but the queue need not hold the whole move
                    elif s_k > ready_s and not (due or beyond):
                        break  # final once its fit window is measured
                    if not track:
                        held = np.zeros(6)
                    elif s_k <= weld.laser_to_mm:
                        # one due at once is sent with what there is (TrackingError when
                        # that is not enough: the weld stops)
                        held = tracker.correction_at(s_k)
                    elif not beyond:
                        # past the weld's end the seam is followed on a little where it is
                        # measured (a correction stopping dead at the laser's last cycle
                        # would be braked within RS-5.34 before it), then held
                        with contextlib.suppress(TrackingError):
                            held = tracker.correction_at(s_k)
                    batch_t.append(t_k)
                    own(t_k, held)
                    sent_c.append(held + ff(t_k - t0))
                    k_next += 1
                if batch_t:
                    sent_t.extend(batch_t)
                    state = link.queue(np.array(batch_t), np.array(sent_c[-len(batch_t) :]))
                    late_t.extend(batch_t[: state.late])
            else:
                if s <= weld.laser_to_mm:
                    held = tracker.correction(t_move) if track else np.zeros(6)
                own(t_cycle, held)
                link.alter(held + ff(t_move))
                corrections += t_move > 0.0  # the stand before a real-clock move is no cycle
            want_on = weld.laser and weld.laser_from_mm <= s <= weld.laser_to_mm
            if want_on != laser_on:
                link.set_laser(want_on)
                laser_on = want_on
            # after the correction, whose cycle is the deadline, and every other cycle: the
            # points come at the trigger rate and are measured 40 mm ahead of the laser
            if n % 2 == 0 or timed:
                fetch()
            n += 1
            link.step()
        if timed:
            state = link.queue(np.zeros(0), np.zeros((0, 6)))  # the counts of the weld
    except (TrackingError, RemoteError) as exc:
        # the seam is lost, or the robot refused a correction (it ends alter mode when the
        # stream goes silent, and takes control from a client silent past its lease)
        stopped = str(exc) if isinstance(exc, TrackingError) else f"the robot refused: {exc}"
        stopped_at = link.time() - t0
        log.warning("the weld stopped %.3f s into the move: %s", stopped_at, stopped)
        _stop_safely(link)
        laser_on = False
    except KeyboardInterrupt:  # Ctrl-C, a stop signal: the same safe stop, then out
        with contextlib.suppress(Exception):
            link.set_laser(False)
            link.reset_motion()
            log.warning("interrupted: laser off, motion reset")
        raise
    if laser_on:
        link.set_laser(False)
    cycles = round((link.time() - t0) / period)
    if timed:  # the move's cycles whose correction was queued
        t_arr = np.array(sent_t)
        corrections = int(np.count_nonzero((t_arr > t0) & (t_arr <= t0 + cycles * period)))
    link.finish()
    # the verdict from what a real cell has: the laser's path from the measured joints, the
    # seam the sensor measured, the corrections the robot did not get in time
    try:
        laser = link.laser_points(weld.laser_tool, t_first)
    except RemoteError as exc:
        stopped = stopped or f"the robot's joint log is not available: {exc}"
        laser = np.zeros((0, 3))
    s_est, err = estimate_errors(tracker.model, laser, weld.laser_from_mm, weld.laser_to_mm)
    late_arr = np.array(late_t)
    # a late correction of the stand or of the run-out costs nothing: the laser is off there
    s_late = nominal.s_at(late_arr - t0) if len(late_arr) else late_arr
    late_on = int(np.count_nonzero((s_late >= weld.laser_from_mm) & (s_late <= weld.laser_to_mm)))
    if len(late_arr):
        log.info(
            "%d corrections late (%d of laser cycles), at %s s of the move",
            len(late_arr), late_on, np.round(late_arr - t0, 3).tolist()[:20],
        )  # fmt: skip
    late, missed = (late_on, state.held_total) if timed else (0, cycles - corrections)
    verdict = judge(
        err,
        late=late,
        held=max(missed, 0),
        tolerance_mm=weld.tolerance_mm,
        stopped=stopped,
        s=s_est,
    )
    sent = (
        np.column_stack([sent_t, np.array(sent_c).reshape(-1, 6)]) if sent_t else np.zeros((0, 7))
    )
    estimate = np.column_stack([s_est, err])
    rows_seen = np.vstack(seen) if seen else np.zeros((0, 17))
    return TrackOutcome(
        stopped,
        cycles,
        corrections,
        on_grid,
        verdict,
        sent,
        timed,
        estimate,
        t0,
        rows_seen,
        late_arr,
        stopped_at,
    )


def _stop_safely(link: TrackLink) -> None:
    """Laser off first, then the arm stops along its path and drops its queue. A robot that
    has taken control from this client (its lease ran out: a stalled PC) made that stop
    itself [RS-7.10] and refuses these commands: that is logged, not raised, so the weld's
    result is still judged and written."""
    try:
        link.set_laser(False)
        link.reset_motion()
    except RemoteError as exc:
        if exc.code is not ErrorCode.NOT_IN_CONTROL:
            raise
        log.warning("control was lost: the robot made its controlled stop itself (%s)", exc)


def _check_cancelled(cancelled: Callable[[], bool] | None) -> None:
    if cancelled is not None and cancelled():
        raise TrackingError("cancelled by the operator")


class RobotLink:
    """Through a RobotSocket server, as any client would. ``client`` holds control (a
    :class:`~robotsocket.client.RobotClient` or any ``call(command, *params)``);
    ``sensor_endpoint`` the sensor's trigger address for SetSensorEndpoint (None: as
    configured). ``real_time``: the robot runs on the wall clock, so the loop waits for the
    next cycle on it; otherwise WaitEndMove of one cycle advances the simulated clock."""

    def __init__(
        self,
        client: _Caller,
        sensor_endpoint: tuple[str, int] | None = None,
        *,
        period: float = 0.004,
        real_time: bool = False,
    ) -> None:
        self.client = client
        self.sensor_endpoint = sensor_endpoint
        self.period = period
        self.real_time = real_time
        self._offset = 0.0  # robot time - local monotonic time (real clock)
        self._end = -math.inf  # robot time the queued move's law ends (real clock)
        self.timed = False
        #: use timed corrections when the robot lists AlterQueue in Hello (False: Alter only)
        self.use_queue = True
        self._model: RobotModel | None = None

    def _call(self, command: CommandId, *params: Value) -> tuple[Value, ...]:
        return self.client.call(command, *params)

    def delta_t(self) -> float:
        return float(self._call(CommandId.GET_SYNC_CONFIG)[2])  # type: ignore[arg-type]

    def here(self, tool: Loc) -> Loc:
        loc = self._call(CommandId.HERE, Location(*tool), IDENTITY_LOCATION)[0]
        assert isinstance(loc, Location)
        return loc.as_tuple()

    def start(self, tool: Loc, rate_hz: float) -> int:
        info = self._call(CommandId.HELLO, wire.VERSION_MAJOR, wire.VERSION_MINOR, "track")
        commands = info[6]
        listed = commands.values if isinstance(commands, IntArray) else []
        self.timed = self.use_queue and int(CommandId.ALTER_QUEUE) in listed
        self._model = get_model(str(info[3]))
        self._call(CommandId.ENABLE_POWER)
        if self.sensor_endpoint is not None:
            self._call(CommandId.SET_SENSOR_ENDPOINT, *self.sensor_endpoint)
        first = self._call(CommandId.START_TRIGGERS, float(rate_hz), 0)[0]
        self._call(CommandId.ALTER_BEGIN, Location(*tool), 0.1)
        if self.real_time:
            self._sync_clock()
        assert isinstance(first, int)
        return first

    def time(self) -> float:
        if self.real_time:
            return time.monotonic() + self._offset
        return self._robot_time()

    def _robot_time(self) -> float:
        return float(self._call(CommandId.GET_TIME)[0])  # type: ignore[arg-type]

    def _sync_clock(self) -> None:
        """Real clock: the robot's time as the local monotonic clock plus an offset, taken
        from the GetTime of the shortest of a few round trips (its middle); one round trip
        per cycle less, and a stalled reply no longer shifts the time the loop works with."""
        best = math.inf
        for _ in range(5):
            t0 = time.monotonic()
            robot = self._robot_time()
            t1 = time.monotonic()
            if t1 - t0 < best:
                best = t1 - t0
                self._offset = robot - (t0 + t1) / 2.0

    def _cycle_of(self, t: float) -> int:
        return math.floor(t / self.period + 1e-9)

    def next_cycle(self) -> float:
        """Robot time of the cycle that applies the next command."""
        if not self.real_time:
            return self.time() + self.period  # the simulated clock stands on a cycle
        return (self._cycle_of(self.time()) + 1) * self.period

    def points(self, since: int) -> FloatArray:
        m = self._call(CommandId.GET_SEAM_POINTS, since)[0]
        assert isinstance(m, Matrix)
        return np.array(m.values, dtype=np.float64).reshape(m.rows, m.cols)

    def alter(self, correction: FloatArray) -> None:
        self._call(CommandId.ALTER, Location(*(float(v) for v in correction)))

    def queue(self, times: FloatArray, corrections: FloatArray) -> QueueState:
        r = self._call(
            CommandId.ALTER_QUEUE,
            wire_params.FloatArray(times.tolist()),
            Matrix(len(times), 6, corrections.ravel().tolist()),
        )
        return QueueState(int(r[4]), int(r[5]), float(r[3]), float(r[7]), int(r[1]))  # type: ignore[arg-type]

    def laser_points(self, tool: Loc, since: float) -> FloatArray:
        """The laser tool's points (N, 3), base frame, from the measured joints logged
        after ``since`` (GetJointLog and the arm's model of Hello)."""
        m = self._call(CommandId.GET_JOINT_LOG, float(since))[0]
        assert isinstance(m, Matrix) and self._model is not None
        rows = np.array(m.values, dtype=np.float64).reshape(m.rows, m.cols)
        return laser_path(self._model, rows[:, 1:], tool)

    def step(self) -> None:
        if not self.real_time:
            self._call(CommandId.WAIT_END_MOVE, self.period)
            return
        # wait for the next cycle on the robot's clock (a deadline on it, not a guess), a
        # little after it so the cycle has run
        wait = self.next_cycle() + 0.0003 - self.time()
        deadline = time.monotonic() + wait
        while (left := deadline - time.monotonic()) > 0:
            time.sleep(left)

    def move(self, times: FloatArray, locs: FloatArray, tool: Loc) -> tuple[float, bool]:
        """Queue the timed path; (the robot time its law starts at, whether that is
        certain). The robot starts a queued move's law at the cycle during which it takes
        it, and a long path takes it longer than a cycle to receive and plan. So on the real
        clock a short stand at the start (two samples: received and planned within the cycle
        it is sent in, sent just after a cycle starts) goes first, and the path follows it
        from the cycle the stand ends on: certain when the stand's reply came within its
        cycle and the path was queued before the stand ended."""
        if not self.real_time:
            self._send_path(times, locs, tool)
            return self.time(), True  # the simulated clock did not move meanwhile
        self.step()
        before = self.time()
        self._send_path(np.array([0.0, HOLD_S]), np.array([locs[0], locs[0]]), tool)
        k = self._cycle_of(before)
        after = self.time()
        certain = k == self._cycle_of(after)
        log.debug("the stand before the path: sent %.2f ms into cycle %d, reply after %.2f ms",
                  (before - k * self.period) * 1e3, k, (after - before) * 1e3)  # fmt: skip
        t0 = k * self.period + HOLD_S
        self._send_path(times, locs, tool)
        certain = certain and self.time() < t0 - self.period
        self._end = t0 + float(times[-1])
        return t0, certain

    def _send_path(self, times: FloatArray, locs: FloatArray, tool: Loc) -> None:
        self._call(
            CommandId.TOOL_MOVE_TRAJECTORY,
            wire_params.FloatArray(times.tolist()),
            Matrix(len(locs), 6, locs.ravel().tolist()),
            Location(*tool),
            IDENTITY_LOCATION,
        )

    def queued(self) -> int:
        if self.real_time and self.time() < self._end:
            return 1  # the move runs until its law ends: no round trip to ask
        return int(self._call(CommandId.ROBOT_STATUS)[3])  # type: ignore[arg-type]

    def set_laser(self, on: bool) -> None:
        self._call(CommandId.SET_OUTPUT, "laser", on)

    def reset_motion(self) -> None:
        self._call(CommandId.RESET_MOTION)

    def stop_triggers(self) -> None:
        self._call(CommandId.STOP_TRIGGERS)

    def finish(self) -> None:
        # alter mode may have ended already (the robot stopped a stream that went silent)
        with contextlib.suppress(RemoteError):
            self._call(CommandId.ALTER_END)
        try:
            self._call(CommandId.STOP_TRIGGERS)
            self._call(CommandId.WAIT_END_MOVE, 5.0)
        except RemoteError as exc:
            # a robot that took control away stopped the triggers and the arm itself
            # [RS-7.10]; what the weld did is still read from its logs
            if exc.code is not ErrorCode.NOT_IN_CONTROL:
                raise

    def close(self) -> None:
        pass


def reference_points(
    nominal: WeldPath,
    laser2sensor: FloatArray,
    t_move: FloatArray,
    seen: FloatArray,
    correction: FloatArray,
) -> FloatArray:
    """Seam points (M, 3), base frame: the sensor's readings ``seen`` (M, 3) (^S_G T's
    translation) placed on the sensor's reference pose at ``t_move`` (M,) s since the move's
    start (the stand before it: its start), the laser on the nominal path plus
    ``correction`` (M, 3) with the path's orientation, the sensor ``laser2sensor`` (4, 4)
    from it."""
    rot = location_to_transform(np.concatenate([np.zeros(3), nominal.angles]))[:3, :3]
    laser = nominal.point(nominal.s_at(t_move)) + correction
    r_s = rot @ laser2sensor[:3, :3]
    out: FloatArray = laser + rot @ laser2sensor[:3, 3] + seen @ r_s.T
    return out


def _own_at(t: FloatArray, hist_t: list[float], hist_c: list[FloatArray]) -> FloatArray:
    """(M, 3) the correction at the robot times ``t``, linear between the recorded cycles,
    the ends held; zero before any."""
    if not hist_t:
        return np.zeros((len(t), 3))
    c = np.array(hist_c)
    return np.column_stack([np.interp(t, hist_t, c[:, k]) for k in range(3)])


def laser_path(model: RobotModel, joints: FloatArray, tool: Loc) -> FloatArray:
    """Points (N, 3) of ``tool`` (flange, mm, deg), base frame, at the joints (N, 6) deg."""
    if not len(joints):
        return np.zeros((0, 3))
    f2b = model.flange2base_batch(joints)
    out: FloatArray = (f2b @ location_to_transform(np.array(tool, dtype=np.float64)))[:, :3, 3]
    return out


class _Caller(Protocol):
    def call(
        self, command: int, *params: Value, timeout: float | None = ...
    ) -> tuple[Value, ...]: ...
