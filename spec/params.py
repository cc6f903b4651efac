"""The typed, self-describing parameter list (PROTOCOL.md section 4).

A parameter list is a count followed by tagged values. Python values map to wire types as:

========================  =============  ==============================================
Python value              wire type      notes
========================  =============  ==============================================
``int`` (not bool)        INT            signed 64-bit
``float``                 FLOAT          IEEE 754 binary64
``bool``                  BOOL           one byte, 0 or 1
``str``                   STRING         UTF-8, u32 byte length
``bytes``                 BYTES          u32 length
:class:`FloatArray`       FLOAT_ARRAY    u32 count + f64 each
:class:`IntArray`         INT_ARRAY      u32 count + i64 each
:class:`Joints`           JOINTS         u8 count (1..16) + f64 each, degrees
:class:`Location`         LOCATION       x, y, z (mm), rx, ry, rz (degrees)
:class:`Transform`        TRANSFORM      4x4 row-major f64, last row 0 0 0 1
:class:`Matrix`           MATRIX         u32 rows, u32 cols, f64 row-major
:class:`Image`            IMAGE          width, height, format, order, u32 length, pixels
========================  =============  ==============================================

Arrays are packed and unpacked by ``struct`` in one call each: no per-element Python loop.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from spec import wire
from spec.errors import ParameterError, UsageError
from spec.wire import ParamType, PixelFormat, PixelOrder

_T = TypeVar("_T")


def _trusted(cls: type[_T], **fields: object) -> _T:
    """Build a value from fields the decoder already checked, skipping per-element work."""
    obj = object.__new__(cls)
    for name, value in fields.items():
        object.__setattr__(obj, name, value)
    return obj


def _trusted_values(cls: type[_T], values: tuple[Any, ...]) -> _T:
    """:func:`_trusted` for the classes whose one field is ``values`` (the common replies)."""
    obj = object.__new__(cls)
    object.__setattr__(obj, "values", values)
    return obj


def _floats(values: object, what: str) -> tuple[float, ...]:
    try:
        return tuple(map(float, values))  # type: ignore[call-overload]
    except (TypeError, ValueError) as exc:
        raise UsageError(f"{what}: expected a sequence of numbers ({exc})") from None


@dataclass(frozen=True, slots=True)
class FloatArray:
    """A list of float64 values (any IEEE value, NaN allowed)."""

    values: tuple[float, ...]

    def __init__(self, values: object) -> None:
        object.__setattr__(self, "values", _floats(values, "FloatArray"))


@dataclass(frozen=True, slots=True)
class IntArray:
    """A list of signed 64-bit integers."""

    values: tuple[int, ...]

    def __init__(self, values: object) -> None:
        try:
            vals = tuple(int(v) for v in values)  # type: ignore[attr-defined]
        except (TypeError, ValueError) as exc:
            raise UsageError(f"IntArray: expected a sequence of integers ({exc})") from None
        object.__setattr__(self, "values", vals)


@dataclass(frozen=True, slots=True)
class Joints:
    """Joint positions in degrees, VAL3 zero (arm straight up); 1 to 16 axes."""

    values: tuple[float, ...]

    def __init__(self, values: object) -> None:
        vals = _floats(values, "Joints")
        if not 1 <= len(vals) <= wire.MAX_JOINTS:
            raise UsageError(f"Joints: 1 to {wire.MAX_JOINTS} values, got {len(vals)}")
        if not all(map(math.isfinite, vals)):
            raise UsageError("Joints: values must be finite")
        object.__setattr__(self, "values", vals)


#: A VAL3 location as a plain value: x, y, z (mm), rx, ry, rz (degrees),
#: R = Rx(rx)·Ry(ry)·Rz(rz): the one declaration (kinematics.types re-exports it for numpy code).
Loc = tuple[float, float, float, float, float, float]
#: The identity location: a tool at the flange, a frame at the base.
IDENTITY_LOC: Loc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True, slots=True)
class Location:
    """A VAL3 location: x, y, z in mm, rx, ry, rz in degrees, R = Rx(rx)·Ry(ry)·Rz(rz)."""

    x: float
    y: float
    z: float
    rx: float
    ry: float
    rz: float

    def __post_init__(self) -> None:
        for name in ("x", "y", "z", "rx", "ry", "rz"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise UsageError(f"Location.{name} must be finite")
            object.__setattr__(self, name, value)

    @classmethod
    def of(cls, values: object) -> Location:
        vals = _floats(values, "Location")
        if len(vals) != 6:
            raise UsageError(f"Location: 6 values (x, y, z, rx, ry, rz), got {len(vals)}")
        return cls(*vals)

    def as_tuple(self) -> Loc:
        return (self.x, self.y, self.z, self.rx, self.ry, self.rz)


#: A frame on itself: the zero location, and the identity transform (16 values, row-major).
IDENTITY_LOCATION = Location(*IDENTITY_LOC)
IDENTITY_MATRIX = (1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True, slots=True)
class Transform:
    """A 4x4 homogeneous transform, 16 values row-major, translation in mm."""

    values: tuple[float, ...] = IDENTITY_MATRIX

    def __init__(self, values: object = IDENTITY_MATRIX) -> None:
        try:
            flat = _floats(_flatten(values), "Transform")
        except TypeError:
            raise UsageError("Transform: expected 16 numbers or a 4x4 nested sequence") from None
        if len(flat) != 16:
            raise UsageError(f"Transform: 16 values, got {len(flat)}")
        if not all(map(math.isfinite, flat)):
            raise UsageError("Transform: values must be finite")
        if flat[12:] != (0.0, 0.0, 0.0, 1.0):
            raise UsageError("Transform: the last row must be 0 0 0 1")
        object.__setattr__(self, "values", flat)

    def rows(self) -> tuple[tuple[float, ...], ...]:
        v = self.values
        return (v[0:4], v[4:8], v[8:12], v[12:16])


def _flatten(values: object) -> list[object]:
    out: list[object] = []
    for v in values:  # type: ignore[attr-defined]
        if isinstance(v, int | float):
            out.append(v)
        else:
            out.extend(v)
    return out


@dataclass(frozen=True, slots=True)
class Matrix:
    """A rows x cols float64 matrix, row-major; e.g. a joint log or profile points."""

    rows: int
    cols: int
    values: tuple[float, ...]

    def __init__(self, rows: int, cols: int, values: object) -> None:
        vals = _floats(values, "Matrix")
        if rows < 0 or cols < 0 or rows * cols != len(vals):
            raise UsageError(f"Matrix: {rows}x{cols} needs {rows * cols} values, got {len(vals)}")
        object.__setattr__(self, "rows", int(rows))
        object.__setattr__(self, "cols", int(cols))
        object.__setattr__(self, "values", vals)

    def row(self, i: int) -> tuple[float, ...]:
        return self.values[i * self.cols : (i + 1) * self.cols]

    def to_rows(self) -> list[tuple[float, ...]]:
        return [self.row(i) for i in range(self.rows)]


@dataclass(frozen=True, slots=True)
class Image:
    """A camera frame: ``width`` columns, ``height`` rows, pixel bytes in ``order``."""

    width: int
    height: int
    data: bytes
    format: PixelFormat = PixelFormat.MONO8
    order: PixelOrder = PixelOrder.ROW_MAJOR

    def __post_init__(self) -> None:
        if not (0 <= self.width <= 0xFFFF and 0 <= self.height <= 0xFFFF):
            raise UsageError("Image: width and height must fit in 16 bits")
        expected = self.width * self.height * wire.BYTES_PER_PIXEL[PixelFormat(self.format)]
        if len(self.data) != expected:
            raise UsageError(f"Image: {expected} pixel bytes expected, got {len(self.data)}")
        if not isinstance(self.data, bytes):
            object.__setattr__(self, "data", bytes(self.data))


Value = (
    int | float | bool | str | bytes | FloatArray | IntArray | Joints | Location | Transform
) | (Matrix | Image)


def type_of(value: Value) -> ParamType:
    """The wire type a Python value is encoded as."""
    if isinstance(value, bool):
        return ParamType.BOOL
    if isinstance(value, int):
        return ParamType.INT
    kind = _TYPE_OF_CLASS.get(type(value))
    if kind is None:
        raise UsageError(f"cannot encode a {type(value).__name__} as a parameter")
    return kind


_TYPE_OF_CLASS: dict[type, ParamType] = {
    float: ParamType.FLOAT,
    str: ParamType.STRING,
    bytes: ParamType.BYTES,
    FloatArray: ParamType.FLOAT_ARRAY,
    IntArray: ParamType.INT_ARRAY,
    Joints: ParamType.JOINTS,
    Location: ParamType.LOCATION,
    Transform: ParamType.TRANSFORM,
    Matrix: ParamType.MATRIX,
    Image: ParamType.IMAGE,
}


#: The exact Python class of each wire type (a subclass, e.g. an IntEnum member, also encodes).
CLASS_OF: dict[ParamType, type] = {
    ParamType.BOOL: bool,
    ParamType.INT: int,
    **{kind: cls for cls, kind in _TYPE_OF_CLASS.items()},
}


# --- encoding ---------------------------------------------------------------------------------


def encode_params(params: tuple[Value, ...] | list[Value]) -> bytes:
    """Encode a parameter list (count + tagged values)."""
    return b"".join(encode_params_parts(params))


def encode_params_parts(params: tuple[Value, ...] | list[Value]) -> list[bytes]:
    """The encoded parameter list as chunks, so a frame is joined with one copy."""
    if len(params) > 0xFFFF:
        raise UsageError("at most 65535 parameters")
    parts: list[bytes] = [_COUNT_PACK(len(params))]
    for value in params:
        encoder = _ENCODERS.get(type(value))
        parts.extend(_encode_value(value) if encoder is None else encoder(value))
    return parts


def _encode_value(value: Value) -> tuple[bytes, ...]:
    encoder = _ENCODERS.get(type(value))
    if encoder is not None:
        return encoder(value)
    # Subclasses (an IntEnum member, say): type_of names the wire type or raises.
    kind = type_of(value)
    if kind is ParamType.BOOL:
        return _enc_bool(bool(value))
    if kind is ParamType.INT:
        return _enc_int(int(value))  # type: ignore[arg-type]
    raise UsageError(f"cannot encode a {type(value).__name__} as a parameter")


# One encoder per Python class (exact type, as type_of): a table instead of an if-chain,
# because encoding a small reply is on every round trip.


def _enc_bool(value: bool) -> tuple[bytes, ...]:
    return (b"\x03\x01" if value else b"\x03\x00",)


def _enc_int(value: int) -> tuple[bytes, ...]:
    if not -(1 << 63) <= value < (1 << 63):
        raise UsageError(f"INT out of the signed 64-bit range: {value}")
    return (_TAG_INT + wire.I64.pack(value),)


def _enc_float(value: float) -> tuple[bytes, ...]:
    return (_TAG_FLOAT + wire.F64.pack(value),)


def _enc_str(value: str) -> tuple[bytes, ...]:
    raw = value.encode("utf-8")
    return (_TAG_STRING + wire.U32.pack(len(raw)) + raw,)


def _enc_bytes(value: bytes) -> tuple[bytes, ...]:
    return (_TAG_BYTES + wire.U32.pack(len(value)), value)


def _enc_float_array(value: FloatArray) -> tuple[bytes, ...]:
    n = len(value.values)
    return (_TAG_FLOAT_ARRAY + wire.U32.pack(n) + _f64s(n).pack(*value.values),)


def _enc_int_array(value: IntArray) -> tuple[bytes, ...]:
    n = len(value.values)
    try:
        return (_TAG_INT_ARRAY + wire.U32.pack(n) + _i64s(n).pack(*value.values),)
    except struct.error as exc:
        raise UsageError(f"IntArray: {exc}") from None


def _enc_joints(value: Joints) -> tuple[bytes, ...]:
    n = len(value.values)
    return (_TAG_JOINTS + wire.U8.pack(n) + _f64s(n).pack(*value.values),)


def _enc_location(value: Location) -> tuple[bytes, ...]:
    return (_TAG_LOCATION + wire.LOCATION.pack(*value.as_tuple()),)


def _enc_transform(value: Transform) -> tuple[bytes, ...]:
    return (_TAG_TRANSFORM + wire.TRANSFORM.pack(*value.values),)


def _enc_matrix(value: Matrix) -> tuple[bytes, ...]:
    shape = wire.MATRIX_SHAPE.pack(value.rows, value.cols)
    return (_TAG_MATRIX + shape + _f64s(len(value.values)).pack(*value.values),)


def _enc_image(value: Image) -> tuple[bytes, ...]:
    meta = wire.IMAGE_HEADER.pack(
        value.width, value.height, int(value.format), int(value.order), len(value.data)
    )
    return (_TAG_IMAGE + meta, value.data)


_TAG = {t: wire.TAG.pack(t) for t in ParamType}  # the one-byte tag of each type
_COUNT_PACK = wire.PARAM_COUNT.pack
_TAG_BYTES = _TAG[ParamType.BYTES]
_TAG_FLOAT = _TAG[ParamType.FLOAT]
_TAG_FLOAT_ARRAY = _TAG[ParamType.FLOAT_ARRAY]
_TAG_IMAGE = _TAG[ParamType.IMAGE]
_TAG_INT = _TAG[ParamType.INT]
_TAG_INT_ARRAY = _TAG[ParamType.INT_ARRAY]
_TAG_JOINTS = _TAG[ParamType.JOINTS]
_TAG_LOCATION = _TAG[ParamType.LOCATION]
_TAG_MATRIX = _TAG[ParamType.MATRIX]
_TAG_STRING = _TAG[ParamType.STRING]
_TAG_TRANSFORM = _TAG[ParamType.TRANSFORM]
_ENCODERS: dict[type, Callable[[Any], tuple[bytes, ...]]] = {
    bool: _enc_bool,
    int: _enc_int,
    float: _enc_float,
    str: _enc_str,
    bytes: _enc_bytes,
    FloatArray: _enc_float_array,
    IntArray: _enc_int_array,
    Joints: _enc_joints,
    Location: _enc_location,
    Transform: _enc_transform,
    Matrix: _enc_matrix,
    Image: _enc_image,
}


# --- decoding ---------------------------------------------------------------------------------


# Enum members as module constants: an enum attribute look-up costs a few hundred ns in
# Python 3.11, and the decoders name their type on every call.
_PT_BOOL = ParamType.BOOL
_PT_BYTES = ParamType.BYTES
_PT_FLOAT = ParamType.FLOAT
_PT_FLOAT_ARRAY = ParamType.FLOAT_ARRAY
_PT_IMAGE = ParamType.IMAGE
_PT_INT = ParamType.INT
_PT_INT_ARRAY = ParamType.INT_ARRAY
_PT_JOINTS = ParamType.JOINTS
_PT_LOCATION = ParamType.LOCATION
_PT_MATRIX = ParamType.MATRIX
_PT_STRING = ParamType.STRING
_PT_TRANSFORM = ParamType.TRANSFORM
_COUNT_UNPACK = wire.PARAM_COUNT.unpack_from
_MAX_JOINTS = wire.MAX_JOINTS
_isfinite = math.isfinite


def decode_params(payload: bytes | memoryview) -> tuple[Value, ...]:
    """Decode a whole payload into its parameter list [RS-4.1]; raise :class:`ParameterError`."""
    buf = payload if type(payload) is memoryview else memoryview(payload)
    end = len(buf)
    if end < 2:
        raise ParameterError("payload shorter than the 2-byte parameter count")
    (count,) = _COUNT_UNPACK(buf, 0)
    pos = 2
    values: list[Value] = []
    for index in range(count):
        if pos >= end:
            raise ParameterError(f"parameter {index} (type tag) truncated")
        decoder = _DECODERS.get(buf[pos])
        if decoder is None:
            raise ParameterError(f"parameter {index}: unknown type tag 0x{buf[pos]:02x}")
        value, pos = decoder(buf, pos + 1, index)
        values.append(value)
    if pos != end:
        # [RS-4.3] the parameter list must fill the payload exactly.
        raise ParameterError(f"{end - pos} unexpected bytes after {count} parameters")
    return tuple(values)


# One decoder per type tag: (buffer, position after the tag, parameter index) -> (value, next
# position). A table instead of an if-chain: decoding a small reply is on every round trip.
_Decoded = tuple["Value", int]


def _need(buf: memoryview, pos: int, size: int, index: int, tag: ParamType) -> None:
    if pos + size > len(buf):
        raise ParameterError(f"parameter {index} ({tag.name}) truncated")


def _finite(values: tuple[float, ...], index: int, tag: ParamType) -> None:
    if not all(map(math.isfinite, values)):
        raise ParameterError(f"parameter {index} ({tag.name}) must be finite")


@functools.cache
def _f64s(n: int) -> struct.Struct:
    return struct.Struct(f">{n}d")


@functools.cache
def _i64s(n: int) -> struct.Struct:
    return struct.Struct(f">{n}q")


def _dec_int(buf: memoryview, pos: int, index: int) -> _Decoded:
    _need(buf, pos, 8, index, _PT_INT)
    return wire.I64.unpack_from(buf, pos)[0], pos + 8


def _dec_float(buf: memoryview, pos: int, index: int) -> _Decoded:
    _need(buf, pos, 8, index, _PT_FLOAT)
    return wire.F64.unpack_from(buf, pos)[0], pos + 8


def _dec_bool(buf: memoryview, pos: int, index: int) -> _Decoded:
    _need(buf, pos, 1, index, _PT_BOOL)
    if buf[pos] > 1:
        raise ParameterError(f"parameter {index}: BOOL must be 0 or 1, got {buf[pos]}")
    return buf[pos] == 1, pos + 1


def _counted(buf: memoryview, pos: int, index: int, tag: ParamType, size: int) -> int:
    """The u32 count at ``pos``, checked against the bytes left for ``size``-byte items."""
    _need(buf, pos, 4, index, tag)
    (n,) = wire.U32.unpack_from(buf, pos)
    _need(buf, pos + 4, n * size, index, tag)
    return int(n)


def _dec_bytes(buf: memoryview, pos: int, index: int) -> _Decoded:
    n = _counted(buf, pos, index, _PT_BYTES, 1)
    return bytes(buf[pos + 4 : pos + 4 + n]), pos + 4 + n


def _dec_string(buf: memoryview, pos: int, index: int) -> _Decoded:
    n = _counted(buf, pos, index, _PT_STRING, 1)
    try:
        return str(buf[pos + 4 : pos + 4 + n], "utf-8"), pos + 4 + n
    except UnicodeDecodeError:
        raise ParameterError(f"parameter {index}: STRING is not valid UTF-8") from None


def _dec_float_array(buf: memoryview, pos: int, index: int) -> _Decoded:
    n = _counted(buf, pos, index, _PT_FLOAT_ARRAY, 8)
    vals = _f64s(n).unpack_from(buf, pos + 4)
    return _trusted_values(FloatArray, vals), pos + 4 + 8 * n


def _dec_int_array(buf: memoryview, pos: int, index: int) -> _Decoded:
    n = _counted(buf, pos, index, _PT_INT_ARRAY, 8)
    vals = _i64s(n).unpack_from(buf, pos + 4)
    return _trusted_values(IntArray, vals), pos + 4 + 8 * n


def _dec_joints(buf: memoryview, pos: int, index: int) -> _Decoded:
    # The checks of _need and _finite written out: this decodes every Herej reply.
    size = len(buf)
    if pos >= size:
        raise ParameterError(f"parameter {index} (JOINTS) truncated")
    n = buf[pos]
    if not 1 <= n <= _MAX_JOINTS:
        raise ParameterError(f"parameter {index}: JOINTS count {n} not in 1..16")
    end = pos + 1 + 8 * n
    if end > size:
        raise ParameterError(f"parameter {index} (JOINTS) truncated")
    joints = _f64s(n).unpack_from(buf, pos + 1)
    if not all(map(_isfinite, joints)):
        raise ParameterError(f"parameter {index} (JOINTS) must be finite")
    obj = object.__new__(Joints)
    object.__setattr__(obj, "values", joints)
    return obj, end


def _dec_location(buf: memoryview, pos: int, index: int) -> _Decoded:
    _need(buf, pos, wire.LOCATION.size, index, _PT_LOCATION)
    loc = wire.LOCATION.unpack_from(buf, pos)
    _finite(loc, index, _PT_LOCATION)
    value = _trusted(Location, x=loc[0], y=loc[1], z=loc[2], rx=loc[3], ry=loc[4], rz=loc[5])
    return value, pos + wire.LOCATION.size


def _dec_transform(buf: memoryview, pos: int, index: int) -> _Decoded:
    _need(buf, pos, wire.TRANSFORM.size, index, _PT_TRANSFORM)
    t = wire.TRANSFORM.unpack_from(buf, pos)
    _finite(t, index, _PT_TRANSFORM)
    if t[12:] != (0.0, 0.0, 0.0, 1.0):
        raise ParameterError(f"parameter {index}: TRANSFORM last row must be 0 0 0 1")
    return _trusted_values(Transform, t), pos + wire.TRANSFORM.size


def _dec_matrix(buf: memoryview, pos: int, index: int) -> _Decoded:
    _need(buf, pos, wire.MATRIX_SHAPE.size, index, _PT_MATRIX)
    rows, cols = wire.MATRIX_SHAPE.unpack_from(buf, pos)
    pos += wire.MATRIX_SHAPE.size
    n = rows * cols
    _need(buf, pos, 8 * n, index, _PT_MATRIX)
    vals = _f64s(n).unpack_from(buf, pos)
    return _trusted(Matrix, rows=rows, cols=cols, values=vals), pos + 8 * n


def _dec_image(buf: memoryview, pos: int, index: int) -> _Decoded:
    # The checks of _need and the fields of _trusted written out: a GetImage reply decodes
    # one per frame, and this is the client's Python per image besides the copy.
    start = pos + _IMAGE_META_SIZE
    if start > len(buf):
        raise ParameterError(f"parameter {index} (IMAGE) truncated")
    width, height, fmt, order, n = _IMAGE_META_UNPACK(buf, pos)
    pixel_format, pixel_order = _PIXEL_FORMATS.get(fmt), _PIXEL_ORDERS.get(order)
    if pixel_format is None or pixel_order is None:
        msg = f"parameter {index}: unknown image format {fmt} / order {order}"
        raise ParameterError(msg)
    if n != width * height * pixel_format[1]:
        raise ParameterError(f"parameter {index}: IMAGE length {n} != width*height*bpp")
    end = start + n
    if end > len(buf):
        raise ParameterError(f"parameter {index} (IMAGE) truncated")
    image = _new(Image)
    _set(image, "width", width)
    _set(image, "height", height)
    _set(image, "data", bytes(buf[start:end]))  # the one copy: Image.data owns its bytes
    _set(image, "format", pixel_format[0])
    _set(image, "order", pixel_order)
    return image, end


# Look-ups by value without calling the enum class (slow in Python 3.11): the format with
# its bytes per pixel, so no enum member is hashed per image.
_PIXEL_FORMATS = {int(f): (f, wire.BYTES_PER_PIXEL[f]) for f in PixelFormat}
_PIXEL_ORDERS = {int(o): o for o in PixelOrder}
_IMAGE_META_UNPACK = wire.IMAGE_HEADER.unpack_from
_IMAGE_META_SIZE = wire.IMAGE_HEADER.size
_new = object.__new__
_set = object.__setattr__

_DECODERS: dict[int, Callable[[memoryview, int, int], _Decoded]] = {
    ParamType.INT: _dec_int,
    ParamType.FLOAT: _dec_float,
    ParamType.BOOL: _dec_bool,
    ParamType.STRING: _dec_string,
    ParamType.BYTES: _dec_bytes,
    ParamType.FLOAT_ARRAY: _dec_float_array,
    ParamType.INT_ARRAY: _dec_int_array,
    ParamType.JOINTS: _dec_joints,
    ParamType.LOCATION: _dec_location,
    ParamType.TRANSFORM: _dec_transform,
    ParamType.MATRIX: _dec_matrix,
    ParamType.IMAGE: _dec_image,
}
