"""The CRC combine (spec/crc.py) and the prepared payload (spec/codec.py) against plain
zlib.crc32 over the whole bytes and the plain encoding."""

from __future__ import annotations

import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spec import wire
from spec.codec import (
    FrameDecoder,
    Packet,
    Rejected,
    decode_packet,
    encode_packet,
    encode_packet_parts,
    packet_of,
    prepare_params,
    reply_to,
    request,
)
from spec.crc import (
    CRC32_IMPLEMENTATION,
    _select_crc32,
    crc32,
    crc32_combine,
    crc32_combine_reference,
)
from spec.errors import BadCrcError, ErrorCode
from spec.params import Image, Value
from spec.wire import TRAILER, PacketKind


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=5000), st.integers(0, 0xFFFFFFFF), st.integers(0, 64))
def test_the_selected_crc32_is_zlibs(data: bytes, start: int, skip: int) -> None:
    """Whichever implementation was picked (zlib-ng with the `fast` extra), it is zlib.crc32:
    on bytes, on views into a receive buffer, continued from any running value."""
    view = memoryview(bytearray(data))[skip:]
    assert crc32(data) == zlib.crc32(data)
    assert crc32(view, start) == zlib.crc32(view, start)


def test_the_fast_crc32_is_used_when_installed_and_zlib_otherwise() -> None:
    assert _select_crc32(fast=False) == (zlib.crc32, "zlib")
    try:
        import zlib_ng  # noqa: F401
    except ImportError:
        assert CRC32_IMPLEMENTATION == "zlib"
    else:
        assert CRC32_IMPLEMENTATION == "zlib-ng"
    image = bytes(range(256)) * 512  # 128 KiB, the size that made it worth it
    assert crc32(image) == zlib.crc32(image)


def _image_frame(request_id: int = 5) -> bytes:
    image = Image(512, 256, bytes(range(251)) * 522 + bytes(50))
    frame = encode_packet(reply_to(request(0x2003, request_id), 3, image))
    # The server sends a full frame from its prepared payload: the same bytes.
    assert _frame(prepare_params((3, image)), request_id) == frame
    return frame


# Not the magic or the length field: those lose the frame boundary, a different error.
@pytest.mark.parametrize("where", [3, 8, 17, 40, 70_000, 131_000, -5, -1])
@pytest.mark.parametrize("in_place", [False, True])
def test_a_flipped_byte_in_an_image_frame_is_a_bad_crc(where: int, in_place: bool) -> None:
    """[RS-3.6] one changed bit anywhere in a 128 KiB frame (header, pixels, trailer) is
    caught, whether the frame comes through feed() or is received in place."""
    frame = bytearray(_image_frame())
    frame[where] ^= 0x10
    decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
    if in_place:
        decoder.feed(frame[:100])
        pos = 100
        while (view := decoder.get_buffer()) is not None:
            n = min(len(view), 50_000)
            view[:n] = frame[pos : pos + n]
            decoder.buffer_updated(n)
            pos += n
    else:
        decoder.feed(bytes(frame))
    (event,) = decoder.events()
    assert isinstance(event, Rejected) and event.code == ErrorCode.BAD_CRC
    with pytest.raises(BadCrcError):
        decode_packet(bytes(frame))
    good = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
    good.feed(_image_frame())
    assert isinstance(next(good.events()), Packet)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=300), st.binary(max_size=300))
def test_combine_is_the_crc_of_the_concatenation(a: bytes, b: bytes) -> None:
    whole = zlib.crc32(a + b)
    assert crc32_combine(zlib.crc32(a), zlib.crc32(b), len(b)) == whole
    assert crc32_combine_reference(zlib.crc32(a), zlib.crc32(b), len(b)) == whole


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 0xFFFFFFFF), st.integers(0, 0xFFFFFFFF), st.integers(0, 1 << 24))
def test_table_combine_matches_zlibs_bitwise_algorithm(c1: int, c2: int, n: int) -> None:
    assert crc32_combine(c1, c2, n) == crc32_combine_reference(c1, c2, n)


def _frame(params: tuple[Value, ...], request_id: int, crc: bool = True) -> bytes:
    packet = packet_of((PacketKind.REPLY, 0x2003, request_id, params, wire.VERSION_MINOR))
    return b"".join(encode_packet_parts(packet, crc=crc))


_values = st.one_of(
    st.integers(-(1 << 63), (1 << 63) - 1),
    st.booleans(),
    st.binary(max_size=64),
    st.binary(min_size=16 * 1024, max_size=20 * 1024),  # a large part, kept as it is
    st.text(max_size=20),
)


@settings(max_examples=60, deadline=None)
@given(st.lists(_values, max_size=5), st.integers(1, 0xFFFFFFFF), st.booleans())
def test_a_prepared_payload_encodes_as_the_plain_one(
    values: list[Value], request_id: int, crc: bool
) -> None:
    """The fast path (payload and its CRC made once) against the plain encoding, byte for
    byte, with the CRC on and off."""
    params = tuple(values)
    prepared = prepare_params(params)
    assert prepared == params
    for rid in (request_id, request_id % 7 + 1):  # the same prepared payload, new headers
        assert _frame(prepared, rid, crc) == _frame(params, rid, crc)


def test_a_resent_image_frame_carries_the_crc_of_its_bytes() -> None:
    image = Image(512, 256, bytes(range(256)) * 512)
    prepared = prepare_params((7, image))
    for request_id in (1, 2, 3):  # same payload, new header each time
        reply = packet_of((PacketKind.REPLY, 0x2003, request_id, prepared, wire.VERSION_MINOR))
        parts = encode_packet_parts(reply)
        assert parts[2] is image.data  # the pixels go out as they are, not copied
        frame = b"".join(parts)
        (crc,) = TRAILER.unpack_from(frame, len(frame) - 4)
        assert crc == zlib.crc32(frame[:-4])
        packet = decode_packet(frame)
        assert isinstance(packet, Packet) and packet.params == (7, image)
