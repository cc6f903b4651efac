"""Real time under load (issue 12): the 4 ms tick, the live ΔT and the idle cost.

Load: ``HOGS`` CPU-bound processes and a process with ``CLIENTS`` threads polling Herej as
fast as they can, on the same machine (two cores here). Figures, each with a baseline from
the same run:

- robot tick lateness p50 / p99 / max under load with the real-time isolation of
  docs/REALTIME.md (SCHED_FIFO thread, 0.5 ms GIL switch interval), against the same load
  without it (a normal thread, the 5 ms default interval), and idle with isolation;
- live ΔT of the real-clock cell at 250 Hz under load, |estimate - truth| with encoder
  latencies 0 and 10 ms, against the same error on an idle machine (truth: the cell's own
  records of each acquisition, :meth:`cell.cell.EmulatedCell.measured_delta_t`); and the
  data datagrams lost under load;
- idle CPU (% of one core over ``IDLE_S``) of each server process, against the 0.5 % budget.

Run alone: ``python -m bench --only realtime``; ``python -m bench.bench_realtime herej
HOST PORT N`` is the Herej load process it starts.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import Result, result
from spec.realtime import REALTIME_SWITCH_INTERVAL_S

HOGS = 2
CLIENTS = 64
TICK_S = 5.0
IDLE_S = 4.0
IDLE_BUDGET_PCT = 0.5


def _herej_load(host: str, port: int, n: int) -> None:
    """The load process: ``n`` threads polling Herej until stdin closes."""
    from robotsocket.client import RobotClient

    stop = threading.Event()
    calls = [0] * n

    def poll(i: int) -> None:
        with RobotClient(host, port, timeout=10.0) as c:
            while not stop.is_set():
                c.herej()
                calls[i] += 1

    threads = [threading.Thread(target=poll, args=(i,), daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    print("ready", flush=True)
    sys.stdin.read()
    stop.set()
    print(sum(calls), flush=True)


@contextlib.contextmanager
def _load(
    address: tuple[str, int], clients: int = CLIENTS, hogs: int = HOGS
) -> Iterator[list[int]]:
    """CPU hogs and a Herej client process for the duration of the block; the yielded list
    receives the number of Herej calls served once the block ends."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(hogs)]
    if not clients:
        try:
            yield []
        finally:
            for p in procs:
                p.kill()
                p.wait()
        return
    load = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bench.bench_realtime",
            "herej",
            address[0],
            str(address[1]),
            str(clients),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    calls: list[int] = []
    try:
        assert load.stdout is not None
        load.stdout.readline()  # "ready": every client connected
        yield calls
    finally:
        try:
            out, _ = load.communicate("", timeout=10.0)  # closes stdin: the clients stop
            calls.extend(int(x) for x in out.split())
        except (subprocess.TimeoutExpired, ValueError):
            load.kill()
        for p in procs:
            p.kill()
            p.wait()


def _tick_lateness(
    isolated: bool, loaded: bool, switch_interval_s: float = REALTIME_SWITCH_INTERVAL_S
) -> tuple[dict[str, float], dict[str, float], float]:
    """Lateness (s) of the robot server's ticks over TICK_S, as ``robotsocket serve`` runs
    it, the lateness of the samples (by whichever thread computed them first) and the Herej
    calls per second the server answered meanwhile."""
    from robotsocket.emulator import HOME, RobotEmulator
    from robotsocket.service import RobotService
    from robotsocket.sync_service import attach_udp_sync
    from spec.server import FramedServer

    before = sys.getswitchinterval()
    robot = RobotEmulator(clock="real")
    loop = robot._loop
    assert loop is not None
    loop.switch_interval_s = switch_interval_s
    if not isolated:
        loop.rt_priority = 0
        loop.switch_interval_s = None
        sys.setswitchinterval(0.005)  # CPython's default
    service = RobotService(robot)
    _, endpoint = attach_udp_sync(service, robot)
    server = FramedServer(service, "127.0.0.1", 0)
    server.start()
    robot.start()
    endpoint.start()
    calls: list[int] = []
    try:
        # the arm moves back and forth the whole time: at rest the clock thread sleeps
        robot.enable_power()
        a, b = np.array([-15.0, 0.0, 90.0, 0.0, 90.0, 0.0]), np.array(HOME)
        for i in range(40):
            robot.joint_move(a if i % 2 == 0 else b)
        with contextlib.ExitStack() as stack:
            if loaded:
                calls = stack.enter_context(_load(server.address))
            n0 = robot.jitter()["count"]
            time.sleep(TICK_S)
            assert robot.status().moving and robot.jitter()["count"] > n0
    finally:
        endpoint.stop()
        robot.close()
        server.shutdown()
        sys.setswitchinterval(before)
    return robot.jitter(), robot.sample_lateness(), sum(calls) / TICK_S


def _live_delta_t(latency_s: float, clients: int, hogs: int) -> tuple[float, dict[str, Any]]:
    """|ΔT estimate - truth| (s) of a 3 s live ``python -m sync delay`` at 250 Hz (its own
    process, as a user runs it) against the real-clock cell, and its JSON (statistics,
    verdict)."""
    from cell.cell import CellTiming, EmulatedCell

    timing = replace(CellTiming(), encoder_latency_s=latency_s)
    with (
        tempfile.TemporaryDirectory() as tmp,
        EmulatedCell(clock="real", seed=2, timing=timing) as cell,
    ):
        out = Path(tmp) / "d.json"
        first = cell.core.next_index
        with contextlib.ExitStack() as stack:
            if clients or hogs:
                stack.enter_context(_load(cell.robot_address, clients=clients, hogs=hogs))
            robot, sensor = cell.robot_address, cell.sensor_address
            done = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "sync",
                    "delay",
                    "-q",
                    "--duration",
                    "3",
                    "--robot",
                    f"{robot[0]}:{robot[1]}",
                    "--sensor",
                    f"{sensor[0]}:{sensor[1]}",
                    "--json",
                    str(out),
                ],
                capture_output=True,
                text=True,
                timeout=120,
            )
        truth = cell.measured_delta_t(first)
        if not out.exists():  # no result at all: say why
            lines = done.stderr.strip().splitlines() or ["?"]
            return math.nan, {"exit": done.returncode, "error": lines[-1]}
        j: dict[str, Any] = json.loads(out.read_text())
    return abs(j["delta_t_ms"] * 1e-3 - truth), j


_SERVERS = {
    "robotsocket serve --clock sim": ["robotsocket", "serve", "--clock", "sim", "--port", "0"],
    "robotsocket serve --clock real": ["robotsocket", "serve", "--clock", "real", "--port", "0"],
    "sensorsocket serve --clock sim": [
        "sensorsocket",
        "serve",
        "--clock",
        "sim",
        "--port",
        "0",
        "--udp-port",
        "0",
    ],
    "cell serve --clock sim": [
        "cell",
        "serve",
        "--clock",
        "sim",
        "--robot-port",
        "0",
        "--sensor-port",
        "0",
        "--udp-port",
        "0",
    ],
}


def _cpu_s(pid: int) -> float:
    """CPU time of every thread of ``pid`` (s), from schedstat (ns; /proc/PID/stat counts in
    10 ms ticks, too coarse for a 0.5 % budget)."""
    total = 0
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                total += int(f.read().split()[0])
        except (FileNotFoundError, ProcessLookupError):
            continue  # a thread that just ended
    return total / 1e9


def _idle_cpu() -> dict[str, float]:
    """% of one core each server uses over IDLE_S after it is listening (all at once)."""
    procs = {
        name: subprocess.Popen(
            [sys.executable, "-u", "-m", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,  # some say "listening" in their log
            text=True,
        )
        for name, argv in _SERVERS.items()
    }
    try:
        for p in procs.values():
            assert p.stdout is not None
            p.stdout.readline()  # the first line once it listens
        time.sleep(1.0)  # start-up work (imports, first ticks) is not idle cost
        c0 = {n: _cpu_s(p.pid) for n, p in procs.items()}
        t0 = time.monotonic()
        time.sleep(IDLE_S)
        dt = time.monotonic() - t0
        return {n: (_cpu_s(p.pid) - c0[n]) / dt * 100.0 for n, p in procs.items()}
    finally:
        for p in procs.values():
            p.terminate()
            try:
                p.wait(5.0)
            except subprocess.TimeoutExpired:
                p.kill()


def run() -> list[Result]:
    out: list[Result] = []
    load = f"{HOGS} hogs + {CLIENTS} Herej clients"
    idle, _, _ = _tick_lateness(isolated=True, loaded=False)
    bare, bare_samples, bare_rate = _tick_lateness(isolated=False, loaded=True)
    iso, iso_samples, iso_rate = _tick_lateness(isolated=True, loaded=True)
    for key in ("p50", "p99", "max"):
        out.append(
            result(
                f"robot tick lateness {key}, {load}, isolated",
                iso[key] * 1e3,
                "ms",
                f"same load, not isolated {key} (idle isolated {idle[key] * 1e3:.3f} ms)",
                bare[key] * 1e3,
            )
        )
    for key in ("p50", "p99"):
        out.append(
            result(
                f"robot sample lateness {key} (any thread), {load}, isolated",
                iso_samples[key] * 1e3,
                "ms",
                f"same load, not isolated {key}",
                bare_samples[key] * 1e3,
            )
        )
    out.append(
        result(f"Herej calls/s, {load}, isolated", iso_rate, "1/s", "not isolated", bare_rate)
    )
    # the server's 64 connections: the experiment's and 63 Herej clients
    loads = ((f"{HOGS} hogs", 0), (f"{HOGS} hogs + {CLIENTS - 1} Herej clients", CLIENTS - 1))
    for what, clients in loads:
        for latency in (0.0, 10e-3):
            err_idle, _ = _live_delta_t(latency, 0, 0)
            err, j = _live_delta_t(latency, clients, HOGS)
            stats = j.get("statistics", {})
            verdict = j.get("verdict", {})
            if "error" in j:
                note = f" (no result, exit {j['exit']}: {j['error'][:60]})"
            else:
                note = "" if verdict.get("ok") else " (UNTRUSTED: exit 3)"
            out.append(
                result(
                    f"live ΔT |error| 250 Hz, encoder {latency * 1e3:g} ms, {what}{note}",
                    err * 1e3,
                    "ms",
                    "same, idle machine",
                    err_idle * 1e3,
                )
            )
            out.append(
                result(
                    f"live ΔT data late or lost (encoder {latency * 1e3:g} ms, {what})",
                    stats.get("lost", math.nan),
                    "datagrams",
                    "triggers sent",
                    stats.get("sent", math.nan),
                )
            )
            out.append(
                result(
                    f"live ΔT readings used (encoder {latency * 1e3:g} ms, {what})",
                    stats.get("matched", math.nan),
                    "readings",
                    "triggers sent (the rest: OVERRUN, the sensor's backlog)",
                    stats.get("sent", math.nan),
                )
            )
    if sys.platform.startswith("linux"):
        for name, pct in _idle_cpu().items():
            out.append(result(f"idle CPU {name}", pct, "% core", "budget", IDLE_BUDGET_PCT))
    return out


if __name__ == "__main__":
    if len(sys.argv) == 5 and sys.argv[1] == "herej":
        _herej_load(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
    else:
        print("usage: python -m bench.bench_realtime herej HOST PORT N", file=sys.stderr)
        sys.exit(2)
