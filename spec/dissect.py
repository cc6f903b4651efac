"""Human-readable dissection of any frame or datagram, as a protocol analyser prints it."""

from __future__ import annotations

import math

from spec import wire
from spec.codec import FrameDecoder, Header, Packet, Rejected, decode_packet
from spec.datagrams import SensorData, Trigger, decode_datagram
from spec.errors import ErrorCode, FrameError, ParameterError, PeerError
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
from spec.registry import BY_ID, ParamSpec, check_params_reference
from spec.wire import PacketKind, SensorStatus


def _short(values: tuple[float, ...] | tuple[int, ...], limit: int = 8) -> str:
    shown = ", ".join(f"{v:g}" for v in values[:limit])
    more = f", … ({len(values)} values)" if len(values) > limit else ""
    return f"[{shown}{more}]"


def format_value(value: Value) -> str:
    """One parameter value as text."""
    if isinstance(value, bool | int):
        return str(value)
    if isinstance(value, float):
        return f"{value:.17g}" if math.isfinite(value) else str(value)
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, bytes):
        return f"{len(value)} bytes {value[:32].hex()}{'…' if len(value) > 32 else ''}"
    if isinstance(value, FloatArray | IntArray | Joints):
        return _short(value.values)
    if isinstance(value, Location):
        return (
            f"x={value.x:g} y={value.y:g} z={value.z:g} mm, "
            f"rx={value.rx:g} ry={value.ry:g} rz={value.rz:g} deg"
        )
    if isinstance(value, Transform):
        return " / ".join(_short(row, 4) for row in value.rows())
    if isinstance(value, Matrix):
        return f"{value.rows}x{value.cols} {_short(value.values, 6)}"
    assert isinstance(value, Image)
    return (
        f"{value.width}x{value.height} {value.format.name} {value.order.name}, "
        f"{len(value.data)} bytes"
    )


def _param_specs(packet: Packet) -> tuple[ParamSpec, ...]:
    spec = BY_ID.get(packet.command)
    if spec is None:
        return ()
    if packet.kind is PacketKind.REQUEST:
        return spec.params
    if packet.kind is PacketKind.REPLY:
        return spec.reply
    return ()


def packet_rules(packet: Packet) -> list[str]:
    """The rules a decodable frame breaks on its own, each ``[ID] what`` (the frame-level
    checks of the codec passed already: magic, length, CRC, version, kind, flags, encoding)."""
    out = []
    kind, spec = packet.kind, BY_ID.get(packet.command)
    if kind is PacketKind.REQUEST and packet.request_id == 0:
        out.append("[RS-3.18] a request with request ID 0")
    if kind is PacketKind.ERROR:
        p = packet.params
        if len(p) != 2 or type(p[0]) is not int or not isinstance(p[1], str):
            out.append("[RS-6.1] an error frame carries exactly (INT code, STRING message)")
        elif p[0] not in ErrorCode._value2member_map_:
            out.append(f"[RS-6.1] error code {p[0]} is not in the table")
    elif spec is not None and kind in (PacketKind.REQUEST, PacketKind.REPLY):
        request = kind is PacketKind.REQUEST
        try:
            check_params_reference(
                spec.params if request else spec.reply,
                packet.params,
                f"{spec.name} {'request' if request else 'reply'}",
                allow_extra=not request,  # a newer minor version's extra reply values [RS-5.6]
            )
        except ParameterError as exc:
            out.append(f"[{'RS-5.4' if request else 'RS-5.5'}] {exc.message}")
        else:
            if not request and spec.name == "Hello":
                version, service = packet.params[0], packet.params[1]
                header = f"{wire.VERSION_MAJOR}.{packet.version_minor}"
                if version != header:
                    out.append(
                        f"[RS-5.31] Hello version {version!r} differs from the frame header's "
                        f"{header}"
                    )
                if service not in ("robot", "sensor"):
                    out.append(f"[RS-5.31] Hello service {service!r} is not robot or sensor")
    return out


def datagram_rules(d: Trigger | SensorData) -> list[str]:
    """The rules of section 9 a decodable datagram breaks on its own."""
    if not isinstance(d, SensorData):
        return []
    out = []
    if not d.t_arrival <= d.t_exposure_start <= d.t_exposure_end:
        out.append("[SY-2.6] t_arrival <= t_exposure_start <= t_exposure_end does not hold")
    if d.status is not SensorStatus.FOUND and not (
        all(math.isnan(v) for v in d.seam) or all(v == 0 for v in d.seam)
    ):
        out.append(f"[SY-2.7] status {d.status.name} with a location not all NaN or all zero")
    return out


def _rule_lines(rules: list[str]) -> list[str]:
    return [f"breaks           {r}" for r in rules]


def describe_packet(packet: Packet, raw: bytes) -> list[str]:
    header = Header.unpack(raw)
    spec = BY_ID.get(packet.command)
    name = spec.name if spec else "unknown command"
    (crc,) = wire.TRAILER.unpack_from(raw, len(raw) - wire.TRAILER_SIZE)
    lines = [
        f"frame            {len(raw)} bytes",
        f"magic            {header.magic.hex()} ({header.magic.decode('ascii', 'replace')})",
        f"version          {header.version_major}.{header.version_minor}",
        f"kind             {packet.kind.name} ({int(packet.kind)})",
        f"flags            0x{header.flags:02x}",
        f"command          0x{packet.command:04x} {name}" + (f" ({spec.service})" if spec else ""),
        f"request id       {packet.request_id}",
        f"payload length   {header.length}",
        f"crc32            {crc:08x} (ok)",
        f"parameters       {len(packet.params)}",
    ]
    specs = _param_specs(packet)
    error_names = ("code", "message")
    for i, value in enumerate(packet.params):
        label = f"#{i}"
        unit = ""
        if packet.kind is PacketKind.ERROR and i < 2:
            label += f" {error_names[i]}"
            if i == 0 and isinstance(value, int):
                try:
                    unit = f" ({ErrorCode(value).name})"
                except ValueError:
                    unit = " (unknown code)"
        elif i < len(specs):
            label += f" {specs[i].name}"
            unit = f" [{specs[i].unit}]" if specs[i].unit else ""
        lines.append(f"  {label:<22} {type_of(value).name:<12} {format_value(value)}{unit}")
    return lines + _rule_lines(packet_rules(packet))


def describe_datagram(raw: bytes) -> list[str]:
    d = decode_datagram(raw)
    lines = [
        f"datagram         {len(raw)} bytes",
        f"kind             {'TRIGGER' if isinstance(d, Trigger) else 'DATA'}",
        f"index            {d.index}",
        f"t_trigger        {d.t_trigger:.9f} s (robot clock)",
    ]
    if isinstance(d, SensorData):
        x, y, z, rx, ry, rz = d.seam
        lines += [
            f"status           {d.status.name} ({int(d.status)})",
            f"seam in S        x={x:g} y={y:g} z={z:g} mm, rx={rx:g} ry={ry:g} rz={rz:g} deg",
            f"quality          {d.quality:g}",
            f"t_arrival        {d.t_arrival:.9f} s (sensor clock)",
            f"t_exposure_start {d.t_exposure_start:.9f} s",
            f"t_exposure_end   {d.t_exposure_end:.9f} s",
        ]
    return lines + _rule_lines(datagram_rules(d))


def describe(raw: bytes) -> str:
    """Dissect one frame or datagram; raises the codec's PeerError when it is malformed."""
    if raw[:2] == wire.DATAGRAM_MAGIC:
        return "\n".join(describe_datagram(raw))
    return "\n".join(describe_packet(decode_packet(raw), raw))


def broken_rules(raw: bytes) -> list[str]:
    """``frame N: [ID] what`` for every rule the good frames of ``raw`` (or its datagram)
    break on their own; the first malformed frame ends the list, as it ends the dissection."""
    if raw[:2] == wire.DATAGRAM_MAGIC:
        try:
            return datagram_rules(decode_datagram(raw))
        except PeerError:
            return []
    decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
    decoder.feed(raw)
    out = []
    try:
        for i, event in enumerate(decoder.events(), start=1):
            if isinstance(event, Rejected):
                break
            out += [f"frame {i}: {r}" for r in packet_rules(event)]
    except PeerError:
        pass
    return out


def describe_all(raw: bytes) -> tuple[str, PeerError | None]:
    """Dissect a datagram, or every frame of a TCP capture (frames back to back): the text of
    the good frames and the codec's PeerError at the first malformed or incomplete one (None
    when there is none), so a capture cut short still shows what it holds."""
    if raw[:2] == wire.DATAGRAM_MAGIC:
        return describe(raw), None
    decoder = FrameDecoder(max_payload=wire.MAX_PAYLOAD)
    decoder.feed(raw)
    parts: list[str] = []
    offset = 0
    error: PeerError | None = None
    for event in decoder.events():
        if isinstance(event, Rejected):
            error = event.error
            break
        size = wire.FRAME_OVERHEAD + Header.unpack(raw[offset:]).length
        frame = raw[offset : offset + size]
        offset += size
        parts.append("\n".join(describe_packet(event, frame)))
    if error is None and decoder.buffered:
        need = wire.HEADER_SIZE
        if decoder.buffered >= wire.HEADER_SIZE:
            need = wire.FRAME_OVERHEAD + Header.unpack(raw[offset:]).length
        error = FrameError(f"truncated frame at byte {offset}: {decoder.buffered} of {need} bytes")
    if not parts or (len(parts) == 1 and error is None):
        return "".join(parts), error
    total = f" of {len(parts)}" if error is None else ""  # the error says where it stopped
    text = "\n\n".join(f"== frame {i + 1}{total}\n{p}" for i, p in enumerate(parts))
    return text, error
