"""Round-trip properties of the parameter list and the frame codec."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spec.codec import (
    Event,
    FrameDecoder,
    Packet,
    decode_packet,
    encode_packet,
    encode_packet_parts,
    encode_reply,
    encode_request,
    request,
)
from spec.errors import ParameterError, UsageError
from spec.params import (
    FloatArray,
    Image,
    IntArray,
    Joints,
    Location,
    Matrix,
    Transform,
    Value,
    decode_params,
    encode_params,
)
from spec.wire import PacketKind, PixelFormat, PixelOrder

finite = st.floats(allow_nan=False, allow_infinity=False)
anyfloat = st.floats(allow_nan=False)  # NaN != NaN; checked separately below


@st.composite
def images(draw: st.DrawFn) -> Image:
    w = draw(st.integers(0, 12))
    h = draw(st.integers(0, 12))
    fmt = draw(st.sampled_from(list(PixelFormat)))
    n = w * h * (1 if fmt is PixelFormat.MONO8 else 2)
    return Image(w, h, draw(st.binary(min_size=n, max_size=n)), fmt,
                 draw(st.sampled_from(list(PixelOrder))))  # fmt: skip


@st.composite
def matrices(draw: st.DrawFn) -> Matrix:
    rows, cols = draw(st.integers(0, 6)), draw(st.integers(0, 6))
    return Matrix(rows, cols, draw(st.lists(anyfloat, min_size=rows * cols, max_size=rows * cols)))


@st.composite
def transforms(draw: st.DrawFn) -> Transform:
    return Transform([*draw(st.lists(finite, min_size=12, max_size=12)), 0.0, 0.0, 0.0, 1.0])


values: st.SearchStrategy[Value] = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    anyfloat,
    st.booleans(),
    st.text(max_size=40),
    st.binary(max_size=64),
    st.lists(anyfloat, max_size=20).map(FloatArray),
    st.lists(st.integers(-(2**63), 2**63 - 1), max_size=20).map(IntArray),
    st.lists(finite, min_size=1, max_size=16).map(Joints),
    st.lists(finite, min_size=6, max_size=6).map(Location.of),
    transforms(),
    matrices(),
    images(),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(values, max_size=8))
def test_any_parameter_list_round_trips(params: list[Value]) -> None:
    assert decode_params(encode_params(params)) == tuple(params)


@settings(max_examples=200, deadline=None)
@given(
    st.lists(values, max_size=6),
    st.sampled_from(list(PacketKind)),
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFFFFFF),
)
def test_any_packet_round_trips_whole_and_split(
    params: list[Value], kind: PacketKind, command: int, request_id: int
) -> None:
    packet = Packet(kind, command, request_id, tuple(params))
    raw = encode_packet(packet)
    assert decode_packet(raw) == packet
    decoder = FrameDecoder()
    out: list[Event] = []
    for i in range(0, len(raw), 5):
        decoder.feed(raw[i : i + 5])
        out.extend(decoder.events())
    assert out == [packet]


def test_nan_float_round_trips_bit_exact() -> None:
    (back,) = decode_params(encode_params([math.nan]))
    assert isinstance(back, float) and math.isnan(back)


def test_bool_is_not_encoded_as_int() -> None:
    assert encode_params([True])[2] == 0x03
    assert encode_params([1])[2] == 0x01


@pytest.mark.parametrize(
    "build",
    [
        lambda: Joints([]),
        lambda: Joints([math.nan] * 6),
        lambda: Joints(range(17)),
        lambda: Location(0, 0, math.inf, 0, 0, 0),
        lambda: Location.of([1, 2, 3]),
        lambda: Transform([1.0] * 16),
        lambda: Matrix(2, 2, [1.0]),
        lambda: Image(2, 2, b"\x00"),
        lambda: encode_params([2**63]),
        lambda: encode_params([object()]),  # type: ignore[list-item]
        lambda: encode_packet(request(0x10000, 1)),
    ],
)
def test_unencodable_values_raise_usage_error(build: object) -> None:
    with pytest.raises(UsageError):
        build()  # type: ignore[operator]


def test_large_arrays_and_images_decode() -> None:
    image = Image(512, 256, bytes(range(256)) * 512)
    log = Matrix(2500, 7, [float(i) for i in range(2500 * 7)])
    assert decode_params(encode_params([image, log])) == (image, log)


def test_payload_must_be_filled_exactly() -> None:
    with pytest.raises(ParameterError):
        decode_params(encode_params([1]) + b"\x00")


def test_large_frames_received_in_place_reuse_one_buffer_without_aliasing() -> None:
    """Two large frames through get_buffer / buffer_updated (as a socket's recv_into): the
    decoder reuses its buffer, and the first decoded image is not overwritten by the second."""
    decoder = FrameDecoder()
    images = [Image(512, 256, bytes([fill]) * (512 * 256)) for fill in (7, 9)]
    got: list[Packet] = []
    for i, image in enumerate(images):
        raw = encode_packet(Packet(PacketKind.REPLY, 0x2003, i + 1, (i, image)))
        decoder.feed(raw[:100])
        pos = 100
        while pos < len(raw):
            view = decoder.get_buffer()
            assert view is not None
            n = min(len(view), 40000, len(raw) - pos)
            view[:n] = raw[pos : pos + n]
            decoder.buffer_updated(n)
            pos += n
        got.extend(e for e in decoder.events() if isinstance(e, Packet))
    assert [p.params for p in got] == [(0, images[0]), (1, images[1])]


@settings(max_examples=100, deadline=None)
@given(st.lists(st.lists(values, max_size=3), min_size=1, max_size=4), st.data())
def test_borrowed_feed_matches_copied_feed(lists: list[list[Value]], data: st.DataObject) -> None:
    """Bytes fed as views of one reused receive buffer (borrow=True, keep() before it is
    overwritten) decode to the same packets as bytes fed as copies."""
    packets = [Packet(PacketKind.REPLY, 7, i + 1, tuple(p)) for i, p in enumerate(lists)]
    stream = b"".join(encode_packet(p) for p in packets)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    pieces = [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
    scratch = bytearray(len(stream) + 1)
    borrowed, copied = FrameDecoder(), FrameDecoder()
    got: list[object] = []
    want: list[object] = []
    for piece in pieces:
        borrowed.keep()
        scratch[:] = b"\xee" * len(scratch)  # what the previous piece left is overwritten
        scratch[: len(piece)] = piece
        borrowed.feed(memoryview(scratch)[: len(piece)], borrow=True)
        got.extend(borrowed.events())
        copied.feed(piece)
        want.extend(copied.events())
    assert got == want == packets


@pytest.mark.parametrize(
    ("command", "request_id", "field"),
    [
        (0x10000, 1, "command ID"),
        (-1, 1, "command ID"),
        (1, 1 << 32, "request ID"),
        (1, -1, "request ID"),
    ],
)
def test_a_header_field_out_of_range_is_a_usage_error_naming_it(
    command: int, request_id: int, field: str
) -> None:
    with pytest.raises(UsageError, match=field):
        encode_packet(Packet(PacketKind.REQUEST, command, request_id, ()))
    with pytest.raises(UsageError, match=field):
        encode_request(command, request_id)  # the template path says the same


@settings(max_examples=300, deadline=None)
@given(
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFFFFFF),
    st.one_of(st.just([]), st.lists(values, max_size=3)),
    st.integers(0, 0xFF),
)
def test_a_client_request_is_encoded_as_encode_packet_does(
    command: int, request_id: int, params: list[Value], minor: int
) -> None:
    """The request template (a client's call without parameters) is the plain encoding."""
    packet = Packet(PacketKind.REQUEST, command, request_id, tuple(params), minor)
    assert encode_request(command, request_id, tuple(params), minor) == encode_packet(packet)


@settings(max_examples=300, deadline=None)
@given(
    st.integers(0, 0xFFFF),
    st.integers(0, 0xFFFFFFFF),
    st.one_of(
        st.lists(finite, min_size=1, max_size=16).map(lambda v: [Joints(v)]),
        st.lists(values, max_size=3),
    ),
    st.booleans(),
)
def test_a_server_reply_is_encoded_as_encode_packet_parts_does(
    command: int, request_id: int, params: list[Value], crc: bool
) -> None:
    """The reply template (one Joints: Herej) is the plain encoding, with CRC or without."""
    packet = Packet(PacketKind.REPLY, command, request_id, tuple(params))
    assert encode_reply(command, request_id, tuple(params), crc) == encode_packet_parts(
        packet, crc=crc
    )


@pytest.mark.parametrize(("command", "request_id"), [(0x10000, 1), (1, 1 << 32), (1, -1)])
def test_a_reply_header_field_out_of_range_is_the_plain_usage_error(
    command: int, request_id: int
) -> None:
    with pytest.raises(UsageError, match="ID"):
        encode_reply(command, request_id, (Joints([1.0] * 6),))


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b"\x00\x01\x08", "parameter 0 (JOINTS) truncated"),
        (b"\x00\x01\x08\x00", "JOINTS count 0 not in 1..16"),
        (b"\x00\x01\x08\x11" + bytes(8 * 17), "JOINTS count 17 not in 1..16"),
        (b"\x00\x01\x08\x02" + bytes(15), "parameter 0 (JOINTS) truncated"),
        (b"\x00\x01\x08\x01\x7f\xf8" + bytes(6), "parameter 0 (JOINTS) must be finite"),
    ],
)
def test_bad_joints_are_refused_with_what_is_wrong(payload: bytes, message: str) -> None:
    with pytest.raises(ParameterError, match=message.replace("(", r"\(").replace(")", r"\)")):
        decode_params(payload)
