"""``python -m welding ilc --emulate``: the ILC trials (:mod:`welding.ilc_loop`) on the
simulated cell, through its servers, each trial judged against the emulator's truth.

Only this module and :mod:`welding.emulate` of the ILC build a :mod:`cell`; the trials see
the robot and the sensor through the protocol, as they would a real cell.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from cell.cell import CellTiming, EmulatedCell
from cell.options import timing_kwargs
from cell.rtcell import CellProcess
from cell.seams import cell_seam
from cell.truth import WeldRecorder, WeldTruth
from kinematics.types import IDENTITY_LOC, Loc
from robotsocket.rtprocess import ChildStartError
from spec.client import FramedClient
from spec.clocks import ClockKind
from spec.errors import ProtocolError
from spec.exitcodes import ExitCode
from spec.files import write_atomically
from spec.realtime import realtime_threads
from spec.registry import CommandId
from welding import job as J
from welding.emulate import CELL_FRAME, CELL_TOOLS, TRACKER_PRIORITY, cell_tables
from welding.ilc import Convergence, IlcTable, LearningDiverges
from welding.ilc_loop import (
    IlcSettings,
    IlcTrial,
    PassGeometry,
    PathPass,
    check_learnable,
    job_path,
    path_pass,
    run_ilc,
)
from welding.tools import BUILTIN_FRAME, BUILTIN_TOOL
from welding.track_loop import TrackOutcome
from welding.tracking import seam_error

__all__ = ["cmd_ilc", "job_table", "run_ilc_emulated"]

log = logging.getLogger(__name__)


def run_ilc_emulated(
    settings: IlcSettings,
    *,
    seam: str = "sine",
    dynamics: str = "elastic",
    timing: CellTiming | None = None,
    seed: int = 0,
    workpiece_error: Loc | None = None,
    job: J.Job | None = None,
    path: str | None = None,
    table: IlcTable | None = None,
    save: Any = None,
    progress: Any = None,
    clock: ClockKind = "sim",
) -> dict[str, Any]:
    """The trials on an emulated cell (``seam`` of ``welding track``, ``dynamics``); the
    result as the JSON of ``welding ilc`` (trials in order, each with ``error_max_mm``
    against the truth), plus ``"profiles"`` (per trial (arc length, error) arrays) and
    ``"table"`` (the learned :class:`IlcTable`), which the JSON leaves out.
    ``workpiece_error`` lies on top of the seam's own placement (:func:`cell.seams.cell_seam`):
    a workpiece placed otherwise than the one a ``table`` was learned on. ``job``: learn its
    ``path`` (:func:`welding.ilc_loop.job_path`; tools ``laser``, ``sensor`` and frame
    ``workpiece`` of :func:`welding.emulate.cell_tables`) at its velocity instead of the
    cell's pass at ``settings.speed_mm_s``. ``clock="real"``: the cell's real-time part in a
    child process (:class:`~cell.rtcell.CellProcess`, as ``track --clock real``), the trials
    a client of its servers on the wall clock; ValueError when the child cannot start."""
    shape, placement = cell_seam(seam, workpiece_error or IDENTITY_LOC)
    config: dict[str, Any] = {
        "timing": timing or CellTiming(),
        "seam": shape,
        "workpiece_error": placement,
        "seed": seed,
        "dynamics": dynamics,
    }
    line: PathPass | None = None
    if clock == "real":
        try:
            child = CellProcess(**config)
        except ChildStartError as exc:
            raise ValueError(f"the real-time cell did not start: {exc}") from None
        try:
            # this process is the controller: real-time below the child's own threads
            with realtime_threads(TRACKER_PRIORITY) as got:
                log.info("ILC threads: scheduling %s", got)
                side: _Side = _ChildSide(child.start())
                if job is not None:
                    line = path_pass(job_path(job, path), cell_tables(child))
                result = _learn(side, settings, line, table, save, progress)
        finally:
            child.close()
    else:
        cell = EmulatedCell(clock="sim", **config)
        cell.core.set_delay(cell.true_delta_t_s())  # as `track --true-delta-t`
        side = _SimSide(cell)
        if job is not None:
            line = path_pass(job_path(job, path), cell_tables(cell))
        cell.start()
        try:
            result = _learn(side, settings, line, table, save, progress)
        finally:
            cell.close()
    if line is not None:
        settings = replace(settings, speed_mm_s=line.speed_mm_s, weld_mm=line.length_mm)
    trials, conv, learned = result
    return {
        "seam": seam,
        "job": None if job is None else job.name,
        "path": None if job is None else job_path(job, path).name,
        "dynamics": dynamics,
        "clock": clock,
        "speed_mm_s": settings.speed_mm_s,
        "source": settings.source,
        "track": settings.track,
        "gain": settings.gain,
        "q_hz": settings.q_hz,
        "model_payload_kg": settings.model_payload_kg,
        "run_up_mm": settings.run_up_mm,
        "average_from": settings.average_from,
        "arm_payload_kg": settings.params.payload_kg,
        "convergence": conv.summary(),
        "trusted": all(not t.untrusted for t in trials),
        "trials": [t.summary() for t in trials],
        "profiles": [t.profile for t in trials],
        "table": learned,
    }


class _Side(Protocol):
    """What the trials need of the emulated cell, in this process or in the real-time child."""

    robot_address: tuple[str, int]
    udp_address: tuple[str, int]
    laser_tool: Loc
    sensor_tool: Loc
    real_time: bool

    def record(self) -> None: ...
    def truth(self) -> WeldTruth: ...


class _SimSide:
    def __init__(self, cell: EmulatedCell) -> None:
        self.robot_address = cell.robot_address
        self.udp_address = cell.udp_address
        self.laser_tool = cell.laser_tool
        self.sensor_tool = cell.sensor_tool
        self.real_time = False
        recorder = WeldRecorder(cell)
        self.record = recorder.start
        self.truth = recorder.truth


class _ChildSide:
    """The cell in the real-time child: its servers, facts and record of the laser's path;
    the ΔT in force set to its true one (as ``track --true-delta-t``)."""

    def __init__(self, child: CellProcess) -> None:
        facts = child.child.facts
        self.robot_address = child.robot_address
        self.udp_address = child.udp_address
        self.laser_tool: Loc = tuple(facts["laser_tool"])
        self.sensor_tool: Loc = tuple(facts["sensor_tool"])
        self.real_time = True
        self.record = child.record_weld
        self.truth = child.weld_truth
        with FramedClient(*self.robot_address, timeout=10.0, client_name="ilc") as c:
            c.take_control()
            c.call(CommandId.SET_SYNC_DELAY, child.true_delta_t_s())
            c.release_control()


def _learn(
    side: _Side,
    settings: IlcSettings,
    line: PathPass | None,
    table: IlcTable | None,
    save: Any,
    progress: Any,
) -> tuple[list[IlcTrial], Convergence, IlcTable]:
    def judge(outcome: TrackOutcome, g: PassGeometry) -> tuple[float, float, np.ndarray]:
        # over the cycles of the laser's window by their stamps (the move's start on the
        # robot's grid), not over those the laser was on: a client switches the laser, so
        # those are when its thread ran
        truth = side.truth()
        s = g.weld.s_at(truth.cycle_times - outcome.t0)
        inside = (truth.cycle_times >= outcome.t0) & (s >= g.laser_from_mm)
        inside &= s <= g.laser_to_mm
        laser = truth.cycle_laser[inside]
        scene = truth.scene
        lat, hgt = seam_error(
            laser, scene.base2workpiece, scene.path.lateral, scene.joint.seam_height_mm
        )
        err = np.hypot(lat, hgt)
        if not len(err):
            return math.nan, math.nan, np.zeros((0, 2))
        profile = np.column_stack([g.weld.project(laser) - g.laser_from_mm, err])
        return float(err.max()), float(np.sqrt(np.mean(err**2))), profile

    if line is not None:
        settings = replace(settings, speed_mm_s=line.speed_mm_s, weld_mm=line.length_mm)
    client = FramedClient(*side.robot_address, timeout=30.0, client_name="ilc")
    try:
        return run_ilc(
            client,
            side.udp_address,
            settings,
            judge,
            laser_tool=side.laser_tool,
            sensor_tool=side.sensor_tool,
            table=table,
            save=save,
            progress=progress,
            record=side.record,
            job_pass=line,
            real_time=side.real_time,
        )
    finally:
        with contextlib.suppress(OSError, ProtocolError):  # not held, or gone
            client.release_control()
        client.close()


def _line(trial: IlcTrial) -> str:
    truth = (
        f"error against the truth max {trial.error_max_mm:.4f} mm, rms {trial.error_rms_mm:.4f} mm"
    )
    stopped = f"; STOPPED: {trial.stopped}" if trial.stopped else ""
    if trial.untrusted:
        what = "tracked, with the table" if trial.tracked else "not learned from"
        return f"trial {trial.trial} UNTRUSTED ({what}): {trial.untrusted}; {truth}{stopped}"
    if trial.tracked:
        return (
            f"trial {trial.trial} (tracked, with the table): {truth}; table up to "
            f"{trial.correction_max_mm:.3f} mm{stopped}"
        )
    return (
        f"trial {trial.trial}: {truth}; the ILC measured {trial.measured_max_mm:.4f} mm; "
        f"correction up to {trial.correction_max_mm:.3f} mm{stopped}"
    )


def cmd_ilc(args: argparse.Namespace) -> int:
    """Learn, print a line per trial, write the JSON, the table and the plots."""
    settings = IlcSettings(
        speed_mm_s=args.speed,
        weld_mm=args.length,
        trials=args.trials,
        source=args.source,
        gain=args.gain,
        q_hz=args.q_hz,
        track=args.track,
        model_payload_kg=args.model_payload_kg,
        run_up_mm=args.run_up,
        average_from=args.average_from,
    )
    job = None
    table_path = args.table
    if args.job:
        job = J.load(
            args.job,
            has_tool=lambda n: n in (*CELL_TOOLS, BUILTIN_TOOL),
            has_frame=lambda n: n in (CELL_FRAME, BUILTIN_FRAME),
        )
        try:
            learned_path = job_path(job, args.path)
            check_learnable(learned_path)  # before a cell is built
            name = learned_path.name
        except ValueError as exc:
            print(f"python -m welding: error: {exc}", file=sys.stderr)
            return ExitCode.USAGE
        table_path = table_path or str(job_table(Path(args.job), name))
    elif args.path:
        print("python -m welding: error: --path names a path of a JOB.xml", file=sys.stderr)
        return ExitCode.USAGE
    table = None
    if table_path and Path(table_path).exists():
        try:
            table = IlcTable.load(table_path)
        except ValueError as exc:
            print(f"python -m welding: error: {exc}", file=sys.stderr)
            return ExitCode.USAGE
        print(f"reusing the table of {table_path} ({table.trials} trials learned)")
    try:
        result = run_ilc_emulated(
            settings,
            seam=args.seam,
            dynamics=args.dynamics,
            timing=CellTiming(**timing_kwargs(args)),
            seed=args.seed,
            job=job,
            path=args.path,
            table=table,
            save=(lambda t: t.save(table_path)) if table_path else None,
            progress=lambda t: print(_line(t), flush=True),
            clock=args.clock,
        )
    except (LearningDiverges, ValueError) as exc:
        print(f"python -m welding: error: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    profiles = result.pop("profiles")
    result.pop("table")
    if args.json:
        write_atomically(args.json, json.dumps(result, indent=1) + "\n")
    if args.plot:
        plot_trials(result, profiles, Path(args.plot))
    trials = result["trials"]
    if any(t["stopped"] for t in trials):
        return ExitCode.FAILED
    untrusted = [t for t in trials if not t["trusted"]]
    if untrusted:
        print(
            f"UNTRUSTED: {len(untrusted)} of {len(trials)} trials"
            f" ({', '.join(str(t['trial']) for t in untrusted)}) could not be measured on time,"
            " so no convergence is claimed"
        )
        for t in untrusted:  # the reasons on stderr, as every tool's UNTRUSTED (docs/CLI.md)
            print(f"trial {t['trial']}: {t['untrusted']}", file=sys.stderr)
        return ExitCode.UNTRUSTED
    learned = [t["error_max_mm"] for t in trials if not t["tracked"]]
    tracked = [t["error_max_mm"] for t in trials if t["tracked"]]
    line = (
        f"error max {learned[0]:.4f} -> {learned[-1]:.4f} mm over {len(learned)} trials"
        if learned
        else "no trial learned"
    )
    if tracked:
        line += f"; tracked with the table {tracked[0]:.4f} mm"
    print(line)
    return ExitCode.OK


def job_table(job_file: Path, path: str) -> Path:
    """Where the table learned on ``path`` of the job in ``job_file`` is kept: beside the
    job, ``JOB.PATH.ilc.json``."""
    return job_file.with_name(f"{job_file.stem}.{path}.ilc.json")


def plot_trials(result: dict[str, Any], profiles: list[np.ndarray], out_dir: Path) -> None:
    """``ilc_trials.png`` (the truth error along the path, per trial) and
    ``ilc_convergence.png`` (max and rms per trial, log scale)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ValueError("--plot needs matplotlib (the `plot` extra)") from None
    out_dir.mkdir(parents=True, exist_ok=True)
    title = (
        f"{result['seam']} seam, {result['speed_mm_s']:g} mm/s, dynamics {result['dynamics']}, "
        f"source {result['source']}, {result.get('clock', 'sim')} clock"
        + (", tracked" if result["track"] else "")
    )
    fig, ax = plt.subplots(figsize=(10, 4))
    for t, p in zip(result["trials"], profiles, strict=True):
        ax.plot(p[:, 0], p[:, 1] * 1e3, linewidth=1, label=f"trial {t['trial']}")
    ax.set_xlabel("along the weld (mm)")
    ax.set_ylabel("laser error against the truth (µm)")
    ax.set_yscale("log")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(out_dir / "ilc_trials.png", dpi=100)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4))
    k = [t["trial"] for t in result["trials"]]
    ax.semilogy(k, [t["error_max_mm"] for t in result["trials"]], "o-", label="max")
    ax.semilogy(k, [t["error_rms_mm"] for t in result["trials"]], "s--", label="rms")
    ax.axhline(0.1, color="grey", linewidth=0.8, label="0.1 mm")
    ax.set_xticks(k)  # whole trials: there is no trial 1.5
    ax.set_xlabel("trial")
    ax.set_ylabel("error against the truth (mm)")
    ax.set_title(title, fontsize=8)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / "ilc_convergence.png", dpi=100)
    plt.close(fig)
