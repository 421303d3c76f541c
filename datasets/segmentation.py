"""The shared sample type and base class of every image (+ label) dataset.

A dataset is a list of :class:`ImageItem` (image path, optional label path, name) plus a
look-up table that maps the file's label values to project classes (``classes.voc_lut()`` for
VOC, identity for the project's own label PNGs). Subclasses only build the item list (VOC, TUM
now; SBD and COCO later).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

import cv2
import numpy as np
import torch
from PIL import Image as PILImage
from torch.utils.data import Dataset
from torchvision import tv_tensors

from uss_slam.datasets.classes import IGNORE_INDEX, NUM_CLASSES
from uss_slam.datasets.errors import DataFormatError
from uss_slam.datasets.transforms import eval_transform


class SegmentationSample(TypedDict, total=False):
    """One sample after transforms; the data module collates these into batches of ``N``."""

    image: torch.Tensor  # (3, H, W) float32, normalised
    label: torch.Tensor  # (H, W) int64 project class ids, IGNORE_INDEX = ignore
    name: str


@dataclass(frozen=True)
class ImageItem:
    image: Path
    label: Path | None
    name: str


Transform = Callable[[dict[str, Any]], dict[str, Any]]


def identity_lut() -> np.ndarray:
    """Label values 0..NUM_CLASSES-1 and 255 kept; a value outside them is an error (``-1``)."""
    lut = np.full(256, -1, dtype=np.int16)
    lut[:NUM_CLASSES] = np.arange(NUM_CLASSES)
    lut[IGNORE_INDEX] = IGNORE_INDEX
    return lut


def read_image(path: Path) -> tv_tensors.Image:
    """An image file (JPEG / PNG, any channel count) -> ``(3, H, W)`` uint8 RGB."""
    rgb = cv2.imread(str(path), cv2.IMREAD_COLOR_RGB)
    if rgb is None:
        raise DataFormatError(path, "cannot decode image (missing, truncated or not an image)")
    return tv_tensors.Image(torch.from_numpy(rgb).permute(2, 0, 1))


def read_label(path: Path, lut: np.ndarray) -> tv_tensors.Mask:
    """A single-channel label PNG (palette 'P' or grey 'L') -> ``(H, W)`` uint8 project ids.

    ``lut`` (256 entries) maps file values to project classes; ``-1`` entries mark values that
    must not occur.
    """
    try:
        with PILImage.open(path) as image:
            if image.mode not in ("P", "L"):
                raise DataFormatError(
                    path,
                    f"expected a palette ('P') or greyscale ('L') label PNG of class indices, "
                    f"got mode {image.mode!r}",
                )
            values = np.asarray(image, dtype=np.uint8)
    except (OSError, ValueError) as error:
        raise DataFormatError(path, f"cannot decode label image ({error})") from error
    mapped = lut[values]
    if mapped.min() < 0:
        bad = sorted(set(np.unique(values[mapped < 0]).tolist()))[:5]
        raise DataFormatError(path, f"label values {bad} are not valid class indices")
    return tv_tensors.Mask(torch.from_numpy(mapped.astype(np.uint8)))


class SegmentationDataset(Dataset):
    """Images with optional labels; ``__getitem__`` returns a :class:`SegmentationSample`.

    Args:
        items: the files, one :class:`ImageItem` each (label ``None`` = unlabelled).
        lut: 256-entry table from label-file values to project classes (``-1`` = invalid).
        transform: joint v2 transform of the sample dict; default: normalisation only.
    """

    def __init__(
        self,
        items: Sequence[ImageItem],
        lut: np.ndarray | None = None,
        transform: Transform | None = None,
    ) -> None:
        self.items = list(items)
        self.lut = identity_lut() if lut is None else lut
        self.transform = transform if transform is not None else eval_transform()

    def __len__(self) -> int:
        return len(self.items)

    @property
    def labelled(self) -> bool:
        return bool(self.items) and all(item.label is not None for item in self.items)

    def load(self, index: int) -> dict[str, Any]:
        """The untransformed sample: uint8 image and mask tv_tensors, and the name."""
        item = self.items[index]
        sample: dict[str, Any] = {"image": read_image(item.image), "name": item.name}
        if item.label is not None:
            label = read_label(item.label, self.lut)
            if label.shape[-2:] != sample["image"].shape[-2:]:
                raise DataFormatError(
                    item.label,
                    f"label is {label.shape[-1]}×{label.shape[-2]} but its image "
                    f"{item.image.name} is {sample['image'].shape[-1]}×"
                    f"{sample['image'].shape[-2]}",
                )
            sample["label"] = label
        return sample

    def __getitem__(self, index: int) -> SegmentationSample:
        sample = self.transform(self.load(index))
        out: SegmentationSample = {"image": sample["image"].as_subclass(torch.Tensor)}
        if "label" in sample:
            out["label"] = sample["label"].as_subclass(torch.Tensor).to(torch.int64)
        out["name"] = sample["name"]
        return out
