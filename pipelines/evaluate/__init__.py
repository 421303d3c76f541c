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

One module each: :mod:`.frames` (the labelled frames), :mod:`.models` (checkpoint or ONNX
model), :mod:`.metrics` (scoring frame by frame), :mod:`.markdown` (``eval.md``),
:mod:`.overlays`, and :mod:`.cli` (the command line and :func:`evaluate`).
"""

from __future__ import annotations

from .cli import COMMANDS, PROG, build_parser, evaluate, main
from .frames import CONFIG_DIR, FrameSource, LabelledFrame, config_val_frames, sequence_frames
from .markdown import markdown
from .metrics import FrameScores, evaluate_frames
from .models import MODEL_KINDS, CheckpointSegmenter, load_segmenter, model_kind
from .overlays import evenly_spaced, overlay, remove_stale_overlays, write_overlays

__all__ = [
    "COMMANDS",
    "CONFIG_DIR",
    "MODEL_KINDS",
    "PROG",
    "CheckpointSegmenter",
    "FrameScores",
    "FrameSource",
    "LabelledFrame",
    "build_parser",
    "config_val_frames",
    "evaluate",
    "evaluate_frames",
    "evenly_spaced",
    "load_segmenter",
    "main",
    "markdown",
    "model_kind",
    "overlay",
    "remove_stale_overlays",
    "sequence_frames",
    "write_overlays",
]
