"""Command line: ``python -m kinematics fk|ik|models``.

Values are comma-separated, mm and degrees. Negative first values: write ``--joints=-30,...``
(the ``--joints -30,...`` form is accepted too). Errors: one line on stderr, exit code 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from kinematics.errors import KinematicsError
from kinematics.robot import DEFAULT_MODEL, get_model, list_models
from kinematics.transforms import (
    concat,
    invert,
    location_to_transform,
    transform_to_location,
)
from spec.exitcodes import ExitCode

#: Largest coordinate (mm) or angle (deg) on the command line.
_LARGEST = 1e6

_VALUE_OPTIONS = ("--joints", "--tool", "--frame", "--location", "--near", "--config", "--model")


class _UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> Any:  # one line and exit 2, no usage dump
        raise _UsageError(message)

    def _get_values(self, action: argparse.Action, arg_strings: list[str]) -> Any:
        # As spec.cliargs.Parser (not imported: kinematics stands on numpy alone): Python
        # 3.11 stores [] for ``--joints=--``; the value "--" is passed on like any other.
        if action.option_strings and action.nargs is None and arg_strings == ["--"]:
            return self._get_value(action, "--")
        return super()._get_values(action, arg_strings)


def _six(text: str, what: str) -> list[float]:
    parts = [p for p in text.replace(" ", "").split(",") if p != ""]
    if len(parts) != 6:
        raise KinematicsError(f"{what}: expected 6 comma-separated numbers, got {len(parts)}")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise KinematicsError(f"{what}: not a number in {text!r}") from None
    if not all(math.isfinite(v) for v in vals):
        raise KinematicsError(f"{what}: contains NaN or infinity")
    if any(abs(v) > _LARGEST for v in vals):
        # A kilometre or a thousand turns: a typo, not a pose (and squares would overflow).
        raise KinematicsError(f"{what}: values must be within ±{_LARGEST:g}")
    return vals


def _clean(v: float) -> float:
    r = round(float(v), 9)  # nm and 1e-9 degree: well below any pendant display
    return 0.0 if r == 0.0 else r


def _join_negative_values(argv: Sequence[str]) -> list[str]:
    """Turn ``--joints -30,45,...`` into ``--joints=-30,45,...`` (argparse reads -30 as a flag)."""
    out: list[str] = []
    it = iter(argv)
    for arg in it:
        if arg in _VALUE_OPTIONS:
            nxt = next(it, None)
            if nxt is None:
                out.append(arg)
            elif nxt.startswith("-") and len(nxt) > 1 and (nxt[1].isdigit() or nxt[1] == "."):
                out.append(f"{arg}={nxt}")
            else:
                out.extend([arg, nxt])
        else:
            out.append(arg)
    return out


def _parser() -> _Parser:
    p = _Parser(prog="python -m kinematics", description=__doc__)
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)
    fk = sub.add_parser("fk", help="location of tool in frame for VAL3 joints")
    fk.add_argument("--model", default=DEFAULT_MODEL)
    fk.add_argument("--joints", required=True, help="J1,...,J6 in degrees")
    fk.add_argument("--tool", help="tool location x,y,z,rx,ry,rz in the flange frame")
    fk.add_argument("--frame", help="frame location x,y,z,rx,ry,rz in the base frame")
    ik = sub.add_parser("ik", help="all joint solutions for a location of tool in frame")
    ik.add_argument("--model", default=DEFAULT_MODEL)
    ik.add_argument("--location", required=True, help="x,y,z,rx,ry,rz (mm, degrees)")
    ik.add_argument("--tool")
    ik.add_argument("--frame")
    ik.add_argument("--config", help="e.g. righty,epositive,wpositive (any subset)")
    ik.add_argument("--near", help="current joints J1,...,J6: sort by distance to them")
    models = sub.add_parser("models", help="list the models with their parameters and limits")
    models.add_argument("--json", action="store_true", help="every field as JSON")
    return p


def _tool_frame(args: argparse.Namespace) -> tuple[np.ndarray, np.ndarray]:
    tool = location_to_transform(_six(args.tool, "tool")) if args.tool else np.eye(4)
    frame = location_to_transform(_six(args.frame, "frame")) if args.frame else np.eye(4)
    return tool, frame


def _run(argv: Sequence[str]) -> dict[str, Any] | list[dict[str, Any]]:
    args = _parser().parse_args(_join_negative_values(argv))
    if args.cmd == "models":
        return [get_model(n).to_dict() for n in list_models()]
    model = get_model(args.model)
    tool, frame = _tool_frame(args)
    if args.cmd == "fk":
        q = _six(args.joints, "joints")
        # VAL3 Here(tool, frame): tool2frame = frame^-1 · flange2base · tool.
        loc = transform_to_location(concat(invert(frame), model.flange2base(q), tool))
        return dict(zip(("x", "y", "z", "rx", "ry", "rz"), (_clean(v) for v in loc), strict=True))
    target = location_to_transform(_six(args.location, "location"))
    flange2base = concat(frame, target, invert(tool))
    near = _six(args.near, "near") if args.near else None
    sols = model.ik(flange2base, config=args.config, near=near)
    out = []
    for s in sols:
        d = s.as_dict()
        d["joints"] = [_clean(v) for v in d["joints"]]
        out.append(d)
    return {"solutions": out}


def _models_table(models: list[dict[str, Any]]) -> str:
    """One row per model: the link lengths (mm) and the joint ranges (deg) a user picks by."""
    head = ("model", "shoulder", "lateral", "upper_arm", "forearm", "wrist", "joint limits")
    rows = [head]
    for m in models:
        limits = " ".join(f"{lo:g}..{hi:g}" for lo, hi in m["joint_limits_deg"])
        lengths = (
            m["shoulder_offset_mm"],
            m["lateral_offset_mm"],
            m["upper_arm_mm"],
            m["forearm_mm"],
            m["wrist_to_flange_mm"],
        )
        rows.append((m["name"], *(f"{v:g}" for v in lengths), limits))
    widths = [max(len(r[i]) for r in rows) for i in range(len(head) - 1)]
    lines = [
        "  ".join([*(c.ljust(w) for c, w in zip(r, widths, strict=False)), r[-1]]) for r in rows
    ]
    return "\n".join([*lines, "lengths in mm, limits in degrees (J1 … J6); --json for every field"])


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        result = _run(argv)
    except (_UsageError, KinematicsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    try:
        if isinstance(result, list) and "--json" not in argv:
            print(_models_table(result), flush=True)
        else:
            print(json.dumps(result), flush=True)
    except BrokenPipeError:  # `… | head -c N`: end quietly, as a Unix tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return ExitCode.BROKEN_PIPE
    return 0


def console() -> int:
    """The installed command ``rsf-kinematics`` (a console-script entry point)."""
    return main()
