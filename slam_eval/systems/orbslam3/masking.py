"""Dynamic pixels for ORB-SLAM3, which takes no masks: the pixels that the region filters find in
the frame alone (those with ``masks_input``: the semantic filter's dilated dynamic classes,
exactly as in the harness) are blanked in its input (depth 0; the colour flat grey, or filled
from the surroundings by inpainting), and the masks of every frame, and the inpainted images,
are computed once for all repeats.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from uss_slam.core.errors import UssSlamError
from uss_slam.core.files import write_file
from uss_slam.core.images import read_colour
from uss_slam.core.progress import progress_bar

from ...filters.base import DynamicFilter
from ...segmenters.base import Segmenter
from ...sequence import Frame, TumSequence


def segment_timed(segmenter: Segmenter, frame: Frame) -> tuple[np.ndarray, float]:
    """``segmenter``'s (H, W) labels of ``frame`` and the wall seconds they took; one line
    (:class:`UssSlamError`) where it returns none."""
    start = time.perf_counter()
    labels = segmenter.segment(frame)
    seconds = time.perf_counter() - start
    if labels is None:
        raise UssSlamError(
            f"segmenter {segmenter.name!r} returned no labels for frame {frame.index}"
        )
    return labels, seconds


def dynamic_mask(
    frame: Frame, labels: np.ndarray | None, masks: Sequence[DynamicFilter]
) -> np.ndarray:
    """``(H, W)`` bool: the union of the pixels each filter of ``masks`` finds in ``frame`` and
    its ``labels`` alone (:meth:`~...filters.base.DynamicFilter.input_region`), as the harness's
    filters find them."""
    out = np.zeros(frame.depth.shape, bool)
    for f in masks:
        region = f.input_region(frame, labels)
        if region is not None:
            out |= region
    return out


def check_masks(masks: Sequence[DynamicFilter]) -> None:
    """Each of ``masks`` finds its pixels in the frame alone; else one line naming it."""
    for f in masks:
        if not f.masks_input:
            raise UssSlamError(
                f"system=orbslam3: filter {f.name!r} cannot blank ORB-SLAM3's input (it needs "
                "the harness's keypoints, pose or map); use filters whose pixels come from the "
                "frame alone (semantic)"
            )


FILLS = ("grey", "inpaint")
"""How the colour of blanked pixels is filled (``system.blank_fill``)."""

INPAINT_RADIUS = 5
"""Pixels around each filled point that ``cv2.inpaint`` (Telea) takes its colour from."""


def fill_dynamic(rgb: np.ndarray, mask: np.ndarray, fill: str = "grey", value: int = 128):
    """A copy of ``rgb`` (H, W, 3) uint8 with the ``mask`` pixels filled: flat grey ``value``
    (``grey``), or continued from the pixels around the mask (``inpaint``: ``cv2.inpaint``,
    Telea). A mask that covers only part of a walker leaves an edge across him that moves with
    him; inpainting leaves a weaker one there than flat grey, so fewer corners on the walker
    (``studies/orbslam3_partial_masks.py``)."""
    if fill == "grey":
        out = rgb.copy()
        out[mask] = value
        return out
    if fill == "inpaint":
        return cv2.inpaint(rgb, mask.astype(np.uint8), INPAINT_RADIUS, cv2.INPAINT_TELEA)
    raise UssSlamError(f"system.blank_fill={fill!r}: expected one of {', '.join(FILLS)}")


def blank_dynamic(
    rgb: np.ndarray,
    depth: np.ndarray,
    mask: np.ndarray | None,
    value: int = 128,
    filled: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Copies of ``rgb`` (H, W, 3) uint8 and ``depth`` (H, W) float32 with the ``mask`` pixels
    set to grey ``value`` (or, given ``filled``, the colour image replaced by it: the frame as
    :func:`fill_dynamic` filled it) and to depth 0 (no measurement); the inputs themselves when
    ``mask`` is None or empty."""
    if mask is None or not mask.any():
        return rgb, depth
    depth = depth.copy()
    depth[mask] = 0.0
    if filled is not None:
        return filled, depth
    return fill_dynamic(rgb, mask, "grey", value), depth


def filled_path(folder: str | Path, index: int) -> Path:
    """Where :func:`compute_masks` keeps frame ``index`` filled (lossless PNG, BGR)."""
    return Path(folder) / f"{index:06d}.png"


def read_filled(folder: str | Path, index: int) -> np.ndarray | None:
    """Frame ``index`` as :func:`compute_masks` filled it (RGB), or None (nothing blanked)."""
    path = filled_path(folder, index)
    if not path.is_file():
        return None
    bgr = read_colour(path)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


@dataclass
class MaskPass:
    """The dynamic masks of every frame (packed bits, one row per frame) and their cost."""

    packed: np.ndarray
    shape: tuple[int, int]
    blanked_fraction: float
    """Mean fraction of the image blanked per frame."""
    segmentation_ms: float
    """Mean wall milliseconds of the segmenter per frame."""
    fill_ms: float = 0.0
    """Mean wall milliseconds per frame of inpainting (``fill_dir``), 0 for grey."""


def compute_masks(
    sequence: TumSequence,
    segmenter: Segmenter,
    masks: Sequence[DynamicFilter],
    progress: bool = True,
    fill_dir: Path | None = None,
) -> MaskPass:
    """Segment every frame once (shared by all repeats) and keep its dynamic mask (the union of
    the regions of ``masks``, :func:`dynamic_mask`); with ``fill_dir``, also write every frame
    with a masked pixel there inpainted (:func:`fill_dynamic`, :func:`filled_path`), so that
    the repeats feed ORB-SLAM3 at the same pace as with grey."""
    width, height = sequence.image_size
    packed = np.zeros((len(sequence), (width * height + 7) // 8), np.uint8)
    spent = 0.0
    filling = 0.0
    blanked = 0
    if fill_dir is not None:
        fill_dir.mkdir(parents=True, exist_ok=True)
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
            labels, seconds = segment_timed(segmenter, frame)
            spent += seconds
            mask = dynamic_mask(frame, labels, masks)
            blanked += int(mask.sum())
            packed[frame.index] = np.packbits(mask.reshape(-1))
            if fill_dir is not None and mask.any():
                start = time.perf_counter()
                filled = fill_dynamic(frame.rgb, mask, "inpaint")
                filling += time.perf_counter() - start
                path = filled_path(fill_dir, frame.index)
                ok, data = cv2.imencode(path.suffix, cv2.cvtColor(filled, cv2.COLOR_RGB2BGR))
                if not ok:
                    raise UssSlamError(f"{path}: could not be encoded (the inpainted frame)")
                write_file(path, data.tobytes())  # a path in any encoding, a full disk named
    finally:
        frames.close()
    n = max(len(sequence), 1)
    return MaskPass(
        packed, (height, width), blanked / (n * width * height), 1000 * spent / n,
        1000 * filling / n,
    )  # fmt: skip
