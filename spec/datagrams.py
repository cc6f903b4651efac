"""Sans-I/O codec of the UDP synchronisation datagrams (PROTOCOL.md section 9).

Trigger: robot -> sensor, index i and send time t_i^T. Data: sensor -> robot, the same index,
a status, the seam location ^S_G T, a quality figure and the sensor's own timestamps. A bad
datagram raises :class:`DatagramError`; receivers count it and drop it [SY-1.4].
"""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass

from spec import wire
from spec.errors import DatagramError, UsageError
from spec.wire import DatagramKind, SensorStatus

#: Trigger indices are u32 and wrap from 2^32 - 1 to 0 [SY-1.3].
INDEX_MODULUS = 1 << 32
_HALF_MODULUS = INDEX_MODULUS // 2


def serial_diff(a: int, b: int) -> int:
    """Signed distance from index ``b`` to index ``a`` in serial-number arithmetic
    (RFC 1982) [SY-1.3]: ``(a - b) mod 2^32`` read in [-2^31, 2^31), so the index after
    2^32 - 1 is 0 and ``serial_diff(0, 2**32 - 1) == 1``."""
    d = (a - b) % INDEX_MODULUS
    return d - INDEX_MODULUS if d >= _HALF_MODULUS else d


def serial_newer(a: int, b: int) -> bool:
    """True when index ``a`` is after ``b`` in serial-number arithmetic (RFC 1982) [SY-1.3]."""
    return serial_diff(a, b) > 0


# Whole-datagram layouts for the per-trigger hot path of the sensor (one unpack per trigger,
# one pack per reply), concatenated from the layouts of wire.py so they cannot drift apart.
#: Trigger datagram: header, t_i^T, CRC-32 [SY-1.1] [SY-2.1].
TRIGGER_DATAGRAM = struct.Struct(
    wire.DATAGRAM_HEADER.format + wire.TRIGGER_BODY.format[1:] + wire.TRAILER.format[1:]
)
#: Data datagram without its CRC-32 trailer: header and body [SY-1.1] [SY-3.1].
DATA_DATAGRAM_BODY = struct.Struct(wire.DATAGRAM_HEADER.format + wire.DATA_BODY.format[1:])

_MAGIC = wire.DATAGRAM_MAGIC
_MAJOR = wire.VERSION_MAJOR
_MINOR = wire.VERSION_MINOR
_KIND_TRIGGER = int(DatagramKind.TRIGGER)
_KIND_DATA = int(DatagramKind.DATA)
_TRIGGER_SIZE = wire.TRIGGER_SIZE
_CRC_END = -wire.TRAILER_SIZE
_crc32 = zlib.crc32
_isfinite = math.isfinite
_unpack_trigger = TRIGGER_DATAGRAM.unpack
_pack_data = DATA_DATAGRAM_BODY.pack
_pack_crc = wire.TRAILER.pack


@dataclass(frozen=True, slots=True)
class Trigger:
    """Trigger datagram: start one acquisition [SY-2.1]."""

    index: int
    t_trigger: float  # robot clock, s


@dataclass(frozen=True, slots=True)
class SensorData:
    """Data datagram: the measurement of the acquisition started by trigger ``index``."""

    index: int
    status: SensorStatus
    seam: tuple[float, float, float, float, float, float]  # ^S_G T as a VAL3 location
    quality: float
    t_trigger: float  # t_i^T echoed from the trigger, robot clock, s
    t_arrival: float  # sensor clock, s
    t_exposure_start: float  # sensor clock, s
    t_exposure_end: float  # sensor clock, s


Datagram = Trigger | SensorData


def _header(kind: DatagramKind, index: int) -> bytes:
    if not 0 <= index < INDEX_MODULUS:
        raise UsageError(f"datagram index {index} does not fit in 32 bits")
    return wire.DATAGRAM_HEADER.pack(
        wire.DATAGRAM_MAGIC, wire.VERSION_MAJOR, wire.VERSION_MINOR, int(kind), 0, index
    )


def _seal(body: bytes) -> bytes:
    return body + wire.TRAILER.pack(zlib.crc32(body))


def encode_trigger(trigger: Trigger) -> bytes:
    return _seal(
        _header(DatagramKind.TRIGGER, trigger.index) + wire.TRIGGER_BODY.pack(trigger.t_trigger)
    )


def encode_data(data: SensorData) -> bytes:
    return encode_data_fields(
        data.index,
        data.status,
        data.seam,
        data.quality,
        data.t_trigger,
        data.t_arrival,
        data.t_exposure_start,
        data.t_exposure_end,
    )


def encode_data_fields(
    index: int,
    status: SensorStatus,
    seam: tuple[float, ...],
    quality: float,
    t_trigger: float,
    t_arrival: float,
    t_exposure_start: float,
    t_exposure_end: float,
) -> bytes:
    """The data datagram of :class:`SensorData` with these fields, without building one
    (the sensor's per-trigger path): one pack of header and body, then the CRC-32."""
    try:
        body = _pack_data(
            _MAGIC, _MAJOR, _MINOR, _KIND_DATA, 0, index, status, 0, *seam,
            quality, t_trigger, t_arrival, t_exposure_start, t_exposure_end,
        )  # fmt: skip
    except struct.error:
        # The checks are here, off the hot path: struct rejected one of the fields.
        if len(seam) != 6:
            raise UsageError("seam must be a 6-value VAL3 location") from None
        if not 0 <= index < INDEX_MODULUS:
            raise UsageError(f"datagram index {index} does not fit in 32 bits") from None
        raise UsageError(f"unencodable data datagram fields (status {status!r})") from None
    return body + _pack_crc(_crc32(body))


def encode_datagram(datagram: Datagram) -> bytes:
    if isinstance(datagram, Trigger):
        return encode_trigger(datagram)
    return encode_data(datagram)


def trigger_fields(raw: bytes) -> tuple[int, float] | None:
    """``(index, t_i^T)`` of a well-formed trigger datagram; None for anything else, which
    :func:`decode_datagram` then decodes or rejects with the reason.

    The same checks as :func:`decode_datagram` with one unpack and no allocation beyond the
    result: the sensor runs this once per trigger.
    """
    if len(raw) != _TRIGGER_SIZE:
        return None
    magic, major, _minor, kind, flags, index, t_trigger, crc = _unpack_trigger(raw)
    if (
        magic != _MAGIC
        or major != _MAJOR
        or kind != _KIND_TRIGGER
        or flags
        or not _isfinite(t_trigger)
        or _crc32(raw[:_CRC_END]) != crc
    ):
        return None
    return index, t_trigger


def decode_datagram(raw: bytes | bytearray | memoryview) -> Datagram:
    """Decode one datagram; raise :class:`DatagramError` for anything malformed."""
    buf = bytes(raw)
    trigger = trigger_fields(buf)
    if trigger is not None:
        return Trigger(*trigger)
    head = wire.DATAGRAM_HEADER.size
    if len(buf) < head + wire.TRAILER_SIZE:
        raise DatagramError(f"datagram of {len(buf)} bytes is shorter than a header")
    magic, major, _minor, kind, flags, index = wire.DATAGRAM_HEADER.unpack_from(buf, 0)
    if magic != wire.DATAGRAM_MAGIC:
        raise DatagramError(f"bad datagram magic {magic.hex()}, expected 5359")
    (crc,) = wire.TRAILER.unpack_from(buf, len(buf) - wire.TRAILER_SIZE)
    if zlib.crc32(buf[: -wire.TRAILER_SIZE]) != crc:
        raise DatagramError("datagram CRC-32 mismatch")
    if major != wire.VERSION_MAJOR:
        raise DatagramError(f"datagram version {major} not supported")
    if flags != 0:
        raise DatagramError(f"reserved datagram flags must be 0, got 0x{flags:02x}")
    if kind == DatagramKind.TRIGGER:
        if len(buf) != wire.TRIGGER_SIZE:
            raise DatagramError(f"trigger datagram must be {wire.TRIGGER_SIZE} bytes")
        (t_trigger,) = wire.TRIGGER_BODY.unpack_from(buf, head)
        if not math.isfinite(t_trigger):
            raise DatagramError("trigger time must be finite")
        return Trigger(index, t_trigger)
    if kind == DatagramKind.DATA:
        if len(buf) != wire.DATA_SIZE:
            raise DatagramError(f"data datagram must be {wire.DATA_SIZE} bytes")
        fields = wire.DATA_BODY.unpack_from(buf, head)
        try:
            status = SensorStatus(fields[0])
        except ValueError:
            raise DatagramError(f"unknown sensor status {fields[0]}") from None
        seam = fields[2:8]
        t_arr, t_start, t_end = fields[10:13]
        if not all(math.isfinite(v) for v in (fields[9], t_arr, t_start, t_end)):
            raise DatagramError("datagram timestamps must be finite")
        if status is SensorStatus.FOUND and not all(math.isfinite(v) for v in seam):
            raise DatagramError("a FOUND seam location must be finite")
        return SensorData(index, status, seam, fields[8], fields[9], t_arr, t_start, t_end)
    raise DatagramError(f"unknown datagram kind {kind}")
