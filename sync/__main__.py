"""Command line of the synchronisation: the ΔT experiment (paper section VI) and eq. 8-9.

    python -m sync delay --robot HOST:PORT --sensor HOST:PORT [--frequency 1.5]
        [--amplitude 2] [--duration 10] [--rate 250] [--sweep] [--json FILE] [--plot DIR]
    python -m sync delay --emulate [cell timing options]   (in-process cell, simulated clock)
    python -m sync sweep ...                                (same as delay --sweep)
    python -m sync curvature --amplitude 2 --frequency 5 --speed 250

Exit codes: 0 a trusted result; 2 an error (one line on stderr); 3 a result that cannot be
trusted (the quality gates of :func:`sync.delay.assess_run`: data lost or late, MSE minimum at
the edge of the range, residual not better with synchronisation than without, ΔT drifting
across the run; one line on stderr saying why, the same verdict in the JSON); 130 interrupted
(Ctrl-C or SIGTERM: triggers and motion stopped, control released; one line on stderr).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from types import FrameType
from typing import Any

from spec import cliargs
from spec.errors import ProtocolError, RemoteError, error_text
from spec.exitcodes import ExitCode
from sync.curvature import sine_min_radius, sine_min_radius_numeric
from sync.delay import DelayEstimateError, QualityLimits, Verdict
from sync.experiment import (
    DEFAULT_SWEEP_HZ,
    DelayResult,
    ExperimentError,
    ExperimentSettings,
    exposed_late_text,
    judge,
    run_delay_experiment,
    run_sweep,
    write_json,
    write_plots,
)

PROG = "python -m sync"


_FORCE_AFTER_S = 5.0


class Interrupted(Exception):
    """Ctrl-C or SIGTERM arrived: the experiment stops at its next safe point."""


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


def _parser() -> cliargs.Parser:
    p = cliargs.Parser(prog=PROG, description="Robot-sensor synchronisation tools.")
    sub = p.add_subparsers(dest="command", required=True, parser_class=cliargs.Parser)
    for name in ("delay", "sweep"):
        what = "the frequency sweep of Fig. 8" if name == "sweep" else "the sine experiment"
        d = sub.add_parser(name, help=f"measure ΔT with {what} (section VI)")
        cliargs.add_endpoint(d, "robot")
        cliargs.add_endpoint(d, "sensor")
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
        d.add_argument(
            "--max-lost-pct",
            type=cliargs.number_in(0.0, 100.0),
            default=QualityLimits.max_lost_fraction * 100,
            help="gate: triggers without data in time, at most this %% (default 2)",
        )
        d.add_argument(
            "--max-spread-ms",
            type=cliargs.number_in(0.0, 1000.0, low_open=True),
            default=QualityLimits.max_spread_s * 1e3,
            help="gate: spread of the per-window ΔT, at most (ms, default 0.5)",
        )
        d.add_argument("--model", help="robot model for the DGM (default: from Hello)")
        token = d.add_mutually_exclusive_group()
        token.add_argument("--token", default="", help="control token of the robot")
        cliargs.add_token_file(token, "the robot's")
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
        from cell.options import add_dynamics_option, add_timing_options

        add_dynamics_option(d)
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


class _Progress:
    """The progress line on stderr (none with ``quiet``) and the interrupt check: a signal
    only sets a flag; the experiment stops at its next progress report, between two calls,
    so the connection stays in step and the clean-up commands get their own replies."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.open = False
        self.interrupted = False
        self._first_signal = 0.0

    def __call__(self, frac: float, msg: str) -> None:
        if self.interrupted:
            raise Interrupted
        if not self.quiet:
            print(f"\r  [{frac * 100:5.1f} %] {msg:50}", end="", file=sys.stderr, flush=True)
            self.open = True

    def end(self) -> None:
        """End the progress line, so what follows starts on a line of its own."""
        if self.open:
            print(file=sys.stderr, flush=True)
            self.open = False

    @contextmanager
    def catching_signals(self) -> Iterator[None]:
        """SIGINT and SIGTERM set the flag. Another signal within ``_FORCE_AFTER_S`` is
        ignored (an interrupt inside a call would leave the connection out of step and the
        clean-up would read the wrong replies); a later one interrupts at once (a hung
        server)."""

        def handler(signum: int, frame: FrameType | None) -> None:
            now = time.monotonic()
            if self.interrupted and now - self._first_signal > _FORCE_AFTER_S:
                raise KeyboardInterrupt
            if not self.interrupted:
                self.interrupted, self._first_signal = True, now

        try:
            old = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
        except ValueError:  # not the main thread (embedded): no handlers
            yield
            return
        try:
            yield
        finally:
            for sig, h in old.items():
                signal.signal(sig, h)


def _print_result(r: DelayResult, verdict: Verdict) -> None:
    s = r.summary()
    mark = "" if verdict.ok else "  UNTRUSTED (reason below)"
    print(f"ΔT = {r.delta_t_ms:.3f} ms  ({s['frequency_hz']:g} Hz, {s['amplitude_mm']:g} mm){mark}")
    st = r.data.statistics
    print(
        f"  this run: {st.get('sent', 0)} triggers, {verdict.lost_fraction:.1%} without data "
        f"in time ({verdict.lost_on_wire} lost on the wire, {verdict.dropped_late} late)"
    )
    print(f"  {exposed_late_text(st)}")
    if math.isfinite(verdict.spread_s):
        print(
            f"  ΔT per window: spread {verdict.spread_s * 1e3:.3f} ms over "
            f"{len(verdict.window_delta_t_s)} windows"
        )
    else:
        print("  ΔT per window: not judged (fewer than two windows of full amplitude)")
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


def _print_untrusted(verdicts: Sequence[tuple[str, Verdict]]) -> None:
    for what, v in verdicts:
        if not v.ok:
            print(f"{PROG}: untrusted result{what}: {v.reason}", file=sys.stderr)


def cmd_delay(args: argparse.Namespace, progress: _Progress) -> int:
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
    limits = QualityLimits(
        max_lost_fraction=args.max_lost_pct / 100.0, max_spread_s=args.max_spread_ms * 1e-3
    )
    cell: Any = None
    if args.emulate:
        from cell.cell import CellTiming, EmulatedCell
        from cell.options import timing_kwargs

        cell = EmulatedCell(
            clock="sim",
            timing=CellTiming(**timing_kwargs(args)),
            seed=args.seed,
            dynamics=args.dynamics,
        )
        cell.start()
        robot, sensor = cell.robot_address, cell.sensor_address
    else:
        if args.robot is None:
            raise ExperimentError(
                "give --robot HOST:PORT (and --sensor), or --emulate", ExitCode.USAGE
            )
        robot, sensor = args.robot, args.sensor
    try:
        extra: dict[str, Any] = {}
        if cell is not None:
            extra["true_delta_t_ms"] = cell.true_delta_t_s() * 1e3
        out: dict[str, Any]
        verdicts: list[tuple[str, Verdict]] = []
        if args.sweep:
            results = run_sweep(robot, sensor, settings, args.frequencies, progress=progress)
            progress.end()
            print(f"{'f (Hz)':>7} {'ΔT (ms)':>9} {'max (µm)':>9} {'rms (µm)':>9} {'at f (µm)':>9}")
            sweep = []
            for r in results:
                r.extra.update(extra)
                s = r.summary()
                v = judge(r, limits)
                verdicts.append((f" at {s['frequency_hz']:g} Hz", v))
                s["verdict"] = v.to_json()
                sweep.append(s)
                mark = "" if v.ok else "  UNTRUSTED"
                print(
                    f"{s['frequency_hz']:7g} {s['delta_t_ms']:9.3f} {s['residual_max_um']:9.1f} "
                    f"{s['residual_rms_um']:9.1f} {s['residual_sine_amplitude_um']:9.2f}{mark}"
                )
            if extra:
                print(f"true ΔT (cell) = {extra['true_delta_t_ms']:.3f} ms")
            out = {"sweep": sweep, **extra}
            main_result = next(
                (r for r in results if r.settings.frequency_hz == args.frequency), None
            )
        else:
            main_result = run_delay_experiment(
                robot, sensor, settings, progress=progress, require_interior=False
            )
            progress.end()
            main_result.extra.update(extra)
            v = judge(main_result, limits, need_windows=True)
            verdicts.append(("", v))
            _print_result(main_result, v)
            if "applied_delta_t_ms" in main_result.extra:
                print(
                    f"SetSyncDelay: the robot now synchronises with ΔT = "
                    f"{main_result.extra['applied_delta_t_ms']:.3f} ms"
                    + ("" if v.ok else " (an UNTRUSTED estimate: check the reasons below)")
                )
            out = main_result.to_json()
            out["verdict"] = v.to_json()
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
    _print_untrusted(verdicts)
    return ExitCode.UNTRUSTED if any(not v.ok for _, v in verdicts) else 0


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
    progress = _Progress(getattr(args, "quiet", True))
    try:
        if args.command == "curvature":
            return cmd_curvature(args)
        with progress.catching_signals():
            return cmd_delay(args, progress)
    except BrokenPipeError:
        raise  # our stdout was closed (`| head`): cliargs.run_cli ends quietly
    except (Interrupted, KeyboardInterrupt):
        progress.end()
        print(
            f"{PROG}: interrupted: triggers and motion stopped, control released",
            file=sys.stderr,
        )
        return ExitCode.INTERRUPTED
    except (ExperimentError, DelayEstimateError, ProtocolError, OSError, ValueError) as exc:
        progress.end()
        print(f"{PROG}: error: {error_text(exc)}", file=sys.stderr)
        return _exit_code(exc)


def _exit_code(exc: Exception) -> ExitCode:
    """One table for every tool (docs/CLI.md): bad arguments USAGE, an endpoint that does not
    answer or speak the protocol UNREACHABLE, an experiment that cannot run or gave too little
    data FAILED."""
    if isinstance(exc, ExperimentError):
        return exc.code
    if isinstance(exc, (DelayEstimateError, RemoteError)):  # too little data; a refusal
        return ExitCode.FAILED
    if isinstance(exc, ValueError):
        return ExitCode.USAGE
    if isinstance(exc, (ProtocolError, OSError)):
        return ExitCode.UNREACHABLE
    return ExitCode.FAILED


def console() -> int:
    """The installed command (a console-script entry point of pyproject.toml)."""
    return cliargs.run_cli(main)


if __name__ == "__main__":
    sys.exit(console())
