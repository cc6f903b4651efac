"""pcapng files: write a session as Wireshark reads it, read one back (ours or a capture's).

Writing: a Section Header Block with a comment naming the endpoints, one Interface
Description Block (link type RAW: every packet is an IPv4 or IPv6 packet, nanosecond
timestamps), then an Enhanced Packet Block per packet, flushed to the operating system at once
so a recorder killed with SIGKILL leaves a file that opens up to its last packet. The file is
written as ``NAME.part`` and renamed to ``NAME`` when the recording ends, so ``NAME`` is only
ever the whole recording [pcapng: draft-ietf-opsawg-pcapng].

TCP is synthesized (:class:`TcpFlow`): a handshake, each chunk of bytes as it was sent or
received as segments with consistent sequence numbers and checksums, a FIN at the end; a
dissector reassembles frames across them as it does on a real capture. UDP datagrams likewise.

Reading: :func:`read_packets` takes pcapng (any block order, several interfaces, either byte
order) and classic pcap, with link types RAW, Ethernet, Linux cooked and BSD loopback, and
stops quietly at a block cut off at the end (a killed capture). :func:`sessions` turns the
packets back into TCP byte streams per connection and UDP datagrams.
"""

from __future__ import annotations

import ipaddress
import os
import struct
import sys
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

# --- block layouts (little-endian when we write; either when we read) ----------------------

BYTE_ORDER_MAGIC = 0x1A2B3C4D
SHB_TYPE = 0x0A0D0D0A
IDB_TYPE = 0x00000001
EPB_TYPE = 0x00000006
SPB_TYPE = 0x00000003
OPT_END = 0
OPT_COMMENT = 1
SHB_HARDWARE, SHB_OS, SHB_USERAPPL = 2, 3, 4
IF_NAME, IF_TSRESOL = 2, 9

LINKTYPE_NULL = 0
LINKTYPE_ETHERNET = 1
LINKTYPE_RAW = 101
LINKTYPE_LINUX_SLL = 113
LINKTYPE_IPV4 = 228
LINKTYPE_IPV6 = 229

#: IP protocol numbers.
TCP, UDP = 6, 17
#: Largest TCP payload per synthesized segment (an IPv4 packet is at most 65535 bytes).
SEGMENT_MAX = 65000

_TCP_FIN, _TCP_SYN, _TCP_PSH, _TCP_ACK = 0x01, 0x02, 0x08, 0x10
_IPV4 = struct.Struct(">BBHHHBBH4s4s")
_IPV6 = struct.Struct(">IHBB16s16s")
_TCP = struct.Struct(">HHIIBBHHH")
_UDP = struct.Struct(">HHHH")


class PcapError(ValueError):
    """A file that is not a capture we can read (message names the problem)."""


def _pad(data: bytes) -> bytes:
    return data + b"\0" * (-len(data) % 4)


def _options(options: Iterable[tuple[int, bytes]]) -> bytes:
    out = b"".join(struct.pack("<HH", code, len(v)) + _pad(v) for code, v in options)
    return out + struct.pack("<HH", OPT_END, 0) if out else b""


def _block(block_type: int, body: bytes) -> bytes:
    length = 12 + len(body)
    return struct.pack("<II", block_type, length) + body + struct.pack("<I", length)


def section_header(comment: str, application: str) -> bytes:
    opts = [
        (OPT_COMMENT, comment.encode()),
        (SHB_OS, f"{sys.platform}".encode()),
        (SHB_USERAPPL, application.encode()),
    ]
    # section length -1: not given (we append as we go)
    body = struct.pack("<IHHq", BYTE_ORDER_MAGIC, 1, 0, -1) + _options(opts)
    return _block(SHB_TYPE, body)


def interface_description(linktype: int, name: str, snaplen: int = 0) -> bytes:
    # if_tsresol 9: timestamps in nanoseconds
    opts = [(IF_NAME, name.encode()), (IF_TSRESOL, bytes([9]))]
    body = struct.pack("<HHI", linktype, 0, snaplen) + _options(opts)
    return _block(IDB_TYPE, body)


def enhanced_packet(data: bytes, timestamp_ns: int, comment: str | None = None) -> bytes:
    opts = [(OPT_COMMENT, comment.encode())] if comment else []
    head = struct.pack(
        "<IIIII", 0, timestamp_ns >> 32, timestamp_ns & 0xFFFFFFFF, len(data), len(data)
    )
    return _block(EPB_TYPE, head + _pad(data) + _options(opts))


# --- synthesized IP, TCP and UDP -----------------------------------------------------------


def _checksum(data: bytes) -> int:
    """Internet checksum (RFC 1071); the sum of native-order 16-bit words is folded and
    swapped at the end, which is the same sum (RFC 1071, 2.(B))."""
    if len(data) % 2:
        data += b"\0"
    total = sum(memoryview(data).cast("H"))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    value = ~total & 0xFFFF
    return value if sys.byteorder == "big" else ((value & 0xFF) << 8) | (value >> 8)


Address = ipaddress.IPv4Address | ipaddress.IPv6Address


def ip_of(host: str) -> Address:
    """The IP address of a socket address's host (a scope suffix dropped)."""
    return ipaddress.ip_address(host.split("%", 1)[0])


def same_family(a: Address, b: Address) -> tuple[Address, Address]:
    """Both as IPv6 when one is (IPv4-mapped), so a packet has one IP version."""
    if a.version == b.version:
        return a, b
    v6 = [x if x.version == 6 else ipaddress.IPv6Address(f"::ffff:{x}") for x in (a, b)]
    return v6[0], v6[1]


def ip_packet(src: Address, dst: Address, protocol: int, payload: bytes, ident: int = 0) -> bytes:
    """``payload`` (a TCP segment or UDP datagram whose checksum is already in place) in an IP
    packet from ``src`` to ``dst``."""
    if src.version == 4:
        head = _IPV4.pack(
            0x45,
            0,
            20 + len(payload),
            ident & 0xFFFF,
            0x4000,
            64,
            protocol,
            0,
            src.packed,
            dst.packed,
        )
        head = head[:10] + struct.pack(">H", _checksum(head)) + head[12:]
        return head + payload
    return _IPV6.pack(6 << 28, len(payload), protocol, 64, src.packed, dst.packed) + payload


def _pseudo_header(src: Address, dst: Address, protocol: int, length: int) -> bytes:
    if src.version == 4:
        return src.packed + dst.packed + struct.pack(">BBH", 0, protocol, length)
    return src.packed + dst.packed + struct.pack(">IxxxB", length, protocol)


def tcp_segment(
    src: tuple[Address, int],
    dst: tuple[Address, int],
    seq: int,
    ack: int,
    flags: int,
    payload: bytes = b"",
) -> bytes:
    head = _TCP.pack(src[1], dst[1], seq & 0xFFFFFFFF, ack & 0xFFFFFFFF, 5 << 4, flags, 65535, 0, 0)
    check = _checksum(
        _pseudo_header(src[0], dst[0], TCP, len(head) + len(payload)) + head + payload
    )
    return ip_packet(
        src[0], dst[0], TCP, head[:16] + struct.pack(">H", check) + head[18:] + payload
    )


def udp_datagram(src: tuple[Address, int], dst: tuple[Address, int], payload: bytes) -> bytes:
    length = 8 + len(payload)
    head = _UDP.pack(src[1], dst[1], length, 0)
    check = _checksum(_pseudo_header(src[0], dst[0], UDP, length) + head + payload) or 0xFFFF
    return ip_packet(src[0], dst[0], UDP, head[:6] + struct.pack(">H", check) + payload)


@dataclass
class TcpFlow:
    """One TCP connection as packets: ``client`` and ``server`` are (IP, port)."""

    client: tuple[Address, int]
    server: tuple[Address, int]
    _seq: list[int] = field(default_factory=lambda: [1000, 5000])  # client's, server's

    def _ends(self, from_client: bool) -> tuple[tuple[Address, int], tuple[Address, int], int]:
        side = 0 if from_client else 1
        return (self.client, self.server, side) if from_client else (self.server, self.client, side)

    def handshake(self) -> list[bytes]:
        c, s = self.client, self.server
        cs, ss = self._seq
        packets = [
            tcp_segment(c, s, cs, 0, _TCP_SYN),
            tcp_segment(s, c, ss, cs + 1, _TCP_SYN | _TCP_ACK),
            tcp_segment(c, s, cs + 1, ss + 1, _TCP_ACK),
        ]
        self._seq = [cs + 1, ss + 1]
        return packets

    def data(self, from_client: bool, payload: bytes) -> list[bytes]:
        """``payload`` as it went one way, in segments of at most :data:`SEGMENT_MAX`."""
        src, dst, side = self._ends(from_client)
        packets = []
        for start in range(0, len(payload), SEGMENT_MAX):
            piece = payload[start : start + SEGMENT_MAX]
            seq, ack = self._seq[side], self._seq[1 - side]
            packets.append(tcp_segment(src, dst, seq, ack, _TCP_PSH | _TCP_ACK, piece))
            self._seq[side] = seq + len(piece)
        return packets

    def fin(self, from_client: bool) -> list[bytes]:
        src, dst, side = self._ends(from_client)
        seq, ack = self._seq[side], self._seq[1 - side]
        self._seq[side] = seq + 1
        return [tcp_segment(src, dst, seq, ack, _TCP_FIN | _TCP_ACK)]


# --- the writer ----------------------------------------------------------------------------


def partial_path(path: str | os.PathLike[str]) -> Path:
    """Where a recording of ``path`` is written until it ends (``NAME.part``)."""
    target = Path(path)
    return target.with_name(target.name + ".part")


class PcapngWriter:
    """A pcapng file being recorded: :meth:`write` one IP packet, flushed to the operating
    system at once; :meth:`close` renames ``NAME.part`` to ``NAME``. Thread-safe per call
    through the GIL-held single ``write`` of each block (one call per block)."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        comment: str,
        *,
        application: str = "python -m spec record",
        interface: str = "recorded",
    ) -> None:
        self.path = Path(path)
        self.partial = partial_path(self.path)
        self.packets = 0
        self._file: BinaryIO | None = open(self.partial, "wb")  # noqa: SIM115 (closed by close)
        self._file.write(section_header(comment, application))
        self._file.write(interface_description(LINKTYPE_RAW, interface))
        self._file.flush()

    def write(self, packet: bytes, timestamp_ns: int | None = None) -> None:
        if self._file is None:
            return  # closed: the recording is over
        stamp = time.time_ns() if timestamp_ns is None else timestamp_ns
        self._file.write(enhanced_packet(packet, stamp))
        self._file.flush()
        self.packets += 1

    def write_all(self, packets: Iterable[bytes], timestamp_ns: int | None = None) -> None:
        stamp = time.time_ns() if timestamp_ns is None else timestamp_ns
        for p in packets:
            self.write(p, stamp)

    @property
    def closed(self) -> bool:
        return self._file is None

    def close(self) -> None:
        """End the recording: ``NAME`` is now the whole file (an older ``NAME`` replaced in one
        step)."""
        f, self._file = self._file, None
        if f is None:
            return
        f.flush()
        os.fsync(f.fileno())
        f.close()
        os.replace(self.partial, self.path)

    def __enter__(self) -> PcapngWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- the reader ----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CapturedPacket:
    """One packet of a capture: its time (ns since the epoch), link type and bytes."""

    timestamp_ns: int
    linktype: int
    data: bytes


@dataclass
class Capture:
    """What a capture file holds: its section comments and packets."""

    comments: list[str]
    packets: list[CapturedPacket]
    truncated: bool = False  # the file ended inside a block (a killed recorder)


def _options_of(data: bytes, endian: str) -> list[tuple[int, bytes]]:
    out = []
    pos = 0
    while pos + 4 <= len(data):
        code, length = struct.unpack_from(endian + "HH", data, pos)
        if code == OPT_END:
            break
        out.append((code, data[pos + 4 : pos + 4 + length]))
        pos += 4 + length + (-length % 4)
    return out


def _tsresol(value: bytes) -> int:
    """Ticks per second of an if_tsresol option."""
    if not value:
        return 1_000_000
    v = value[0]
    return int(2 ** (v & 0x7F) if v & 0x80 else 10**v)


def read_capture(path: str | os.PathLike[str]) -> Capture:
    """Read a pcapng or pcap file; :class:`PcapError` names what is wrong with another file."""
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise PcapError(f"cannot read {path}: {exc.strerror}") from None
    if len(raw) >= 4 and struct.unpack_from("<I", raw)[0] == SHB_TYPE:
        return _read_pcapng(raw, path)
    if len(raw) >= 24 and raw[:4] in _PCAP_MAGICS:
        return _read_pcap(raw)
    raise PcapError(f"{path} is not a pcapng or pcap file")


_PCAP_MAGICS = {
    b"\xd4\xc3\xb2\xa1": ("<", 1_000_000),
    b"\xa1\xb2\xc3\xd4": (">", 1_000_000),
    b"\x4d\x3c\xb2\xa1": ("<", 1_000_000_000),
    b"\xa1\xb2\x3c\x4d": (">", 1_000_000_000),
}


def _read_pcap(raw: bytes) -> Capture:
    endian, per_second = _PCAP_MAGICS[raw[:4]]
    linktype = struct.unpack_from(endian + "I", raw, 20)[0] & 0x0FFFFFFF
    packets = []
    pos = 24
    truncated = False
    while pos < len(raw):
        if pos + 16 > len(raw):
            truncated = True
            break
        sec, frac, incl, _orig = struct.unpack_from(endian + "IIII", raw, pos)
        if pos + 16 + incl > len(raw):
            truncated = True
            break
        stamp = sec * 1_000_000_000 + frac * (1_000_000_000 // per_second)
        packets.append(CapturedPacket(stamp, linktype, raw[pos + 16 : pos + 16 + incl]))
        pos += 16 + incl
    return Capture([], packets, truncated)


def _read_pcapng(raw: bytes, path: str | os.PathLike[str]) -> Capture:
    comments: list[str] = []
    packets: list[CapturedPacket] = []
    interfaces: list[tuple[int, int]] = []  # (linktype, ticks per second) of the section
    endian = "<"
    pos = 0
    truncated = False
    while pos < len(raw):
        if pos + 12 > len(raw):
            truncated = True
            break
        block_type = struct.unpack_from(endian + "I", raw, pos)[0]
        if block_type == SHB_TYPE:
            magic = raw[pos + 8 : pos + 12]
            if magic == b"\x4d\x3c\x2b\x1a":
                endian = "<"
            elif magic == b"\x1a\x2b\x3c\x4d":
                endian = ">"
            else:
                raise PcapError(f"{path}: bad byte-order magic at byte {pos}")
            interfaces = []
        length = struct.unpack_from(endian + "I", raw, pos + 4)[0]
        if length < 12 or length % 4:
            raise PcapError(f"{path}: bad block length {length} at byte {pos}")
        if pos + length > len(raw):
            truncated = True
            break
        body = raw[pos + 8 : pos + length - 4]
        if block_type == SHB_TYPE:
            comments += [
                v.decode("utf-8", "replace")
                for c, v in _options_of(body[16:], endian)
                if c == OPT_COMMENT
            ]
        elif block_type == IDB_TYPE:
            linktype = struct.unpack_from(endian + "H", body)[0]
            opts = dict(_options_of(body[8:], endian))
            interfaces.append((linktype, _tsresol(opts.get(IF_TSRESOL, b""))))
        elif block_type == EPB_TYPE:
            iface, hi, lo, captured, _orig = struct.unpack_from(endian + "IIIII", body)
            if iface >= len(interfaces):
                raise PcapError(f"{path}: packet of undeclared interface {iface} at byte {pos}")
            linktype, per_second = interfaces[iface]
            ticks = (hi << 32) | lo
            stamp = ticks * 1_000_000_000 // per_second
            packets.append(CapturedPacket(stamp, linktype, body[20 : 20 + captured]))
        elif block_type == SPB_TYPE and interfaces:
            (orig,) = struct.unpack_from(endian + "I", body)
            linktype, _ = interfaces[0]
            packets.append(CapturedPacket(0, linktype, body[4 : 4 + orig]))
        pos += length
    return Capture(comments, packets, truncated)


# --- from link-layer packets back to TCP streams and UDP datagrams --------------------------


@dataclass(frozen=True, slots=True)
class IpPacket:
    src: Address
    dst: Address
    protocol: int
    payload: bytes


def ip_of_frame(linktype: int, data: bytes) -> IpPacket | None:
    """The IP packet in a link-layer frame (None for anything else: ARP, other link types)."""
    if linktype == LINKTYPE_ETHERNET:
        if len(data) < 14:
            return None
        ethertype = struct.unpack_from(">H", data, 12)[0]
        offset = 14
        if ethertype == 0x8100 and len(data) >= 18:  # one VLAN tag
            ethertype = struct.unpack_from(">H", data, 16)[0]
            offset = 18
        if ethertype not in (0x0800, 0x86DD):
            return None
        data = data[offset:]
    elif linktype == LINKTYPE_LINUX_SLL:
        data = data[16:]
    elif linktype == LINKTYPE_NULL:
        data = data[4:]
    elif linktype not in (LINKTYPE_RAW, LINKTYPE_IPV4, LINKTYPE_IPV6):
        return None
    if not data:
        return None
    version = data[0] >> 4
    if version == 4 and len(data) >= 20:
        ihl = (data[0] & 0x0F) * 4
        total = struct.unpack_from(">H", data, 2)[0]
        src4, dst4 = ipaddress.IPv4Address(data[12:16]), ipaddress.IPv4Address(data[16:20])
        return IpPacket(src4, dst4, data[9], data[ihl:total])
    if version == 6 and len(data) >= 40:
        length = struct.unpack_from(">H", data, 4)[0]
        src, dst = ipaddress.IPv6Address(data[8:24]), ipaddress.IPv6Address(data[24:40])
        return IpPacket(src, dst, data[6], data[40 : 40 + length])
    return None


Endpoint = tuple[Address, int]


@dataclass
class TcpStream:
    """The bytes of one TCP connection, per direction, with the time each piece came."""

    a: Endpoint  # the side that sent the SYN (or the first segment seen)
    b: Endpoint
    #: (timestamp_ns, from_a, bytes) in capture order, retransmissions dropped.
    chunks: list[tuple[int, bool, bytes]] = field(default_factory=list)
    _next: dict[bool, int] = field(default_factory=dict)

    def add(self, stamp: int, from_a: bool, seq: int, syn: bool, fin: bool, data: bytes) -> None:
        if syn:
            self._next[from_a] = (seq + 1) & 0xFFFFFFFF
            return
        expected = self._next.get(from_a)
        if expected is None:
            expected = seq  # joined mid-connection
        skip = (expected - seq) & 0xFFFFFFFF
        if skip < 0x80000000:  # an old (retransmitted) start: drop what we have
            data = data[skip:]
        else:
            expected = seq  # a gap (bytes not captured): carry on from here
        if data:
            self.chunks.append((stamp, from_a, data))
        self._next[from_a] = (expected + len(data) + (1 if fin else 0)) & 0xFFFFFFFF

    def bytes_from(self, from_a: bool) -> bytes:
        return b"".join(d for _, side, d in self.chunks if side == from_a)


@dataclass(frozen=True, slots=True)
class UdpDatagram:
    timestamp_ns: int
    src: Endpoint
    dst: Endpoint
    payload: bytes


def sessions(capture: Capture) -> tuple[list[TcpStream], list[UdpDatagram]]:
    """The TCP connections (in order of their first packet) and UDP datagrams of a capture."""
    streams: dict[tuple[Endpoint, Endpoint], TcpStream] = {}
    ordered: list[TcpStream] = []
    datagrams: list[UdpDatagram] = []
    for p in capture.packets:
        ip = ip_of_frame(p.linktype, p.data)
        if ip is None:
            continue
        if ip.protocol == TCP and len(ip.payload) >= 20:
            sport, dport, seq, _ack, offset, flags = struct.unpack_from(">HHIIBB", ip.payload)
            src, dst = (ip.src, sport), (ip.dst, dport)
            stream = streams.get((src, dst)) or streams.get((dst, src))
            if stream is None or (flags & _TCP_SYN and not flags & _TCP_ACK and stream.chunks):
                stream = TcpStream(src, dst)
                streams[(src, dst)] = stream
                ordered.append(stream)
            payload = ip.payload[(offset >> 4) * 4 :]
            stream.add(
                p.timestamp_ns,
                src == stream.a,
                seq,
                bool(flags & _TCP_SYN),
                bool(flags & _TCP_FIN),
                payload,
            )
        elif ip.protocol == UDP and len(ip.payload) >= 8:
            sport, dport, length, _ = _UDP.unpack_from(ip.payload)
            datagrams.append(
                UdpDatagram(p.timestamp_ns, (ip.src, sport), (ip.dst, dport), ip.payload[8:length])
            )
    return ordered, datagrams


def iter_packets(path: str | os.PathLike[str]) -> Iterator[CapturedPacket]:
    yield from read_capture(path).packets


__all__ = [
    "Capture",
    "CapturedPacket",
    "PcapError",
    "PcapngWriter",
    "TcpFlow",
    "TcpStream",
    "UdpDatagram",
    "ip_of",
    "partial_path",
    "read_capture",
    "same_family",
    "sessions",
    "udp_datagram",
]
