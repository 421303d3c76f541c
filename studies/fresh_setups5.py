"""The preparations of the fifth fresh set (``studies/fresh_cases5.txt``): a sequence's own
``intrinsics.yaml`` damaged (a number as text or as a list, a YAML syntax error, empty, a key
given twice, another width, a zero depth scale, a folder of that name, missing); a camera file
with a negative focal length; a user's own Hydra config files (a sequence, an experiment preset,
a scale) valid, with a value of the wrong type, a YAML syntax error or a misspelt key; a
training run's saved ``.hydra/config.yaml`` with a wrong type, a syntax error or empty; frames
that are WebP data named ``.png``, a PNG whose header declares 60000x60000 pixels, frames that
are symbolic links; trajectories with a NaN position, stamps near 1e20 or negative, a header row
without ``#``, semicolons; a vocabulary with CRLF line ends or gzipped; a CMYK JPEG in a VOC
set; a valid ONNX model that is no segmenter; a read-only parent folder for an output, a parent
folder that cannot be entered above an input; and runs interrupted by Ctrl-C before the case
runs the same command again (``interrupted``)."""

from __future__ import annotations

import gzip
import shlex
import shutil
import signal
import struct
import subprocess
import time
import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
from fresh_setups import Setup, _gt_rows, _seq_edit, stop_group
from fresh_setups3 import BIN, _nth, _voc_edit
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------ config files
def _intrinsics(change: Callable[[str], str]) -> Callable[[Path], None]:
    def edit(seq: Path) -> None:
        path = seq / "intrinsics.yaml"
        path.write_text(change(path.read_text()))

    return edit


def _intrinsics_folder(seq: Path) -> None:
    (seq / "intrinsics.yaml").unlink()
    (seq / "intrinsics.yaml").mkdir()


def _user_config(group: str, text: Callable[[dict[str, str]], str]) -> Setup:
    """``{C}/cfg/<group>/mine.yaml`` holding ``text(world)`` (for ``--config-dir {C}/cfg``)."""

    def setup(c: Path, world: dict[str, str]) -> None:
        (c / "cfg" / group).mkdir(parents=True, exist_ok=True)
        (c / "cfg" / group / "mine.yaml").write_text(text(world))

    return setup


def _shipped(name: str, change: Callable[[str], str] = lambda t: t) -> Callable[[dict], str]:
    """A shipped config file's text (``configs/<name>``) as a user copies it, edited."""
    return lambda world: change((ROOT / "configs" / name).read_text())


def _train_run(change: Callable[[str], str]) -> Setup:
    """A copy of the world's ``ci`` training run whose ``.hydra/config.yaml`` is edited."""

    def setup(c: Path, world: dict[str, str]) -> None:
        shutil.copytree(Path(world["ckpt"]).parents[1], c / "train")
        config = c / "train" / ".hydra" / "config.yaml"
        config.write_text(change(config.read_text()))

    return setup


# ------------------------------------------------------------------------------ images
def _webp_as_png(seq: Path) -> None:
    path = _nth(seq, "rgb")
    ok, data = cv2.imencode(".webp", cv2.imread(str(path)))
    assert ok
    path.write_bytes(data.tobytes())


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png_bomb(seq: Path) -> None:
    """Colour frame 2 as a PNG whose header declares 60000x60000 RGB pixels (its data is short)."""
    header = struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0)
    data = zlib.compress(b"\x00" * 4096)
    png = b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", data)
    _nth(seq, "rgb").write_bytes(png + _chunk(b"IEND", b""))


def _linked_frames(seq: Path) -> None:
    """Every colour frame a symbolic link to a copy kept beside the sequence."""
    keep = seq.parent / "frames_kept"
    shutil.copytree(seq / "rgb", keep)
    for path in sorted((seq / "rgb").iterdir()):
        path.unlink()
        path.symlink_to(keep / path.name)


def _voc_cmyk(voc: Path) -> None:
    path = sorted((voc / "JPEGImages").iterdir())[1]
    Image.open(path).convert("CMYK").save(path, "JPEG")


def _identity_onnx(c: Path, world: dict[str, str]) -> None:
    """A valid ONNX model that is no segmenter: its output is its input (N, 3, H, W)."""
    import onnx
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("input", TensorProto.FLOAT, ["n", 3, "h", "w"])
    y = helper.make_tensor_value_info("output", TensorProto.FLOAT, ["n", 3, "h", "w"])
    graph = helper.make_graph([helper.make_node("Identity", ["input"], ["output"])], "id", [x], [y])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    onnx.save(model, str(c / "identity.onnx"))


# ------------------------------------------------------------------------------ text files
def _traj(name: str, change: Callable[[list[str]], str]) -> Setup:
    def setup(c: Path, world: dict[str, str]) -> None:
        (c / name).write_text(change(_gt_rows(world)))

    return setup


def _column(
    rows: list[str], index: int, change: Callable[[str], str], only: int | None = None
) -> str:
    out = []
    for i, row in enumerate(rows):
        parts = row.split()
        if only is None or i == only:
            parts[index] = change(parts[index])
        out.append(" ".join(parts))
    return "\n".join(out) + "\n"


def _vocab(change: Callable[[bytes], bytes], name: str) -> Setup:
    return lambda c, world: (c / name).write_bytes(change(Path(world["vocab"]).read_bytes()))


# ------------------------------------------------------------------------------ permissions
def _ro_parent(c: Path, world: dict[str, str]) -> None:
    (c / "rodir").mkdir()
    (c / "rodir").chmod(0o555)


def _unreadable_parent_seq(c: Path, world: dict[str, str]) -> None:
    """``{C}/hid/seq``, a sequence copy under a folder whose mode forbids entering it (0600)."""
    (c / "hid").mkdir()
    shutil.copytree(world["seq"], c / "hid" / "seq")
    (c / "hid").chmod(0o600)


# ------------------------------------------------------------------------------ interrupted runs
def interrupted(command: str, seconds: float) -> Setup:
    """Run ``command`` (a console script and its arguments) in the case's folder and press
    Ctrl-C (SIGINT to its process group) after ``seconds``; wait for it to stop (120 s)."""

    def setup(c: Path, world: dict[str, str]) -> None:
        args = shlex.split(command.format(C=c, **world))
        proc = subprocess.Popen([str(BIN / args[0]), *args[1:]], cwd=c, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
        try:
            proc.wait(timeout=seconds)
        except subprocess.TimeoutExpired:
            stop_group(proc, signal.SIGINT, grace=120)
        time.sleep(0.5)

    return setup


SEQ_PLAIN = "path: {seq}\nstride: 2\nmax_frames: 10\n"

FIFTH: dict[str, Setup] = {
    "intr_fx_text": _seq_edit(_intrinsics(lambda t: t.replace("fx: 133.85", "fx: 133,85"))),
    "intr_fx_list": _seq_edit(
        _intrinsics(lambda t: t.replace("fx: 133.85", "fx: [133.85, 134.8]"))
    ),
    "intr_syntax": _seq_edit(_intrinsics(lambda t: t.replace("fx: 133.85", "fx: [133.85"))),
    "intr_empty": _seq_edit(_intrinsics(lambda t: "")),
    "intr_dup_key": _seq_edit(_intrinsics(lambda t: t + "fx: 525.0\n")),
    "intr_width": _seq_edit(_intrinsics(lambda t: t.replace("width: 160", "width: 640"))),
    "intr_depth_scale_zero": _seq_edit(
        _intrinsics(lambda t: t.replace("depth_scale: 5000.0", "depth_scale: 0"))
    ),
    "intr_tab": _seq_edit(_intrinsics(lambda t: t.replace("depth_scale:", "\tdepth_scale:"))),
    "intr_folder": _seq_edit(_intrinsics_folder),
    "intr_missing": _seq_edit(lambda s: (s / "intrinsics.yaml").unlink()),
    "cam_negative_fx": lambda c, w: (c / "cam.yaml").write_text(
        "fx: -120.0\nfy: 120.0\ncx: 80.0\ncy: 60.0\n"
    ),
    "userconf_seq": _user_config("sequence", lambda w: SEQ_PLAIN.format(**w)),
    "userconf_seq_badtype": _user_config(
        "sequence", lambda w: SEQ_PLAIN.format(**w).replace("stride: 2", "stride: two")
    ),
    "userconf_seq_syntax": _user_config(
        "sequence", lambda w: SEQ_PLAIN.format(**w).replace("max_frames: 10", "max_frames: [10")
    ),
    "userconf_train": _user_config("experiment", _shipped("experiment/ci.yaml")),
    "userconf_train_badtype": _user_config(
        "experiment",
        _shipped("experiment/ci.yaml", lambda t: t.replace("batch_size: 2", "batch_size: two")),
    ),
    "userconf_train_syntax": _user_config(
        "experiment", _shipped("experiment/ci.yaml", lambda t: t + "\ndata: [\n")
    ),
    "userconf_train_misspelt": _user_config(
        "experiment",
        _shipped("experiment/ci.yaml", lambda t: t.replace("max_iters: 4", "max_itres: 4")),
    ),
    "userconf_scale": _user_config("scale", _shipped("scale/quick.yaml")),
    "userconf_scale_badtype": _user_config(
        "scale",
        _shipped("scale/quick.yaml", lambda t: t.replace("voc_images: 16", "voc_images: many")),
    ),
    "trainrun_badtype": _train_run(lambda t: t.replace("num_classes: 4", "num_classes: four")),
    "trainrun_syntax": _train_run(lambda t: t + "\nmodel: [\n"),
    "trainrun_empty": _train_run(lambda t: ""),
    "rgb_webp_as_png": _seq_edit(_webp_as_png),
    "rgb_png_bomb": _seq_edit(_png_bomb),
    "rgb_linked": _seq_edit(_linked_frames),
    "voc_cmyk": _voc_edit(_voc_cmyk),
    "onnx_identity": _identity_onnx,
    "gt_nan_position": _traj("nanpos.txt", lambda r: _column(r, 1, lambda v: "nan", only=3)),
    "gt_huge_stamps": _traj("big.txt", lambda r: _column(r, 0, lambda v: f"{float(v) + 1e20:.6f}")),
    "gt_negative_stamps": _traj(
        "neg.txt", lambda r: _column(r, 0, lambda v: f"{float(v) - 2e9:.6f}")
    ),
    "gt_header_row": _traj(
        "head.txt", lambda r: "timestamp tx ty tz qx qy qz qw\n" + "\n".join(r) + "\n"
    ),
    "gt_semicolons": _traj("semi.txt", lambda r: "\n".join(";".join(x.split()) for x in r) + "\n"),
    "vocab_crlf": _vocab(lambda b: b.replace(b"\n", b"\r\n"), "crlf.txt"),
    "vocab_gz": _vocab(gzip.compress, "v.txt.gz"),
    "ro_parent": _ro_parent,
    "unreadable_parent_seq": _unreadable_parent_seq,
    "interrupted_synth": interrupted(
        "uss-synth sequence --preset walking_rpy --frames 600 --size 320x240 --out {C}/s --quiet", 3
    ),
    "interrupted_vocab": interrupted(
        "uss-vocab build {seq} {seq2} --out {C}/v.txt -k 10 -L 5 --stride 1 --features 2000", 3
    ),
    "interrupted_eval": interrupted(
        "uss-eval {onnx} --sequence {seq} --sequence {seq2} --overlays 20 --out {C}/e", 3
    ),
    "interrupted_slam": interrupted(
        "uss-slam sequence.path={seq} out_dir={C}/o progress=false slam.repeats=20", 5
    ),
    "interrupted_train": interrupted(
        "uss-train experiment=ci data.source.root={voc} data.target.roots=[{seq}] "
        "data.val.roots=[{seq}] data.val.stride=1 hydra.run.dir={C}/run paths.log_dir={C}/logs "
        "logger=none model.max_iters=400 data.iterations_per_epoch=200",
        12,
    ),
    "interrupted_export": interrupted(
        "uss-export ckpt_path={ckpt} out_dir={C}/exports hydra.run.dir={C}/hydra int8=true "
        "calibration.root={seq} calibration.frames=30",
        6,
    ),
    "interrupted_demo": interrupted(
        "uss-demo --out {C}/d --experiment ci --until train --quiet", 8
    ),
    "interrupted_experiments": interrupted(
        "uss-experiments out_dir={C}/x stages=[data] scale=standard", 6
    ),
}
"""Setup name -> preparation (``seqcopy`` first for the ``intr_*``, ``rgb_*`` edits)."""
