"""Print the results of one ``make bench`` run as Markdown tables, or put them into a document.

Usage: ``python -m bench.table [RESULTS] [--into docs/BENCHMARKS.md] [--check]``

RESULTS is ``bench-results/results.json`` by default; its run record ``results.run.json``
(date, commit, machine, load, library versions) becomes the line above the tables, and the
targets of :mod:`bench.targets` are checked against the run in the first table. With
``--into``, the text between the document's ``<!-- bench-table:start -->`` and
``<!-- bench-table:end -->`` lines is replaced (atomically), so the published tables are always
one run's output and never a hand-merged mix of runs. ``--check`` prints the targets table
alone, and its exit status says whether the run meets every target: 0 yes, 4 a target is
missed, 5 none is missed but some are undecided (missed only while the CPU ran below full
speed) or not measured; 1 is an unreadable results file.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from bench.pace import FULL_SPEED
from bench.run_info import record_path
from bench.targets import Verdict, judge, verdicts
from spec import cliargs
from spec.exitcodes import ExitCode
from spec.files import write_atomically

START = "<!-- bench-table:start -->"
END = "<!-- bench-table:end -->"


def number(value: float) -> str:
    """A figure with the digits a benchmark on a shared machine can vouch for (3-4)."""
    magnitude = abs(value)
    if magnitude >= 10_000:
        return f"{value:,.0f}"
    if magnitude >= 100:
        return f"{value:.0f}"
    if magnitude >= 1:
        return f"{value:.3g}"
    return f"{value:.3g}" if magnitude >= 1e-3 or value == 0 else f"{value:.2e}"


def ratio(value: float, baseline: float) -> str:
    """ours / baseline; a dash where the baseline is zero (e.g. 0 datagrams lost)."""
    return f"{value / baseline:.3g}" if baseline else "—"


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def describe_run(info: Mapping[str, Any]) -> str:
    """One paragraph: when, which commit, on what, beside what load, with which libraries."""
    load_start = "/".join(f"{x:g}" for x in info.get("load_average_start", []))
    load_end = "/".join(f"{x:g}" for x in info.get("load_average_end", []))
    packages = ", ".join(f"{k} {v}" for k, v in info.get("packages", {}).items())
    return (
        f"One `make bench` run, {info['started']} to {info['finished'].split(' ', 1)[1]},"
        f" commit {info['commit']}, on {info['cpu']} ({info['cpus']} CPUs),"
        f" load average (1/5/15 min) {load_start} at the start and {load_end} at the end;"
        f" Python {info['python']}, {info['platform']}, CRC-32 by {info['crc32']};"
        f" {packages}.{_speed_range(info)}"
    )


def _speed_range(info: Mapping[str, Any]) -> str:
    slowest = info.get("cpu_speed_slowest")
    if slowest is None:
        return ""
    return (
        f" The CPU's speed (bench.pace's gauge) ranged from {float(slowest) * 100:.0f} %"
        " to 100 % of its fastest during the run; figures with an absolute target wait for"
        " full speed."
    )


_SHOWN = {
    Verdict.MET: "yes",
    Verdict.NOT_MET: "**no**",
    Verdict.UNDECIDED: "undecided (CPU below full speed)",
    Verdict.NOT_MEASURED: "—",
}


def _speed_note(r: Mapping[str, Any]) -> str:
    """ " (CPU at 64 % of full speed)" for a figure measured on a slowed-down machine."""
    speed = r.get("machine_speed")
    if speed is None or float(speed) >= FULL_SPEED:
        return ""
    return f" (CPU at {float(speed) * 100:.0f} % of full speed)"


def targets_table(results: list[Mapping[str, Any]]) -> str:
    """Whether the run meets each target (bench/targets.py), with the figure that decides it."""
    out = [
        "| target | this run (ours; ours / baseline) | met |",
        "|---|---|---|",
    ]
    for target, r in verdicts(results):
        verdict = judge(target, r)
        if r is None:
            out.append(f"| {_cell(target.goal)} | not measured in this run | {_SHOWN[verdict]} |")
            continue
        shown = (
            f"{number(r['value'])} {r['unit']}{_speed_note(r)};"
            f" {ratio(r['value'], r['baseline'])} × {r['baseline_name']}"
        )
        out.append(f"| {_cell(target.goal)} | {_cell(shown)} | {_SHOWN[verdict]} |")
    return "\n".join(out) + "\n"


def check_status(results: list[Mapping[str, Any]]) -> int:
    """Exit status of ``--check``: OK every target met, FAILED one missed, UNTRUSTED one that
    the results cannot decide."""
    found = {judge(target, r) for target, r in verdicts(results)}
    if Verdict.NOT_MET in found:
        return ExitCode.FAILED
    return ExitCode.OK if found == {Verdict.MET} else ExitCode.UNTRUSTED


def tables(results: Iterable[Mapping[str, Any]]) -> str:
    """A table per benchmark area: figure, ours, the baseline of the same run, the ratio."""
    areas: dict[str, list[Mapping[str, Any]]] = {}
    for r in results:
        areas.setdefault(str(r.get("area", "bench")), []).append(r)
    out: list[str] = []
    for area, rows in areas.items():
        out += [
            f"`{area}`:",
            "",
            "| figure (function measured) | ours | baseline in the same run | ours / baseline |",
            "|---|---|---|---|",
        ]
        for r in rows:
            unit = r["unit"]
            out.append(
                f"| {_cell(r['name'])} | {number(r['value'])} {unit}{_speed_note(r)}"
                f" | {_cell(r['baseline_name'])}: {number(r['baseline'])} {unit}"
                f" | {ratio(r['value'], r['baseline'])} |"
            )
        out.append("")
    return "\n".join(out)


def load(results_path: Path) -> list[Mapping[str, Any]]:
    results = json.loads(results_path.read_text())
    if not isinstance(results, list) or not results:
        raise ValueError(f"{results_path} holds no benchmark results")
    return results


def render(results_path: Path) -> str:
    results = load(results_path)
    run_path = record_path(results_path)
    head = (
        describe_run(json.loads(run_path.read_text()))
        if run_path.exists()
        else f"(no {run_path.name} beside {results_path.name}: date and machine unknown)"
    )
    return f"{head}\n\n{targets_table(results)}\n{tables(results)}"


def put_into(document: str, text: str) -> str:
    """``document`` with the lines between its table markers replaced by ``text``."""
    lines = document.splitlines(keepends=True)
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == START)
        end = next(i for i, line in enumerate(lines) if line.strip() == END and i > start)
    except StopIteration:
        raise ValueError(f"no {START} ... {END} lines to put the tables between") from None
    return "".join(lines[: start + 1]) + "\n" + text.rstrip("\n") + "\n\n" + "".join(lines[end:])


def main(argv: list[str] | None = None) -> int:
    parser = cliargs.Parser(prog="python -m bench.table", description=__doc__)
    parser.add_argument("results", nargs="?", type=Path, default=Path("bench-results/results.json"))
    parser.add_argument("--into", type=Path, help="document whose table section to replace")
    parser.add_argument(
        "--check", action="store_true", help="print the targets alone; exit 0 if all are met"
    )
    args = parser.parse_args(argv)
    if args.check and args.into is not None:
        parser.error("--check and --into do not go together")
    try:
        if args.check:
            results = load(args.results)
            sys.stdout.write(targets_table(results))
            return check_status(results)
        text = render(args.results)
        if args.into is None:
            sys.stdout.write(text)
            return 0
        write_atomically(args.into, put_into(args.into.read_text(), text))
    except (OSError, ValueError) as exc:  # JSONDecodeError is a ValueError
        print(f"bench.table: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    except KeyError as exc:
        print(f"bench.table: {args.results}: a result lacks the field {exc}", file=sys.stderr)
        return ExitCode.USAGE
    print(f"bench.table: wrote the tables of {args.results} into {args.into}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(cliargs.run_cli(main))
