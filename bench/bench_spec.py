"""Codec benchmarks: small packet per packet, image throughput; baselines in the same run."""

from __future__ import annotations

from bench.common import Result, result, time_per_call
from spec import wire
from spec.codec import FrameDecoder, decode_packet, encode_packet, reply_to, request
from spec.params import Image, Joints
from spec.registry import CommandId


def run() -> list[Result]:
    out: list[Result] = []
    herej = reply_to(request(CommandId.HEREJ, 1), Joints([10.0, -20.0, 90.0, 0.0, 45.0, 0.0]))
    raw = encode_packet(herej)

    def small() -> None:
        decode_packet(encode_packet(herej))

    header = wire.HEADER.pack(wire.MAGIC, 1, 0, 2, 0, 0x1002, 1, 52)

    def bare_struct() -> None:
        wire.HEADER.unpack(wire.HEADER.pack(*wire.HEADER.unpack(header)))

    t_small = time_per_call(small)
    t_struct = time_per_call(bare_struct)
    out.append(
        result(
            "small packet encode + decode (spec.codec encode_packet/decode_packet)",
            t_small * 1e6, "us",
            "struct header pack+unpack", t_struct * 1e6,
        )
    )  # fmt: skip

    decoder = FrameDecoder()

    def stream_decode() -> None:
        decoder.feed(raw)
        for _ in decoder.events():
            pass

    out.append(
        result(
            "small packet from a byte stream (spec.codec.FrameDecoder)",
            time_per_call(stream_decode) * 1e6, "us",
            "struct header pack+unpack", t_struct * 1e6,
        )
    )  # fmt: skip

    pixels = bytes(range(256)) * (512 * 256 // 256)
    image_packet = reply_to(request(CommandId.GET_IMAGE, 2), 7, Image(512, 256, pixels))
    size = len(encode_packet(image_packet))

    def image() -> None:
        decode_packet(encode_packet(image_packet))

    source = bytearray(encode_packet(image_packet))

    def copy() -> None:
        bytes(source)

    t_image = time_per_call(image)
    t_copy = time_per_call(copy)
    out.append(
        result(
            "512x256 image packet encode + decode (spec.codec)", size / t_image / 1e9, "GB/s",
            "bytes copy of the same size", size / t_copy / 1e9,
        )
    )  # fmt: skip
    return out
