"""Bad inputs a new user gives every console script, and what each must do with them.

One parametrized matrix over all nine console scripts, run in this process (``main(argv)`` for
the argparse scripts, ``sys.argv`` + ``main()`` for the Hydra apps). For every case:

- the exit code: 1 for a bad file, value, key or folder; 2 for an argparse usage error;
  130 after Ctrl-C;
- stderr: exactly one line ``<prog>: error: ...`` naming the file (and line) or the key, and
  what was expected (a usage error: argparse's usage, then that line; Ctrl-C:
  ``<prog>: interrupted``); never a traceback;
- the disk: nothing written (every file under the test's folder byte for byte as before the
  call, an earlier run or export in the output folder included). Hydra's own record of a call
  (its ``.hydra/`` folder and log file in the run folder) is the only exception.

Cases that an existing test already asserts the same way are not repeated here (see the
``tests/<package>/`` error tests); this file is about breadth. A kill -9 of ``uss-export``
while it writes is at the end.
"""

from __future__ import annotations

import importlib
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from shared_helpers import fake_run, tiny_net

from uss_slam.core.files import file_sha256
from uss_slam.core.schema import MAX_THREADS

TESTS = Path(__file__).resolve().parent

# Console script -> (module of its entry point, how main is called: "argv" = main(argv)
# returning or exiting with the code; "sys.argv" = a Hydra app reading sys.argv).
ENTRY_POINTS = {
    "uss-synth": ("uss_slam.synthetic.cli", "argv"),
    "uss-traj": ("uss_slam.slam_eval.scoring.traj_cli", "argv"),
    "uss-vocab": ("uss_slam.slam_eval.systems.orbslam3.vocab_cli", "argv"),
    "uss-eval": ("uss_slam.pipelines.evaluate", "argv"),
    "uss-demo": ("uss_slam.pipelines.demo", "argv"),
    "uss-slam": ("uss_slam.slam_eval.run", "sys.argv"),
    "uss-train": ("uss_slam.train.train", "sys.argv"),
    "uss-export": ("uss_slam.export.cli", "sys.argv"),
    "uss-experiments": ("uss_slam.pipelines.experiments.cli", "sys.argv"),
}


# ------------------------------------------------------------------------------ the world


@pytest.fixture(scope="module")
def world(
    tmp_path_factory: pytest.TempPathFactory, synthetic_sequence, synthetic_voc
) -> dict[str, Path]:
    """Read-only inputs shared by the cases: a small labelled sequence, the training data of the
    train tests, a uss-train run folder, and a complete earlier uss-slam run."""
    root = tmp_path_factory.mktemp("matrix")
    seq = synthetic_sequence(preset="walking_xyz", frames=8, size=(160, 120), seed=5)
    ckpt = fake_run(root / "train_run", tiny_net(seed=3))
    slam = root / "slam_run"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(sys, "argv", ["uss-slam", f"sequence.path={seq}", f"out_dir={slam}",
                                    "progress=false"])  # fmt: skip
        try:
            importlib.import_module("uss_slam.slam_eval.run").main()
        finally:
            HydraConfig.instance().cfg = None
            GlobalHydra.instance().clear()
    assert (slam / "run.json").is_file()
    return {
        "seq": seq,
        "gt": seq / "groundtruth.txt",
        "voc": synthetic_voc(),
        "target": synthetic_sequence(),
        "val": synthetic_sequence(frames=6, size=(160, 120), seed=1),
        "ckpt": ckpt,
        "slam_run": slam,
    }


# ------------------------------------------------------------------------------ setups
# Each setup prepares the case's inputs in its own folder; ``p`` maps template names to paths
# (``tmp`` the case's folder, the world's inputs, and what the setup adds).

Setup = Callable[[dict[str, Path]], None]


def afile(p: dict[str, Path]) -> None:
    """``{afile}``: a file where the user meant a folder."""
    p["afile"] = p["tmp"] / "afile"
    p["afile"].write_text("a file, not a folder\n")


def fifo(p: dict[str, Path]) -> None:
    """``{fifo}``: a named pipe (nobody writes it: a reader would wait for ever)."""
    p["fifo"] = p["tmp"] / "fifo"
    os.mkfifo(p["fifo"])


def read_only_vocabulary(p: dict[str, Path]) -> None:
    """``{v}``: a vocabulary of the user's, made read-only (``chmod 444``)."""
    p["v"] = p["tmp"] / "v.txt"
    p["v"].write_text("10 2 0 0\n")
    p["v"].chmod(0o444)


def folder(name: str, ext: str = "") -> Setup:
    def make(p: dict[str, Path]) -> None:
        p[name] = p["tmp"] / f"{name}{ext}"
        p[name].mkdir()

    return make


def write(
    name: str, data: bytes | str | Callable[[dict[str, Path]], bytes], ext: str = ""
) -> Setup:
    """``{name}``: a file ``<name><ext>`` in the case's folder with ``data`` (or ``data(p)``)."""

    def make(p: dict[str, Path]) -> None:
        content = data(p) if callable(data) else data
        p[name] = p["tmp"] / f"{name}{ext}"
        p[name].write_bytes(content.encode() if isinstance(content, str) else content)

    return make


def seq_copy(change: Callable[[Path], None] = lambda seq: None) -> Setup:
    """``{s}``: a copy of the world's sequence, then ``change(copy)``."""

    def make(p: dict[str, Path]) -> None:
        p["s"] = p["tmp"] / "s"
        shutil.copytree(p["seq"], p["s"])
        change(p["s"])

    return make


def earlier_slam_run(p: dict[str, Path]) -> None:
    """``{out}``: a complete earlier uss-slam run (the call must leave it as it is)."""
    p["out"] = p["tmp"] / "out"
    shutil.copytree(p["slam_run"], p["out"])


def earlier_checkpoint(p: dict[str, Path]) -> None:
    """An earlier training's checkpoint in the run folder the case trains into."""
    folder = p["tmp"] / "run" / "checkpoints"
    folder.mkdir(parents=True)
    shutil.copy(p["ckpt"], folder / "last.ckpt")


def earlier_export(p: dict[str, Path]) -> None:
    """``{exports}``: files of an earlier export under the names uss-export would write."""
    p["exports"] = p["tmp"] / "exports"
    p["exports"].mkdir()
    for name in ("fake.onnx", "fake.int8.onnx", "fake.verify.json"):
        (p["exports"] / name).write_bytes(f"earlier {name}\n".encode())


def nth(folder: str, k: int) -> Callable[[Path], Path]:
    return lambda seq: sorted((seq / folder).iterdir())[k]


def corrupt(folder: str, k: int, data: bytes = b"\x89PNG\r\n\x1a\ntruncated") -> Callable:
    return lambda seq: nth(folder, k)(seq).write_bytes(data)


def plain_onnx(p: dict[str, Path]) -> bytes:
    """A valid ONNX model that is not a uss-export segmenter (no metadata)."""
    import onnx
    from onnx import TensorProto, helper

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])
    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g", [x], [y])
    return onnx.helper.make_model(graph).SerializeToString()


def bad_segmenter(**kwargs: Any) -> Callable[[dict[str, Path]], bytes]:
    """An exported segmenter whose outputs disagree with its metadata
    (:func:`shared_helpers.colour_model`'s ``label_map`` / ``logits_channels``);
    ``class_names`` the metadata's class list (default: the project's)."""
    from shared_helpers import colour_model, segmenter_props

    from uss_slam.core.classes import CLASS_NAMES

    names = kwargs.pop("class_names", CLASS_NAMES)

    def data(p: dict[str, Path]) -> bytes:
        path = colour_model(p["tmp"] / ".model.onnx", segmenter_props(names), **kwargs)
        content = path.read_bytes()
        path.unlink()
        return content

    return data


DARK_IS_7 = {"label_map": (7, 1, 2, 3)}
"""Pixels darker than 128 in every channel (every frame has them) get label 7: no class."""
THREE_CLASSES = {"class_names": ("background", "person", "chair"), "logits_channels": "C"}
"""Metadata of 3 classes, 4 logit channels the graph does not declare."""


def truncated(name: str, keep: float = 0.5) -> Callable[[dict[str, Path]], bytes]:
    def data(p: dict[str, Path]) -> bytes:
        content = p[name].read_bytes()
        return content[: int(len(content) * keep)]

    return data


def flat_rgb(seq: Path) -> None:
    """Every RGB frame of ``seq`` one flat grey (no corners for ORB)."""
    for path in (seq / "rgb").iterdir():
        cv2.imwrite(str(path), np.full((120, 160, 3), 128, np.uint8))


def png_bytes(p: dict[str, Path]) -> bytes:
    return nth("rgb", 0)(p["seq"]).read_bytes()


def vocabulary_text(rows: int) -> str:
    """A DBoW2 text vocabulary header and ``rows`` well-formed nodes of a k=10, L=4 tree."""
    node = "0 1 " + " ".join(["7"] * 32) + " 0.5"
    return "\n".join(["10 4 0 0", *[node] * rows])


# ------------------------------------------------------------------------------ cases


@dataclass(frozen=True)
class Case:
    """One bad input. ``argv`` and ``says`` are templates over the case's paths (``{tmp}``,
    ``{seq}``, ...); every ``says`` item must appear in the error line."""

    id: str
    prog: str
    argv: tuple[str, ...]
    code: int
    says: tuple[str, ...]
    setup: tuple[Setup, ...] = ()
    interrupt: tuple[str, int] | None = None
    """``("module:Object.attr", n)``: that callable raises KeyboardInterrupt on call n + 1."""
    marks: tuple[Any, ...] = field(default_factory=tuple)


def case(id: str, prog: str, argv: str, code: int, *says: str, **kw: Any) -> Case:
    return Case(id, prog, tuple(argv.split()), code, says, **kw)


SLAM = "sequence.path={seq} out_dir={out} progress=false"
SLAM_S = "sequence.path={s} out_dir={out} progress=false"
TRAIN = (
    "experiment=ci data.source.root={voc} data.target.roots=[{target}] data.val.roots=[{val}] "
    "data.val.stride=1 hydra.run.dir={tmp}/run paths.log_dir={tmp}/logs logger=none"
)
EXPORT = "ckpt_path={ckpt} out_dir={tmp}/exports hydra.run.dir={tmp}/hydra"
TRAIN_AT = TRAIN.replace(" hydra.run.dir={tmp}/run", "")
LONG = "a" * 300
"""A file name longer than any file system allows (255 bytes)."""


def over(base: str, *overrides: str) -> str:
    """``base`` (a Hydra command line) with ``overrides``: a key already in it takes the new
    value in its place (a key given twice is refused), the others are added at the end."""
    args = base.split()
    for override in overrides:
        key = override.split("=", 1)[0].lstrip("+~")
        at = [i for i, a in enumerate(args) if a.split("=", 1)[0].lstrip("+~") == key]
        if at:
            args[at[0]] = override
        else:
            args.append(override)
    return " ".join(args)


def _no_cuda() -> tuple[Any, ...]:
    import torch

    return (pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present"),)


NO_CUDA = _no_cuda()
EXPERIMENTS = "out_dir={tmp}/exp dry_run=true"
CASES = [
    # ---------------------------------------------------------------- uss-synth (argparse)
    case("synth-out-under-a-file", "uss-synth",
         "sequence --preset walking_xyz --frames 2 --size 32x24 --out {afile}/seq --quiet", 1,
         "--out={afile}/seq", "cannot create the output folder ({afile} is a file)",
         setup=(afile,)),
    case("synth-out-is-a-file", "uss-synth", "voc --images 1 --size 32x24 --out {afile}", 1,
         "--out={afile}: is a file; expected a folder", setup=(afile,)),
    case("synth-seed-not-a-number", "uss-synth",
         "voc --images 1 --seed one --out {tmp}/voc", 2, "--seed", "expected an integer >= 0 and <= 4294967295, got 'one'"),
    case("synth-frames-above-the-bound", "uss-synth",
         "sequence --preset walking_xyz --frames 18001 --out {tmp}/seq", 2,
         "argument --frames", "expected an integer >= 2 and <= 18000", "20 GB", "got '18001'"),
    case("synth-images-above-the-bound", "uss-synth", "voc --images 100001 --out {tmp}/voc", 2,
         "argument --images", "expected an integer >= 1 and <= 100000", "3 GB", "got '100001'"),
    case("synth-missing-preset", "uss-synth", "sequence --out {tmp}/seq", 2,
         "the following arguments are required: --preset"),
    case("synth-ctrl-c-while-rendering", "uss-synth",
         "sequence --preset static_xyz --frames 4 --size 32x24 --out {tmp}/seq --quiet", 130,
         "uss-synth: interrupted; nothing was written",
         interrupt=("uss_slam.synthetic.sequence:SequenceRenderer.frame", 2)),
    case("synth-out-name-too-long", "uss-synth",
         f"voc --images 1 --size 32x24 --out {{tmp}}/{LONG} --quiet", 1,
         f"--out={{tmp}}/{LONG}: the name", "is 300 bytes; expected at most 255"),
    # ---------------------------------------------------------------- uss-traj (argparse)
    case("traj-png-as-trajectory", "uss-traj", "ate {gt} {png}", 1,
         "{png}:1: not a text file: byte 0x89 at column 1 is not UTF-8",
         setup=(write("png", png_bytes),)),
    case("traj-truncated-groundtruth", "uss-traj", "ate {gt} {cut}", 1,
         "{cut}:", "expected 8 columns", setup=(write("cut", lambda p: p["gt"].read_bytes()[:200]),)),
    case("traj-latin1-garbage", "uss-traj", "rpe {bad} {gt}", 1,
         "{bad}:1: not a text file: byte 0xff at column 1 is not UTF-8",
         setup=(write("bad", b"\xff\xfe\x00 caf\xe9\n"),)),
    case("traj-zero-quaternion", "uss-traj", "ate {gt} {zq}", 1,
         "{zq}:1:", "unit norm, got norm 0.000000",
         setup=(write("zq", "1 0 0 0 0 0 0 0\n2 0 0 0 0 0 0 1\n3 0 0 0 0 0 0 1\n"),)),
    case("traj-plot-under-a-file", "uss-traj", "ate {gt} {gt} --plot {afile}/ate.png", 1,
         "--plot={afile}/ate.png", "({afile} is a file)", setup=(afile,)),
    case("traj-plot-is-a-folder", "uss-traj", "ate {gt} {gt} --plot {plots}", 1,
         "--plot={plots}: is a folder; expected a file", setup=(folder("plots", ".png"),)),
    case("traj-plot-is-an-input", "uss-traj", "ate {gtp} {gt} --plot {gtp}", 1,
         "--plot={gtp}: is the input file {gtp}; expected a file of its own",
         setup=(write("gtp", lambda p: p["gt"].read_bytes(), ".png"),)),
    case("traj-plot-is-an-input-past-a-new-folder", "uss-traj",
         "ate {gt} {gtp} --plot {tmp}/new/../gtp.png", 1,
         "--plot={tmp}/new/../gtp.png: is the input file {gtp}; expected a file of its own",
         setup=(write("gtp", lambda p: p["gt"].read_bytes(), ".png"),)),
    case("traj-offset-nan", "uss-traj", "ate {gt} {gt} --offset nan", 2,
         "argument --offset", "expected a finite number, got 'nan'"),
    case("traj-delta-finer-than-sampling", "uss-traj",
         "rpe {gt} {gt} --unit seconds --delta 0.0001", 1,
         "--delta=0.0001 (seconds): {gt}: no pose pairs 0.0001 seconds apart"),
    case("traj-ctrl-c-while-plotting", "uss-traj", "ate {gt} {gt} --plot {tmp}/ate.png", 130,
         "uss-traj: interrupted",
         interrupt=("uss_slam.slam_eval.scoring.traj_cli:plot_ate", 0)),
    # ---------------------------------------------------------------- uss-vocab (argparse)
    case("vocab-build-not-a-sequence", "uss-vocab", "build {voc} --out {tmp}/v.txt", 1,
         "{voc}/rgb.txt: does not exist"),
    case("vocab-build-out-under-a-file", "uss-vocab",
         "build {seq} --out {afile}/v.txt -k 3 -L 2", 1,
         "--out={afile}/v.txt: cannot create the output folder ({afile} is a file)",
         setup=(afile,)),
    case("vocab-build-out-is-a-folder", "uss-vocab",
         "build {seq} --out {vocab} --overwrite -k 3 -L 2", 1,
         "--out={vocab}: is a folder; expected a file", setup=(folder("vocab"),)),
    case("vocab-build-k-too-large", "uss-vocab", "build {seq} --out {tmp}/v.txt -k 21", 2,
         "argument -k/--branching", "expected an integer >= 2 and <= 20, got '21'"),
    case("vocab-build-missing-frame", "uss-vocab", "build {s} --out {tmp}/v.txt --stride 1",
         1, "{s}/rgb/", "empty file; expected a colour image",
         setup=(seq_copy(corrupt("rgb", 0, b"")),)),
    case("vocab-build-overwrite-a-non-vocabulary", "uss-vocab",
         "build {seq} --out {png} --overwrite -k 3 -L 2", 1,
         "--out={png}: not a DBoW2 text vocabulary; --overwrite replaces only a vocabulary",
         setup=(write("png", png_bytes, ".png"),)),
    case("vocab-build-texture-less-frames", "uss-vocab",
         "build {s} --out {tmp}/v.txt -k 3 -L 2 --max-frames 2", 1,
         "{s}: no ORB descriptors in the 2 training frames (the frames have no texture)",
         setup=(seq_copy(flat_rgb),)),
    case("vocab-info-truncated", "uss-vocab", "info {v}", 1,
         "{v}:3: expected 'parent is_leaf' + 32 descriptor bytes + 'weight' (35 fields)",
         setup=(write("v", vocabulary_text(3)[:120]),)),
    case("vocab-info-binary", "uss-vocab", "info {png}", 1,
         "{png}:1: not a text file: byte 0x89 at column 1 is not ASCII; expected a DBoW2 text "
         "vocabulary file", setup=(write("png", png_bytes),)),
    case("vocab-ctrl-c-while-clustering", "uss-vocab",
         "build {seq} --out {tmp}/v.txt -k 3 -L 2 --max-frames 2", 130,
         "uss-vocab: interrupted",
         interrupt=("uss_slam.slam_eval.systems.orbslam3.vocabulary:build_vocabulary", 0)),
    # ---------------------------------------------------------------- uss-eval (argparse)
    case("eval-truncated-onnx", "uss-eval", "{m} --sequence {seq} --out {tmp}/eval", 1,
         "{m}: holds no ONNX graph; expected an ONNX model written by uss-export",
         setup=(write("m", b"\x08\x07\x12\x04onnx", ".onnx"),)),
    case("eval-onnx-without-metadata", "uss-eval", "{m} --sequence {seq} --out {tmp}/eval",
         1, "{m}: not a uss-slam segmenter", "(export it with uss-export)",
         setup=(write("m", plain_onnx, ".onnx"),)),
    case("eval-onnx-label-not-a-class", "uss-eval", "{m} --sequence {seq} --out {tmp}/eval", 1,
         "{m}: output 'labels' holds class id 7, but uss_slam.class_names lists 4 classes",
         setup=(write("m", bad_segmenter(**DARK_IS_7), ".onnx"),)),
    case("eval-onnx-channels-not-the-classes", "uss-eval",
         "{m} --sequence {seq} --out {tmp}/eval", 1,
         "{m}: output 'logits' has 4 channels but uss_slam.class_names lists 3 classes",
         setup=(write("m", bad_segmenter(**THREE_CLASSES), ".onnx"),)),
    case("eval-garbage-ckpt", "uss-eval", "{m} --sequence {seq} --out {tmp}/eval", 1,
         "{m}: not a readable checkpoint", setup=(write("m", "not a checkpoint\n", ".ckpt"),)),
    case("eval-out-under-a-file", "uss-eval", "{m} --sequence {seq} --out {afile}/eval", 1,
         "--out={afile}/eval", "({afile} is a file)",
         setup=(afile, write("m", "not read: --out is checked first", ".onnx"))),
    case("eval-unknown-data-option-after-options", "uss-eval",
         "{m} --out {tmp}/eval data=nope", 1,
         "data: unknown option 'nope'; expected one of pretrain, real, synthetic",
         setup=(write("m", "not read: the data config is composed first", ".onnx"),)),
    case("eval-unknown-data-key", "uss-eval", "{m} data.val.bogus=1 --out {tmp}/eval", 1,
         "data.val.bogus: unknown key; expected one of roots, labels, stride, transform",
         setup=(write("m", "not read", ".onnx"),)),
    case("eval-data-value-type", "uss-eval", "{m} data.val.stride=abc --out {tmp}/eval", 1,
         "data.val.stride: expected an integer >= 1, got 'abc'", setup=(write("m", "not read", ".onnx"),)),
    case("eval-corrupt-label-png", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/labels/", "truncated PNG", setup=(seq_copy(corrupt("labels", 3)),)),
    case("eval-threads-zero", "uss-eval", "{m} --sequence {seq} --threads 0 --out {tmp}/e", 2,
         "argument --threads: expected an integer >= 1 and <= ", setup=(write("m", "not read", ".onnx"),)),
    case("eval-ctrl-c-while-inferring", "uss-eval",
         "{ckpt} --sequence {seq} --overlays 2 --out {tmp}/eval", 130, "uss-eval: interrupted",
         interrupt=("uss_slam.pipelines.evaluate:CheckpointSegmenter.infer", 2)),
    case("eval-val-stride-zero", "uss-eval", "{m} data.val.stride=0 --out {tmp}/eval", 1,
         "data.val.stride: expected an integer >= 1, got 0",
         setup=(write("m", "not read", ".onnx"),)),
    case("eval-lock-file-is-a-folder", "uss-eval", "{m} --sequence {seq} --out {tmp}/eval", 1,
         "{tmp}/.eval.lock: the lock file of --out={tmp}/eval is a folder; expected a file",
         setup=(write("m", "not read: the lock comes first", ".onnx"), folder(".eval", ".lock"))),
    # ---------------------------------------------------------------- uss-demo (argparse)
    case("demo-out-under-a-file", "uss-demo",
         "--out {afile}/demo --experiment ci --until data --quiet", 1,
         "--out={afile}/demo", "({afile} is a file)", setup=(afile,)),
    case("demo-sequence-garbage-groundtruth", "uss-demo",
         "--out {tmp}/demo --experiment ci --sequence {s} --quiet", 1,
         "--sequence {s}", "{s}/groundtruth.txt:1: expected 8 columns",
         setup=(seq_copy(lambda s: (s / "groundtruth.txt").write_text("garbage\n")),)),
    case("demo-sequence-empty-rgb-list", "uss-demo",
         "--out {tmp}/demo --experiment ci --sequence {s} --quiet", 1,
         "{s}/rgb.txt", "lists no images",
         setup=(seq_copy(lambda s: (s / "rgb.txt").write_text("")),)),
    case("demo-unknown-experiment", "uss-demo", "--out {tmp}/demo --experiment paper", 2,
         "argument --experiment: invalid choice: 'paper'"),
    case("demo-train-threads-not-a-number", "uss-demo", "--out {tmp}/d --train-threads two", 2,
         "argument --train-threads: expected an integer >= 1 and <= ", "got 'two'"),
    case("demo-ctrl-c-in-the-data-stage", "uss-demo",
         "--out {tmp}/demo --experiment ci --until data --quiet", 130, "uss-demo: interrupted",
         interrupt=("uss_slam.pipelines.synthetic_data:render_demo_data", 0)),
    case("demo-out-is-a-slam-run", "uss-demo", "--out {out} --experiment ci --quiet", 1,
         "--out={out}: holds the outputs of uss-slam (run.json); expected a new folder or an "
         "earlier uss-demo output", setup=(earlier_slam_run,)),
    case("demo-sequence-empty-groundtruth", "uss-demo",
         "--out {tmp}/demo --experiment ci --sequence {s} --quiet", 1,
         "--sequence {s}: {s}/groundtruth.txt: expected at least 2 poses",
         setup=(seq_copy(lambda s: (s / "groundtruth.txt").write_text("")),)),
    # ---------------------------------------------------------------- uss-slam (Hydra)
    case("slam-stride-not-a-number", "uss-slam", f"{SLAM} sequence.stride=abc", 1,
         "sequence.stride: expected an integer >= 1, got 'abc'", setup=(earlier_slam_run,)),
    case("slam-progress-not-a-bool", "uss-slam", over(SLAM, "progress=maybe"), 1,
         "progress: expected true or false, got 'maybe'", setup=(earlier_slam_run,)),
    case("slam-negative-max-diff", "uss-slam", f"{SLAM} sequence.max_diff=-1", 1,
         "sequence.max_diff: expected a number > 0, got -1",
         setup=(earlier_slam_run,)),
    case("slam-added-unknown-key", "uss-slam", f"{SLAM} +max_frames=5", 1,
         "max_frames: unknown key; expected one of sequence, segmenter, slam,",
         setup=(earlier_slam_run,)),
    case("slam-added-unknown-sequence-key", "uss-slam", f"{SLAM} +sequence.maxframes=5", 1,
         "sequence.maxframes: unknown key; expected one of path, camera, max_diff, start,",
         setup=(earlier_slam_run,)),
    case("slam-out-dir-under-a-file", "uss-slam",
         "sequence.path={seq} out_dir={afile}/run progress=false", 1,
         "out_dir={afile}/run: cannot create the output folder ({afile} is a file)",
         setup=(afile,)),
    # an output folder that is an input folder: the outputs would be written among the inputs
    case("slam-out-dir-is-the-sequence", "uss-slam", "sequence.path={s} out_dir={s} progress=false",
         1, "out_dir={s}: is the input folder sequence.path={s}; expected a folder of its own",
         setup=(seq_copy(),)),
    # hydra.run.dir beside out_dir, which sets it: the outputs went to hydra.run.dir
    case("slam-run-dir-beside-out-dir", "uss-slam",
         "sequence.path={seq} out_dir={tmp}/o progress=false hydra.run.dir={tmp}/other", 1,
         "hydra.run.dir={tmp}/other: is not out_dir={tmp}/o, which sets the run folder of "
         "uss-slam; expected out_dir alone"),
    case("slam-multirun-sweep-dir-beside-out-dir", "uss-slam",
         "-m sequence.path={seq} out_dir={tmp}/o progress=false hydra.sweep.dir={tmp}/other "
         "sequence.stride=1,2", 1,
         "hydra.sweep.dir={tmp}/other: is not out_dir={tmp}/o, which sets the sweep folder of "
         "uss-slam; expected out_dir alone"),
    # a log file placed where it cannot be opened: logging's traceback before
    case("slam-log-file-in-a-missing-folder", "uss-slam",
         "sequence.path={seq} out_dir={tmp}/o progress=false "
         "hydra.job_logging.handlers.file.filename={tmp}/no/x.log", 1,
         "hydra.job_logging.handlers.file.filename={tmp}/no/x.log: its folder does not exist"),
    case("train-log-file-cannot-be-written", "uss-train",
         f"{TRAIN} hydra.job_logging.handlers.file.filename=/proc/x.log", 1,
         "hydra.job_logging.handlers.file.filename=/proc/x.log: cannot write to /proc"),
    # a multirun's sweep folder: the same checks as a run folder's
    case("slam-multirun-into-the-sequence", "uss-slam",
         "-m sequence.path={s} out_dir={s} progress=false sequence.stride=1,2", 1,
         "out_dir={s}: is the input folder sequence.path={s}; expected a folder of its own",
         setup=(seq_copy(),)),
    case("train-multirun-sweep-dir-is-a-target-root", "uss-train",
         over(TRAIN_AT, "data.target.roots=[{s}]", "hydra.sweep.dir={s}", "seed=1,2") + " -m", 1,
         "hydra.sweep.dir={s}: is the input folder data.target.roots={s}; expected a folder of",
         setup=(seq_copy(),)),
    case("train-run-dir-is-a-target-root", "uss-train",
         over(TRAIN, "data.target.roots=[{s}]", "hydra.run.dir={s}"), 1,
         "hydra.run.dir={s}: is the input folder data.target.roots={s}; expected a folder of its",
         setup=(seq_copy(),)),
    case("export-out-dir-is-the-calibration-root", "uss-export",
         over(EXPORT, "int8=true", "calibration.root={s}", "out_dir={s}"), 1,
         "out_dir={s}: is the input folder calibration.root={s}; expected a folder of its own",
         setup=(seq_copy(),)),
    case("experiments-out-dir-is-the-tum-folder", "uss-experiments",
         over(EXPERIMENTS, "data.real.tum={s}", "out_dir={s}"), 1,
         "out_dir={s}: is the input folder data.real.tum={s}; expected a folder of its own",
         setup=(seq_copy(),)),
    case("slam-unknown-system", "uss-slam", f"{SLAM} system=orbslam2", 1,
         "system: unknown option 'orbslam2'; expected one of harness, orbslam3", setup=(earlier_slam_run,)),
    case("slam-garbage-groundtruth", "uss-slam", SLAM_S, 1,
         "{s}/groundtruth.txt:1: expected 8 columns",
         setup=(seq_copy(lambda s: (s / "groundtruth.txt").write_text("1 2 3\n")),
                earlier_slam_run)),
    case("slam-intrinsics-not-yaml", "uss-slam", SLAM_S, 1,
         "{s}/intrinsics.yaml:2: not valid YAML",
         setup=(seq_copy(lambda s: (s / "intrinsics.yaml").write_text("fx: [1,\n")),
                earlier_slam_run)),
    case("slam-intrinsics-missing-keys", "uss-slam", SLAM_S, 1,
         "{s}/intrinsics.yaml: expected a mapping with keys fx, fy, cx, cy, width, height",
         setup=(seq_copy(lambda s: (s / "intrinsics.yaml").write_text("fx: 100\n")),
                earlier_slam_run)),
    case("slam-empty-rgb-list", "uss-slam", SLAM_S, 1,
         "{s}/rgb.txt: the sequence lists no images",
         setup=(seq_copy(lambda s: (s / "rgb.txt").write_text("")), earlier_slam_run)),
    case("slam-depth-png-is-8-bit-colour", "uss-slam", SLAM_S, 1,
         "{s}/depth/", "expected a single-channel uint16 depth PNG, got uint8",
         setup=(seq_copy(lambda s: cv2.imwrite(str(nth("depth", 4)(s)),
                                               np.zeros((120, 160, 3), np.uint8))),
                earlier_slam_run)),
    case("slam-corrupt-label-png-mid-run", "uss-slam",
         f"{SLAM_S} segmenter=labels filters=[semantic]", 1, "{s}/labels/",
         "truncated PNG",
         setup=(seq_copy(corrupt("labels", 5)), earlier_slam_run)),
    case("slam-truncated-onnx", "uss-slam",
         f"{SLAM} segmenter=onnx segmenter.path={{m}} filters=[semantic]", 1,
         "{m}: holds no ONNX graph; expected an ONNX model written by uss-export",
         setup=(write("m", b"\x08\x07\x12\x04onnx", ".onnx"), earlier_slam_run)),
    case("slam-onnx-without-metadata", "uss-slam",
         f"{SLAM} segmenter=onnx segmenter.path={{m}} filters=[semantic]", 1,
         "{m}: not a uss-slam segmenter", setup=(write("m", plain_onnx, ".onnx"), earlier_slam_run)),
    case("slam-onnx-label-not-a-class", "uss-slam",
         f"{SLAM} segmenter=onnx segmenter.path={{m}} filters=[semantic]", 1,
         "{m}: output 'labels' holds class id 7, but uss_slam.class_names lists 4 classes",
         setup=(write("m", bad_segmenter(**DARK_IS_7), ".onnx"), earlier_slam_run)),
    case("slam-onnx-channels-not-the-classes", "uss-slam",
         f"{SLAM} segmenter=onnx segmenter.path={{m}} filters=[semantic]", 1,
         "{m}: output 'logits' has 4 channels but uss_slam.class_names lists 3 classes",
         setup=(write("m", bad_segmenter(**THREE_CLASSES), ".onnx"), earlier_slam_run)),
    case("slam-ctrl-c-mid-run", "uss-slam", SLAM, 130, "uss-slam: interrupted",
         setup=(earlier_slam_run,),
         # A main-process step of every frame: with the frame worker process (auto on two
         # cores) frames are loaded in the worker, where no hook of this process reaches.
         interrupt=("uss_slam.slam_eval.systems.frame_loop:FrameLoop.step", 3)),
    case("slam-ctrl-c-in-the-second-run-of-a-comparison", "uss-slam",
         f"{SLAM} segmenter=labels compare=[[semantic],[geometry]]", 130,
         "uss-slam: interrupted", setup=(earlier_slam_run,),
         interrupt=("uss_slam.slam_eval.systems.harness:SlamPipeline.run", 1)),
    case("slam-ctrl-c-in-the-last-run-of-a-comparison", "uss-slam",
         f"{SLAM} segmenter=labels compare=[[semantic],[geometry]]", 130,
         "uss-slam: interrupted", setup=(earlier_slam_run,),
         interrupt=("uss_slam.slam_eval.systems.harness:SlamPipeline.run", 2)),
    case("slam-out-dir-name-too-long", "uss-slam",
         f"sequence.path={{seq}} out_dir={{tmp}}/{LONG} progress=false", 1,
         f"out_dir={{tmp}}/{LONG}: the name", "is 300 bytes; expected at most 255"),
    # ---------------------------------------------------------------- uss-train (Hydra)
    case("train-negative-learning-rate", "uss-train", f"{TRAIN} model.optimizer.lr=-1", 1,
         "model.optimizer.lr: expected a number >= 0, got -1"),
    case("train-adam-betas-out-of-range", "uss-train",
         f"{TRAIN} model.method.d_optimizer.betas=[2,0.9]", 1,
         "model.method.d_optimizer.betas[0]: expected a number >= 0 and < 1, got 2"),
    case("train-batch-size-zero", "uss-train", f"{TRAIN} data.batch_size=0", 1,
         "data.batch_size: expected an integer >= 1, got 0"),
    case("train-discriminator-without-layers", "uss-train",
         f"{TRAIN} model.method.discriminator.n_layers=0", 1,
         "model.method.discriminator.n_layers: expected an integer >= 1, got 0"),
    case("train-classes-disagree", "uss-train", f"{TRAIN} model.net.num_classes=3", 1,
         "model.net.num_classes is 3 but model.class_names lists 4"),
    case("train-unknown-experiment", "uss-train", "experiment=paper hydra.run.dir={tmp}/run", 1,
         "experiment: unknown option 'paper'; expected one of ci, demo,"),
    case("train-unknown-method", "uss-train", f"{TRAIN} model/method=dann", 1,
         "model/method: unknown option 'dann'; expected one of ", "adaptsegnet, "),
    case("train-source-is-a-sequence", "uss-train", over(TRAIN, "data.source.root={seq}"), 1,
         "{seq}: not a VOC tree"),
    case("train-resume-from-a-folder", "uss-train", f"{TRAIN} ckpt_path={{tmp}}", 1,
         "ckpt_path={tmp}: is a folder; expected a file"),
    case("train-second-run-into-a-used-folder", "uss-train", TRAIN, 1,
         "callbacks.model_checkpoint.dirpath={tmp}/run/checkpoints: holds checkpoints of an "
         "earlier run (last.ckpt, 1 in all); resume it with "
         "ckpt_path={tmp}/run/checkpoints/last.ckpt", setup=(earlier_checkpoint,)),
    case("train-batch-beyond-the-memory", "uss-train", f"{TRAIN} data.batch_size=1000000", 1,
         "data.batch_size=1000000, data.source.transform.crop_size=129:", "of memory",
         "available"),
    case("train-num-threads-negative", "uss-train", f"{TRAIN} num_threads=-1", 1,
         f"num_threads: expected an integer >= 1 and <= {MAX_THREADS} or null, got -1"),
    case("train-num-threads-zero", "uss-train", f"{TRAIN} num_threads=0", 1,
         f"num_threads: expected an integer >= 1 and <= {MAX_THREADS} or null, got 0"),
    case("train-num-threads-text", "uss-train", f"{TRAIN} num_threads=x", 1,
         f"num_threads: expected an integer >= 1 and <= {MAX_THREADS} or null, got 'x'"),
    case("train-seed-text", "uss-train", f"{TRAIN} seed=abc", 1,
         "seed: expected an integer >= 0 and <= 4294967295 or null, got 'abc'"),
    case("train-tags-not-a-list", "uss-train", f"{TRAIN} tags=5", 1,
         "tags: expected a list of strings, got 5"),
    case("train-seed-negative", "uss-train", f"{TRAIN} seed=-1", 1,
         "seed: expected an integer >= 0 and <= 4294967295 or null, got -1"),
    case("train-gpu-without-cuda", "uss-train", f"{TRAIN} trainer=gpu", 1,
         "trainer=gpu: no CUDA device found; use trainer=cpu", marks=NO_CUDA),
    case("train-ddp-without-cuda", "uss-train", f"{TRAIN} trainer=ddp", 1,
         "trainer=ddp: no CUDA device found; use trainer=cpu", marks=NO_CUDA),
    case("train-run-dir-is-a-slam-run", "uss-train", f"{TRAIN_AT} hydra.run.dir={{out}}", 1,
         "hydra.run.dir={out}: holds the outputs of uss-slam (run.json)",
         setup=(earlier_slam_run,)),
    # ---------------------------------------------------------------- uss-export (Hydra)
    case("export-unknown-key", "uss-export", f"{EXPORT} opsett=17", 1,
         "opsett: unknown key; expected one of ckpt_path, ensemble, name, out_dir, out, head, opset,"),
    case("export-bad-override-syntax", "uss-export", f"{EXPORT} trace_size=[1", 1,
         "trace_size=[1: no viable alternative at input '[1'"),
    case("export-hydra-dir-under-a-file", "uss-export",
         "ckpt_path={ckpt} out_dir={tmp}/exports hydra.run.dir={afile}/hydra", 1,
         "hydra.run.dir={afile}/hydra: cannot create the output folder ({afile} is a file)",
         setup=(afile,)),
    case("export-label-agreement-above-one", "uss-export", f"{EXPORT} min_label_agreement=2",
         1, "min_label_agreement: expected a number > 0 and <= 1 or null, got 2"),
    case("export-one-pixel-verification", "uss-export", f"{EXPORT} verify_size=[1,1]", 1,
         "verify_size must be at least [32, 32], got [1, 1]", "output stride is 8",
         setup=(earlier_export,)),
    case("export-thin-verification", "uss-export", f"{EXPORT} verify_size=[120,31]", 1,
         "verify_size must be at least [32, 32], got [120, 31]"),
    case("export-logit-diff-zero", "uss-export", f"{EXPORT} max_logit_diff=0", 1,
         "max_logit_diff: expected a number > 0 or null, got 0"),
    case("export-onnx-as-checkpoint", "uss-export",
         "ckpt_path={m} out_dir={exports} hydra.run.dir={tmp}/hydra", 1,
         "{m}: not a readable checkpoint",
         setup=(write("m", plain_onnx, ".onnx"), earlier_export)),
    case("export-checkpoint-is-a-folder", "uss-export",
         "ckpt_path={tmp} out_dir={exports} hydra.run.dir={tmp}/hydra", 1,
         "ckpt_path={tmp}: is a folder; expected a file", setup=(earlier_export,)),
    case("export-net-config-without-target", "uss-export",
         f"{EXPORT} net_config={{y}}", 1, "net config {y} has no _target_",
         setup=(write("y", "num_classes: 4\n"),)),
    case("export-unknown-dynamic-class", "uss-export", f"{EXPORT} dynamic_classes=[ghost]", 1,
         "dynamic_classes ['ghost'] are not among"),
    case("export-out-under-a-file", "uss-export",
         "ckpt_path={ckpt} out={afile}/m.onnx hydra.run.dir={tmp}/hydra", 1,
         "out={afile}/m.onnx: cannot create the output folder ({afile} is a file)",
         setup=(afile,)),
    case("export-ctrl-c-while-writing", "uss-export",
         "ckpt_path={ckpt} out_dir={exports} hydra.run.dir={tmp}/hydra", 130,
         "uss-export: interrupted", setup=(earlier_export,),
         interrupt=("uss_slam.export.onnx:verify_model", 0)),
    case("export-run-dir-is-a-slam-run", "uss-export",
         "ckpt_path={ckpt} out_dir={tmp}/exports hydra.run.dir={out}", 1,
         "hydra.run.dir={out}: holds the outputs of uss-slam (run.json); expected a new folder "
         "or an earlier uss-export output", setup=(earlier_slam_run,)),
    # ---------------------------------------------------------------- uss-experiments (Hydra)
    case("experiments-unknown-scale", "uss-experiments", f"{EXPERIMENTS} scale=huge", 1,
         "scale: unknown value 'huge'; accepted: converged, paper, quick, standard, standard_full"),
    case("experiments-unknown-launcher", "uss-experiments", f"{EXPERIMENTS} launcher=k8s", 1,
         "launcher: unknown value 'k8s'; accepted: joblib, local, slurm, submitit_local"),
    case("experiments-unknown-stage", "uss-experiments", f"{EXPERIMENTS} stages=[deploy]", 1,
         "stages[0]: expected one of data, train, export, slam, tables, got 'deploy'"),
    case("experiments-depth-out-of-range", "uss-experiments", f"{EXPERIMENTS} grid.n_layers=[0]",
         1, "grid.n_layers[0]: expected an integer >= 1 and <= 8, got 0"),
    case("experiments-seeds-not-a-list", "uss-experiments", f"{EXPERIMENTS} grid.seeds=abc", 1,
         "grid.seeds: expected a non-empty list of integers >= 0 and <= 4294967295, each once, got 'abc'"),
    case("experiments-unknown-key", "uss-experiments", f"{EXPERIMENTS} grid.depths=[4]", 1,
         "grid.depths"),
    case("experiments-bad-override-syntax", "uss-experiments", f"{EXPERIMENTS} grid.seeds=[0",
         1, "grid.seeds=[0: no viable alternative at input '[0'"),
    case("experiments-out-dir-is-a-file", "uss-experiments",
         "out_dir={afile} dry_run=true", 1, "{afile}", setup=(afile,)),
    case("experiments-dry-run-not-a-bool", "uss-experiments", "out_dir={tmp}/exp dry_run=maybe",
         1, "dry_run: expected true or false, got 'maybe'"),
]  # fmt: skip


# ------------------------------------------------------------------------------ more cases
# A second set of bad inputs of the same families (the earlier held-out set, kept as tests):
# wrong types and ranges of keys, missing or garbled files of every input kind, unwritable
# outputs and foreign folders. A case a console script handles badly today is marked
# ``xfail(strict=True)`` naming the problem: it fails when the fault is mended.


def foreign(p: dict[str, Path]) -> None:
    """``{foreign}``: a folder of the user's own files, no output of ours."""
    p["foreign"] = p["tmp"] / "foreign"
    p["foreign"].mkdir()
    (p["foreign"] / "notes.txt").write_text("the user's notes\n")
    (p["foreign"] / "data.csv").write_text("a,b\n1,2\n")


def eval_output(p: dict[str, Path]) -> None:
    """``{ev}``: an earlier uss-eval output (eval.json, eval.md)."""
    p["ev"] = p["tmp"] / "ev"
    p["ev"].mkdir()
    (p["ev"] / "eval.json").write_text('{"frames": 8}\n')
    (p["ev"] / "eval.md").write_text("# earlier evaluation\n")


def float_input_model(p: dict[str, Path]) -> bytes:
    """An exported segmenter's metadata on a graph whose input is float32, not uint8."""
    from onnx import TensorProto
    from shared_helpers import colour_model, segmenter_props

    from uss_slam.core.classes import CLASS_NAMES

    path = colour_model(
        p["tmp"] / ".m.onnx", segmenter_props(CLASS_NAMES), input_type=TensorProto.FLOAT
    )
    content = path.read_bytes()
    path.unlink()
    return content


def ckpt_bytes(p: dict[str, Path]) -> bytes:
    return p["ckpt"].read_bytes()


def remove(*names: str) -> Callable[[Path], None]:
    def change(seq: Path) -> None:
        for name in names:
            target = seq / name
            shutil.rmtree(target) if target.is_dir() else target.unlink()

    return change


def rewrite(name: str, text: str) -> Callable[[Path], None]:
    return lambda seq: (seq / name).write_text(text)


def replace_frame(folder_name: str, k: int, image: np.ndarray) -> Callable[[Path], None]:
    return lambda seq: cv2.imwrite(str(nth(folder_name, k)(seq)), image)


def gt_rows(p: dict[str, Path], shift: float = 0.0, rows: int | None = None) -> str:
    lines = [r for r in p["gt"].read_text().splitlines() if r and not r.startswith("#")]
    out = []
    for line in lines[:rows]:
        stamp, *rest = line.split()
        out.append(f"{float(stamp) + shift:.6f} {' '.join(rest)}")
    return "\n".join(out) + "\n"


EVAL = "{m} --sequence {seq} --out {tmp}/eval"
NOT_READ = write("m", "not read: the arguments are checked first", ".onnx")
XFAIL = pytest.mark.xfail


def bad(reason: str) -> tuple[Any, ...]:
    """The mark of a case handled badly today (a traceback, a silent success, a lost result)."""
    return (XFAIL(strict=True, reason=reason),)


# ------------------------------------------------------------------------------ cases

MORE_CASES = [
    # ---------------------------------------------------------------- uss-synth (argparse)
    case("synth-size-garbled", "uss-synth", "voc --images 1 --size 32by24 --out {tmp}/v", 2,
         "--size", "32by24",
         "size must be WIDTHxHEIGHT like 640x480"),
    case("synth-size-zero-width", "uss-synth", "voc --images 1 --size 0x24 --out {tmp}/v", 2,
         "--size", "0x24",
         "size must be between 16x16 and 4096x4096, got 0x24"),
    case("synth-frames-zero", "uss-synth",
         "sequence --preset walking_xyz --frames 0 --out {tmp}/s", 2, "--frames", "0",
         "expected an integer >= 2 and <= 18000"),
    case("synth-images-negative", "uss-synth", "voc --images -3 --out {tmp}/v", 2,
         "--images", "-3",
         "expected an integer >= 1 and <= 100000"),
    case("synth-unknown-preset", "uss-synth", "sequence --preset running --out {tmp}/s", 2,
         "--preset", "running",
         "unknown preset 'running'; choose one of walking_xyz"),
    case("synth-unknown-kind", "uss-synth", "video --out {tmp}/v", 2, "video",
         "invalid choice: 'video' (choose from 'sequence', 'voc')"),
    case("synth-overwrite-a-foreign-folder", "uss-synth",
         "voc --images 1 --size 32x24 --out {foreign} --overwrite --quiet", 2,
         "{foreign}: not a uss-synth output", "refusing to overwrite it", setup=(foreign,)),
    case("synth-overwrite-a-slam-run", "uss-synth",
         "sequence --preset static_xyz --frames 2 --size 32x24 --out {out} --overwrite --quiet",
         2, "{out}: not a uss-synth output", setup=(earlier_slam_run,)),
    # ---------------------------------------------------------------- uss-traj (argparse)
    case("traj-missing-file", "uss-traj", "ate {gt} {tmp}/est.txt", 1, "{tmp}/est.txt",
         ": does not exist; expected a trajectory file (TUM format)"),
    case("traj-folder-as-trajectory", "uss-traj", "ate {gt} {tmp}", 1, "{tmp}",
         ": is a folder; expected a file"),
    case("traj-empty-file", "uss-traj", "ate {gt} {e}", 1, "{e}",
         ": no poses (expected lines 'timestamp tx ty tz qx qy qz qw')", setup=(write("e", ""),)),
    case("traj-comments-only", "uss-traj", "rpe {gt} {e}", 1, "{e}",
         ": no poses (expected lines 'timestamp tx ty tz qx qy qz qw')",
         setup=(write("e", "# timestamp tx ty tz qx qy qz qw\n"),)),
    case("traj-nan-position", "uss-traj", "ate {gt} {e}", 1, "{e}:1:",
         "expected a finite number for tx, got 'nan'",
         setup=(write("e", "1 nan 0 0 0 0 0 1\n2 0 0 0 0 0 0 1\n3 0 0 0 0 0 0 1\n"),)),
    case("traj-no-common-time", "uss-traj", "ate {gt} {e}", 1, "{e}",
         "only 0 of its 83 poses associate with",
         setup=(write("e", lambda p: gt_rows(p, shift=1000.0)),)),
    case("traj-one-pose", "uss-traj", "ate {gt} {e}", 1, "{e}",
         "need at least 3",
         setup=(write("e", lambda p: gt_rows(p, rows=1)),)),
    case("traj-unknown-align", "uss-traj", "ate {gt} {gt} --align affine", 2, "--align",
         "affine",
         "invalid choice: 'affine'"),
    case("traj-max-diff-negative", "uss-traj", "ate {gt} {gt} --max-diff -1", 2, "--max-diff",
         "expected a number >= 0, got '-1'"),
    case("traj-delta-zero", "uss-traj", "rpe {gt} {gt} --delta 0", 2, "--delta",
         "argument --delta: expected a number > 0, got '0'"),
    # ---------------------------------------------------------------- uss-vocab (argparse)
    case("vocab-info-missing-file", "uss-vocab", "info {tmp}/v.txt", 1, "{tmp}/v.txt",
         ": does not exist; expected a DBoW2 text vocabulary file"),
    case("vocab-info-folder", "uss-vocab", "info {tmp}", 1, "{tmp}",
         ": is a folder; expected a file"),
    case("vocab-info-header-not-numbers", "uss-vocab", "info {v}", 1, "{v}:1:",
         "expected the DBoW2 text header 'k L scoring weighting' (4 integers), got 'ten four zero zero'",
         setup=(write("v", "ten four zero zero\n"),)),
    case("vocab-build-levels-zero", "uss-vocab", "build {seq} --out {tmp}/v.txt -L 0", 2,
         "-L",
         "expected an integer >= 1 and <= 10, got '0'"),
    case("vocab-build-stride-zero", "uss-vocab", "build {seq} --out {tmp}/v.txt --stride 0", 2,
         "--stride",
         "expected an integer >= 1, got '0'"),
    case("vocab-build-features-zero", "uss-vocab",
         "build {seq} --out {tmp}/v.txt --features 0", 2, "--features",
         "expected an integer >= 1 and <= 100000, got '0'"),
    case("vocab-build-out-exists", "uss-vocab", "build {seq} --out {v} -k 3 -L 2", 1,
         "--out={v}: exists; pass --overwrite", setup=(write("v", "the user's file\n"),)),
    case("vocab-build-overwrite-a-read-only-vocabulary", "uss-vocab",
         "build {seq} --out {v} -k 3 -L 2 --overwrite", 1,
         "--out={v}: is read-only (its mode forbids writing", setup=(read_only_vocabulary,)),
    case("demo-out-is-the-sequence", "uss-demo",
         "--out {seq} --experiment ci --sequence {seq} --until data --quiet", 1,
         "--out={seq}: is the input folder --sequence={seq}; expected a folder of its own"),
    case("vocab-build-out-is-a-device", "uss-vocab", "build {seq} --out /dev/null -k 3 -L 2", 1,
         "--out=/dev/null: is a device, not a regular file"),
    case("traj-input-is-a-fifo", "uss-traj", "ate {fifo} {gt}", 1,
         "{fifo}: is a named pipe (FIFO), not a regular file", setup=(fifo,)),
    case("vocab-info-of-a-fifo", "uss-vocab", "info {fifo}", 1,
         "{fifo}: is a named pipe (FIFO), not a regular file", setup=(fifo,)),
    case("vocab-build-garbled-rgb-list", "uss-vocab", "build {s} --out {tmp}/v.txt -k 3 -L 2",
         1, "{s}/rgb.txt:1:",
         "expected 'timestamp filename' (2 columns), got 1 columns", setup=(seq_copy(rewrite("rgb.txt", "garbage\n")),)),
    case("vocab-build-listed-frame-missing", "uss-vocab",
         "build {s} --out {tmp}/v.txt -k 3 -L 2 --stride 1", 1, "{s}/rgb/",
         "file not found (listed in {s}/rgb.txt)",
         setup=(seq_copy(lambda s: nth("rgb", 0)(s).unlink()),)),
    # ---------------------------------------------------------------- uss-eval (argparse)
    case("eval-missing-model", "uss-eval", "{tmp}/m.onnx --sequence {seq} --out {tmp}/eval", 1,
         "{tmp}/m.onnx",
         ": does not exist"),
    case("eval-model-unknown-kind", "uss-eval", EVAL, 1, "{m}",
         "expected a uss-train checkpoint (.ckpt) or an exported model (.onnx)", setup=(write("m", "x", ".pt"),)),
    case("eval-stride-zero", "uss-eval", f"{EVAL} --stride 0", 2, "--stride",
         "argument --stride: expected an integer >= 1, got '0'", setup=(NOT_READ,)),
    case("eval-overlays-negative", "uss-eval", f"{EVAL} --overlays -1", 2, "--overlays",
         "argument --overlays: expected an integer >= 0, got '-1'",
         setup=(NOT_READ,)),
    case("eval-sequence-is-a-file", "uss-eval", "{m} --sequence {afile} --out {tmp}/eval", 1,
         "--sequence={afile}",
         ": is a file; expected a folder", setup=(afile, NOT_READ)),
    case("eval-sequence-and-overrides", "uss-eval",
         "{m} data=synthetic --sequence {seq} --out {tmp}/eval", 1, "--sequence",
         "give either --sequence folders or data-config overrides",
         setup=(NOT_READ,)),
    case("eval-sequence-without-labels", "uss-eval", "{m} --sequence {s} --out {tmp}/eval", 1,
         "{s}",
         "labels requested but the folder does not exist", setup=(NOT_READ, seq_copy(remove("labels")))),
    case("eval-sequence-given-twice", "uss-eval",
         "{m} --sequence {seq} --sequence {seq} --out {tmp}/eval", 1, "--sequence={seq}",
         ": given twice (as {seq}); expected each folder once",
         setup=(NOT_READ,)),
    case("eval-out-is-a-file", "uss-eval", "{m} --sequence {seq} --out {afile}", 1,
         "--out={afile}",
         ": is a file; expected a folder", setup=(afile, NOT_READ)),
    case("eval-truncated-checkpoint", "uss-eval", EVAL, 1, "{m}",
         ": not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt",
         setup=(write("m", truncated("ckpt"), ".ckpt"),)),
    case("eval-onnx-float-input", "uss-eval", EVAL, 1, "{m}",
         "input 'image' is tensor(float)",
         setup=(write("m", float_input_model, ".onnx"),)),
    case("eval-label-png-wrong-size", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/labels/",
         "labels are 80x60 but the colour image", setup=(seq_copy(replace_frame("labels", 2, np.zeros((60, 80),
                                                                            np.uint8))),)),
    case("eval-label-png-16-bit", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/labels/",
         "expected a single-channel uint8 class-id PNG, got uint16", setup=(seq_copy(replace_frame("labels", 1, np.zeros((120, 160),
                                                                            np.uint16))),)),
    case("eval-rgb-png-garbled", "uss-eval", "{ckpt} --sequence {s} --out {tmp}/eval", 1,
         "{s}/rgb/",
         ": truncated PNG", setup=(seq_copy(corrupt("rgb", 2)),)),
    case("eval-out-is-a-slam-run", "uss-eval", "{ckpt} --sequence {seq} --out {out}", 1,
         "--out={out}: holds the outputs of uss-slam (run.json); expected a new folder or an "
         "earlier uss-eval output", setup=(earlier_slam_run,)),
    # ---------------------------------------------------------------- uss-demo (argparse)
    case("demo-unknown-stage", "uss-demo", "--out {tmp}/demo --until deploy", 2, "--until",
         "deploy",
         "invalid choice: 'deploy'"),
    case("demo-sequence-missing-folder", "uss-demo",
         "--out {tmp}/demo --experiment ci --sequence {tmp}/nope --quiet", 1,
         "--sequence={tmp}/nope",
         "does not exist; expected a TUM sequence folder or one of the demo's SLAM sequences"),
    case("demo-sequence-garbled-rgb-list", "uss-demo",
         "--out {tmp}/demo --experiment ci --sequence {s} --quiet", 1, "{s}/rgb.txt",
         "expected 'timestamp filename' (2 columns), got 1 columns",
         setup=(seq_copy(rewrite("rgb.txt", "1.0\n")),)),
    case("demo-out-is-a-file", "uss-demo", "--out {afile} --experiment ci --quiet", 1,
         "--out={afile}",
         ": is a file; expected a folder", setup=(afile,)),
    case("demo-out-is-an-eval-output", "uss-demo",
         "--out {ev} --experiment ci --until data --quiet", 1,
         "--out={ev}: holds the outputs of uss-eval (eval.json)", setup=(eval_output,)),
    case("demo-train-threads-zero", "uss-demo",
         "--out {tmp}/demo --experiment ci --train-threads 0 --quiet", 2,
         "argument --train-threads: expected an integer >= 1 and <= ", "got '0'"),
    # ---------------------------------------------------------------- uss-slam (Hydra)
    case("slam-sequence-path-missing", "uss-slam", "out_dir={out} progress=false", 1,
         "sequence.path",
         "Missing mandatory value", setup=(earlier_slam_run,)),
    case("slam-sequence-path-is-a-file", "uss-slam",
         "sequence.path={afile} out_dir={out} progress=false", 1, "{afile}",
         "sequence.path={afile}: is a file; expected a folder",
         setup=(afile, earlier_slam_run)),
    case("slam-sequence-is-a-voc-tree", "uss-slam",
         "sequence.path={voc} out_dir={out} progress=false", 1, "{voc}",
         "not a TUM RGB-D sequence: rgb.txt not found",
         setup=(earlier_slam_run,)),
    case("slam-unknown-camera", "uss-slam", f"{SLAM} sequence.camera=fr9", 1, "fr9",
         "not one of fr1, fr2, fr3 and no such file",
         setup=(earlier_slam_run,)),
    case("slam-start-past-the-end", "uss-slam", f"{SLAM} sequence.start=1000", 1,
         "sequence.start=1000: past the 8 associated frames of {seq}; expected 0..7",
         setup=(earlier_slam_run,)),
    case("slam-max-frames-zero", "uss-slam", f"{SLAM} sequence.max_frames=0", 1,
         "sequence.max_frames",
         "expected an integer >= 2 or null, got 0", setup=(earlier_slam_run,)),
    case("slam-repeats-zero", "uss-slam", f"{SLAM} slam.repeats=0", 1, "slam.repeats",
         "expected an integer >= 1 and <= 1000, got 0",
         setup=(earlier_slam_run,)),
    case("slam-repeat-budget-half", "uss-slam", f"{SLAM} slam.repeat_budget=0.5", 1,
         "slam.repeat_budget",
         "got 0.5", setup=(earlier_slam_run,)),
    case("slam-workers-zero", "uss-slam", f"{SLAM} slam.workers=0", 1, "slam.workers",
         f"expected an integer >= 1 and <= {MAX_THREADS}, got 0",
         setup=(earlier_slam_run,)),
    case("slam-dilation-negative", "uss-slam",
         f"{SLAM} segmenter=labels filters=[semantic] slam.filter_params.semantic.dilation=-2",
         1, "dilation",
         "slam.filter_params.semantic.dilation: expected an integer >= 0, got -2",
         setup=(earlier_slam_run,)),
    case("slam-dynamic-classes-not-a-list", "uss-slam",
         f"{SLAM} slam.filter_params.semantic.dynamic_classes=person", 1,
         "slam.filter_params.semantic.dynamic_classes",
         "expected a list of strings, got 'person'", setup=(earlier_slam_run,)),
    case("slam-threshold-above-one", "uss-slam",
         f"{SLAM} segmenter=onnx segmenter.path={{m}} segmenter.threshold=1.5", 1,
         "segmenter.threshold",
         "must be a probability in (0, 1) or null, got 1.5", setup=(NOT_READ, earlier_slam_run)),
    case("slam-onnx-float-input", "uss-slam", f"{SLAM} segmenter=onnx segmenter.path={{m}}", 1,
         "{m}",
         "input 'image' is tensor(float)", setup=(write("m", float_input_model, ".onnx"), earlier_slam_run)),
    case("slam-checkpoint-as-segmenter", "uss-slam",
         f"{SLAM} segmenter=onnx segmenter.path={{ckpt}}", 1,
         "{ckpt}: a PyTorch checkpoint, not an ONNX model; export it first: uss-export "
         "ckpt_path={ckpt}",
         setup=(earlier_slam_run,)),
    case("slam-labels-folder-missing", "uss-slam",
         f"{SLAM_S} segmenter=labels filters=[semantic]", 1, "{s}",
         "labels requested but the folder does not exist",
         setup=(seq_copy(remove("labels")), earlier_slam_run)),
    case("slam-depth-list-garbled", "uss-slam", SLAM_S, 1, "{s}/depth.txt",
         "expected 'timestamp filename' (2 columns), got 3 columns",
         setup=(seq_copy(rewrite("depth.txt", "1.0 depth/a.png extra\nnot-a-stamp x\n")),
                earlier_slam_run)),
    case("slam-listed-depth-missing", "uss-slam", SLAM_S, 1, "{s}/depth.txt:6: listed image depth/",
         "not found",
         setup=(seq_copy(lambda s: nth("depth", 2)(s).unlink()), earlier_slam_run)),
    case("slam-rgb-png-garbled", "uss-slam", SLAM_S, 1, "{s}/rgb/",
         ": truncated PNG",
         setup=(seq_copy(corrupt("rgb", 4)), earlier_slam_run)),
    case("slam-label-png-wrong-size", "uss-slam",
         f"{SLAM_S} segmenter=labels filters=[semantic]", 1, "{s}/labels/",
         "labels are 80x60 but the colour image",
         setup=(seq_copy(replace_frame("labels", 3, np.zeros((60, 80), np.uint8))),
                earlier_slam_run)),
    case("slam-intrinsics-negative-focal", "uss-slam", SLAM_S, 1, "{s}/intrinsics.yaml",
         "fx must be > 0, got -100",
         setup=(seq_copy(rewrite("intrinsics.yaml", "fx: -100\nfy: 100\ncx: 80\ncy: 60\n"
                                 "width: 160\nheight: 120\n")), earlier_slam_run)),
    case("slam-out-dir-is-an-eval-output", "uss-slam",
         "sequence.path={seq} out_dir={ev} progress=false", 1,
         "out_dir={ev}: holds the outputs of uss-eval (eval.json)", setup=(eval_output,)),
    case("slam-multirun-into-an-eval-output", "uss-slam",
         "-m sequence.path={seq} out_dir={ev} progress=false sequence.stride=1,2", 1,
         "out_dir={ev}: holds the outputs of uss-eval (eval.json)", setup=(eval_output,)),
    case("slam-out-dir-is-an-export", "uss-slam",
         "sequence.path={seq} out_dir={exports} progress=false", 1,
         "out_dir={exports}: holds the outputs of uss-export (fake.verify.json)",
         setup=(earlier_export,)),
    # ---------------------------------------------------------------- uss-train (Hydra)
    case("train-source-root-missing", "uss-train", over(TRAIN, "data.source.root={tmp}/nope"), 1,
         "data.source.root={tmp}/nope",
         ": does not exist; expected a folder"),
    case("train-target-root-is-a-file", "uss-train", over(TRAIN, "data.target.roots=[{afile}]"),
         1, "data.target.roots={afile}",
         ": is a file; expected a folder", setup=(afile,)),
    case("train-val-root-is-a-voc-tree", "uss-train", over(TRAIN, "data.val.roots=[{voc}]"), 1,
         "{voc}",
         "not a TUM RGB-D sequence"),
    case("train-max-iters-zero", "uss-train", f"{TRAIN} model.max_iters=0", 1, "max_iters",
         "model.max_iters: expected an integer >= 1, got 0"),
    case("train-adv-weight-negative", "uss-train", f"{TRAIN} model.method.lambda_adv_main=-1", 1,
         "model.method.lambda_adv_main: expected a number >= 0, got -1"),
    case("train-weights-path-missing", "uss-train",
         f"{TRAIN} model.net.weights_path={{tmp}}/init.ckpt", 1, "{tmp}/init.ckpt",
         "weights file not found; expected a uss-train checkpoint"),
    case("train-weights-path-garbage", "uss-train",
         f"{TRAIN} model.net.weights_path={{w}}", 1, "{w}",
         "not a readable torch weights file (truncated, corrupt or not written by torch.save: "
         "UnpicklingError); expected",
         setup=(write("w", "not a checkpoint\n", ".ckpt"),)),
    case("train-resume-from-garbage", "uss-train", f"{TRAIN} ckpt_path={{c}}", 1, "{c}",
         "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt",
         setup=(write("c", b"\x80\x02garbage", ".ckpt"),)),
    case("train-resume-from-an-onnx", "uss-train", f"{TRAIN} ckpt_path={{m}}", 1, "{m}",
         "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt",
         setup=(write("m", plain_onnx, ".onnx"),)),
    case("train-val-label-png-garbled", "uss-train", over(TRAIN, "data.val.roots=[{s}]"), 1,
         "data.val.roots={s}: labels/",
         "truncated PNG", setup=(seq_copy(corrupt("labels", 0)),)),
    # ---------------------------------------------------------------- uss-export (Hydra)
    case("export-checkpoint-missing", "uss-export",
         "ckpt_path={tmp}/nope.ckpt out_dir={exports} hydra.run.dir={tmp}/hydra", 1,
         "ckpt_path={tmp}/nope.ckpt",
         ": does not exist", setup=(earlier_export,)),
    case("export-truncated-checkpoint", "uss-export",
         "ckpt_path={c} out_dir={exports} hydra.run.dir={tmp}/hydra", 1, "{c}",
         "not a readable checkpoint: truncated, corrupt or not a uss-train .ckpt",
         setup=(write("c", truncated("ckpt", 0.3), ".ckpt"), earlier_export)),
    case("export-calibration-frames-zero", "uss-export",
         f"{EXPORT} int8=true calibration.root={{seq}} calibration.frames=0", 1,
         "calibration.frames: expected an integer >= 1, got 0"),
    case("export-calibration-frames-text", "uss-export",
         f"{EXPORT} int8=true calibration.root={{seq}} calibration.frames=many", 1,
         "calibration.frames: expected an integer >= 1, got 'many'"),
    case("export-calibration-rgb-list-garbled", "uss-export",
         f"{EXPORT} int8=true calibration.root={{s}}", 1, "calibration.root={s}: rgb.txt",
         "expected 'timestamp filename' (2 columns), got 3 columns",
         setup=(seq_copy(rewrite("rgb.txt", "one two three\n")),)),
    case("export-net-config-missing", "uss-export", f"{EXPORT} net_config={{tmp}}/net.yaml", 1,
         "{tmp}/net.yaml",
         ": net config file not found"),
    case("export-net-config-not-yaml", "uss-export", f"{EXPORT} net_config={{y}}", 1, "{y}",
         ": not a readable YAML file",
         setup=(write("y", "_target_: [unclosed\n", ".yaml"),)),
    case("export-out-dir-is-a-file", "uss-export",
         "ckpt_path={ckpt} out_dir={afile} hydra.run.dir={tmp}/hydra", 1, "{afile}",
         ": is a file; expected a folder",
         setup=(afile,)),
    case("export-min-agreement-text", "uss-export", f"{EXPORT} min_label_agreement=most", 1,
         "min_label_agreement: expected a number > 0 and <= 1 or null, got 'most'"),
    case("export-trace-size-negative", "uss-export", f"{EXPORT} trace_size=[-8,64]", 1,
         "trace_size",
         "must be [H, W], two positive integers; got [-8, 64]"),
    case("export-run-folder-as-checkpoint", "uss-export",
         "ckpt_path={out}/run.json out_dir={tmp}/exports hydra.run.dir={tmp}/hydra", 1,
         "{out}/run.json",
         "not a readable checkpoint", setup=(earlier_slam_run,)),
    # ---------------------------------------------------------------- uss-experiments (Hydra)
    case("experiments-seeds-empty", "uss-experiments", f"{EXPERIMENTS} grid.seeds=[]", 1,
         "grid.seeds",
         "expected a non-empty list of integers >= 0 and <= 4294967295, each once, got []"),
    case("experiments-depth-text", "uss-experiments", f"{EXPERIMENTS} grid.n_layers=[deep]", 1,
         "grid.n_layers[0]",
         "expected an integer >= 1 and <= 8, got 'deep'"),
    case("experiments-stages-empty", "uss-experiments", f"{EXPERIMENTS} stages=[]", 1,
         "stages",
         "expected a non-empty list of data, train, export, slam, tables"),
    case("experiments-added-unknown-key", "uss-experiments", f"{EXPERIMENTS} +bogus=1", 1,
         "bogus: unknown key; expected one of scale_name, out_dir, stages, dry_run"),
    case("experiments-added-unknown-section-key", "uss-experiments",
         f"{EXPERIMENTS} +grid.seed=1", 1,
         "grid.seed: unknown key; expected one of methods, n_layers, depth_sweep, seeds"),
    case("experiments-out-dir-is-a-slam-run", "uss-experiments", "out_dir={out} dry_run=true",
         1, "out_dir={out}: holds the outputs of uss-slam (run.json)",
         setup=(earlier_slam_run,)),
    case("experiments-out-dir-is-an-eval-output", "uss-experiments",
         "out_dir={ev} dry_run=true", 1, "out_dir={ev}: holds the outputs of uss-eval (eval.json)",
         setup=(eval_output,)),
    case("experiments-duplicated-seeds", "uss-experiments", f"{EXPERIMENTS} grid.seeds=[3,3]",
         1, "grid.seeds",
         "3 is listed twice"),
    # a key given twice on a Hydra command line (Hydra keeps the last value without a word)
    case("slam-key-given-twice", "uss-slam", f"{SLAM} progress=true", 1,
         "progress: given twice on the command line (progress=false and progress=true)",
         setup=(earlier_slam_run,)),
    case("slam-group-given-twice", "uss-slam", f"{SLAM} segmenter=labels segmenter=none", 1,
         "segmenter: given twice", "segmenter=labels and segmenter=none",
         setup=(earlier_slam_run,)),
    case("train-key-given-twice-added", "uss-train", f"{TRAIN} +model.x=1 model.x=2", 1,
         "model.x: given twice", "+model.x=1 and model.x=2"),
    case("export-out-dir-given-twice", "uss-export", f"{EXPORT} out_dir={{tmp}}/other", 1,
         "out_dir: given twice"),
    case("experiments-key-given-twice", "uss-experiments", f"{EXPERIMENTS} dry_run=false", 1,
         "dry_run: given twice", "dry_run=true and dry_run=false"),
    case("experiments-train-overrides-key-twice", "uss-experiments",
         f"{EXPERIMENTS} train.overrides=['model.max_iters=5','model.max_iters=6']", 1,
         "train.overrides: model.max_iters is given twice"),
    # a path holding characters Hydra reads only quoted: the quoted form to write
    case("slam-path-with-parentheses", "uss-slam", over(SLAM, "sequence.path={tmp}/run(1)"), 1,
         "sequence.path: the value", "must be quoted for Hydra (it holds ( ))",
         "write sequence.path='{tmp}/run(1)'", setup=(earlier_slam_run,)),
    case("export-out-dir-with-equals", "uss-export", over(EXPORT, "out_dir={tmp}/a=b"), 1,
         "out_dir: the value", "must be quoted for Hydra (it holds =)"),
    case("train-precision-64", "uss-train", f"{TRAIN} trainer.precision=64-true", 1,
         "trainer.precision=64-true: not supported"),
    case("train-accelerator-mps", "uss-train", f"{TRAIN} trainer.accelerator=mps", 1,
         "trainer.accelerator=mps: no Apple GPU"),
    case("slam-out-dir-null", "uss-slam", over(SLAM, "out_dir=null"), 1,
         "out_dir: expected a folder to write into, got null"),
    case("experiments-out-dir-null", "uss-experiments", "out_dir=null dry_run=true", 1,
         "out_dir: expected a folder to write into, got null"),
    # Hydra's own switches it cannot follow (its ValueError was a traceback)
    case("slam-shell-completion-alone", "uss-slam", "--shell-completion", 1,
         "--shell-completion: Expecting one subcommand"),
    case("export-shell-completion-alone", "uss-export", "-sc", 1, "--shell-completion: "),
]  # fmt: skip
CASES += MORE_CASES


# ------------------------------------------------------------------------------ running


def run_console_script(
    prog: str, argv: list[str], monkeypatch: pytest.MonkeyPatch, capsys
) -> tuple[int, str, str]:
    """``prog ARGV`` in this process: (exit code, stdout, stderr)."""
    module, style = ENTRY_POINTS[prog]
    main = importlib.import_module(module).main
    capsys.readouterr()
    try:
        if style == "argv":
            code = main(argv)
        else:
            monkeypatch.setattr(sys, "argv", [prog, *argv])
            code = main()
    except SystemExit as stop:
        code = stop.code
    out, err = capsys.readouterr()
    return int(code or 0), out, err


def interrupt_after(monkeypatch: pytest.MonkeyPatch, target: str, calls: int) -> None:
    """Make ``module:Object.attr`` raise KeyboardInterrupt (Ctrl-C) on call ``calls + 1``."""
    module, _, path = target.partition(":")
    owner: Any = importlib.import_module(module)
    *parents, name = path.split(".")
    for parent in parents:
        owner = getattr(owner, parent)
    original = getattr(owner, name)
    count = [0]

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        count[0] += 1
        if count[0] > calls:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(owner, name, wrapper)


def snapshot(root: Path) -> dict[str, str]:
    """Every file under ``root`` -> its SHA-256, every folder -> ``folder``: Hydra's record of
    a refused call (``.hydra/``, its log, the run folder it made) included."""
    files = {}
    for path in sorted(root.rglob("*")):
        rel = path.relative_to(root).as_posix()
        if path.is_file():
            files[rel] = file_sha256(path)
        elif path.is_dir() and not path.is_symlink():
            files[rel] = "folder"
    return files


def check_case(
    bad: Case,
    world: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
) -> None:
    """Run ``bad`` in this process and check what the matrix promises: its exit code, no
    traceback, the one line (argparse: after its usage) holding every text of ``bad.says``,
    and nothing written into ``tmp_path``."""
    paths = {**world, "tmp": tmp_path}
    for setup in bad.setup:
        setup(paths)
    argv = [arg.format(**paths) for arg in bad.argv]
    says = [text.format(**paths) for text in bad.says]
    if bad.interrupt is not None:
        interrupt_after(monkeypatch, *bad.interrupt)
    monkeypatch.chdir(tmp_path)  # relative defaults (outputs/...) stay in the test's folder
    # An earlier in-process app call may leave a log handler on a capture stream pytest has
    # closed since; its "--- Logging error ---" report is this process's, not the script's.
    monkeypatch.setattr(logging, "raiseExceptions", False)
    before = snapshot(tmp_path)

    code, _, err = run_console_script(bad.prog, argv, monkeypatch, capsys)

    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert code == bad.code, err
    if code == 2:  # argparse: its usage (uss-synth: none), then the error line
        assert lines[-1].startswith(bad.prog) and ": error: " in lines[-1], err
        assert all(line.startswith(("usage:", " ")) for line in lines[:-1]), err
    elif code == 130:
        assert lines == says, err
    else:
        assert len(lines) == 1 and lines[0].startswith(f"{bad.prog}: error: "), err
    for text in says:
        assert text in lines[-1], (text, lines[-1])
    assert snapshot(tmp_path) == before  # nothing written; an earlier run or export intact


@pytest.mark.parametrize("bad", [pytest.param(c, id=c.id, marks=c.marks) for c in CASES])
def test_bad_input(
    bad: Case,
    world: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
) -> None:
    check_case(bad, world, tmp_path, monkeypatch, capsys)


def test_every_console_script_is_in_the_matrix() -> None:
    """Each console script of pyproject has at least four cases here."""
    import tomllib

    scripts = tomllib.loads((TESTS.parent / "pyproject.toml").read_text())["project"]["scripts"]
    from uss_slam.core.launch import SCRIPTS

    assert set(scripts) == set(ENTRY_POINTS) == set(SCRIPTS)
    for prog, target in scripts.items():
        assert target == f"uss_slam.core.launch:{prog.replace('-', '_')}"
        assert SCRIPTS[prog] == ENTRY_POINTS[prog][0]
        assert sum(c.prog == prog for c in CASES) >= 4, prog
    assert len(CASES) >= 60


# ------------------------------------------------------------------------------ reruns


def test_eval_rerun_into_the_same_out_holds_one_runs_files(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """A second ``uss-eval`` into a used ``--out`` with fewer overlays: the folder holds the
    second run's overlays only (those of the first were not left beside them)."""
    out = tmp_path / "eval"
    base = [str(world["ckpt"]), "--sequence", str(world["seq"]), "--out", str(out)]
    for overlays, expected in ((3, 3), (1, 1), (0, 0)):
        code, _, err = run_console_script(
            "uss-eval", [*base, "--overlays", str(overlays)], monkeypatch, capsys
        )
        assert code == 0, err
        listed = json.loads((out / "eval.json").read_text())["overlays"]
        present = sorted(p.relative_to(out).as_posix() for p in out.glob("overlays/*"))
        assert len(listed) == expected and present == listed
    assert sorted(p.name for p in out.iterdir()) == ["eval.json", "eval.md"]


# ------------------------------------------------------------------------------ Ctrl-C of uss-train


def test_train_ctrl_c_exits_130_and_keeps_the_checkpoints(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """Ctrl-C of ``uss-train`` in its third iteration (after the first epoch's checkpoints):
    exit code 130 and the line ``uss-train: interrupted`` (not Lightning's shutdown notice and
    exit 1); the checkpoints saved before it stay whole (the first epoch's iteration)."""
    from uss_slam.models.checkpoint import read_checkpoint

    paths = {**world, "tmp": tmp_path}
    argv = [arg.format(**paths) for arg in TRAIN.split()]
    interrupt_after(monkeypatch, "uss_slam.train.module:AdversarialSegmentation.training_step", 2)
    # An earlier in-process app call may leave a log handler on a capture stream pytest has
    # closed since; its "--- Logging error ---" report is this process's, not uss-train's.
    monkeypatch.setattr(logging, "raiseExceptions", False)
    monkeypatch.chdir(tmp_path)
    try:
        code, _, err = run_console_script("uss-train", argv, monkeypatch, capsys)
    finally:
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # Ctrl-C works again
    # Lightning's own start-up notices (GPU available, ...) go to stderr in every run; after
    # them, the one line of an interrupt and nothing of Lightning's shutdown.
    assert code == 130 and err.strip().splitlines()[-1] == "uss-train: interrupted", err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    saved = sorted((tmp_path / "run" / "checkpoints").iterdir())
    assert [p.name for p in saved if p.name == "last.ckpt"] == ["last.ckpt"]
    assert len(saved) == 2 and not [p for p in saved if p.name.endswith(".tmp")]
    for path in saved:  # whole and readable, of the first epoch
        assert read_checkpoint(path).iteration == 2, path


def test_slam_groundtruth_without_common_time_span_warns(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``uss-slam`` on a sequence whose ground truth lies 1000 s after its frames: the run
    succeeds (exit 0, ATE null in metrics.json) and stderr holds one warning line naming
    groundtruth.txt and both time spans."""
    seq = tmp_path / "s"
    shutil.copytree(world["seq"], seq)
    gt = seq / "groundtruth.txt"
    rows = [line.split() for line in gt.read_text().splitlines() if not line.startswith("#")]
    gt.write_text("".join(f"{float(r[0]) + 1000:.6f} {' '.join(r[1:])}\n" for r in rows))
    out = tmp_path / "out"
    argv = [f"sequence.path={seq}", f"out_dir={out}", "progress=false"]
    try:
        code, _, err = run_console_script("uss-slam", argv, monkeypatch, capsys)
    finally:
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"uss-slam: warning: {gt}: the ground truth "
                                                  "spans "), err  # fmt: skip
    first, last = float(rows[0][0]), float(rows[-1][0])
    assert f"{first + 1000:.3f}-{last + 1000:.3f} s, the frames " in lines[0]
    assert lines[0].endswith("no time in common, so ATE and RPE are n/a")
    assert json.loads((out / "metrics.json").read_text())["ate"] is None


def test_vocab_of_one_frame_warns_that_every_weight_is_zero(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``uss-vocab build`` from one frame: every word's idf weight is ln(1/1) = 0; the file is
    written (exit 0) and stderr holds one warning line naming the sequence folder."""
    out = tmp_path / "v.txt"
    argv = ["build", str(world["seq"]), "--out", str(out), "-k", "3", "-L", "2",
            "--max-frames", "1"]  # fmt: skip
    code, _, err = run_console_script("uss-vocab", argv, monkeypatch, capsys)
    assert code == 0 and out.is_file(), err
    assert err.strip().splitlines() == [
        f"uss-vocab: warning: {world['seq']}: every word of the vocabulary has weight 0 (each "
        "occurs in all 1 training frames); use more, and more varied, frames (--stride, "
        "--max-frames, more sequences)"
    ]


@pytest.mark.parametrize(
    "prog, argv, key",
    [
        ("uss-vocab", "build {seq} {again} --out {tmp}/v.txt -k 3 -L 2", None),
        ("uss-eval", "{m} --sequence {seq} --sequence {again} --out {tmp}/e", "--sequence"),
        ("uss-eval", "compare {m} {m2} --sequence {seq} --sequence {again} --out {tmp}/c",
         "--sequence"),
    ],
    ids=["vocab-build", "eval", "eval-compare"],
)  # fmt: skip
def test_sequence_given_twice_is_refused_everywhere(
    prog: str, argv: str, key: str | None, world: dict[str, Path], tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, capsys,
) -> None:  # fmt: skip
    """One policy for a sequence folder given twice, in any spelling (``S/../S``): refused with
    one line naming it and its first spelling (``core.paths.distinct_folders``), nothing
    written."""
    from shared_helpers import colour_model, segmenter_props

    from uss_slam.core.classes import CLASS_NAMES

    models = tmp_path / "models"
    models.mkdir()
    m, m2 = (colour_model(models / f"{name}.onnx", segmenter_props(CLASS_NAMES), bias=bias)
             for name, bias in (("m", 128.0), ("m2", 100.0)))  # fmt: skip
    seq = world["seq"]
    again = f"{seq}/../{seq.name}"
    text = argv.format(seq=seq, again=again, tmp=tmp_path, m=m, m2=m2)
    code, _, err = run_console_script(prog, text.split(), monkeypatch, capsys)
    named = again if key is None else f"{key}={again}"
    assert code == 1, err
    shown = f"{prog} compare" if argv.startswith("compare") else prog
    assert err.strip().splitlines()[-1] == (
        f"{shown}: error: {named}: given twice (as {seq}); expected each folder once"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["models"]


@pytest.mark.parametrize(
    "argv, line",
    [
        ("compare {m} {m2} --sequence {seq} --repeats 5 --out {tmp}/c",
         "uss-eval compare: error: --repeats needs --slam (it counts the SLAM runs per row)"),
        ("compare {m} {m2} --sequence {seq} --source-frames 5 --out {tmp}/c",
         "uss-eval compare: error: --source-frames needs --source DIR (the source-domain images)"),
        ("compare {m} {m2} --sequence {seq} --out {seq}",
         "uss-eval compare: error: --out={seq}: is the input folder --sequence={seq}; expected a "
         "folder of its own for the outputs"),
        ("{m} --sequence {seq} --out {seq}",
         "uss-eval: error: --out={seq}: is the input folder --sequence={seq}; expected a folder "
         "of its own for the outputs"),
        ("{m} --sequence {seq} --dynamic person,,chair --out {tmp}/e",
         "uss-eval: error: argument --dynamic: expected comma-separated names of background, "
         "person, chair, monitor, each once, got 'person,,chair'"),
    ],
    ids=["compare-repeats-without-slam", "compare-source-frames-without-source",
         "compare-out-is-the-sequence", "eval-out-is-the-sequence", "eval-dynamic-empty-name"],
)  # fmt: skip
def test_eval_options_that_change_nothing_or_mix_outputs_with_inputs(
    argv: str, line: str, world: dict[str, Path], tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch, capsys,
) -> None:  # fmt: skip
    """An option that needs another (``--repeats`` without ``--slam``), an output folder that
    is an input folder, an empty name in a list: one line, nothing written."""
    from shared_helpers import colour_model, segmenter_props

    from uss_slam.core.classes import CLASS_NAMES

    models = tmp_path / "models"
    models.mkdir()
    m, m2 = (colour_model(models / f"{name}.onnx", segmenter_props(CLASS_NAMES), bias=bias)
             for name, bias in (("m", 128.0), ("m2", 100.0)))  # fmt: skip
    seq = tmp_path / "seq"
    shutil.copytree(world["seq"], seq)
    before = snapshot(tmp_path)
    text = argv.format(seq=seq, tmp=tmp_path, m=m, m2=m2)
    code, _, err = run_console_script("uss-eval", text.split(), monkeypatch, capsys)
    assert code in (1, 2), err
    assert err.strip().splitlines()[-1] == line.format(seq=seq)
    assert snapshot(tmp_path) == before


def test_eval_of_frames_with_only_ignore_labels_warns(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """Labels that are all 255 (ignore) leave every IoU null: the run succeeds and one warning
    names the sequence and its frames."""
    seq = tmp_path / "s"
    shutil.copytree(world["seq"], seq)
    for label in (seq / "labels").iterdir():
        cv2.imwrite(str(label), np.full((120, 160), 255, np.uint8))
    model = tmp_path / "m.onnx"
    model.write_bytes(colour_onnx({"tmp": tmp_path}))
    argv = [str(model), "--sequence", str(seq), "--out", str(tmp_path / "eval")]
    code, _, err = run_console_script("uss-eval", argv, monkeypatch, capsys)
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"uss-eval: warning: --sequence {seq}: 8 of 8 frames have only ignore labels (255): s/"
    ), err
    assert lines[0].endswith("and 5 more; every IoU and the mIoU are null"), err
    assert json.loads((tmp_path / "eval" / "eval.json").read_text())["mIoU"] is None


def test_traj_into_a_closed_pipe_exits_quietly(world: dict[str, Path]) -> None:
    """``uss-traj ate GT EST --json | head -c0``: the reader is gone before the output is
    written; exit code 1 (the output was not delivered) and nothing on stderr."""
    command = [sys.executable, "-m", "uss_slam.slam_eval.scoring.traj_cli", "ate",
               str(world["gt"]), str(world["gt"]), "--json"]  # fmt: skip
    reader, writer = os.pipe()
    os.close(reader)  # head -c0: closed before uss-traj writes
    try:
        done = subprocess.run(command, stdout=writer, stderr=subprocess.PIPE, timeout=120)
    finally:
        os.close(writer)
    assert (done.returncode, done.stderr.decode()) == (1, "")


def test_a_dry_runs_plan_into_a_closed_pipe_exits_quietly(tmp_path: Path) -> None:
    """``uss-experiments dry_run=true | head -c0``: the plan is the dry run's product; it exited
    0 without a word. Exit code 1 and nothing on stderr, as ``uss-traj``'s numbers."""
    code = "from uss_slam.core.launch import uss_experiments; uss_experiments()"
    reader, writer = os.pipe()
    os.close(reader)
    try:
        done = subprocess.run([sys.executable, "-c", code, f"out_dir={tmp_path / 'e'}",
                               "dry_run=true"], stdout=writer, stderr=subprocess.PIPE,
                              cwd=tmp_path, timeout=300)  # fmt: skip
    finally:
        os.close(writer)
    assert (done.returncode, done.stderr.decode()) == (1, "")


# ------------------------------------------------------------------------------ file modes


@pytest.mark.parametrize("umask", [0o022, 0o002])
def test_outputs_follow_the_umask(
    umask: int, world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """Every file ``uss-slam`` and ``uss-vocab`` write (atomically, through a temporary
    sibling) gets mode 0666 minus the umask, as a plain ``open()`` would give it: 0644 under
    umask 022, 0664 under 002 (never 0600 whatever the umask)."""
    out = tmp_path / "out"
    previous = os.umask(umask)
    try:
        code, _, err = run_console_script(
            "uss-slam", [f"sequence.path={world['seq']}", f"out_dir={out}", "progress=false"],
            monkeypatch, capsys,
        )  # fmt: skip
        assert code == 0, err
        code, _, err = run_console_script(
            "uss-vocab", ["build", str(world["seq"]), "--out", str(out / "v.txt"), "-k", "10",
                          "-L", "2", "--stride", "1"],
            monkeypatch, capsys,
        )  # fmt: skip
        assert code == 0, err
    finally:
        os.umask(previous)
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    modes = {p.name: p.stat().st_mode & 0o777 for p in out.rglob("*") if p.is_file()}
    assert {"run.json", "trajectory.txt", "v.txt"} <= set(modes)
    assert modes == dict.fromkeys(modes, 0o666 & ~umask)


def test_a_umask_leaving_new_folders_unwritable_names_the_apps_output_key(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """``umask 0222`` with a new ``out_dir`` and a new run folder: the line names ``out_dir``,
    the key the user set for the outputs (checked before the run folder Hydra makes), and
    nothing is written."""
    monkeypatch.chdir(tmp_path)
    argv = [f"ckpt_path={world['ckpt']}", f"out_dir={tmp_path}/new/exports",
            f"hydra.run.dir={tmp_path}/hydra"]  # fmt: skip
    previous = os.umask(0o222)
    try:
        code, _, err = run_console_script("uss-export", argv, monkeypatch, capsys)
    finally:
        os.umask(previous)
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    assert code == 1 and err.strip().splitlines() == [
        f"uss-export: error: out_dir={tmp_path}/new/exports: a folder created now could not be "
        "written into: the umask 0222 removes the owner's write permission; set a umask such "
        "as 0022; expected a folder to write into"
    ], err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ two processes

HOLD = """
import sys
from uss_slam.core.files import output_lock
with output_lock(sys.argv[1]):
    print("held", flush=True)
    sys.stdin.read()  # until the test closes stdin
"""


class Holder:
    """Another process holding the lock of ``target`` (as a running console script does)."""

    def __init__(self, target: Path) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-c", HOLD, str(target)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert self.proc.stdout is not None and self.proc.stdout.readline() == "held\n"

    def release(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        assert self.proc.wait(timeout=30) == 0


def colour_onnx(p: dict[str, Path]) -> bytes:
    from shared_helpers import colour_model, segmenter_props

    from uss_slam.core.classes import CLASS_NAMES

    path = colour_model(p["tmp"] / ".colour.onnx", segmenter_props(CLASS_NAMES))
    content = path.read_bytes()
    path.unlink()
    return content


# (console script, argv, the output it locks, how the error line names it, setup)
IN_USE = [
    ("uss-slam", SLAM, "{out}", "out_dir={out}", (earlier_slam_run,)),
    ("uss-export", EXPORT.replace("{tmp}/exports", "{exports}"), "{exports}/fake.onnx",
     "{exports}/fake.onnx", (earlier_export,)),
    ("uss-synth", "sequence --preset static_xyz --frames 2 --size 32x24 --out {tmp}/seq --quiet",
     "{tmp}/seq", "{tmp}/seq", ()),
    ("uss-demo", "--out {tmp}/demo --experiment ci --until data --quiet", "{tmp}/demo",
     "--out={tmp}/demo", ()),
    ("uss-experiments", "out_dir={tmp}/exp stages=[data]", "{tmp}/exp", "out_dir={tmp}/exp", ()),
    ("uss-eval", "{m} --sequence {seq} --out {tmp}/eval", "{tmp}/eval", "--out={tmp}/eval",
     (write("m", colour_onnx, ".onnx"),)),
    ("uss-vocab", "build --out {tmp}/vocab.txt {seq}", "{tmp}/vocab.txt",
     "--out={tmp}/vocab.txt", ()),
]  # fmt: skip


@pytest.mark.parametrize(
    ("prog", "argv", "target", "named", "setup"), IN_USE, ids=[c[0] for c in IN_USE]
)
def test_an_output_in_use_by_another_process_stops_a_second_one(
    prog: str,
    argv: str,
    target: str,
    named: str,
    setup: tuple[Setup, ...],
    world: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
) -> None:
    """While another process holds an output's lock, a second console script writing it stops
    before any work: exit code 2, one line naming the output and the holder's pid, nothing
    written (an earlier run or export intact). Once the holder is gone the lock file is gone
    too, and the same call succeeds (uss-slam, uss-synth: the cheap ones)."""
    paths = {**world, "tmp": tmp_path}
    for step in setup:
        step(paths)
    holder = Holder(Path(target.format(**paths)))
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    try:
        args = [arg.format(**paths) for arg in argv.split()]
        code, _, err = run_console_script(prog, args, monkeypatch, capsys)
        lines = err.strip().splitlines()
        assert code == 2, err
        assert len(lines) == 1, err
        assert lines[0].startswith(
            f"{prog}: error: {named.format(**paths)} is in use by pid {holder.proc.pid} (started "
        ), lines[0]
        assert snapshot(tmp_path) == before
    finally:
        holder.release()
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    assert not list(tmp_path.rglob("*.lock"))
    if prog in ("uss-slam", "uss-synth"):
        code, _, err = run_console_script(prog, args, monkeypatch, capsys)
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
        assert code == 0, err
        assert not list(tmp_path.rglob("*.lock"))


def test_a_lock_left_by_a_killed_run_is_taken_over_with_one_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """The lock file of a ``uss-synth`` killed with -9 (its pid gone): the next run renders
    (exit 0) and says once, as a warning line, whose lock it took over."""
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    pid = int(gone.stdout)
    lock = tmp_path / ".seq.lock"
    lock.write_text(json.dumps({"pid": pid, "host": "h", "started": "2026-01-02 03:04:05"}))
    out = tmp_path / "seq"
    argv = ["sequence", "--preset", "static_xyz", "--frames", "2", "--size", "32x24", "--out",
            str(out), "--quiet"]  # fmt: skip
    code, _, err = run_console_script("uss-synth", argv, monkeypatch, capsys)
    assert code == 0, err
    assert err.strip().splitlines()[0] == (
        f"uss-synth: warning: {out}: taking over the lock {lock} left by pid {pid} (started "
        "2026-01-02 03:04:05), which ended without releasing it"
    )
    assert len(err.strip().splitlines()) == 2  # and "done in ... s"
    assert not lock.exists() and (out / "rgb.txt").is_file()


def test_two_slam_runs_into_one_out_dir(
    world: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """Two real ``uss-slam`` runs on one ``out_dir``: the second (in this process), started
    while the first (a subprocess, on a 30-frame sequence) runs, exits with 2 naming the
    first's pid and writes nothing; the first finishes as if it were alone (a complete,
    verified run replacing the earlier one)."""
    from shared_helpers import outside_staging

    from uss_slam.slam_eval.scoring.run_folder import verify_run

    out = tmp_path / "out"
    shutil.copytree(world["slam_run"], out)
    args = [f"sequence.path={world['target']}", f"out_dir={out}", "progress=false"]
    script = Path(sys.executable).parent / "uss-slam"
    first = subprocess.Popen(
        [str(script), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    lock = tmp_path / ".out.lock"
    deadline = time.monotonic() + 120
    while not (lock.is_file() and lock.read_text().strip()):
        assert first.poll() is None, first.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.01)
    # the first run creates and fills its own staging folder meanwhile: leave those out
    before = outside_staging(snapshot(out))
    try:
        code, _, err = run_console_script("uss-slam", args, monkeypatch, capsys)
    finally:
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    assert first.poll() is None, "the first run ended before the second reached the lock"
    assert outside_staging(snapshot(out)) == before  # the second wrote nothing
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith(
        f"uss-slam: error: out_dir={out} is in use by pid {first.pid} (started "
    ), lines[0]
    _, err = first.communicate(timeout=300)
    assert first.returncode == 0, err
    assert verify_run(out) == [] and not lock.exists()
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["sequence"] == str(world["target"])


# ------------------------------------------------------------------------------ full disk


def earlier_synth_output(p: dict[str, Path]) -> None:
    """``{seq}``: an earlier uss-synth sequence (``--overwrite`` may replace it)."""
    from uss_slam.synthetic import render_sequence

    p["seq_out"] = render_sequence(
        p["tmp"] / "seq", preset="static_xyz", frames=2, size=(32, 24), seed=3, progress=False
    )


SYNTH_OVER = (
    "sequence --preset static_xyz --frames 3 --size 32x24 --out {tmp}/seq --overwrite --quiet"
)
NO_SPACE = [
    # (id, console script, argv, setup, the outputs whose write hits the full disk, the line
    # after "<prog>: error: ": the key or flag that set the output, and the file)
    ("slam", "uss-slam", SLAM, (earlier_slam_run,), ["metrics.json"],
     "out_dir={out}: no space left on device while writing {out}/metrics.json"),
    ("slam-compare-plot", "uss-slam", f"{SLAM} segmenter=labels compare=[[semantic]]",
     (earlier_slam_run,), ["ate.png"],
     "out_dir={out}: no space left on device while writing {out}/baseline/ate.png"),
    ("export-model", "uss-export", EXPORT, (earlier_export,), ["fake.onnx"],
     "out_dir={exports}: no space left on device while writing {exports}/fake.onnx"),
    ("export-report", "uss-export", EXPORT, (earlier_export,), ["fake.verify.json"],
     "out_dir={exports}: no space left on device while writing {exports}/fake.verify.json"),
    ("synth-frame", "uss-synth", SYNTH_OVER, (earlier_synth_output,),
     lambda path: path.parent.name == "labels", "--out={tmp}/seq: no space left on device"),
    ("synth-marker", "uss-synth", SYNTH_OVER, (earlier_synth_output,), [".uss-synth"],
     "--out={tmp}/seq: no space left on device"),
    ("eval", "uss-eval", "{m} --sequence {seq} --out {tmp}/eval", (write("m", colour_onnx, ".onnx"),),
     ["eval.json"], "--out={tmp}/eval: no space left on device while writing {tmp}/eval/eval.json"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("prog", "argv", "setup", "names", "named"),
    [c[1:] for c in NO_SPACE],
    ids=[c[0] for c in NO_SPACE],
)
def test_a_full_disk_is_one_line_and_keeps_the_earlier_outputs(
    prog: str,
    argv: str,
    setup: tuple[Setup, ...],
    names: Any,
    named: str,
    world: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
) -> None:
    """ENOSPC while an output is written (the file being written is ``/dev/full``): exit code
    1, one line ``<prog>: error: <key>=<output>: no space left on device while writing <path>``
    naming the key or flag that set the output and the file's final path, every earlier output
    byte for byte as before, and no temporary file, staging or partial folder left behind."""
    from shared_helpers import full_disk

    paths = {**world, "tmp": tmp_path}
    for step in setup:
        step(paths)
    monkeypatch.chdir(tmp_path)
    before = snapshot(tmp_path)
    hit = full_disk(monkeypatch, names)
    try:
        args = [arg.format(**paths) for arg in argv.split()]
        code, _, err = run_console_script(prog, args, monkeypatch, capsys)
    finally:
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    assert hit, "the full disk was never reached"
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert code == 1 and len(lines) == 1, err
    assert lines == [f"{prog}: error: {named.format(**paths)}"]
    assert snapshot(tmp_path) == before
    left = [p.name for p in tmp_path.rglob("*") if p.is_symlink() or ".tmp" in p.name
            or ".partial-" in p.name or p.name.startswith(".uss-slam-new.")]  # fmt: skip
    assert left == []


FILE_SIZE_LIMIT = [
    # (console script, argv, ulimit -f in KiB, the line after "<prog>: error: ")
    ("uss-synth", "voc --images 2 --size 96x64 --out {tmp}/v --quiet", 1,
     "--out={tmp}/v: the file size limit is exceeded (ulimit -f)"),
    ("uss-traj", "ate {gt} {gt} --plot {tmp}/p.png", 4,
     "--plot={tmp}/p.png: the file size limit is exceeded (ulimit -f)"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("prog", "argv", "kib", "named"), FILE_SIZE_LIMIT, ids=[c[0] for c in FILE_SIZE_LIMIT]
)
def test_a_file_size_limit_names_the_flag_of_the_output(
    prog: str, argv: str, kib: int, named: str, world: dict[str, Path], tmp_path: Path
) -> None:
    """``ulimit -f`` met while an output is written (the script's own process, the real
    limit): one line naming the flag that set the output, nothing left behind."""
    import resource

    paths = {**world, "tmp": tmp_path, "gt": world["seq"] / "groundtruth.txt"}
    limit = kib * 1024

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    script = Path(sys.executable).parent / prog
    done = subprocess.run([str(script), *(a.format(**paths) for a in argv.split())],
                          capture_output=True, text=True, timeout=120, preexec_fn=limited)  # fmt: skip
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().splitlines() == [f"{prog}: error: {named.format(**paths)}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ no working folder


def _in_a_deleted_folder(folder: Path) -> Callable[[], None]:
    """A ``preexec_fn``: the child starts in ``folder``, deleted under it (``rm -r`` in another
    terminal)."""

    def gone() -> None:
        os.rmdir(folder)

    return gone


@pytest.mark.slow  # a uss-eval process importing torch: ~15 s on two busy cores
def test_eval_of_a_checkpoint_without_a_working_folder_runs(
    world: dict[str, Path], tmp_path: Path
) -> None:
    """torch's oneMKL cannot be loaded without a working folder (``Intel oneMKL FATAL ERROR``
    ended the process): the launcher loads it from ``/``; the absolute paths work."""
    gone = tmp_path / "gone"
    gone.mkdir()
    script = Path(sys.executable).parent / "uss-eval"
    argv = [str(world["ckpt"]), "--sequence", str(world["seq"]), "--out", str(tmp_path / "e")]
    done = subprocess.run([str(script), *argv], cwd=gone, capture_output=True, text=True,
                          timeout=300, preexec_fn=_in_a_deleted_folder(gone))  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "FATAL" not in done.stderr
    assert (tmp_path / "e" / "eval.json").is_file()


def test_demo_training_without_a_working_folder_is_one_line_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
) -> None:
    """The demo's training stage cannot start without a working folder (Hydra's composition,
    torch): refused before the data stage, naming ``--until``; ``--until data`` is not."""
    gone = tmp_path / "gone"
    gone.mkdir()
    monkeypatch.chdir(gone)
    gone.rmdir()
    argv = ["--out", str(tmp_path / "demo"), "--experiment", "ci", "--quiet"]
    code, _, err = run_console_script("uss-demo", [*argv, "--until", "train"], monkeypatch, capsys)
    assert code == 1 and err.strip().splitlines() == [
        "uss-demo: error: --until train: the working folder no longer exists (it was deleted), "
        "and the training stage needs one (torch and Hydra cannot start without it); run from "
        "an existing folder, or --until data"
    ]
    assert sorted(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------ kill -9


def _pair(folder: Path) -> dict[str, str]:
    """The export's files under their final names -> SHA-256."""
    names = ("fake.onnx", "fake.int8.onnx", "fake.verify.json")
    return {n: file_sha256(folder / n) for n in names if (folder / n).is_file()}


def _checkpoint_of_pair(folder: Path) -> set[str]:
    """The checkpoint SHA-256 every file of the pair names (one value for a consistent pair)."""
    import onnx

    from uss_slam.core.onnx_contract import SegmenterMetadata

    found = {json.loads((folder / "fake.verify.json").read_text())["checkpoint_sha256"]}
    for name in ("fake.onnx", "fake.int8.onnx"):
        props = {p.key: p.value for p in onnx.load(str(folder / name)).metadata_props}
        found.add(SegmenterMetadata.from_props(props, folder / name).checkpoint_sha256)
    return found


@pytest.mark.slow  # three uss-export processes with INT8, each importing torch: ~40 s
def test_export_killed_while_writing_keeps_the_earlier_pair(
    world: dict[str, Path], tmp_path: Path
) -> None:
    """kill -9 of ``uss-export`` while it writes the new FP32 / INT8 pair (its files staged
    under temporary names in the output folder): the earlier pair stays, consistent, under
    the final names; a rerun replaces it with a consistent pair of the new checkpoint."""
    other = fake_run(tmp_path / "run_b", tiny_net(seed=4))
    script = Path(sys.executable).parent / "uss-export"
    exports = tmp_path / "exports"
    common = ["out_dir=exports", "int8=true", f"calibration.root={world['seq']}",
              "calibration.frames=2", "num_threads=1"]  # fmt: skip

    def export(ckpt: Path, tag: str) -> subprocess.Popen:
        return subprocess.Popen(
            [str(script), f"ckpt_path={ckpt}", *common, f"hydra.run.dir=hydra_{tag}"],
            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip

    first = export(world["ckpt"], "a")
    _, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    pair = _pair(exports)
    assert len(pair) == 3 and _checkpoint_of_pair(exports) == {file_sha256(world["ckpt"])}

    killed = export(other, "b")
    deadline = time.monotonic() + 300
    while not any(p.name.endswith(".tmp") for p in exports.iterdir()):
        assert killed.poll() is None, "uss-export ended before it staged a file"
        assert time.monotonic() < deadline
        time.sleep(0.01)
    os.kill(killed.pid, signal.SIGKILL)
    killed.wait(timeout=60)
    assert killed.returncode == -signal.SIGKILL
    assert _pair(exports) == pair  # the earlier pair, byte for byte
    leftovers = {p.name for p in exports.iterdir()} - set(pair)
    assert ".fake.onnx.lock" in leftovers  # its lock file, which the kernel unlocked
    temporaries = leftovers - {".fake.onnx.lock"}
    assert temporaries and all(n.startswith(".fake.") and n.endswith(".tmp") for n in temporaries)

    rerun = export(other, "c")
    _, err = rerun.communicate(timeout=600)
    assert rerun.returncode == 0, err
    assert _checkpoint_of_pair(exports) == {file_sha256(other)}
    assert "uss-export: warning: exports/fake.onnx: taking over the lock" in err
    assert not (exports / ".fake.onnx.lock").exists()


# ------------------------------------------------------------- generated from the schemas
# For every key of every Hydra script's schema (the dataclass schemas and the schemas of the
# ``_target_`` nodes of the shipped config), the values :mod:`uss_slam.core.schema.cases`
# makes up from its declarations: wrong type, each bound crossed, unknown choice, null, empty,
# a name twice, an unknown key. Each is set on the composed config as a command-line
# override would set it (OmegaConf's own refusal of a typed node becomes the line the console
# script prints) and checked by the script's own check, in this process: one line starting
# with the full key, no library text. A new key enters without an edit here. A sample of each
# script's cases runs end to end above the matrix (``test_generated_sample_end_to_end``).

LIBRARY_TEXT = ("Traceback", "omegaconf", "Invalid ", "Cannot merge", "object_type",
                "full_key", "DictConfig", "ListConfig", "must be")  # fmt: skip
"""Phrases of OmegaConf's, torch's and the old hand-written checks' messages."""


def _compose(config: str, overrides: list[str]) -> Any:
    from hydra import compose, initialize_config_module

    GlobalHydra.instance().clear()
    try:
        with initialize_config_module("uss_slam.configs", version_base="1.3"):
            return compose(config, overrides=overrides)
    finally:
        GlobalHydra.instance().clear()


def _slam_checker() -> tuple[Any, Callable[[Any], Any], list[Any]]:
    from omegaconf import OmegaConf

    from uss_slam.core.schema import target_schema
    from uss_slam.core.schema.cases import bad_values
    from uss_slam.slam_eval.config import SlamEvalConfig, check, register_configs
    from uss_slam.slam_eval.systems.orbslam3.config import OrbSlam3Config, check_system

    register_configs()
    cfg = _compose("slam_eval", ["sequence.path=/nonexistent/seq", "out_dir=/nonexistent/out",
                                 "segmenter=onnx", "segmenter.path=/nonexistent/m.onnx",
                                 "system=orbslam3"])  # fmt: skip
    bad = list(bad_values(SlamEvalConfig))
    for name in cfg.slam.filter_params:
        schema = target_schema(str(cfg.slam.filter_params[name]._target_))
        bad += list(bad_values(schema, f"slam.filter_params.{name}")) if schema else []
    bad += [
        b
        for b in bad_values(target_schema(str(cfg.segmenter._target_)), "segmenter")
        if b.key != "segmenter.path"
    ]  # fmt: skip  (a path: the path layer's cases)
    bad += list(bad_values(OrbSlam3Config, "system"))  # last: the samples run the harness

    def check_with_system(c: Any) -> Any:
        check(c)
        return check_system(OmegaConf.to_container(c.system, resolve=True))

    return cfg, check_with_system, bad


def _train_checker() -> tuple[Any, Callable[[Any], Any], list[Any]]:
    import torch

    from uss_slam.core.schema import target_schema
    from uss_slam.core.schema.cases import bad_values
    from uss_slam.train.train import TYPED_SECTIONS, RunSettings, check_config

    cfg = _compose("train", ["experiment=ci", "paths.output_dir=/nonexistent/out"])
    bad = list(bad_values(RunSettings))
    for key, node in _target_nodes(cfg, TYPED_SECTIONS):
        schema = target_schema(str(node._target_), opaque=(torch.Tensor,))
        if schema is not None:
            bad += [b for b in bad_values(schema, key)
                    if not b.key.endswith(".no_such_key") or not _loose(node)]  # fmt: skip
    return cfg, check_config, bad


def _loose(node: Any) -> bool:
    from uss_slam.core.schema import takes_any_keyword

    return takes_any_keyword(str(node._target_))


def _target_nodes(cfg: Any, sections: tuple[str, ...]) -> list[tuple[str, Any]]:
    """``(full key, node)`` of every ``_target_`` node under ``sections`` of ``cfg``."""
    from omegaconf import DictConfig

    found: list[tuple[str, Any]] = []

    def walk(node: Any, key: str) -> None:
        if not isinstance(node, DictConfig):
            return
        if "_target_" in node:
            found.append((key, node))
        for name in node:
            if not str(name).startswith("_"):
                walk(node._get_node(name), f"{key}.{name}")

    for section in sections:
        if section in cfg:
            walk(cfg[section], section)
    return found


def _experiments_checker() -> tuple[Any, Callable[[Any], Any], list[Any]]:
    from uss_slam.core.schema import check
    from uss_slam.core.schema.cases import bad_values
    from uss_slam.pipelines.experiments.schema import ExperimentsSchema

    cfg = _compose("experiments", ["out_dir=/nonexistent/exp"])
    bad = [b for b in bad_values(ExperimentsSchema) if not b.key.startswith("launcher")]
    return (
        cfg,
        lambda c: check({k: v for k, v in c.items() if k != "hydra"}, ExperimentsSchema),
        bad,
    )


def _export_checker() -> tuple[Any, Callable[[Any], Any], list[Any]]:
    from omegaconf import OmegaConf

    from uss_slam.core.schema import check
    from uss_slam.core.schema.cases import bad_values
    from uss_slam.export.cli import ExportSchema

    cfg = _compose("export", ["ckpt_path=/nonexistent/x.ckpt"])
    plain = lambda c: OmegaConf.create({k: v for k, v in c.items() if k != "hydra"})  # noqa: E731
    return cfg, lambda c: check(plain(c), ExportSchema), list(bad_values(ExportSchema))


CHECKERS = {"uss-slam": _slam_checker, "uss-train": _train_checker,
            "uss-experiments": _experiments_checker, "uss-export": _export_checker}  # fmt: skip
"""Each Hydra script: its composed config, its own check, and the generated bad values."""


def refusal(cfg: Any, checker: Callable[[Any], Any], key: str, value: Any) -> str | None:
    """The one line ``key=value`` ends in (None when it is accepted): OmegaConf's refusal on a
    typed node as the console scripts print it, else the script's check's error."""
    import copy

    from omegaconf import OmegaConf, open_dict
    from omegaconf.errors import OmegaConfBaseException

    from uss_slam.core.errors import UssSlamError
    from uss_slam.core.schema import omegaconf_error_line

    cfg = copy.deepcopy(cfg)
    try:
        with open_dict(cfg):
            OmegaConf.update(cfg, key, value, force_add=True)
    except OmegaConfBaseException as error:
        return omegaconf_error_line(error)
    try:
        checker(cfg)
    except UssSlamError as error:
        return str(error)
    return None


@pytest.fixture(scope="module")
def checkers() -> dict[str, tuple[Any, Callable[[Any], Any], list[Any]]]:
    return {prog: make() for prog, make in CHECKERS.items()}


def test_the_generated_matrix_refuses_every_bad_value_naming_its_key(checkers) -> None:
    """Every generated bad value of every key of the four Hydra scripts' schemas: refused, one
    line, starting with its full key, no library text (docs/errors.md)."""
    problems: list[str] = []
    counts: dict[str, int] = {}
    for prog, (cfg, checker, bad) in checkers.items():
        counts[prog] = len(bad)
        for b in bad:
            line = refusal(cfg, checker, b.key, b.value)
            if line is None:
                problems.append(f"{prog} {b.id} ({b.kind}): accepted")
            elif "\n" in line or not line.startswith(b.key) or any(t in line for t in LIBRARY_TEXT):
                problems.append(f"{prog} {b.id} ({b.kind}): {line}")
    assert problems == [], "\n".join(problems)
    assert all(n >= 20 for n in counts.values()), counts


SAMPLE_BASE = {"uss-slam": (SLAM, (earlier_slam_run,)), "uss-train": (TRAIN, ()),
               "uss-export": (EXPORT, (earlier_export,)), "uss-experiments": (EXPERIMENTS, ())}  # fmt: skip
"""Each Hydra script's command line for a sample case, and what the case's folder holds."""


PATH_KEYS = ("dir", "path", "root", "roots")
"""Keys of paths: the path families' cases, not these."""


def _override(key: str, value: Any, kind: str) -> str:
    """``key=value`` as typed on a command line (``+key=`` for a key the config lacks)."""

    def text(v: Any) -> str:
        if v is None:
            return "null"
        if isinstance(v, list):
            return "[" + ",".join(text(x) for x in v) + "]"
        return str(v).lower() if isinstance(v, bool) else str(v)

    return f"{'+' if kind == 'unknown' else ''}{key}={text(value)}"


@pytest.mark.parametrize("prog", list(CHECKERS))
def test_generated_sample_end_to_end(
    prog: str, checkers, world: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    """The first generated value of each kind for ``prog``'s own schema, run as the console
    script in this process: exit 1, one line naming the key, nothing written (an earlier run or
    export in the output folder intact)."""
    base, setup = SAMPLE_BASE[prog]
    _, _, bad = checkers[prog]
    firsts = {b.kind: b for b in reversed(bad)
              if ("." not in b.key or b.kind != "unknown") and not b.key.endswith(PATH_KEYS)}  # fmt: skip
    for n, b in enumerate(sorted(firsts.values(), key=lambda b: b.kind)):
        folder = tmp_path / f"case{n}"
        folder.mkdir()
        argv = over(base, _override(b.key, b.value, b.kind))
        try:
            check_case(Case(b.id, prog, tuple(argv.split()), 1, (b.key,), setup=setup),
                       world, folder, monkeypatch, capsys)  # fmt: skip
        finally:
            HydraConfig.instance().cfg = None
            GlobalHydra.instance().clear()


def test_the_cases_have_distinct_ids_and_cover_every_console_script() -> None:
    assert len({c.id for c in CASES}) == len(CASES)
    for prog in ENTRY_POINTS:
        assert sum(c.prog == prog for c in CASES) >= 8, prog


def _present_keys(cfg: Any) -> dict[str, tuple[str, Any]]:
    """The first key of ``cfg`` (depth first) of each kind of value: null, ``???``, a list, a
    bool or a number -> ``(key, value)``. Hydra's own ``+key`` check missed the first three."""
    from omegaconf import OmegaConf

    found: dict[str, tuple[str, Any]] = {}

    def walk(node: Any, prefix: str) -> None:
        for name, value in node.items():
            key = f"{prefix}{name}"
            if isinstance(value, dict):
                walk(value, f"{key}.")
                continue
            kind = ("null" if value is None else "missing" if value == "???" else
                    "list" if isinstance(value, list) and all(
                        isinstance(v, (bool, int, float)) or (isinstance(v, str) and v.isalnum())
                        for v in value) else
                    "scalar" if isinstance(value, (bool, int, float)) else None)  # fmt: skip
            if kind is not None and not str(name).startswith("_"):
                found.setdefault(kind, (key, value))

    walk({k: v for k, v in OmegaConf.to_container(cfg, resolve=False).items() if k != "hydra"}, "")
    return found


@pytest.mark.parametrize("prog", list(CHECKERS))
def test_adding_a_key_the_config_has_is_refused(
    prog: str, checkers, world: dict[str, Path], tmp_path: Path, monkeypatch, capsys
) -> None:
    """``+key=value`` for a key of ``prog``'s composed config, one of each kind of value (null,
    ``???`` where it has one, a list, a plain value): exit 1, one line naming the key and the ``key=`` and
    ``++key=`` to write instead, nothing written: alike in every Hydra script."""
    base, setup = SAMPLE_BASE[prog]
    cfg, _, _ = checkers[prog]
    present = _present_keys(cfg)
    assert {"null", "list", "scalar"} <= set(present), present
    for kind, (key, value) in sorted(present.items()):
        folder = tmp_path / kind
        folder.mkdir()
        added = _override(key, value, "unknown")
        says = (f"An item is already at '{key}'", f"remove + prefix: '{added[1:]}'", f"'+{added}'")
        try:
            check_case(Case(f"{prog}-added-{kind}", prog, tuple(over(base, added).split()), 1,
                            says, setup=setup), world, folder, monkeypatch, capsys)  # fmt: skip
        finally:
            HydraConfig.instance().cfg = None
            GlobalHydra.instance().clear()
