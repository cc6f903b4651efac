"""Wall time of the conformance profiles against our in-process reference servers.

Targets (issue 7): the core profile under 20 s and the full profile under 120 s per service.
Baseline, measured in the same run: the smoke profile against the same server.
"""

from __future__ import annotations

import time

from bench.common import Result, result
from conformance.context import Options
from conformance.reference import ReferenceUnavailable, start
from conformance.runner import Selection
from conformance.runner import run as run_cases


def _wall(service: str, profile: str) -> tuple[float, int]:
    """Seconds for one run of ``profile`` (fresh reference server) and the case count."""
    ref = start(service)
    try:
        t0 = time.perf_counter()
        out = run_cases(service, ref.host, ref.port, Options(allow_motion=True), Selection(profile))
        return time.perf_counter() - t0, len(out.results)
    finally:
        ref.stop()


def run_bench() -> list[Result]:
    results: list[Result] = []
    for service in ("robot", "sensor"):
        try:
            smoke, n_smoke = _wall(service, "smoke")
        except ReferenceUnavailable:
            continue
        for profile in ("core", "full"):
            wall, n = _wall(service, profile)
            results.append(
                result(
                    f"conformance {service} {profile} profile ({n} cases) wall time",
                    wall,
                    "s",
                    f"smoke profile ({n_smoke} cases)",
                    smoke,
                )
            )
    return results


def run() -> list[Result]:
    return run_bench()
