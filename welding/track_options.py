"""The options of ``python -m welding track`` and the seams it tracks, apart from
:mod:`welding.emulate`: building the parser of every ``python -m welding`` command needs them,
and importing the emulated cell (about 0.35 s) only the commands that run one."""

from __future__ import annotations

import argparse

from cell.options import add_dynamics_option, add_timing_options, add_tool_error_options
from cell.seams import SEAM_NAMES, SEAMS
from kinematics.types import Loc
from spec import cliargs
from spec.clocks import CLOCK_KINDS

__all__ = [
    "SEAM_NAMES",
    "TRACK_SEAMS",
    "add_dynamics_option",
    "add_ilc_options",
    "add_seam_option",
    "add_track_options",
]

#: The cell's seam catalogue (:mod:`cell.seams`) as (shape, placement) pairs: the view the
#: console reads. Every command takes the same names (``add_seam_option``).
TRACK_SEAMS: dict[str, tuple[str, Loc]] = {n: (s.shape, s.placement) for n, s in SEAMS.items()}


def add_seam_option(p: argparse.ArgumentParser, default: str, note: str = "") -> None:
    """``--seam`` with the names of the cell's seam catalogue: one option, one set of names,
    in every command that builds an emulated cell."""
    p.add_argument(
        "--seam",
        choices=SEAM_NAMES,
        default=default,
        help=f"the emulated cell's seam{note}: "
        + "; ".join(f"{n}: {s.description}" for n, s in SEAMS.items()),
    )


def add_track_options(p: argparse.ArgumentParser) -> None:
    """Options of ``python -m welding track`` (the cell's timing options included)."""
    p.add_argument(
        "--emulate",
        action="store_true",
        required=True,
        help="track on an emulated cell (--clock sim: in this process; real: its real-time "
        "part in a child process); required",
    )
    add_seam_option(p, "sine")
    p.add_argument("--speed", type=cliargs.number_in(1.0, 500.0), default=250.0, help="mm/s")
    p.add_argument(
        "--delta-t-ms",
        type=cliargs.number_in(-100.0, 100.0),
        help="override the ΔT in force (default: measured first, section VI procedure)",
    )
    p.add_argument(
        "--true-delta-t",
        action="store_true",
        help="skip the measurement: the cell's true ΔT is set in force",
    )
    p.add_argument("--length", type=cliargs.number_in(10.0, 200.0), default=200.0, help="mm")
    p.add_argument("--rate", type=cliargs.number_in(10.0, 1000.0), default=200.0, help="Hz")
    p.add_argument("--untracked", action="store_true", help="weld the nominal path (baseline)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--clock",
        choices=CLOCK_KINDS,
        default="sim",
        help="sim: the cell's simulated clock (deterministic); real: its 4 ms cycle on the "
        "wall clock in a real-time child process, the tracker a client that keeps pace "
        "(default %(default)s)",
    )
    p.add_argument(
        "--tolerance",
        type=cliargs.number_in(0.001, 10.0),
        default=0.1,
        metavar="MM",
        help="the tracker's own error estimate must stay within it: exit 0, else 1 "
        "(default %(default)s)",
    )
    p.add_argument(
        "--per-cycle",
        action="store_true",
        help="send one Alter per cycle instead of timed corrections ahead (AlterQueue)",
    )
    p.add_argument("--json", type=cliargs.output_file, metavar="OUT.json")
    p.add_argument(
        "--plot", metavar="DIR", type=cliargs.output_dir, help="write track.png (needs matplotlib)"
    )
    p.add_argument(
        "--sensor-tool",
        metavar="NAME",
        help="the sensor tool the robot computes seam points with, from the tool database "
        "(e.g. one `calibrate sensor-tool --save NAME` wrote; default: the cell's nominal)",
    )
    add_dynamics_option(p)
    add_timing_options(p)
    add_tool_error_options(p)


def add_ilc_options(p: argparse.ArgumentParser) -> None:
    """Options of ``python -m welding ilc`` (docs/ILC.md)."""
    p.add_argument(
        "job",
        nargs="?",
        metavar="JOB.xml",
        help="learn a path of this job (one <line>, tools laser/sensor, frame workpiece of the "
        "cell); its table is kept beside it (JOB.PATH.ilc.json) and reused; default: the "
        "cell's pass, as track",
    )
    p.add_argument("--path", metavar="NAME", help="the job's path to learn (default: its only)")
    p.add_argument(
        "--emulate",
        action="store_true",
        required=True,
        help="learn on the emulated cell (through its servers; --clock); required",
    )
    p.add_argument(
        "--clock",
        choices=CLOCK_KINDS,
        default="sim",
        help="sim: the cell's simulated clock (deterministic); real: its 4 ms cycle on the "
        "wall clock in a real-time child process; a trial whose corrections came late or "
        "whose readings have gaps is reported UNTRUSTED, not learned from, and the run "
        "exits 4 (default %(default)s)",
    )
    add_seam_option(p, "sine")
    p.add_argument("--speed", type=cliargs.number_in(1.0, 500.0), default=250.0, help="mm/s")
    p.add_argument("--length", type=cliargs.number_in(10.0, 200.0), default=200.0, help="mm")
    p.add_argument(
        "--trials",
        type=cliargs.int_in(0, 100),
        default=5,
        help="passes learned (default 5; 0 with --track: only the tracked weld, e.g. with a "
        "--table learned before)",
    )
    p.add_argument(
        "--source",
        choices=("seam", "joints"),
        default="seam",
        help="the error learned from: seam = the sensor's measurement of where the tool went "
        "(end-effector ILC, default); joints = the measured joints (motor encoders)",
    )
    p.add_argument(
        "--gain",
        type=cliargs.number_in(0.01, 10.0),
        default=1.0,
        help="learning gain γ (default 1; a gain the model says diverges is refused)",
    )
    p.add_argument(
        "--average-from",
        type=cliargs.int_in(0, 100),
        default=3,
        metavar="TRIAL",
        help="from this trial on, the table is the running mean of the updates learned since "
        "the trial before it: the sensor's trial-to-trial error (jitter, noise) is averaged "
        "out instead of learned anew in every trial (default 3; 0: never)",
    )
    p.add_argument(
        "--q-hz",
        type=cliargs.number_in(1.0, 120.0),
        default=50.0,
        help="cutoff of the zero-phase Q-filter (Hz, default 50)",
    )
    p.add_argument(
        "--run-up",
        type=cliargs.number_in(0.0, 500.0),
        default=40.0,
        metavar="MM",
        help="the pass starts this far before the sensor's look-ahead: the elastic arm's "
        "ringing after the start's acceleration dies out before the weld (default 40)",
    )
    p.add_argument(
        "--track",
        action="store_true",
        help="after the trials, one tracked weld with the learned table (the tracker follows "
        "the workpiece's deviation from the taught seam; the JSON's last trial, tracked)",
    )
    p.add_argument(
        "--model-payload-kg",
        type=cliargs.number_in(0.0, 50.0),
        default=5.0,
        help="the payload the ILC's model assumes (the emulated arm carries 5 kg)",
    )
    p.add_argument(
        "--table",
        metavar="PATH",
        type=cliargs.output_file,
        help="the learned table: reused when the file exists, written after every trial",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=cliargs.output_file, metavar="OUT.json")
    p.add_argument(
        "--plot",
        metavar="DIR",
        type=cliargs.output_dir,
        help="write ilc_trials.png, ilc_convergence.png (matplotlib)",
    )
    add_dynamics_option(p)
    add_timing_options(p)
