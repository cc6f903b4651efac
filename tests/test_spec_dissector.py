"""The Wireshark dissector: generated from the registry (drift test), and run by Debian's tshark
over pcapng files built from the registry and the vectors and recorded from our servers.

``make test`` installs tshark when it runs as root (as it does chromium); without it the
tshark tests are skipped with a loud line.
"""

from __future__ import annotations

import ipaddress
import os
import shutil
import subprocess
from collections.abc import Iterable
from ipaddress import IPv4Address, IPv6Address
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from robotsocket.client import RobotClient
from robotsocket.emulator import RobotEmulator
from robotsocket.service import RobotService
from sensorsocket.client import SensorClient
from sensorsocket.service import SensorService
from spec import dissector, wire
from spec.codec import Packet, encode_packet, error_packet
from spec.datagrams import SensorData, Trigger, encode_data, encode_trigger
from spec.errors import ErrorCode
from spec.params import (
    FloatArray,
    Image,
    IntArray,
    Joints,
    Location,
    Matrix,
    Transform,
    Value,
)
from spec.pcapng import PcapngWriter, TcpFlow, udp_datagram
from spec.record import SessionRecorder
from spec.registry import COMMANDS, ParamSpec
from spec.vectorgen import load
from tests.test_sensor_service import make_sensor

if TYPE_CHECKING:
    from tests.conftest import Serve
from spec.wire import PacketKind, ParamType, PixelFormat, SensorStatus

TSHARK = shutil.which("tshark")
LUA = str(dissector.LUA_PATH)
CLIENT = (ipaddress.ip_address("10.1.1.1"), 41000)
IpAddress = IPv4Address | IPv6Address
ROBOT = (ipaddress.ip_address("10.1.1.2"), 4000)
SENSOR = (ipaddress.ip_address("10.1.1.3"), 2000)

needs_tshark = pytest.mark.skipif(
    TSHARK is None,
    reason="TSHARK TESTS SKIPPED: tshark not installed (apt-get install tshark; make test does)",
)


def test_the_lua_file_is_what_the_registry_generates() -> None:
    assert not dissector.differences(), "run: python -m spec dissector --write"
    text = dissector.LUA_PATH.read_text()
    for c in COMMANDS:  # every command of the registry, whoever added it
        assert f'[0x{int(c.id):04x}] = {{ name = "{c.name}"' in text
    for code in ErrorCode:
        assert f'[{int(code)}] = "{code.name}"' in text


if TSHARK is None:
    print("\nTSHARK TESTS WILL BE SKIPPED: tshark is not installed (apt-get install tshark)")


def tshark(
    path: Path, *fields: str, two_pass: bool = True, display: str = "rsock"
) -> list[list[str]]:
    """One row per packet matching ``display``: the values of ``fields`` (tab-separated in
    tshark's output, several occurrences of a field joined by commas)."""
    assert TSHARK is not None
    cmd = [TSHARK, "-n", "-X", f"lua_script:{LUA}", "-r", str(path), "-T", "fields"]
    cmd += ["-2"] if two_pass else []
    cmd += ["-Y", display, "-E", "occurrence=a", "-E", "aggregator=|"]
    for field in fields:
        cmd += ["-e", field]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Lua" not in r.stderr, r.stderr
    return [line.split("\t") for line in r.stdout.splitlines()]


def write_capture(
    path: Path, chunks: Iterable[tuple[bool, bytes]], server: tuple[IpAddress, int] = ROBOT
) -> Path:
    """A pcapng of one TCP connection: each chunk one write, from the client or the server."""
    with PcapngWriter(path, "test") as w:
        flow = TcpFlow(CLIENT, server)
        w.write_all(flow.handshake(), 10**18)
        for i, (from_client, data) in enumerate(chunks):
            w.write_all(flow.data(from_client, data), 10**18 + (i + 1) * 1000)
    return path


def sample(spec: ParamSpec) -> Value:
    """A value of the parameter's type."""
    t = spec.type
    samples: dict[ParamType, Value] = {
        ParamType.INT: -7,
        ParamType.FLOAT: 1.5,
        ParamType.BOOL: True,
        ParamType.STRING: "sé",
        ParamType.BYTES: b"\x00\xff",
        ParamType.FLOAT_ARRAY: FloatArray((0.25, 0.5)),
        ParamType.INT_ARRAY: IntArray((1, 2, 3)),
        ParamType.JOINTS: Joints((1.0, 2.0, 3.0, 4.0, 5.0, 6.0)),
        ParamType.LOCATION: Location(1.0, 2.0, 3.0, 4.0, 5.0, 6.0),
        ParamType.TRANSFORM: Transform(),
        ParamType.MATRIX: Matrix(2, 2, (1.0, 2.0, 3.0, 4.0)),
        ParamType.IMAGE: Image(4, 2, bytes(range(8))),
    }
    return samples[t]


@needs_tshark
def test_every_command_of_the_registry_is_decoded_with_its_names(tmp_path: Path) -> None:
    chunks = []
    for i, c in enumerate(COMMANDS, start=1):
        params = tuple(sample(p) for p in c.params)
        reply = tuple(sample(p) for p in c.reply)
        if c.name == "Hello":  # its rule [RS-5.31]: tested below
            reply = (wire.VERSION, "robot", *reply[2:])
        chunks.append((True, encode_packet(Packet(PacketKind.REQUEST, c.id, i, params))))
        chunks.append((False, encode_packet(Packet(PacketKind.REPLY, c.id, i, reply))))
    path = write_capture(tmp_path / "commands.pcapng", chunks)
    rows = tshark(path, "rsock.name", "rsock.kind", "rsock.request_id", "rsock.param.name",
                  "rsock.param.type", "rsock.crc.status", "_ws.expert.message",
                  "rsock.request_in", "rsock.response_in")  # fmt: skip
    assert len(rows) == 2 * len(COMMANDS)
    for i, c in enumerate(COMMANDS):
        for row, kind, specs in ((rows[2 * i], "1", c.params), (rows[2 * i + 1], "2", c.reply)):
            name, k, rid, names, types, crc, experts, _, _ = row
            assert (name, k, rid, crc) == (c.name, kind, str(i + 1), "1"), row
            assert names == "|".join(p.name for p in specs), row
            assert types == "|".join(f"0x{int(p.type):02x}" for p in specs), row
            assert experts == "", row  # sample values of the declared types break no rule
        # the request names its reply's packet and the reply its request's (two passes)
        assert rows[2 * i][8] and rows[2 * i + 1][7] and rows[2 * i][8] != rows[2 * i + 1][7]


@needs_tshark
def test_values_of_every_type(tmp_path: Path) -> None:
    params: tuple[Value, ...] = (
        -(2**62), 0.1, False, "naïve", b"\x01\x02", FloatArray((1e-300, -2.5)),
        IntArray((-1, 2**40)), Joints((10.0, -20.0, 90.0, 0.0, 45.0, 0.0)),
        Location(100.0, -5.0, 985.0, 0.0, 90.0, 180.0),
        Transform((1.0, 0, 0, 5, 0, 1, 0, 6, 0, 0, 1, 7, 0, 0, 0, 1)),
        Matrix(1, 3, (1.0, 2.0, 3.0)), Image(2, 2, bytes(8), format=PixelFormat(2)),
    )  # fmt: skip
    frame = encode_packet(Packet(PacketKind.EVENT, 0x8001, 0, params))
    (row,) = tshark(write_capture(tmp_path / "v.pcapng", [(False, frame)]),
                    "rsock.param.int", "rsock.param.float", "rsock.param.bool",
                    "rsock.param.string", "rsock.param.bytes", "rsock.param.int_element",
                    "rsock.param.element", "rsock.param.width", "rsock.param.format",
                    "_ws.expert.message")  # fmt: skip
    ints, floats, bools, strings, raw, int_elements, elements, width, fmt, experts = row
    assert ints == str(-(2**62)) and floats == "0.1" and bools == "0"
    assert strings == "naïve" and raw == "0102" and int_elements == f"-1|{2**40}"
    values = [float(v) for v in elements.split("|")]
    assert values[:2] == [1e-300, -2.5] and values[2:8] == [10.0, -20.0, 90.0, 0.0, 45.0, 0.0]
    assert values[8:14] == [100.0, -5.0, 985.0, 0.0, 90.0, 180.0]
    assert values[14:30] == [1.0, 0, 0, 5, 0, 1, 0, 6, 0, 0, 1, 7, 0, 0, 0, 1]
    assert values[30:] == [1.0, 2.0, 3.0]
    assert width == "2" and fmt == "2"
    assert experts == "Command not in the registry"  # a vendor event: a note, nothing worse


@needs_tshark
def test_getdata_status_is_named(tmp_path: Path) -> None:
    # [SS-5.13] "laser off" reads as such in a capture, not as a bare 2
    chunks = []
    for i, status in enumerate(SensorStatus, start=1):
        reply = (i, int(status), Location(0, 0, 0, 0, 0, 0), 0.0, 1.0, 1.0, 1.0)
        chunks.append((False, encode_packet(Packet(PacketKind.REPLY, 0x2002, i, reply))))
    rows = tshark(write_capture(tmp_path / "d.pcapng", chunks, SENSOR), "rsock.param.value")
    assert [r[0].split("|")[1] for r in rows] == [f"{int(s)} ({s.name})" for s in SensorStatus]


@needs_tshark
def test_every_error_code(tmp_path: Path) -> None:
    chunks = [(False, encode_packet(error_packet(0x1006, int(c), c, f"m{int(c)}")))
              for c in ErrorCode]  # fmt: skip
    rows = tshark(write_capture(tmp_path / "e.pcapng", chunks), "rsock.error.code",
                  "rsock.error.message", "_ws.col.Info")  # fmt: skip
    assert [r[0] for r in rows] == [str(int(c)) for c in ErrorCode]
    assert [r[1] for r in rows] == [f"m{int(c)}" for c in ErrorCode]
    assert [r[2] for r in rows] == [f"Error JointMove id={int(c)} {c.name}" for c in ErrorCode]


@needs_tshark
def test_every_datagram_kind_and_status(tmp_path: Path) -> None:
    path = tmp_path / "udp.pcapng"
    sensor_udp = (SENSOR[0], 2001)
    robot_udp = (ROBOT[0], 50123)
    with PcapngWriter(path, "udp") as w:
        for i, status in enumerate(SensorStatus):
            t = 100.0 + i
            w.write(udp_datagram(robot_udp, sensor_udp, encode_trigger(Trigger(i, t))), 10**18 + i)
            seam = (1.0, 2.0, 3.0, 0.0, 0.0, 0.0) if status is SensorStatus.FOUND else (0.0,) * 6
            data = SensorData(i, status, seam, 0.9, t, 5.0, 5.001, 5.002)
            w.write(udp_datagram(sensor_udp, robot_udp, encode_data(data)), 10**18 + i + 500_000)
    rows = tshark(path, "rssync.kind", "rssync.index", "rssync.t_trigger", "rssync.status",
                  "rssync.seam.y", "rssync.crc.status", "rssync.trigger_in", "rssync.delay",
                  "_ws.expert.message", display="rssync")  # fmt: skip
    assert len(rows) == 2 * len(SensorStatus)
    for i, status in enumerate(SensorStatus):
        trigger, reply = rows[2 * i], rows[2 * i + 1]
        assert trigger[:2] == ["1", str(i)] and float(trigger[2]) == 100.0 + i
        assert trigger[5] == "1"
        assert reply[:2] == ["2", str(i)] and float(reply[2]) == 100.0 + i
        assert reply[3] == str(int(status)) and reply[5] == "1"
        assert reply[4] == ("2" if status is SensorStatus.FOUND else "0")
        assert reply[6] == str(2 * i + 1)  # the trigger's packet number
        assert reply[7] == "0.000500000" and reply[8] == ""


@needs_tshark
def test_a_frame_split_across_segments_and_frames_sharing_one(tmp_path: Path) -> None:
    ping = encode_packet(Packet(PacketKind.REQUEST, 0x0002, 1, (b"x" * 300,)))
    herej = encode_packet(Packet(PacketKind.REQUEST, 0x1002, 2))
    status = encode_packet(Packet(PacketKind.REQUEST, 0x1001, 3))
    chunks = [(True, ping[:5]), (True, ping[5:100]), (True, ping[100:] + herej + status[:3]),
              (True, status[3:])]  # fmt: skip
    rows = tshark(write_capture(tmp_path / "split.pcapng", chunks), "frame.number",
                  "rsock.name", "rsock.crc.status", "rsock.param.count")  # fmt: skip
    # the Ping is shown where its last byte came, with the Herej that followed in that segment
    assert rows == [["6", "Ping|Herej", "1|1", "300"], ["7", "GetStatus", "1", ""]]
    # each frame has its own CRC and its own place in the Info column, whichever call shows it
    info = tshark(tmp_path / "split.pcapng", "_ws.col.Info")
    assert "Ping" in info[0][0] and "Herej" in info[0][0], info


@needs_tshark
def test_bad_crc_and_a_garbage_stream(tmp_path: Path) -> None:
    good = encode_packet(Packet(PacketKind.REQUEST, 0x1002, 1))
    bad = bytearray(encode_packet(Packet(PacketKind.REQUEST, 0x1002, 2)))
    bad[-1] ^= 0xFF
    chunks = [(True, good), (True, bytes(bad)), (True, b"GET / HTTP/1.1\r\n\r\n")]
    rows = tshark(write_capture(tmp_path / "bad.pcapng", chunks), "rsock.crc.status",
                  "_ws.expert.message", "rsock.garbage", "_ws.col.Info")  # fmt: skip
    assert rows[0] == ["1", "Request without a reply in the capture", "", "Request Herej id=1"]
    assert rows[1][0] == "0" and "CRC-32 mismatch" in rows[1][1] and "[RS-3.6]" in rows[1][1]
    assert rows[1][3] == "Request Herej id=2 [bad CRC]"
    assert rows[2][0] == "" and "bad magic 0x4745" in rows[2][1] and "[RS-3.8]" in rows[2][1]
    assert rows[2][2] == b"GET / HTTP/1.1\r\n\r\n".hex() and rows[2][3] == "[garbage]"


@needs_tshark
def test_the_vectors_valid_ones_clean_invalid_ones_flagged(tmp_path: Path) -> None:
    vectors = load("frames.json")
    for v in vectors:
        path = write_capture(tmp_path / f"{v['name']}.pcapng", [(True, bytes.fromhex(v["hex"]))])
        rows = tshark(path, "rsock.crc.status", "_ws.expert.message", "_ws.expert.severity",
                      two_pass=False)  # fmt: skip
        if v["valid"]:
            assert len(rows) == 1, v["name"]
            crc, messages, severities = rows[0]
            assert crc in ("1", "2"), v["name"]  # good, or a NO_CRC frame not checked
            assert "8388608" not in severities.split("|"), (v["name"], messages)  # no error
            continue
        error = v["error"]
        if error == "INCOMPLETE":
            assert rows == [], v["name"]  # waiting for the rest of the frame
            continue
        assert len(rows) == 1, v["name"]
        crc, messages, _ = rows[0]
        if error == "BAD_CRC":
            assert crc == "0", v["name"]
        else:
            expected = {
                "BAD_PARAMETERS": "[RS-4.",
                "UNSUPPORTED_VERSION": "[RS-3.11]",
                "FRAME_TOO_LARGE": "[RS-3.5]",
                "BAD_FRAME": "[RS-3.",
            }[error]
            assert expected in messages, (v["name"], messages)


@needs_tshark
def test_hello_whose_version_is_not_its_headers_is_flagged(tmp_path: Path) -> None:
    hello = next(c for c in COMMANDS if c.name == "Hello")
    reply = [sample(p) for p in hello.reply]
    reply[0], reply[1] = "1.0", "robot"
    frame = encode_packet(Packet(PacketKind.REPLY, hello.id, 1, tuple(reply)))
    rows = tshark(write_capture(tmp_path / "h.pcapng", [(False, frame)]), "_ws.expert.message")
    assert rows == [['Hello version "1.0" differs from the frame header\'s 1.3 [RS-5.31]']]


@needs_tshark
def test_a_recorded_robot_and_sensor_session(serve: Serve, tmp_path: Path) -> None:
    robot_server = serve(RobotService(RobotEmulator()), None)
    sensor_server = serve(SensorService(make_sensor(), trigger_endpoint=("127.0.0.1", 2001)), None)
    path = tmp_path / "session.pcapng"
    recorder = SessionRecorder(path, "robot and sensor", "test")
    try:
        with RobotClient(*robot_server.address, record=recorder) as robot:
            robot.hello()
            robot.take_control()
            robot.enable_power()
            robot.joint_move((10.0, 0.0, 90.0, 0.0, 0.0, 0.0))
            robot.wait_end_move(30)
            robot.herej()
        with SensorClient(*sensor_server.address, record=recorder) as sensor:
            sensor.hello()
            sensor.take_control()
            sensor.acquire()
            _, image = sensor.get_image()
    finally:
        recorder.close()
    rows = tshark(path, "_ws.col.Protocol", "rsock.name", "rsock.kind", "rsock.param.width",
                  "rsock.crc.status", "rsock.time", "tcp.stream")  # fmt: skip
    protocols = {r[6]: r[0] for r in rows}
    assert protocols == {"0": "RobotSocket", "1": "SensorSocket"}
    names = [r[1] for r in rows]
    assert names[:4] == ["Hello", "Hello", "TakeControl", "TakeControl"]
    assert "JointMove" in names and "WaitEndMove" in names and names[-1] == "GetImage"
    assert all(r[4] == "1" for r in rows)
    # the 128 KiB image came in several segments and is one frame in the last of them
    assert rows[-1][2] == "2" and rows[-1][3] == str(image.shape[1])
    assert all(float(r[5]) >= 0 for r in rows if r[2] == "2")
    assert os.path.getsize(path) > 128 * 1024
