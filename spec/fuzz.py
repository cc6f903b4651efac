"""Seeded fuzzing of the decoders: random and mutated inputs must raise only the codec's own
errors (:class:`PeerError`), never anything else, and never hang."""

from __future__ import annotations

import random
import struct
import zlib
from collections import Counter
from dataclasses import dataclass, field

from spec.codec import FrameDecoder, Rejected
from spec.datagrams import decode_datagram
from spec.errors import PeerError
from spec.vectorgen import load


@dataclass
class FuzzReport:
    inputs: int = 0
    packets: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    failures: list[tuple[bytes, str]] = field(default_factory=list)  # (input, exception)


def _seeds() -> list[bytes]:
    frames = [bytes.fromhex(v["hex"]) for v in load("frames.json") if v["valid"]]
    return frames + [bytes.fromhex(v["hex"]) for v in load("datagrams.json") if v["valid"]]


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One random mutation: flip, overwrite, insert, delete, truncate, splice or repeat."""
    buf = bytearray(data)
    op = rng.randrange(7)
    if not buf:
        return bytes(rng.randbytes(rng.randrange(1, 64)))
    pos = rng.randrange(len(buf))
    if op == 0:
        buf[pos] ^= 1 << rng.randrange(8)
    elif op == 1:
        buf[pos] = rng.randrange(256)
    elif op == 2:
        buf[pos:pos] = rng.randbytes(rng.randrange(1, 9))
    elif op == 3:
        del buf[pos : pos + rng.randrange(1, 9)]
    elif op == 4:
        del buf[pos:]
    elif op == 5:
        # Length and count fields are where decoders go wrong: hit them on purpose.
        target = rng.choice([12, 13, 14, 15, 16, 17, 18]) if len(buf) > 18 else pos
        buf[target] = rng.choice([0x00, 0x01, 0x7F, 0x80, 0xFF])
    else:
        buf += buf[: rng.randrange(1, len(buf) + 1)]
    return bytes(buf)


def run(count: int, seed: int) -> FuzzReport:
    rng = random.Random(seed)
    seeds = _seeds()
    report = FuzzReport()
    for _ in range(count):
        if rng.random() < 0.15:
            data = rng.randbytes(rng.randrange(0, 200))
            if rng.random() < 0.5:
                data = b"RS" + data
        else:
            data = rng.choice(seeds)
            for _ in range(rng.randrange(1, 4)):
                data = mutate(data, rng)
            if rng.random() < 0.6 and len(data) > 4:
                # Re-seal the CRC so the mutation reaches the header and parameter checks.
                data = data[:-4] + struct.pack(">I", zlib.crc32(data[:-4]))
        report.inputs += 1
        try:
            decoder = FrameDecoder(max_payload=1 << 20)
            step = rng.choice([1, 7, len(data) or 1])
            for i in range(0, len(data), step):
                decoder.feed(data[i : i + step])
                for event in decoder.events():
                    if isinstance(event, Rejected):
                        report.rejected[event.code.name] += 1
                    else:
                        report.packets += 1
        except PeerError as exc:
            report.rejected[exc.code.name] += 1
        except Exception as exc:  # noqa: BLE001  the finding: anything but a PeerError
            report.failures.append((data, f"{type(exc).__name__}: {exc}"))
        try:
            decode_datagram(data)
        except PeerError:
            pass
        except Exception as exc:  # noqa: BLE001  the finding: anything but a PeerError
            report.failures.append((data, f"datagram {type(exc).__name__}: {exc}"))
    return report
