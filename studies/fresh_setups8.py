"""The preparations of the eighth fresh set (``studies/fresh_cases8.txt``): valid image files
of forms the earlier sets did not try (a colour frame as grey with alpha, 1-bit grey, a 2-bit
palette, an animated PNG whose first frame is the image, CMYK JPEG frames, VOC images saved
as progressive JPEG or with an EXIF orientation tag) and forms the docs refuse (a 16-bit RGB
colour frame, a PNG named ``.jpg``, a folder named like a frame); sequence folders with names
that shells and format strings give a meaning to (``%``, ``{}``, ``$``, ``*?[]``, ``#;&|``,
a newline, a tab, a quote, ``=``, ``,``, parentheses, a trailing space, an emoji, a combining
accent); an ONNX model whose weights are in an external data file, present or gone; a user's
sequence config written as JSON or left empty; an earlier vocabulary to replace; a file where
a settings folder is expected.

``PARTS`` are path parts the cases' templates may name (``{nl}``, ``{pct}``, ...), and
``{big}`` a 4401-digit integer (more digits than Python converts by default)."""

from __future__ import annotations

import shutil
import struct
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from fresh_setups import Setup, _seq_edit
from fresh_setups3 import _nth, _voc_edit
from fresh_setups7 import _as_jpeg, _chunk, _chunks, _rewrite_rows
from PIL import Image

PARTS = {
    "nl": "new\nline",
    "tab": "a\tb",
    "glob": "a*b?[c]",
    "pct": "100% {x} %s",
    "dollar": "$HOME",
    "hash": "#1;&|",
    "quote": "it's",
    "eq": "a=b",
    "comma": "a,b",
    "paren": "run(1)",
    "spend": "end ",
    "emoji": "seq 😀",
    "nfd": "se\u0301q",
    "big": "1" + "0" * 4400,
}
"""Path parts (and one number) of the eighth set's templates."""


# ------------------------------------------------------------------------------ PNG forms
def _frame_as(save: Callable[[Image.Image, Path], None]) -> Callable[[Path], None]:
    """Colour frame 2 written again by ``save`` (the same picture, another PNG form)."""

    def change(seq: Path) -> None:
        path = _nth(seq, "rgb")
        image = Image.open(path).convert("RGB")
        path.unlink()
        save(image, path)

    return change


def _la(image: Image.Image, path: Path) -> None:
    image.convert("LA").save(path, "PNG")


def _one_bit(image: Image.Image, path: Path) -> None:
    image.convert("1").save(path, "PNG")


def _palette_2bit(image: Image.Image, path: Path) -> None:
    image.convert("P", palette=Image.Palette.ADAPTIVE, colors=4).save(path, "PNG", bits=2)


def _rgb16(image: Image.Image, path: Path) -> None:
    bgr = np.asarray(image)[:, :, ::-1].astype(np.uint16) * 257
    cv2.imwrite(str(path), bgr)


def _apng(image: Image.Image, path: Path) -> None:
    """An animated PNG of one frame whose default image is the frame (acTL, fcTL before IDAT)."""
    image.save(path, "PNG")
    chunks = _chunks(path.read_bytes())
    w, h = image.size
    actl = struct.pack(">II", 1, 0)
    fctl = struct.pack(">IIIIIHHBB", 0, w, h, 0, 0, 1, 30, 0, 0)
    out = b"\x89PNG\r\n\x1a\n"
    for kind, data in chunks:
        if kind == b"IDAT" and actl:
            out += _chunk(b"acTL", actl) + _chunk(b"fcTL", fctl)
            actl = b""
        out += _chunk(kind, data)
    path.write_bytes(out)


def _png_named_jpg(seq: Path) -> None:
    """Colour frame 2 (a PNG) renamed ``.jpg`` and listed so in ``rgb.txt``."""
    path = _nth(seq, "rgb")
    path.rename(path.with_suffix(".jpg"))
    _rewrite_rows(seq / "rgb.txt", lambda x: x.replace(path.name, path.with_suffix(".jpg").name))


def _folder_as_frame(seq: Path) -> None:
    """Colour frame 2 replaced by an empty folder of the same name (``rgb/<stamp>.png/``)."""
    path = _nth(seq, "rgb")
    path.unlink()
    path.mkdir()


# ------------------------------------------------------------------------------ VOC forms
def _voc_progressive(voc: Path) -> None:
    for path in sorted((voc / "JPEGImages").iterdir()):
        Image.open(path).convert("RGB").save(path, "JPEG", quality=90, progressive=True)


def _exif_orientation(value: int) -> bytes:
    """An APP1 Exif segment whose IFD0 holds one tag: Orientation (0x0112) = ``value``."""
    ifd = b"\x01\x00" + struct.pack("<HHIHH", 0x0112, 3, 1, value, 0) + b"\x00\x00\x00\x00"
    body = b"Exif\x00\x00" + b"II*\x00\x08\x00\x00\x00" + ifd
    return b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body


def _voc_rotated_tag(voc: Path) -> None:
    """Every VOC image with an EXIF orientation tag of 6 (a phone held upright); the stored
    pixels are unchanged, so the labels still match them."""
    for path in sorted((voc / "JPEGImages").iterdir()):
        data = path.read_bytes()
        path.write_bytes(data[:2] + _exif_orientation(6) + data[2:])


# ------------------------------------------------------------------------------ folders, files
def _seq_named(part: str) -> Setup:
    """The world's sequence copied to ``{C}/<PARTS[part]>``."""

    def setup(c: Path, world: dict[str, str]) -> None:
        shutil.copytree(world["seq"], c / PARTS[part])

    return setup


def _vocab_copy(c: Path, world: dict[str, str]) -> None:
    """An earlier vocabulary at ``{C}/v.txt`` (the world's)."""
    shutil.copy(world["vocab"], c / "v.txt")


def _onnx_external(gone: bool) -> Setup:
    """The world's model saved as ``{C}/ext/m.onnx`` with its weights in ``m.onnx.data`` beside
    it (ONNX's external data, as large models are saved); ``gone``: that file deleted."""

    def setup(c: Path, world: dict[str, str]) -> None:
        import onnx

        (c / "ext").mkdir()
        model = onnx.load(world["onnx"])
        onnx.save_model(model, str(c / "ext" / "m.onnx"), save_as_external_data=True,
                        all_tensors_to_one_file=True, location="m.onnx.data",
                        size_threshold=0)  # fmt: skip
        if gone:
            (c / "ext" / "m.onnx.data").unlink()

    return setup


def _a_file(name: str) -> Setup:
    def setup(c: Path, world: dict[str, str]) -> None:
        (c / name).write_text("not a folder\n")

    return setup


def _user_sequence(text: Callable[[dict[str, str]], str]) -> Setup:
    def setup(c: Path, world: dict[str, str]) -> None:
        (c / "cfg" / "sequence").mkdir(parents=True)
        (c / "cfg" / "sequence" / "mine.yaml").write_text(text(world))

    return setup


EIGHTH: dict[str, Setup] = {
    "rgb_la": _seq_edit(_frame_as(_la)),
    "rgb_1bit": _seq_edit(_frame_as(_one_bit)),
    "rgb_palette_2bit": _seq_edit(_frame_as(_palette_2bit)),
    "rgb_rgb16": _seq_edit(_frame_as(_rgb16)),
    "rgb_apng": _seq_edit(_frame_as(_apng)),
    "rgb_jpeg_cmyk": _seq_edit(_as_jpeg(lambda d, im: d, mode="CMYK")),
    "rgb_png_named_jpg": _seq_edit(_png_named_jpg),
    "rgb_folder_as_frame": _seq_edit(_folder_as_frame),
    "voc_progressive": _voc_edit(_voc_progressive),
    "voc_rotated_tag": _voc_edit(_voc_rotated_tag),
    **{f"seq_{part}": _seq_named(part) for part in PARTS if part != "big"},
    "vocab_copy": _vocab_copy,
    "onnx_external": _onnx_external(gone=False),
    "onnx_external_gone": _onnx_external(gone=True),
    "xdg_file": _a_file("xdg"),
    "userconf_seq_json": _user_sequence(
        lambda w: '{{"path": "{seq}", "stride": 2, "max_frames": 10}}\n'.format(**w)
    ),
    "userconf_seq_empty": _user_sequence(lambda w: ""),
}
