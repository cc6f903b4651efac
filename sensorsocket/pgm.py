"""Binary PGM (P5) write, atomic, and read of sensor images (pure stdlib + numpy).

Images are written in the conventional layout: width = chip columns (512), height = rows
(256), row by row. Pass a column-major frame through :func:`sensorsocket.camera.image_rows`
first (or use ``write_frame``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from spec.files import write_atomically


class PgmError(ValueError):
    """Not a PGM image this module can read or write."""


def write_pgm(path: str | os.PathLike[str], image: NDArray[np.generic]) -> None:
    """Write a (rows, columns) uint8 or uint16 image as binary PGM; atomic replace."""
    a = np.asarray(image)
    if a.ndim != 2 or a.shape[0] < 1 or a.shape[1] < 1:
        raise PgmError(f"PGM needs a 2-D image, got shape {a.shape}")
    if a.dtype == np.uint8:
        maxval, data = 255, np.ascontiguousarray(a).tobytes()
    elif a.dtype == np.uint16:
        maxval, data = 65535, np.ascontiguousarray(a, dtype=">u2").tobytes()
    else:
        raise PgmError(f"PGM needs uint8 or uint16 pixels, got {a.dtype}")
    header = f"P5\n{a.shape[1]} {a.shape[0]}\n{maxval}\n".encode("ascii")
    target = Path(path)
    write_atomically(target, header + data)


def write_frame(path: str | os.PathLike[str], frame: NDArray[np.uint8]) -> None:
    """Write a column-major (columns, rows) frame as a conventional PGM."""
    write_pgm(path, np.asarray(frame).T)


def _tokens(data: bytes, count: int) -> tuple[list[int], int]:
    """First ``count`` header integers and the offset after the single whitespace."""
    out: list[int] = []
    i = 2
    n = len(data)
    while len(out) < count:
        while i < n and data[i : i + 1].isspace():
            i += 1
        if i < n and data[i : i + 1] == b"#":
            while i < n and data[i : i + 1] not in (b"\n", b"\r"):
                i += 1
            continue
        start = i
        while i < n and data[i : i + 1].isdigit():
            i += 1
        if start == i:
            raise PgmError("malformed PGM header")
        out.append(int(data[start:i]))
    if i >= n or not data[i : i + 1].isspace():
        raise PgmError("malformed PGM header")
    return out, i + 1


def parse_pgm(data: bytes) -> NDArray[np.generic]:
    """Decode binary (P5) or plain (P2) PGM bytes into a (rows, columns) array."""
    if data[:2] not in (b"P5", b"P2"):
        raise PgmError("not a PGM file (magic P5 or P2 expected)")
    (width, height, maxval), offset = _tokens(data, 3)
    if not (0 < width <= 1 << 16 and 0 < height <= 1 << 16 and 0 < maxval < 65536):
        raise PgmError(f"PGM size {width}x{height} maxval {maxval} out of range")
    dtype = np.dtype(np.uint8) if maxval < 256 else np.dtype(">u2")
    count = width * height
    if data[:2] == b"P5":
        body = data[offset : offset + count * dtype.itemsize]
        if len(body) != count * dtype.itemsize:
            raise PgmError("PGM pixel data truncated")
        pixels = np.frombuffer(body, dtype=dtype)
    else:
        try:
            values = [int(t) for t in data[offset:].split()[:count]]
        except ValueError as exc:
            raise PgmError("malformed plain PGM pixels") from exc
        if len(values) != count:
            raise PgmError("PGM pixel data truncated")
        pixels = np.array(values, dtype=dtype)
    if int(pixels.max()) > maxval:
        raise PgmError("PGM pixel above maxval")
    out: NDArray[np.generic] = pixels.reshape(height, width).astype(dtype.newbyteorder("="))
    return out


def read_pgm(path: str | os.PathLike[str]) -> NDArray[np.generic]:
    """Read a PGM file into a (rows, columns) uint8 or uint16 array."""
    return parse_pgm(Path(path).read_bytes())


def read_frame(path: str | os.PathLike[str]) -> NDArray[np.generic]:
    """Read a PGM into the sensor's column-major (columns, rows) C-contiguous layout."""
    return np.ascontiguousarray(read_pgm(path).T)
