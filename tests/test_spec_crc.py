"""The CRC combine and cache (spec/crc.py) against plain zlib.crc32 over the whole bytes."""

from __future__ import annotations

import zlib

from hypothesis import given, settings
from hypothesis import strategies as st

from spec.codec import Packet, decode_packet, encode_packet_parts, reply_to, request
from spec.crc import (
    CACHED_MIN,
    cached_crc32,
    crc32_combine,
    crc32_combine_reference,
    crc32_parts,
)
from spec.params import Image
from spec.wire import TRAILER


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


@settings(max_examples=50, deadline=None)
@given(st.lists(st.binary(max_size=64), max_size=4), st.binary(min_size=1, max_size=64))
def test_parts_with_a_large_part_match_zlib(small: list[bytes], seed: bytes) -> None:
    big = (seed * (CACHED_MIN // len(seed) + 1))[: CACHED_MIN + len(seed)]
    parts = [*small, big, *small, big]
    assert crc32_parts(parts) == zlib.crc32(b"".join(parts))
    assert crc32_parts(parts) == zlib.crc32(b"".join(parts))  # now from the cache


def test_the_cache_follows_the_object_not_a_stale_entry() -> None:
    for fill in range(10):  # more objects than the cache holds, freed and reallocated
        data = bytes([fill]) * (CACHED_MIN + 7)
        assert cached_crc32(data) == zlib.crc32(data)
    mutable = bytearray(CACHED_MIN)
    first = crc32_parts([mutable])
    mutable[0] = 1  # a bytearray can change: never cached
    assert crc32_parts([mutable]) != first == zlib.crc32(bytes(CACHED_MIN))


def test_a_resent_image_frame_carries_the_crc_of_its_bytes() -> None:
    image = Image(512, 256, bytes(range(256)) * 512)
    for request_id in (1, 2, 3):  # same image object, new header each time
        reply = reply_to(request(0x2003, request_id), request_id, image)
        parts = encode_packet_parts(reply)
        frame = b"".join(parts)
        (crc,) = TRAILER.unpack_from(frame, len(frame) - 4)
        assert crc == zlib.crc32(frame[:-4])
        packet = decode_packet(frame)
        assert isinstance(packet, Packet) and packet.params == (request_id, image)
