"""SensorSocket over loopback: GetImage throughput against a bare TCP transfer of the same
bytes, trigger -> data round trip against a bare UDP echo, and loss at 250 Hz triggering."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np

from bench.common import Result, one_cpu, percentile, result, time_per_call
from sensorsocket.client import SensorClient
from sensorsocket.emulator import CameraEmulator
from sensorsocket.scene import fixed_pose
from sensorsocket.sensor import Reading, Sensor, make_scene
from sensorsocket.service import SensorService
from sensorsocket.timing import TimingModel
from sensorsocket.udp import TriggerHandler, TriggerListener
from spec.crc import crc32
from spec.datagrams import SensorData, Trigger, decode_datagram, encode_trigger
from spec.server import FramedServer
from spec.wire import SensorStatus

IMAGE_CALLS = 150  # per round; 5 rounds
RTT_SAMPLES = 1500
RATE_HZ = 250.0
RATE_SECONDS = 2.0


def _sensor(*, zero_time: bool) -> Sensor:
    scene = make_scene("butt", "straight")
    pose = fixed_pose(scene.sensor_over_seam(0.0, seam_y_mm=0.5))
    rng = np.random.default_rng(0)
    if zero_time:
        # Modelled acquisition and processing ~0: only the real work remains.
        timing = TimingModel(
            rng=rng,
            poll_rate_hz=1e12,
            start_jitter_s=0.0,
            full_frame_time_s=1e-12,
            processing_time_s=0.0,
        )
    else:
        timing = TimingModel(rng=rng)
    return Sensor(CameraEmulator(scene, pose, timing, rng=rng), clock=time.monotonic)


class _StubSensor:
    """Zero-cost sensor: isolates the trigger handler and listener from the emulator."""

    def __init__(self) -> None:
        eye = np.eye(4)
        self._frame = np.zeros((512, 256), np.uint8)
        self._points = np.zeros((0, 3))
        self._eye = eye

    def busy(self, t_arrival: float) -> bool:
        return False

    def acquire(
        self, t_arrival: float | None = None, *, index: int | None = None, t_trigger: float = 0.0
    ) -> Reading:
        t = 0.0 if t_arrival is None else t_arrival
        return Reading(
            index or 0, SensorStatus.FOUND, self._eye, (0.0,) * 6, 1.0, t_trigger,
            t, t, t, t, self._frame, self._points, self._eye,
        )  # fmt: skip


# --- GetImage throughput --------------------------------------------------------------------


def _get_image_throughput(address: tuple[str, int], *, frame_crc: bool) -> float:
    """MB/s of sequential GetImage calls; ``frame_crc=False`` turns the frame CRC off on the
    connection (SetFrameCrc, PROTOCOL.md 3.1)."""
    with SensorClient(*address, timeout=10.0, frame_crc=frame_crc) as client:
        if client.frame_crc_active != frame_crc:
            raise RuntimeError("the server did not apply SetFrameCrc")
        for _ in range(10):
            client.get_image_raw()
        t0 = time.perf_counter()
        for _ in range(IMAGE_CALLS):
            _, image = client.get_image_raw()
        dt = time.perf_counter() - t0
    return IMAGE_CALLS * len(image.data) / dt / 1e6


def _bare_tcp_throughput(size: int, *, crc: bool = False) -> float:
    """Request one byte, receive ``size`` bytes: the same exchange without the protocol.
    ``crc``: add the CRC-32 both ends of a framed exchange must compute, by the implementation
    the codec uses (context figure)."""
    payload = bytes(size)
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(10.0)

    def serve() -> None:
        conn, _ = listener.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(10.0)
        with conn:
            while conn.recv(1):
                if crc:
                    crc32(payload)
                conn.sendall(payload)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    sock = socket.create_connection(listener.getsockname(), timeout=10.0)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    buf = bytearray(size)
    view = memoryview(buf)

    def once() -> None:
        sock.sendall(b"x")
        got = 0
        while got < size:
            n = sock.recv_into(view[got:], size - got)
            if not n:
                raise ConnectionError("bare server closed")
            got += n
        if crc:
            crc32(buf)

    try:
        for _ in range(10):
            once()
        t0 = time.perf_counter()
        for _ in range(IMAGE_CALLS):
            once()
        dt = time.perf_counter() - t0
    finally:
        sock.close()
        thread.join(5)
        listener.close()
    return IMAGE_CALLS * size / dt / 1e6


# --- UDP round trip -------------------------------------------------------------------------


def _rtt(target: tuple[str, int], samples: int) -> list[float]:
    """Round trip (s) of sequential triggers to ``target``."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(2.0)
    out: list[float] = []
    try:
        for i in range(samples + 20):
            data = encode_trigger(Trigger(i, float(i)))
            t0 = time.perf_counter()
            sock.sendto(data, target)
            sock.recvfrom(2048)
            if i >= 20:
                out.append(time.perf_counter() - t0)
    finally:
        sock.close()
    return out


def _echo_server() -> tuple[tuple[str, int], threading.Event, threading.Thread]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.2)
    stop = threading.Event()

    def run() -> None:
        with sock:
            while not stop.is_set():
                try:
                    data, src = sock.recvfrom(2048)
                except TimeoutError:
                    continue
                sock.sendto(data, src)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return sock.getsockname(), stop, thread


def _listener_rtt(sensor: Sensor | _StubSensor, samples: int) -> list[float]:
    listener = TriggerListener(
        TriggerHandler(sensor), "127.0.0.1", 0, clock=time.monotonic, hold=True
    )
    with listener:
        return _rtt(listener.address, samples)


def _process_cost() -> tuple[float, float]:
    """CPU time (s) of one ``TriggerHandler.process`` with the zero-cost sensor, and of that
    sensor's ``acquire`` alone in the same loop: the handler's own work is the difference."""
    stub = _StubSensor()
    handler = TriggerHandler(stub)
    datagrams = [encode_trigger(Trigger(i, float(i))) for i in range(1 << 16)]
    count = 0

    def process_one() -> None:
        nonlocal count
        count += 1  # a fresh index every call; a fresh source after each lap of the list
        handler.process(datagrams[count & 0xFFFF], 1.0, count >> 16)

    def acquire_one() -> None:
        nonlocal count
        count += 1
        stub.acquire(1.0, index=count & 0xFFFF, t_trigger=1.0)

    return time_per_call(process_one), time_per_call(acquire_one)


def _bare_echo_rtt(samples: int) -> list[float]:
    address, stop, thread = _echo_server()
    try:
        return _rtt(address, samples)
    finally:
        stop.set()
        thread.join(2)


# --- 250 Hz ---------------------------------------------------------------------------------


def _rate(target: tuple[str, int]) -> tuple[int, int, int]:
    """(sent, distinct replies, OVERRUN replies) for triggers at RATE_HZ on deadlines."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    got: dict[int, int] = {}
    done = threading.Event()

    def receive() -> None:
        sock.settimeout(0.05)
        while True:
            try:
                raw, _ = sock.recvfrom(2048)
            except TimeoutError:
                if done.is_set():
                    return
                continue
            d = decode_datagram(raw)
            if isinstance(d, SensorData):
                got[d.index] = int(d.status)
            else:  # the bare echo returns the trigger itself
                got[d.index] = int(SensorStatus.FOUND)

    receiver = threading.Thread(target=receive, daemon=True)
    receiver.start()
    n = int(RATE_HZ * RATE_SECONDS)
    period = 1.0 / RATE_HZ
    wait = threading.Event()
    start = time.monotonic() + 0.05
    try:
        for i in range(n):
            delay = start + i * period - time.monotonic()
            if delay > 0:
                wait.wait(delay)  # deadline-based: no drift from late wake-ups
            sock.sendto(encode_trigger(Trigger(i, time.monotonic())), target)
        time.sleep(0.3)  # let the last replies arrive
    finally:
        done.set()
        receiver.join(2)
        sock.close()
    overruns = sum(1 for s in got.values() if s == int(SensorStatus.OVERRUN))
    return n, len(got), overruns


def run() -> list[Result]:
    results: list[Result] = []
    size = 512 * 256
    sensor = _sensor(zero_time=False)
    sensor.acquire()
    server = FramedServer(SensorService(sensor), "127.0.0.1", 0).start()
    # Interleaved rounds, medians: a busy moment of the machine hits every variant alike.
    rounds: dict[str, list[float]] = {"crc": [], "no_crc": [], "bare": [], "bare_crc": []}
    try:
        for _ in range(5):
            rounds["bare"].append(_bare_tcp_throughput(size + 64))
            rounds["crc"].append(_get_image_throughput(server.address, frame_crc=True))
            rounds["no_crc"].append(_get_image_throughput(server.address, frame_crc=False))
            rounds["bare_crc"].append(_bare_tcp_throughput(size + 64, crc=True))
    finally:
        server.shutdown()
    ours, no_crc, bare, bare_crc = (
        percentile(rounds[k], 50) for k in ("crc", "no_crc", "bare", "bare_crc")
    )
    name = "GetImage 512x256 MONO8 throughput, in process, loopback (SensorClient.get_image_raw)"
    results.append(result(name, ours, "MB/s", "bare TCP", bare))
    results.append(result(name, ours, "MB/s", "bare TCP + CRC-32 at both ends", bare_crc))
    results.append(result(f"{name}, frame CRC off", no_crc, "MB/s", "bare TCP", bare))

    # Alternate the two in rounds so a busy moment of the machine hits both alike.
    echo: list[float] = []
    stub: list[float] = []
    with one_cpu() as pinned:
        for _ in range(3):
            echo += _bare_echo_rtt(RTT_SAMPLES // 3)
            stub += _listener_rtt(_StubSensor(), RTT_SAMPLES // 3)
        full = _listener_rtt(_sensor(zero_time=True), RTT_SAMPLES // 3)
    where = "sender and listener on one CPU" if pinned else "unpinned"
    echo_p50, echo_p99 = percentile(echo, 50) * 1e6, percentile(echo, 99) * 1e6
    for name, samples in (
        (f"trigger->data RTT, listener + handler (zero-cost sensor, {where})", stub),
        (f"trigger->data RTT, full emulator (render + detect), acquisition time 0, {where}", full),
    ):
        results.append(
            result(f"{name}, p50", percentile(samples, 50) * 1e6, "us", "bare UDP echo", echo_p50)
        )
        results.append(
            result(f"{name}, p99", percentile(samples, 99) * 1e6, "us", "bare UDP echo", echo_p99)
        )

    if pinned:  # context: the same, wherever the scheduler puts the threads
        echo_free = _bare_echo_rtt(RTT_SAMPLES // 3)
        stub_free = _listener_rtt(_StubSensor(), RTT_SAMPLES // 3)
        results.append(
            result(
                "trigger->data RTT, listener + handler (zero-cost sensor, unpinned, context), p50",
                percentile(stub_free, 50) * 1e6,
                "us",
                "bare UDP echo",
                percentile(echo_free, 50) * 1e6,
            )
        )

    process_s, acquire_s = _process_cost()
    results.append(
        result(
            "TriggerHandler.process per trigger, zero-cost sensor (CPU, breakdown)",
            process_s * 1e6, "us", "the zero-cost sensor's acquire alone", acquire_s * 1e6,
        )
    )  # fmt: skip

    sensor = _sensor(zero_time=False)
    listener = TriggerListener(TriggerHandler(sensor), "127.0.0.1", 0, clock=time.monotonic)
    with listener:
        sent, received, overruns = _rate(listener.address)
    address, stop, thread = _echo_server()
    try:
        echo_sent, echo_received, _ = _rate(address)
    finally:
        stop.set()
        thread.join(2)
    loss, echo_loss = sent - received, echo_sent - echo_received
    results.append(
        result(
            f"250 Hz triggers for {RATE_SECONDS:g} s, full emulator: data datagrams received",
            received, "datagrams", "triggers sent", sent,
        )
    )  # fmt: skip
    results.append(result("250 Hz: lost (no reply)", loss, "datagrams", "triggers sent", sent))
    results.append(result("250 Hz, bare UDP echo: lost", echo_loss, "datagrams", "sent", echo_sent))
    results.append(result("250 Hz: OVERRUN replies", overruns, "datagrams", "triggers sent", sent))
    return results


if __name__ == "__main__":
    for r in run():
        print(r)
