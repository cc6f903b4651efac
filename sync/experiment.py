"""The ΔT experiment of section VI through the public protocol (any conforming robot + sensor).

The sensor is moved in a sine of amplitude A and frequency f along y of its own frame S,
perpendicular to a straight seam that the user has put in the middle of the field of view,
starting from the current pose. Through the protocol only:

1. Hello (the robot's model, for the DGM), TakeControl, the sensor's trigger endpoint
   (GetTriggerEndpoint) given to the robot (SetSensorEndpoint), the sensor tool ^N_S T
   (GetSyncConfig), EnablePower, the start pose Here(^N_S T, world);
2. StartTriggers at ``trigger_rate_hz``, then ToolMoveTrajectory with the sensor tool: rest,
   a sine with raised-cosine ramps in and out, rest (sampled every 4 ms);
3. while the arm moves (WaitEndMove in chunks): GetJointLog and GetSeamPoints.

y^R(t_k^R) is the sensor origin's displacement along y of the start frame S0, from the
logged joints through DGM(q) · ^N_S T (eq. 2-3); y^S(t_i^T) is the seam's y in S (column
``sy`` of GetSeamPoints) relative to its value at rest, negated (the seam moves the other way
in S), stamped with t_i^T. :func:`sync.delay.estimate_delay` gives ΔT (eq. 6-7 + parabola) and
:func:`sync.delay.residual_after_sync` the residual with and without it (Fig. 9).
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kinematics.robot import RobotModel, get_model
from kinematics.transforms import location_to_transform
from kinematics.types import FloatArray
from spec import params as wire_params
from spec.client import ClientTimeout, FramedClient, wait_end_move, wait_move
from spec.errors import ErrorCode, RemoteError
from spec.exitcodes import ExitCode
from spec.files import atomic_path, prepare_output_path, write_atomically
from spec.params import IDENTITY_LOCATION, IntArray, Location, Matrix, Value
from spec.registry import BY_ID, SEAM_POINT_COLUMNS, CommandId
from spec.wire import MoveOutcome, SensorStatus
from sync.delay import (
    DelayEstimate,
    QualityLimits,
    ResidualReport,
    Verdict,
    assess_run,
    estimate_delay,
    residual_after_sync,
    sine_amplitude,
    window_delays,
)

__all__ = [
    "DEFAULT_SWEEP_HZ",
    "DelayResult",
    "ExperimentData",
    "ExperimentError",
    "ExperimentSettings",
    "analyse",
    "judge",
    "reading_times",
    "record_sine",
    "run_delay_experiment",
    "run_sweep",
    "sine_path",
    "write_json",
    "write_plots",
]

Progress = Callable[[float, str], None]

#: Frequencies of the sweep (Fig. 8), Hz.
DEFAULT_SWEEP_HZ = (0.1, 0.2, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 7.0, 10.0)
_SY = SEAM_POINT_COLUMNS.index("sy")
_TT = SEAM_POINT_COLUMNS.index("t_trigger")
_TS = SEAM_POINT_COLUMNS.index("t_sync")
#: t_S - t_T - ΔT of a seam point below this (s) is the rounding of t_T + ΔT, not an extra
#: exposure lag the robot placed the reading later by [SY-3.8] (0.5 ms and more).
_EXTRA_LAG_FLOOR_S = 1e-6
_IDX = SEAM_POINT_COLUMNS.index("index")


class ExperimentError(RuntimeError):
    """The experiment cannot run or gave too little data (message says why); ``code`` is the
    exit code a command line ends with (an endpoint that is not what it was given as: USAGE or
    UNREACHABLE; else FAILED)."""

    def __init__(self, message: str, code: ExitCode = ExitCode.FAILED) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class ExperimentSettings:
    """The sine motion (mm, Hz, s), triggering and estimation settings.

    ``duration_s`` is the length of the sine including its ramps (raised cosine,
    ``ramp_s``, default one period clipped to 0.25..1 s); ``rest_s`` of stillness before and
    after. ``search_*_s`` bound the ΔT search. ``model`` overrides the robot's model name.
    ``apply`` sets the robot's ΔT to the estimate afterwards (SetSyncDelay).
    """

    frequency_hz: float = 1.5
    amplitude_mm: float = 2.0
    duration_s: float = 10.0
    trigger_rate_hz: float = 250.0
    ramp_s: float | None = None
    rest_s: float = 0.2
    search_min_s: float = 0.0
    search_max_s: float = 20e-3
    model: str | None = None
    apply: bool = False
    token: str = ""
    chunk_s: float = 1.0
    sample_period_s: float = 0.004

    def __post_init__(self) -> None:
        checks = (
            ("frequency_hz", 0.0 < self.frequency_hz <= 50.0),
            ("amplitude_mm", 0.0 < self.amplitude_mm <= 20.0),
            ("duration_s", 0.0 < self.duration_s <= 600.0),
            ("trigger_rate_hz", 0.0 < self.trigger_rate_hz <= 1000.0),
            ("rest_s", 0.0 <= self.rest_s <= 10.0),
            ("search range", self.search_min_s < self.search_max_s),
        )
        for name, ok in checks:
            if not ok:
                raise ExperimentError(f"{name} out of range")

    @property
    def ramp(self) -> float:
        if self.ramp_s is not None:
            return min(self.ramp_s, self.duration_s / 2)
        return min(max(0.25, 1.0 / self.frequency_hz), 1.0, self.duration_s / 2)

    @property
    def total_s(self) -> float:
        return self.duration_s + 2 * self.rest_s


#: Control lease asked for (s): the server's 0.25 s default was lost mid-sine on a loaded
#: 2-core machine (a full test run beside the sweep), which stopped the sweep.
EXPERIMENT_LEASE_S = 1.0


def sine_path(s: ExperimentSettings) -> tuple[FloatArray, FloatArray]:
    """The commanded lateral displacement: times (N,) s on the 4 ms grid from 0, y (N,) mm."""
    n = math.ceil(s.total_s / s.sample_period_s - 1e-9)
    t = np.arange(n + 1) * s.sample_period_s
    tau = t - s.rest_s
    inside = (tau >= 0) & (tau <= s.duration_s)
    r = s.ramp
    w = np.clip(np.minimum(tau, s.duration_s - tau) / r, 0.0, 1.0)
    w = 0.5 - 0.5 * np.cos(np.pi * w)
    y: FloatArray = np.where(
        inside, s.amplitude_mm * w * np.sin(2 * np.pi * s.frequency_hz * tau), 0.0
    )
    return t.astype(np.float64), y


@dataclass(frozen=True)
class ExperimentData:
    """Recorded signals: robot (K,) times s and y^R mm; sensor (I,) t_i^T s and y^S mm.

    ``t_trigger`` is a reading's t_i^T plus the extra exposure lag the robot placed it later
    by (t_S - t_T - ΔT, for a reading exposed late [SY-3.8]; t_i^T itself for every other):
    ΔT is then the delay of a reading exposed on time, the one the robot adds to t_i^T.
    """

    t_robot: FloatArray
    y_robot: FloatArray
    t_trigger: FloatArray
    y_sensor: FloatArray
    t_start: float
    model: str
    statistics: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class DelayResult:
    """One experiment: the settings, the data, the estimate and the residuals."""

    settings: ExperimentSettings
    data: ExperimentData
    estimate: DelayEstimate
    residual: ResidualReport
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def delta_t_ms(self) -> float:
        return self.estimate.delta_t_s * 1e3

    def summary(self) -> dict[str, Any]:
        """Scalars only (the sweep table)."""
        syn, uns = self.residual.synced, self.residual.unsynced
        out: dict[str, Any] = {
            "frequency_hz": self.settings.frequency_hz,
            "amplitude_mm": self.settings.amplitude_mm,
            "duration_s": self.settings.duration_s,
            "delta_t_ms": self.delta_t_ms,
            "at_edge": self.estimate.at_edge,
            "residual_max_um": syn.max_um,
            "residual_rms_um": syn.rms_um,
            "residual_sine_amplitude_um": syn.sine_amplitude_um,
            "unsynced_max_um": uns.max_um,
            "unsynced_rms_um": uns.rms_um,
            "unsynced_sine_amplitude_um": uns.sine_amplitude_um,
            "n_robot": int(self.data.t_robot.size),
            "n_sensor": int(self.data.t_trigger.size),
        }
        out.update(self.extra)
        return out

    def to_json(self) -> dict[str, Any]:
        out = self.summary()
        out["model"] = self.data.model
        out["statistics"] = self.data.statistics
        out["mse_curve"] = {
            "delta_t_ms": (self.estimate.shifts_s * 1e3).round(4).tolist(),
            "mse_um2": (self.estimate.mse * 1e6).tolist(),
        }
        return out


def _f(v: Value) -> float:
    assert isinstance(v, float)
    return v


def _matrix(v: Value) -> FloatArray:
    assert isinstance(v, Matrix)
    return np.array(v.values, dtype=np.float64).reshape(v.rows, v.cols)


def _reply(
    client: FramedClient, command: CommandId, *params: Value, timeout: float | None = None
) -> dict[str, Value]:
    """``command``'s reply by the field names of the registry, not by position (the client
    has checked the reply's types against the same registry entry)."""
    values = client.call(command, *params, timeout=timeout)
    return dict(zip((p.name for p in BY_ID[command].reply), values, strict=False))


def _endpoint(sensor: FramedClient) -> tuple[str, int]:
    reply = _reply(sensor, CommandId.GET_TRIGGER_ENDPOINT)
    host, port = reply["host"], reply["port"]
    assert isinstance(host, str) and isinstance(port, int)
    if port == 0:
        raise ExperimentError("the sensor reports no UDP trigger endpoint")
    if host in ("", "0.0.0.0", "::"):
        host = sensor.host
    return host, port


#: The shortest rest before the sine after which the seam is checked to be in view, and the
#: sensor answers without a seam that stop the run.
_MIN_REST_CHECK_S = 0.1
_MIN_ANSWERS = 5


def _no_seam(sensor: FramedClient | None, answered: int, waited_s: float) -> str:
    """Why the sensor gave no seam point at the start pose, from its latest measurement."""
    what = "the sensor sees no seam, or its laser is off (--sensor HOST:PORT tells which)"
    if sensor is not None:
        try:
            code = _reply(sensor, CommandId.GET_DATA)["status"]
            status = SensorStatus(code if isinstance(code, int) else -1)
        except RemoteError:  # NO_DATA: it never measured
            what = "the sensor got no trigger (is --sensor the robot's trigger endpoint?)"
        except ValueError:
            pass
        else:
            what = status.problem(sensor.address) or what
    return (
        f"no seam point in {answered} sensor answers ({waited_s:.2f} s) at the start pose, "
        f"nothing moved: {what}"
    )


def _sync_statistics(robot: FramedClient) -> dict[str, int]:
    """GetSyncStatistics by field name (the counters since the robot's server started)."""
    reply = _reply(robot, CommandId.GET_SYNC_STATISTICS)
    return {k: v for k, v in reply.items() if isinstance(v, int) and not isinstance(v, bool)}


def exposed_late_text(statistics: Mapping[str, int]) -> str:
    """What a run's counters say of the readings the robot placed later by their extra
    exposure lag [SY-3.8]: their count [SY-5.9], or that the robot does not report it (one
    from before SY-5.9 leaves the counter off; not reported is not 0)."""
    n = statistics.get("exposed_late")
    if n is None:
        return "readings exposed late: not reported by this robot (GetSyncStatistics before SY-5.9)"
    return f"{n} readings exposed late (the sensor busy; placed later by their extra lag)"


#: How long the robot and the sensor get to answer Hello (s): a connection check, as the
#: conformance runner's, so an endpoint that accepts and never answers is named in seconds,
#: not after the experiment's own reply timeout.
HELLO_TIMEOUT_S = 3.0


def _hello(client: FramedClient, wanted: str) -> dict[str, Value]:
    """Hello from the endpoint given as --robot (--sensor), checked to be that service."""
    timeout = min(client.timeout, HELLO_TIMEOUT_S)
    try:
        info = client.hello(timeout=timeout)
    except ClientTimeout:
        protocol = "RobotSocket" if wanted == "robot" else "SensorSocket"
        raise ExperimentError(
            f"{client.address} (--{wanted}) accepted the connection but did not answer Hello"
            f" within {timeout:g} s (not a {protocol} server, or a hung one?)",
            ExitCode.UNREACHABLE,
        ) from None
    _check_service(client, info, wanted)
    return info


def _check_service(client: FramedClient, info: dict[str, Value], wanted: str) -> None:
    """The endpoint given as --robot (--sensor) announces that service in Hello [RS-5.31];
    the other one means the two addresses were swapped (else: an unknown model name)."""
    service = info.get("service")
    if service in ("robot", "sensor") and service != wanted:
        raise ExperimentError(
            f"{client.address} (--{wanted}) is a {service} endpoint, not a {wanted}:"
            " are --robot and --sensor swapped?",
            ExitCode.USAGE,
        )


def _check_endpoints(
    robot: FramedClient, sensor: FramedClient | None, s: ExperimentSettings
) -> RobotModel:
    """Hello to both, the sensor's laser on, the robot's kinematic model known and the
    commands the run needs offered: each problem one ExperimentError before anything moves."""
    info = _hello(robot, "robot")
    if sensor is not None:
        _hello(sensor, "sensor")
        if not _reply(sensor, CommandId.SENSOR_STATUS)["laser"]:
            raise ExperimentError(SensorStatus.LASER_OFF.problem(sensor.address))
    model_name = s.model or str(info.get("model", ""))
    try:
        model = get_model(model_name)
    except Exception as exc:  # unknown name: say which and how to override
        raise ExperimentError(f"no kinematic model {model_name!r}: use --model") from exc
    commands = info.get("commands")
    if isinstance(commands, IntArray):
        needed = (CommandId.TOOL_MOVE_TRAJECTORY, CommandId.START_TRIGGERS)
        missing = [c.name for c in needed if int(c) not in commands.values]
        if missing:
            raise ExperimentError(f"the robot does not implement {', '.join(missing)}")
    return model


def _stop_triggers(robot: FramedClient) -> None:
    """StopTriggers; a robot that has taken control away stopped them itself [RS-7.10]
    (so the error that ended the run is the one reported)."""
    try:
        robot.call(CommandId.STOP_TRIGGERS)
    except RemoteError as exc:
        if exc.code is not ErrorCode.NOT_IN_CONTROL:
            raise


def _sine_done(robot: FramedClient, wait_s: float) -> bool:
    """Wait up to ``wait_s`` for the sine move: True once it has reached its end. A move
    stopped short (the robot took control away, an emergency stop) or failed ends the run:
    its data would fit only a part of the sine, and waiting on would never end."""
    moved = wait_move(robot, wait_s)
    if moved.outcome in (MoveOutcome.STOPPED, MoveOutcome.FAILED):
        raise ExperimentError(f"the sine move {moved.outcome}: {moved.reason}")
    return moved.reached


def record_sine(
    robot: FramedClient,
    sensor: FramedClient | None,
    settings: ExperimentSettings,
    progress: Progress | None = None,
) -> ExperimentData:
    """Run the sine motion with triggering and collect y^R and y^S (see module docstring).

    ``sensor`` is used only to ask for its trigger endpoint; with ``None`` the robot must
    already know it (SetSensorEndpoint).
    """
    s = settings
    model = _check_endpoints(robot, sensor, s)
    robot.take_control_asking(s.token, EXPERIMENT_LEASE_S)
    if sensor is not None:
        host, port = _endpoint(sensor)
        robot.call(CommandId.SET_SENSOR_ENDPOINT, host, port)
    config = _reply(robot, CommandId.GET_SYNC_CONFIG)
    if not config["port"]:
        raise ExperimentError("the robot has no sensor endpoint: give --sensor")
    tool = config["sensor2flange"]
    assert isinstance(tool, Location)
    status = _reply(robot, CommandId.ROBOT_STATUS)
    if not status["powered"]:
        robot.call(CommandId.ENABLE_POWER)
    if status["moving"]:
        wait_end_move(robot, 30.0)
    loc0 = _reply(robot, CommandId.HERE, tool, IDENTITY_LOCATION)["location"]
    assert isinstance(loc0, Location)
    times, y = sine_path(s)
    locs = np.zeros((times.size, 6))
    locs[:, 1] = y
    t_start = _f(robot.get_time())
    log_since = t_start - 0.1
    count = math.ceil((s.total_s + 0.1) * s.trigger_rate_hz)
    stats_before = _sync_statistics(robot)  # the counters run since the server started
    first = _reply(robot, CommandId.START_TRIGGERS, float(s.trigger_rate_hz), count)["first_index"]
    assert isinstance(first, int)
    try:
        robot.call(
            CommandId.TOOL_MOVE_TRAJECTORY,
            wire_params.FloatArray(times.tolist()),
            Matrix(times.size, 6, locs.ravel().tolist()),
            tool,
            loc0,
        )
        logs: list[FloatArray] = []
        points: list[FloatArray] = []
        since_index = first - 1
        done = False
        # the first wait ends with the rest before the sine: no seam by then, and the run
        # stops before the arm has moved instead of after all of it
        chunk = s.rest_s if s.rest_s >= _MIN_REST_CHECK_S else float(s.chunk_s)
        while True:
            if not done:
                done = _sine_done(robot, chunk)
            rows = _matrix(_reply(robot, CommandId.GET_JOINT_LOG, float(log_since))["log"])
            if rows.size:
                logs.append(rows)
                log_since = float(rows[-1, 0])
            while True:
                prow = _matrix(_reply(robot, CommandId.GET_SEAM_POINTS, since_index)["points"])
                if not prow.size:
                    break
                points.append(prow)
                since_index = int(prow[-1, _IDX])
            now = _f(robot.get_time())
            chunk = float(s.chunk_s)
            if not points:
                # the sensor answered and none of its answers had a seam: stop. Not a
                # timeout: on a busy machine answers may be late, never taken for "no seam".
                answered = _sync_statistics(robot).get("received", 0) - stats_before.get(
                    "received", 0
                )
                if answered >= _MIN_ANSWERS:
                    robot.call(CommandId.RESET_MOTION)
                    raise ExperimentError(_no_seam(sensor, answered, now - t_start))
            if progress is not None:
                frac = min(1.0, (now - t_start) / s.total_s)
                progress(frac, f"{now - t_start:6.2f} s of {s.total_s:.2f} s")
            if done:
                break
    finally:
        _stop_triggers(robot)
    # This run's own counts; "pending" is a level, not a count.
    stats = {
        k: v - (stats_before.get(k, 0) if k != "pending" else 0)
        for k, v in _sync_statistics(robot).items()
    }
    if not logs or not points:
        raise ExperimentError(
            f"no data: {sum(len(x) for x in logs)} joint samples, "
            f"{sum(len(x) for x in points)} seam points (is the seam in view?)"
        )
    jl = np.vstack(logs)
    pt = np.vstack(points)
    s0 = location_to_transform(np.array(loc0.as_tuple()))
    sensor2flange = location_to_transform(np.array(tool.as_tuple()))
    poses = model.flange2base_batch(jl[:, 1:7]) @ sensor2flange
    # y of the sensor origin in the start frame S0: (R0^T (p - p0))_y
    y_r = (poses[:, :3, 3] - s0[:3, 3]) @ s0[:3, 1]
    t_t = reading_times(pt, _f(config["delta_t"]))
    sy = pt[:, _SY]
    rest = t_t < t_start + 0.8 * s.rest_s
    sy_ref = float(np.median(sy[rest])) if np.count_nonzero(rest) >= 5 else float(np.mean(sy))
    order = np.argsort(t_t, kind="stable")
    return ExperimentData(
        t_robot=jl[:, 0],
        y_robot=y_r,
        t_trigger=t_t[order],
        y_sensor=(sy_ref - sy)[order],
        t_start=t_start,
        model=model.name,
        statistics=stats,
    )


def reading_times(rows: FloatArray, delta_t_s: float) -> FloatArray:
    """(M,) the trigger time t_i^T of each GetSeamPoints row, plus the extra exposure lag the
    robot placed a reading exposed late by [SY-3.8] (its t_S - t_T beyond ``delta_t_s``, the
    ΔT in force): the time the reading belongs to on the t_i^T scale. Readings on time keep
    t_i^T to the bit; so do all of a robot that places every reading at t_i^T + ΔT."""
    t_t: FloatArray = rows[:, _TT]
    extra = (rows[:, _TS] - t_t) - delta_t_s
    late = extra > _EXTRA_LAG_FLOOR_S
    if not late.any():
        return t_t
    out = t_t.copy()
    out[late] += extra[late]
    return out


def analyse(
    data: ExperimentData, settings: ExperimentSettings, *, require_interior: bool = True
) -> DelayResult:
    """Estimate ΔT (eq. 6-7) and the residual with and without it."""
    s = settings
    t_r, y_r = data.t_robot, data.y_robot
    keep = (data.t_trigger >= t_r[0] - s.search_min_s) & (
        data.t_trigger <= t_r[-1] - s.search_max_s
    )
    t_t, y_s = data.t_trigger[keep], data.y_sensor[keep]
    if t_t.size < 10:
        raise ExperimentError(f"only {t_t.size} sensor readings overlap the joint log")
    est = estimate_delay(
        t_r,
        y_r,
        t_t,
        y_s,
        search_min_s=s.search_min_s,
        search_max_s=s.search_max_s,
        require_interior=require_interior,
    )
    res = residual_after_sync(t_r, y_r, t_t, y_s, est.delta_t_s, frequency_hz=s.frequency_hz)
    return DelayResult(s, data, est, res)


def run_delay_experiment(
    robot: tuple[str, int],
    sensor: tuple[str, int] | None,
    settings: ExperimentSettings,
    *,
    progress: Progress | None = None,
    timeout: float = 30.0,
    require_interior: bool = True,
) -> DelayResult:
    """Connect, record the sine, analyse; optionally apply the estimate (SetSyncDelay)."""
    with FramedClient(*robot, timeout=timeout, client_name="sync-delay") as rc:
        try:
            if sensor is not None:
                with FramedClient(*sensor, timeout=timeout, client_name="sync-delay") as sc:
                    data = record_sine(rc, sc, settings, progress)
            else:
                data = record_sine(rc, None, settings, progress)
        except BaseException:
            # Interrupted (a progress callback raised, Ctrl-C) or failed: stop the motion this
            # run started and give control back before the connection closes; best effort,
            # the connection may be what failed.
            with contextlib.suppress(Exception):
                rc.call(CommandId.RESET_MOTION)
                rc.release_control()
            raise
        result = analyse(data, settings, require_interior=require_interior)
        if settings.apply:
            rc.call(CommandId.SET_SYNC_DELAY, float(result.estimate.delta_t_s))
            result.extra["applied_delta_t_ms"] = result.estimate.delta_t_s * 1e3
        rc.release_control()
    return result


def run_sweep(
    robot: tuple[str, int],
    sensor: tuple[str, int] | None,
    settings: ExperimentSettings,
    frequencies: Sequence[float] = DEFAULT_SWEEP_HZ,
    *,
    progress: Progress | None = None,
) -> list[DelayResult]:
    """Fig. 8: the experiment at each frequency (at least two periods each)."""
    out = []
    for n, f in enumerate(frequencies):
        s = ExperimentSettings(
            **{
                **settings.__dict__,
                "frequency_hz": float(f),
                "duration_s": max(settings.duration_s, 2.0 / f),
                "ramp_s": None,
            }
        )

        def step(frac: float, msg: str, n: int = n, f: float = f) -> None:
            if progress is not None:
                progress((n + frac) / len(frequencies), f"{f:g} Hz: {msg}")

        out.append(run_delay_experiment(robot, sensor, s, progress=step, require_interior=False))
    return out


def write_json(path: str | Path, obj: Any) -> None:
    """Write ``obj`` as JSON atomically (temporary file in the same directory, rename)."""
    write_atomically(prepare_output_path(path), json.dumps(obj, indent=1, allow_nan=True) + "\n")


class PlotUnavailableError(ExperimentError):
    """matplotlib is not installed."""


def write_plots(
    directory: str | Path, result: DelayResult | None, sweep: Sequence[DelayResult] = ()
) -> list[Path]:
    """The paper's figures 6-9 as PNG under ``directory``; returns the files written."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise PlotUnavailableError(
            "plots need matplotlib: pip install matplotlib (or the 'plot' extra)"
        ) from None
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []

    def save(fig: Any, name: str) -> None:
        path = d / name
        fig.tight_layout()
        with atomic_path(path) as tmp:  # a reader never sees half a figure
            fig.savefig(tmp, dpi=110)
        plt.close(fig)
        files.append(path)

    if result is not None:
        data, t0 = result.data, result.data.t_start
        tr, ts = data.t_robot - t0, data.t_trigger - t0
        inside = (tr >= ts.min()) & (tr <= ts.max())  # the robot log also holds the approach
        fig, (a, b) = plt.subplots(2, 1, figsize=(8, 6))
        # top: lines only (every 4 ms sample and every trigger as a dot made a solid band);
        # bottom, the zoom: the samples themselves
        a.plot(tr[inside], data.y_robot[inside], "-", lw=0.8, label="$y^R(t_k^R)$")
        a.plot(ts, data.y_sensor, "-", lw=0.6, alpha=0.8, label="$y^S(t_i^T)$")
        b.plot(tr[inside], data.y_robot[inside], ".-", ms=3, lw=0.8, label="$y^R(t_k^R)$")
        b.plot(ts, data.y_sensor, ".", ms=3, label="$y^S(t_i^T)$")
        for ax in (a, b):
            ax.set_xlabel("time (s)")
            ax.set_ylabel("y (mm)")
        # Zoom on the rising zero crossing nearest the middle, where the delay shows.
        rising = np.flatnonzero((data.y_sensor[:-1] < 0) & (data.y_sensor[1:] >= 0))
        mid = 0.5 * (ts.min() + ts.max())
        tc = ts[rising[np.argmin(np.abs(ts[rising] - mid))]] if rising.size else mid
        b.set_xlim(tc - 0.015, tc + 0.015)
        window = (ts > tc - 0.015) & (ts < tc + 0.015)
        if window.any():
            lo, hi = data.y_sensor[window].min(), data.y_sensor[window].max()
            b.set_ylim(lo - 0.1 * (hi - lo + 1e-3), hi + 0.1 * (hi - lo + 1e-3))
        b.set_title("zoom: y^S stamped at t^T runs ΔT ahead of the robot log y^R")
        # outside the axes: inside, the legend covered the first peak
        a.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize="small")
        a.set_title(f"Fig. 6: sine motion at {result.settings.frequency_hz:g} Hz")
        save(fig, "fig6_sine.png")
        est = result.estimate
        fig, ax = plt.subplots(figsize=(6, 4))
        ax.plot(est.shifts_s * 1e3, est.mse * 1e6, ".-")
        ax.axvline(est.delta_t_s * 1e3, color="r", lw=0.8)
        ax.set_xlabel("ΔT (ms)")
        ax.set_ylabel("MSE (µm²)")
        ax.set_title(f"Fig. 7: MSE(ΔT), minimum at {est.delta_t_s * 1e3:.3f} ms")
        save(fig, "fig7_mse.png")
        syn = result.residual.synced
        fig, ax = plt.subplots(figsize=(8, 3.5))
        ax.plot(syn.times_s - t0, syn.residual_um, lw=0.6)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("residual (µm)")
        ax.set_title(f"Fig. 9: residual after synchronisation (max {syn.max_um:.1f} µm)")
        save(fig, "fig9_residual.png")
    if sweep:
        fig, ax = plt.subplots(figsize=(6, 4))
        f = [r.settings.frequency_hz for r in sweep]
        ax.semilogx(f, [r.delta_t_ms for r in sweep], "o-", label="estimated ΔT")
        true_ms = sweep[0].extra.get("true_delta_t_ms")
        if true_ms is not None:
            ax.axhline(true_ms, color="k", ls="--", lw=0.8, label=f"true ΔT {true_ms:.3f} ms")
            ax.legend(fontsize="small")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("ΔT (ms)")
        ax.set_title("Fig. 8: ΔT against the sine frequency")
        ax.grid(True, which="both", lw=0.3)
        save(fig, "fig8_sweep.png")
    return files


def judge(
    r: DelayResult, limits: QualityLimits | None = None, *, need_windows: bool = False
) -> Verdict:
    """The quality verdict of one run (:func:`sync.delay.assess_run`): ΔT per window over the
    full-amplitude part of the sine, loss, the residual with and without synchronisation.
    ``need_windows``: a run too short for two windows is not trusted (one ``delay`` run; a
    sweep's low frequencies never fit two windows in a few seconds)."""
    limits = QualityLimits() if limits is None else limits
    st = r.settings
    # the full-amplitude part of the sine, with a cycle's margin for the start of the move
    margin = 0.05
    t0 = r.data.t_start + st.rest_s + st.ramp + margin
    t1 = r.data.t_start + st.rest_s + st.duration_s - st.ramp
    window = max(limits.window_s, 2.0 / st.frequency_hz)  # as window_delays cuts them
    # the ramp grows with the duration up to its cap: the cap's, when two windows need it
    ramp = min(max(0.25, 1.0 / st.frequency_hz), 1.0) if st.ramp_s is None else st.ramp_s
    min_duration = 2 * ramp + margin + 2 * window if need_windows else None
    windows = window_delays(
        r.data.t_robot,
        r.data.y_robot,
        r.data.t_trigger,
        r.data.y_sensor,
        (t0, t1),
        period_s=1.0 / st.frequency_hz,
        limits=limits,
        search_min_s=st.search_min_s,
        search_max_s=st.search_max_s,
    )
    full = (r.data.t_trigger >= t0) & (r.data.t_trigger <= t1)
    robot = (r.data.t_robot >= t0) & (r.data.t_robot <= t1)
    motion = (
        sine_amplitude(r.data.t_trigger[full], r.data.y_sensor[full], st.frequency_hz),
        sine_amplitude(r.data.t_robot[robot], r.data.y_robot[robot], st.frequency_hz),
        st.frequency_hz,
    )
    return assess_run(
        r.estimate,
        r.residual,
        r.data.statistics,
        windows,
        limits,
        motion=motion,
        min_duration_s=min_duration,
    )
