"""SensorSocket over real loopback sockets: every command, its errors, image integrity, seam
accuracy, control rules, and robustness of the server against bad clients."""

from __future__ import annotations

import math
import random
import socket
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from sensorsocket.client import SensorClient
from sensorsocket.emulator import CameraEmulator
from sensorsocket.scene import fixed_pose
from sensorsocket.sensor import Sensor, SimClock, make_scene
from sensorsocket.service import SensorService
from sensorsocket.timing import TimingModel
from spec.codec import FrameDecoder, Packet, Rejected, decode_packet, encode_packet, request
from spec.errors import ErrorCode, PeerError, RemoteError
from spec.fuzz import mutate
from spec.registry import CommandId, commands_for
from spec.server import FramedServer, ServerPolicy
from spec.wire import PacketKind, PixelOrder, SensorStatus

SEAM_Y, SEAM_Z = 1.2, 0.5  # mm: where the seam lies in the sensor frame (truth)
TIMEOUT = 5.0


def make_sensor(seed: int = 3, clock: SimClock | None = None, *, keep_truth: bool = True) -> Sensor:
    scene = make_scene("butt", "straight")
    pose = fixed_pose(scene.sensor_over_seam(0.0, seam_y_mm=SEAM_Y, seam_z_mm=SEAM_Z))
    rng = np.random.default_rng(seed)
    emulator = CameraEmulator(scene, pose, TimingModel(rng=rng), rng=rng)
    return Sensor(emulator, clock=clock or SimClock(10.0), keep_truth=keep_truth)


def test_truth_is_opt_in_and_does_not_change_the_measurement() -> None:
    with_truth, without = make_sensor(keep_truth=True), make_sensor(keep_truth=False)
    for t in (10.0, 10.004, 10.008):
        a, b = with_truth.acquire(t), without.acquire(t)
        assert b.truth_seam2sensor is None and a.truth_seam2sensor is not None
        np.testing.assert_allclose(a.truth_seam2sensor[:3, 3], [0.0, SEAM_Y, SEAM_Z], atol=1e-9)
        assert np.array_equal(a.frame, b.frame) and a.seam == b.seam and a.status is b.status


class Rig:
    def __init__(self, policy: ServerPolicy | None = None) -> None:
        self.sensor = make_sensor()
        self.service = SensorService(self.sensor, trigger_endpoint=("127.0.0.1", 2001))
        self.server = FramedServer(self.service, "127.0.0.1", 0, policy).start()
        self.host, self.port = self.server.address

    def client(self) -> SensorClient:
        return SensorClient(self.host, self.port, timeout=TIMEOUT)

    def raw(self) -> socket.socket:
        s = socket.create_connection((self.host, self.port), timeout=TIMEOUT)
        s.settimeout(TIMEOUT)
        return s

    def close(self) -> None:
        self.server.shutdown()
        errors = list(self.server.handler_errors)
        assert errors == [], errors  # nothing a client sent may crash a handler


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = Rig(ServerPolicy(frame_timeout=0.3))
    yield r
    r.close()


@pytest.fixture
def client(rig: Rig) -> Iterator[SensorClient]:
    c = rig.client()
    yield c
    c.close()


def code_of(exc: pytest.ExceptionInfo[RemoteError]) -> ErrorCode:
    return exc.value.code


# --- commands -------------------------------------------------------------------------------


def test_hello_lists_every_sensor_command(client: SensorClient) -> None:
    info = client.hello()
    assert info["service"] == "sensor"
    listed = set(info["commands"].values)  # type: ignore[union-attr]
    assert {int(c.id) for c in commands_for("sensor")} <= listed
    assert int(CommandId.HEREJ) not in listed


def test_no_data_before_the_first_measurement(client: SensorClient) -> None:
    # [SS-5.2]
    for fn in (client.get_data, client.get_image, client.get_profile):
        with pytest.raises(RemoteError) as exc:
            fn()
        assert code_of(exc) is ErrorCode.NO_DATA
    assert client.status().last_index == -1


@pytest.mark.parametrize(
    ("command", "params"),
    [
        (CommandId.SET_LASER, (False,)),
        (CommandId.SET_EXPOSURE, (1e-4,)),
        (CommandId.SET_READOUT_WINDOW, (0, 256)),
        (CommandId.ACQUIRE, ()),
    ],
)
def test_settings_need_control(
    client: SensorClient, command: CommandId, params: tuple[object, ...]
) -> None:
    with pytest.raises(RemoteError) as exc:
        client.call(command, *params)  # type: ignore[arg-type]
    assert code_of(exc) is ErrorCode.NOT_IN_CONTROL


def test_control_is_held_by_one_client(rig: Rig, client: SensorClient) -> None:
    client.take_control()
    with rig.client() as other:
        with pytest.raises(RemoteError) as exc:
            other.take_control()
        assert code_of(exc) is ErrorCode.BUSY
        assert other.status().controlled and not other.status().in_control
        with pytest.raises(RemoteError) as exc:
            other.call(CommandId.ACQUIRE)
        assert code_of(exc) is ErrorCode.NOT_IN_CONTROL
    assert client.status().in_control


def test_acquire_then_get_data_matches_the_scene(rig: Rig, client: SensorClient) -> None:
    client.take_control()
    index = client.acquire()
    data = client.get_data()
    reading = rig.sensor.latest
    assert reading is not None and data.index == index == reading.index
    assert data.status is SensorStatus.FOUND and data.seam is not None
    assert 0.5 < data.quality <= 1.0
    # truth: the seam was placed at (0, 1.2, 0.5) mm in S; the detector's accuracy is a few
    # tens of micrometres on a clean butt joint.
    x, y, z, rx, ry, rz = data.seam
    assert abs(x) < 1e-9 and abs(y - SEAM_Y) < 0.03 and abs(z - SEAM_Z) < 0.03
    assert abs(rx) < 1.0 and abs(ry) < 1e-6 and abs(rz) < 1e-6
    assert reading.truth_seam2sensor is not None
    truth = reading.truth_seam2sensor[:3, 3]
    assert np.allclose(truth, [0.0, SEAM_Y, SEAM_Z], atol=1e-9)
    # [SS-5.5] timestamps ordered; the exposure window is the acquisition time (3.5 ms)
    assert data.t_arrival <= data.t_exposure_start <= data.t_exposure_end
    assert data.t_exposure_end - data.t_exposure_start == pytest.approx(3.5e-3, rel=1e-9)
    assert data.t_arrival == pytest.approx(10.0)  # the simulated clock at the Acquire
    status = client.status()
    assert (status.frames, status.last_index, status.laser) == (1, index, True)
    assert client.acquire() == index + 1


def test_get_image_bytes_equal_the_rendered_frame(rig: Rig, client: SensorClient) -> None:
    client.take_control()
    for _ in range(2):
        index = client.acquire()
        reading = rig.sensor.latest
        assert reading is not None
        got_index, raw = client.get_image_raw()
        assert got_index == index == reading.index
        assert (raw.width, raw.height, raw.order) == (512, 256, PixelOrder.ROW_MAJOR)
        # [SS-5.3] row-major on the wire: the transpose of the (columns, rows) readout frame
        assert raw.data == np.ascontiguousarray(reading.frame.T).tobytes()
        # Sent again from the reply encoded once per reading; the whole region is that reply.
        assert client.get_image_raw() == (index, raw)
        assert client.get_image_raw((0, 0, 512, 256)) == (index, raw)
        _, image = client.get_image()
        assert image.shape == (256, 512) and np.array_equal(image, reading.frame.T)
        assert image.max() > 100  # the stripe is there
    assert reading is not None
    _, region = client.get_image((100, 20, 64, 32))
    assert np.array_equal(region, reading.frame.T[20:52, 100:164])
    _, corner = client.get_image((511, 255, 1, 1))
    assert corner.shape == (1, 1) and corner[0, 0] == reading.frame[511, 255]
    _, tail = client.get_image((500,))  # optional parameters: the rest of the sensor
    assert np.array_equal(tail, reading.frame.T[:, 500:])


@pytest.mark.parametrize(
    "region",
    [(512, 0, 1, 1), (0, 256, 1, 1), (-1, 0, 10, 10), (0, 0, 0, 10), (0, 0, 10, 0),
     (500, 0, 13, 10), (0, 250, 10, 7), (0, 0, 513, 256)],
)  # fmt: skip
def test_get_image_region_outside_is_out_of_range(
    client: SensorClient, region: tuple[int, int, int, int]
) -> None:
    client.take_control()
    client.acquire()
    with pytest.raises(RemoteError) as exc:
        client.get_image(region)
    assert code_of(exc) is ErrorCode.OUT_OF_RANGE  # [SS-5.4]


def test_get_profile_is_the_stripe_in_the_sensor_frame(rig: Rig, client: SensorClient) -> None:
    client.take_control()
    index = client.acquire()
    got, points = client.get_profile()
    reading = rig.sensor.latest
    assert reading is not None and got == index
    # [SS-5.9] N x 3 in mm, bit-exact with the detector's points
    assert points.shape == reading.points.shape and points.shape[1] == 3
    assert points.shape[0] > 300
    assert np.array_equal(points, reading.points)
    assert np.all(points[:, 0] == 0.0)  # the laser plane x_S = 0
    # plates are flat at the seam depth: every point within 0.1 mm of z = SEAM_Z
    assert np.all(np.abs(points[:, 2] - SEAM_Z) < 0.1)


def test_settings_change_the_acquisition_time(client: SensorClient) -> None:
    client.take_control()
    s = client.get_settings()
    assert (s.laser, s.first_column, s.columns, s.width, s.height) == (True, 0, 512, 512, 256)
    assert s.acquisition_time == pytest.approx(3.5e-3)
    # [SS-5.7] proportional to the columns read
    assert client.set_readout_window(128, 256) == pytest.approx(1.75e-3)
    assert client.set_readout_window(0, 64) == pytest.approx(3.5e-3 * 64 / 512)
    client.set_exposure(2e-5)
    s = client.get_settings()
    assert (s.first_column, s.columns, s.exposure) == (0, 64, 2e-5)
    assert s.acquisition_time == pytest.approx(3.5e-3 * 64 / 512)
    client.acquire()
    data = client.get_data()
    assert data.t_exposure_end - data.t_exposure_start == pytest.approx(63 * 3.5e-3 / 512 + 2e-5)


@pytest.mark.parametrize("window", [(-1, 100), (0, 0), (500, 13), (512, 1), (0, 513)])
def test_bad_readout_window_is_out_of_range(client: SensorClient, window: tuple[int, int]) -> None:
    client.take_control()
    with pytest.raises(RemoteError) as exc:
        client.set_readout_window(*window)
    assert code_of(exc) is ErrorCode.OUT_OF_RANGE  # [SS-5.6]
    assert client.get_settings().columns == 512  # unchanged


@pytest.mark.parametrize("exposure", [0.0, -1e-3, 5e-7, 0.0101, math.inf, math.nan])
def test_bad_exposure_is_out_of_range(client: SensorClient, exposure: float) -> None:
    client.take_control()
    with pytest.raises(RemoteError) as exc:
        client.set_exposure(exposure)
    assert code_of(exc) is ErrorCode.OUT_OF_RANGE  # [SS-5.6]


def test_laser_off_reports_no_seam(client: SensorClient) -> None:
    client.take_control()
    client.set_laser(False)
    assert client.get_settings().laser is False and client.status().laser is False
    client.acquire()
    data = client.get_data()
    # [SS-5.8] status LASER_OFF and no seam (six zeros on the wire, None in the client)
    assert data.status is SensorStatus.LASER_OFF and data.seam is None and data.quality == 0.0
    raw = client.call(CommandId.GET_DATA)
    assert raw[2].as_tuple() == (0.0,) * 6  # type: ignore[union-attr]
    _, image = client.get_image()
    assert image.max() < 60  # background only
    client.set_laser(True)
    client.acquire()
    assert client.get_data().found


@pytest.mark.parametrize(
    ("command", "params"),
    [
        (CommandId.GET_IMAGE, (1.0,)),
        (CommandId.GET_IMAGE, (0, 0, 10, 10, 5)),
        (CommandId.SET_LASER, ()),
        (CommandId.SET_LASER, (1,)),
        (CommandId.SET_EXPOSURE, (1,)),
        (CommandId.SET_READOUT_WINDOW, (0,)),
        (CommandId.GET_DATA, ("x",)),
    ],
)
def test_bad_parameters(client: SensorClient, command: CommandId, params: tuple[object]) -> None:
    client.take_control()
    with pytest.raises(RemoteError) as exc:
        client.call(command, *params)  # type: ignore[arg-type]
    assert code_of(exc) is ErrorCode.BAD_PARAMETERS


@pytest.mark.parametrize("command", [CommandId.HEREJ, CommandId.START_TRIGGERS, 0x2FFF, 0x7777])
def test_robot_and_unknown_commands_are_unknown(client: SensorClient, command: int) -> None:
    with pytest.raises(RemoteError) as exc:
        client.call(command)
    assert code_of(exc) is ErrorCode.UNKNOWN_COMMAND


def test_trigger_endpoint_and_time(client: SensorClient) -> None:
    assert client.get_trigger_endpoint() == ("127.0.0.1", 2001)
    assert client.get_time() == 10.0  # the service clock is the sensor's (simulated) clock


# --- robustness -----------------------------------------------------------------------------


def exchange(rig: Rig, data: bytes) -> list[Packet]:
    """Send ``data`` on a fresh connection, half-close, read every packet until the server
    closes."""
    s = rig.raw()
    try:
        try:
            s.sendall(data)
            s.shutdown(socket.SHUT_WR)
        except OSError:
            pass  # the server may close first after a fatal header error
        received = b""
        while True:
            try:
                chunk = s.recv(65536)
            except ConnectionResetError:
                break
            if not chunk:
                break
            received += chunk
    finally:
        s.close()
    decoder = FrameDecoder()
    decoder.feed(received)
    return [e for e in decoder.events() if isinstance(e, Packet)]


def expected_rejections(data: bytes, max_payload: int) -> int:
    """How many frames of ``data`` a request decoder rejects (offline truth)."""
    decoder = FrameDecoder(max_payload=max_payload, kinds=frozenset({PacketKind.REQUEST}))
    count = 0
    try:
        decoder.feed(data)
        for event in decoder.events():
            count += isinstance(event, Rejected)
    except PeerError:
        count += 1
    return count


def seeds() -> list[bytes]:
    return [
        encode_packet(request(CommandId.SENSOR_STATUS, 1)),
        encode_packet(request(CommandId.GET_DATA, 2)),
        encode_packet(request(CommandId.GET_IMAGE, 3, 0, 0, 16, 16)),
        encode_packet(request(CommandId.SET_READOUT_WINDOW, 4, 10, 100)),
        encode_packet(request(CommandId.PING, 5, b"abcdefgh")),
        encode_packet(request(CommandId.HELLO, 6, 1, 0, "fuzz")),
    ]


def alive(rig: Rig) -> None:
    with rig.client() as c:
        assert c.ping(b"still here") == b"still here"
        assert c.status().frames >= 0


def test_truncated_frames_are_dropped_without_harm(rig: Rig) -> None:
    frame = seeds()[2]
    before = rig.server.statistics()
    for cut in range(1, len(frame)):
        assert exchange(rig, frame[:cut]) == []  # no reply to half a frame, clean close
    after = rig.server.statistics()
    assert after["frames_in"] == before["frames_in"]
    assert after["rejected"] == before["rejected"]
    alive(rig)


def test_garbage_gets_bad_frame_and_is_counted(rig: Rig) -> None:
    before = rig.server.statistics()["rejected"]
    packets = exchange(rig, b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
    assert [p.kind for p in packets] == [PacketKind.ERROR]
    assert packets[0].error is not None and packets[0].error[0] == ErrorCode.BAD_FRAME
    assert rig.server.statistics()["rejected"] == before + 1
    alive(rig)


def test_mutated_frames_are_all_accounted_for(rig: Rig) -> None:
    rng = random.Random(2024)
    base = seeds()
    before = rig.server.statistics()
    expected = 0
    for _ in range(150):
        data = rng.choice(base)
        for _ in range(rng.randrange(1, 4)):
            data = mutate(data, rng)
        expected += expected_rejections(data, rig.server.policy.max_payload)
        for packet in exchange(rig, data):
            assert packet.kind in (PacketKind.REPLY, PacketKind.ERROR)
    stats = rig.server.statistics()
    assert stats["rejected"] - before["rejected"] == expected
    assert expected > 20  # the mutations did reach the checks
    assert stats["handler_errors"] == 0
    alive(rig)


def test_one_byte_then_silence_times_out(rig: Rig) -> None:
    before = rig.server.statistics()["timeouts"]
    s = rig.raw()
    try:
        s.sendall(b"R")  # a frame starts and never finishes (frame_timeout 0.3 s)
        data = b""
        while True:
            chunk = s.recv(4096)
            if not chunk:
                break
            data += chunk
    finally:
        s.close()
    packet = decode_packet(data)
    assert packet.kind is PacketKind.ERROR and packet.error is not None
    assert packet.error[0] == ErrorCode.TIMEOUT
    assert rig.server.statistics()["timeouts"] == before + 1
    alive(rig)


def test_many_clients_at_once(rig: Rig) -> None:
    with rig.client() as controller:
        controller.take_control()
        controller.acquire()
    reading = rig.sensor.latest
    assert reading is not None
    expected = reading.frame.T
    failures: list[str] = []

    def worker(k: int) -> None:
        try:
            with rig.client() as c:
                for _ in range(3):
                    index, image = c.get_image()
                    if index != reading.index or not np.array_equal(image, expected):
                        failures.append(f"client {k}: wrong image")
                    if c.get_data().index != reading.index:
                        failures.append(f"client {k}: wrong data")
        except Exception as exc:  # noqa: BLE001  collected, asserted below
            failures.append(f"client {k}: {exc!r}")

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(24)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert failures == []
    assert rig.server.statistics()["connections"] >= 25
    alive(rig)
