"""The message classes: one per command and direction, from the registry, bytes unchanged."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from spec import doc, messages
from spec.codec import decode_packet, encode_packet
from spec.messages import (
    REPLIES,
    REQUESTS,
    GetDataReply,
    MessageError,
    PingRequest,
    RobotStatusReply,
    RobotStatusRequest,
    TakeControlReply,
    TakeControlRequest,
    reply_of,
    request_of,
)
from spec.params import CLASS_OF, FloatArray, Image, IntArray, Joints, Location, Matrix, Value
from spec.registry import COMMANDS, CommandSpec, ParamSpec
from spec.vectorgen import load
from spec.wire import PacketKind, ParamType

FRAMES = load("frames.json")

_SAMPLE: dict[ParamType, Value] = {
    ParamType.BOOL: True,
    ParamType.INT: 7,
    ParamType.FLOAT: 1.5,
    ParamType.STRING: "s",
    ParamType.BYTES: b"b",
    ParamType.FLOAT_ARRAY: FloatArray([1.0, 2.0]),
    ParamType.INT_ARRAY: IntArray([1, 2]),
    ParamType.JOINTS: Joints([0.0] * 6),
    ParamType.LOCATION: Location(1, 2, 3, 4, 5, 6),
    ParamType.MATRIX: Matrix(1, 2, [1.0, 2.0]),
    ParamType.IMAGE: Image(1, 1, b"\x00"),
}


def _sample(table: tuple[ParamSpec, ...]) -> tuple[Value, ...]:
    return tuple(_SAMPLE[p.type] for p in table)


def test_the_classes_are_generated_from_the_current_registry() -> None:
    assert "messages" not in doc.differences(), "run: python -m spec doc --write"


def test_every_command_has_a_request_and_a_reply_class() -> None:
    assert set(REQUESTS) == set(REPLIES) == {int(c.id) for c in COMMANDS}
    for c in COMMANDS:
        for cls, table in ((REQUESTS[c.id], c.params), (REPLIES[c.id], c.reply)):
            assert cls.command is c.id and cls.table is table
            fields = dataclasses.fields(cls)  # type: ignore[arg-type]
            assert [f.name for f in fields] == [p.name for p in table]


@pytest.mark.parametrize("spec", COMMANDS, ids=lambda c: f"{c.service}.{c.name}")
def test_decode_and_encode_round_trip(spec: CommandSpec) -> None:
    for cls, table in ((REQUESTS[spec.id], spec.params), (REPLIES[spec.id], spec.reply)):
        values = _sample(table)
        message = cls.decode(values)
        assert message.encode() == values
        for p, v in zip(table, values, strict=True):
            assert getattr(message, p.name) == v
            assert type(getattr(message, p.name)) is CLASS_OF[p.type]


@pytest.mark.parametrize("vector", [v for v in FRAMES if v["valid"]], ids=lambda v: v["name"])
def test_every_vector_frame_goes_through_its_message_unchanged(vector: dict[str, Any]) -> None:
    raw = bytes.fromhex(vector["hex"])
    packet = decode_packet(raw)
    if packet.kind not in (PacketKind.REQUEST, PacketKind.REPLY) or packet.command not in REPLIES:
        pytest.skip("not a request or reply of a registered command")
    decode = request_of if packet.kind is PacketKind.REQUEST else reply_of
    try:
        message = decode(packet.command, packet.params)
    except MessageError:
        pytest.skip("a codec vector whose parameters are not the command's")
    if len(message.encode()) != len(packet.params):
        pytest.skip("a codec vector with parameters appended to the command's")
    again = packet._replace(params=message.encode())
    assert encode_packet(again) == raw


def test_a_wrong_field_type_names_the_command_the_field_and_both_types() -> None:
    good = RobotStatusReply(False, False, True, 1, False, True, 0, "", 2.0).encode()
    with pytest.raises(MessageError) as caught:
        RobotStatusReply.decode((*good[:2], 1, *good[3:]))
    exc = caught.value
    assert (exc.what, exc.field, exc.index, exc.expected, exc.got) == (
        "GetStatus reply",
        "moving",
        2,
        "BOOL",
        "INT",
    )
    assert exc.message == "GetStatus reply parameter 2 (moving) must be BOOL, got INT"
    assert int(exc.code) == 6  # BAD_PARAMETERS: what a server answers a request's with


def test_a_wrong_count_says_what_the_table_takes() -> None:
    with pytest.raises(MessageError, match=r"GetStatus reply takes 9 parameters .*got 1"):
        RobotStatusReply.decode((True,))
    with pytest.raises(MessageError, match=r"Ping request takes 0\.\.1 parameters"):
        PingRequest.decode((b"", b""))


def test_optional_fields_are_none_when_left_off_and_left_off_again() -> None:
    assert TakeControlReply.decode(()).watchdog is None  # a 1.0 server
    assert TakeControlReply.decode(()).encode() == ()
    assert TakeControlRequest("t").encode() == ("t",)
    assert TakeControlRequest("t", 1.2).encode() == ("t", 1.2)


def test_a_reply_ignores_appended_parameters_a_request_refuses_them() -> None:
    assert TakeControlReply.decode((1.2, "newer")).watchdog == 1.2  # [RS-5.6]
    with pytest.raises(MessageError):
        RobotStatusRequest.decode((1,))


def test_an_int_enum_counts_as_an_int() -> None:
    from spec.wire import SensorStatus

    values = (3, SensorStatus.FOUND, Location(0, 0, 0, 0, 0, 0), 1.0, 0.0, 0.0, 0.0)
    assert GetDataReply.decode(values).status == 0


def test_a_request_knows_its_reply_class() -> None:
    assert RobotStatusRequest().reply_type() is RobotStatusReply
    assert messages.REQUESTS[0x1001] is RobotStatusRequest
