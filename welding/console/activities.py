"""The console's long-running actions: a job, teaching, ΔT, a tool calibration, a tracked weld.

Each action is a function run in the activity's own thread by
:meth:`welding.console.backend.Console.start`: ``act`` is what the status stream shows of it
(written only through its methods, under its lock, and read under the same lock),
``cancelled`` is the operator's abort, checked at each measurement. An action returns its
result for the result pages (None: none), or raises: the console turns that into the
activity's "failed" or "aborted" with the exception's one line.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from welding import job as J
from welding.process import JobRunner, Progress
from welding.teach import SeamTeacher, TeachError

__all__ = [
    "Activity",
    "CountedDetector",
    "CountedSensor",
    "IlcCancelled",
    "run_calibration",
    "run_delta_t",
    "run_ilc",
    "run_job",
    "run_teach",
    "run_track",
]


@dataclass
class Activity:
    """A long-running action the status stream reports; its thread writes it through
    :meth:`update`, :meth:`add_point` and :meth:`finish`, the stream reads :meth:`to_json`,
    all under one lock."""

    kind: str  # "job" | "teach" | "delta_t" | "calibration" | "track"
    detail: dict[str, Any] = field(default_factory=dict)
    state: str = "running"  # running | done | aborted | failed
    #: What the state alone does not say (never the state's own word again).
    message: str = ""
    #: What the operator can do about a refusal, one line ("" when nothing to add).
    hint: str = ""
    cancel: Callable[[], None] | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    @property
    def running(self) -> bool:
        with self._lock:
            return self.state == "running"

    def update(self, **detail: Any) -> None:
        with self._lock:
            self.detail.update(detail)

    def count(self, key: str) -> None:
        with self._lock:
            self.detail[key] += 1

    def add_point(self, point: list[float]) -> None:
        """One more seam point for the teaching page (a new list: a reader's stays whole)."""
        with self._lock:
            points = [*self.detail["points"], point]
            self.detail.update(points=points, count=len(points))

    def finish(self, state: str, message: str = "", hint: str = "") -> None:
        with self._lock:
            self.state, self.message, self.hint = state, message, hint

    def to_json(self) -> dict[str, Any]:
        with self._lock:
            return {"kind": self.kind, "state": self.state, "message": self.message,
                    "hint": self.hint, **self.detail}  # fmt: skip


def run_job(act: Activity, cancelled: threading.Event, runner: JobRunner, job: J.Job) -> None:
    def progress(p: Progress) -> None:
        act.update(index=p.index, item=p.item, phase=p.phase)

    runner.on_progress = progress
    runner.run(job)
    act.finish("done")


def _rounded(values: Any) -> list[float]:
    return [round(float(v), 3) for v in values]


def run_teach(act: Activity, cancelled: threading.Event, teacher: SeamTeacher) -> None:
    """Each seam point is shown as it is measured; an abort stops at the next one."""

    def each(seam2base: Any) -> None:
        if cancelled.is_set():
            raise TeachError("cancelled by the operator")
        if seam2base is not None:
            act.add_point(_rounded(seam2base[:3, 3]))

    teacher.on_measure = each
    result = teacher.teach()
    act.update(
        points=[_rounded(q.position) for q in result.points],
        count=len(result.points),
        length_mm=round(result.length_mm, 3),
    )
    act.finish("done", result.stop_reason)


def run_delta_t(
    act: Activity, cancelled: threading.Event, robot: Any, sensor: Any, settings: Any
) -> dict[str, Any]:
    """Section VI's measurement from where the arm is; its result for the ΔT page."""
    from sync.experiment import ExperimentError, analyse, record_sine
    from welding.console.deltat import result_json

    def progress(fraction: float, text: str) -> None:
        if cancelled.is_set():
            raise ExperimentError("cancelled by the operator")
        act.update(fraction=round(fraction, 3))

    data = record_sine(robot, sensor, settings, progress)
    result = result_json(analyse(data, settings))
    act.update(fraction=1.0, delta_t_ms=result["delta_t_ms"], trusted=result["trusted"])
    act.finish("done", "; ".join(result["reasons"]))
    return result


class CountedSensor:
    """The seam sensor as a calibration uses it, each acquisition counted (``tick``, which
    raises to abort)."""

    def __init__(self, sensor: Any, tick: Callable[[], None]) -> None:
        self._sensor, self._tick = sensor, tick
        self.address = getattr(sensor, "address", "HOST:PORT")

    def acquire(self) -> int:
        self._tick()
        return int(self._sensor.acquire())

    def get_data(self) -> Any:
        return self._sensor.get_data()


class CountedDetector:
    """A spot detector, each reading counted (``tick``, which raises to abort)."""

    def __init__(self, detector: Any, tick: Callable[[], None]) -> None:
        self._detector, self._tick = detector, tick
        self.plate2base = detector.plate2base
        self.beam = detector.beam
        self.sigma_centre_mm = detector.sigma_centre_mm
        self.sigma_radius_mm = detector.sigma_radius_mm

    def measure(self) -> Any:
        self._tick()
        return self._detector.measure()


def run_calibration(
    act: Activity, cancelled: threading.Event, cal: Any, which: str, truth: Any, nominal: str
) -> dict[str, Any]:
    """A tool calibration (``cal`` built on a Counted sensor or detector); its result."""
    from welding.calibrate_cli import result_json

    est = cal.run()
    result = result_json(which, est, truth, nominal, beam_only=which == "laser-tool")
    act.finish("done", f"residual rms {est.residual_rms_mm * 1e3:.1f} µm")
    return result


def run_track(
    act: Activity, cancelled: threading.Event, seam: str, speed: float, tracked: bool
) -> dict[str, Any]:
    """A tracked weld on the real clock, on a copy of the emulated cell in its own real-time
    child (as ``welding track --emulate --clock real``): the tracker's own verdict, and the
    error against the copy's true seam beside it. The operator's abort stops it (laser off,
    motion reset) and keeps what it welded."""
    from welding.emulate import run_tracking

    run = run_tracking(seam, speed, track=tracked, clock="real", cancelled=cancelled.is_set)
    laser, true = run.plot["laser"], run.plot["seam"]
    result = run.summary() | {
        "top": {k: np.round(v[:, :2], 4).tolist() for k, v in run.plot.items()},
        "error_um": np.round(
            np.column_stack([laser[:, 0], (laser[:, 1] - true[:, 1]) * 1e3]), 3
        ).tolist(),
    }
    if cancelled.is_set():
        act.finish("aborted", "cancelled by the operator")
        return result
    verdict = run.verdict.get("line") or run.verdict.get("reason") or ""
    stopped = f"; STOPPED: {run.stopped}" if run.stopped else ""
    act.finish("done", f"max {run.tracking_error_max_mm * 1e3:.1f} µm{stopped}; {verdict}")
    return result


class IlcCancelled(Exception):
    """The operator aborted the ILC between two trials."""


def run_ilc(act: Activity, cancelled: threading.Event, seam: str, settings: Any) -> dict[str, Any]:
    """ILC trials on a copy of the emulated cell with elastic joints (as ``welding ilc
    --emulate``, simulated clock: the trials repeat one pass exactly); each trial's error
    against the truth reaches the page as it ends. The operator's abort stops it between
    two trials."""
    from welding.ilc_emulate import run_ilc_emulated

    done: list[dict[str, Any]] = []

    def progress(trial: Any) -> None:
        done.append(trial.summary())
        act.update(trials=list(done))
        if cancelled.is_set():
            raise IlcCancelled("cancelled by the operator")

    run = run_ilc_emulated(settings, seam=seam, progress=progress)
    result = {k: v for k, v in run.items() if k not in ("profiles", "table")}
    result["profiles"] = [np.round(p, 4).tolist() for p in run["profiles"]]
    first, last = run["trials"][0], run["trials"][-1]
    act.finish(
        "done",
        f"{len(run['trials'])} trials: max {first['error_max_mm'] * 1e3:.1f} µm in the first, "
        f"{last['error_max_mm'] * 1e3:.1f} µm in the last",
    )
    return result
