"""Command line of the emulated work cell.

``python -m cell serve [--robot-port 4000] [--sensor-port 2000] [--udp-port 2001]
[--clock real|sim] [timing options]`` serves the cell until Ctrl-C (in ``sim`` the clock only
advances while a client waits in WaitEndMove).

``python -m cell demo`` (what ``make demo`` runs) starts a real-time cell on free ports, drives
the robot through RobotSocket, takes a sensor frame through SensorSocket (PGM under ./out/),
runs a short ΔT measurement through the sockets, prints ΔT and the residuals beside the
paper's figures, then runs the conformance harness against the cell if it is installed.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from cell.cell import CellError, CellTiming, EmulatedCell
from cell.options import (
    add_dynamics_option,
    add_timing_options,
    add_tool_error_options,
    timing_kwargs,
)
from cell.rtcell import CellProcess
from cell.seams import SEAM_NAMES, cell_seam
from robotsocket.rtprocess import ChildStartError
from sensorsocket.pgm import write_pgm
from spec import cliargs
from spec.client import FramedClient, wait_end_move
from spec.clocks import CLOCK_KINDS
from spec.errors import ProtocolError, error_text
from spec.exitcodes import ExitCode
from spec.params import Image, Joints, Location
from spec.registry import CommandId
from spec.server import ServerPolicy, serve_until_signal
from sync.experiment import (
    ExperimentError,
    ExperimentSettings,
    exposed_late_text,
    judge,
    run_delay_experiment,
    write_plots,
)

log = logging.getLogger("cell")


def _parser() -> cliargs.Parser:
    p = cliargs.Parser(prog="python -m cell", description="The emulated robot + sensor work cell.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=cliargs.Parser)
    for name, text in (("serve", "serve the cell until Ctrl-C"), ("demo", "the make demo tour")):
        s = sub.add_parser(name, help=text)
        s.add_argument("--host", default="127.0.0.1")
        default_ports = (4000, 2000, 2001) if name == "serve" else (0, 0, 0)
        s.add_argument("--robot-port", type=cliargs.port, default=default_ports[0])
        s.add_argument("--sensor-port", type=cliargs.port, default=default_ports[1])
        s.add_argument("--udp-port", type=cliargs.port, default=default_ports[2])
        s.add_argument("--clock", choices=CLOCK_KINDS, default="real")
        s.add_argument("--model", default="RX90B")
        s.add_argument("--joint", choices=("butt", "fillet", "lap"), default="butt")
        s.add_argument("--seam", choices=SEAM_NAMES, default="straight", help="(cell/seams.py)")
        s.add_argument("--seed", type=cliargs.seed, default=0)
        s.add_argument("-v", "--verbose", action="store_true")
        add_dynamics_option(s)
        add_timing_options(s)
        add_tool_error_options(s)
        if name == "serve":
            s.add_argument(
                "--in-process",
                action="store_true",
                help="real clock: run the robot loop, UDP and sensor in this process instead "
                "of the real-time child process used by default (docs/REALTIME.md)",
            )
            s.add_argument(
                "--frame-timeout",
                type=cliargs.number_in(0.1, 600.0),
                default=ServerPolicy.frame_timeout,
                metavar="S",
                help="time a client has to finish a frame it started (s, 0.1..600, default "
                "%(default)g as in PROTOCOL.md RS-7.5; announced in Hello)",
            )
        if name == "demo":
            s.add_argument(
                "--out",
                type=cliargs.output_dir,
                default="out",
                help="directory for the frame and plots (created)",
            )
            s.add_argument(
                "--duration",
                type=cliargs.number_in(0.01, 3600.0),
                default=4.0,
                help="sine duration (s, 0.01..3600)",
            )
            s.add_argument(
                "--rate",
                type=cliargs.number_in(0.1, 10000.0),
                default=100.0,
                help="trigger rate (Hz, 0.1..10000)",
            )
            s.add_argument("--no-conformance", action="store_true")
    return p


def _cell_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "timing": CellTiming(**timing_kwargs(args)),
        "model": args.model,
        "dynamics": args.dynamics,
        "joint": args.joint,
        "seam": cell_seam(args.seam)[0],
        "workpiece_error": cell_seam(args.seam)[1],
        "seed": args.seed,
        "sensor_tool_error": args.sensor_tool_error,
        "laser_tool_error": args.laser_tool_error,
        "host": args.host,
        "robot_port": args.robot_port,
        "sensor_port": args.sensor_port,
        "udp_port": args.udp_port,
    }


def _cell(args: argparse.Namespace) -> EmulatedCell:
    return EmulatedCell(clock=args.clock, **_cell_kwargs(args))


def cmd_serve(args: argparse.Namespace) -> int:
    cell: EmulatedCell | CellProcess
    policy = ServerPolicy(frame_timeout=args.frame_timeout)
    if args.clock == "real" and not args.in_process:
        try:  # the real-time part in a child process (docs/REALTIME.md)
            cell = CellProcess(policy=policy, **_cell_kwargs(args)).start()
        except ChildStartError as exc:
            raise CellError(str(exc)) from None
    else:
        cell = EmulatedCell(clock=args.clock, policy=policy, **_cell_kwargs(args)).start()

    def announce() -> None:
        for k, v in cell.describe().items():
            print(f"{k:>22}: {round(v, 9) if isinstance(v, float) else v}")
        if args.clock == "sim":
            print("simulated clock: time advances while a client waits in WaitEndMove")
        sys.stdout.flush()

    serve_until_signal([], on_stop=cell.close, ready=announce)
    # serve_until_signal returns only after SIGINT or SIGTERM, the cell closed: one line
    # saying so and exit 130, as every tool ends on Ctrl-C (docs/CLI.md, "Exit codes")
    return cliargs.interrupted(
        "python -m cell", "the emulated cell stopped (robot, sensor), its servers closed"
    )


def _fmt(loc: Any) -> str:
    # round first, then + 0.0: no "-0.00" for values that round to zero
    return "(" + ", ".join(f"{round(float(v), 2) + 0.0:.2f}" for v in loc) + ")"


def _robot_tour(robot: FramedClient) -> None:
    info = robot.hello()
    print(
        f"\n2/4 RobotSocket (paper III-A): {info['vendor']!s} {info['model']!s}, protocol "
        f"{info['version']!s}; VAL3-like commands over TCP"
    )
    robot.take_control("")
    robot.call(CommandId.ENABLE_POWER)
    (q,) = robot.call(CommandId.HEREJ)
    assert isinstance(q, Joints)
    print(f"  EnablePower, Herej() = {_fmt(q.values)} deg (the cell's ready pose)")
    away = list(q.values)
    away[0] += 10.0
    robot.call(CommandId.JOINT_MOVE, Joints(away))
    wait_end_move(robot, 10.0)
    config = robot.call(CommandId.GET_SYNC_CONFIG)
    tool = config[3]
    world = Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    (here,) = robot.call(CommandId.HERE, tool, world)
    assert isinstance(here, Location)
    print(f"  JointMove(joint 1 + 10 deg), Here(sensor tool) = {_fmt(here.as_tuple())} mm, deg")
    robot.call(CommandId.JOINT_MOVE, Joints(list(q.values)))
    wait_end_move(robot, 10.0)
    (here,) = robot.call(CommandId.HERE, tool, world)
    assert isinstance(here, Location)
    print(f"  back over the seam:          Here(sensor tool) = {_fmt(here.as_tuple())}")
    robot.release_control()


def _sensor_tour(sensor: FramedClient, out: Path) -> None:
    info = sensor.hello()
    print(f"\n3/4 SensorSocket (paper III-B): {info['vendor']!s} {info['model']!s}")
    sensor.take_control("")
    (index,) = sensor.call(CommandId.ACQUIRE)
    time.sleep(0.05)
    data = sensor.call(CommandId.GET_DATA)
    seam = data[2]
    assert isinstance(seam, Location)
    _, image = sensor.call(CommandId.GET_IMAGE)
    assert isinstance(image, Image)
    pixels = np.frombuffer(image.data, dtype=np.uint8).reshape(image.height, image.width)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "frame.pgm"
    write_pgm(path, pixels)
    print(
        f"  Acquire: frame {index!s}, {image.width} x {image.height} laser-stripe image read "
        f"column by column, saved as {path}"
    )
    quality = data[3]
    assert isinstance(quality, float)
    found = "found" if data[1] == 0 else f"status {data[1]!s}"
    print(
        f"  GetData: seam {found} at {_fmt(seam.as_tuple())} in the sensor frame S, quality "
        f"{quality:.2f} (the cell starts with the seam centred under the sensor)"
    )
    sensor.release_control()


def _conformance(cell: EmulatedCell) -> bool:
    """Run the harness against the cell's three endpoints; True when all are conformant.

    The robot's run (about 17 s, mostly waiting: its frame-timeout case and real moves)
    overlaps the sensor's, which has its own endpoint and control; the sync run, whose
    deadlines are tens of ms, runs alone after both. The verdicts print in a fixed order."""
    if importlib.util.find_spec("conformance.cli") is None:
        print("  harness not installed, skipped")
        return True
    robot = _harness("robot", cell.robot_address, "--allow-motion")
    sensor = _harness("sensor", cell.sensor_address)
    ok = _verdict(robot, "robot", "RobotSocket, motion allowed")
    ok = _verdict(sensor, "sensor", "SensorSocket") and ok
    sync = _harness("sync", cell.udp_address)
    return _verdict(sync, "sync", "UDP trigger listener") and ok


def _harness(service: str, address: tuple[str, int], *extra: str) -> subprocess.Popen[str]:
    host, port = address
    cmd = [sys.executable, "-m", "conformance", service, f"{host}:{port}", "-q", *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _verdict(proc: subprocess.Popen[str], service: str, what: str) -> bool:
    """Wait for one harness run (at most 120 s) and print its verdict line."""
    try:
        stdout, _ = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        print(f"  {service:<7} timed out")
        return False
    total = (stdout.strip().splitlines() or [""])[-1]
    counts = total.removeprefix("total: ").split("  (")[0]
    verdict = "conformant" if proc.returncode == 0 else f"NOT conformant (exit {proc.returncode})"
    print(f"  {service:<7} {verdict}: {counts} ({what})")
    return proc.returncode == 0


def _experiment(cell: EmulatedCell, args: argparse.Namespace, out: Path) -> bool:
    """The ΔT measurement of paper section VI through the sockets; True when trusted."""
    d = cell.describe()
    settings = ExperimentSettings(duration_s=args.duration, trigger_rate_hz=args.rate)
    print(
        f"\n4/4 The ΔT measurement (paper VI): the sensor moves in a {settings.amplitude_mm:g} mm "
        f"sine across a straight seam at {settings.frequency_hz:g} Hz for "
        f"{settings.duration_s:g} s, triggered over UDP at {settings.trigger_rate_hz:g} Hz; the "
        f"robot's joints and the sensor's seam positions are matched by shifting one by ΔT ..."
    )
    first = cell.core.next_index
    result = run_delay_experiment(cell.robot_address, cell.sensor_address, settings)
    verdict = judge(result)
    truth = cell.measured_delta_t(first)
    design = cell.true_delta_t_s()
    t = cell.timing
    s = result.summary()
    syn, uns = s["residual_max_um"], s["unsynced_max_um"]
    rows = (
        ("ΔT measured (ms)", f"{result.delta_t_ms:.3f}", "4.9"),
        ("ΔT true in this run (ms)", f"{truth * 1e3:.3f}", ""),
        ("ΔT by design (ms)", f"{design * 1e3:.3f}", ""),
        ("trigger jitter width (ms)", f"{d['jitter_width_ms']:.2f}", "0.6"),
        ("seam error, synchronised, max (µm)", f"{syn:.1f}", "≈ 30"),
        ("seam error, synchronised, rms (µm)", f"{s['residual_rms_um']:.1f}", ""),
        ("seam error, not synchronised, max (µm)", f"{uns:.1f}", ""),
    )
    print(f"  {'':40} {'this run':>10} {'paper':>8}")
    for name, here, paper in rows:
        print(f"  {name:40} {here:>10} {paper:>8}")
    print(
        f"  ΔT by design = encoder latency {t.encoder_latency_s * 1e3:.2f} + network "
        f"{t.network_delay_s * 1e3:.2f} + mean trigger poll wait {0.5e3 / t.poll_rate_hz:.3f} + "
        f"mean start jitter {t.start_jitter_s * 0.5e3:.3f} + half the {t.acquisition_s * 1e3:.1f} "
        "ms readout (the seam is read at mid-frame);\n  the true ΔT of this run is what its "
        "exposures really had: the same plus this run's draw of the jitter."
    )
    st = result.data.statistics
    print(
        f"  datagrams this run: {st.get('sent', 0)} triggers sent, {st.get('matched', 0)} seam "
        f"points, {st.get('lost', 0)} lost, {st.get('late', 0)} late; {exposed_late_text(st)}"
    )
    try:
        files = write_plots(out, result)
        print(f"  figures 6, 7 and 9 of the paper: {', '.join(str(out / f.name) for f in files)}")
    except ExperimentError as exc:
        print(f"  plots skipped: {exc}")
    if verdict.ok:
        print(
            f"  verdict: ΔT {result.delta_t_ms:.3f} ms, {abs(result.delta_t_ms - truth * 1e3):.3f}"
            f" ms from this run's truth; synchronisation cuts the seam error {uns / syn:.1f}x "
            f"({uns:.0f} -> {syn:.0f} µm). OK"
        )
    else:
        print(f"  verdict: UNTRUSTED: {verdict.reason}")
    return verdict.ok


def cmd_demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    t0 = time.monotonic()
    # The harness engages the e-stop and drops controllers on purpose, and the robot's
    # controlled stops log warnings: expected here, not news for the person watching.
    for name in ("robotsocket", "sensorsocket", "spec", "sync"):
        logging.getLogger(name).setLevel(logging.ERROR)
    with _cell(args) as cell:
        d = cell.describe()
        print(
            "1/4 The work cell of the paper (Fig. 1), emulated: a Staubli RX90B with the "
            f"seam-tracking sensor on its flange, {d['clock']} clock"
        )
        print(f"  robot {d['robot']} (TCP), sensor {d['sensor']} (TCP), triggers {d['udp']}")
        print(
            f"  timing as in the paper: encoder latency {d['encoder_latency_ms']:.2f} ms, network "
            f"{d['network_delay_ms']:.2f} ms, trigger poll {d['trigger_poll_hz']:g} Hz, start "
            f"jitter {d['start_jitter_ms']:.2f} ms, readout {d['acquisition_ms']:.2f} ms"
        )
        with FramedClient(*cell.robot_address, timeout=20.0) as robot:
            _robot_tour(robot)
        with FramedClient(*cell.sensor_address, timeout=20.0) as sensor:
            _sensor_tour(sensor, out)
        trusted = _experiment(cell, args, out)
        conformant = True
        if not args.no_conformance:
            print("\nConformance: the harness checks the three endpoints against PROTOCOL.md")
            conformant = _conformance(cell)
    seconds = time.monotonic() - t0
    if trusted and conformant:
        print(f"\nResult: everything worked ({seconds:.0f} s).")
        return 0
    if not conformant:
        print(f"\nResult: an endpoint is not conformant ({seconds:.0f} s); see above.")
        return ExitCode.FAILED
    print(f"\nResult: the ΔT run could not be trusted ({seconds:.0f} s); see above.")
    return ExitCode.UNTRUSTED


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    try:
        if args.command == "serve":
            return cmd_serve(args)
        return cmd_demo(args)
    except BrokenPipeError:
        raise  # our stdout was closed (`| head`): cliargs.run_cli ends quietly
    except ValueError as exc:  # the kinematics (unknown model) and emulator argument checks
        print(f"python -m cell: error: {error_text(exc)}", file=sys.stderr)
        return ExitCode.USAGE
    except (CellError, ExperimentError, ProtocolError, OSError) as exc:
        print(f"python -m cell: error: {error_text(exc)}", file=sys.stderr)
        return ExitCode.FAILED
    except KeyboardInterrupt:  # the demo's cell and clients are closed on the way out
        print("python -m cell: interrupted", file=sys.stderr)
        return ExitCode.INTERRUPTED


def console() -> int:
    """The installed command (a console-script entry point of pyproject.toml)."""
    return cliargs.run_cli(main)


if __name__ == "__main__":
    sys.exit(console())
