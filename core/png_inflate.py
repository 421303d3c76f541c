"""Faster PNG decoding: the image data inflated by ISA-L, the rest left to libpng.

A PNG's pixels are deflate-compressed rows, each behind a filter byte. OpenCV's libpng inflates
them with the system zlib (1.2.x here), which is most of a frame's decoding time: ~3.5 of the
~6 CPU ms of a noisy 640×480 colour PNG, ~2 of the ~3.3 ms of a 16-bit depth PNG (AMD EPYC,
AVX-512). ISA-L's inflate (the ``isal`` package) does the same in about half the time, but
libpng has no way to be handed inflated rows. So :func:`stored` inflates the image data with
ISA-L and writes it back as one *stored* (uncompressed) zlib stream in a single ``IDAT`` chunk;
libpng then only copies it, unfilters the rows and converts the pixels as before. The pixels
are the same, bit for bit (PNG is lossless; the rows and their filter bytes are unchanged).

Any PNG this cannot rewrite (interlaced, an unusual layout, data that does not inflate to the
size its header says) is returned as it was, for libpng to decode or refuse as before; without
``isal`` installed nothing is rewritten. Torch-free (floor 0).
"""

from __future__ import annotations

import struct
import zlib

try:
    from isal import isal_zlib
except ImportError:  # pragma: no cover - isal is a dependency; the plain decoder still works
    isal_zlib = None

crc32 = zlib.crc32 if isal_zlib is None else isal_zlib.crc32
"""CRC-32 of a bytes-like object (ISA-L's where installed: ~5x faster than zlib 1.2's)."""

_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_BLOCK = 0xFFFF
"""Largest stored deflate block, bytes."""
_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
"""Samples per pixel of each PNG colour type (grey, RGB, palette, grey + alpha, RGBA)."""
MAX_PIXELS = 1 << 30
"""The most pixels an image may declare (OpenCV's default ``CV_IO_MAX_IMAGE_PIXELS``): the
image reader (:mod:`uss_slam.core.images`) refuses a header past it before anything is decoded
or allocated, and a larger image is never inflated here."""
MIN_SHARE = 16
"""Image data compressed to less than 1/16 of its size is left to libpng: zlib inflates such
data (long repeats: label images, 4.4 kB for 307 kB of rows) at least as fast as copying it
again (0.55 against 0.9 CPU ms per 640×480 label PNG)."""


def stored(data: bytes) -> bytes:
    """The whole PNG file ``data`` with its image data stored uncompressed (module docstring),
    or ``data`` itself where it cannot be rewritten. ``data`` must already have passed
    :func:`~uss_slam.core.images.png_problem` (every chunk whole, an ``IEND``)."""
    if isal_zlib is None or len(data) < 33 or data[12:16] != b"IHDR" or data[28] != 0:
        return data  # no ISA-L, no IHDR first, or interlaced (Adam7): rows of several sizes
    width, height = struct.unpack_from(">II", data, 16)
    depth, colour = data[24], data[25]
    if colour not in _CHANNELS or width * height > MAX_PIXELS:
        return data
    size = height * (1 + (width * _CHANNELS[colour] * depth + 7) // 8)
    pieces, first, after = _image_data(data)
    if first < 0 or sum(len(p) for p in pieces) * MIN_SHARE < size:
        return data  # also bounds what is allocated by the file's size, not by its header
    try:
        rows = isal_zlib.decompress(b"".join(pieces), 15, size)
    except isal_zlib.error:
        return data  # libpng names the problem as before
    if len(rows) != size:
        return data
    body = _stored_stream(rows)
    head = struct.pack(">I", sum(len(p) for p in body)) + b"IDAT"
    crc = 0
    for part in (b"IDAT", *body):
        crc = crc32(part, crc)
    return b"".join(
        (memoryview(data)[:first], head, *body, struct.pack(">I", crc), memoryview(data)[after:])
    )


def _image_data(data: bytes) -> tuple[list[memoryview], int, int]:
    """The ``IDAT`` chunks' contents (views), the offset of the first ``IDAT`` chunk and the
    offset just past the last; ``-1`` for both where they are not one run of chunks."""
    view = memoryview(data)
    pieces: list[memoryview] = []
    pos, first, after = len(_SIGNATURE), -1, -1
    while pos + 8 <= len(data):
        length = int.from_bytes(data[pos : pos + 4], "big")
        kind = data[pos + 4 : pos + 8]
        end = pos + 12 + length
        if kind == b"IDAT":
            if first >= 0 and after != pos:
                return [], -1, -1  # IDAT chunks with other chunks between them
            first = pos if first < 0 else first
            pieces.append(view[pos + 8 : end - 4])
            after = end
        elif kind == b"IEND":
            break
        pos = end
    return pieces, first, after


def _stored_stream(rows: bytes) -> list[bytes | memoryview]:
    """``rows`` as a zlib stream of stored deflate blocks (RFC 1950 / 1951), in pieces: the
    header, each block's 5-byte header and its slice of ``rows``, the Adler-32."""
    view = memoryview(rows)
    out: list[bytes | memoryview] = [b"\x78\x01"]  # deflate, 32 kB window, no preset dictionary
    for start in range(0, len(rows), _BLOCK):
        block = view[start : start + _BLOCK]
        last = start + _BLOCK >= len(rows)
        out.append(struct.pack("<BHH", last, len(block), len(block) ^ 0xFFFF))
        out.append(block)
    out.append(struct.pack(">I", isal_zlib.adler32(rows)))
    return out
