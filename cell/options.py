"""Command-line options of the cell's timing, shared by ``python -m cell`` and
``python -m sync delay --emulate`` (milliseconds, Hz and µm on the command line)."""

from __future__ import annotations

import argparse
import math
from typing import Any

from spec import cliargs

__all__ = [
    "add_dynamics_option",
    "add_timing_options",
    "add_tool_error_options",
    "timing_kwargs",
    "tool_error",
]

#: (option, CellTiming field, factor to SI, default on the command line, help)
_OPTIONS: tuple[tuple[str, str, float, float, str], ...] = (
    ("--encoder-latency-ms", "encoder_latency_s", 1e-3, 2.8, "measured joints lag (ms)"),
    ("--trigger-poll-hz", "poll_rate_hz", 1.0, 4000.0, "sensor trigger polling rate (Hz)"),
    ("--start-jitter-ms", "start_jitter_s", 1e-3, 0.25, "uniform start jitter width (ms)"),
    ("--start-latency-ms", "start_latency_s", 1e-3, 0.0, "fixed start latency (ms)"),
    ("--acquisition-ms", "acquisition_s", 1e-3, 3.5, "full-frame readout time (ms)"),
    ("--processing-ms", "processing_s", 1e-3, 1.0, "image processing time (ms)"),
    ("--network-delay-ms", "network_delay_s", 1e-3, 0.1, "mean one-way UDP delay (ms, sim)"),
    ("--network-jitter-ms", "network_jitter_s", 1e-3, 0.1, "UDP delay jitter width (ms, sim)"),
    ("--sensor-noise-um", "sensor_noise_mm", 1e-3, 10.0, "extra seam noise, 1 sigma (µm)"),
)


#: The times (ms, and the noise in µm) are bounded where the emulator's buffers and waits
#: still make sense; beyond that a value is a typo, refused before the cell starts.
_TIME_MS = cliargs.number_in(0.0, 1000.0)
_POLL_HZ = cliargs.number_in(1.0, 1e6)


def add_timing_options(parser: argparse.ArgumentParser) -> None:
    """Add the timing options (group "cell timing")."""
    group = parser.add_argument_group("cell timing (the true ΔT follows from these)")
    for option, _field, _factor, default, text in _OPTIONS:
        kind = _POLL_HZ if option == "--trigger-poll-hz" else _TIME_MS
        group.add_argument(option, type=kind, default=default, help=f"{text}, default {default:g}")


def timing_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """CellTiming keyword arguments (SI units) from parsed options; ValueError naming the
    options when they do not go together (checked here so the message speaks of options)."""
    out: dict[str, Any] = {}
    for option, name, factor, _default, _text in _OPTIONS:
        out[name] = getattr(args, option.lstrip("-").replace("-", "_")) * factor
    if not 0.0 < args.acquisition_ms <= 100.0:
        raise ValueError(f"--acquisition-ms must be in (0, 100] ms, got {args.acquisition_ms:g}")
    if args.network_jitter_ms > 2.0 * args.network_delay_ms:
        raise ValueError(
            f"--network-jitter-ms ({args.network_jitter_ms:g}) must be at most twice"
            f" --network-delay-ms ({args.network_delay_ms:g}): a delay never goes below 0"
        )
    return out


def tool_error(text: str) -> tuple[float, float, float, float, float, float]:
    """``DX,DY,DZ,RX,RY,RZ`` (mm, deg): a tool error for ``--sensor-tool-error`` and
    ``--laser-tool-error``."""
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 6 or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"expected DX,DY,DZ,RX,RY,RZ (6 numbers), got {text!r}")
    if max(abs(x) for x in v[:3]) > 50.0 or max(abs(x) for x in v[3:]) > 30.0:
        raise argparse.ArgumentTypeError(f"{text!r}: at most 50 mm and 30 deg per component")
    return (v[0], v[1], v[2], v[3], v[4], v[5])


def add_tool_error_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--sensor-tool-error`` and ``--laser-tool-error`` (group "true tools")."""
    group = parser.add_argument_group(
        "true tools (the robot and the application only know the nominal ones)"
    )
    zero = (0.0,) * 6
    for which in ("sensor", "laser"):
        group.add_argument(
            f"--{which}-tool-error",
            type=tool_error,
            default=zero,
            metavar="DX,DY,DZ,RX,RY,RZ",
            help=f"the true {which} tool = nominal · this error (mm, deg; default none)",
        )


#: kinematics.dynamics.DYNAMICS, spelt out: parsers import this module without numpy
#: (``robotsocket call`` starts without it); tests/test_robot_emulator.py checks they agree.
DYNAMICS = ("off", "elastic")


def add_dynamics_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--dynamics off|elastic`` (the emulated arm's; default off, a rigid arm)."""
    parser.add_argument(
        "--dynamics",
        choices=DYNAMICS,
        default="off",
        help="the emulated arm: off = exactly at its setpoints (default); elastic = elastic "
        "joints with servos on the motor encoders (measured joints are the motor side, the "
        "tool and the sensor follow the link side; docs/ILC.md)",
    )
