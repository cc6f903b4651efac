"""What a benchmark run ran on: the record written beside the results (``results.run.json``).

A figure means little without the machine, the load it shared the machine with and the code it
measured, so ``python -m bench`` writes them next to ``results.json`` and ``python -m
bench.table`` prints them above the table.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path
from typing import NotRequired, TypedDict

#: Libraries whose version moves the figures: ours (numpy, the CRC) and the peers'.
_PACKAGES = (
    "numpy",
    "zlib-ng",
    "roboticstoolbox-python",
    "opencv-python-headless",
    "scipy",
    "pyzmq",
    "pyModbusTCP",
)


class RunInfo(TypedDict):
    started: str
    finished: str
    commit: str
    cpu: str
    cpus: int
    load_average_start: list[float]
    load_average_end: list[float]
    python: str
    platform: str
    crc32: str
    packages: dict[str, str]
    # the slowest CPU speed bench.pace's gauge saw, as a fraction of the fastest (1.0: steady)
    cpu_speed_slowest: NotRequired[float]


def record_path(results: Path) -> Path:
    """Where the run record of ``results`` goes: beside it, named after it, so two result
    files in one directory never share (or swap) their records."""
    return results.with_name(f"{results.stem}.run.json")


def utc_now() -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())


def load_average() -> list[float]:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:  # not available on this platform
        return []


def cpu_model() -> str:
    """The CPU's model name (Linux), else what platform knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def git_commit() -> str:
    """The checkout's commit (with ``+changes`` when the tree differs), or "unknown"."""
    try:
        head = _git("rev-parse", "--short", "HEAD")
        dirty = _git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return f"{head}+changes" if dirty else head


def _git(*args: str) -> str:
    """What ``git ARGS`` prints in this checkout, stripped; raises if git fails."""
    here = Path(__file__).resolve().parent.parent
    done = subprocess.run(
        ["git", "-C", str(here), *args], capture_output=True, text=True, timeout=10, check=True
    )
    return done.stdout.strip()


def _versions() -> dict[str, str]:
    found = {}
    for name in _PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return found


def collect(started: str, load_start: list[float]) -> RunInfo:
    """The record of a run that began at ``started`` with load average ``load_start``."""
    from bench.pace import GAUGE
    from spec.crc import CRC32_IMPLEMENTATION

    info = RunInfo(
        started=started,
        finished=utc_now(),
        commit=git_commit(),
        cpu=cpu_model(),
        cpus=os.cpu_count() or 0,
        load_average_start=load_start,
        load_average_end=load_average(),
        python=sys.version.split()[0],
        platform=platform.platform(terse=True),
        crc32=CRC32_IMPLEMENTATION,
        packages=_versions(),
    )
    info["cpu_speed_slowest"] = round(GAUGE.slowest(), 3)
    return info
