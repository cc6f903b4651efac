"""`python -m bench.table` turns one run's results into the README's tables (bench/table.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

import pytest

from bench import run_info
from bench.common import result
from bench.table import END, START, number, put_into, ratio, render
from bench.targets import TARGETS, Verdict, judge
from spec.exitcodes import ExitCode


def _run(tmp_path: Path) -> Path:
    results = [
        {**result("robotsocket Herej p50 (RobotClient.herej)", 61.2e-0, "µs", "pyModbusTCP", 55.0),
         "area": "bench_peers_net"},
        {**result("sensor.detect() butt", 3125.4, "frames/s", "memory read", 165000.0),
         "area": "bench_sensor"},
    ]  # fmt: skip
    path = tmp_path / "results.json"
    path.write_text(json.dumps(results))
    info = run_info.collect("2026-11-27 10:20 UTC", [0.5, 0.7, 1.0])
    run_info.record_path(path).write_text(json.dumps(info))
    return path


def test_each_figure_stands_beside_its_baseline_under_the_run_that_measured_it(
    tmp_path: Path,
) -> None:
    text = render(_run(tmp_path))
    head = text.splitlines()[0]
    assert head.startswith("One `make bench` run, 2026-11-27 10:20 UTC to ")
    assert run_info.cpu_model() in head and "load average (1/5/15 min) 0.5/0.7/1 " in head
    assert (
        "| robotsocket Herej p50 (RobotClient.herej) | 61.2 µs | pyModbusTCP: 55 µs | 1.11 |"
        in text
    )
    assert (
        "| sensor.detect() butt | 3125 frames/s | memory read: 165,000 frames/s | 0.0189 |" in text
    )
    assert text.index("`bench_peers_net`:") < text.index("`bench_sensor`:")


def test_numbers_keep_the_digits_a_shared_machine_vouches_for() -> None:
    assert [number(v) for v in (1_706_543.2, 3125.4, 61.23, 7.266, 0.02079, 2e-5)] == [
        "1,706,543",
        "3125",
        "61.2",
        "7.27",
        "0.0208",
        "2.00e-05",
    ]


def test_a_zero_baseline_gives_a_dash_not_infinity() -> None:
    assert (ratio(0.0, 0.0), ratio(3.0, 0.0), ratio(3.0, 2.0)) == ("—", "—", "1.5")


def test_only_the_marked_section_of_a_document_is_replaced() -> None:
    doc = f"# Title\n\ntext before\n{START}\nold table\n{END}\ntext after\n"
    once = put_into(doc, "new table\n")
    assert once == f"# Title\n\ntext before\n{START}\n\nnew table\n\n{END}\ntext after\n"
    assert put_into(once, "new table\n") == once  # a second run changes nothing
    with pytest.raises(ValueError, match="bench-table:start"):
        put_into("# no markers\n", "table")


def _cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    command = [sys.executable, "-m", "bench.table", *map(str, args)]
    return subprocess.run(command, capture_output=True, text=True, timeout=60)


def test_cli_writes_into_the_document_and_refuses_what_it_cannot_use(tmp_path: Path) -> None:
    results = _run(tmp_path)
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{START}\n{END}\n")
    done = _cli(results, "--into", readme)
    assert done.returncode == 0, done.stderr
    assert "| sensor.detect() butt |" in readme.read_text()

    plain = tmp_path / "plain.md"
    plain.write_text("no markers here\n")
    refused = _cli(results, "--into", plain)
    assert refused.returncode == ExitCode.USAGE and "Traceback" not in refused.stderr
    assert "bench-table:start" in refused.stderr and plain.read_text() == "no markers here\n"

    missing = _cli(tmp_path / "nothing.json")
    assert missing.returncode == ExitCode.USAGE and "nothing.json" in missing.stderr
    assert len(missing.stderr.splitlines()) == 1


def test_targets_are_read_off_the_run_met_or_not_or_not_measured(tmp_path: Path) -> None:
    herej = "robot herej round trip p50, client and server processes"
    results = [
        {**result(herej, 70.0, "us", "pyModbusTCP p50", 56.0), "area": "bench_peers_net"},
        {**result("sensor.detect.butt", 3125.0, "frames/s", "memory read", 1e5), "area": "s"},
    ]
    path = tmp_path / "results.json"
    path.write_text(json.dumps(results))
    lines = render(path).splitlines()
    assert (
        "| Herej p50 across processes ≤ pyModbusTCP's | 70 us; 1.25 × pyModbusTCP p50 | **no** |"
        in lines
    )
    assert (
        "| detect() ≥ 3,000 frames/s, butt | 3125 frames/s; 0.0312 × memory read | yes |" in lines
    )
    assert "| ΔT estimate ≤ 1 ms | not measured in this run | — |" in lines
    assert lines[0] == "(no results.run.json beside results.json: date and machine unknown)"


def _results_file(tmp_path: Path, *results: Mapping[str, object]) -> Path:
    path = tmp_path / "results.json"
    path.write_text(json.dumps([{**r, "area": "bench_sensor"} for r in results]))
    return path


def test_a_value_missed_on_a_slowed_machine_is_undecided_a_ratio_missed_is_not() -> None:
    detect = next(t for t in TARGETS if t.name == "sensor.detect.butt")
    ik = next(t for t in TARGETS if t.name.startswith("kinematics.ik"))
    slow = {"machine_speed": 0.5}
    assert judge(detect, result("sensor.detect.butt", 3100.0, "frames/s", "m", 1e5)) is (
        Verdict.MET
    )
    missed = result("sensor.detect.butt", 2900.0, "frames/s", "m", 1e5)
    assert judge(detect, missed) is Verdict.NOT_MET
    assert judge(detect, {**missed, **slow}) is Verdict.UNDECIDED
    # slower than the peer measured in the same rounds: the machine is no excuse
    behind = result("kinematics.ik single pose, all solutions", 40.0, "µs", "rtb", 30.0)
    assert judge(ik, {**behind, **slow}) is Verdict.NOT_MET
    assert judge(ik, None) is Verdict.NOT_MEASURED


def test_check_prints_the_targets_and_says_with_its_exit_status_if_all_are_met(
    tmp_path: Path,
) -> None:
    # each figure just at its bound, its ratio to its baseline at the ratio's bound (1
    # where there is none): every check holds
    at_bound = [next((c.bound for c in t.checks if c.of == "value"), 1.0) for t in TARGETS]
    ratios = [next((c.bound for c in t.checks if c.of == "ratio"), 1.0) for t in TARGETS]
    fast = [
        result(t.name, v, "x", t.baseline, v / q)
        for t, v, q in zip(TARGETS, at_bound, ratios, strict=True)
    ]
    all_met = _cli(_results_file(tmp_path, *fast), "--check")
    assert all_met.returncode == 0, all_met.stdout + all_met.stderr
    assert all_met.stdout.startswith("| target |") and "**no**" not in all_met.stdout
    assert "`bench_sensor`" not in all_met.stdout  # the targets alone

    slow = [
        {**r, "value": 10.0, "machine_speed": 0.5} if "detect" in r["name"] else r for r in fast
    ]
    undecided = _cli(_results_file(tmp_path, *slow), "--check")
    assert undecided.returncode == ExitCode.UNTRUSTED
    assert "10 x (CPU at 50 % of full speed)" in undecided.stdout
    assert "undecided (CPU below full speed)" in undecided.stdout

    missed = [{**r, "value": 10.0} if "detect" in r["name"] else r for r in fast]
    assert _cli(_results_file(tmp_path, *missed), "--check").returncode == ExitCode.FAILED
    assert (
        _cli(_results_file(tmp_path, *fast[:2]), "--check").returncode == ExitCode.UNTRUSTED
    )  # not measured
    both = _cli(_results_file(tmp_path, *fast), "--check", "--into", tmp_path / "README.md")
    assert both.returncode == 2 and "--into" in both.stderr
