"""More bad inputs of the same families as ``tests/test_cli_matrix.py``, none of them in that
matrix or in another test: wrong types and ranges of keys, missing or garbled files of every
input kind (checkpoint, ONNX model, TUM text files, images, label PNGs, YAML records),
unwritable outputs and foreign folders, across the nine console scripts.

Each case is held to the same contract as that matrix (its ``test_bad_input``): the exit code
(1 for a bad file, value, key or folder; 2 for an argparse usage error), exactly one stderr line
``<prog>: error: ...`` naming the key or file and what was expected (a usage error: argparse's
usage, then that line), never a traceback, and nothing written (every file under the case's
folder byte for byte as before, an earlier run or export included; Hydra's own record of a
call is the only exception). All run in this process, as that matrix runs them.

A case that a console script handles badly today is marked ``xfail(strict=True)`` naming the
problem: it fails when the fault is mended, and the mark must go then.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from test_cli_matrix import (  # noqa: F401  (world: the fixture of the shared inputs)
    EXPERIMENTS,
    EXPORT,
    SLAM,
    SLAM_S,
    TRAIN,
    Case,
    afile,
    case,
    check_case,
    corrupt,
    earlier_export,
    earlier_slam_run,
    folder,
    nth,
    plain_onnx,
    png_bytes,
    run_console_script,
    seq_copy,
    snapshot,
    truncated,
    world,
    write,
)

from uss_slam.core.schema import MAX_THREADS

# ------------------------------------------------------------------------------ setups


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

CASES = [
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
         "expected an integer >= 1, got '0'"),
    case("vocab-build-out-exists", "uss-vocab", "build {seq} --out {v} -k 3 -L 2", 1,
         "{v}: exists; pass --overwrite", setup=(write("v", "the user's file\n"),)),
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
         "{m} --sequence {seq} --sequence {seq} --out {tmp}/eval", 1, "given twice",
         "its frames would count twice",
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
         "expected an integer >= 1, got 0",
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
    case("slam-out-dir-is-an-export", "uss-slam",
         "sequence.path={seq} out_dir={exports} progress=false", 1,
         "out_dir={exports}: holds the outputs of uss-export (fake.verify.json)",
         setup=(earlier_export,)),
    # ---------------------------------------------------------------- uss-train (Hydra)
    case("train-source-root-missing", "uss-train", f"{TRAIN} data.source.root={{tmp}}/nope", 1,
         "data.source.root={tmp}/nope",
         ": does not exist; expected a folder"),
    case("train-target-root-is-a-file", "uss-train", f"{TRAIN} data.target.roots=[{{afile}}]",
         1, "data.target.roots={afile}",
         ": is a file; expected a folder", setup=(afile,)),
    case("train-val-root-is-a-voc-tree", "uss-train", f"{TRAIN} data.val.roots=[{{voc}}]", 1,
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
    case("train-val-label-png-garbled", "uss-train", f"{TRAIN} data.val.roots=[{{s}}]", 1,
         "{s}/labels/",
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
         f"{EXPORT} int8=true calibration.root={{s}}", 1, "{s}/rgb.txt",
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
         "expected a non-empty list of integers >= 0, each once, got []"),
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
]  # fmt: skip


# ------------------------------------------------------------------------------ running


@pytest.mark.parametrize("bad", [pytest.param(c, id=c.id, marks=c.marks) for c in CASES])
def test_bad_input_fresh(
    bad: Case,
    world: dict[str, Path],  # noqa: F811  (the fixture imported above)
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys,
) -> None:
    check_case(bad, world, tmp_path, monkeypatch, capsys)


def test_the_fresh_cases_are_new_and_cover_every_console_script() -> None:
    """At least 60 cases, none with the id of a case of the first matrix, each console script
    with at least four."""
    from test_cli_matrix import CASES as FIRST
    from test_cli_matrix import ENTRY_POINTS

    assert len(CASES) >= 60
    assert len({c.id for c in CASES}) == len(CASES)
    assert not {c.id for c in CASES} & {c.id for c in FIRST}
    for prog in ENTRY_POINTS:
        assert sum(c.prog == prog for c in CASES) >= 4, prog
