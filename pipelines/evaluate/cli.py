"""``uss-eval``'s command line and :func:`evaluate`: check the arguments, score the model on the
frames, write ``eval.json``, ``eval.md`` and the overlays."""

from __future__ import annotations

import argparse
import enum
import importlib
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from uss_slam.core.arguments import THREADS_ARG, Names, given_once, of_field, path_argument
from uss_slam.core.classes import CLASS_NAMES, DYNAMIC_CLASSES
from uss_slam.core.cli import exit_on_user_error, warning
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import (
    check_output_owner,
    output_lock,
    write_json_atomic,
    write_text_atomic,
)
from uss_slam.core.paths import output_folder
from uss_slam.core.schema import MAX_THREADS, SchemaError, ranged, validate
from uss_slam.core.seg_metrics import iou_report, mask_metrics

from .frames import FrameSource, check_overrides, config_val_frames, sequence_frames
from .markdown import markdown
from .metrics import evaluate_frames
from .models import load_segmenter, model_kind
from .overlays import evenly_spaced, remove_stale_overlays, write_overlays

PROG = "uss-eval"
COMMANDS = {"compare": "uss_slam.pipelines.evaluate.compare_cli"}
"""Subcommands with a parser of their own (``build_parser`` and ``main`` of the module)."""

ClassName = enum.Enum("ClassName", {name: name for name in CLASS_NAMES})  # type: ignore[misc]


@dataclass
class EvalOptions:
    """The ranges of ``uss-eval``'s numbers and lists (the same rules as the Hydra scripts'
    schemas; an error names the flag: ``--frame-iou: expected a number > 0 and <= 1, got 0``)."""

    stride: int = ranged(1, min=1)
    overlays: int = ranged(0, min=0)
    frame_iou: float = ranged(0.5, gt=0, max=1)
    threads: Optional[int] = ranged(None, min=1, max=MAX_THREADS)  # noqa: UP045 (OmegaConf)
    dynamic: list[ClassName] = ranged(default_factory=list, nonempty=True)  # type: ignore[valid-type]


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
    values = {"stride": stride, "overlays": overlays, "frame_iou": frame_iou,
              "threads": threads, "dynamic": list(dynamic)}  # fmt: skip
    try:
        validate(values, EvalOptions)
    except SchemaError as error:
        raise error.as_flag() from None
    check_overrides(overrides)  # a second model or value among them: named
    if sequences and overrides:
        raise UssSlamError(
            "give either --sequence folders or data-config overrides (the val set), not both"
        )
    output_folder(out, "--out", inputs=[("--sequence", s) for s in sequences])
    check_output_owner(out, PROG, "--out")  # a uss-slam run, a uss-demo output, ...
    source = sequence_frames(sequences, stride) if sequences else config_val_frames(overrides)
    if source.count == 0:
        raise UssSlamError("no labelled frames to evaluate")
    if overlays > source.count:
        warning(
            f"--overlays {overlays}: the data has {source.count} frames; {source.count} "
            "overlays are written, one per frame"
        )
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
    warn_unlabelled(scores.unlabelled, len(scores.names), source.description)
    written = write_overlays(out, scores.kept)
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
    remove_stale_overlays(out / "overlays", written)
    return result


def warn_unlabelled(frames: Sequence[str], total: int, data: Any) -> None:
    """One warning naming the frames whose labels are all ignore (255): they add nothing to
    the IoUs, and when every frame is such a frame each IoU and the mIoU are null."""
    if not frames:
        return
    roots = data.get("roots") if isinstance(data, dict) else None
    where = "--sequence " + ", ".join(roots) if roots else "data.val"
    shown = ", ".join(frames[:3]) + (f" and {len(frames) - 3} more" if len(frames) > 3 else "")
    result = (
        "every IoU and the mIoU are null"
        if len(frames) == total
        else "they count for nothing in the IoUs"
    )
    warning(
        f"{where}: {len(frames)} of {total} frames have only ignore labels (255): {shown}; {result}"
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG,
        epilog="uss-eval compare MODEL MODEL [...] --sequence DIR: compare exported models on "
        "unlabelled target frames (uss-eval compare --help).",
        description="Evaluate a segmenter (a uss-train checkpoint or an exported ONNX model) on "
        "labelled frames: per-class IoU, mIoU and the dynamic-mask frame metrics (FPR, FNR, "
        "recall, precision, PWC). Frames: --sequence TUM folders with labels/, or the val set "
        "of the data config (Hydra overrides as in uss-train, e.g. data=real "
        "paths.data_dir=DIR). Writes OUT/eval.json and OUT/eval.md (printed).",
    )
    parser.add_argument(
        "model", type=path_argument, help="a .ckpt (uss-train) or .onnx (uss-export)"
    )
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE",
                        help="data-config overrides selecting the val set (default: the "
                             "shipped data=synthetic under paths.data_dir=outputs/demo/data)")  # fmt: skip
    parser.add_argument("--sequence", type=path_argument, action="append", default=[], metavar="DIR",
                        help="a TUM RGB-D folder with labels/ (repeatable) instead of data.val")  # fmt: skip
    parser.add_argument("--stride", type=of_field(EvalOptions, "stride"), default=1,
                        help="every N-th frame of each --sequence (default: 1)")  # fmt: skip
    parser.add_argument("--out", type=path_argument, default=None,
                        help="output folder (default: outputs/eval/<model file stem>)")  # fmt: skip
    parser.add_argument("--dynamic", type=Names(CLASS_NAMES), default=",".join(DYNAMIC_CLASSES),
                        help="comma-separated classes of the dynamic mask (default: "
                             f"{','.join(DYNAMIC_CLASSES)})")  # fmt: skip
    parser.add_argument("--frame-iou", type=of_field(EvalOptions, "frame_iou"), default=0.5,
                        help="mask IoU from which a frame counts as correctly segmented "
                             "(default: 0.5)")  # fmt: skip
    parser.add_argument("--overlays", type=of_field(EvalOptions, "overlays"), default=0, metavar="N",
                        help="write N PNG overlays of evenly spaced frames (default: 0)")  # fmt: skip
    parser.add_argument("--threads", type=THREADS_ARG, default=None,
                        help="inference threads (default: the runtime's)")  # fmt: skip
    return given_once(parser)


def main(argv: Sequence[str] | None = None) -> int:
    from hydra.errors import ConfigCompositionException, OverrideParseException
    from omegaconf.errors import OmegaConfBaseException

    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] and argv[0] in COMMANDS:  # uss-eval compare MODEL MODEL ... (see compare_cli)
        return importlib.import_module(COMMANDS[argv[0]]).main(argv[1:])
    # Intermixed: data-config overrides may follow the options (MODEL --out DIR data=real).
    args = build_parser().parse_intermixed_args(argv)
    out = args.out if args.out is not None else Path("outputs") / "eval" / args.model.stem
    config_errors = (ConfigCompositionException, OverrideParseException, OmegaConfBaseException)
    with exit_on_user_error(PROG, config_errors):
        result = evaluate(
            args.model, out, sequences=args.sequence, overrides=args.overrides,
            stride=args.stride, dynamic=args.dynamic,
            frame_iou=args.frame_iou, overlays=args.overlays, threads=args.threads,
        )  # fmt: skip
        print(markdown(result))
        print(f"{PROG}: wrote {out / 'eval.json'} and {out / 'eval.md'}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
