"""The rules a single frame or datagram breaks, as ``spec decode`` flags them, and the shipped
capture conforms."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from spec import vectorgen, wire
from spec.codec import Packet, encode_packet, error_packet, request
from spec.datagrams import SensorData, encode_data
from spec.dissect import broken_rules, datagram_rules, packet_rules
from spec.params import IntArray, Joints, Value
from spec.registry import BY_ID, CommandId
from spec.wire import PacketKind, SensorStatus

ROOT = Path(__file__).resolve().parents[1]


def hello_reply(version: str, service: str = "robot") -> Packet:
    spec = BY_ID[CommandId.HELLO]
    values: list[Value] = [version, service, "v", "m", "s", "1", IntArray((1,)), 1024, 1, 1.0, 1.0]
    assert len(values) == len(spec.reply)
    return Packet(PacketKind.REPLY, CommandId.HELLO, 1, tuple(values))


@pytest.mark.parametrize(
    ("packet", "expected"),
    [
        (hello_reply(wire.VERSION), []),
        (hello_reply("1.0"),
         [f"[RS-5.31] Hello version '1.0' differs from the frame header's {wire.VERSION}"]),
        (hello_reply(wire.VERSION, "camera"),
         ["[RS-5.31] Hello service 'camera' is not robot or sensor"]),
        (request(CommandId.HEREJ, 0), ["[RS-3.18] a request with request ID 0"]),
        (request(CommandId.JOINT_MOVE, 1, 5),
         ["[RS-5.4] JointMove request parameter 0 (joints) must be JOINTS, got INT"]),
        (Packet(PacketKind.REPLY, CommandId.HEREJ, 1, ()),
         ["[RS-5.5] Herej reply takes 1 parameters (joints:JOINTS), got 0"]),
        (Packet(PacketKind.REPLY, CommandId.HEREJ, 1, (Joints((1.0,)), 7)), []),  # [RS-5.6]
        (error_packet(0x1006, 1, 99, "x"), ["[RS-6.1] error code 99 is not in the table"]),
        (Packet(PacketKind.ERROR, 0x1006, 1, ("x",)),
         ["[RS-6.1] an error frame carries exactly (INT code, STRING message)"]),
        (Packet(PacketKind.EVENT, 0x8001, 0, (1,)), []),  # a vendor event: no table to break
    ],
)  # fmt: skip
def test_packet_rules(packet: Packet, expected: list[str]) -> None:
    assert packet_rules(packet) == expected


def test_datagram_rules() -> None:
    def data(
        status: SensorStatus, seam: tuple[float, ...], t: tuple[float, float, float]
    ) -> SensorData:
        return SensorData(1, status, seam, 1.0, 0.0, *t)  # type: ignore[arg-type]

    assert datagram_rules(data(SensorStatus.FOUND, (1.0,) * 6, (1.0, 2.0, 3.0))) == []
    assert datagram_rules(data(SensorStatus.NOT_FOUND, (float("nan"),) * 6, (1, 1, 1))) == []
    assert datagram_rules(data(SensorStatus.FOUND, (1.0,) * 6, (2.0, 1.0, 3.0))) == [
        "[SY-2.6] t_arrival <= t_exposure_start <= t_exposure_end does not hold"
    ]
    assert datagram_rules(data(SensorStatus.LASER_OFF, (1.0,) * 6, (1, 2, 3))) == [
        "[SY-2.7] status LASER_OFF with a location not all NaN or all zero"
    ]
    raw = encode_data(data(SensorStatus.FOUND, (1.0,) * 6, (2.0, 1.0, 3.0)))
    assert broken_rules(raw) == [
        "[SY-2.6] t_arrival <= t_exposure_start <= t_exposure_end does not hold"
    ]


def test_the_shipped_capture_conforms_and_is_what_vectorgen_makes() -> None:
    raw = vectorgen.CAPTURE_PATH.read_bytes()
    assert raw == vectorgen.capture(), "run: python -m spec vectors --generate --force"
    assert broken_rules(raw) == []


def test_decode_flags_a_broken_rule_with_exit_1() -> None:
    capture = encode_packet(request(CommandId.HELLO, 1, 1, 2, "c")) + encode_packet(
        hello_reply("1.0")
    )
    r = subprocess.run([sys.executable, "-m", "spec", "decode", capture.hex()], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 1, r.stderr
    assert "breaks           [RS-5.31] Hello version '1.0'" in r.stdout
    assert r.stderr == (f"spec decode: breaks 1 rule(s): frame 2: [RS-5.31] Hello version '1.0' "
                        f"differs from the frame header's {wire.VERSION}\n")  # fmt: skip
    r = subprocess.run([sys.executable, "-m", "spec", "decode", "spec/capture.bin"], cwd=ROOT,
                       capture_output=True, text=True, timeout=60)  # fmt: skip
    assert r.returncode == 0 and "breaks" not in r.stdout and r.stderr == ""
