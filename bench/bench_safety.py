"""Safety of control under faults: time from the fault of a controlling client (a real
``python -m robotsocket call`` process) to the stopped arm, and the joint travel after the
fault, against a ResetMotion issued in the server's process at the same point of the same
move (the controlled stop the fault should cost, no more). EmergencyStop on a full server:
connect and request to the reply (the arm is halted when it comes), against the same on a
free server.

The robot runs on the real clock with the default control watchdog (0.25 s)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from bench.common import Result, result
from robotsocket.client import RobotClient
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from spec.server import FramedServer, ServerPolicy

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
TARGET = (150.0, 0.0, 90.0, 0.0, 90.0, 0.0)
FAULT_AT_DEG = 20.0  # the fault comes when joint 1 has moved this far (at cruise speed)


def _wait(what: Callable[[], bool], timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while not what():
        if time.monotonic() > deadline:
            raise RuntimeError("the arm did not reach the expected state")
        time.sleep(0.0005)


def _stop_after(robot: RobotEmulator, fault: Callable[[], None]) -> tuple[float, float]:
    """Run ``fault`` when joint 1 passes FAULT_AT_DEG; (seconds to stopped, travel deg)."""
    _wait(lambda: robot.herej()[0] >= FAULT_AT_DEG)
    q0 = float(robot.herej()[0])
    t0 = time.monotonic()
    fault()
    _wait(lambda: not robot.status().moving)
    return time.monotonic() - t0, float(robot.herej()[0]) - q0


def _home(robot: RobotEmulator) -> None:
    robot.reset_emergency_stop()
    robot.enable_power()
    robot.joint_move(list((0.0, *TARGET[1:])))  # type: ignore[arg-type]
    robot.wait_end_move(30.0)


def run() -> list[Result]:
    robot = RobotEmulator(clock="real").start()
    server = FramedServer(RobotService(robot), "127.0.0.1", 0, ServerPolicy(max_clients=16))
    endpoint = f"127.0.0.1:{server.address[1]}"
    out: list[Result] = []
    with server:
        robot.enable_power()

        def direct() -> tuple[float, float]:
            _home(robot)
            robot.joint_move(list(TARGET))  # type: ignore[arg-type]
            return _stop_after(robot, robot.reset_motion)

        base_s, base_deg = direct()

        def by_signal(sig: signal.Signals) -> tuple[float, float]:
            _home(robot)
            proc = subprocess.Popen(
                [sys.executable, "-m", "robotsocket", "call", endpoint, "JointMove",
                 ",".join(map(str, TARGET))],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=ENV, cwd=ROOT,
            )  # fmt: skip
            try:
                return _stop_after(robot, lambda: proc.send_signal(sig))
            finally:
                if sig == signal.SIGSTOP:
                    proc.send_signal(signal.SIGCONT)
                proc.kill()
                proc.wait(10)

        for label, sig in (
            ("kill -9 in WaitEndMove", signal.SIGKILL),
            ("SIGSTOP (watchdog 1 s)", signal.SIGSTOP),
            ("Ctrl-C of call", signal.SIGINT),
        ):
            seconds, travel = by_signal(sig)
            name = f"safety stop after {label}"
            out.append(result(name, seconds * 1e3, "ms", "in-process ResetMotion", base_s * 1e3))
            name = f"safety travel after {label}"
            out.append(result(name, travel, "deg", "in-process ResetMotion", base_deg))

        def estop_latency(full: bool) -> float:
            """Connect, EmergencyStop, reply: seconds (robot halted when the reply comes)."""
            _home(robot)
            n = 16 if full else 0
            fillers = [socket.create_connection(server.address, timeout=5) for _ in range(n)]
            try:
                _wait(lambda: server.statistics()["clients"] == n)
                t0 = time.perf_counter()
                with RobotClient(*server.address) as client:
                    client.emergency_stop()
                seconds = time.perf_counter() - t0
            finally:
                for s in fillers:
                    s.close()
            assert robot.status().estop
            return seconds

        free_s = estop_latency(full=False)
        full_s = estop_latency(full=True)
        name = "EmergencyStop on a full server (connect + request)"
        out.append(result(name, full_s * 1e3, "ms", "the same on a free server", free_s * 1e3))
        robot.reset_emergency_stop()
    robot.close()
    return out
