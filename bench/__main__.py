"""Run every benchmark module and write the results as one JSON list.

Usage: ``python -m bench [-o bench-results/results.json] [--only AREA ...]``

Beside the results goes their run record (``results.run.json``): when, which commit, on what
machine and beside what load they were measured (``bench.run_info``); ``python -m bench.table``
prints both as Markdown, with the targets of ``bench.targets`` met or not.
"""

from __future__ import annotations

import importlib
import json
import logging
import pkgutil
import sys
from pathlib import Path

import bench
from bench import run_info
from spec import cliargs
from spec.exitcodes import ExitCode
from spec.files import write_atomically


def _modules(only: list[str]) -> list[str]:
    names = sorted(
        m.name for m in pkgutil.iter_modules(bench.__path__) if m.name.startswith("bench_")
    )
    if only:
        names = [n for n in names if n.removeprefix("bench_") in only]
    return names


def main(argv: list[str] | None = None) -> int:
    parser = cliargs.Parser(prog="python -m bench", description=__doc__)
    parser.add_argument(
        "-o", "--output", type=cliargs.output_file, default="bench-results/results.json"
    )
    parser.add_argument("--only", nargs="*", default=[], help="areas to run, e.g. spec kinematics")
    args = parser.parse_args(argv)
    # The servers under test log warnings on purpose (e-stops, lost controllers) when the
    # conformance benchmark drives them; they are not results.
    logging.basicConfig(level=logging.ERROR)
    results: list[dict[str, object]] = []
    names = _modules(args.only)
    if not names:
        print("bench: nothing selected", file=sys.stderr)
        return ExitCode.NOTHING_SELECTED
    started, load_start = run_info.utc_now(), run_info.load_average()
    for name in names:
        print(f"== {name}", file=sys.stderr, flush=True)
        module = importlib.import_module(f"bench.{name}")
        for r in module.run():
            print(
                f"  {r['name']:<48} {r['value']:>14.4g} {r['unit']:<10}"
                f" vs {r['baseline_name']} {r['baseline']:.4g}  ratio {r['ratio']:.3g}"
                + (f"  CPU speed {r['machine_speed']:.0%}" if "machine_speed" in r else ""),
                file=sys.stderr,
                flush=True,
            )
            results.append({**r, "area": name})
    output = Path(args.output)
    write_atomically(output, json.dumps(results, indent=2) + "\n")
    info = run_info.collect(started, load_start)
    write_atomically(run_info.record_path(output), json.dumps(info, indent=2) + "\n")
    print(f"wrote {len(results)} results and their run record to {output.parent}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
