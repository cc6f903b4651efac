"""pcapng writing and reading: blocks, synthesized TCP/UDP, streams back from packets."""

from __future__ import annotations

import ipaddress
import struct
from pathlib import Path

import pytest

from spec.pcapng import (
    LINKTYPE_ETHERNET,
    LINKTYPE_RAW,
    Capture,
    CapturedPacket,
    PcapError,
    PcapngWriter,
    TcpFlow,
    _checksum,
    ip_of_frame,
    partial_path,
    read_capture,
    sessions,
    udp_datagram,
)

C = (ipaddress.ip_address("10.0.0.1"), 40000)
S = (ipaddress.ip_address("10.0.0.2"), 4000)


def test_a_recording_is_a_part_file_until_closed(tmp_path: Path) -> None:
    target = tmp_path / "s.pcapng"
    target.write_bytes(b"the old recording")
    w = PcapngWriter(target, "a to b")
    flow = TcpFlow(C, S)
    w.write_all(flow.handshake(), 1_000_000_000)
    w.write_all(flow.data(True, b"hello"), 1_500_000_123)
    # flushed per packet: the partial file is readable now, the old target untouched
    part = read_capture(partial_path(target))
    assert len(part.packets) == 4 and part.comments == ["a to b"]
    assert target.read_bytes() == b"the old recording"
    w.close()
    assert not partial_path(target).exists()
    cap = read_capture(target)
    assert [p.timestamp_ns for p in cap.packets][-1] == 1_500_000_123  # nanoseconds kept
    assert all(p.linktype == LINKTYPE_RAW for p in cap.packets)


def test_streams_come_back_per_direction_across_segments(tmp_path: Path) -> None:
    big = bytes(range(256)) * 600  # 153600 bytes: three segments
    with PcapngWriter(tmp_path / "s.pcapng", "x") as w:
        flow = TcpFlow(C, S)
        w.write_all(flow.handshake())
        w.write_all(flow.data(True, b"request"))
        segments = flow.data(False, big)
        assert len(segments) == 3
        w.write_all(segments)
        w.write_all(segments[1:2])  # a retransmission: dropped by the reader
        w.write_all(flow.fin(True) + flow.fin(False))
        w.write(udp_datagram(C, S, b"datagram"))
    streams, datagrams = sessions(read_capture(tmp_path / "s.pcapng"))
    assert len(streams) == 1
    (s,) = streams
    assert s.a == C and s.b == S
    assert s.bytes_from(True) == b"request" and s.bytes_from(False) == big
    assert [(d.src, d.dst, d.payload) for d in datagrams] == [(C, S, b"datagram")]


def test_checksums_are_those_of_rfc_1071() -> None:
    # RFC 1071's example: the sum of 0001 f203 f4f5 f6f7 is ddf2, its complement 220d
    assert _checksum(bytes.fromhex("0001f203f4f5f6f7")) == 0x220D
    packet = TcpFlow(C, S).data(True, b"odd")[0]
    assert _checksum(packet[:20]) == 0  # a correct IPv4 header sums to 0
    pseudo = C[0].packed + S[0].packed + struct.pack(">BBH", 0, 6, len(packet) - 20)
    assert _checksum(pseudo + packet[20:]) == 0


def test_ipv6_and_ethernet_frames_are_read() -> None:
    c6 = (ipaddress.ip_address("::1"), 5)
    s6 = (ipaddress.ip_address("::1"), 6)
    packet = TcpFlow(c6, s6).data(True, b"v6")[0]
    ip = ip_of_frame(LINKTYPE_RAW, packet)
    assert ip is not None and ip.src == c6[0] and ip.payload.endswith(b"v6")
    ether = b"\0" * 12 + b"\x86\xdd" + packet
    ip = ip_of_frame(LINKTYPE_ETHERNET, ether)
    assert ip is not None and ip.payload.endswith(b"v6")
    assert ip_of_frame(LINKTYPE_ETHERNET, b"\0" * 12 + b"\x08\x06" + b"arp") is None


def test_a_file_cut_inside_a_block_reads_up_to_it(tmp_path: Path) -> None:
    with PcapngWriter(tmp_path / "s.pcapng", "x") as w:
        w.write_all(TcpFlow(C, S).handshake())
    raw = (tmp_path / "s.pcapng").read_bytes()
    (tmp_path / "cut.pcapng").write_bytes(raw[:-10])
    cap = read_capture(tmp_path / "cut.pcapng")
    assert cap.truncated and len(cap.packets) == 2


def test_classic_pcap_is_read(tmp_path: Path) -> None:
    packet = TcpFlow(C, S).data(True, b"abc")[0]
    head = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, LINKTYPE_RAW)
    rec = struct.pack("<IIII", 7, 250, len(packet), len(packet)) + packet
    (tmp_path / "c.pcap").write_bytes(head + rec)
    cap = read_capture(tmp_path / "c.pcap")
    assert cap.packets == [CapturedPacket(7_000_250_000, LINKTYPE_RAW, packet)]


@pytest.mark.parametrize("content", [b"", b"not a capture at all", b"\x0a\x0d\x0d\x0a" + b"\0" * 8])
def test_other_files_are_refused_by_name(tmp_path: Path, content: bytes) -> None:
    f = tmp_path / "x.pcapng"
    f.write_bytes(content)
    with pytest.raises(PcapError, match=r"x\.pcapng"):
        read_capture(f)
    with pytest.raises(PcapError, match="cannot read"):
        read_capture(tmp_path / "missing.pcapng")


def test_sessions_of_an_empty_capture() -> None:
    assert sessions(Capture([], [])) == ([], [])
