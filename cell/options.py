"""Command-line options of the cell's timing, shared by ``python -m cell`` and
``python -m sync delay --emulate`` (milliseconds, Hz and µm on the command line)."""

from __future__ import annotations

import argparse
from typing import Any

from spec import cliargs

__all__ = ["add_timing_options", "timing_kwargs"]

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
