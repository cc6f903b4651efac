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
from cell.options import add_timing_options, add_tool_error_options, timing_kwargs
from sensorsocket.pgm import write_pgm
from spec import cliargs
from spec.client import FramedClient, wait_end_move
from spec.errors import ProtocolError
from spec.params import Image, Joints, Location
from spec.registry import CommandId
from spec.server import serve_until_signal
from sync.experiment import ExperimentError, ExperimentSettings, run_delay_experiment, write_plots

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
        s.add_argument("--clock", choices=("real", "sim"), default="real")
        s.add_argument("--model", default="RX90B")
        s.add_argument("--joint", choices=("butt", "fillet", "lap"), default="butt")
        s.add_argument("--seam", choices=("straight", "sine", "corner"), default="straight")
        s.add_argument("--seed", type=cliargs.seed, default=0)
        s.add_argument("-v", "--verbose", action="store_true")
        add_timing_options(s)
        add_tool_error_options(s)
        if name == "demo":
            s.add_argument("--out", default="out", help="directory for the frame and plots")
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


def _cell(args: argparse.Namespace) -> EmulatedCell:
    return EmulatedCell(
        clock=args.clock,
        timing=CellTiming(**timing_kwargs(args)),
        model=args.model,
        joint=args.joint,
        seam=args.seam,
        seed=args.seed,
        sensor_tool_error=args.sensor_tool_error,
        laser_tool_error=args.laser_tool_error,
        host=args.host,
        robot_port=args.robot_port,
        sensor_port=args.sensor_port,
        udp_port=args.udp_port,
    )


def cmd_serve(args: argparse.Namespace) -> int:
    cell = _cell(args).start()
    for k, v in cell.describe().items():
        print(f"{k:>22}: {round(v, 9) if isinstance(v, float) else v}")
    if args.clock == "sim":
        print("simulated clock: time advances while a client waits in WaitEndMove")
    sys.stdout.flush()
    serve_until_signal([], on_stop=cell.close)
    return 0


def _fmt(loc: Any) -> str:
    # round first, then + 0.0: no "-0.00" for values that round to zero
    return "(" + ", ".join(f"{round(float(v), 2) + 0.0:.2f}" for v in loc) + ")"


def _robot_tour(robot: FramedClient) -> None:
    info = robot.hello()
    print(f"robot: {info['vendor']!s} {info['model']!s} ({info['service']!s}, {info['version']!s})")
    robot.take_control("")
    robot.call(CommandId.ENABLE_POWER)
    (q,) = robot.call(CommandId.HEREJ)
    assert isinstance(q, Joints)
    print(f"  EnablePower; Herej = {_fmt(q.values)} deg")
    away = list(q.values)
    away[0] += 10.0
    robot.call(CommandId.JOINT_MOVE, Joints(away))
    wait_end_move(robot, 10.0)
    config = robot.call(CommandId.GET_SYNC_CONFIG)
    tool = config[3]
    world = Location(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    (here,) = robot.call(CommandId.HERE, tool, world)
    assert isinstance(here, Location)
    print(f"  JointMove(joint 1 + 10 deg); Here(sensor tool) = {_fmt(here.as_tuple())}")
    robot.call(CommandId.JOINT_MOVE, Joints(list(q.values)))
    wait_end_move(robot, 10.0)
    (here,) = robot.call(CommandId.HERE, tool, world)
    assert isinstance(here, Location)
    print(f"  back over the seam:      Here(sensor tool) = {_fmt(here.as_tuple())}")
    robot.release_control()


def _sensor_tour(sensor: FramedClient, out: Path) -> None:
    info = sensor.hello()
    print(f"sensor: {info['vendor']!s} {info['model']!s}")
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
    print(f"  Acquire -> frame {index!s}: {image.width}x{image.height} written to {path}")
    quality = data[3]
    assert isinstance(quality, float)
    print(f"  GetData: status {data[1]!s}, seam in S = {_fmt(seam.as_tuple())}, q {quality:.2f}")
    sensor.release_control()


def _conformance(cell: EmulatedCell) -> None:
    if importlib.util.find_spec("conformance.cli") is None:
        print("conformance: harness not installed, skipped")
        return
    endpoints: tuple[tuple[str, tuple[str, int], list[str]], ...] = (
        ("robot", cell.robot_address, ["--allow-motion"]),  # an emulator: nothing can be hurt
        ("sensor", cell.sensor_address, []),
        ("sync", cell.udp_address, []),
    )
    # The robot cases engage the e-stop and drop a controller on purpose: their warnings are
    # expected here, not news for the person watching the demo.
    logging.getLogger("robotsocket").setLevel(logging.ERROR)
    for service, (host, port), extra in endpoints:
        cmd = [sys.executable, "-m", "conformance", service, f"{host}:{port}", "-q", *extra]
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        except subprocess.TimeoutExpired:
            print(f"conformance {service}: timed out")
            continue
        last = (done.stdout.strip().splitlines() or [""])[-1]
        print(f"conformance {service}: exit {done.returncode} {last}")


def cmd_demo(args: argparse.Namespace) -> int:
    out = Path(args.out)
    t0 = time.monotonic()
    with _cell(args) as cell:
        d = cell.describe()
        print(f"cell ({d['clock']} clock): robot {d['robot']}, sensor {d['sensor']}, ", end="")
        print(f"udp {d['udp']}")
        print(
            f"  timing: encoder latency {d['encoder_latency_ms']:.2f} ms, network "
            f"{d['network_delay_ms']:.2f} ms, poll {d['trigger_poll_hz']:g} Hz, start jitter "
            f"{d['start_jitter_ms']:.2f} ms, acquisition {d['acquisition_ms']:.2f} ms"
        )
        with FramedClient(*cell.robot_address, timeout=20.0) as robot:
            _robot_tour(robot)
        with FramedClient(*cell.sensor_address, timeout=20.0) as sensor:
            _sensor_tour(sensor, out)
        settings = ExperimentSettings(duration_s=args.duration, trigger_rate_hz=args.rate)
        print(
            f"ΔT experiment through the sockets: {settings.amplitude_mm:g} mm sine at "
            f"{settings.frequency_hz:g} Hz for {settings.duration_s:g} s, "
            f"triggers at {settings.trigger_rate_hz:g} Hz ..."
        )
        first = cell.core.next_index
        result = run_delay_experiment(cell.robot_address, cell.sensor_address, settings)
        truth = cell.measured_delta_t(first)
        s = result.summary()
        print(f"  {'':28} {'here':>10} {'paper':>10}")
        rows = (
            ("ΔT (ms)", f"{result.delta_t_ms:.3f}", "4.9"),
            ("true ΔT, cell records (ms)", f"{truth * 1e3:.3f}", ""),
            ("true ΔT, parameters (ms)", f"{cell.true_delta_t_s() * 1e3:.3f}", ""),
            ("jitter width (ms)", f"{d['jitter_width_ms']:.2f}", "0.6"),
            ("residual max (µm)", f"{s['residual_max_um']:.1f}", "30"),
            ("residual rms (µm)", f"{s['residual_rms_um']:.1f}", ""),
            ("residual at 1.5 Hz (µm)", f"{s['residual_sine_amplitude_um']:.2f}", "none"),
            ("unsynchronised max (µm)", f"{s['unsynced_max_um']:.1f}", ""),
        )
        for name, here, paper in rows:
            print(f"  {name:28} {here:>10} {paper:>10}")
        print(f"  datagrams: {result.data.statistics}")
        try:
            files = write_plots(out, result)
            print(f"  figures 6, 7, 9 written to {out}/ ({', '.join(f.name for f in files)})")
        except ExperimentError as exc:
            print(f"  plots skipped: {exc}")
        if not args.no_conformance:
            _conformance(cell)
    print(f"demo done in {time.monotonic() - t0:.1f} s")
    return 0


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
    except (CellError, ExperimentError, ProtocolError, OSError, ValueError) as exc:
        # ValueError covers the kinematics (unknown model) and emulator argument checks.
        print(f"python -m cell: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def console() -> int:
    """The installed command (a console-script entry point of pyproject.toml)."""
    return cliargs.run_cli(main)


if __name__ == "__main__":
    sys.exit(console())
