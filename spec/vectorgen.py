"""Build the test vectors of ``spec/vectors/`` (maintainer tool, run once per protocol change).

``python -m spec vectors --generate`` refuses to overwrite existing files without ``--force``:
the vectors are the reference the codec is tested against, not a mirror of the current code.
Invalid frames are built by hand-editing valid ones and re-sealing the CRC where the error under
test is not the CRC itself.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from pathlib import Path
from typing import Any

from spec import wire
from spec.codec import Packet, encode_packet, error_packet, request
from spec.datagrams import SensorData, Trigger, encode_data, encode_trigger
from spec.errors import ErrorCode
from spec.files import write_atomically
from spec.jsonform import packet_to_json
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
from spec.registry import CommandId as C
from spec.wire import PacketKind, PixelFormat, PixelOrder, SensorStatus

VECTOR_DIR = Path(__file__).with_name("vectors")


def _reply(command: int, rid: int, *params: Value) -> Packet:
    return Packet(PacketKind.REPLY, command, rid, tuple(params))


def _seal(header_and_payload: bytes) -> bytes:
    return header_and_payload + struct.pack(">I", zlib.crc32(header_and_payload))


def _frame(payload: bytes, *, kind: int = 1, command: int = 0x1002, rid: int = 1,
           major: int = 1, minor: int = 0, flags: int = 0, length: int | None = None,
           magic: bytes = wire.MAGIC) -> bytes:  # fmt: skip
    n = len(payload) if length is None else length
    header = wire.HEADER.pack(magic, major, minor, kind, flags, command, rid, n)
    return _seal(header + payload)


def _params(count: int, body: bytes) -> bytes:
    return struct.pack(">H", count) + body


ROTATION = (0.0, -1.0, 0.0, 10.0, 1.0, 0.0, 0.0, -20.5, 0.0, 0.0, 1.0, 300.0, 0.0, 0.0, 0.0, 1.0)


def valid_frames() -> list[tuple[str, str, Packet]]:
    hello_reply = _reply(
        C.HELLO, 1, wire.VERSION, "robot", "reference", "RX90B", "0001", "0.1.0",
        IntArray([1, 2, 3, 4, 5, 0x1002]), 4194304, 64, 300.0, 5.0,
    )  # fmt: skip
    return [
        ("request-herej", "Herej request without parameters", request(C.HEREJ, 1)),
        ("reply-herej", "Herej reply with six joints", _reply(C.HEREJ, 1, Joints([10, -20, 90, 0, 45, 0]))),
        ("request-jointmove", "JointMove request", request(C.JOINT_MOVE, 2, Joints([0, 0, 90, 0, 90, 0]))),
        ("error-not-powered", "error packet NOT_POWERED", error_packet(C.JOINT_MOVE, 2, ErrorCode.NOT_POWERED, "arm power is off")),
        ("error-request-id-0", "error answering no request (BUSY)", error_packet(0, 0, ErrorCode.BUSY, "client limit reached")),
        ("error-frame-too-large", "the answer to length-over-max: command ID 0 and request ID 0, although the header was readable [RS-3.20]", error_packet(0, 0, ErrorCode.FRAME_TOO_LARGE, "payload length 16777217 is over the limit 16777216")),
        ("error-timeout-partial-header", "the answer to a frame stopped after 10 of its 16 header bytes: TIMEOUT with command ID 0 and request ID 0 [RS-3.20] [RS-7.5]", error_packet(0, 0, ErrorCode.TIMEOUT, "frame stopped after 10 bytes")),
        ("event-bool", "event packet with a BOOL", Packet(PacketKind.EVENT, C.ROBOT_STATUS, 0, (True,))),
        ("request-here", "Here(tool, frame) with two locations", request(C.HERE, 3, Location(0, 0, 120, 0, 0, 0), Location(500, 0, 0, 0, 0, 90))),
        ("reply-here", "Here reply", _reply(C.HERE, 3, Location(450.5, -12.25, 300, 180, 0, -90))),
        ("int-values", "INT extremes", _reply(0xC001, 4, 0, -1, 2**63 - 1, -(2**63))),
        ("float-values", "FLOAT: negative zero, tiny, huge, infinity", _reply(0xC001, 5, -0.0, 5e-324, 1.7976931348623157e308, math.inf)),
        ("float-nan", "FLOAT NaN is allowed", _reply(0xC001, 6, math.nan)),
        ("bool-values", "BOOL true and false", _reply(0xC001, 7, True, False)),
        ("string-empty", "empty STRING", request(C.TAKE_CONTROL, 8, "")),
        ("string-utf8", "UTF-8 STRING", _reply(0xC001, 9, "Stäubli ΔT ✓")),
        ("bytes-values", "BYTES empty and with content", _reply(C.PING, 10, b"", bytes(range(16)))),
        ("ping-request", "Ping with data", request(C.PING, 11, b"\x00\x01\xfe\xff")),
        ("float-array", "FLOAT_ARRAY empty and three values", request(C.SCHEDULE_TRIGGERS, 12, FloatArray([]), FloatArray([0.004, 0.008, 0.0125]))),
        ("int-array", "INT_ARRAY", _reply(0xC001, 13, IntArray([1, -2, 0x1002]))),
        ("joints-1", "JOINTS with one axis", _reply(0xC001, 14, Joints([12.5]))),
        ("joints-16", "JOINTS with sixteen axes", _reply(0xC001, 15, Joints(range(16)))),
        ("transform-identity", "TRANSFORM identity", _reply(0xC001, 16, Transform())),
        ("transform-rotation", "TRANSFORM with rotation and translation", _reply(0xC001, 17, Transform(ROTATION))),
        ("matrix-empty", "MATRIX 0x7", _reply(C.GET_JOINT_LOG, 18, Matrix(0, 7, []), 0.004)),
        ("matrix-2x3", "MATRIX 2x3", _reply(0xC001, 19, Matrix(2, 3, [1, 2, 3, 4, 5, 6]))),
        ("image-row-major", "IMAGE 4x2 MONO8 row-major", _reply(0xC001, 20, Image(4, 2, bytes(range(8))))),
        ("image-column-major", "IMAGE 4x2 MONO8 column-major", _reply(0xC001, 21, Image(4, 2, bytes(range(8, 16)), PixelFormat.MONO8, PixelOrder.COLUMN_MAJOR))),
        ("image-mono16", "IMAGE 2x2 MONO16", _reply(0xC001, 22, Image(2, 2, bytes([0, 1, 2, 3, 255, 254, 128, 0]), PixelFormat.MONO16))),
        ("hello-request", "Hello request", request(C.HELLO, 1, 1, 0, "client/1.0")),
        ("hello-reply", "Hello reply", hello_reply),
        ("minor-version-5", "a newer minor version is accepted", Packet(PacketKind.REQUEST, C.PING, 23, (b"x",), 5)),
        ("minor-version-2", "a 1.2 peer's frame (minor 2) is accepted by a 1.3 receiver [RS-1.2]", Packet(PacketKind.REQUEST, C.PING, 27, (b"1.2",), 2)),
        ("minor-version-0", "a 1.0 peer's frame (minor 0) is accepted [RS-1.2]", Packet(PacketKind.REQUEST, C.PING, 28, (b"1.0",), 0)),
        ("request-id-max", "largest request ID, experimental command", request(0xFFFE, 0xFFFFFFFF)),
        ("mixed-params", "every scalar type in one list", request(0x8001, 24, 7, 2.5, True, "s", b"b", Location(1, 2, 3, 4, 5, 6))),
        ("set-motion-desc", "SetMotionDesc with six FLOATs", request(C.SET_MOTION_DESC, 25, 10.0, 100.0, 100.0, 250.0, 90.0, 0.0)),
        ("request-alterqueue", "AlterQueue: two timed corrections (RS-5.39)", request(C.ALTER_QUEUE, 26, FloatArray([12.004, 12.008]), Matrix(2, 6, [0.0, 0.25, -0.5, 0.0, 0.0, 0.0, 0.0, 0.3, -0.5, 0.0, 0.0, 0.1]))),
        ("reply-alterqueue", "AlterQueue reply: counts, queue state, applied, time (RS-5.45)", _reply(C.ALTER_QUEUE, 26, 2, 0, 40, 12.16, 0, 0, Location(0.0, 0.2, -0.5, 0.0, 0.0, 0.0), 12.0)),
    ]  # fmt: skip


def invalid_frames() -> list[tuple[str, str, bytes, ErrorCode, bool]]:
    """(name, description, bytes, error, fatal); fatal: the header itself is unusable."""
    good = encode_packet(request(C.HEREJ, 1))
    count0 = _params(0, b"")
    j = struct.pack(">6d", 0, 0, 90, 0, 90, 0)
    loc_inf = struct.pack(">6d", 0, 0, math.inf, 0, 0, 0)
    bad_last_row = struct.pack(">16d", *ROTATION[:12], 0, 0, 1, 1)
    return [
        ("bad-magic", "magic 'XS' instead of 'RS'", b"XS" + good[2:], ErrorCode.BAD_FRAME, True),
        ("bad-magic-two-bytes", "only the two bytes 'XS': the magic is judged once two bytes arrived, not after the header [RS-3.19]", b"XS", ErrorCode.BAD_FRAME, True),
        ("bad-magic-second-byte", "magic 'RX': a right first byte and a wrong second one [RS-3.19]", b"RX" + good[2:], ErrorCode.BAD_FRAME, True),
        ("garbage-http", "an HTTP request line", b"GET / HTTP/1.1\r\nHost: x\r\n\r\n", ErrorCode.BAD_FRAME, True),
        ("length-over-max", "payload length 16 MiB + 1", wire.HEADER.pack(wire.MAGIC, 1, 0, 1, 0, 0x1002, 1, wire.MAX_PAYLOAD + 1), ErrorCode.FRAME_TOO_LARGE, True),
        ("length-max-u32", "payload length 0xFFFFFFFF", wire.HEADER.pack(wire.MAGIC, 1, 0, 1, 0, 0x1002, 1, 0xFFFFFFFF), ErrorCode.FRAME_TOO_LARGE, True),
        ("bad-crc", "last CRC byte flipped", good[:-1] + bytes([good[-1] ^ 0x01]), ErrorCode.BAD_CRC, False),
        ("bad-crc-payload", "payload byte changed after sealing", encode_packet(request(C.PING, 2, b"abc"))[:-5] + b"X" + encode_packet(request(C.PING, 2, b"abc"))[-4:], ErrorCode.BAD_CRC, False),
        ("version-2", "major version 2", _frame(count0, major=2), ErrorCode.UNSUPPORTED_VERSION, False),
        ("version-0", "major version 0", _frame(count0, major=0), ErrorCode.UNSUPPORTED_VERSION, False),
        ("kind-0", "packet kind 0", _frame(count0, kind=0), ErrorCode.BAD_FRAME, False),
        ("kind-5", "packet kind 5", _frame(count0, kind=5), ErrorCode.BAD_FRAME, False),
        ("flags-set", "reserved flags 0x80", _frame(count0, flags=0x80), ErrorCode.BAD_FRAME, False),
        ("empty-payload", "payload without parameter count", _frame(b""), ErrorCode.BAD_PARAMETERS, False),
        ("one-byte-payload", "payload of one byte", _frame(b"\x00"), ErrorCode.BAD_PARAMETERS, False),
        ("unknown-tag", "type tag 0x7f", _frame(_params(1, b"\x7f\x00")), ErrorCode.BAD_PARAMETERS, False),
        ("precedence-unknown-command-bad-tag", "unknown command 0xfff0 with an unknown type tag: the parameter list is decoded first [RS-6.4]", _frame(_params(1, b"\x7f\x00"), command=0xFFF0), ErrorCode.BAD_PARAMETERS, False),
        ("precedence-bad-crc-and-version", "major version 2 and a wrong CRC: the CRC is checked first [RS-6.4]", _frame(count0, major=2)[:-1] + b"\x00", ErrorCode.BAD_CRC, False),
        ("tag-zero", "type tag 0x00", _frame(_params(1, b"\x00")), ErrorCode.BAD_PARAMETERS, False),
        ("count-too-high", "count 2, one parameter present", _frame(_params(2, b"\x03\x01")), ErrorCode.BAD_PARAMETERS, False),
        ("trailing-in-payload", "bytes after the last parameter", _frame(_params(1, b"\x03\x01\x00")), ErrorCode.BAD_PARAMETERS, False),
        ("int-truncated", "INT with 4 of 8 bytes", _frame(_params(1, b"\x01\x00\x00\x00\x01")), ErrorCode.BAD_PARAMETERS, False),
        ("bool-2", "BOOL byte 2", _frame(_params(1, b"\x03\x02")), ErrorCode.BAD_PARAMETERS, False),
        ("string-bad-utf8", "STRING with invalid UTF-8", _frame(_params(1, b"\x04\x00\x00\x00\x02\xc3\x28")), ErrorCode.BAD_PARAMETERS, False),
        ("string-past-payload", "STRING length beyond the payload", _frame(_params(1, b"\x04\x00\x00\x01\x00abc")), ErrorCode.BAD_PARAMETERS, False),
        ("bytes-huge-length", "BYTES length 0xFFFFFFFF", _frame(_params(1, b"\x05\xff\xff\xff\xff")), ErrorCode.BAD_PARAMETERS, False),
        ("float-array-truncated", "FLOAT_ARRAY of 3 with 2 values", _frame(_params(1, b"\x06\x00\x00\x00\x03" + struct.pack(">2d", 1, 2))), ErrorCode.BAD_PARAMETERS, False),
        ("joints-0", "JOINTS with zero axes", _frame(_params(1, b"\x08\x00")), ErrorCode.BAD_PARAMETERS, False),
        ("joints-17", "JOINTS with seventeen axes", _frame(_params(1, b"\x08\x11" + struct.pack(">17d", *range(17)))), ErrorCode.BAD_PARAMETERS, False),
        ("joints-nan", "JOINTS containing NaN", _frame(_params(1, b"\x08\x06" + j[:8] + struct.pack(">d", math.nan) + j[16:])), ErrorCode.BAD_PARAMETERS, False),
        ("location-inf", "LOCATION with infinite z", _frame(_params(1, b"\x09" + loc_inf)), ErrorCode.BAD_PARAMETERS, False),
        ("location-truncated", "LOCATION with 5 values", _frame(_params(1, b"\x09" + loc_inf[:40])), ErrorCode.BAD_PARAMETERS, False),
        ("transform-last-row", "TRANSFORM last row 0 0 1 1", _frame(_params(1, b"\x0a" + bad_last_row)), ErrorCode.BAD_PARAMETERS, False),
        ("matrix-truncated", "MATRIX 2x2 with 3 values", _frame(_params(1, b"\x0b" + struct.pack(">II3d", 2, 2, 1, 2, 3))), ErrorCode.BAD_PARAMETERS, False),
        ("image-length-mismatch", "IMAGE 4x2 with length 7", _frame(_params(1, b"\x0c" + struct.pack(">HHBBI", 4, 2, 1, 0, 7) + bytes(7))), ErrorCode.BAD_PARAMETERS, False),
        ("image-unknown-format", "IMAGE format 9", _frame(_params(1, b"\x0c" + struct.pack(">HHBBI", 1, 1, 9, 0, 1) + b"\x00")), ErrorCode.BAD_PARAMETERS, False),
        ("image-unknown-order", "IMAGE order 3", _frame(_params(1, b"\x0c" + struct.pack(">HHBBI", 1, 1, 1, 3, 1) + b"\x00")), ErrorCode.BAD_PARAMETERS, False),
    ]  # fmt: skip


def truncated_frames() -> list[tuple[str, str, bytes]]:
    """Prefixes of valid frames: a decoder needs more data and must not fail or guess."""
    reply = encode_packet(_reply(C.HEREJ, 1, Joints([10, -20, 90, 0, 45, 0])))
    return [
        ("truncated-1-byte", "first byte of a frame", reply[:1]),
        ("truncated-1-wrong-byte", "one byte X: the magic is two bytes [RS-3.19]", b"X"),
        ("truncated-header", "15 of 16 header bytes", reply[:15]),
        ("truncated-payload", "header and half the payload", reply[:40]),
        ("truncated-crc", "all but the last CRC byte", reply[:-1]),
    ]


def datagrams() -> list[dict[str, Any]]:
    trigger = encode_trigger(Trigger(42, 12.5))
    found = encode_data(
        SensorData(42, SensorStatus.FOUND, (0.0, 1.25, 80.0, 0.0, 0.0, 0.0), 0.95, 12.5,
                   100.0001, 100.0003, 100.0038)
    )  # fmt: skip
    nan6 = (math.nan,) * 6
    not_found = encode_data(
        SensorData(7, SensorStatus.NOT_FOUND, nan6, 0.0, 1.0, 2.0, 2.0001, 2.0036)
    )
    out: list[dict[str, Any]] = [
        {"name": "trigger", "hex": trigger.hex(), "valid": True,
         "decoded": {"kind": "TRIGGER", "index": 42, "t_trigger": 12.5}},
        {"name": "trigger-minor-2", "hex": _seal(trigger[:3] + b"\x02" + trigger[4:-4]).hex(),
         "valid": True, "decoded": {"kind": "TRIGGER", "index": 42, "t_trigger": 12.5}},
        {"name": "trigger-index-max", "hex": encode_trigger(Trigger(0xFFFFFFFF, 0.0)).hex(),
         "valid": True, "decoded": {"kind": "TRIGGER", "index": 0xFFFFFFFF, "t_trigger": 0.0}},
        {"name": "data-found", "hex": found.hex(), "valid": True,
         "decoded": {"kind": "DATA", "index": 42, "status": "FOUND",
                     "seam": [0.0, 1.25, 80.0, 0.0, 0.0, 0.0], "quality": 0.95,
                     "t_trigger": 12.5, "t_arrival": 100.0001,
                     "t_exposure_start": 100.0003, "t_exposure_end": 100.0038}},
        {"name": "data-not-found", "hex": not_found.hex(), "valid": True,
         "decoded": {"kind": "DATA", "index": 7, "status": "NOT_FOUND", "seam": ["nan"] * 6,
                     "quality": 0.0, "t_trigger": 1.0, "t_arrival": 2.0,
                     "t_exposure_start": 2.0001, "t_exposure_end": 2.0036}},
    ]  # fmt: skip

    def reseal(raw: bytes) -> bytes:
        return _seal(raw[:-4])

    bad = [
        ("dg-empty", b""),
        ("dg-short", trigger[:10]),
        ("dg-bad-magic", reseal(b"XY" + trigger[2:])),
        ("dg-bad-crc", trigger[:-1] + bytes([trigger[-1] ^ 0xFF])),
        ("dg-version-2", reseal(trigger[:2] + b"\x02" + trigger[3:])),
        ("dg-kind-3", reseal(trigger[:4] + b"\x03" + trigger[5:])),
        ("dg-flags", reseal(trigger[:5] + b"\x01" + trigger[6:])),
        ("dg-trigger-long", _seal(trigger[:-4] + b"\x00")),
        ("dg-data-short", _seal(found[:-5])),
        ("dg-unknown-status", reseal(found[:10] + b"\x09" + found[11:])),
        ("dg-trigger-nan-time", _seal(trigger[:10] + struct.pack(">d", math.nan))),
    ]
    for name, raw in bad:
        out.append({"name": name, "hex": raw.hex(), "valid": False, "error": "BAD_FRAME"})
    return out


def build() -> dict[str, list[dict[str, Any]]]:
    frames: list[dict[str, Any]] = []
    for name, desc, packet in valid_frames():
        frames.append({"name": name, "description": desc, "valid": True,
                       "hex": encode_packet(packet).hex(), "decoded": packet_to_json(packet)})  # fmt: skip
    for name, desc, raw, code, fatal in invalid_frames():
        frames.append({"name": name, "description": desc, "valid": False, "hex": raw.hex(),
                       "error": code.name, "fatal": fatal})  # fmt: skip
    for name, desc, raw in truncated_frames():
        frames.append({"name": name, "description": desc, "valid": False, "hex": raw.hex(),
                       "error": "INCOMPLETE", "fatal": False})  # fmt: skip
    return {"frames.json": frames, "datagrams.json": datagrams()}


#: A short robot session, frames back to back as a TCP capture holds them (both directions):
#: what ``python -m spec decode spec/capture.bin`` shows a new user.
CAPTURE_PATH = Path(__file__).with_name("capture.bin")


def capture() -> bytes:
    """The session of :data:`CAPTURE_PATH`; it conforms: no frame breaks a rule on its own
    (Hello's version is its headers' [RS-5.31]), request IDs go up by one [RS-3.13], and the
    commands it answers are listed in Hello [RS-5.3]."""
    herej, joint_move = int(C.HEREJ), int(C.JOINT_MOVE)
    commands = IntArray((1, 2, 3, 4, 5, herej, joint_move))
    hello = int(C.HELLO)
    packets = [
        request(hello, 1, wire.VERSION_MAJOR, wire.VERSION_MINOR, "client/1.0"),
        _reply(
            hello,
            1,
            wire.VERSION,
            "robot",
            "reference",
            "RX90B",
            "0001",
            "0.1.0",
            commands,
            wire.DEFAULT_MAX_PAYLOAD,
            64,
            300.0,
            5.0,
        ),
        request(herej, 2),
        _reply(herej, 2, Joints((10.0, -20.0, 90.0, 0.0, 45.0, 0.0))),
        request(joint_move, 3, Joints((0.0, 0.0, 90.0, 0.0, 90.0, 0.0))),
        error_packet(joint_move, 3, ErrorCode.NOT_POWERED, "arm power is off"),
    ]
    return b"".join(encode_packet(p) for p in packets)


def write(force: bool = False) -> list[Path]:
    VECTOR_DIR.mkdir(exist_ok=True)
    written = []
    if force or not CAPTURE_PATH.exists():
        write_atomically(CAPTURE_PATH, capture())
        written.append(CAPTURE_PATH)
    for name, items in build().items():
        path = VECTOR_DIR / name
        if path.exists() and not force:
            continue
        write_atomically(path, json.dumps(items, indent=1, ensure_ascii=False) + "\n")
        written.append(path)
    return written


def load(name: str) -> list[dict[str, Any]]:
    data: list[dict[str, Any]] = json.loads((VECTOR_DIR / name).read_text(encoding="utf-8"))
    return data
