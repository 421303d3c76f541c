"""Dynamic pixels for ORB-SLAM3, which takes no masks: the segmenter's dynamic classes, dilated
exactly as the harness's semantic filter, are blanked in its input (grey colour, depth 0), and the
masks of every frame are computed once for all repeats.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from uss_slam.core.errors import UssSlamError
from uss_slam.core.progress import progress_bar

from ...filters.dynamic import SemanticFilter
from ...segmenters.base import Segmenter
from ...sequence import TumSequence


def dynamic_mask(labels: np.ndarray, semantic: SemanticFilter) -> np.ndarray:
    """``(H, W)`` bool: the dynamic classes of ``labels``, dilated exactly as the harness's
    semantic filter does (:meth:`SemanticFilter.mask`)."""
    return semantic.mask(labels) > 0


def blank_dynamic(
    rgb: np.ndarray, depth: np.ndarray, mask: np.ndarray | None, value: int = 128
) -> tuple[np.ndarray, np.ndarray]:
    """Copies of ``rgb`` (H, W, 3) uint8 and ``depth`` (H, W) float32 with the ``mask`` pixels
    set to grey ``value`` and to depth 0 (no measurement); the inputs themselves when ``mask``
    is None or empty."""
    if mask is None or not mask.any():
        return rgb, depth
    rgb = rgb.copy()
    depth = depth.copy()
    rgb[mask] = value
    depth[mask] = 0.0
    return rgb, depth


@dataclass
class MaskPass:
    """The dynamic masks of every frame (packed bits, one row per frame) and their cost."""

    packed: np.ndarray
    shape: tuple[int, int]
    blanked_fraction: float
    """Mean fraction of the image blanked per frame."""
    segmentation_ms: float
    """Mean wall milliseconds of the segmenter per frame."""


def compute_masks(
    sequence: TumSequence, segmenter: Segmenter, semantic: SemanticFilter, progress: bool = True
) -> MaskPass:
    """Segment every frame once (shared by all repeats) and keep its dilated dynamic mask."""
    width, height = sequence.image_size
    packed = np.zeros((len(sequence), (width * height + 7) // 8), np.uint8)
    spent = 0.0
    blanked = 0
    frames = sequence.frames()
    try:
        for frame in progress_bar(
            frames,
            total=len(sequence),
            desc=f"{sequence.path.name} [segmentation]",
            unit="frame",
            disable=not progress,
            dynamic_ncols=True,
        ):
            start = time.perf_counter()
            labels = segmenter.segment(frame)
            spent += time.perf_counter() - start
            if labels is None:
                raise UssSlamError(
                    f"segmenter {segmenter.name!r} returned no labels for frame {frame.index}"
                )
            mask = dynamic_mask(labels, semantic)
            blanked += int(mask.sum())
            packed[frame.index] = np.packbits(mask.reshape(-1))
    finally:
        frames.close()
    n = max(len(sequence), 1)
    return MaskPass(packed, (height, width), blanked / (n * width * height), 1000 * spent / n)
