"""CRC-32 (IEEE 802.3, as :func:`zlib.crc32`) of a frame whose large part does not change.

A server that sends the same image again (GetImage between two acquisitions) would run the
CRC over its 128 KiB every time. :func:`crc32_combine` joins the CRC of the header bytes
with the CRC of the payload, computed once per image (:func:`spec.codec.prepare_params`),
the way zlib's ``crc32_combine`` does: crc(A + B) = crc(A) * x^(8 len B) mod P  xor  crc(B).
Stdlib has no binding for it; the polynomial arithmetic below is zlib's, on 32-bit ints.

:func:`crc32` is the same function as :func:`zlib.crc32`, from zlib-ng when the optional
``fast`` extra is installed: its carry-less-multiply folding checks a 128 KiB image in ~3 µs
where the system zlib (1.2.13, byte tables) takes ~70 µs, more than a whole pyzmq round trip
of the same array. Without it, zlib.crc32 does the work: the code is stdlib-only.
"""

from __future__ import annotations

import functools
import zlib
from collections.abc import Callable


def _select_crc32(fast: bool = True) -> tuple[Callable[..., int], str]:
    """The CRC-32 function and its name: zlib-ng's when ``fast`` and importable, else zlib's."""
    if fast:
        try:
            from zlib_ng import zlib_ng  # the optional `fast` extra
        except ImportError:
            pass
        else:
            return zlib_ng.crc32, "zlib-ng"
    return zlib.crc32, "zlib"


#: zlib.crc32(data, value=0) by the fastest implementation installed; and its name.
crc32, CRC32_IMPLEMENTATION = _select_crc32()

_POLY = 0xEDB88320  # reflected CRC-32 polynomial


def _multmodp(a: int, b: int) -> int:
    """a * b modulo the CRC polynomial, bit-reflected (zlib's multmodp)."""
    m = 1 << 31
    p = 0
    while True:
        if a & m:
            p ^= b
            if not a & (m - 1):
                return p
        m >>= 1
        b = (b >> 1) ^ _POLY if b & 1 else b >> 1


def _x2n_table() -> tuple[int, ...]:
    """x^(2^k) modulo P for k = 0..31."""
    p = 1 << 30  # x^1
    table = [p]
    for _ in range(31):
        p = _multmodp(p, p)
        table.append(p)
    return tuple(table)


_X2N = _x2n_table()


def _x2nmodp(length: int) -> int:
    """x^(8 * length) modulo P: the operator that moves a CRC past ``length`` bytes."""
    p = 1 << 31  # x^0
    k = 3
    while length:
        if length & 1:
            p = _multmodp(_X2N[k & 31], p)
        length >>= 1
        k += 1
    return p


@functools.lru_cache(maxsize=16)
def _shift_tables(length: int) -> tuple[tuple[int, ...], ...]:
    """The shift past ``length`` bytes as four byte tables: multiplying by a constant is
    linear, so crc * op = T0[byte 0] ^ T1[byte 1] ^ T2[byte 2] ^ T3[byte 3] (built once per
    length, 1024 products; a frame of the same size then costs four look-ups)."""
    op = _x2nmodp(length)
    return tuple(tuple(_multmodp(op, v << (8 * k)) for v in range(256)) for k in range(4))


def crc32_combine(crc1: int, crc2: int, length2: int) -> int:
    """CRC-32 of A + B from crc1 = crc32(A), crc2 = crc32(B) and length2 = len(B)."""
    t0, t1, t2, t3 = _shift_tables(length2)
    return (
        t0[crc1 & 0xFF] ^ t1[(crc1 >> 8) & 0xFF] ^ t2[(crc1 >> 16) & 0xFF] ^ t3[crc1 >> 24] ^ crc2
    )


def crc32_combine_reference(crc1: int, crc2: int, length2: int) -> int:
    """zlib's crc32_combine as written there (the plain reference the tests check against)."""
    return _multmodp(_x2nmodp(length2), crc1) ^ crc2


__all__ = [
    "CRC32_IMPLEMENTATION",
    "crc32",
    "crc32_combine",
    "crc32_combine_reference",
]
