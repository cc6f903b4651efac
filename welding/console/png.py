"""A greyscale image as PNG bytes (stdlib zlib): the sensor view sends the stripe image to
the browser as a picture it can draw without any image library on either side."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import numpy.typing as npt

__all__ = ["grey_png"]

_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    crc = zlib.crc32(kind + data) & 0xFFFFFFFF
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)


def grey_png(image: npt.NDArray[np.uint8] | npt.NDArray[np.uint16]) -> bytes:
    """PNG of ``image`` (rows, columns); 16-bit images are scaled to 8 bits."""
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"expected a (rows, columns) image, got shape {a.shape}")
    if a.dtype != np.uint8:
        a = (a.astype(np.uint32) >> 8).astype(np.uint8)
    rows, cols = a.shape
    # filter type 0 (none) before each row
    raw = np.hstack([np.zeros((rows, 1), dtype=np.uint8), a]).tobytes()
    header = struct.pack(">IIBBBBB", cols, rows, 8, 0, 0, 0, 0)
    return b"".join(
        (
            _SIGNATURE,
            _chunk(b"IHDR", header),
            _chunk(b"IDAT", zlib.compress(raw, 6)),
            _chunk(b"IEND", b""),
        )
    )
