"""Round trips across processes against peer protocols (issue 20): Herej against a
pyModbusTCP server (read 12 holding registers, the same 48 bytes of payload), GetImage
512x256 MONO8 with the frame CRC on against a pyzmq REQ/REP of the same array. GetImage sends
the latest frame again (it is rendered by Acquire, not per call), as the peer sends its one
array: both figures measure the transfer.

Every server runs in its own process (ours: ``python -m robotsocket serve --clock sim`` and
``python -m sensorsocket serve``); the clients run here. Ours and the peer alternate in
rounds so that a busy moment of the machine hits both alike; figures are medians.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable

from bench.common import Result, percentile, result
from bench.peers import MODBUS_SERVER, ZMQ_REP_SERVER, free_port, peer, server_process
from robotsocket.client import RobotClient
from sensorsocket.client import SensorClient
from spec.crc import CRC32_IMPLEMENTATION

ROUNDS = 5
RTT_PER_ROUND = 300
CLIENT_COUNTS = (1, 8, 64)
THROUGHPUT_S = 0.6
IMAGE_CALLS = 100
FRAME_BYTES = 512 * 256


def _samples(fn: Callable[[], object], n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def _throughput(
    connect: Callable[[], tuple[Callable[[], object], Callable[[], None]]], n: int, what: str
) -> float:
    """Calls per second of ``n`` client threads, each with its own connection. A client whose
    call fails stops (its calls so far count); how many did is printed, not raised."""
    counts = [0] * n
    failed: list[str] = []
    stop = threading.Event()
    ready = threading.Barrier(n + 1)

    def worker(i: int) -> None:
        call, close = connect()
        try:
            ready.wait()
            while not stop.is_set():
                call()
                counts[i] += 1
        except Exception as exc:  # noqa: BLE001  a load thread's failure, reported by the run
            failed.append(str(exc))
        finally:
            close()

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    ready.wait()
    t0 = time.perf_counter()
    time.sleep(THROUGHPUT_S)
    stop.set()
    for t in threads:
        t.join()
    if failed:
        print(f"  {what}: {len(failed)} of {n} clients failed ({failed[0]})", file=sys.stderr)
    return sum(counts) / (time.perf_counter() - t0)


def _herej(results: list[Result]) -> None:
    mb = peer("pyModbusTCP.client", "Herej vs pyModbusTCP")
    if mb is None:
        return
    port = free_port()
    with (
        server_process(["-m", "robotsocket", "serve", "--clock", "sim", "--port", "0"]) as ours,
        server_process(["-c", MODBUS_SERVER, str(port)]) as theirs,
    ):

        def connect_ours() -> tuple[Callable[[], object], Callable[[], None]]:
            c = RobotClient(*ours)
            return c.herej, c.close

        def connect_modbus() -> tuple[Callable[[], object], Callable[[], None]]:
            c = mb.ModbusClient(host=theirs[0], port=theirs[1], auto_open=True, timeout=10.0)

            def call() -> object:
                regs = c.read_holding_registers(0, 12)
                if regs is None:
                    raise RuntimeError(f"pyModbusTCP: {c.last_error_as_txt}")
                return regs

            return call, c.close

        a_call, a_close = connect_ours()
        b_call, b_close = connect_modbus()
        rtt_a: list[float] = []
        rtt_b: list[float] = []
        try:
            _samples(a_call, 100)
            _samples(b_call, 100)
            for _ in range(ROUNDS):
                rtt_a += _samples(a_call, RTT_PER_ROUND)
                rtt_b += _samples(b_call, RTT_PER_ROUND)
        finally:
            a_close()
            b_close()
        for p in (50, 99):
            results.append(
                result(
                    f"robot herej round trip p{p}, client and server processes",
                    percentile(rtt_a, p) * 1e6,
                    "us",
                    f"pyModbusTCP read_holding_registers(0, 12) p{p}",
                    percentile(rtt_b, p) * 1e6,
                )
            )
        for n in CLIENT_COUNTS:
            ra: list[float] = []
            rb: list[float] = []
            for _ in range(2):
                ra.append(_throughput(connect_ours, n, "ours"))
                rb.append(_throughput(connect_modbus, n, "pyModbusTCP"))
            results.append(
                result(
                    f"robot herej throughput, {n} client(s), server process",
                    max(ra),
                    "calls/s",
                    f"pyModbusTCP read 12 registers, {n} client(s)",
                    max(rb),
                )
            )


def _get_image(results: list[Result]) -> None:
    zmq = peer("zmq", "GetImage vs pyzmq REQ/REP")
    if zmq is None:
        return
    with (
        server_process(["-m", "sensorsocket", "serve", "--port", "0", "--udp-port", "off"]) as ours,
        server_process(["-c", ZMQ_REP_SERVER, str(FRAME_BYTES)]) as theirs,
    ):
        ctx = zmq.Context()
        req = ctx.socket(zmq.REQ)
        req.connect(f"tcp://{theirs[0]}:{theirs[1]}")

        def zmq_call() -> object:
            req.send(b"get")
            return req.recv(copy=False)

        rates: dict[str, list[float]] = {"crc": [], "no_crc": [], "zmq": []}
        clients = {
            "crc": SensorClient(*ours, timeout=10.0, frame_crc=True),
            "no_crc": SensorClient(*ours, timeout=10.0, frame_crc=False),
        }
        try:
            # GetImage serves the latest frame: make one
            clients["crc"].take_control()
            clients["crc"].acquire()
            clients["crc"].release_control()
            for key, c in clients.items():
                if c.frame_crc_active != (key == "crc"):
                    raise RuntimeError("the server did not apply SetFrameCrc")
                _, image = c.get_image_raw()
                if len(image.data) != FRAME_BYTES:
                    raise RuntimeError(f"GetImage: {len(image.data)} bytes, not {FRAME_BYTES}")
                _samples(c.get_image_raw, 10)
            _samples(zmq_call, 10)
            for _ in range(ROUNDS):
                for key, c in clients.items():
                    rates[key].append(IMAGE_CALLS / sum(_samples(c.get_image_raw, IMAGE_CALLS)))
                rates["zmq"].append(IMAGE_CALLS / sum(_samples(zmq_call, IMAGE_CALLS)))
        finally:
            for c in clients.values():
                c.close()
            req.close(linger=0)
            ctx.term()
    crc, no_crc, base = (percentile(rates[k], 50) for k in ("crc", "no_crc", "zmq"))
    name = "GetImage 512x256 MONO8 (same frame re-sent), client and server processes"
    peer_name = "pyzmq REQ/REP of the same 128 KiB array"
    # Which CRC-32 checked the frames: zlib-ng (the `fast` extra) or the system zlib.
    on = f"frame CRC on ({CRC32_IMPLEMENTATION})"
    results.append(result(f"{name}, {on}", crc, "frames/s", peer_name, base))
    results.append(result(f"{name}, frame CRC off", no_crc, "frames/s", peer_name, base))


def run() -> list[Result]:
    results: list[Result] = []
    _herej(results)
    _get_image(results)
    return results
