"""The one image reader: colour, depth and label images of every tool go through
:func:`read_image` (and its three faces :func:`read_colour`, :func:`read_depth`,
:func:`read_labels`), which refuses a file that is not whole before a decoder sees it.

Decoders are lenient: OpenCV decodes a truncated JPEG with its missing rows grey and says so
only on stderr ("Premature end of JPEG file"), and libpng prints its own line ("libpng error:
Read Error") before OpenCV returns nothing. So the file's structure is checked first, in
Python, from its bytes (cheap next to decoding):

- PNG: the signature, every chunk whole with its CRC-32 right, and an ``IEND`` chunk;
- JPEG: start-of-image, every marker segment whole, each scan's entropy-coded data followed by
  a marker, and an end-of-image marker (bytes after it are allowed, as cameras append them);
- the format, by the file's magic bytes: PNG or JPEG only (OpenCV would also decode WebP, BMP,
  TIFF, ... none of which can be checked whole here), and the one its extension names
  (``.png``; ``.jpg``, ``.jpeg``): WebP data named ``.png`` or a PNG named ``.jpg`` is
  refused, naming the file and what its content is.

A damaged file is one :class:`DataFormatError` naming the file and what is wrong, and the
decoders never print. (A changed byte inside a JPEG's compressed data cannot be found this
way: JPEG has no checksum.) Torch-free (floor 0).
"""

from __future__ import annotations

import os
from os import PathLike

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES, IGNORE_INDEX
from uss_slam.core.errors import DataFormatError
from uss_slam.core.paths import input_file
from uss_slam.core.png_inflate import MAX_PIXELS, crc32, stored

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
JPEG_SOI = b"\xff\xd8"
_STANDALONE = {0x01, *range(0xD0, 0xD8)}  # TEM, RST0..RST7: markers without a length


def png_problem(data: bytes) -> str | None:
    """Why the PNG bytes ``data`` are not a whole PNG file, else None: every chunk whole with
    its CRC, the image data starting as a zlib stream (else libpng prints its own line)."""
    pos = len(PNG_SIGNATURE)
    view = memoryview(data)  # a chunk's CRC without copying the chunk
    first_idat = True
    while pos + 8 <= len(data):
        length = int.from_bytes(data[pos : pos + 4], "big")
        kind = data[pos + 4 : pos + 8]
        end = pos + 12 + length
        name = kind.decode("latin-1")
        if not kind.isalpha():
            return f"corrupt PNG: no chunk at byte {pos} (expected a 4-letter chunk type)"
        if end > len(data):
            return f"truncated PNG: it ends inside its {name} chunk at byte {pos} (no IEND chunk)"
        crc = int.from_bytes(data[end - 4 : end], "big")
        if crc32(view[pos + 4 : end - 4]) != crc:
            return f"corrupt PNG: the CRC of its {name} chunk at byte {pos} does not match"
        if kind == b"IEND":
            return None
        head = data[pos + 8 : pos + 10]  # two bytes: slicing to the end would copy the file
        if kind == b"IDAT" and first_idat and length >= 2 and not _zlib_header(head):
            return f"corrupt PNG: its image data (IDAT chunk at byte {pos}) is no zlib stream"
        first_idat = first_idat and kind != b"IDAT"
        pos = end
    return "truncated PNG: no IEND chunk at the end of the file"


def _zlib_header(head: bytes) -> bool:
    """Whether ``head`` starts with a zlib header (RFC 1950: deflate, its check bits)."""
    return head[0] & 0x0F == 8 and (head[0] << 8 | head[1]) % 31 == 0


def _scan_end(data: bytes, pos: int) -> int:
    """The offset of the marker that ends the entropy-coded data starting at ``pos`` (a 0xFF
    not followed by a stuffed 0x00 or a restart marker), or -1 when the data ends first."""
    while True:
        pos = data.find(b"\xff", pos)
        if pos < 0 or pos + 1 >= len(data):
            return -1
        following = data[pos + 1]
        if following == 0x00 or 0xD0 <= following <= 0xD7 or following == 0xFF:
            pos += 1 if following == 0xFF else 2
            continue
        return pos


def jpeg_problem(data: bytes) -> str | None:
    """Why the JPEG bytes ``data`` are not a whole JPEG file (walked marker by marker up to
    its end-of-image marker), else None."""
    pos = len(JPEG_SOI)
    while True:
        while (
            pos < len(data) and data[pos] == 0xFF and pos + 1 < len(data) and data[pos + 1] == 0xFF
        ):
            pos += 1  # fill bytes before a marker
        if pos + 2 > len(data):
            return "truncated JPEG: no end-of-image marker (FFD9)"
        if data[pos] != 0xFF:
            return f"corrupt JPEG: expected a marker at byte {pos}, found 0x{data[pos]:02x}"
        marker = data[pos + 1]
        if marker == 0xD9:
            return None
        if marker in _STANDALONE:
            pos += 2
            continue
        if pos + 4 > len(data):
            return "truncated JPEG: it ends inside a marker segment (no end-of-image marker)"
        end = pos + 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
        if end > len(data):
            return f"truncated JPEG: it ends inside its 0xff{marker:02x} segment at byte {pos}"
        pos = _scan_end(data, end) if marker == 0xDA else end
        if pos < 0:
            return "truncated JPEG: its image data ends without an end-of-image marker (FFD9)"


OTHER_FORMATS = (
    (b"RIFF", 8, b"WEBP", "WebP"), (b"GIF8", 0, b"", "GIF"), (b"BM", 0, b"", "BMP"),
    (b"II*\x00", 0, b"", "TIFF"), (b"MM\x00*", 0, b"", "TIFF"),
    (b"\x00\x00\x00\x0cjP  ", 0, b"", "JPEG 2000"), (b"\xff\x4f\xff\x51", 0, b"", "JPEG 2000"),
    (b"v/1\x01", 0, b"", "OpenEXR"), (b"", 4, b"ftyp", "HEIF / AVIF"), (b"qoif", 0, b"", "QOI"),
)  # fmt: skip
"""(magic at byte 0, offset of a second mark, the mark, name) of the image formats the decoder
would take that the project does not read: named in the line that refuses them."""
SUFFIXES = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG", ".jpe": "JPEG", ".jfif": "JPEG"}
"""A file name's extension -> the format its content must have."""


def content_format(data: bytes) -> str | None:
    """The image format of a file's bytes, by their magic bytes: ``"PNG"``, ``"JPEG"``, the
    name of another format (:data:`OTHER_FORMATS`), or None (no image format known)."""
    if data.startswith(PNG_SIGNATURE):
        return "PNG"
    if data.startswith(JPEG_SOI):
        return "JPEG"
    for magic, at, mark, name in OTHER_FORMATS:
        if data.startswith(magic) and data[at : at + len(mark)] == mark:
            return name
    return None


def format_problem(path: str | PathLike[str], data: bytes) -> str | None:
    """Why the content ``data`` of the file ``path`` is not an image this reader takes: a format
    other than PNG or JPEG (WebP, BMP, ... which the decoder would take, unchecked), or a PNG
    or JPEG under the other's extension (a name that says what the file is not); else None.
    Content no image format starts as is left to the decoder's ``not a readable image``."""
    found = content_format(data)
    named = SUFFIXES.get(os.path.splitext(os.fspath(path))[1].lower())
    if found not in (None, "PNG", "JPEG"):
        said = f", not the {named} its name says" if named else ", not PNG or JPEG"
        return f"its content is a {found} image{said}"
    if found is not None and named is not None and found != named:
        return f"its content is a {found} image, not the {named} its name says"
    return None


def image_problem(data: bytes) -> str | None:
    """Why ``data`` (a file's bytes) is an incomplete or damaged PNG / JPEG, else None (other
    formats are left to the decoder)."""
    if data.startswith(PNG_SIGNATURE):
        return png_problem(data)
    if data.startswith(JPEG_SOI):
        return jpeg_problem(data)
    return None


def read_image(path: str | PathLike[str], flags: int, what: str = "an image") -> np.ndarray:
    """The pixels of the image file ``path`` as ``cv2.imdecode(..., flags)`` gives them, as
    stored (a JPEG's EXIF orientation is not applied: depth and label images are aligned with
    the stored pixels, as VOC's labels with its JPEGs), after :func:`image_problem`'s check;
    :class:`DataFormatError` naming the file for one that is missing, unreadable, damaged or
    not an image (``what``: what was expected)."""
    return _decode(path, _file_bytes(path, what), flags, what)


def _file_bytes(path: str | PathLike[str], what: str) -> bytes:
    """The bytes of the file ``path``. It is opened at once (the SLAM harness reads three
    images a frame: checking each path's folders first cost as much as 0.1 ms an image); when
    that fails, :func:`~uss_slam.core.paths.input_file` names the problem."""
    try:
        with open(path, "rb") as file:
            return file.read()
    except OSError as error:
        input_file(path, None, f"expected {what}")  # a missing file, a folder, a broken link
        raise DataFormatError(path, f"cannot read it ({error.strerror}); expected {what}") from None


def declared_size(data: bytes) -> tuple[int, int] | None:
    """``(width, height)`` a PNG's header declares, else None (other formats: the decoder's)."""
    if data.startswith(PNG_SIGNATURE) and len(data) >= 24 and data[12:16] == b"IHDR":
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    return None


def _check(path: str | PathLike[str], data: bytes, what: str) -> None:
    """Refuse the file ``path`` of bytes ``data`` before any decoder sees it: empty, damaged,
    not the format its name says, or declaring more pixels than an image may have."""
    problem = (image_problem(data) or format_problem(path, data)) if data else "empty file"
    size = declared_size(data) if not problem else None
    if size is not None and size[0] * size[1] > MAX_PIXELS:
        problem = (
            f"its header declares {size[0]}x{size[1]} pixels, more than an image may have (2^30)"
        )
    if problem:
        raise DataFormatError(path, f"{problem}; expected {what}")


def _decode(path: str | PathLike[str], data: bytes, flags: int, what: str) -> np.ndarray:
    _check(path, data, what)
    if data.startswith(PNG_SIGNATURE):
        data = stored(data)  # the same pixels, inflated by ISA-L: core/png_inflate.py
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), flags | cv2.IMREAD_IGNORE_ORIENTATION)
    except cv2.error as error:  # a limit of the decoder's (a JPEG's declared size, ...)
        first = (str(error).strip().splitlines() or [""])[-1].strip()
        raise DataFormatError(path, f"not a readable image ({first}); expected {what}") from None
    if image is None:
        raise DataFormatError(path, f"not a readable image; expected {what}")
    return image


COLOUR = "a colour image (PNG or JPEG)"


def read_colour(path: str | PathLike[str]) -> np.ndarray:
    """A colour image as ``(H, W, 3)`` uint8 BGR (any channel count in the file; a 16-bit PNG,
    such as a depth image, is refused: :func:`_read_eight_bit`)."""
    return _read_eight_bit(path, cv2.IMREAD_COLOR)


_RGB = getattr(cv2, "IMREAD_COLOR_RGB", None)
"""OpenCV's flag to decode straight to RGB (4.11 on), else None."""


def read_rgb(path: str | PathLike[str]) -> np.ndarray:
    """A colour image as ``(H, W, 3)`` uint8 RGB: :func:`read_colour`'s pixels with the
    channels in RGB order, decoded in that order (no BGR image converted afterwards: ~0.1 CPU
    ms less a 640x480 frame) where OpenCV can."""
    if _RGB is None:  # pragma: no cover - an OpenCV before 4.11
        return cv2.cvtColor(read_colour(path), cv2.COLOR_BGR2RGB)
    return _read_eight_bit(path, _RGB)


def read_grey(path: str | PathLike[str]) -> np.ndarray:
    """A colour image as ``(H, W)`` uint8 grey (a 16-bit PNG refused, as by :func:`read_colour`)."""
    return _read_eight_bit(path, cv2.IMREAD_GRAYSCALE)


def _read_eight_bit(path: str | PathLike[str], flags: int) -> np.ndarray:
    """:func:`read_image` of a colour frame, refusing a PNG whose header says 16 bits per
    channel (the decoder would scale it to 8 bits without a word: a depth image listed as a
    colour frame), from the bytes read once."""
    return _decode(path, _colour_bytes(path), flags, COLOUR)


def check_colour(path: str | PathLike[str]) -> None:
    """Refuse the colour frame ``path`` as :func:`read_colour` would, from its bytes, without
    decoding it (a whole sequence checked before a run's work: ~0.5 CPU ms a 640x480 PNG)."""
    _check(path, _colour_bytes(path), COLOUR)


def _colour_bytes(path: str | PathLike[str]) -> bytes:
    """The bytes of the colour frame ``path``; a PNG whose header says 16 bits per channel is
    refused (:func:`sixteen_bit_problem`)."""
    data = _file_bytes(path, COLOUR)
    problem = sixteen_bit_problem(data)
    if problem:
        raise DataFormatError(path, problem)
    return data


def sixteen_bit_problem(head: bytes) -> str | None:
    """Why a colour frame whose first bytes (26 or more) are ``head`` is refused: a PNG whose
    header says 16 bits per channel; else None."""
    if head.startswith(PNG_SIGNATURE) and len(head) >= 26 and head[24] == 16:
        return f"a 16-bit PNG (a depth image?); expected an 8-bit {COLOUR[2:]}"
    return None


def read_depth(path: str | PathLike[str]) -> np.ndarray:
    """A depth image as stored (``(H, W)`` uint16 for TUM's 5000-per-metre PNGs; checking the
    type is the caller's)."""
    return read_image(path, cv2.IMREAD_UNCHANGED, "a 16-bit depth PNG")


def read_labels(path: str | PathLike[str], num_classes: int = len(CLASS_NAMES)) -> np.ndarray:
    """A label image of class ids: ``(H, W)`` uint8, every value a class id
    (``0..num_classes-1``) or the ignore label 255; anything else names the file, the first
    values outside them and the accepted ones."""
    labels = read_label_values(path)
    check_label_values(path, labels, num_classes)
    return labels


def read_label_values(path: str | PathLike[str]) -> np.ndarray:
    """The stored values of a label image, ``(H, W)`` uint8: a greyscale PNG's, a palette PNG's
    indices; its structure checked whole, its values not (a data set's own ids, VOC's 0..20,
    are mapped by its reader; :func:`read_labels` checks the project's)."""
    what = "a single-channel uint8 class-id PNG"
    data = _file_bytes(path, what)
    indexed = palette_as_grey(data)  # None for the usual greyscale labels: checked once below
    if indexed and image_problem(data):  # a damaged palette PNG: named on its own bytes
        indexed = None
    labels = _decode(path, indexed[0] if indexed else data, cv2.IMREAD_UNCHANGED, what)
    if indexed and indexed[1] < 8 and labels.dtype == np.uint8:  # 1/2/4-bit indices: scaled
        labels = labels // (255 // (2 ** indexed[1] - 1))  # to 0..255 by the decoder
    if labels.dtype != np.uint8 or labels.ndim != 2:
        raise DataFormatError(
            path,
            f"expected a single-channel uint8 class-id PNG, got {labels.dtype} "
            f"with shape {labels.shape}",
        )
    return labels


def palette_as_grey(data: bytes) -> tuple[bytes, int] | None:
    """A palette PNG (colour type 3: a labelling tool's or VOC's ``SegmentationClass``, whose
    indices are the class ids) rewritten as the greyscale PNG of its indices (the decoder would
    expand the palette to colours), with its bit depth; None for any other image. The image
    data is untouched: only ``IHDR``'s colour type changes and ``PLTE`` / ``tRNS`` go."""
    if not data.startswith(PNG_SIGNATURE) or len(data) < 33 or data[12:16] != b"IHDR":
        return None
    if data[25] != 3:
        return None
    header = bytearray(data[8:33])
    header[17] = 0  # colour type: greyscale (byte 25 of the file)
    header[21:25] = crc32(bytes(header[4:21])).to_bytes(4, "big")
    out, pos = [PNG_SIGNATURE, bytes(header)], 33
    while pos + 8 <= len(data):
        end = pos + 12 + int.from_bytes(data[pos : pos + 4], "big")
        if data[pos + 4 : pos + 8] not in (b"PLTE", b"tRNS"):
            out.append(data[pos:end])
        pos = end
    return b"".join(out), data[24]


def check_label_values(
    path: str | PathLike[str], labels: np.ndarray, num_classes: int = len(CLASS_NAMES)
) -> None:
    """Refuse label values other than the class ids ``0..num_classes-1`` and 255 (ignore).

    Only the pixels at or above ``num_classes`` are counted (a uint8 comparison is ~20x faster
    than counting a whole 640x480 image: the SLAM harness checks every frame's labels)."""
    high = labels[labels >= num_classes]
    if not high.size:
        return
    counts = np.bincount(high.reshape(-1), minlength=256)
    counts[:num_classes] = 0
    counts[IGNORE_INDEX] = 0
    bad = np.flatnonzero(counts)
    if bad.size:
        shown = ", ".join(str(v) for v in bad[:5]) + (", ..." if bad.size > 5 else "")
        raise DataFormatError(
            path,
            f"label values {shown} are not class ids; expected 0..{num_classes - 1} "
            f"({', '.join(CLASS_NAMES[:num_classes])}) or {IGNORE_INDEX} (ignore)",
        )
