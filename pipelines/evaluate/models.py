"""The model ``uss-eval`` scores: a ``uss-train`` checkpoint or an exported ONNX model, as
``infer(rgb) -> class ids``."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import file_sha256
from uss_slam.core.onnx_contract import check_label_ids, check_logit_channels
from uss_slam.core.paths import input_file

MODEL_KINDS = {".ckpt": "checkpoint", ".onnx": "onnx"}


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
    expected = "expected a uss-train checkpoint (.ckpt) or an exported model (.onnx)"
    input_file(path, None, expected)
    kind = MODEL_KINDS.get(path.suffix.lower())
    if kind is None:
        raise UssSlamError(f"{path}: {expected}")
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
