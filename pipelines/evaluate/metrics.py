"""Scoring a segmenter frame by frame: the confusion matrix, each frame's dynamic-mask pixel
counts and the inference time."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from uss_slam.core.classes import CLASS_NAMES
from uss_slam.core.errors import UssSlamError
from uss_slam.core.seg_metrics import BinaryCounts, confusion_matrix, mask_counts

from .frames import LabelledFrame


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
    unlabelled: list[str] = field(default_factory=list)
    """Frames whose every label pixel is outside the classes (255, ignore): they count for
    nothing in the IoUs."""


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
        if not np.any(np.asarray(frame.labels) < n):
            scores.unlabelled.append(frame.name)
        if keep(k):
            scores.kept.append((frame, pred))
    return scores
