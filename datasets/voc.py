"""PASCAL VOC 2012 segmentation layout (the real devkit tree and ``uss-synth voc`` output).

``<root>/ImageSets/Segmentation/<split>.txt`` lists image ids; ``JPEGImages/<id>.jpg`` holds
the images and ``SegmentationClass/<id>.png`` the palette PNGs of VOC indices, remapped to the
project's classes with ``classes.voc_lut()`` (person / chair / tvmonitor; every other VOC class
becomes background, 255 stays ignore).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uss_slam.datasets.classes import IGNORE_INDEX, VOC_CLASS_NAMES, voc_lut
from uss_slam.datasets.errors import DataFormatError
from uss_slam.datasets.segmentation import ImageItem, SegmentationDataset, Transform


def voc_checked_lut() -> np.ndarray:
    """``voc_lut()`` with values that are no VOC index (21..254) marked invalid (``-1``)."""
    lut = voc_lut().astype(np.int16)
    invalid = np.ones(256, dtype=bool)
    invalid[: len(VOC_CLASS_NAMES)] = False
    invalid[IGNORE_INDEX] = False
    lut[invalid] = -1
    return lut


def find_voc_root(root: str | Path) -> Path:
    """Accept ``.../VOC2012`` itself or a folder containing ``VOCdevkit/VOC2012``."""
    root = Path(root)
    for candidate in (root, root / "VOC2012", root / "VOCdevkit" / "VOC2012"):
        if (candidate / "ImageSets" / "Segmentation").is_dir():
            return candidate
    raise DataFormatError(
        root, "not a VOC tree: expected ImageSets/Segmentation/ under it or VOCdevkit/VOC2012/"
    )


class VOCSegmentation(SegmentationDataset):
    """VOC segmentation split with project classes.

    Args:
        root: the ``VOC2012`` folder (or a parent holding ``VOCdevkit/VOC2012``).
        split: name of the id list in ``ImageSets/Segmentation`` (``train``, ``val``, ...).
        transform: joint v2 transform (see :mod:`uss_slam.datasets.transforms`).

    Every listed image and label must exist; a missing one is reported with the list file and
    line. Samples: ``image (3, H, W)`` float32, ``label (H, W)`` int64, ``name`` = image id.
    """

    def __init__(
        self, root: str | Path, split: str = "train", transform: Transform | None = None
    ) -> None:
        self.root = find_voc_root(root)
        self.split = split
        list_file = self.root / "ImageSets" / "Segmentation" / f"{split}.txt"
        if not list_file.is_file():
            raise DataFormatError(list_file, f"split list for split {split!r} not found")
        items = []
        for number, line in enumerate(list_file.read_text().splitlines(), start=1):
            name = line.strip()
            if not name:
                continue
            image = self.root / "JPEGImages" / f"{name}.jpg"
            label = self.root / "SegmentationClass" / f"{name}.png"
            for path in (image, label):
                if not path.is_file():
                    raise DataFormatError(
                        list_file, f"{path} (listed as {name!r}) not found", number
                    )
            items.append(ImageItem(image=image, label=label, name=name))
        if not items:
            raise DataFormatError(list_file, "the split list is empty")
        super().__init__(items, lut=voc_checked_lut(), transform=transform)
