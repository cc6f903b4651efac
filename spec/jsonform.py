"""JSON forms of parameter values and packets: typed (for test vectors) and plain (for CLIs)."""

from __future__ import annotations

import base64
import math
from typing import Any

from spec.codec import Packet
from spec.errors import UsageError
from spec.params import (
    FloatArray,
    Image,
    IntArray,
    Joints,
    Location,
    Matrix,
    Transform,
    Value,
    type_of,
)
from spec.wire import PacketKind, ParamType, PixelFormat, PixelOrder


def _num(v: float) -> float | str:
    # JSON has no NaN or infinity: spell them as strings.
    return v if math.isfinite(v) else repr(v)


def _unnum(v: Any) -> float:
    return float(v)


def plain(value: Value) -> Any:
    """A JSON-ready plain value: numbers, strings, lists, dicts (for printing replies)."""
    if isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        return _num(value)
    if isinstance(value, bytes):
        return {"base64": base64.b64encode(value).decode("ascii")}
    if isinstance(value, FloatArray | Joints):
        return [_num(v) for v in value.values]
    if isinstance(value, IntArray):
        return list(value.values)
    if isinstance(value, Location):
        return {k: getattr(value, k) for k in ("x", "y", "z", "rx", "ry", "rz")}
    if isinstance(value, Transform):
        return [list(row) for row in value.rows()]
    if isinstance(value, Matrix):
        return [[_num(v) for v in value.row(i)] for i in range(value.rows)]
    assert isinstance(value, Image)
    return {
        "width": value.width,
        "height": value.height,
        "format": value.format.name,
        "order": value.order.name,
        "base64": base64.b64encode(value.data).decode("ascii"),
    }


def typed(value: Value) -> dict[str, Any]:
    """``{"type": NAME, "value": …}``, reversible with :func:`from_typed`."""
    kind = type_of(value)
    if isinstance(value, Matrix):
        body: Any = {
            "rows": value.rows,
            "cols": value.cols,
            "values": [_num(v) for v in value.values],
        }
    else:
        body = plain(value)
    return {"type": kind.name, "value": body}


def from_typed(item: dict[str, Any]) -> Value:
    """Inverse of :func:`typed`; raise :class:`UsageError` on a malformed item."""
    try:
        kind = ParamType[item["type"]]
        v = item["value"]
        if kind is ParamType.INT:
            return int(v)
        if kind is ParamType.FLOAT:
            return _unnum(v)
        if kind is ParamType.BOOL:
            return bool(v)
        if kind is ParamType.STRING:
            return str(v)
        if kind is ParamType.BYTES:
            return base64.b64decode(v["base64"])
        if kind is ParamType.FLOAT_ARRAY:
            return FloatArray([_unnum(x) for x in v])
        if kind is ParamType.INT_ARRAY:
            return IntArray(v)
        if kind is ParamType.JOINTS:
            return Joints(v)
        if kind is ParamType.LOCATION:
            return Location(*(float(v[k]) for k in ("x", "y", "z", "rx", "ry", "rz")))
        if kind is ParamType.TRANSFORM:
            return Transform(v)
        if kind is ParamType.MATRIX:
            return Matrix(v["rows"], v["cols"], [_unnum(x) for x in v["values"]])
        return Image(
            v["width"],
            v["height"],
            base64.b64decode(v["base64"]),
            PixelFormat[v["format"]],
            PixelOrder[v["order"]],
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise UsageError(f"malformed typed value {item!r}: {exc}") from None


def packet_to_json(packet: Packet) -> dict[str, Any]:
    return {
        "kind": packet.kind.name,
        "command": packet.command,
        "request_id": packet.request_id,
        "version_minor": packet.version_minor,
        "params": [typed(v) for v in packet.params],
    }


def packet_from_json(item: dict[str, Any]) -> Packet:
    return Packet(
        PacketKind[item["kind"]],
        int(item["command"]),
        int(item["request_id"]),
        tuple(from_typed(p) for p in item["params"]),
        int(item.get("version_minor", 0)),
    )
