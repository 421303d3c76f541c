"""``uss-eval``: a segmenter's accuracy on labelled frames — per-class IoU, mIoU and the
dynamic-mask frame metrics (FPR, FNR, recall, precision, PWC) of
:mod:`uss_slam.core.seg_metrics`.

The model is a ``uss-train`` checkpoint (``.ckpt``: the architecture from its run's
``.hydra/config.yaml``, run in PyTorch through the export wrapper, i.e. the graph ``uss-export``
would write) or an exported ONNX model (``.onnx``: :class:`OnnxSegmenter`). The frames are
TUM RGB-D folders with ``labels/`` (``--sequence``, e.g. ``uss-synth`` sequences) or the
validation set of a data config composed from the shipped configs with Hydra overrides::

    uss-eval exports/adapted.onnx --sequence outputs/demo/data/slam/walking_xyz --stride 10
    uss-eval outputs/demo/train/adapted/checkpoints/last.ckpt paths.data_dir=outputs/demo/data
    uss-eval model.onnx data=real data/val=coco data.val.annotations=a.json data.val.images=imgs

Writes ``OUT/eval.json`` and ``OUT/eval.md`` (printed) and, with ``--overlays N``, N PNGs of
evenly spaced frames (truth | prediction over the image) in ``OUT/overlays/``.

A command line rather than a Hydra app: one positional model, a few options, and data-config
overrides handed to Hydra's compose API (so ``data=...`` works as in ``uss-train``).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uss_slam.core.classes import CLASS_NAMES, DYNAMIC_CLASSES, colorize
from uss_slam.core.cli import exit_on_user_error, hydra_error_line
from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import (
    atomic_path,
    check_writable,
    file_sha256,
    output_lock,
    write_json_atomic,
    write_text_atomic,
)
from uss_slam.core.onnx_contract import check_label_ids, check_logit_channels
from uss_slam.core.seg_metrics import (
    RATE_NAMES,
    BinaryCounts,
    confusion_matrix,
    iou_report,
    mask_counts,
    mask_metrics,
)

PROG = "uss-eval"
CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
MODEL_KINDS = {".ckpt": "checkpoint", ".onnx": "onnx"}


@dataclass(frozen=True)
class LabelledFrame:
    """``rgb`` (H, W, 3) uint8 RGB; ``labels`` (H, W) uint8 project class ids (255 ignore)."""

    name: str
    rgb: np.ndarray
    labels: np.ndarray


@dataclass
class FrameScores:
    """What :func:`evaluate_frames` measured: the confusion matrix over all frames (rows truth,
    columns prediction, project classes), each frame's dynamic-mask pixel counts, inference time
    (seconds, summed) and the frames chosen for overlays with their predictions."""

    matrix: np.ndarray
    mask_counts: list[BinaryCounts] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    seconds: float = 0.0
    kept: list[tuple[LabelledFrame, np.ndarray]] = field(default_factory=list)


def evaluate_frames(
    infer: Callable[[np.ndarray], np.ndarray],
    frames: Iterable[LabelledFrame],
    class_names: Sequence[str] = CLASS_NAMES,
    dynamic_ids: Sequence[int] = (),
    keep: Callable[[int], bool] = lambda index: False,
) -> FrameScores:
    """Run ``infer(rgb) -> (H, W) class ids`` on every frame and count; ``keep(k)`` selects
    frames whose prediction is kept (for overlays)."""
    n = len(class_names)
    scores = FrameScores(matrix=np.zeros((n, n), np.int64))
    for k, frame in enumerate(frames):
        t0 = time.perf_counter()
        pred = infer(frame.rgb)
        scores.seconds += time.perf_counter() - t0
        try:
            scores.matrix += confusion_matrix(frame.labels, pred, n)
        except UssSlamError as error:
            raise UssSlamError(f"frame {frame.name}: {error}") from error
        if dynamic_ids:
            scores.mask_counts.append(mask_counts(frame.labels, pred, dynamic_ids))
        scores.names.append(frame.name)
        if keep(k):
            scores.kept.append((frame, pred))
    return scores


# ------------------------------------------------------------------------------ models


def _project_lut(model_classes: Sequence[str], source: str) -> np.ndarray | None:
    """Model class index -> project class id (by name); None when they coincide."""
    unknown = [c for c in model_classes if c not in CLASS_NAMES]
    if unknown:
        raise UssSlamError(
            f"{source}: class names {unknown} are not project classes ({', '.join(CLASS_NAMES)})"
        )
    ids = [CLASS_NAMES.index(c) for c in model_classes]
    if ids == list(range(len(ids))):
        return None
    lut = np.zeros(256, np.uint8)
    lut[: len(ids)] = ids
    return lut


class CheckpointSegmenter:
    """A ``uss-train`` checkpoint's segmenter (``main`` head) as ``infer(rgb) -> class ids``,
    through the same wrapper (normalisation, upsampling, argmax) the ONNX export traces."""

    def __init__(self, path: Path, threads: int | None = None) -> None:
        import torch

        from uss_slam.export import SegmenterExport, load_checkpoint

        loaded = load_checkpoint(path)
        if threads is not None:
            torch.set_num_threads(threads)
        self.model = SegmenterExport(loaded.segmenter, head="main").eval()
        self.path = path
        self.class_names = tuple(loaded.class_names)
        self.lut = _project_lut(loaded.class_names, str(path))
        self.info = {
            "path": str(path),
            "kind": "checkpoint",
            "sha256": loaded.sha256,
            "experiment": loaded.experiment,
            "iteration": loaded.iteration,
            "class_names": list(loaded.class_names),
        }

    def infer(self, rgb: np.ndarray) -> np.ndarray:
        """``(H, W, 3)`` uint8 RGB -> ``(H, W)`` uint8 project class ids; the outputs held to
        the checkpoint's class list as an exported model's are (one logit channel per class,
        every label a class id)."""
        import torch

        with torch.inference_mode():
            logits, labels = self.model(torch.from_numpy(np.ascontiguousarray(rgb))[None])
        check_logit_channels(self.path, self.class_names, int(logits.shape[1]))
        out = labels[0].numpy()
        check_label_ids(self.path, self.class_names, out)
        return out if self.lut is None else self.lut[out]


def model_kind(path: Path) -> str:
    """``checkpoint`` or ``onnx`` by the file's extension; an error for anything else or a
    missing file."""
    kind = MODEL_KINDS.get(path.suffix.lower())
    if kind is None:
        raise UssSlamError(
            f"{path}: expected a uss-train checkpoint (.ckpt) or an exported model (.onnx)"
        )
    if not path.is_file():
        raise UssSlamError(f"{path}: no such file")
    return kind


def load_segmenter(
    path: Path, threads: int | None = None, crf_params: Mapping[str, Any] | None = None
) -> tuple[Callable, dict[str, Any]]:
    """``(infer, info)`` of a ``.ckpt`` or ``.onnx`` model file; with ``crf_params`` (an ONNX
    model only; empty = the CRF's defaults), followed by the dense CRF of ``uss-slam
    segmenter.crf=true``."""
    if model_kind(path) == "checkpoint":
        if crf_params is not None:
            raise UssSlamError(f"{path}: the dense CRF runs on an exported .onnx model")
        model = CheckpointSegmenter(path, threads)
        return model.infer, model.info
    from uss_slam.slam_eval.segmenters.onnx import OnnxSegmenter

    crf = crf_params is not None
    onnx = OnnxSegmenter(path, threads=threads, crf=crf, crf_params=crf_params if crf else None)
    meta = onnx.metadata
    info = {
        "path": str(path),
        "kind": "onnx",
        "sha256": file_sha256(path),
        "experiment": meta.experiment,
        "checkpoint_sha256": meta.checkpoint_sha256,
        "class_names": list(meta.class_names),
    }
    if crf:
        info["crf"] = dict(crf_params)
    return onnx.infer, info


# ------------------------------------------------------------------------------ frames


@dataclass
class FrameSource:
    """Labelled frames to evaluate: their count, a description and an iterator."""

    description: dict[str, Any]
    count: int
    frames: Callable[[], Iterator[LabelledFrame]]


def sequence_frames(roots: Sequence[Path], stride: int) -> FrameSource:
    """Every ``stride``-th colour frame of labelled frame folders: TUM RGB-D sequences with
    ``labels/``, or image folders with only ``rgb.txt``, ``rgb/`` and ``labels/`` (depth and
    ground truth are not needed). Lists and files are checked before any inference; a folder
    given twice is an error (its frames would count twice)."""
    from uss_slam.core.tum_io import read_tum_folder

    if stride < 1:
        raise UssSlamError(f"--stride: expected an integer >= 1, got {stride}")
    seen: dict[Path, Path] = {}
    folders = []
    for root in roots:
        if not root.is_dir():
            raise UssSlamError(f"--sequence {root}: not a folder")
        resolved = root.resolve()
        if resolved in seen:
            raise UssSlamError(
                f"--sequence {root}: given twice (as {seen[resolved]}); its frames would count twice"
            )
        seen[resolved] = root
        folder = read_tum_folder(root, depth=False, labels=True)
        frames = folder.frames[::stride]
        for frame in frames:
            missing = folder.missing(frame)
            if missing is not None:
                raise missing
            if frame.labels is not None and not frame.labels.is_file():
                raise DataFormatError(
                    frame.labels, f"no labels for colour frame {frame.rgb.name} (expected a "
                    "uint8 class-id PNG of the same name in labels/)"
                )  # fmt: skip
        folders.append((root, frames))

    def frames() -> Iterator[LabelledFrame]:
        for root, files in folders:
            for frame in files:
                assert frame.labels is not None  # read with labels=True
                yield LabelledFrame(f"{root.name}/{frame.stamp:.6f}", *_read_pair(frame))

    description = {"source": "sequence", "roots": [str(r) for r in roots], "stride": stride}
    return FrameSource(description, sum(len(f) for _, f in folders), frames)


def _read_pair(frame: Any) -> tuple[np.ndarray, np.ndarray]:
    """The colour image (RGB) and the labels of ``frame``, checked (errors name the file)."""
    from uss_slam.slam_eval.sequence import read_labels

    bgr = cv2.imread(str(frame.rgb), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DataFormatError(frame.rgb, "not a readable image")
    labels = read_labels(frame.labels, bgr.shape[:2], frame.rgb.name)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), labels


def config_val_frames(overrides: Sequence[str]) -> FrameSource:
    """The validation set (``data.val``) of the data config composed from the shipped
    ``train`` config with ``overrides`` (e.g. ``data=real``, ``paths.data_dir=...``)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from uss_slam.train.config_check import check_config_types

    bad = [o for o in overrides if "=" not in o]
    if bad:
        raise UssSlamError(
            f"{bad[0]!r}: expected a data-config override KEY=VALUE (e.g. data=real, "
            "paths.data_dir=DIR, data.val.stride=1)"
        )
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
            cfg = compose("train", overrides=list(overrides))
    except Exception as error:  # an unknown key or option, bad override syntax: one line
        line = hydra_error_line(error)
        if line is None:
            raise
        raise UssSlamError(line) from None
    finally:
        GlobalHydra.instance().clear()
    node = OmegaConf.select(cfg, "data.val")
    if node is None:
        raise UssSlamError("the composed data config has no data.val (the validation set)")
    check_config_types(cfg, ("data",))  # data.val.stride=abc: one line naming the key
    dataset = instantiate(node)
    if not getattr(dataset, "labelled", False):
        raise UssSlamError("data.val has no labels: nothing to evaluate against")

    def frames() -> Iterator[LabelledFrame]:
        for k in range(len(dataset)):
            sample = dataset.load(k)
            rgb = sample["image"].permute(1, 2, 0).numpy()
            yield LabelledFrame(str(sample["name"]), rgb, sample["label"].numpy())

    description = {
        "source": "data.val",
        "overrides": list(overrides),
        "config": OmegaConf.to_container(node, resolve=True),
    }
    return FrameSource(description, len(dataset), frames)


# ------------------------------------------------------------------------------ report


def evenly_spaced(count: int, total: int) -> list[int]:
    """``count`` indices spread evenly over ``range(total)`` (all of them if fewer)."""
    if count <= 0 or total <= 0:
        return []
    if count >= total:
        return list(range(total))
    return sorted({int(round(v)) for v in np.linspace(0, total - 1, count)})


def overlay(frame: LabelledFrame, pred: np.ndarray, alpha: float = 0.5) -> np.ndarray:
    """``(H, 2W, 3)`` uint8 RGB: the truth (left) and the prediction (right) in class colours
    over the image (background and ignored pixels show the image)."""
    panels = []
    for labels in (frame.labels, pred):
        colours = colorize(labels).astype(np.float32)
        shown = (labels > 0) & (labels != 255)
        mixed = frame.rgb.astype(np.float32)
        mixed[shown] = (1 - alpha) * mixed[shown] + alpha * colours[shown]
        panels.append(np.clip(np.rint(mixed), 0, 255).astype(np.uint8))
    return np.concatenate(panels, axis=1)


def _pct(value: float | None) -> str:
    return "—" if value is None else f"{100 * value:.2f}%"


def markdown(result: dict[str, Any]) -> str:
    """``eval.md``: the model and data, the per-class IoU table and the dynamic-mask table."""
    model, data = result["model"], result["data"]
    where = ", ".join(data.get("roots", [])) or " ".join(data.get("overrides", [])) or "defaults"
    lines = [
        f"# uss-eval: {Path(model['path']).name}",
        "",
        f"Model: `{model['path']}` ({model['kind']}, experiment `{model['experiment']}`). "
        f"Frames: {result['frames']} from {data['source']} ({where}); "
        f"{result['ms_per_frame']:.1f} ms per frame.",
        "",
        "| class | IoU | truth pixels | predicted pixels |",
        "|---|---|---|---|",
    ]
    matrix = np.asarray(result["confusion_matrix"])
    for k, name in enumerate(result["classes"]):
        iou = result["IoU"][name]
        lines.append(
            f"| {name} | {'—' if iou is None else f'{iou:.4f}'} | {int(matrix[k].sum())} | "
            f"{int(matrix[:, k].sum())} |"
        )
    miou = result["mIoU"]
    lines += ["", f"**mIoU {'—' if miou is None else f'{miou:.4f}'}** (mean over the classes "
              "present in truth or prediction).", ""]  # fmt: skip
    mask = result["mask"]
    if mask is not None:
        frames, pooled, mean = mask["frames"], mask["pixels_pooled"], mask["pixels_mean"]
        counts = frames["counts"]
        lines += [
            f"Dynamic mask ({', '.join(result['dynamic_classes'])}) against the truth's: "
            f"frames as the paper's Table III (TP {counts['TP']}, FP {counts['FP']}, TN "
            f"{counts['TN']}, FN {counts['FN']}; correctly segmented = mask IoU >= "
            f"{frames['iou_threshold']:g}), pixels pooled over all frames, and the mean of "
            "per-frame pixel rates.",
            "",
            "| metric | frames | pixels (pooled) | pixels (mean over frames) |",
            "|---|---|---|---|",
        ]
        for name in RATE_NAMES:
            lines.append(
                f"| {name} | {_pct(frames[name])} | {_pct(pooled[name])} | {_pct(mean[name])} |"
            )
        lines.append("")
    if result["overlays"]:
        lines += ["Overlays (truth | prediction): "
                  + ", ".join(f"[{Path(p).name}]({p})" for p in result["overlays"]), ""]  # fmt: skip
    return "\n".join(lines)


def evaluate(
    model: Path,
    out: Path,
    *,
    sequences: Sequence[Path] = (),
    overrides: Sequence[str] = (),
    stride: int = 1,
    dynamic: Sequence[str] = DYNAMIC_CLASSES,
    frame_iou: float = 0.5,
    overlays: int = 0,
    threads: int | None = None,
) -> dict[str, Any]:
    """Evaluate ``model`` and write ``out/eval.json``, ``out/eval.md`` (and overlays); returns
    the content of ``eval.json``. Every argument is checked before the model runs."""
    model_kind(model)
    if stride < 1:
        raise UssSlamError(f"--stride must be >= 1, got {stride}")
    if overlays < 0:
        raise UssSlamError(f"--overlays must be >= 0, got {overlays}")
    if not 0.0 < frame_iou <= 1.0:
        raise UssSlamError(f"--frame-iou must be in (0, 1], got {frame_iou}")
    if threads is not None and threads < 1:
        raise UssSlamError(f"--threads must be >= 1, got {threads}")
    unknown = [c for c in dynamic if c not in CLASS_NAMES]
    if unknown or not dynamic:
        raise UssSlamError(
            f"--dynamic {','.join(dynamic)}: expected class names of {', '.join(CLASS_NAMES)}"
        )
    if sequences and overrides:
        raise UssSlamError(
            "give either --sequence folders or data-config overrides (the val set), not both"
        )
    if out.exists() and not out.is_dir():
        raise UssSlamError(f"--out {out}: exists and is not a folder")
    check_writable(out, "--out", create=False)
    source = sequence_frames(sequences, stride) if sequences else config_val_frames(overrides)
    if source.count == 0:
        raise UssSlamError("no labelled frames to evaluate")
    with output_lock(out, "--out"):
        return _evaluate(model, out, source, dynamic, frame_iou, overlays, threads)


def _evaluate(
    model: Path,
    out: Path,
    source: FrameSource,
    dynamic: Sequence[str],
    frame_iou: float,
    overlays: int,
    threads: int | None,
) -> dict[str, Any]:
    """:func:`evaluate` once its arguments are checked and ``out`` is locked."""
    infer, info = load_segmenter(model, threads)
    dynamic_ids = [CLASS_NAMES.index(c) for c in dynamic]
    chosen = set(evenly_spaced(overlays, source.count))
    scores = evaluate_frames(infer, source.frames(), CLASS_NAMES, dynamic_ids, chosen.__contains__)
    written = []
    for frame, pred in scores.kept:
        name = f"overlays/{len(written):03d}_{frame.name.replace('/', '_')}.png"
        ok, png = cv2.imencode(".png", cv2.cvtColor(overlay(frame, pred), cv2.COLOR_RGB2BGR))
        if not ok:
            raise UssSlamError(f"{out / name}: could not encode the overlay")
        with atomic_path(out / name) as tmp:
            tmp.write_bytes(png.tobytes())
        written.append(name)
    result = {
        "model": info,
        "data": source.description,
        "frames": len(scores.names),
        "classes": list(CLASS_NAMES),
        **iou_report(scores.matrix, CLASS_NAMES),
        "confusion_matrix": scores.matrix.tolist(),
        "dynamic_classes": list(dynamic),
        "mask": mask_metrics(scores.mask_counts, iou_threshold=frame_iou),
        "ms_per_frame": 1000 * scores.seconds / max(len(scores.names), 1),
        "overlays": written,
    }
    write_json_atomic(out / "eval.json", result)
    write_text_atomic(out / "eval.md", markdown(result))
    _remove_stale_overlays(out / "overlays", written)
    return result


def _remove_stale_overlays(folder: Path, written: Sequence[str]) -> None:
    """Overlays of an earlier evaluation into the same ``--out`` that this one did not write
    (fewer ``--overlays``, other frames): removed, so that the folder holds one run's."""
    if not folder.is_dir():
        return
    mine = {Path(name).name for name in written}
    for path in folder.glob("[0-9][0-9][0-9]_*.png"):
        if path.name not in mine:
            path.unlink()
    if not any(folder.iterdir()):
        folder.rmdir()


# ------------------------------------------------------------------------------ main


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Evaluate a segmenter (a uss-train checkpoint or an exported ONNX model) on "
        "labelled frames: per-class IoU, mIoU and the dynamic-mask frame metrics (FPR, FNR, "
        "recall, precision, PWC). Frames: --sequence TUM folders with labels/, or the val set "
        "of the data config (Hydra overrides as in uss-train, e.g. data=real "
        "paths.data_dir=DIR). Writes OUT/eval.json and OUT/eval.md (printed).",
    )
    parser.add_argument("model", type=Path, help="a .ckpt (uss-train) or .onnx (uss-export)")
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                        help="data-config overrides selecting the val set (default: the "
                             "shipped data=synthetic under paths.data_dir=outputs/demo/data)")  # fmt: skip
    parser.add_argument("--sequence", type=Path, action="append", default=[], metavar="DIR",
                        help="a TUM RGB-D folder with labels/ (repeatable) instead of data.val")  # fmt: skip
    parser.add_argument("--stride", type=int, default=1,
                        help="every N-th frame of each --sequence (default: 1)")  # fmt: skip
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: outputs/eval/<model file stem>)")  # fmt: skip
    parser.add_argument("--dynamic", default=",".join(DYNAMIC_CLASSES),
                        help="comma-separated classes of the dynamic mask (default: "
                             f"{','.join(DYNAMIC_CLASSES)})")  # fmt: skip
    parser.add_argument("--frame-iou", type=float, default=0.5,
                        help="mask IoU from which a frame counts as correctly segmented "
                             "(default: 0.5)")  # fmt: skip
    parser.add_argument("--overlays", type=int, default=0, metavar="N",
                        help="write N PNG overlays of evenly spaced frames (default: 0)")  # fmt: skip
    parser.add_argument("--threads", type=int, default=None,
                        help="inference threads (default: the runtime's)")  # fmt: skip
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from hydra.errors import ConfigCompositionException, OverrideParseException
    from omegaconf.errors import OmegaConfBaseException

    # Intermixed: data-config overrides may follow the options (MODEL --out DIR data=real).
    args = build_parser().parse_intermixed_args(argv)
    out = args.out if args.out is not None else Path("outputs") / "eval" / args.model.stem
    config_errors = (ConfigCompositionException, OverrideParseException, OmegaConfBaseException)
    with exit_on_user_error(PROG, config_errors):
        result = evaluate(
            args.model, out, sequences=args.sequence, overrides=args.overrides,
            stride=args.stride, dynamic=[c.strip() for c in args.dynamic.split(",") if c.strip()],
            frame_iou=args.frame_iou, overlays=args.overlays, threads=args.threads,
        )  # fmt: skip
        print(markdown(result))
        print(f"{PROG}: wrote {out / 'eval.json'} and {out / 'eval.md'}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
