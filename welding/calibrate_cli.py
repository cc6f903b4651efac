"""``python -m welding calibrate sensor-tool|laser-tool``: the tool calibrations of
:mod:`welding.calibration` from the command line.

Start with the sensor over a straight seam (the emulated cell's ready pose does that). The
result goes to ``--json OUT``: the estimated tool, each component's 1σ, the residuals and,
on the emulated cell, ``error_vs_true`` against the cell's true tool. ``--save NAME`` writes
the tool into the database (replacing an entry of that name). A result the calibration
refuses (degenerate poses, too uncertain) exits 1 and saves nothing.

The laser tool is measured by a spot detector fixed in the cell (see
:mod:`welding.calibration`); only the emulated cell has one (``--emulate``). Its
``error_vs_true`` orientation is the angle between the beam axes (the roll about a round
beam is no property of the laser).

The emulated sensor's GetData is only as noisy as its detector (~1 µm); the emulated path
adds the cell's sensor noise (``sensor_noise_mm``, 10 µm by default) to every seam point
here, as the cell adds it to its data datagrams, so the calibration faces the noise the
targets are stated for.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from spec import cliargs
from spec.files import write_atomically
from welding.calibration import (
    CalibrationError,
    EmulatedSpotDetector,
    LaserToolCalibration,
    Limits,
    SensorToolCalibration,
    ToolEstimate,
    error_vs_true,
)
from welding.tools import Entry, ToolDB

__all__ = ["NoisySeams", "add_parser", "cmd_calibrate", "result_json"]


class NoisySeams:
    """A sensor client whose seam points get Gaussian noise (``sigma_mm``) on y and z."""

    def __init__(self, sensor: Any, sigma_mm: float, rng: np.random.Generator) -> None:
        self.sensor = sensor
        self.sigma_mm = sigma_mm
        self._rng = rng

    @property
    def address(self) -> str:
        return str(self.sensor.address)

    def acquire(self) -> int:
        return int(self.sensor.acquire())

    def get_data(self) -> Any:
        data = self.sensor.get_data()
        if data.seam is None or self.sigma_mm <= 0:
            return data
        dy, dz = self._rng.normal(0.0, self.sigma_mm, 2)
        v = list(data.seam)
        v[1] += float(dy)
        v[2] += float(dz)
        return dataclasses.replace(data, seam=tuple(v))


def add_parser(sub: Any, add_cell_options: Callable[..., None]) -> None:
    p = sub.add_parser(
        "calibrate",
        help="find the sensor tool or the laser tool by least squares",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("which", choices=("sensor-tool", "laser-tool"))
    add_cell_options(p, sensor=True)
    p.add_argument("--tool", help="the nominal tool in the database (default sensor / laser)")
    p.add_argument("--poses", type=cliargs.positive_int, default=30, help="at most 30")
    p.add_argument(
        "--repeats",
        type=cliargs.positive_int,
        default=16,
        help="measurements averaged at each pose (default %(default)s)",
    )
    p.add_argument("--json", type=cliargs.output_file, metavar="OUT.json")
    p.add_argument("--save", metavar="NAME", help="write the calibrated tool into the database")


def cmd_calibrate(args: argparse.Namespace, open_cell: Any) -> int:
    if args.poses > 30:
        raise CalibrationError("--poses: at most 30 poses per procedure")
    if args.which == "laser-tool":
        return _laser(args, open_cell)
    if args.emulate and args.seam not in ("straight", "offset"):
        raise CalibrationError("sensor-tool calibrates on a straight seam: --seam straight")
    with open_cell(args, control=True, sensor=True) as cell:
        assert cell.sensor is not None
        nominal = cell.tables.tool(args.tool or "sensor")
        sensor = cell.sensor
        truth = None
        if cell.emulated is not None:
            emulated = cell.emulated.cell
            rng = np.random.default_rng(np.random.SeedSequence([args.seed, 17]))
            sensor = NoisySeams(sensor, emulated.timing.sensor_noise_mm, rng)
            truth = emulated.true_sensor_tool
        cal = SensorToolCalibration(
            cell.robot, sensor, nominal.location, poses=args.poses, repeats=args.repeats
        )
        est = cal.run()
    return _report(args, est, truth, nominal.name, beam_only=False)


def _laser(args: argparse.Namespace, open_cell: Any) -> int:
    if not args.emulate:
        # no protocol reaches a spot detector yet: a live cell needs its own driver
        raise CalibrationError("laser-tool needs a spot detector; only --emulate has one")
    with open_cell(args, control=True) as cell:
        nominal = cell.tables.tool(args.tool or "laser")
        emulated = cell.emulated.cell
        rng = np.random.default_rng(np.random.SeedSequence([args.seed, 18]))
        detector = EmulatedSpotDetector(emulated, rng)
        cal = LaserToolCalibration(
            cell.robot, detector, nominal.location, poses=args.poses, repeats=args.repeats
        )
        est = cal.run()
    return _report(args, est, emulated.true_laser_tool, nominal.name, beam_only=True)


def result_json(
    which: str, est: ToolEstimate, truth: Any, nominal_name: str, *, beam_only: bool
) -> dict[str, Any]:
    """A calibration's result as the CLI's ``--json`` and the console show it: the estimate
    with its 1σ and residuals, the limits, and against ``truth`` (the emulated cell's true
    tool, or None) its error."""
    data: dict[str, Any] = {"calibration": which, "nominal_tool": nominal_name}
    data.update(est.to_json())
    data["limits"] = dataclasses.asdict(Limits())
    if truth is not None:
        data["true_tool"] = list(truth)
        data["error_vs_true"] = error_vs_true(est.tool, truth, beam_only=beam_only)
    return data


def _report(
    args: argparse.Namespace, est: ToolEstimate, truth: Any, nominal_name: str, *, beam_only: bool
) -> int:
    data = result_json(args.which, est, truth, nominal_name, beam_only=beam_only)
    if args.save:
        kind = "sensor" if args.which == "sensor-tool" else "laser"
        stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
        note = f"calibrated {stamp}, {est.poses} poses, residual {est.residual_rms_mm:.4f} mm"
        ToolDB(args.tools).add(Entry(args.save, kind, est.tool, note), replace=True)
        data["saved"] = {"database": args.tools, "name": args.save}
    if args.json:
        write_atomically(args.json, json.dumps(data, indent=1) + "\n")
    tool = ", ".join(f"{v:.4f}" for v in est.tool)
    sig = ", ".join(f"{v:.4f}" for v in est.sigma)
    print(f"{args.which}: ({tool}) ± ({sig}) [mm, deg, 1 sigma]")
    print(f"  {est.poses} poses, residual rms {est.residual_rms_mm * 1e3:.1f} µm")
    if truth is not None:
        e = data["error_vs_true"]
        print(
            f"  error vs the cell's true tool: {e['position_mm']:.4f} mm, "
            f"{e['orientation_deg']:.4f} deg"
        )
    if args.save:
        print(f"  saved as {args.save!r} in {args.tools}", file=sys.stderr)
    return 0
