"""The preparations of the third fresh set (``studies/fresh_cases3.txt``): odd paths (links that
loop or point nowhere on the way, read-only targets reached through links, FIFOs, devices),
damaged and odd images (CRCs, empty files, other bit depths and channels, other sizes, label
values outside the classes), text files in other encodings, missing packages (a module that
raises ``ModuleNotFoundError`` on import, first on ``PYTHONPATH``), earlier outputs with a part
deleted, and a second process already writing the same output (a *background* setup: it
returns the process, which the runner ends after the case)."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
import time
import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from fresh_setups import Setup, _seq_edit, seqcopy

BIN = Path(sys.executable).parent


# ------------------------------------------------------------------------------ paths
def links(c: Path, world: dict[str, str]) -> None:
    """``a -> b -> a`` (a loop on the way), ``dang -> nowhere`` (a dangling folder on the way),
    ``rolink -> ro`` (a read-only folder through a link), ``fifo`` (a named pipe)."""
    (c / "a").symlink_to(c / "b")
    (c / "b").symlink_to(c / "a")
    (c / "dang").symlink_to(c / "nowhere")
    (c / "ro").mkdir()
    (c / "ro" / "keep.txt").write_text("the user's file\n")
    (c / "ro").chmod(0o555)
    (c / "rolink").symlink_to(c / "ro", target_is_directory=True)
    os.mkfifo(c / "fifo")


def rofile(c: Path, world: dict[str, str]) -> None:
    """A read-only vocabulary file of the user's (``v.txt``, mode 0444) in a writable folder."""
    shutil.copy(world["vocab"], c / "v.txt")
    (c / "v.txt").chmod(0o444)


def seqloop(c: Path, world: dict[str, str]) -> None:
    """A sequence copy whose ``rgb`` folder is a link to itself."""
    seqcopy(c, world)
    shutil.rmtree(c / "seq" / "rgb")
    (c / "seq" / "rgb").symlink_to(c / "seq" / "rgb")


# ------------------------------------------------------------------------------ images
def _nth(seq: Path, folder: str, k: int = 2) -> Path:
    return sorted((seq / folder).iterdir())[k]


def _rewrite(folder: str, change: Callable[[np.ndarray], np.ndarray], k: int = 2) -> Setup:
    def edit(seq: Path) -> None:
        path = _nth(seq, folder, k)
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(path), change(image))

    return _seq_edit(edit)


def _bad_crc(seq: Path) -> None:
    """One byte of a colour frame's first IDAT chunk flipped (its CRC no longer matches)."""
    path = _nth(seq, "rgb")
    data = bytearray(path.read_bytes())
    at = data.index(b"IDAT") + 20
    data[at] ^= 0xFF
    path.write_bytes(bytes(data))


def _bad_crc_fixed(seq: Path) -> None:
    """A depth PNG whose IDAT data is garbage with a matching CRC (zlib fails, not the CRC)."""
    path = _nth(seq, "depth")
    data = bytearray(path.read_bytes())
    at = data.index(b"IDAT")
    length = int.from_bytes(data[at - 4 : at], "big")
    body = bytes((b * 7 + 3) % 256 for b in data[at + 4 : at + 4 + length])
    crc = zlib.crc32(b"IDAT" + body).to_bytes(4, "big")
    data[at + 4 : at + 8 + length] = body + crc
    path.write_bytes(bytes(data))


def _rgb_as_jpeg(truncate: bool) -> Callable[[Path], None]:
    """Every colour frame as a JPEG (``rgb.txt`` lists ``.jpg``); one truncated to 60%."""

    def edit(seq: Path) -> None:
        for i, png in enumerate(sorted((seq / "rgb").iterdir())):
            image = cv2.imread(str(png), cv2.IMREAD_COLOR)
            jpg = png.with_suffix(".jpg")
            cv2.imwrite(str(jpg), image)
            png.unlink()
            if truncate and i == 3:
                jpg.write_bytes(jpg.read_bytes()[: jpg.stat().st_size * 3 // 5])
        text = (seq / "rgb.txt").read_text().replace(".png", ".jpg")
        (seq / "rgb.txt").write_text(text)

    return edit


def _latin1_rgb_txt(seq: Path) -> None:
    lines = (seq / "rgb.txt").read_bytes().splitlines(keepends=True)
    lines.insert(1, b"# prise de vue \xe0 Paris\n")
    (seq / "rgb.txt").write_bytes(b"".join(lines))


def _voc_edit(change: Callable[[Path], None]) -> Setup:
    def setup(c: Path, world: dict[str, str]) -> None:
        shutil.copytree(world["voc"], c / "voc")
        change(c / "voc")

    return setup


def _voc_truncated_jpeg(voc: Path) -> None:
    jpg = sorted((voc / "JPEGImages").iterdir())[1]
    jpg.write_bytes(jpg.read_bytes()[: jpg.stat().st_size // 2])


def _voc_label_value(voc: Path) -> None:
    """A VOC label holding 40 (VOC's classes are 0..20 and 255)."""
    png = sorted((voc / "SegmentationClass").iterdir())[0]
    image = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
    image[:4, :4] = 40
    cv2.imwrite(str(png), image)


def _labels_value(value: int) -> Callable[[np.ndarray], np.ndarray]:
    def change(image: np.ndarray) -> np.ndarray:
        image = image.copy()
        image[:3, :3] = value
        return image

    return change


def utf16(c: Path, world: dict[str, str]) -> None:
    (c / "gt16.txt").write_bytes(Path(world["gt"]).read_text().encode("utf-16"))


def nomod(*names: str) -> Setup:
    """``{C}/nomod`` holding a module per name that raises as a package that is not installed."""

    def setup(c: Path, world: dict[str, str]) -> None:
        (c / "nomod").mkdir(exist_ok=True)
        for name in names:
            (c / "nomod" / f"{name}.py").write_text(
                f"raise ModuleNotFoundError(\"No module named '{name}'\", name={name!r})\n"
            )

    return setup


# ------------------------------------------------------------------------------ earlier outputs
def slamnorunjson(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(world["slam"], c / "run")
    (c / "run" / "run.json").unlink()


def exportsnoonnx(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(Path(world["onnx"]).parent, c / "exports")
    (c / "exports" / "m.onnx").unlink()


def synthvocholes(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(Path(world["voc"]).parents[1], c / "v")
    for jpg in sorted((c / "v" / "VOCdevkit" / "VOC2012" / "JPEGImages").iterdir())[:3]:
        jpg.unlink()


def _run_quiet(*argv: str, cwd: Path) -> None:
    done = subprocess.run([str(BIN / argv[0]), *argv[1:]], cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"setup: {' '.join(argv)} failed:\n{done.stderr[-2000:]}")


def evalnojson(c: Path, world: dict[str, str]) -> None:
    _run_quiet("uss-eval", world["onnx"], "--sequence", world["seq"], "--stride", "5",
               "--out", str(c / "e"), cwd=c)  # fmt: skip
    (c / "e" / "eval.json").unlink()


def demodatahole(c: Path, world: dict[str, str]) -> None:
    _run_quiet("uss-demo", "--out", str(c / "d"), "--experiment", "ci", "--until", "data",
               "--quiet", cwd=c)  # fmt: skip
    rgb = sorted(p for p in (c / "d").rglob("*.png") if "rgb" in p.parts)
    rgb[0].unlink()


# ------------------------------------------------------------------------------ a second writer
def background(command: str) -> Setup:
    """Start ``command`` (a console script and its arguments; ``{C}`` and the world's names are
    filled in) in the case's folder, and return once it holds a lock file there (at most 120 s)."""

    def setup(c: Path, world: dict[str, str]) -> subprocess.Popen:
        args = shlex.split(command.format(C=c, **world))
        proc = subprocess.Popen([str(BIN / args[0]), *args[1:]], cwd=c, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL, start_new_session=True)  # fmt: skip
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if any(c.rglob(".*.lock")):
                time.sleep(2)
                break
            time.sleep(0.5)
        return proc

    return setup


THIRD: dict[str, Setup] = {
    "links": links,
    "rofile": rofile,
    "seqloop": seqloop,
    "rgb_bad_crc": _seq_edit(_bad_crc),
    "depth_bad_zlib": _seq_edit(_bad_crc_fixed),
    "rgb_empty_file": _seq_edit(lambda s: _nth(s, "rgb").write_bytes(b"")),
    "rgb_text_file": _seq_edit(lambda s: _nth(s, "rgb").write_text("not an image\n")),
    "rgb_jpeg": _seq_edit(_rgb_as_jpeg(False)),
    "rgb_jpeg_trunc": _seq_edit(_rgb_as_jpeg(True)),
    "rgb_16bit": _rewrite("rgb", lambda im: im.astype(np.uint16) * 257),
    "depth_8bit": _rewrite("depth", lambda im: (im // 256).astype(np.uint8)),
    "depth_3ch": _rewrite("depth", lambda im: np.dstack([im, im, im])),
    "depth_size": _rewrite(
        "depth",
        lambda im: cv2.resize(
            im, (im.shape[1] // 2, im.shape[0] // 2), interpolation=cv2.INTER_NEAREST
        ),
    ),
    "label_16bit": _rewrite("labels", lambda im: im.astype(np.uint16), k=0),
    "label_rgb": _rewrite("labels", lambda im: np.dstack([im, im, im]), k=0),
    "label_254": _rewrite("labels", _labels_value(254), k=0),
    "label_4": _rewrite("labels", _labels_value(4), k=1),
    "latin1_rgb_txt": _seq_edit(_latin1_rgb_txt),
    "voc_trunc_jpeg": _voc_edit(_voc_truncated_jpeg),
    "voc_label_40": _voc_edit(_voc_label_value),
    "utf16": utf16,
    "nomod_matplotlib": nomod("matplotlib"),
    "nomod_onnxruntime": nomod("onnxruntime"),
    "nomod_cv2": nomod("cv2"),
    "nomod_pyoctomap": nomod("pyoctomap"),
    "nomod_pydensecrf": nomod("pydensecrf"),
    "nomod_scipy": nomod("scipy"),
    "slamnorunjson": slamnorunjson,
    "exportsnoonnx": exportsnoonnx,
    "synthvocholes": synthvocholes,
    "evalnojson": evalnojson,
    "demodatahole": demodatahole,
    "busy_slam": background(
        "uss-slam sequence.path={seq} out_dir={C}/o progress=false slam.repeats=40"
    ),
    "busy_vocab": background(
        "uss-vocab build {seq} {seq2} --out {C}/v.txt -k 10 -L 6 --stride 1 "
        "--features 3000 --max-iterations 1000"
    ),
    "busy_synth": background(
        "uss-synth sequence --preset walking_rpy --frames 3000 --size 320x240 --out {C}/s --quiet"
    ),
    "busy_eval": background(
        "uss-eval compare {onnx} {onnx2} --sequence {seq} --sequence {seq2} "
        "--slam --repeats 8 --out {C}/c --quiet"
    ),
    "busy_train": background(
        "uss-train experiment=ci data.source.root={voc} "
        "data.target.roots=[{seq}] data.val.roots=[{seq}] hydra.run.dir={C}/run "
        "paths.log_dir={C}/logs logger=none model.max_iters=400 "
        "data.iterations_per_epoch=200"
    ),
    "busy_experiments": background("uss-experiments out_dir={C}/x stages=[data] scale=standard"),
    "busy_demo": background("uss-demo --out {C}/d --experiment demo --until data --quiet"),
}
