"""Sans-I/O frame codec: packets to bytes and bytes (as they arrive) back to packets.

No socket, thread or clock here (STYLE.md practice 1). :func:`encode_packet` produces one
frame; :class:`FrameDecoder` takes bytes in any split or coalesced pieces with
:meth:`FrameDecoder.feed` and yields :class:`Packet` or :class:`Rejected` events.

A rejection is *recoverable* when the header could be read and the frame's end is known (the
receiver answers with an error packet and goes on with the next frame) and *fatal* when not
(the decoder raises; the receiver answers with a request-ID-0 error packet and closes)
[RS-3.8], [RS-3.9].
"""

from __future__ import annotations

import functools
import struct
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import NamedTuple, NoReturn, cast

from spec import wire
from spec.crc import crc32, crc32_combine
from spec.errors import (
    BadCrcError,
    ErrorCode,
    FrameError,
    FrameTooLargeError,
    PeerError,
    ProtocolError,
    UsageError,
    VersionError,
)
from spec.params import Joints, Value, decode_params, encode_params_parts
from spec.wire import PacketKind, ParamType


class Packet(NamedTuple):
    """One decoded frame (PROTOCOL.md section 3). A named tuple: one is built per frame."""

    kind: PacketKind
    command: int
    request_id: int
    params: tuple[Value, ...] = ()
    version_minor: int = wire.VERSION_MINOR

    @property
    def error(self) -> tuple[int, str] | None:
        """(code, message) of an error packet, ``None`` for other kinds."""
        if self.kind is not PacketKind.ERROR:
            return None
        code = self.params[0] if self.params and isinstance(self.params[0], int) else 0
        text = self.params[1] if len(self.params) > 1 and isinstance(self.params[1], str) else ""
        return int(code), text


#: ``Packet`` from its five fields in a tuple, without the named tuple's generated
#: ``__new__`` (a Python frame per packet): for the paths that build one per frame.
packet_of = cast(
    "Callable[[tuple[PacketKind, int, int, tuple[Value, ...], int]], Packet]",
    functools.partial(tuple.__new__, Packet),
)


def request(command: int, request_id: int, *params: Value) -> Packet:
    return Packet(PacketKind.REQUEST, command, request_id, tuple(params))


def reply_to(req: Packet, *params: Value) -> Packet:
    """The reply packet for ``req``: same command ID, echoed request ID [RS-3.4]."""
    return Packet(PacketKind.REPLY, req.command, req.request_id, tuple(params))


def error_packet(command: int, request_id: int, code: ErrorCode | int, message: str) -> Packet:
    """An error packet: parameters (INT code, STRING message) [RS-6.1]."""
    return Packet(PacketKind.ERROR, command, request_id, (int(code), message))


class PreparedParams(tuple[Value, ...]):
    """A parameter list encoded once, for a reply that is sent again unchanged: GetImage
    between two acquisitions sends the same 128 KiB frame, so its payload pieces and their
    CRC-32 are made once (:func:`prepare_params`) and each frame that carries them adds only
    its header and the CRC of that header combined with the payload's [RS-3.6]. It is a
    tuple of the values, so it reads as the parameter list it is everywhere else."""

    #: (payload pieces, payload length, CRC-32 of the payload).
    encoded: tuple[tuple[bytes, ...], int, int]


def prepare_params(params: tuple[Value, ...]) -> PreparedParams:
    """Encode ``params`` once for many frames; the values are immutable, so the encoding
    stays theirs. Small pieces are joined, large ones (pixels) kept as they are, not copied."""
    pieces: list[bytes] = []
    small: list[bytes] = []
    for part in encode_params_parts(params):
        if len(part) < _ONE_PIECE_MAX:
            small.append(part)
            continue
        if small:
            pieces.append(b"".join(small))
            small = []
        pieces.append(part)
    if small:
        pieces.append(b"".join(small))
    length = sum(map(len, pieces))
    if length > wire.MAX_PAYLOAD:
        raise UsageError(f"payload of {length} bytes exceeds the maximum of {wire.MAX_PAYLOAD}")
    payload_crc = 0
    for piece in pieces:
        payload_crc = crc32(piece, payload_crc)
    prepared = PreparedParams(params)
    prepared.encoded = (tuple(pieces), length, payload_crc)
    return prepared


def encode_packet_parts(
    packet: Packet, max_payload: int = wire.MAX_PAYLOAD, *, crc: bool = True
) -> list[bytes]:
    """One frame as a list of byte strings, so a large payload (an image) is never copied to
    build the frame: send it with ``sendmsg``. A small frame (under ``_ONE_PIECE_MAX``
    bytes of payload) comes as one piece, ready for ``sendall``.

    ``crc=False`` sends the frame with the NO_CRC flag and a zero trailer, on a connection
    where the client turned CRCs off (SetFrameCrc, [RS-3.16])."""
    kind, command, request_id, params, minor = packet
    prepared = type(params) is PreparedParams
    if prepared:
        pieces, length, payload_crc = cast(PreparedParams, params).encoded
        parts = list(pieces)
    else:
        parts = encode_params_parts(params)
        length = sum(map(len, parts))
    if length > max_payload:
        raise UsageError(f"payload of {length} bytes exceeds the maximum of {max_payload}")
    flags = 0 if crc else wire.FLAG_NO_CRC
    try:
        header = _HEADER_PACK(_MAGIC, _MAJOR, minor, kind, flags, command, request_id, length)
    except struct.error:  # the field ranges are checked here, off the path of a good packet
        if not 0 <= command <= 0xFFFF:
            raise UsageError(f"command ID {command} does not fit in 16 bits") from None
        if not 0 <= request_id <= 0xFFFFFFFF:
            raise UsageError(f"request ID {request_id} does not fit in 32 bits") from None
        raise
    if prepared:
        # The payload's CRC was computed once: only the 16 header bytes are scanned here.
        trailer = _TRAILER_PACK(crc32_combine(crc32(header), payload_crc, length))
        return [header, *parts, trailer if crc else _NO_CRC_TRAILER]
    if length < _ONE_PIECE_MAX:
        body = header + b"".join(parts)
        return [body + (_TRAILER_PACK(crc32(body)) if crc else _NO_CRC_TRAILER)]
    parts.insert(0, header)
    if crc:
        frame_crc = 0
        for part in parts:
            frame_crc = crc32(part, frame_crc)
        parts.append(_TRAILER_PACK(frame_crc))
    else:
        parts.append(_NO_CRC_TRAILER)
    return parts


#: A payload shorter than this is encoded as one piece; longer ones keep their large parts.
_ONE_PIECE_MAX = 16 * 1024
_HEADER_PACK = wire.HEADER.pack
_TRAILER_PACK = wire.TRAILER.pack
_NO_CRC_TRAILER = wire.TRAILER.pack(0)


def encode_packet(
    packet: Packet, max_payload: int = wire.MAX_PAYLOAD, *, crc: bool = True
) -> bytes:
    """Encode one frame: header, parameter list, CRC-32 [RS-3.1], [RS-3.6]."""
    return b"".join(encode_packet_parts(packet, max_payload, crc=crc))


def encode_request(
    command: int, request_id: int, params: tuple[Value, ...] = (), minor: int = wire.VERSION_MINOR
) -> bytes:
    """``encode_packet(request(command, request_id, *params))``, made for a client's every call:
    a request without parameters (Herej, GetData, GetImage of the whole sensor) is its
    command's header template with the request ID put in, and its CRC-32 [RS-3.6]."""
    if params:
        return encode_packet(packet_of((PacketKind.REQUEST, command, request_id, params, minor)))
    try:
        body = _EMPTY_REQUEST_PACK(_request_head(command, minor), request_id, 2, 0)
    except struct.error:
        raise UsageError(f"request ID {request_id} does not fit in 32 bits") from None
    return body + _TRAILER_PACK(crc32(body))


@functools.cache
def _request_head(command: int, minor: int) -> bytes:
    """The first 8 header bytes (magic to command ID) of every request of ``command``."""
    if not 0 <= command <= 0xFFFF:
        raise UsageError(f"command ID {command} does not fit in 16 bits")
    return _frame_head(PacketKind.REQUEST, 0, command, minor)


@functools.cache
def _frame_head(kind: PacketKind, flags: int, command: int, minor: int) -> bytes:
    """The header bytes before the request ID (magic to command ID), the same in every frame
    of this kind, flags, command and version: the templates of :func:`encode_request` and
    :func:`encode_reply`. struct.error for a command out of range."""
    return _HEADER_PACK(_MAGIC, _MAJOR, minor, kind, flags, command, 0, 0)[:_REQUEST_ID_AT]


_REQUEST_ID_AT = 8  # offset of the request ID in the header (wire.HEADER)
#: Header template, request ID, payload length 2, parameter count 0: a request without
#: parameters, up to its CRC.
_EMPTY_REQUEST_PACK = struct.Struct(">8sIIH").pack


def encode_reply(
    command: int, request_id: int, params: tuple[Value, ...], crc: bool = True
) -> list[bytes]:
    """``encode_packet_parts(reply)``, made for a server's every reply: a reply of one
    :class:`Joints` (Herej, the call a tracking loop makes most) is packed by one struct
    call onto its command's header template, and its CRC-32 added [RS-3.6]."""
    if len(params) == 1 and type(params[0]) is Joints:
        values = params[0].values
        try:
            head, rest, pack = _joints_reply(command, len(values), crc)
            body = pack(head, request_id, rest, *values)
        except struct.error:
            pass  # an ID out of range: the general encoder below says which
        else:
            return [body + (_TRAILER_PACK(crc32(body)) if crc else _NO_CRC_TRAILER)]
    reply = packet_of((PacketKind.REPLY, command, request_id, params, wire.VERSION_MINOR))
    return encode_packet_parts(reply, wire.MAX_PAYLOAD, crc=crc)


@functools.cache
def _joints_reply(command: int, n: int, crc: bool) -> tuple[bytes, bytes, Callable[..., bytes]]:
    """The frame of a reply of ``command`` carrying one Joints of ``n`` values, up to its CRC:
    (the header up to the request ID, the 8 bytes after it, the packer of the whole)."""
    head = _frame_head(
        PacketKind.REPLY, 0 if crc else wire.FLAG_NO_CRC, command, wire.VERSION_MINOR
    )
    length = 4 + 8 * n  # count, JOINTS tag, n, n float64
    rest = _JOINTS_HEAD_PACK(length, 1, ParamType.JOINTS, n)
    pack = struct.Struct(f">{_REQUEST_ID_AT}sI8s{n}d").pack
    return head, rest, pack


#: After the request ID: payload length, parameter count, JOINTS tag, value count.
_JOINTS_HEAD_PACK = struct.Struct(">IHBB").pack


class Header(NamedTuple):
    """The fixed 16-byte frame header, decoded without judging it."""

    magic: bytes
    version_major: int
    version_minor: int
    kind: int
    flags: int
    command: int
    request_id: int
    length: int

    @classmethod
    def unpack(cls, data: bytes | bytearray | memoryview, offset: int = 0) -> Header:
        return cls._make(wire.HEADER.unpack_from(data, offset))


@dataclass(frozen=True, slots=True)
class Rejected:
    """A delimited frame that was rejected; answer with an error packet and go on."""

    header: Header
    error: PeerError

    @property
    def code(self) -> ErrorCode:
        return self.error.code


Event = Packet | Rejected


#: Frames at least this long are received in place (get_buffer) instead of chunk by chunk.
LARGE_FRAME = 64 * 1024
#: The largest frame buffer a decoder keeps for the next large frame.
_SPARE_MAX = wire.DEFAULT_MAX_PAYLOAD + wire.FRAME_OVERHEAD


@dataclass
class FrameDecoder:
    """Incremental decoder: feed bytes, iterate events; raises only :class:`PeerError`.

    ``max_payload`` is this receiver's limit (at most :data:`wire.MAX_PAYLOAD`) [RS-3.5].
    ``kinds`` are the packet kinds this receiver accepts (a server takes requests only).
    ``accept_no_crc`` is set by a client that turned CRCs off on its connection: frames with
    the NO_CRC flag are then accepted without a CRC check [RS-3.17].

    Bytes arrive either through :meth:`feed` or, for the rest of a large frame, straight into
    the frame's own buffer: :meth:`get_buffer` and :meth:`buffer_updated` (the pattern of
    ``asyncio.BufferedProtocol``) let a socket ``recv_into`` it without intermediate copies.
    """

    max_payload: int = wire.DEFAULT_MAX_PAYLOAD
    kinds: frozenset[PacketKind] = frozenset(PacketKind)
    accept_no_crc: bool = False
    # Received bytes as a queue of chunks: a large frame arriving in many pieces is joined
    # once when complete (no growing buffer, no quadratic copying); ``_offset`` is where the
    # unread part of the first chunk starts.
    _chunks: deque[bytes | memoryview] = field(default_factory=deque, repr=False)
    _borrowed: bool = field(default=False, repr=False)
    _offset: int = field(default=0, repr=False)
    _size: int = field(default=0, repr=False)
    _failed: PeerError | None = field(default=None, repr=False)
    # A large frame being received in place: its buffer, bytes filled, and its header.
    _frame: memoryview | None = field(default=None, repr=False)
    _spare: bytearray = field(default_factory=bytearray, repr=False)
    _filled: int = field(default=0, repr=False)
    _frame_header: Header | None = field(default=None, repr=False)

    def feed(self, data: bytes | bytearray | memoryview, *, borrow: bool = False) -> None:
        """Queue received bytes. ``borrow``: ``data`` is a view of the caller's receive buffer,
        queued without a copy; the caller calls :meth:`keep` before it writes there again
        (decoded values never refer to it: they are copies)."""
        if self._failed is not None:
            raise self._failed
        if not data:
            return
        if self._frame is not None and self._filled < len(self._frame):
            # The rest of a large frame: into its buffer; what follows it, to the queue.
            take = min(len(data), len(self._frame) - self._filled)
            self._frame[self._filled : self._filled + take] = data[:take]
            self._filled += take
            data = data[take:]
            if not data:
                return
        if borrow and type(data) is memoryview:
            self._borrowed = True
            chunk: bytes | memoryview = data
        else:
            chunk = data if isinstance(data, bytes) else bytes(data)
        self._chunks.append(chunk)
        self._size += len(chunk)

    def feed_next(self, data: memoryview) -> Event | None:
        """:meth:`feed` (``borrow=True``) then :meth:`next_event`, for a receive buffer's view.
        The usual receive, exactly one whole small frame while nothing is buffered, is
        decoded straight from ``data``, without queueing it."""
        n = len(data)
        if (
            self._size == 0
            and self._frame is None
            and self._failed is None
            and _HEADER_SIZE <= n < LARGE_FRAME
        ):
            header = _HEADER_UNPACK(data, 0)
            length = header[7]
            if header[0] == _MAGIC and length <= self.max_payload and _FRAME_OVERHEAD + length == n:
                return self._decode(header, data)
        self.feed(data, borrow=True)
        return self.next_event()

    def keep(self) -> None:
        """Copy the unread bytes of borrowed views (:meth:`feed`) into bytes of our own."""
        if self._borrowed:
            chunks = self._chunks
            if chunks:
                first = bytes(chunks[0][self._offset :])
                self._chunks = deque([first, *(bytes(c) for c in list(chunks)[1:])])
                self._offset = 0
            self._borrowed = False

    def get_buffer(self) -> memoryview | None:
        """Where the next bytes of a large frame go (``sock.recv_into``), or None when bytes
        should come through :meth:`feed` (no large frame has started)."""
        if self._failed is not None:
            raise self._failed
        if self._frame is not None and self._filled >= len(self._frame):
            return None  # complete: next_event takes it
        if self._frame is None:
            if self._size < wire.HEADER_SIZE:
                return None
            first = self._contiguous(wire.HEADER_SIZE)
            header = Header.unpack(first, self._offset)
            end = wire.HEADER_SIZE + header.length + wire.TRAILER_SIZE
            if (
                end < LARGE_FRAME
                or self._size >= end
                or header.magic != wire.MAGIC
                or header.length > self.max_payload
            ):
                return None  # small, complete or bad: next_event handles it
            # Everything buffered belongs to this unfinished frame: move it into place.
            # A 128 KiB image every call: reuse one buffer (the decoded values are copies, so
            # nothing refers to it after a frame), sparing an allocation and page faults.
            if len(self._spare) < end:
                self._spare = bytearray(end) if end <= _SPARE_MAX else bytearray()
            frame = memoryview(self._spare)[:end] if self._spare else memoryview(bytearray(end))
            pos = 0
            for i, chunk in enumerate(self._chunks):
                piece = memoryview(chunk)[self._offset :] if i == 0 else chunk
                frame[pos : pos + len(piece)] = piece
                pos += len(piece)
            self._chunks.clear()
            self._offset = self._size = 0
            self._frame, self._filled, self._frame_header = frame, pos, header
        return self._frame[self._filled :]

    def buffer_updated(self, n: int) -> None:
        """``n`` bytes were written at the start of the last :meth:`get_buffer` view."""
        self._filled += n

    @property
    def buffered(self) -> int:
        """Bytes received but not yet part of a complete frame."""
        return self._size + self._filled

    @property
    def in_frame(self) -> bool:
        """True when a frame has started but not finished (for partial-frame timeouts)."""
        return self._size > 0 or self._frame is not None

    def events(self) -> Iterator[Event]:
        """Yield every complete frame in the buffer; stop when more data is needed."""
        while True:
            event = self.next_event()
            if event is None:
                return
            yield event

    def _contiguous(self, n: int) -> bytes | memoryview:
        """The first chunk, merged with the following ones until it holds ``n`` unread bytes
        (the caller checked ``_size >= n``)."""
        first = self._chunks[0]
        if len(first) - self._offset < n:
            parts = [first[self._offset :], *list(self._chunks)[1:]]
            first = b"".join(parts)
            self._chunks = deque([first])
            self._offset = 0
        return first

    def next_event(self) -> Event | None:
        """The next complete event, or ``None`` when more data is needed."""
        if self._failed is not None:
            raise self._failed
        if self._frame is not None:
            return self._large_frame_event()
        size = self._size
        if size < _HEADER_SIZE:
            if size >= 2:
                self._check_magic(self._contiguous(2), self._offset)
            return None
        data, off = self._chunks[0], self._offset
        if len(data) - off < _HEADER_SIZE:
            data, off = self._contiguous(_HEADER_SIZE), 0
        header = _HEADER_UNPACK(data, off)
        if header[0] != _MAGIC:
            self._check_magic(data, off)
        length = header[7]
        if length > self.max_payload:
            # [RS-3.5] never buffer an oversized frame: reject before reading it.
            self._fail(
                FrameTooLargeError(
                    f"payload length {length} exceeds the maximum {self.max_payload}"
                ),
            )
        end = _FRAME_OVERHEAD + length
        if size < end:
            return None
        if len(data) - off < end:
            data, off = self._contiguous(end), 0
        self._size = size - end
        if off + end == len(data):
            self._chunks.popleft()
            self._offset = 0
        else:
            self._offset = off + end
        return self._decode(header, memoryview(data)[off : off + end])

    def _check_magic(self, data: bytes | memoryview, off: int) -> None:
        if data[off : off + 2] != wire.MAGIC:
            # [RS-3.8] unusable header: the frame boundary is lost, the connection ends.
            self._fail(FrameError(f"bad magic {data[off : off + 2].hex()}, expected 5253"))

    def _large_frame_event(self) -> Event | None:
        assert self._frame is not None and self._frame_header is not None
        if self._filled < len(self._frame):
            return None
        frame, header = self._frame, self._frame_header
        self._frame, self._filled, self._frame_header = None, 0, None
        return self._decode(header, frame)

    def _decode(
        self, header: tuple[bytes, int, int, int, int, int, int, int], frame: memoryview
    ) -> Event:
        try:
            return _decode_frame(header, frame, self.kinds, self.accept_no_crc)
        except PeerError as exc:
            return Rejected(Header._make(header), exc)

    def _fail(self, error: PeerError) -> NoReturn:
        self._failed = error
        self._chunks.clear()
        self._offset = self._size = self._filled = 0
        self._frame = self._frame_header = None
        raise error


_KINDS = {int(k): k for k in PacketKind}
_ALL_KINDS = frozenset(PacketKind)


def _decode_frame(
    header: tuple[bytes, int, int, int, int, int, int, int],
    frame: memoryview,
    kinds: frozenset[PacketKind],
    accept_no_crc: bool = False,
) -> Packet:
    """Check and decode one delimited frame; ``header`` is its unpacked :data:`wire.HEADER`
    (a plain tuple or a :class:`Header`)."""
    _, major, minor, kind_byte, flags, command, request_id, length = header
    payload_end = _HEADER_SIZE + length
    no_crc = accept_no_crc and flags == wire.FLAG_NO_CRC
    if not no_crc:
        (crc,) = _TRAILER_UNPACK(frame, payload_end)
        if crc32(frame[:payload_end]) != crc:
            raise BadCrcError(f"CRC-32 mismatch (frame says {crc:08x})")
    if major != _MAJOR:
        raise VersionError(
            f"protocol version {major}.{minor} not supported; this peer speaks {wire.VERSION}"
        )
    kind = _KINDS.get(kind_byte)
    if kind is None:
        raise FrameError(f"unknown packet kind {kind_byte}")
    if kind not in kinds:
        raise FrameError(f"packet kind {kind.name} not accepted here")
    if flags and not no_crc:
        raise FrameError(f"reserved flags must be 0, got 0x{flags:02x}")
    if length == 2 and frame[payload_end - 1] == 0 == frame[_HEADER_SIZE]:
        params: tuple[Value, ...] = ()  # a parameter count of 0 (Herej, GetData): no decoder
    else:
        params = decode_params(frame[_HEADER_SIZE:payload_end])
    return packet_of((kind, command, request_id, params, minor))


_HEADER_UNPACK = wire.HEADER.unpack_from
_TRAILER_UNPACK = wire.TRAILER.unpack_from
# Module constants: read on every frame, a global is cheaper than a module attribute.
_MAGIC = wire.MAGIC
_HEADER_SIZE = wire.HEADER_SIZE
_FRAME_OVERHEAD = wire.FRAME_OVERHEAD
_MAJOR = wire.VERSION_MAJOR


def decode_packet(data: bytes, max_payload: int = wire.MAX_PAYLOAD) -> Packet:
    """Decode exactly one complete frame; raise :class:`PeerError` on anything else."""
    header = Header.unpack(data) if len(data) >= wire.HEADER_SIZE else None
    if (
        header is not None
        and header.magic == wire.MAGIC
        and len(data) == wire.FRAME_OVERHEAD + header.length
        and header.length <= max_payload
    ):
        # Fast path for exactly one frame: no buffering copy.
        return _decode_frame(header, memoryview(data), _ALL_KINDS)
    decoder = FrameDecoder(max_payload=max_payload)
    decoder.feed(data)
    event = decoder.next_event()
    if event is None:
        need = wire.HEADER_SIZE if header is None else wire.FRAME_OVERHEAD + header.length
        raise FrameError(f"truncated frame: {len(data)} of {need} bytes", ErrorCode.BAD_FRAME)
    if isinstance(event, Rejected):
        raise event.error
    if decoder.buffered:
        raise FrameError(f"{decoder.buffered} bytes after the end of the frame")
    return event


__all__ = [
    "Event",
    "FrameDecoder",
    "Header",
    "Packet",
    "PreparedParams",
    "ProtocolError",
    "Rejected",
    "decode_packet",
    "encode_packet",
    "encode_packet_parts",
    "encode_reply",
    "encode_request",
    "error_packet",
    "packet_of",
    "prepare_params",
    "reply_to",
    "request",
]
