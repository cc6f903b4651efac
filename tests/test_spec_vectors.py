"""Every test vector, fed whole, byte by byte and followed by trailing bytes [RS-2.4]."""

from __future__ import annotations

import itertools
import math
import struct
import zlib
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spec import wire
from spec.codec import FrameDecoder, Packet, Rejected, encode_packet, request
from spec.datagrams import SensorData, Trigger, decode_datagram, encode_datagram
from spec.errors import ErrorCode, PeerError
from spec.jsonform import packet_from_json
from spec.vectorgen import load

FRAMES = load("frames.json")
DATAGRAMS = load("datagrams.json")
TRAILER = encode_packet(request(0x0002, 99, b"tail"))


def _ids(vector: dict[str, Any]) -> str:
    return str(vector["name"])


def _feed(data: bytes, step: int) -> tuple[list[Packet | Rejected], PeerError | None]:
    decoder = FrameDecoder(max_payload=16 * 1024 * 1024)
    events: list[Packet | Rejected] = []
    try:
        for i in range(0, len(data), step):
            decoder.feed(data[i : i + step])
            events.extend(decoder.events())
    except PeerError as exc:
        return events, exc
    return events, None


def test_there_are_at_least_40_vectors() -> None:
    assert len(FRAMES) + len(DATAGRAMS) >= 40
    assert sum(1 for v in FRAMES if v["valid"]) >= 25
    assert sum(1 for v in FRAMES if not v["valid"]) >= 25


@pytest.mark.parametrize("vector", [v for v in FRAMES if v["valid"]], ids=_ids)
@pytest.mark.parametrize("step", [0, 1], ids=["whole", "byte-by-byte"])
def test_valid_frame_decodes_to_its_json_form(vector: dict[str, Any], step: int) -> None:
    raw = bytes.fromhex(vector["hex"])
    expected = packet_from_json(vector["decoded"])
    events, error = _feed(raw + TRAILER, step or len(raw) + len(TRAILER))
    assert error is None
    assert len(events) == 2, "the frame and the trailing frame"
    packet, tail = events
    assert isinstance(packet, Packet)
    assert encode_packet(packet) == raw  # exact bytes, NaN included
    if not any(isinstance(p, float) and math.isnan(p) for p in expected.params):
        assert packet == expected
    assert isinstance(tail, Packet) and tail.params == (b"tail",)


@pytest.mark.parametrize("vector", [v for v in FRAMES if v["valid"]], ids=_ids)
def test_valid_frame_encodes_to_its_exact_bytes(vector: dict[str, Any]) -> None:
    assert encode_packet(packet_from_json(vector["decoded"])).hex() == vector["hex"]


@pytest.mark.parametrize("vector", [v for v in FRAMES if not v["valid"]], ids=_ids)
@pytest.mark.parametrize("step", [0, 1], ids=["whole", "byte-by-byte"])
def test_invalid_frame_is_rejected_with_its_code(vector: dict[str, Any], step: int) -> None:
    raw = bytes.fromhex(vector["hex"])
    data = raw + TRAILER
    events, error = _feed(data, step or len(data))
    if vector["error"] == "INCOMPLETE":
        # The trailing frame is swallowed as the rest of the incomplete one or rejected; a
        # decoder never invents a packet out of a prefix.
        assert not any(isinstance(e, Packet) and e.params != (b"tail",) for e in events)
        events, error = _feed(raw, step or len(raw))
        assert events == [] and error is None
        return
    code = ErrorCode[vector["error"]]
    if vector["fatal"]:
        assert error is not None and error.code is code
        assert events == []
    else:
        assert error is None, f"a recoverable error must not end the stream: {error}"
        assert isinstance(events[0], Rejected) and events[0].code is code
        # [RS-3.9] the decoder goes on with the next frame.
        assert isinstance(events[-1], Packet) and events[-1].params == (b"tail",)


@pytest.mark.parametrize("vector", DATAGRAMS, ids=_ids)
def test_datagram_vectors(vector: dict[str, Any]) -> None:
    raw = bytes.fromhex(vector["hex"])
    if not vector["valid"]:
        with pytest.raises(PeerError) as info:
            decode_datagram(raw)
        assert info.value.code is ErrorCode[vector["error"]]
        return
    d = decode_datagram(raw)
    want = vector["decoded"]
    assert d.index == want["index"] and d.t_trigger == want["t_trigger"]
    if want["kind"] == "TRIGGER":
        assert isinstance(d, Trigger)
    else:
        assert isinstance(d, SensorData)
        assert d.status.name == want["status"]
        seam = [float(x) for x in want["seam"]]
        pairs = zip(d.seam, seam, strict=True)
        assert all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in pairs)
        assert (d.t_arrival, d.t_exposure_start, d.t_exposure_end) == (
            want["t_arrival"],
            want["t_exposure_start"],
            want["t_exposure_end"],
        )
    # Our encoder writes its own minor version [SY-1.1]; an older peer's (trigger-minor-2)
    # decodes to the same datagram.
    ours = raw[:3] + bytes([wire.VERSION_MINOR]) + raw[4:-4]
    assert encode_datagram(d) == ours + struct.pack(">I", zlib.crc32(ours))


def test_protocol_md_worked_examples_are_real_frames() -> None:
    """The hex dumps of PROTOCOL.md section 10 decode (CRC included) to what they say."""
    from spec.dissect import describe
    from spec.requirements import PROTOCOL_MD

    text = PROTOCOL_MD.read_text(encoding="utf-8").split("## 10. Worked examples")[1]
    blocks = text.split("```")[1::2]
    assert len(blocks) == 6
    for block in blocks:
        hex_text = " ".join(line[:50] for line in block.strip().splitlines())
        raw = bytes.fromhex("".join(c for c in hex_text if c in "0123456789abcdef"))
        assert describe(raw)  # raises on a bad CRC or layout


def _events_fast(chunks: list[bytes]) -> tuple[list[object], object]:
    """The receivers' path: each chunk received into one reused buffer, then feed_next."""
    decoder = FrameDecoder(max_payload=16 * 1024 * 1024)
    scratch = bytearray(1 << 17)
    events: list[object] = []
    try:
        for chunk in chunks:
            decoder.keep()
            scratch[: len(chunk)] = chunk
            event = decoder.feed_next(memoryview(scratch)[: len(chunk)])
            while event is not None:
                events.append(_plain(event))
                event = decoder.next_event()
    except PeerError as exc:
        return events, (exc.code, str(exc))
    return events, None


def _events_reference(chunks: list[bytes]) -> tuple[list[object], object]:
    decoder = FrameDecoder(max_payload=16 * 1024 * 1024)
    events: list[object] = []
    try:
        for chunk in chunks:
            decoder.feed(chunk)
            events.extend(_plain(e) for e in decoder.events())
    except PeerError as exc:
        return events, (exc.code, str(exc))
    return events, None


def _plain(event: Packet | Rejected) -> object:
    """Comparable form (NaN parameters included): a packet's bytes, a rejection's reason."""
    if isinstance(event, Packet):
        return encode_packet(event)
    return (event.header, event.code, str(event.error))


@settings(max_examples=300, deadline=None)
@given(
    picks=st.lists(st.integers(0, len(FRAMES) - 1), min_size=1, max_size=6),
    cuts=st.lists(st.integers(0, 4096), max_size=8),
)
def test_feed_next_gives_what_feed_and_next_event_give(picks: list[int], cuts: list[int]) -> None:
    """feed_next (whole small frames decoded in place) against the plain feed + next_event,
    for frames valid and invalid, whole, coalesced and split anywhere."""
    data = b"".join(bytes.fromhex(FRAMES[i]["hex"]) for i in picks)
    bounds = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
    chunks = [data[a:b] for a, b in itertools.pairwise(bounds) if b > a]
    assert _events_fast(chunks) == _events_reference(chunks)
    # Each frame in a receive of its own: the case feed_next decodes in place.
    alone = [bytes.fromhex(FRAMES[i]["hex"]) for i in picks]
    assert _events_fast(alone) == _events_reference(alone)
