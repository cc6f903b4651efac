"""Command line of the synchronisation: the ΔT experiment (paper section VI) and eq. 8-9.

    python -m sync delay --robot HOST:PORT --sensor HOST:PORT [--frequency 1.5]
        [--amplitude 2] [--duration 10] [--rate 250] [--sweep] [--json FILE] [--plot DIR]
    python -m sync delay --emulate [cell timing options]   (in-process cell, simulated clock)
    python -m sync sweep ...                                (same as delay --sweep)
    python -m sync curvature --amplitude 2 --frequency 5 --speed 250

Errors: one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

from spec import cliargs
from spec.errors import ProtocolError
from sync.curvature import sine_min_radius, sine_min_radius_numeric
from sync.delay import DelayEstimateError
from sync.experiment import (
    DEFAULT_SWEEP_HZ,
    DelayResult,
    ExperimentError,
    ExperimentSettings,
    run_delay_experiment,
    run_sweep,
    write_json,
    write_plots,
)

PROG = "python -m sync"


#: Bounds of the experiment's options: beyond them the sine or the sample arrays stop making
#: sense (or stop fitting in memory, or divide by a denormal), so they are usage errors, not
#: tracebacks later.
_HZ = cliargs.number_in(0.001, 1000.0)
_MM = cliargs.number_in(0.001, 1000.0)
_DURATION = cliargs.number_in(0.01, 3600.0)
_RATE = cliargs.number_in(0.1, 10000.0)
_SEARCH_MS = cliargs.number_in(0.2, 1000.0)


def _frequencies(text: str) -> list[float]:
    values = [_HZ(item) for item in text.split(",") if item.strip()]
    if not values:
        raise argparse.ArgumentTypeError(f"expected comma-separated frequencies, got {text!r}")
    return values


def _endpoint(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host, int(port)


def _parser() -> cliargs.Parser:
    p = cliargs.Parser(prog=PROG, description="Robot-sensor synchronisation tools.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=cliargs.Parser)
    for name in ("delay", "sweep"):
        what = "the frequency sweep of Fig. 8" if name == "sweep" else "the sine experiment"
        d = sub.add_parser(name, help=f"measure ΔT with {what} (section VI)")
        d.add_argument("--robot", type=_endpoint, help="RobotSocket HOST:PORT")
        d.add_argument("--sensor", type=_endpoint, help="SensorSocket HOST:PORT")
        d.add_argument(
            "--frequency", type=_HZ, default=1.5, help="sine frequency (Hz, 0.001..1000)"
        )
        d.add_argument(
            "--amplitude", type=_MM, default=2.0, help="sine amplitude (mm, 0.001..1000)"
        )
        d.add_argument(
            "--duration", type=_DURATION, default=10.0, help="sine duration (s, 0.01..3600)"
        )
        d.add_argument("--rate", type=_RATE, default=250.0, help="trigger rate (Hz, 0.1..10000)")
        d.add_argument(
            "--search-max-ms", type=_SEARCH_MS, default=20.0, help="largest ΔT searched (ms)"
        )
        d.add_argument("--model", help="robot model for the DGM (default: from Hello)")
        token = d.add_mutually_exclusive_group()
        token.add_argument("--token", default="", help="control token of the robot")
        token.add_argument(
            "--token-file",
            dest="token",
            type=cliargs.token_file,
            metavar="FILE",
            help="file holding the robot's control token (one line; not shown by ps)",
        )
        d.add_argument("--apply", action="store_true", help="SetSyncDelay to the estimate")
        d.add_argument(
            "--frequencies",
            type=_frequencies,
            default=list(DEFAULT_SWEEP_HZ),
            help="sweep frequencies, comma separated (Hz)",
        )
        d.add_argument("--sweep", action="store_true", default=name == "sweep")
        d.add_argument(
            "--json", metavar="FILE", type=cliargs.output_file, help="write the results as JSON"
        )
        d.add_argument(
            "--plot", metavar="DIR", type=cliargs.output_dir, help="write figures 6-9 as PNG"
        )
        d.add_argument("--emulate", action="store_true", help="in-process cell, simulated clock")
        d.add_argument("--seed", type=cliargs.seed, default=0, help="seed of the emulated cell")
        d.add_argument("-q", "--quiet", action="store_true", help="no progress")
        from cell.options import add_timing_options

        add_timing_options(d)
    c = sub.add_parser("curvature", help="minimum radius of a sine seam (eq. 8-9)")
    c.add_argument("--amplitude", type=_MM, default=2.0, help="mm (0.001..1000)")
    c.add_argument("--frequency", type=_HZ, default=5.0, help="Hz (0.001..1000)")
    c.add_argument(
        "--speed",
        type=cliargs.number_in(0.1, 10000.0),
        default=250.0,
        help="welding speed (mm/s, 0.1..10000)",
    )
    return p


def _progress(quiet: bool) -> Any:
    def show(frac: float, msg: str) -> None:
        print(f"\r  [{frac * 100:5.1f} %] {msg:50}", end="", file=sys.stderr, flush=True)

    return None if quiet else show


def _print_result(r: DelayResult) -> None:
    s = r.summary()
    print(f"ΔT = {r.delta_t_ms:.3f} ms  ({s['frequency_hz']:g} Hz, {s['amplitude_mm']:g} mm)")
    if "true_delta_t_ms" in s:
        print(f"  true ΔT (cell) = {s['true_delta_t_ms']:.3f} ms")
    print(
        f"  residual after synchronisation: max {s['residual_max_um']:.1f} µm, rms "
        f"{s['residual_rms_um']:.1f} µm, at {s['frequency_hz']:g} Hz "
        f"{s['residual_sine_amplitude_um']:.2f} µm"
    )
    print(
        f"  without synchronisation:        max {s['unsynced_max_um']:.1f} µm, rms "
        f"{s['unsynced_rms_um']:.1f} µm, at {s['frequency_hz']:g} Hz "
        f"{s['unsynced_sine_amplitude_um']:.2f} µm"
    )


def cmd_delay(args: argparse.Namespace) -> int:
    settings = ExperimentSettings(
        frequency_hz=args.frequency,
        amplitude_mm=args.amplitude,
        duration_s=args.duration,
        trigger_rate_hz=args.rate,
        search_max_s=args.search_max_ms * 1e-3,
        model=args.model,
        apply=args.apply,
        token=args.token,
    )
    progress = _progress(args.quiet)
    cell: Any = None
    if args.emulate:
        from cell.cell import CellTiming, EmulatedCell
        from cell.options import timing_kwargs

        cell = EmulatedCell(clock="sim", timing=CellTiming(**timing_kwargs(args)), seed=args.seed)
        cell.start()
        robot, sensor = cell.robot_address, cell.sensor_address
    else:
        if args.robot is None:
            raise ExperimentError("give --robot HOST:PORT (and --sensor), or --emulate")
        robot, sensor = args.robot, args.sensor
    try:
        extra: dict[str, Any] = {}
        if cell is not None:
            extra["true_delta_t_ms"] = cell.true_delta_t_s() * 1e3
        out: dict[str, Any]
        if args.sweep:
            results = run_sweep(robot, sensor, settings, args.frequencies, progress=progress)
            if progress is not None:
                print(file=sys.stderr)
            print(f"{'f (Hz)':>7} {'ΔT (ms)':>9} {'max (µm)':>9} {'rms (µm)':>9} {'at f (µm)':>9}")
            for r in results:
                r.extra.update(extra)
                s = r.summary()
                edge = " (edge)" if s["at_edge"] else ""
                print(
                    f"{s['frequency_hz']:7g} {s['delta_t_ms']:9.3f} {s['residual_max_um']:9.1f} "
                    f"{s['residual_rms_um']:9.1f} {s['residual_sine_amplitude_um']:9.2f}{edge}"
                )
            if extra:
                print(f"true ΔT (cell) = {extra['true_delta_t_ms']:.3f} ms")
            out = {"sweep": [r.summary() for r in results], **extra}
            main_result = next(
                (r for r in results if r.settings.frequency_hz == args.frequency), None
            )
        else:
            main_result = run_delay_experiment(robot, sensor, settings, progress=progress)
            if progress is not None:
                print(file=sys.stderr)
            main_result.extra.update(extra)
            _print_result(main_result)
            out = main_result.to_json()
            results = []
        if args.json:
            write_json(args.json, out)
            print(f"results written to {args.json}")
        if args.plot:
            files = write_plots(args.plot, main_result, results)
            print(f"figures written to {args.plot}: {', '.join(f.name for f in files)}")
    finally:
        if cell is not None:
            cell.close()
    return 0


def cmd_curvature(args: argparse.Namespace) -> int:
    r = sine_min_radius(args.amplitude, args.frequency, args.speed)
    r_num, x = sine_min_radius_numeric(args.amplitude, args.frequency, args.speed)
    print(
        f"seam y = {args.amplitude:g} sin(2π·{args.frequency:g}·x/{args.speed:g}) mm: minimum "
        f"radius of curvature {r:.2f} mm (numeric {r_num:.2f} mm at x = {x:.2f} mm)"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "curvature":
            return cmd_curvature(args)
        return cmd_delay(args)
    except BrokenPipeError:
        raise  # our stdout was closed (`| head`): cliargs.run_cli ends quietly
    except (ExperimentError, DelayEstimateError, ProtocolError, OSError, ValueError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(cliargs.run_cli(main))
