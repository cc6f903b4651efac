"""ILC on the real clock (issue 31): ``welding ilc --emulate --clock real`` as a subprocess,
``--runs`` times per load, the load ``--hogs`` CPU-bound processes (``python3 -c 'while 1:
pass'``, normal scheduling) started before each run and ended after it.

Per run: the exit code, each trial's error max against the emulator's truth, whether it was
trusted and its checks (late corrections, held cycles, joint log samples missing, the longest
gap between sensor readings), trial 1 / trial 5 and whether the error fell at every trial;
the machine's load average before the run (other work on a shared machine shows there).
Not part of ``make bench`` (a minute per run and load); run it alone:

    python -m bench.ilc_real_clock --runs 3 --hogs 0 2 --json docs/bench/ilc-real-clock.json
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bench import run_info
from spec import cliargs
from spec.exitcodes import ExitCode
from spec.files import write_atomically

ROOT = Path(__file__).resolve().parent.parent
TRIALS = 5


@contextlib.contextmanager
def _hogs(n: int) -> Iterator[None]:
    procs = [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def one_run(hogs: int, args: list[str]) -> dict[str, Any]:
    """One ``welding ilc --clock real`` beside ``hogs`` CPU hogs: its figures."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "ilc.json"
        load = run_info.load_average()
        command = [sys.executable, "-m", "welding", "ilc", "--emulate", "--clock", "real",
                   "--dynamics", "elastic", "--seam", "sine", "--speed", "250",
                   "--trials", str(TRIALS), "--json", str(out), *args]  # fmt: skip
        with _hogs(hogs):
            done = subprocess.run(
                command,
                cwd=ROOT,
                capture_output=True,
                text=True,
                timeout=600,
                env=os.environ | {"PYTHONPATH": str(ROOT)},
            )
        data = json.loads(out.read_text()) if out.exists() else {}
    trials = data.get("trials", [])
    errors = [t["error_max_mm"] for t in trials if not t["tracked"]]
    return {
        "hogs": hogs,
        "load_average_before": load,
        "exit": done.returncode,
        "last_lines": done.stdout.strip().splitlines()[-2:],
        "error_max_mm": errors,
        "trusted": [t["trusted"] for t in trials],
        "untrusted": [t["untrusted"] for t in trials if t["untrusted"]],
        "checks": [t["checks"] for t in trials],
        "ratio_first_last": errors[0] / errors[-1] if len(errors) > 1 and errors[-1] else None,
        "falling": all(b < a for a, b in itertools.pairwise(errors)),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.ilc_real_clock", description=__doc__)
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--hogs", type=int, nargs="*", default=[0, 2])
    p.add_argument("--json", type=cliargs.output_file)
    p.add_argument("rest", nargs="*", help="more options of welding ilc (after --)")
    args = p.parse_args(argv)
    started, load_start = run_info.utc_now(), run_info.load_average()
    runs = []
    for hogs in args.hogs:
        for i in range(args.runs):
            r = one_run(hogs, args.rest)
            runs.append(r)
            errs = " ".join(f"{e:.4f}" for e in r["error_max_mm"])
            print(f"hogs {hogs} run {i + 1}: exit {r['exit']}, error max {errs} mm,"
                  f" load before {r['load_average_before']}"
                  + (f"; UNTRUSTED: {r['untrusted']}" if r["untrusted"] else ""),
                  flush=True)  # fmt: skip
    if args.json:
        record = {"runs": runs, "run_info": run_info.collect(started, load_start)}
        write_atomically(args.json, json.dumps(record, indent=1) + "\n")
    return ExitCode.OK if all(r["exit"] == 0 for r in runs) else ExitCode.FAILED


if __name__ == "__main__":
    raise SystemExit(main())
