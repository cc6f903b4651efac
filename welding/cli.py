"""Command line of the welding application: ``python -m welding COMMAND``.

job check|show|run JOB.xml   validate, print, or process a job (run: --dry-run, --log)
tools list|show|add|edit|remove|import|export   the tool and frame database
status                       E-stop, power, motion, joints, position in a tool/frame, I/O
jog                          one joint step or one Cartesian step
move NAME --job JOB.xml      to a named location of a job (via, stitch, path start)
record NAME --job JOB.xml    manual teaching: the current location as a via item
teach                        3D seam teaching with the sensor; JSON and optionally a job
calibrate sensor-tool|laser-tool   tool calibration by least squares (--json, --save)
track --emulate              real-time seam tracking (--seam, --speed, --delta-t-ms, --json)
ilc --emulate                iterative learning control of a repeated pass (--trials, --json)
console --emulate            the operator console in the browser (127.0.0.1:8024)

Robot and sensor: ``--robot HOST:PORT`` / ``--sensor HOST:PORT`` (RobotSocket 4000,
SensorSocket 2000), or ``--emulate`` for an in-process emulated cell (simulated clock),
whose tools ``laser``, ``sensor`` and frame ``workpiece`` are added to the database when
it lacks them. The database is ``--tools PATH`` (default: $WELDING_TOOLS or
./welding-tools.json).

Exit codes: 0 ok, 1 the job/file has problems or the robot refused (error reply, abort),
2 usage, 3 robot or sensor unreachable, 130 interrupted (laser off first, motion stopped).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from robotsocket.client import RobotClient
from sensorsocket.client import SensorClient
from spec import cliargs
from spec.callcli import stop_signals_interrupt, unreachable
from spec.client import ClientTimeout
from spec.errors import ProtocolError, RemoteError, error_text
from spec.exitcodes import ExitCode
from spec.files import write_atomically
from welding import calibrate_cli
from welding import job as J
from welding.calibration import CalibrationError
from welding.console import cli as console_cli
from welding.process import JobAborted, JobRunner, PlanError, Progress, plan, steps_summary
from welding.teach import SeamTeacher, TeachError, record_here, seam_path
from welding.tools import TOOL_KINDS, Entry, Tables, ToolDB, ToolDBError, check_location
from welding.track_options import (
    add_dynamics_option,
    add_ilc_options,
    add_seam_option,
    add_track_options,
)

__all__ = ["main"]

log = logging.getLogger("welding")

DEFAULT_TOOLS = "welding-tools.json"


class CliError(Exception):
    """A failure to report in one line with an exit code."""

    def __init__(self, message: str, code: int = ExitCode.FAILED) -> None:
        super().__init__(message)
        self.code = code


# --- arguments -------------------------------------------------------------------------------


def _location(text: str) -> tuple[float, float, float, float, float, float]:
    try:
        values = [float(v) for v in text.split(",")]
        return check_location(values, "location")
    except (ValueError, ToolDBError) as exc:
        msg = f"expected x,y,z,rx,ry,rz (6 numbers), got {text!r}"
        raise argparse.ArgumentTypeError(msg) from exc


def _name(text: str) -> str:
    if not J.NAME_RE.fullmatch(text):
        raise argparse.ArgumentTypeError(
            f"bad name {text!r}: 1-64 letters, digits, '_', '.', '-' (not first '.' or '-')"
        )
    return text


def _add_tools_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--tools",
        metavar="PATH",
        default=os.environ.get("WELDING_TOOLS", DEFAULT_TOOLS),
        help="tool and frame database (default: $WELDING_TOOLS or ./%(default)s)",
    )


def _add_cell_options(
    p: argparse.ArgumentParser, *, sensor: bool = False, sensor_help: str = ""
) -> None:
    where = p.add_mutually_exclusive_group(required=True)
    cliargs.add_endpoint(where, "robot")
    where.add_argument(
        "--emulate",
        action="store_true",
        help="run against an in-process emulated cell (simulated clock)",
    )
    if sensor:
        cliargs.add_endpoint(p, "sensor", ", with --robot" + sensor_help)
    add_seam_option(p, "straight", " (with --emulate)")
    p.add_argument("--seed", type=int, default=0, help="the emulated cell's seed")
    add_dynamics_option(p)
    for which in ("sensor", "laser"):
        p.add_argument(
            f"--{which}-tool-error",
            type=_location,
            default=(0.0,) * 6,
            metavar="DX,DY,DZ,RX,RY,RZ",
            help=f"the emulated cell's true {which} tool = nominal · this (mm, deg)",
        )
    cliargs.add_token_file(p, "the robot's", dest="token_file")
    p.add_argument(
        "--enable-power",
        action="store_true",
        help="switch arm power on if it is off (a real robot: be sure)",
    )
    p.add_argument(
        "--timeout",
        type=cliargs.positive_float,
        default=10.0,
        help="seconds for each reply (default %(default)s)",
    )
    _add_tools_option(p)


def _parser() -> argparse.ArgumentParser:
    parser = cliargs.Parser(
        prog="python -m welding",
        description="24-Laser: welding jobs, tools and frames, job processing, seam teaching.",
        epilog="Exit codes: 0 ok, 1 problems/refused/aborted, 2 usage, 3 unreachable, "
        "130 interrupted.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log at INFO level")
    sub = parser.add_subparsers(dest="command", required=True)

    job = sub.add_parser("job", help="check, show or run a job file")
    jsub = job.add_subparsers(dest="action", required=True)
    for action, text in (
        ("check", "validate a job (names every problem with line:column)"),
        ("show", "print a job's items and what running it does"),
        ("run", "process a job through RobotSocket"),
    ):
        p = jsub.add_parser(action, help=text, description=text)
        p.add_argument("job", metavar="JOB.xml")
        if action == "run":
            # tracked paths trigger the sensor: its trigger endpoint (else as on the robot)
            _add_cell_options(p, sensor=True, sensor_help="; its triggers, for tracked paths")
            p.add_argument("--dry-run", action="store_true", help="motion only, every output off")
            p.add_argument(
                "--log",
                type=cliargs.output_file,
                metavar="OUT.json",
                help="write the run's log (robot-clock times) as JSON",
            )
            p.add_argument("--no-progress", action="store_true", help="no progress bar")
        else:
            _add_tools_option(p)
            p.add_argument(
                "--no-tools",
                action="store_true",
                help="do not check tool and frame names against the database",
            )
            if action == "show":
                p.add_argument("--json", action="store_true", help="print JSON")

    tools = sub.add_parser("tools", help="the tool and frame database")
    _add_tools_option(tools)
    tsub = tools.add_subparsers(dest="action", required=True)
    p = tsub.add_parser("list", help="every tool and frame")
    p.add_argument("--json", action="store_true")
    p = tsub.add_parser("show", help="one tool or frame")
    p.add_argument("name")
    p.add_argument("--json", action="store_true")
    p = tsub.add_parser("add", help="add a tool (flange-relative) or frame (base-relative)")
    p.add_argument("name", type=_name)
    p.add_argument("--kind", choices=(*TOOL_KINDS, "frame"), required=True)
    p.add_argument("--location", type=_location, required=True, metavar="X,Y,Z,RX,RY,RZ")
    p.add_argument("--note", default="")
    p = tsub.add_parser("edit", help="change a tool's or frame's location or note")
    p.add_argument("name")
    p.add_argument("--location", type=_location, metavar="X,Y,Z,RX,RY,RZ")
    p.add_argument("--note")
    p = tsub.add_parser("remove", help="remove a tool or frame")
    p.add_argument("name")
    p = tsub.add_parser("import", help="merge another database file")
    p.add_argument("file")
    p.add_argument("--replace", action="store_true", help="overwrite entries of the same name")
    p = tsub.add_parser("export", help="write the database to a file")
    p.add_argument("file", type=cliargs.output_file)

    p = sub.add_parser("status", help="robot state, joints, position and I/O")
    _add_cell_options(p)
    p.add_argument("--tool", default="flange", help="tool of the position (default flange)")
    p.add_argument("--frame", default="world", help="frame of the position (default world)")
    p.add_argument("--json", action="store_true")

    p = sub.add_parser("jog", help="one joint step (--joint) or Cartesian step (--axis)")
    _add_cell_options(p)
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--joint", type=int, choices=range(1, 7), metavar="1..6")
    what.add_argument("--axis", choices=("x", "y", "z", "rx", "ry", "rz"))
    p.add_argument("--step", type=float, required=True, help="deg (joint, rx..rz) or mm")
    p.add_argument("--tool", default="flange", help="tool of a Cartesian step")
    p.add_argument("--frame", default="world", help="frame of a Cartesian step")

    p = sub.add_parser("move", help="move to a named location of a job")
    _add_cell_options(p)
    p.add_argument("name", help="a via or stitch item, or a path (its start)")
    p.add_argument("--job", required=True, metavar="JOB.xml")
    p.add_argument("--linear", action="store_true", help="a straight-line move (ToolMoveL)")

    p = sub.add_parser("record", help="manual teaching: save the current location as a via")
    _add_cell_options(p)
    p.add_argument("name", type=_name)
    p.add_argument(
        "--job",
        required=True,
        type=cliargs.output_file,
        metavar="JOB.xml",
        help="created when missing",
    )
    p.add_argument("--tool", default="flange")
    p.add_argument("--frame", default="world")
    p.add_argument("--replace", action="store_true", help="replace an item of that name")

    p = sub.add_parser("teach", help="3D seam teaching with the sensor")
    _add_cell_options(p, sensor=True)
    p.add_argument("--sensor-tool", default="sensor", help="^N_S T in the database")
    p.add_argument("--step", type=cliargs.positive_float, default=5.0, help="mm between points")
    p.add_argument("--length", type=cliargs.positive_float, default=100.0, help="mm to teach")
    p.add_argument("--max-points", type=cliargs.positive_int, default=100)
    p.add_argument("--speed", type=cliargs.positive_float, default=50.0, help="mm/s")
    p.add_argument("--json", type=cliargs.output_file, metavar="OUT.json")
    p.add_argument(
        "--job",
        metavar="JOB.xml",
        type=cliargs.output_file,
        help="add the seam as a path to this job",
    )
    p.add_argument("--name", type=_name, default="seam", help="the path's name")
    p.add_argument("--tool", default="laser", help="the path's tool (default laser)")
    p.add_argument("--frame", default="world", help="the path's frame (default world)")
    p.add_argument("--velocity", type=cliargs.positive_float, default=20.0, help="mm/s")
    p.add_argument("--power", type=cliargs.nonnegative_float, default=1000.0, help="W")
    p.add_argument("--preflow", type=cliargs.nonnegative_float, default=0.5, help="s")
    p.add_argument("--postflow", type=cliargs.nonnegative_float, default=0.5, help="s")

    calibrate_cli.add_parser(sub, _add_cell_options)
    console_cli.add_parser(sub, _add_tools_option)

    p = sub.add_parser("track", help="real-time seam tracking on the emulated cell")
    add_track_options(p)
    _add_tools_option(p)

    p = sub.add_parser("ilc", help="iterative learning control of a repeated pass (emulated)")
    add_ilc_options(p)
    return parser


# --- connections -----------------------------------------------------------------------------


@dataclass
class Cell:
    robot: RobotClient
    sensor: SensorClient | None
    tables: Tables
    dwell: Any
    emulated: Any = None  # the EmulatedSession with --emulate


def _read_tables(path: str) -> Tables:
    return ToolDB(path).read()


@contextmanager
def _cell(args: argparse.Namespace, *, control: bool, sensor: bool = False) -> Iterator[Cell]:
    if args.emulate:
        from welding.emulate import EmulatedSession  # the only path that builds a cell

        session = EmulatedSession(
            args.seam,
            seed=args.seed,
            dynamics=args.dynamics,
            sensor_tool_error=args.sensor_tool_error,
            laser_tool_error=args.laser_tool_error,
        )
        try:
            tables = merge_cell_tools(args.tools, session.tables)
            if sensor:
                session.sensor.take_control()
            yield Cell(session.robot, session.sensor, tables, session.dwell, session)
        finally:
            session.close()
        return
    import time

    tables = _read_tables(args.tools)
    host, port = args.robot
    try:
        robot = RobotClient(host, port, timeout=args.timeout)
    except (OSError, ClientTimeout) as exc:
        raise CliError(f"robot: {unreachable(host, port, exc)}", ExitCode.UNREACHABLE) from None
    sensor_client: SensorClient | None = None
    try:
        if sensor:
            if args.sensor is None:
                raise CliError("--sensor HOST:PORT is needed with --robot", ExitCode.USAGE)
            try:
                sensor_client = SensorClient(*args.sensor, timeout=args.timeout)
            except (OSError, ClientTimeout) as exc:
                sensor_host, sensor_port = args.sensor
                why = unreachable(sensor_host, sensor_port, exc)
                raise CliError(f"sensor: {why}", ExitCode.UNREACHABLE) from None
            sensor_client.take_control(args.token_file or "")
        if control:
            robot.take_control(args.token_file or "")
            if not robot.status().powered:
                if not args.enable_power:
                    raise CliError("arm power is off: switch it on, or pass --enable-power")
                robot.enable_power()
        yield Cell(robot, sensor_client, tables, time.sleep)
        # Given back, not lost: a lost controller would be a controlled stop [RS-7.10].
        if control:
            robot.release_control()
        if sensor_client is not None:
            sensor_client.release_control()
    finally:
        for c in (robot, sensor_client):
            if c is not None:
                c.close()


def merge_cell_tools(path: str, cell_tables: Tables) -> Tables:
    """The database with the emulated cell's tools and frame added when it lacks them (the
    file is updated, so later commands without --emulate know them too)."""
    db = ToolDB(path)
    current = db.read()
    missing = [
        e
        for e in (*cell_tables.tools.values(), *cell_tables.frames.values())
        if not (current.has_frame(e.name) if e.kind == "frame" else current.has_tool(e.name))
    ]
    if missing:

        def add(t: Tables) -> None:
            for e in missing:
                if not (t.has_frame(e.name) if e.kind == "frame" else t.has_tool(e.name)):
                    t.add(e)

        current = db.update(add)
        names = ", ".join(e.name for e in missing)
        print(f"added the emulated cell's {names} to {path}", file=sys.stderr)
    for e in (*cell_tables.tools.values(), *cell_tables.frames.values()):
        mine = current.frame(e.name) if e.kind == "frame" else current.tool(e.name)
        if not np.allclose(mine.location, e.location, atol=1e-6):
            print(
                f"warning: {e.name} in {path} differs from the emulated cell's; this run uses "
                f"the database's (a calibrated one?). For the cell's: python -m welding tools "
                f"remove {e.name} --tools {path}, and run again",
                file=sys.stderr,
            )
    return current


# --- job -------------------------------------------------------------------------------------


def _load_job(path: str, tables: Tables | None) -> J.Job:
    try:
        return J.load(
            path,
            has_tool=None if tables is None else tables.has_tool,
            has_frame=None if tables is None else tables.has_frame,
        )
    except OSError as exc:
        raise CliError(f"cannot read {path}: {exc.strerror}") from None


def _check_before_cell(args: argparse.Namespace) -> None:
    """The job's problems as `job check` lists them, tool and frame names included (against
    the database, and with --emulate the cell's own tools), before anything starts."""
    try:
        _load_job(args.job, None)
    except J.JobError:
        tables = _read_tables(args.tools)
        tools: set[str] = set()
        frames: set[str] = set()
        if args.emulate:
            from welding.emulate import CELL_FRAME, CELL_TOOLS

            tools, frames = set(CELL_TOOLS), {CELL_FRAME}
        J.load(
            args.job,
            has_tool=lambda n: n in tools or tables.has_tool(n),
            has_frame=lambda n: n in frames or tables.has_frame(n),
        )
        raise


def cmd_job(args: argparse.Namespace) -> int:
    if args.action == "run":
        return cmd_run(args)
    tables = None if args.no_tools else _read_tables(args.tools)
    job = _load_job(args.job, tables)
    # without a database only the names are known: tracked paths' sensor view is unchecked
    any_tables = tables is None
    sensor_tool = None if any_tables else "sensor"
    steps = plan(job, tables if tables is not None else _any_tables(job), sensor_tool=sensor_tool)
    if args.action == "check":
        n = len(job.sequence())
        print(f"{args.job}: ok, job {job.name!r}, {n} items to run, {len(steps)} steps")
        return 0
    if args.json:
        print(json.dumps(_job_json(job, steps), indent=2))
        return 0
    print(f"job {job.name!r}" + (f": {job.description}" if job.description else ""))
    for i, item in enumerate(job.sequence(), 1):
        print(f"  {i:3d}. {_describe(item)}")
    s = steps_summary(steps)
    print(
        f"  {s.get('MoveJ', 0)} joint moves, {s.get('MoveL', 0)} linear moves, "
        f"{s.get('Track', 0)} tracked welds, "
        f"{s.get('Output', 0)} output switches, {s.get('Dwell', 0)} dwells"
    )
    return 0


def _any_tables(job: J.Job) -> Tables:
    """Identity tools and frames of every name the job uses (``--no-tools``)."""
    t = Tables({}, {})
    for name in sorted(job.tools() - {"flange"}):
        t.add(Entry(name, "tool", (0.0,) * 6))
    for name in sorted(job.frames() - {"world"} - job.tools()):
        t.add(Entry(name, "frame", (0.0,) * 6))
    return t


def _describe(item: J.Item) -> str:
    if isinstance(item, J.Pause):
        return f"pause {item.name}: {item.duration:g} s"
    if isinstance(item, J.Via):
        a = item.at
        return f"via {item.name}: {a.values} tool {a.tool} frame {a.frame}, {item.speed:g} %"
    if isinstance(item, J.Stitch):
        return (
            f"stitch {item.name}: {item.duration:g} s at {item.power:g} W, "
            f"{item.at.values} tool {item.at.tool} frame {item.at.frame}"
        )
    arcs = sum(isinstance(s, J.Arc) for s in item.segments)
    return (
        f"path {item.name}: {len(item.segments) - arcs} lines, {arcs} arcs, "
        f"{item.velocity:g} mm/s, laser {'on' if item.laser else 'off'} {item.power:g} W, "
        f"gas {'on' if item.gas else 'off'} (pre {item.preflow:g} s, post {item.postflow:g} s), "
        f"crossjet {'on' if item.crossjet else 'off'}" + (", tracked" if item.tracked else "")
    )


def _job_json(job: J.Job, steps: list[Any]) -> dict[str, Any]:
    return {
        "name": job.name,
        "description": job.description,
        "order": [i.name for i in job.sequence()],
        "items": [{"kind": type(i).__name__.lower(), "text": _describe(i)} for i in job.items],
        "steps": steps_summary(steps),
    }


class _ProgressBar:
    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self.last = ""

    def __call__(self, p: Progress) -> None:
        if not self.enabled:
            return
        done = min(p.index, p.total)
        bar = "#" * round(20 * done / max(1, p.total))
        what = "done" if p.phase == "done" else f"{p.item} ({p.phase})"
        line = f"[{bar:<20}] {done}/{p.total} {what}"
        if self.tty:
            print(f"\r{line:<72}", end="" if p.phase != "done" else "\n", file=sys.stderr)
        elif p.phase in ("move", "approach", "pause", "done"):
            print(line, file=sys.stderr)
        sys.stderr.flush()


def cmd_run(args: argparse.Namespace) -> int:
    # A missing or broken file is said before the cell starts, the robot is connected or the
    # tool database gets the emulated cell's tools, with every problem `job check` names.
    _check_before_cell(args)
    with _cell(args, control=True, sensor=not args.emulate and args.sensor is not None) as cell:
        job = _load_job(args.job, cell.tables)
        emulated = cell.emulated is not None
        runner = JobRunner(
            cell.robot,
            cell.tables,
            dry_run=args.dry_run,
            dwell=cell.dwell,
            on_progress=_ProgressBar(not args.no_progress),
            # tracked paths: the emulated cell's trigger endpoint and simulated clock
            sensor_endpoint=cell.emulated.cell.udp_address
            if emulated
            else (cell.sensor.get_trigger_endpoint() if cell.sensor is not None else None),
            real_time=not emulated,
        )
        try:
            entries = runner.run(job)
        except JobAborted as exc:
            if sys.stderr.isatty():
                print(file=sys.stderr)
            _write_log(args, job, "aborted", exc.log, exc.reason)
            print(f"python -m welding: {exc}", file=sys.stderr)
            return ExitCode.INTERRUPTED if exc.reason == "interrupted" else ExitCode.FAILED
        _write_log(args, job, "done", entries, None)
        what = "dry run" if args.dry_run else "run"
        t = [e.t for e in entries]
        print(f"job {job.name!r}: {what} done in {t[-1] - t[0]:.3f} s of robot time")
        return 0


def _write_log(
    args: argparse.Namespace, job: J.Job, result: str, entries: list[Any], reason: str | None
) -> None:
    if args.log is None:
        return
    data = {
        "job": job.name,
        "file": args.job,
        "dry_run": args.dry_run,
        "result": result,
        "reason": reason,
        "clock": "robot",
        "entries": [e.to_json() for e in entries],
    }
    write_atomically(args.log, json.dumps(data, indent=1) + "\n")


# --- tools -----------------------------------------------------------------------------------


def _entry_json(e: Entry) -> dict[str, Any]:
    return {"name": e.name, "kind": e.kind, "location": list(e.location), "note": e.note}


def cmd_tools(args: argparse.Namespace) -> int:
    db = ToolDB(args.tools)
    a = args.action
    if a in ("list", "show"):
        t = db.read()
        if a == "show":
            entries = [t.frames[args.name] if args.name in t.frames else t.tool(args.name)]
        else:
            entries = [t.tool("flange"), *t.tools.values(), t.frame("world"), *t.frames.values()]
        if args.json:
            print(json.dumps([_entry_json(e) for e in entries], indent=2))
            return 0
        for e in entries:
            loc = ", ".join(f"{v:g}" for v in e.location)
            print(f"{e.name:<16} {e.kind:<7} ({loc})" + (f"  {e.note}" if e.note else ""))
        return 0
    if a == "add":
        db.add(Entry(args.name, args.kind, args.location, args.note))
    elif a == "edit":
        if args.location is None and args.note is None:
            raise CliError("nothing to change: give --location and/or --note", ExitCode.USAGE)
        db.edit(args.name, location=args.location, note=args.note)
    elif a == "remove":
        db.remove(args.name)
    elif a == "import":
        n = db.import_from(args.file, replace=args.replace)
        print(f"imported {n} entries into {args.tools}")
        return 0
    else:
        db.export_to(args.file)
        print(f"exported {args.tools} to {args.file}")
        return 0
    print(f"{args.tools}: {a} {args.name}: done (revision {db.read().revision})")
    return 0


# --- status, jog, move, record ---------------------------------------------------------------


def cmd_status(args: argparse.Namespace) -> int:
    with _cell(args, control=False) as cell:
        r = cell.robot
        tool, frame = cell.tables.tool(args.tool), cell.tables.frame(args.frame)
        st = r.status()
        outputs, inputs = r.list_io()
        data: dict[str, Any] = {
            "estop": st.estop,
            "powered": st.powered,
            "moving": st.moving,
            "queue": st.queue,
            "last_error": st.last_error,
            "last_message": st.last_message,
            "time": st.time,
            "joints": [round(float(q), 6) for q in r.herej()],
            "position": {
                "tool": args.tool,
                "frame": args.frame,
                "location": [round(v, 6) for v in r.here(tool.location, frame.location)],
            },
            "outputs": {n: r.read_io(n) for n in outputs},
            "inputs": {n: r.read_io(n) for n in inputs},
        }
    if args.json:
        print(json.dumps(data, indent=2))
        return 0

    def onoff(v: bool) -> str:
        return "on" if v else "off"

    print(
        f"E-stop {'ENGAGED' if data['estop'] else 'clear'}, power {onoff(st.powered)}, "
        f"{'moving' if st.moving else 'still'} (queue {st.queue}), robot time {st.time:.3f} s"
    )
    if st.last_error:
        print(f"last error {st.last_error}: {st.last_message}")
    print("joints (deg): " + ", ".join(f"{q:.3f}" for q in data["joints"]))
    loc = ", ".join(f"{v:.3f}" for v in data["position"]["location"])
    print(f"{args.tool} in {args.frame} (mm, deg): {loc}")
    print("outputs: " + ", ".join(f"{n} {onoff(v)}" for n, v in data["outputs"].items()))
    print("inputs: " + ", ".join(f"{n} {onoff(v)}" for n, v in data["inputs"].items()))
    return 0


def _wait(robot: RobotClient) -> None:
    if not robot.wait_end_move(120.0):
        raise CliError("the move did not end within 120 s")


def cmd_jog(args: argparse.Namespace) -> int:
    with _cell(args, control=True) as cell:
        r = cell.robot
        if args.joint is not None:
            q = r.herej()
            q[args.joint - 1] += args.step
            r.joint_move([float(v) for v in q])
            _wait(r)
            print("joints (deg): " + ", ".join(f"{v:.3f}" for v in r.herej()))
            return 0
        tool = cell.tables.tool(args.tool).location
        frame = cell.tables.frame(args.frame).location
        loc = list(r.here(tool, frame))
        loc[("x", "y", "z", "rx", "ry", "rz").index(args.axis)] += args.step
        r.tool_move_l(loc, tool, frame)
        _wait(r)
        here = r.here(tool, frame)
        print(f"{args.tool} in {args.frame}: " + ", ".join(f"{v:.3f}" for v in here))
        return 0


def cmd_move(args: argparse.Namespace) -> int:
    with _cell(args, control=True) as cell:
        try:
            loc = J.named_location(_load_job(args.job, cell.tables), args.name)
        except KeyError as exc:
            raise CliError(exc.args[0]) from None
        tool = cell.tables.tool(loc.tool).location
        frame = cell.tables.frame(loc.frame).location
        move = cell.robot.tool_move_l if args.linear else cell.robot.tool_move_j
        move(loc.values, tool, frame)
        _wait(cell.robot)
        here = cell.robot.here(tool, frame)
        print(f"at {args.name}: {loc.tool} in {loc.frame}: " + ", ".join(f"{v:.3f}" for v in here))
        return 0


def _job_or_new(path: str, tables: Tables) -> J.Job | None:
    return _load_job(path, tables) if Path(path).exists() else None


def _add_item(job: J.Job | None, path: str, item: J.Item, replace: bool) -> J.Job:
    if job is None:
        name = Path(path).stem if J.NAME_RE.fullmatch(Path(path).stem) else "job"
        return J.Job(name, (item,))
    names = [i.name for i in job.items]
    if item.name in names:
        if not replace:
            raise CliError(f"{path} has an item {item.name!r} already (--replace to overwrite)")
        items = tuple(item if i.name == item.name else i for i in job.items)
        return J.Job(job.name, items, job.order, job.description)
    order = None if job.order is None else (*job.order, item.name)
    return J.Job(job.name, (*job.items, item), order, job.description)


def cmd_record(args: argparse.Namespace) -> int:
    with _cell(args, control=False) as cell:
        job = _job_or_new(args.job, cell.tables)
        loc = record_here(cell.robot, cell.tables, args.tool, args.frame)
        J.save(_add_item(job, args.job, J.Via(args.name, loc), args.replace), args.job)
        print(f"{args.job}: via {args.name} = {loc.values} ({args.tool} in {args.frame})")
        return 0


# --- teach -----------------------------------------------------------------------------------


def cmd_teach(args: argparse.Namespace) -> int:
    with _cell(args, control=True, sensor=True) as cell:
        assert cell.sensor is not None
        job = _job_or_new(args.job, cell.tables) if args.job else None
        teacher = SeamTeacher(
            cell.robot,
            cell.sensor,
            cell.tables.tool(args.sensor_tool).location,
            step_mm=args.step,
            max_points=args.max_points,
            max_length_mm=args.length,
            speed_mm_s=args.speed,
        )
        result = teacher.teach()
        error = (
            cell.emulated.seam_error_mm([q.seam2base for q in result.points])
            if cell.emulated is not None
            else None
        )
        path = None
        if len(result.points) >= 2:
            path = seam_path(
                result,
                args.name,
                tool=args.tool,
                frame=args.frame,
                tables=cell.tables,
                velocity=args.velocity,
                power=args.power,
                preflow=args.preflow,
                postflow=args.postflow,
            )
    data = {
        "seam": args.seam if args.emulate else None,
        "points": [q.to_json() for q in result.points],
        "count": len(result.points),
        "measurements": result.measurements,
        "stop_reason": result.stop_reason,
        "length_mm": result.length_mm,
        "taught_error_max_mm": error,
        "seconds_per_point": result.seconds_per_point,
        "robot_seconds": result.robot_seconds,
        "wall_seconds_per_point": result.wall_seconds / max(1, len(result.points)),
        "clock": "simulated" if args.emulate else "real",
    }
    if args.json:
        write_atomically(args.json, json.dumps(data, indent=1) + "\n")
    err = "" if error is None else f", max error {error * 1e3:.1f} µm from the true seam"
    print(
        f"taught {len(result.points)} points over {result.length_mm:.1f} mm "
        f"({result.stop_reason}){err}, {result.seconds_per_point:.3f} s per point"
    )
    if args.job:
        if path is None:
            raise CliError("too few points for a path; the job was not written")
        J.save(_add_item(job, args.job, path, replace=True), args.job)
        print(f"{args.job}: path {args.name} ({len(path.segments)} segments)")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    return calibrate_cli.cmd_calibrate(args, _cell)


def cmd_track(args: argparse.Namespace) -> int:
    from welding.emulate import cmd_track as run_track

    args.sensor_tool_location = None
    if args.sensor_tool is not None:
        args.sensor_tool_location = _read_tables(args.tools).tool(args.sensor_tool).location
    return run_track(args)


def cmd_ilc(args: argparse.Namespace) -> int:
    from welding.ilc_emulate import cmd_ilc as run_ilc

    return run_ilc(args)


# --- main ------------------------------------------------------------------------------------


#: What Ctrl-C stopped, for the one line a command ends with (cliargs.interrupted). The
#: clients close without giving control back: the robot and the sensor see a lost
#: controller and make their controlled stop (laser off first, motion stopped) [RS-7.10].
_CONTROLLED_STOP = "control dropped, the robot stops in a controlled way (laser off)"
_STOPPED = {
    "calibrate": f"calibration stopped, nothing saved; {_CONTROLLED_STOP}",
    "teach": f"teaching stopped, the job not written; {_CONTROLLED_STOP}",
    "track": "tracked weld stopped: laser off, motion reset",
    "ilc": "ILC trials stopped: laser off, motion reset",
    "jog": f"jog stopped; {_CONTROLLED_STOP}",
    "move": f"move stopped; {_CONTROLLED_STOP}",
    "job run": f"job stopped; {_CONTROLLED_STOP}",
}

COMMANDS = {
    "job": cmd_job,
    "tools": cmd_tools,
    "status": cmd_status,
    "jog": cmd_jog,
    "move": cmd_move,
    "record": cmd_record,
    "teach": cmd_teach,
    "calibrate": cmd_calibrate,
    "track": cmd_track,
    "ilc": cmd_ilc,
    "console": console_cli.cmd_console,
}


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.ERROR,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    try:
        with stop_signals_interrupt():
            return COMMANDS[args.command](args)
    except BrokenPipeError:
        raise  # our stdout was closed (`| head`): cliargs.run_cli ends quietly
    except J.JobError as exc:
        print(exc, file=sys.stderr)
        return ExitCode.FAILED
    except CliError as exc:
        print(f"python -m welding: error: {exc}", file=sys.stderr)
        return exc.code
    except (ToolDBError, PlanError, TeachError, CalibrationError, ValueError) as exc:
        print(f"python -m welding: error: {exc}", file=sys.stderr)
        return ExitCode.FAILED
    except RemoteError as exc:
        print(f"python -m welding: the robot refused: {error_text(exc)}", file=sys.stderr)
        return ExitCode.FAILED
    except (ProtocolError, OSError) as exc:
        print(f"python -m welding: error: {error_text(exc)}", file=sys.stderr)
        return ExitCode.UNREACHABLE
    except KeyboardInterrupt:  # the safe stops ran on the way out (laser off, motion stopped)
        command = " ".join([args.command, getattr(args, "action", "") or ""]).strip()
        stopped = _STOPPED.get(command, _STOPPED.get(args.command, ""))
        return cliargs.interrupted("python -m welding", stopped)
