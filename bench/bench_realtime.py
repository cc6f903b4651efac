"""Real time under load (issue 12): the 4 ms tick, the live ΔT and the idle cost.

Load: ``HOGS`` CPU-bound processes and a process with ``CLIENTS - 1`` threads polling Herej as
fast as they can, on the same machine (two cores here). Figures, each with a baseline from
the same run:

- robot tick lateness p50 / p99 / max under load, the server as ``robotsocket serve --clock
  real`` runs it (the 4 ms loop in a real-time child process; the child's own record of its
  ticks), against the same load with ``--in-process`` (one process, SCHED_FIFO clock thread,
  0.5 ms GIL switch interval), and the child idle;
- live ΔT of the real-clock cell at 250 Hz under load, |estimate - truth| with encoder
  latencies 0 and 10 ms, the cell as ``cell serve`` runs it (real-time child) against the
  in-process cell under the same load (truth: the cell's own records of each acquisition,
  :meth:`cell.cell.EmulatedCell.measured_delta_t`); the data datagrams late or lost and the
  readings used;
- idle CPU (% of one core over ``IDLE_S``, a server and its child process) of each server,
  against the 0.5 % budget.

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
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

from bench.common import Result, result
from spec.exitcodes import ExitCode

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


def _in_process_server() -> tuple[Any, Callable[[], dict[str, float]], Callable[[], None]]:
    """``robotsocket serve --clock real --in-process``: the server, the tick jitter, stop."""
    from robotsocket.emulator import RobotEmulator
    from robotsocket.service import RobotService
    from robotsocket.sync_service import attach_udp_sync
    from spec.server import FramedServer, ServerPolicy

    robot = RobotEmulator(clock="real")
    service = RobotService(robot)
    _, endpoint = attach_udp_sync(service, robot)
    server = FramedServer(
        service, "127.0.0.1", 0, ServerPolicy(max_per_address=CLIENTS)
    ).start()  # one host (RS-7.24)
    robot.start()
    endpoint.start()

    def stop() -> None:
        endpoint.stop()
        robot.close()
        server.shutdown()

    return server, robot.jitter, stop


def _child_server() -> tuple[Any, Callable[[], dict[str, float]], Callable[[], None]]:
    """``robotsocket serve --clock real`` (the default): the loop in a real-time child; the
    jitter is the child's record of its own ticks."""
    from robotsocket.rtprocess import RealtimeProcess, RobotProcess
    from spec.server import FramedServer, ServerPolicy

    config = {
        "model": "RX90B",
        "encoder_latency_s": 0.0,
        "host": "127.0.0.1",
        "udp_port": 0,
        "allow": (),
        "data_from_any": False,
    }
    child = RealtimeProcess("robotsocket.rtprocess:build_robot", config)
    server = FramedServer(
        RobotProcess(child), "127.0.0.1", 0, ServerPolicy(max_per_address=CLIENTS)
    ).start()  # one host (RS-7.24)

    def stop() -> None:
        server.shutdown()
        child.close()

    return server, lambda: dict(child.query("jitter")), stop


def _tick_lateness(child: bool, loaded: bool) -> tuple[dict[str, float], float]:
    """Lateness (s) of the robot's 4 ms ticks over TICK_S while the arm moves back and forth,
    with the server as ``robotsocket serve --clock real`` runs it (``child``) or with
    ``--in-process``, and the Herej calls per second it answered meanwhile."""
    from robotsocket.client import RobotClient
    from robotsocket.emulator import HOME

    before = sys.getswitchinterval()
    server, jitter, stop = _child_server() if child else _in_process_server()
    calls: list[int] = []
    try:
        with RobotClient(*server.address, timeout=10.0) as c:
            c.take_control("")
            c.enable_power()
            a, b = [-15.0, 0.0, 90.0, 0.0, 90.0, 0.0], list(HOME)
            for i in range(40):  # at rest the clock thread sleeps: keep it moving
                c.joint_move(a if i % 2 == 0 else b)
            with contextlib.ExitStack() as stack:
                if loaded:
                    calls = stack.enter_context(_load(server.address, clients=CLIENTS - 1))
                n0 = jitter()["count"]
                time.sleep(TICK_S)
                assert c.status().moving and jitter()["count"] > n0
            j = jitter()
    finally:
        stop()
        sys.setswitchinterval(before)
    return j, sum(calls) / TICK_S


def _live_delta_t(
    latency_s: float, clients: int, hogs: int, child: bool
) -> tuple[float, dict[str, Any]]:
    """|ΔT estimate - truth| (s) of a 3 s live ``python -m sync delay`` at 250 Hz (its own
    process, as a user runs it) against the real-clock cell (``child``: as ``cell serve``
    runs it, else ``--in-process``), and its JSON (statistics, verdict)."""
    from cell.cell import CellTiming, EmulatedCell
    from cell.rtcell import CellProcess

    timing = replace(CellTiming(), encoder_latency_s=latency_s)
    with contextlib.ExitStack() as cells, tempfile.TemporaryDirectory() as tmp:
        if child:
            proc = cells.enter_context(CellProcess(seed=2, timing=timing))
            first = proc.next_index()
            truth_of: Callable[[int], float] = proc.measured_delta_t
            robot, sensor = proc.robot_address, proc.sensor_address
        else:
            cell = cells.enter_context(EmulatedCell(clock="real", seed=2, timing=timing))
            first = cell.core.next_index
            truth_of = cell.measured_delta_t
            robot, sensor = cell.robot_address, cell.sensor_address
        out = Path(tmp) / "d.json"
        with contextlib.ExitStack() as stack:
            if clients or hogs:
                stack.enter_context(_load(robot, clients=clients, hogs=hogs))
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
        truth = truth_of(first)
        if not out.exists():  # no result at all: say why
            lines = done.stderr.strip().splitlines() or ["?"]
            return math.nan, {"exit": done.returncode, "error": lines[-1]}
        j: dict[str, Any] = json.loads(out.read_text())
    return abs(j["delta_t_ms"] * 1e-3 - truth), j


_SERVERS = {
    "robotsocket serve --clock sim": ["robotsocket", "serve", "--clock", "sim", "--port", "0"],
    "robotsocket serve --clock real": ["robotsocket", "serve", "--clock", "real", "--port", "0"],
    "robotsocket serve --clock real --in-process": [
        "robotsocket",
        "serve",
        "--clock",
        "real",
        "--in-process",
        "--port",
        "0",
    ],
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
    "cell serve --clock real": [
        "cell",
        "serve",
        "--clock",
        "real",
        "--robot-port",
        "0",
        "--sensor-port",
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
    """CPU time of every thread of ``pid`` and of its child processes (the real-time child)
    (s), from schedstat (ns; /proc/PID/stat counts in 10 ms ticks, too coarse for a 0.5 %
    budget)."""
    total = 0
    kids: list[int] = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/schedstat") as f:
                total += int(f.read().split()[0])
            with open(f"/proc/{pid}/task/{tid}/children") as f:
                kids.extend(int(k) for k in f.read().split())
        except (FileNotFoundError, ProcessLookupError):
            continue  # a thread that just ended
    return total / 1e9 + sum(_cpu_s(k) for k in kids)


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
    load = f"{HOGS} hogs + {CLIENTS - 1} Herej clients"
    idle, _ = _tick_lateness(child=True, loaded=False)
    inproc, inproc_rate = _tick_lateness(child=False, loaded=True)
    child, child_rate = _tick_lateness(child=True, loaded=True)
    for key in ("p50", "p99", "max"):
        out.append(
            result(
                f"robot tick lateness {key}, {load}, real-time child",
                child[key] * 1e3,
                "ms",
                f"same load, in-process {key} (idle child {idle[key] * 1e3:.3f} ms)",
                inproc[key] * 1e3,
            )
        )
    out.append(
        result(
            f"Herej calls/s, {load}, real-time child", child_rate, "1/s", "in-process", inproc_rate
        )
    )
    # the server's 64 connections: the experiment's and 63 Herej clients
    loads = ((f"{HOGS} hogs", 0), (load, CLIENTS - 1))
    for what, clients in loads:
        for latency in (0.0, 10e-3):
            runs = {c: _live_delta_t(latency, clients, HOGS, child=c) for c in (True, False)}
            (err, j), (err_in, j_in) = runs[True], runs[False]
            stats, stats_in = j.get("statistics", {}), j_in.get("statistics", {})
            verdict = j.get("verdict", {})
            if "error" in j:
                note = f" (no result, exit {j['exit']}: {j['error'][:60]})"
            else:
                note = "" if verdict.get("ok") else f" (UNTRUSTED: exit {ExitCode.UNTRUSTED:d})"
            tag = f"encoder {latency * 1e3:g} ms, {what}"
            out.append(
                result(
                    f"live ΔT |error| 250 Hz, {tag}, real-time child{note}",
                    err * 1e3,
                    "ms",
                    "same, in-process cell",
                    err_in * 1e3,
                )
            )
            out.append(
                result(
                    f"live ΔT data late or lost of {stats.get('sent', math.nan)} ({tag}, child)",
                    stats.get("lost", math.nan),
                    "datagrams",
                    "in-process cell",
                    stats_in.get("lost", math.nan),
                )
            )
            out.append(
                result(
                    f"live ΔT readings used of {stats.get('sent', math.nan)} ({tag}, child)",
                    stats.get("matched", math.nan),
                    "readings",
                    "in-process cell",
                    stats_in.get("matched", math.nan),
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
