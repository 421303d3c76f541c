"""The preparations of the fourth fresh set (``studies/fresh_cases4.txt``): colour frames in
other PNG forms (grey, with alpha, palette), saturated depth, frame lists with an extra column,
a repeated row, trailing blanks, absolute file names or fewer depth rows, trajectories with
comments inside, leading blanks, unnormalised quaternions, one pose, every other pose or
millisecond stamps, VOC trees with a list in CRLF, a repeated id, grey labels, a PNG named
``.jpg``, a label of another size or missing, an empty list; models cut in half or of random
bytes, a checkpoint named ``.pt``, a vocabulary with a line of text appended, an unreadable
frames folder, a read-only copy of a sequence, earlier outputs of ``uss-eval`` and of a
``ci`` export, and packages missing that the third set did not remove."""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from fresh_setups import Setup, _gt_rows, _seq_edit, seqcopy
from fresh_setups3 import _nth, _run_quiet, _voc_edit, nomod
from PIL import Image


# ------------------------------------------------------------------------------ frames
def _rgb_form(mode: str) -> Callable[[Path], None]:
    """Colour frame 2 saved again as a PIL image of ``mode`` ('L', 'RGBA' or 'P')."""

    def edit(seq: Path) -> None:
        path = _nth(seq, "rgb")
        with Image.open(path) as image:
            other = image.convert(mode)
        other.save(path)

    return edit


def _depth_saturated(seq: Path) -> None:
    path = _nth(seq, "depth")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), np.full_like(image, 65535))


def _list_edit(name: str, change: Callable[[list[str]], list[str]]) -> Callable[[Path], None]:
    def edit(seq: Path) -> None:
        lines = (seq / name).read_text().splitlines()
        (seq / name).write_text("\n".join(change(lines)) + "\n")

    return edit


def _rows(change: Callable[[list[str]], list[str]]) -> Callable[[list[str]], list[str]]:
    """``change`` applied to the rows (not the comments) of a list."""

    def apply(lines: list[str]) -> list[str]:
        head = [x for x in lines if x.startswith("#")]
        return head + change([x for x in lines if x.strip() and not x.startswith("#")])

    return apply


def _absolute(seq: Path) -> None:
    lines = (seq / "rgb.txt").read_text().splitlines()
    out = [x if x.startswith("#") or not x.strip() else
           f"{x.split()[0]} {seq / x.split()[1]}" for x in lines]  # fmt: skip
    (seq / "rgb.txt").write_text("\n".join(out) + "\n")


def _unreadable_rgb(seq: Path) -> None:
    (seq / "rgb").chmod(0o000)


def _readonly_tree(c: Path, world: dict[str, str]) -> None:
    """A copy of the sequence whose files and folders are all read-only."""
    seqcopy(c, world)
    for path in sorted((c / "seq").rglob("*"), reverse=True):
        path.chmod(0o555 if path.is_dir() else 0o444)
    (c / "seq").chmod(0o555)


# ------------------------------------------------------------------------------ trajectories
def _traj(name: str, change: Callable[[list[str]], str]) -> Setup:
    def setup(c: Path, world: dict[str, str]) -> None:
        (c / name).write_text(change(_gt_rows(world)))

    return setup


def _scaled_quaternions(rows: list[str]) -> str:
    out = []
    for row in rows:
        v = row.split()
        out.append(" ".join(v[:4] + [f"{2 * float(q):.6f}" for q in v[4:8]]))
    return "\n".join(out) + "\n"


def _milliseconds(rows: list[str]) -> str:
    return "\n".join(f"{float(r.split()[0]) * 1000:.3f} {' '.join(r.split()[1:])}"
                     for r in rows) + "\n"  # fmt: skip


# ------------------------------------------------------------------------------ VOC trees
def _voc_list(change: Callable[[list[str]], str]) -> Callable[[Path], None]:
    def edit(voc: Path) -> None:
        path = voc / "ImageSets" / "Segmentation" / "train.txt"
        path.write_text(change(path.read_text().split()))

    return edit


def _voc_grey_labels(voc: Path) -> None:
    for png in sorted((voc / "SegmentationClass").iterdir()):
        with Image.open(png) as image:
            values = np.array(image)
        Image.fromarray(values, mode="L").save(png)


def _voc_png_as_jpg(voc: Path) -> None:
    jpg = sorted((voc / "JPEGImages").iterdir())[2]
    with Image.open(jpg) as image:
        image.load()
        image.save(jpg, format="PNG")


def _voc_label_size(voc: Path) -> None:
    png = sorted((voc / "SegmentationClass").iterdir())[3]
    with Image.open(png) as image:
        image.resize((image.width // 2, image.height // 2), Image.NEAREST).save(png)


def _voc_drop_label(voc: Path) -> None:
    sorted((voc / "SegmentationClass").iterdir())[4].unlink()


# ------------------------------------------------------------------------------ model files
def _half(key: str, name: str) -> Setup:
    def setup(c: Path, world: dict[str, str]) -> None:
        data = Path(world[key]).read_bytes()
        (c / name).write_bytes(data[: len(data) // 2])

    return setup


def _vocab_appended(c: Path, world: dict[str, str]) -> None:
    text = Path(world["vocab"]).read_text()
    (c / "v.txt").write_text(text + "and a line of notes at the end\n")


def evaldone(c: Path, world: dict[str, str]) -> None:
    """An earlier ``uss-eval`` of every 5th frame into ``{C}/e``, and a note of the user's."""
    _run_quiet("uss-eval", world["onnx"], "--sequence", world["seq"], "--stride", "5",
               "--out", str(c / "e"), cwd=c)  # fmt: skip
    (c / "e" / "my_notes.txt").write_text("keep me\n")


FOURTH: dict[str, Setup] = {
    "rgb_grey": _seq_edit(_rgb_form("L")),
    "rgb_rgba": _seq_edit(_rgb_form("RGBA")),
    "rgb_palette": _seq_edit(_rgb_form("P")),
    "depth_saturated": _seq_edit(_depth_saturated),
    "rgb_txt_third_column": _seq_edit(
        _list_edit(
            "rgb.txt", _rows(lambda r: [x + " extra" if i == 3 else x for i, x in enumerate(r)])
        )
    ),
    "rgb_txt_repeated_row": _seq_edit(_list_edit("rgb.txt", _rows(lambda r: r[:6] + r[5:]))),
    "rgb_txt_trailing_blanks": _seq_edit(_list_edit("rgb.txt", lambda r: [x + " \t" for x in r])),
    "rgb_txt_absolute": _seq_edit(_absolute),
    "depth_txt_fewer": _seq_edit(_list_edit("depth.txt", _rows(lambda r: r[:-5]))),
    "rgb_unreadable": _seq_edit(_unreadable_rgb),
    "seq_readonly": _readonly_tree,
    "gt_mid_comments": _traj(
        "mid.txt", lambda r: "\n".join(r[:5] + ["# paused here", ""] + r[5:]) + "\n"
    ),
    "gt_leading_blanks": _traj("lead.txt", lambda r: "\n".join("  " + x for x in r) + "\n"),
    "gt_scaled_quat": _traj("q2.txt", _scaled_quaternions),
    "gt_one_pose": _traj("one.txt", lambda r: r[0] + "\n"),
    "gt_every_other": _traj("half.txt", lambda r: "\n".join(r[::2]) + "\n"),
    "gt_ms_stamps": _traj("ms.txt", _milliseconds),
    "gt_no_final_newline": _traj("nonl.txt", lambda r: "\n".join(r)),
    "voc_list_crlf": _voc_edit(_voc_list(lambda ids: "\r\n".join(ids) + "\r\n\r\n")),
    "voc_list_repeated_id": _voc_edit(_voc_list(lambda ids: "\n".join(ids + ids[:1]) + "\n")),
    "voc_list_empty": _voc_edit(_voc_list(lambda ids: "")),
    "voc_grey_labels": _voc_edit(_voc_grey_labels),
    "voc_png_as_jpg": _voc_edit(_voc_png_as_jpg),
    "voc_label_size": _voc_edit(_voc_label_size),
    "voc_drop_label": _voc_edit(_voc_drop_label),
    "onnx_half": _half("onnx", "half.onnx"),
    "onnx_random": lambda c, w: (c / "r.onnx").write_bytes(os.urandom(4096)),
    "ckpt_as_pt": lambda c, w: shutil.copy(w["ckpt"], c / "model.pt"),
    "vocab_appended": _vocab_appended,
    "evaldone": evaldone,
    "nomod_onnx": nomod("onnx"),
    "nomod_lightning": nomod("lightning"),
    "nomod_hydra": nomod("hydra"),
    "nomod_numpy": nomod("numpy"),
    "nomod_yaml": nomod("yaml"),
    "nomod_PIL": nomod("PIL"),
    "nomod_torch": nomod("torch"),
    "nomod_tensorboard": nomod("tensorboard"),
    "homedir": lambda c, w: (c / "home").mkdir(),
}
