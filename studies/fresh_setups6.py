"""The preparations of the sixth fresh set (``studies/fresh_cases6.txt``): frames as image
editors and other systems leave them (a PNG re-saved with a text chunk and a colour profile,
bytes after a PNG's end, progressive JPEG frames, upper-case ``.PNG`` names, macOS and Windows
side files beside the frames, palette label PNGs, float TIFF depth images); frame lists with
``./`` or Windows ``\\`` separators, depth stamps a second off the colour stamps, a sequence of
five frames; trajectories in other tools' formats (EuRoC's CSV, KITTI's poses, decimal commas), with
stamps from 0 or UTF-8 comments; labels that are all 255; an estimate scaled by 2; a user's own files in an earlier run's folder; a user's own
``slam`` and ``trainer`` config groups; a checkpoint copied out of its run folder; a VOC set in
the target style; a binary vocabulary and one under a non-ASCII name; and the output of one console script still being written when another is
pointed at it (a background run of the first)."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from fresh_setups import Setup, _gt_rows, _seq_edit
from fresh_setups3 import BIN, _nth, background
from fresh_setups5 import ROOT, _user_config
from PIL import Image, PngImagePlugin


# ------------------------------------------------------------------------------ images
def _editor_chunks(seq: Path) -> None:
    """Colour frame 2 re-saved as an image editor does: a ``tEXt`` chunk and an sRGB ICC profile."""
    path = _nth(seq, "rgb")
    info = PngImagePlugin.PngInfo()
    info.add_text("Software", "GIMP 2.10")
    from PIL import ImageCms

    profile = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    Image.open(path).save(path, "PNG", pnginfo=info, icc_profile=profile)


def _trailing_bytes(seq: Path) -> None:
    """64 bytes after colour frame 2's IEND chunk (some converters pad files)."""
    path = _nth(seq, "rgb")
    path.write_bytes(path.read_bytes() + b"\x00" * 64)


def _rewrite_list(seq: Path, name: str, change: Callable[[str], str]) -> None:
    lines = (seq / name).read_text().splitlines()
    out = [x if x.startswith("#") or not x.strip() else change(x) for x in lines]
    (seq / name).write_text("\n".join(out) + "\n")


def _progressive_jpeg(seq: Path) -> None:
    """Every colour frame as a progressive JPEG (quality 95), ``rgb.txt`` listing ``.jpg``."""
    for path in sorted((seq / "rgb").iterdir()):
        Image.open(path).convert("RGB").save(path.with_suffix(".jpg"), "JPEG", quality=95,
                                             progressive=True)  # fmt: skip
        path.unlink()
    _rewrite_list(seq, "rgb.txt", lambda x: x.replace(".png", ".jpg"))


def _upper_ext(seq: Path) -> None:
    """Every colour frame named ``.PNG`` (as Windows tools write), listed so in ``rgb.txt``."""
    for path in sorted((seq / "rgb").iterdir()):
        path.rename(path.with_suffix(".PNG"))
    _rewrite_list(seq, "rgb.txt", lambda x: x.replace(".png", ".PNG"))


def _os_junk(seq: Path) -> None:
    """A folder copied from a Mac or Windows: ``.DS_Store``, AppleDouble ``._x.png`` files (not
    PNGs), ``Thumbs.db`` beside the frames and labels, and a README of the user's."""
    for folder in ("rgb", "depth", "labels"):
        (seq / folder / ".DS_Store").write_bytes(b"\x00\x00\x00\x01Bud1" + b"\x00" * 100)
        first = sorted(p for p in (seq / folder).iterdir() if p.suffix == ".png")[0]
        (seq / folder / f"._{first.name}").write_bytes(b"\x00\x05\x16\x07" + b"\x00" * 200)
        (seq / folder / "Thumbs.db").write_bytes(b"\xd0\xcf\x11\xe0" + b"\x00" * 100)
    (seq / "README.md").write_text("# my recording\nCaptured 2026-12-01.\n")


def _palette_labels(seq: Path) -> None:
    """Every label PNG as a palette image whose indices are the class ids (a labelling tool's
    VOC-style output)."""
    palette = [0, 0, 0, 192, 128, 128, 192, 0, 0, 0, 64, 128] + [0] * (256 * 3 - 12)
    for path in sorted((seq / "labels").iterdir()):
        image = Image.fromarray(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), mode="L")
        indexed = image.convert("P")
        indexed.putdata(list(image.getdata()))
        indexed.putpalette(palette)
        indexed.save(path)


def _float_tiff_depth(seq: Path) -> None:
    """Every depth image as a float32 TIFF in metres, ``depth.txt`` listing ``.tiff``."""
    for path in sorted((seq / "depth").iterdir()):
        depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.float32) / 5000.0
        cv2.imwrite(str(path.with_suffix(".tiff")), depth)
        path.unlink()
    _rewrite_list(seq, "depth.txt", lambda x: x.replace(".png", ".tiff"))


# ------------------------------------------------------------------------------ frame lists
def _shift_depth_stamps(seq: Path) -> None:
    """``depth.txt``'s stamps one second after the colour stamps (no pair within 0.02 s)."""

    def change(row: str) -> str:
        stamp, name = row.split()[:2]
        return f"{float(stamp) + 1.0:.6f} {name}"

    _rewrite_list(seq, "depth.txt", change)


def _five_frames(seq: Path) -> None:
    """``rgb.txt`` keeps its first five frames."""
    lines = (seq / "rgb.txt").read_text().splitlines()
    head = [x for x in lines if x.startswith("#")]
    body = [x for x in lines if x.strip() and not x.startswith("#")]
    (seq / "rgb.txt").write_text("\n".join(head + body[:5]) + "\n")


# ------------------------------------------------------------------------------ trajectories
def _euroc(c: Path, world: dict[str, str]) -> None:
    """The ground truth in EuRoC's ``data.csv`` form: nanosecond stamps, commas, 17 columns."""
    rows = ["#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],"
            "q_RS_y [],q_RS_z [],v_RS_R_x [m s^-1],v_RS_R_y [m s^-1],v_RS_R_z [m s^-1],"
            "b_w_RS_S_x [rad s^-1],b_w_RS_S_y [rad s^-1],b_w_RS_S_z [rad s^-1],"
            "b_a_RS_S_x [m s^-2],b_a_RS_S_y [m s^-2],b_a_RS_S_z [m s^-2]"]  # fmt: skip
    for row in _gt_rows(world):
        t, x, y, z, qx, qy, qz, qw = row.split()
        rows.append(",".join([str(int(float(t) * 1e9)), x, y, z, qw, qx, qy, qz] + ["0"] * 9))
    (c / "data.csv").write_text("\n".join(rows) + "\n")


def _kitti(c: Path, world: dict[str, str]) -> None:
    """The ground truth as KITTI's poses: a 3x4 matrix per line (12 numbers, no stamp)."""
    from scipy.spatial.transform import Rotation

    rows = []
    for row in _gt_rows(world):
        t, x, y, z, qx, qy, qz, qw = (float(v) for v in row.split())
        r = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        m = np.hstack([r, [[x], [y], [z]]])
        rows.append(" ".join(f"{v:.6e}" for v in m.ravel()))
    (c / "poses.txt").write_text("\n".join(rows) + "\n")


def _relative_stamps(c: Path, world: dict[str, str]) -> None:
    """Both trajectories with stamps from 0 (seconds since the ground truth's first pose)."""
    t0 = float(_gt_rows(world)[0].split()[0])
    for src, name in ((world["gt"], "rel_gt.txt"), (world["est"], "rel_est.txt")):
        rows = [
            r for r in Path(src).read_text().splitlines() if r.strip() and not r.startswith("#")
        ]
        out = [f"{float(r.split()[0]) - t0:.6f} " + " ".join(r.split()[1:]) for r in rows]
        (c / name).write_text("\n".join(out) + "\n")


def _scaled_estimate(c: Path, world: dict[str, str]) -> None:
    """The estimate with every position doubled (a monocular run's scale)."""
    rows = [r for r in Path(world["est"]).read_text().splitlines() if r.strip() and r[0] != "#"]
    out = []
    for r in rows:
        p = r.split()
        out.append(" ".join([p[0], *(f"{2 * float(v):.6f}" for v in p[1:4]), *p[4:]]))
    (c / "scaled.txt").write_text("\n".join(out) + "\n")


def _decimal_comma(c: Path, world: dict[str, str]) -> None:
    """The ground truth as a spreadsheet in a German locale writes it: ``;``-free, decimal
    commas (``1341846313,294900 -1,784398 ...``)."""
    rows = [" ".join(v.replace(".", ",") for v in r.split()) for r in _gt_rows(world)]
    (c / "komma.txt").write_text("\n".join(rows) + "\n")


def _unicode_comments(c: Path, world: dict[str, str]) -> None:
    """The ground truth with UTF-8 comment lines (``# café, température 21 °C``)."""
    rows = _gt_rows(world)
    text = ["# café, température 21 °C", *rows[:10], "# — pause —", *rows[10:]]
    (c / "notes_gt.txt").write_text("\n".join(text) + "\n", encoding="utf-8")


def _labels_all_void(seq: Path) -> None:
    """Every label PNG all 255 (ignore): no frame has a class pixel."""
    for path in sorted((seq / "labels").iterdir()):
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(path), np.full_like(image, 255))


# ------------------------------------------------------------------------------ earlier outputs
def _slam_with_notes(c: Path, world: dict[str, str]) -> None:
    """An earlier uss-slam run in ``{C}/o`` with a file of the user's beside its outputs."""
    shutil.copytree(world["slam"], c / "o")
    (c / "o" / "my_notes.txt").write_text("ATE looked high on this one\n")


def _exports_with_other(c: Path, world: dict[str, str]) -> None:
    """An exports folder holding the world's model and another model of the user's."""
    (c / "exports").mkdir()
    shutil.copy(world["onnx2"], c / "exports" / "other.onnx")


def _ckpt_alone(c: Path, world: dict[str, str]) -> None:
    """The world's checkpoint copied out of its run folder as ``{C}/model.ckpt``."""
    shutil.copy(world["ckpt"], c / "model.ckpt")


def _voc_target(c: Path, world: dict[str, str]) -> None:
    """``uss-synth voc --style target``: a labelled image folder (rgb/, labels/, rgb.txt)."""
    subprocess.run([str(BIN / "uss-synth"), "voc", "--style", "target", "--images", "12",
                    "--size", "160x120", "--out", str(c / "tv"), "--quiet"],
                   check=True, capture_output=True)  # fmt: skip


def _vocab_bin(c: Path, world: dict[str, str]) -> None:
    """``ORBvoc.bin``: 4 KiB of random bytes (a binary vocabulary of another tool)."""
    (c / "ORBvoc.bin").write_bytes(np.random.default_rng(6).bytes(4096))


SIXTH: dict[str, Setup] = {
    "rgb_editor_chunks": _seq_edit(_editor_chunks),
    "rgb_trailing_bytes": _seq_edit(_trailing_bytes),
    "rgb_progressive_jpeg": _seq_edit(_progressive_jpeg),
    "rgb_upper_ext": _seq_edit(_upper_ext),
    "os_junk": _seq_edit(_os_junk),
    "label_palette": _seq_edit(_palette_labels),
    "depth_float_tiff": _seq_edit(_float_tiff_depth),
    "rgb_txt_dot_slash": _seq_edit(
        lambda s: _rewrite_list(s, "rgb.txt", lambda x: x.replace(" rgb/", " ./rgb/"))
    ),
    "rgb_txt_backslash": _seq_edit(
        lambda s: _rewrite_list(s, "rgb.txt", lambda x: x.replace("rgb/", "rgb\\"))
    ),
    "depth_stamps_shifted": _seq_edit(_shift_depth_stamps),
    "five_frames": _seq_edit(_five_frames),
    "gt_euroc": _euroc,
    "gt_kitti": _kitti,
    "relative_stamps": _relative_stamps,
    "gt_decimal_comma": _decimal_comma,
    "gt_unicode_comments": _unicode_comments,
    "labels_all_void": _seq_edit(_labels_all_void),
    "est_scaled": _scaled_estimate,
    "slam_with_notes": _slam_with_notes,
    "exports_with_other": _exports_with_other,
    "ckpt_alone": _ckpt_alone,
    "voc_target": _voc_target,
    "vocab_bin": _vocab_bin,
    "vocab_unicode": lambda c, w: shutil.copy(w["vocab"], c / "vocabulaire é.txt"),
    "userconf_slam": _user_config(
        "slam", lambda w: "defaults:\n  - orb_rgbd\n  - _self_\norb:\n  n_features: 600\n"
    ),
    "userconf_trainer": _user_config(
        "trainer",
        lambda w: (ROOT / "configs" / "trainer" / "cpu.yaml").read_text() + "\nmax_steps: 4\n",
    ),
    "busy_slam_long": background(
        "uss-slam sequence.path={seq} out_dir={C}/o progress=false slam.repeats=60"
    ),
    "busy_synth_seq": background(
        "uss-synth sequence --preset walking_rpy --frames 3000 --size 320x240 --out {C}/s --quiet"
    ),
    "busy_experiments_data": background(
        "uss-experiments out_dir={C}/x stages=[data] scale=standard"
    ),
}
