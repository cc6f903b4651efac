"""RobotSocket benchmarks: Herej round trip vs a bare TCP echo, throughput with 1/8/32
clients, trajectory generator cost per 4 ms cycle, real-time tick jitter."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np

from bench.common import Result, one_cpu, percentile, result, time_per_call
from kinematics.robot import get_model
from robotsocket.client import RobotClient
from robotsocket.emulator import RobotEmulator
from robotsocket.interface import MotionDesc
from robotsocket.paths import plan_joint, plan_linear
from robotsocket.service import RobotService
from robotsocket.trajectory import PERIOD, TrajectoryGenerator
from spec.codec import encode_packet, request
from spec.params import Joints
from spec.registry import CommandId
from spec.server import FramedServer

N_RTT = 2000


def _echo_server(reply_size: int) -> tuple[socket.socket, threading.Thread]:
    """A bare TCP server answering each request-sized read with ``reply_size`` bytes."""
    lst = socket.create_server(("127.0.0.1", 0))
    reply = b"x" * reply_size

    def serve() -> None:
        conn, _ = lst.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with conn:
            while conn.recv(65536):
                conn.sendall(reply)

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    return lst, th


def _rtt(fn: object, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        out.append(time.perf_counter() - t0)
    return out


def _throughput(address: tuple[str, int], clients: int, seconds: float = 1.0) -> float:
    counts = [0] * clients
    stop = threading.Event()
    ready = threading.Barrier(clients + 1)

    def worker(i: int) -> None:
        with RobotClient(*address) as c:
            ready.wait()
            while not stop.is_set():
                c.herej()
                counts[i] += 1

    ths = [threading.Thread(target=worker, args=(i,)) for i in range(clients)]
    for t in ths:
        t.start()
    ready.wait()
    t0 = time.perf_counter()
    time.sleep(seconds)
    stop.set()
    for t in ths:
        t.join()
    return sum(counts) / (time.perf_counter() - t0)


def _echo_throughput(req: bytes, reply_size: int, seconds: float = 1.0) -> float:
    lst, _ = _echo_server(reply_size)
    with socket.create_connection(lst.getsockname()) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            s.sendall(req)
            got = 0
            while got < reply_size:
                got += len(s.recv(65536))
            n += 1
    lst.close()
    return n / (time.perf_counter() - t0)


def _herej_rtt(req: bytes, rep_size: int) -> tuple[list[float], list[float]]:
    """Round trips (s) of Herej through a fresh server, and of a bare TCP echo of the same
    byte sizes, alternated in rounds so a busy moment of the machine hits both alike."""
    rtt: list[float] = []
    base: list[float] = []
    lst, _ = _echo_server(rep_size)
    with (
        FramedServer(RobotService(RobotEmulator()), "127.0.0.1", 0) as srv,
        RobotClient(*srv.address) as c,
        socket.create_connection(lst.getsockname()) as s,
    ):
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

        def echo() -> None:
            s.sendall(req)
            got = 0
            while got < rep_size:
                got += len(s.recv(65536))

        for _ in range(200):
            c.herej()
            echo()
        for _ in range(4):
            rtt += _rtt(c.herej, N_RTT // 4)
            base += _rtt(echo, N_RTT // 4)
    lst.close()
    return rtt, base


def run() -> list[Result]:
    results: list[Result] = []
    req = encode_packet(request(CommandId.HEREJ, 1))
    rep_size = len(encode_packet(request(CommandId.HEREJ, 1, Joints([0.0] * 6))))
    with one_cpu() as pinned:
        rtt, base = _herej_rtt(req, rep_size)
    where = "client and server threads on one CPU" if pinned else "unpinned"
    for p in (50, 99):
        results.append(
            result(
                f"Herej round trip p{p}, in process (RobotClient.herej; {where})",
                percentile(rtt, p) * 1e6,
                "us",
                f"bare TCP echo ({len(req)} B / {rep_size} B) p{p}",
                percentile(base, p) * 1e6,
            )
        )
    if pinned:  # context: the same, wherever the scheduler puts the threads
        rtt, base = _herej_rtt(req, rep_size)
        results.append(
            result(
                "Herej round trip p50, in process (RobotClient.herej; unpinned, context)",
                percentile(rtt, 50) * 1e6,
                "us",
                f"bare TCP echo ({len(req)} B / {rep_size} B) p50",
                percentile(base, 50) * 1e6,
            )
        )
    with FramedServer(RobotService(RobotEmulator()), "127.0.0.1", 0) as srv:
        echo_rate = _echo_throughput(req, rep_size)
        for n in (1, 8, 32):
            rate = _throughput(srv.address, n)
            results.append(
                result(
                    f"Herej requests/s, {n} clients, in process (RobotClient.herej)",
                    rate,
                    "req/s",
                    "bare TCP echo, 1 client",
                    echo_rate,
                )
            )
    # Trajectory generator cost per cycle.
    model = get_model()
    q0 = np.array([0.0, 10.0, 90.0, 0.0, 30.0, 0.0])
    target = np.array([60.0, -20.0, 60.0, 30.0, 60.0, 90.0])
    desc = MotionDesc(joint_speed=20.0)
    T1 = model.flange2base(q0).copy()
    T1[:3, 3] += [150.0, -100.0, -50.0]
    fk_cost = time_per_call(lambda: model.flange2base(q0))
    for kind in ("joint", "linear"):
        gen = TrajectoryGenerator(q0)
        move = (
            plan_joint(1, model, q0, target, desc)
            if kind == "joint"
            else plan_linear(1, model, q0, T1, np.eye(4), desc)
        )
        gen.enqueue(move)
        k, n = 0, 0
        t0 = time.perf_counter()
        while not gen.idle:
            k += 1
            gen.step(k)
            n += 1
        per = (time.perf_counter() - t0) / n
        results.append(
            result(
                f"trajectory {kind} move, cost per 4 ms cycle (TrajectoryGenerator.step)",
                per * 1e3,
                "ms",
                "one DGM flange2base call",
                fk_cost * 1e3,
            )
        )
    # Real-time tick jitter over 2 s.
    robot = RobotEmulator(clock="real").start()
    time.sleep(2.0)
    robot.close()
    j = robot.jitter()
    results.append(
        result(
            "4 ms tick lateness p99, real clock, idle (RobotEmulator)",
            j["p99"] * 1e3,
            "ms",
            "cycle period T_r",
            PERIOD * 1e3,
        )
    )
    results.append(
        result(
            "4 ms tick lateness p50, real clock, idle (RobotEmulator)",
            j["p50"] * 1e3,
            "ms",
            "cycle period T_r",
            PERIOD * 1e3,
        )
    )
    return results
