"""The preparations of the seventh fresh set (``studies/fresh_cases7.txt``): valid image files
of forms the earlier sets did not try (Adam7-interlaced PNG colour, depth and label images; a
PNG whose image data is split over several IDAT chunks, one of them empty; JPEG frames as
phones and cameras write them: an EXIF block holding a thumbnail JPEG, zero bytes after the
end-of-image marker, a ``.jpeg`` name, greyscale); text and config files as Windows editors
write them (a UTF-8 byte-order mark on ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``,
``intrinsics.yaml``, a VOC image list, a vocabulary and a user's Hydra config; CRLF line ends
in a sequence's ``intrinsics.yaml`` and a user's config; a tab indenting a user's config);
trajectories with ``%`` comments, upper-case exponents, ``+`` signs, NUL bytes or a DOS
end-of-file byte at the end, a NaN quaternion or long decimals; a home folder holding inputs
(for ``~`` that a script expands itself); a read-only folder for ``TMPDIR``; a folder path of
about 2800 bytes (under the 4096 limit) holding a sequence; a training run without its
``last.ckpt`` and the best checkpoint of a run copied out."""

from __future__ import annotations

import shutil
import struct
import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from fresh_setups import Setup, _gt_rows, _seq_edit
from fresh_setups3 import _nth, _voc_edit
from fresh_setups5 import ROOT, SEQ_PLAIN, _user_config
from PIL import Image

DEEP_OK = "/".join(["d" * 200] * 14)
"""14 names of 200 bytes (2813 bytes): a long path the file system takes (under 4096)."""


# ------------------------------------------------------------------------------ PNG forms
def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    out, at = [], 8
    while at < len(data):
        (length,) = struct.unpack(">I", data[at : at + 4])
        out.append((data[at + 4 : at + 8], data[at + 8 : at + 8 + length]))
        at += 12 + length
    return out


ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
         (0, 1, 1, 2))  # fmt: skip
"""Adam7's passes: (x0, y0, dx, dy)."""


def _interlaced_png(image: np.ndarray) -> bytes:
    """``image`` (H x W grey or H x W x 3 BGR, uint8 or uint16) as an Adam7-interlaced PNG."""
    if image.ndim == 3:
        image = image[:, :, ::-1]  # BGR -> RGB
    h, w = image.shape[:2]
    depth = 16 if image.dtype == np.uint16 else 8
    colour = 2 if image.ndim == 3 else 0
    raw = b""
    for x0, y0, dx, dy in ADAM7:
        sub = image[y0::dy, x0::dx]
        if sub.size == 0:
            continue
        data = sub.astype(">u2").tobytes() if depth == 16 else sub.tobytes()
        row = len(data) // sub.shape[0]
        raw += b"".join(b"\x00" + data[i * row : (i + 1) * row] for i in range(sub.shape[0]))
    header = struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 1)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header)
            + _chunk(b"IDAT", zlib.compress(raw, 9)) + _chunk(b"IEND", b""))  # fmt: skip


def _interlace(folder: str, k: int = 2) -> Callable[[Path], None]:
    """Image ``k`` of ``folder`` written again as an Adam7-interlaced PNG (the same pixels)."""

    def change(seq: Path) -> None:
        path = _nth(seq, folder, k)
        path.write_bytes(_interlaced_png(cv2.imread(str(path), cv2.IMREAD_UNCHANGED)))

    return change


def _split_idat(seq: Path) -> None:
    """Colour frame 2's image data split over three IDAT chunks and an empty one (valid PNG)."""
    path = _nth(seq, "rgb")
    chunks = _chunks(path.read_bytes())
    data = b"".join(d for kind, d in chunks if kind == b"IDAT")
    third = max(len(data) // 3, 1)
    parts = [data[:third], b"", data[third : 2 * third], data[2 * third :]]
    out = b"\x89PNG\r\n\x1a\n"
    for kind, d in chunks:
        if kind == b"IDAT":
            out += b"".join(_chunk(b"IDAT", p) for p in parts)
            parts = []
        else:
            out += _chunk(kind, d)
    path.write_bytes(out)


# ------------------------------------------------------------------------------ JPEG forms
def _exif_with_thumbnail(image: Image.Image) -> bytes:
    """An APP1 ``Exif`` segment as a phone writes it: a TIFF header, an empty IFD0 and a 40x30
    thumbnail JPEG (its own SOI ... EOI markers inside the segment)."""
    from io import BytesIO

    thumb = BytesIO()
    image.resize((40, 30)).save(thumb, "JPEG", quality=70)
    body = b"Exif\x00\x00" + b"II*\x00\x08\x00\x00\x00" + b"\x00\x00" + b"\x00\x00\x00\x00"
    body += thumb.getvalue()
    return b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body


def _jpeg_bytes(path: Path, mode: str = "RGB") -> bytes:
    from io import BytesIO

    out = BytesIO()
    Image.open(path).convert(mode).save(out, "JPEG", quality=92)
    return out.getvalue()


def _as_jpeg(edit: Callable[[bytes, Image.Image], bytes], mode: str = "RGB",
             suffix: str = ".jpg") -> Callable[[Path], None]:  # fmt: skip
    """Every colour frame as a JPEG (``rgb.txt`` listing it), its bytes passed through ``edit``."""

    def change(seq: Path) -> None:
        for path in sorted((seq / "rgb").iterdir()):
            data = edit(_jpeg_bytes(path, mode), Image.open(path).convert("RGB"))
            path.with_suffix(suffix).write_bytes(data)
            path.unlink()
        _rewrite_rows(seq / "rgb.txt", lambda x: x.replace(".png", suffix))

    return change


def _with_exif(data: bytes, image: Image.Image) -> bytes:
    return data[:2] + _exif_with_thumbnail(image) + data[2:]


def _padded(data: bytes, image: Image.Image) -> bytes:
    """256 zero bytes after the end-of-image marker (cameras pad files to a block size)."""
    return data + b"\x00" * 256


def _voc_jpegs(edit: Callable[[bytes, Image.Image], bytes]) -> Callable[[Path], None]:
    def change(voc: Path) -> None:
        for path in sorted((voc / "JPEGImages").iterdir()):
            path.write_bytes(edit(_jpeg_bytes(path), Image.open(path).convert("RGB")))

    return change


# ------------------------------------------------------------------------------ text files
def _rewrite_rows(path: Path, change: Callable[[str], str]) -> None:
    lines = path.read_text().splitlines()
    out = [x if x.startswith("#") or not x.strip() else change(x) for x in lines]
    path.write_text("\n".join(out) + "\n")


def _bom(name: str) -> Callable[[Path], None]:
    """A UTF-8 byte-order mark before ``name``'s first line (as Windows Notepad saves)."""

    def change(folder: Path) -> None:
        path = folder / name
        path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())

    return change


def _crlf(name: str) -> Callable[[Path], None]:
    def change(folder: Path) -> None:
        path = folder / name
        path.write_bytes(path.read_bytes().replace(b"\n", b"\r\n"))

    return change


def _traj(name: str, text: Callable[[list[str]], str | bytes]) -> Setup:
    def setup(c: Path, world: dict[str, str]) -> None:
        out = text(_gt_rows(world))
        (c / name).write_bytes(out if isinstance(out, bytes) else out.encode())

    return setup


def _numbers(rows: list[str], form: Callable[[float], str]) -> str:
    return "\n".join(" ".join(form(float(v)) for v in r.split()) for r in rows) + "\n"


def _nan_quaternion(rows: list[str]) -> str:
    parts = rows[4].split()
    rows[4] = " ".join(parts[:7] + ["nan"])
    return "\n".join(rows) + "\n"


def _config_text(group: str, world: dict[str, str]) -> str:
    if group == "sequence":
        return SEQ_PLAIN.format(**world)
    if group == "experiment":
        return (ROOT / "configs" / "experiment" / "ci.yaml").read_text()
    return (ROOT / "configs" / "scale" / "quick.yaml").read_text()


def _user_config_as(group: str, change: Callable[[str], str]) -> Setup:
    """``{C}/cfg/<group>/mine.yaml``: a valid config (a sequence, ``ci.yaml``, ``quick.yaml``)
    as ``change`` writes it (a byte-order mark, CRLF ends, a tab)."""

    def setup(c: Path, world: dict[str, str]) -> None:
        (c / "cfg" / group).mkdir(parents=True, exist_ok=True)
        (c / "cfg" / group / "mine.yaml").write_bytes(change(_config_text(group, world)).encode())

    return setup


def _tab_indented(text: str) -> str:
    """The second top-level line of a config indented by a tab (YAML forbids tabs there)."""
    lines = text.splitlines()
    rows = [i for i, x in enumerate(lines) if x and not x.startswith(("#", " "))]
    lines[rows[1]] = "\t" + lines[rows[1]]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------ folders
def _home(*names: str) -> Setup:
    """``{C}/home`` (for ``HOME={C}/home``) holding copies of the world's ``names``."""

    def setup(c: Path, world: dict[str, str]) -> None:
        (c / "home").mkdir()
        for name in names:
            source = Path(world[name])
            target = c / "home" / ("init.ckpt" if name == "ckpt" else name)
            if source.is_dir():
                shutil.copytree(source, target)
            else:
                shutil.copy(source, target)

    return setup


def _ro_tmpdir(c: Path, world: dict[str, str]) -> None:
    (c / "rotmp").mkdir()
    (c / "rotmp").chmod(0o555)


def _deep_seq(c: Path, world: dict[str, str]) -> None:
    """The sequence copied to ``{C}/<DEEP_OK>/seq``."""
    shutil.copytree(world["seq"], c / DEEP_OK / "seq")


def _run_without_last(c: Path, world: dict[str, str]) -> None:
    """A copy of the world's training run (``{C}/train``) whose ``last.ckpt`` was deleted."""
    shutil.copytree(Path(world["ckpt"]).parents[1], c / "train")
    (c / "train" / "checkpoints" / "last.ckpt").unlink()


def _best_ckpt(c: Path, world: dict[str, str]) -> None:
    """The world run's best checkpoint (``best_iter..._miou....ckpt``) copied to ``{C}/best.ckpt``."""
    best = sorted(Path(world["ckpt"]).parent.glob("best_*.ckpt"))[-1]
    shutil.copy(best, c / "best.ckpt")


def _vocab_bom(c: Path, world: dict[str, str]) -> None:
    (c / "bom.txt").write_bytes(b"\xef\xbb\xbf" + Path(world["vocab"]).read_bytes())


SEVENTH: dict[str, Setup] = {
    "rgb_interlaced": _seq_edit(_interlace("rgb")),
    "depth_interlaced": _seq_edit(_interlace("depth")),
    "label_interlaced": _seq_edit(_interlace("labels", k=0)),
    "rgb_split_idat": _seq_edit(_split_idat),
    "rgb_jpeg_exif": _seq_edit(_as_jpeg(_with_exif)),
    "rgb_jpeg_padded": _seq_edit(_as_jpeg(_padded)),
    "rgb_jpeg_ext": _seq_edit(_as_jpeg(lambda d, im: d, suffix=".jpeg")),
    "rgb_jpeg_grey": _seq_edit(_as_jpeg(lambda d, im: d, mode="L")),
    "voc_exif": _voc_edit(_voc_jpegs(_with_exif)),
    "voc_padded": _voc_edit(_voc_jpegs(_padded)),
    "voc_list_bom": _voc_edit(lambda v: _bom("ImageSets/Segmentation/train.txt")(v)),
    "rgb_txt_bom": _seq_edit(_bom("rgb.txt")),
    "depth_txt_bom": _seq_edit(_bom("depth.txt")),
    "gt_txt_bom": _seq_edit(_bom("groundtruth.txt")),
    "intr_bom": _seq_edit(_bom("intrinsics.yaml")),
    "intr_crlf": _seq_edit(_crlf("intrinsics.yaml")),
    "vocab_bom": _vocab_bom,
    "userconf_seq_bom": _user_config_as("sequence", lambda t: "\ufeff" + t),
    "userconf_seq_crlf": _user_config_as("sequence", lambda t: t.replace("\n", "\r\n")),
    "userconf_seq_tab": _user_config_as("sequence", _tab_indented),
    "userconf_train_bom": _user_config_as("experiment", lambda t: "\ufeff" + t),
    "userconf_train_crlf": _user_config_as("experiment", lambda t: t.replace("\n", "\r\n")),
    "userconf_train_tab": _user_config_as("experiment", _tab_indented),
    "userconf_scale_bom": _user_config_as("scale", lambda t: "\ufeff" + t),
    "userconf_scale_crlf": _user_config_as("scale", lambda t: t.replace("\n", "\r\n")),
    "userconf_scale_tab": _user_config_as("scale", _tab_indented),
    "userconf_seq_plain": _user_config("sequence", lambda w: SEQ_PLAIN.format(**w)),
    "gt_percent_comments": _traj(
        "pct.txt", lambda r: "% timestamp tx ty tz qx qy qz qw\n" + "\n".join(r) + "\n"
    ),  # fmt: skip
    "gt_upper_exponent": _traj("upper.txt", lambda r: _numbers(r, lambda v: f"{v:.16E}")),
    "gt_plus_signs": _traj("plus.txt", lambda r: _numbers(r, lambda v: f"{v:+.7f}")),
    "gt_long_decimals": _traj("long.txt", lambda r: _numbers(r, lambda v: f"{v:.15f}")),
    "gt_nul_tail": _traj("nul.txt", lambda r: ("\n".join(r) + "\n").encode() + b"\x00" * 64),
    "gt_ctrl_z": _traj("ctrlz.txt", lambda r: ("\n".join(r) + "\n").encode() + b"\x1a"),
    "gt_nan_quaternion": _traj("nanq.txt", _nan_quaternion),
    "home_seq": _home("seq"),
    "home_ckpt": _home("ckpt"),
    "ro_tmpdir": _ro_tmpdir,
    "deep_seq": _deep_seq,
    "run_without_last": _run_without_last,
    "best_ckpt": _best_ckpt,
}
