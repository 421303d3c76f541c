"""The project's classes and their mapping from VOC and COCO. Pure NumPy.

``0 background, 1 person, 2 chair, 3 monitor``; ``255`` is ignored by the loss and the metrics.
"""

from __future__ import annotations

import numpy as np

CLASS_NAMES: tuple[str, ...] = ("background", "person", "chair", "monitor")
NUM_CLASSES = len(CLASS_NAMES)
IGNORE_INDEX = 255
DYNAMIC_CLASSES: tuple[str, ...] = ("person",)
"""Classes the SLAM harness treats as moving by default."""

CLASS_COLORS = np.array([[0, 0, 0], [220, 20, 60], [255, 160, 0], [0, 90, 255]], dtype=np.uint8)
"""RGB colour per class (person red, chair orange, monitor blue: as the paper's map figures)."""

# PASCAL VOC 2012 class indices (0 background ... 20 tvmonitor).
VOC_CLASS_NAMES: tuple[str, ...] = (
    "background", "aeroplane", "bicycle", "bird", "boat", "bottle", "bus", "car", "cat", "chair",
    "cow", "diningtable", "dog", "horse", "motorbike", "person", "pottedplant", "sheep", "sofa",
    "train", "tvmonitor",
)  # fmt: skip
VOC_TO_PROJECT: dict[int, int] = {15: 1, 9: 2, 20: 3}
"""VOC index -> project class; every other VOC class is background, 255 stays ignore."""
PROJECT_TO_VOC: dict[int, int] = {v: k for k, v in VOC_TO_PROJECT.items()}
COCO_TO_PROJECT: dict[int, int] = {1: 1, 62: 2, 72: 3}
"""COCO category id -> project class (person, chair, tv)."""


def voc_palette() -> np.ndarray:
    """The 256×3 uint8 colour map of VOC's palette PNGs (the devkit's bit-interleaving rule)."""
    palette = np.zeros((256, 3), dtype=np.uint8)
    for index in range(256):
        c, r, g, b = index, 0, 0, 0
        for bit in range(8):
            r |= ((c >> 0) & 1) << (7 - bit)
            g |= ((c >> 1) & 1) << (7 - bit)
            b |= ((c >> 2) & 1) << (7 - bit)
            c >>= 3
        palette[index] = (r, g, b)
    return palette


def voc_lut() -> np.ndarray:
    """256-entry uint8 table: VOC index -> project class (255 -> 255, other classes -> 0)."""
    lut = np.zeros(256, dtype=np.uint8)
    for voc, ours in VOC_TO_PROJECT.items():
        lut[voc] = ours
    lut[IGNORE_INDEX] = IGNORE_INDEX
    return lut


def colorize(labels: np.ndarray) -> np.ndarray:
    """``(H, W)`` class ids -> ``(H, W, 3)`` uint8 RGB; ignore (255) shown white."""
    lut = np.full((256, 3), 255, dtype=np.uint8)
    lut[: len(CLASS_COLORS)] = CLASS_COLORS
    return lut[labels]
