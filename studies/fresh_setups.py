"""The shared inputs of ``studies/fresh_cases.py`` (made once with the console scripts
themselves) and the preparations a case names in its ``setup`` column."""

from __future__ import annotations

import gzip
import hashlib
import os
import shutil
import signal
import subprocess
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

HIDDEN_OUTPUTS = (".uss-slam-new", ".tmp", ".partial", ".lock")
"""Names of staging, temporary and lock files that a finished or interrupted run must not leave."""


def snapshot(root: Path, quick: bool = False) -> dict[str, object]:
    """Every file under ``root`` -> its SHA-256 (``quick``: size and mtime), without Hydra's
    record of a call (``.hydra/``, ``*.log``), as the project's matrix compares them."""
    files: dict[str, object] = {}
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root).as_posix()
        if ".hydra" in rel.split("/") or rel.endswith(".log") or not path.is_file():
            continue
        if quick:
            stat = path.stat()
            files[rel] = (stat.st_size, stat.st_mtime_ns)
        else:
            try:
                files[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
            except PermissionError:
                files[rel] = "unreadable"
    return files


def stop_group(proc: subprocess.Popen, first: int = signal.SIGTERM, grace: float = 60) -> None:
    """End ``proc``'s process group (started with ``start_new_session``): signal ``first``,
    then SIGKILL if it has not ended within ``grace`` seconds."""
    if proc.poll() is not None:
        return
    os.killpg(proc.pid, first)
    try:
        proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _run(bin_dir: Path, prog: str, *args: str, cwd: Path) -> None:
    done = subprocess.run([str(bin_dir / prog), *args], cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"world: {prog} {' '.join(args)} failed:\n{done.stderr[-3000:]}")


def build_world(w: Path, bin_dir: Path) -> dict[str, str]:
    """The shared inputs under ``w`` (made once; a later call reuses them): two labelled
    sequences, a VOC set, a ci training's checkpoint, two exported models, a vocabulary and an
    earlier uss-slam run."""
    w.mkdir(parents=True, exist_ok=True)
    synth = ("--size", "160x120", "--quiet")
    if not (w / "seq").is_dir():
        _run(bin_dir, "uss-synth", "sequence", "--preset", "walking_xyz", "--frames", "30",
             "--seed", "7", *synth, "--out", str(w / "seq"), cwd=w)  # fmt: skip
    if not (w / "seq2").is_dir():
        _run(bin_dir, "uss-synth", "sequence", "--preset", "static_xyz", "--frames", "20",
             "--seed", "8", *synth, "--out", str(w / "seq2"), cwd=w)  # fmt: skip
    if not (w / "voc").is_dir():
        _run(bin_dir, "uss-synth", "voc", "--images", "16", *synth, "--out", str(w / "voc"), cwd=w)
    voc = w / "voc" / "VOCdevkit" / "VOC2012"
    ckpt = w / "train" / "checkpoints" / "last.ckpt"
    if not ckpt.is_file():
        _run(bin_dir, "uss-train", "experiment=ci", f"data.source.root={voc}",
             f"data.target.roots=[{w / 'seq'}]", f"data.val.roots=[{w / 'seq'}]",
             f"hydra.run.dir={w / 'train'}", f"paths.log_dir={w / 'logs'}", "logger=none",
             cwd=w)  # fmt: skip
    onnx = w / "exports" / "m.onnx"
    if not onnx.is_file():
        _run(bin_dir, "uss-export", f"ckpt_path={ckpt}", f"out_dir={w / 'exports'}", "name=m",
             f"hydra.run.dir={w / 'export_run'}", cwd=w)  # fmt: skip
    onnx2 = w / "m2.onnx"
    if not onnx2.is_file():
        import onnx as onnx_lib

        model = onnx_lib.load(str(onnx))
        model.doc_string = "a second model (another file, the same weights)"
        onnx_lib.save(model, str(onnx2))
    if not (w / "vocab.txt").is_file():
        _run(bin_dir, "uss-vocab", "build", str(w / "seq"), "--out", str(w / "vocab.txt"),
             "-k", "3", "-L", "2", "--stride", "5", cwd=w)  # fmt: skip
    if not (w / "slam" / "run.json").is_file():
        _run(bin_dir, "uss-slam", f"sequence.path={w / 'seq'}", f"out_dir={w / 'slam'}",
             "progress=false", cwd=w)  # fmt: skip
    return {"W": str(w), "seq": str(w / "seq"), "seq2": str(w / "seq2"), "voc": str(voc),
            "ckpt": str(ckpt), "onnx": str(onnx), "onnx2": str(onnx2),
            "gt": str(w / "seq" / "groundtruth.txt"), "est": str(w / "slam" / "trajectory.txt"),
            "vocab": str(w / "vocab.txt"), "slam": str(w / "slam")}  # fmt: skip


# ------------------------------------------------------------------------------ setups
# Each takes the case's folder and the world's paths.

Setup = Callable[[Path, dict[str, str]], None]


def _gt_rows(world: dict[str, str]) -> list[str]:
    rows = Path(world["gt"]).read_text().splitlines()
    return [r for r in rows if r.strip() and not r.startswith("#")]


def _write_gt(name: str, change: Callable[[list[str]], str]) -> Setup:
    def setup(c: Path, world: dict[str, str]) -> None:
        (c / name).write_text(change(_gt_rows(world)))

    return setup


def ro(c: Path, world: dict[str, str]) -> None:
    (c / "ro").mkdir()
    (c / "ro" / "keep.txt").write_text("the user's file\n")
    (c / "ro").chmod(0o555)


def notes(c: Path, world: dict[str, str]) -> None:
    (c / "notes").mkdir()
    (c / "notes" / "notes.txt").write_text("my notes\n")


def synthvoc(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(Path(world["voc"]).parents[1], c / "v")


def seqcopy(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(world["seq"], c / "seq")


def sequnicode(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(world["seq"], c / "séquence ü")


def _seq_edit(change: Callable[[Path], None]) -> Setup:
    return lambda c, world: change(c / "seq")


def _drop_first(folder: str) -> Callable[[Path], None]:
    def change(seq: Path) -> None:
        sorted((seq / folder).iterdir())[3].unlink()

    return change


def _label_jpeg(seq: Path) -> None:
    first = sorted((seq / "labels").iterdir())[0]
    image = cv2.imread(str(first), cv2.IMREAD_UNCHANGED)
    ok, data = cv2.imencode(".jpg", image)
    first.write_bytes(data.tobytes())


def _blank_lines(seq: Path) -> None:
    text = (seq / "rgb.txt").read_text().replace("\n", "\n\n")
    (seq / "rgb.txt").write_text(text)


def _unsorted(seq: Path) -> None:
    lines = (seq / "rgb.txt").read_text().splitlines()
    head = [x for x in lines if x.startswith("#")]
    body = [x for x in lines if x.strip() and not x.startswith("#")]
    (seq / "rgb.txt").write_text("\n".join(head + body[::-1]) + "\n")


def _zero_depth(seq: Path) -> None:
    for png in (seq / "depth").iterdir():
        image = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png), np.zeros_like(image))


def _swap_rgb_depth(seq: Path) -> None:
    """The colour frames replaced by the depth images (16-bit, one channel) under their names."""
    depth = sorted((seq / "depth").iterdir())
    for i, rgb in enumerate(sorted((seq / "rgb").iterdir())):
        shutil.copy(depth[min(i, len(depth) - 1)], rgb)


def emptyfile(c: Path, world: dict[str, str]) -> None:
    (c / "empty.txt").write_bytes(b"")


def unreadable(c: Path, world: dict[str, str]) -> None:
    shutil.copy(world["gt"], c / "secret.txt")
    (c / "secret.txt").chmod(0)


def unreadableonnx(c: Path, world: dict[str, str]) -> None:
    shutil.copy(world["onnx"], c / "m.onnx")
    (c / "m.onnx").chmod(0)


def gz(c: Path, world: dict[str, str]) -> None:
    (c / "gt.txt.gz").write_bytes(gzip.compress(Path(world["gt"]).read_bytes()))


def demoout(c: Path, world: dict[str, str]) -> None:
    (c / "demo").mkdir()
    (c / "demo" / "summary.json").write_text('{"demo": "an earlier uss-demo"}\n')
    (c / "demo" / "report.md").write_text("# earlier demo\n")


def trainruncopy(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(
        Path(world["ckpt"]).parents[1], c / "trainrun", ignore=shutil.ignore_patterns("*.ckpt")
    )
    (c / "trainrun" / "checkpoints" / "last.ckpt").write_bytes(b"an earlier checkpoint")


def vocnoseg(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(world["voc"], c / "voc")
    shutil.rmtree(c / "voc" / "SegmentationClass")


# ------------------------------------------------------------------------------ second set
# (studies/fresh_cases2.txt)


def textfile(c: Path, world: dict[str, str]) -> None:
    (c / "file.txt").write_text("a file of mine\n")


def linkdir(c: Path, world: dict[str, str]) -> None:
    """``link`` -> ``real``: an output folder reached through a symlink."""
    (c / "real").mkdir()
    (c / "link").symlink_to(c / "real", target_is_directory=True)


def seqlink(c: Path, world: dict[str, str]) -> None:
    (c / "seqlink").symlink_to(world["seq"], target_is_directory=True)


def _stamp_edit(change: Callable[[str], str]) -> Callable[[list[str]], str]:
    """Rows with ``change`` applied to each stamp."""
    return lambda rows: "\n".join(change(r.split()[0]) + " " + " ".join(r.split()[1:])
                                   for r in rows) + "\n"  # fmt: skip


def _zero_quaternion(rows: list[str]) -> str:
    first = rows[0].split()
    return "\n".join([" ".join(first[:4] + ["0", "0", "0", "0"]), *rows[1:]]) + "\n"


def halfvocab(c: Path, world: dict[str, str]) -> None:
    data = Path(world["vocab"]).read_bytes()
    (c / "half.txt").write_bytes(data[: len(data) // 2])


def truncckpt(c: Path, world: dict[str, str]) -> None:
    data = Path(world["ckpt"]).read_bytes()
    (c / "half.ckpt").write_bytes(data[: len(data) // 2])


def camyaml(c: Path, world: dict[str, str]) -> None:
    (c / "cam.yaml").write_text("cx: 80.0\ncy: 60.0\nfy: 120.0\n")


def _crlf_lists(seq: Path) -> None:
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        text = (seq / name).read_text()
        (seq / name).write_bytes(text.replace("\n", "\r\n").encode())


def _truncate_one(folder: str) -> Callable[[Path], None]:
    def change(seq: Path) -> None:
        png = sorted((seq / folder).iterdir())[2]
        png.write_bytes(png.read_bytes()[: png.stat().st_size // 2])

    return change


def _other_size(folder: str) -> Callable[[Path], None]:
    def change(seq: Path) -> None:
        png = sorted((seq / folder).iterdir())[2]
        image = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png), cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2),
                                         interpolation=cv2.INTER_NEAREST))  # fmt: skip

    return change


def _header_only(seq: Path) -> None:
    lines = (seq / "rgb.txt").read_text().splitlines()
    (seq / "rgb.txt").write_text("\n".join(x for x in lines if x.startswith("#")) + "\n")


def vocnosets(c: Path, world: dict[str, str]) -> None:
    shutil.copytree(world["voc"], c / "voc")
    shutil.rmtree(c / "voc" / "ImageSets")


SECOND: dict[str, Setup] = {
    "textfile": textfile,
    "linkdir": linkdir,
    "seqlink": seqlink,
    "onlycomments": lambda c, w: (c / "comments.txt").write_text("# timestamp tx ty tz\n# none\n"),
    "zeroquat": _write_gt("zq.txt", _zero_quaternion),
    "nanstamp": _write_gt(
        "nan.txt", lambda r: "\n".join(["nan " + " ".join(r[0].split()[1:]), *r[1:]]) + "\n"
    ),  # fmt: skip
    "shifted": _write_gt("shifted.txt", _stamp_edit(lambda t: f"{float(t) + 1000:.6f}")),
    "scistamps": _write_gt("sci.txt", _stamp_edit(lambda t: f"{float(t):.15e}")),
    "halfvocab": halfvocab,
    "truncckpt": truncckpt,
    "camyaml": camyaml,
    "crlf_lists": _seq_edit(_crlf_lists),
    "trunc_depth": _seq_edit(_truncate_one("depth")),
    "rgb_size": _seq_edit(_other_size("rgb")),
    "label_size": _seq_edit(_other_size("labels")),
    "no_depth_txt": _seq_edit(lambda s: (s / "depth.txt").unlink()),
    "header_only": _seq_edit(_header_only),
    "vocnosets": vocnosets,
}


SETUPS: dict[str, Setup] = {
    "ro": ro,
    "notes": notes,
    "synthvoc": synthvoc,
    "crlf": _write_gt("gt_crlf.txt", lambda r: "\r\n".join(r) + "\r\n"),
    "bom": _write_gt("gt_bom.txt", lambda r: "\ufeff" + "\n".join(r) + "\n"),
    "tabs": _write_gt("gt_tabs.txt", lambda r: "\n".join(x.replace(" ", "\t") for x in r) + "\n"),
    "sevencols": _write_gt("seven.txt", lambda r: "\n".join(" ".join(x.split()[:7]) for x in r)),
    "ninecols": _write_gt("nine.txt", lambda r: "\n".join(x + " 1.0" for x in r) + "\n"),
    "backwards": _write_gt("back.txt", lambda r: "\n".join(r[::-1]) + "\n"),
    "dupstamps": _write_gt("dup.txt", lambda r: "\n".join(r[:5] + r[4:]) + "\n"),
    "infpos": _write_gt(
        "inf.txt", lambda r: "\n".join([r[0].split()[0] + " inf 0 0 0 0 0 1", *r[1:]]) + "\n"
    ),
    "commas": _write_gt("comma.txt", lambda r: "\n".join(",".join(x.split()) for x in r) + "\n"),
    "twoposes": _write_gt("two.txt", lambda r: "\n".join(r[:2]) + "\n"),
    "gz": gz,
    "unreadable": unreadable,
    "unreadableonnx": unreadableonnx,
    "seqcopy": seqcopy,
    "sequnicode": sequnicode,
    "no_rgb_txt": _seq_edit(lambda s: (s / "rgb.txt").unlink()),
    "no_gt": _seq_edit(lambda s: (s / "groundtruth.txt").unlink()),
    "no_labels": _seq_edit(lambda s: shutil.rmtree(s / "labels")),
    "empty_gt": _seq_edit(lambda s: (s / "groundtruth.txt").write_text("# no poses\n")),
    "drop_label": _seq_edit(_drop_first("labels")),
    "drop_rgb": _seq_edit(_drop_first("rgb")),
    "label_jpeg": _seq_edit(_label_jpeg),
    "blank_lines": _seq_edit(_blank_lines),
    "unsorted": _seq_edit(_unsorted),
    "zero_depth": _seq_edit(_zero_depth),
    "swap_rgb_depth": _seq_edit(_swap_rgb_depth),
    "emptyfile": emptyfile,
    "ownvocab": lambda c, w: shutil.copy(w["vocab"], c / "v.txt"),
    "demoout": demoout,
    "emptyonnx": lambda c, w: (c / "m.onnx").write_bytes(b""),
    "emptyckpt": lambda c, w: (c / "e.ckpt").write_bytes(b""),
    "upperonnx": lambda c, w: shutil.copy(w["onnx"], c / "M.ONNX"),
    "exportscopy": lambda c, w: shutil.copytree(Path(w["onnx"]).parent, c / "exports"),
    "pngfile": lambda c, w: shutil.copy(sorted(Path(w["seq"], "rgb").iterdir())[0], c / "p.png"),
    "slamcopy": lambda c, w: shutil.copytree(w["slam"], c / "run"),
    "vocnoseg": vocnoseg,
    "trainruncopy": trainruncopy,
}
SETUPS.update(SECOND)
