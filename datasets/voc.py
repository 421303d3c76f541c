"""PASCAL VOC 2012 segmentation layout (the real devkit tree and ``uss-synth voc`` output).

``<root>/ImageSets/Segmentation/<split>.txt`` lists image ids; ``JPEGImages/<id>.jpg`` holds
the images and ``SegmentationClass/<id>.png`` the palette PNGs of VOC indices, remapped to the
project's classes with ``classes.voc_lut()`` (person / chair / tvmonitor; every other VOC class
becomes background, 255 stays ignore).
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np

from uss_slam.core.classes import IGNORE_INDEX, VOC_CLASS_NAMES, voc_lut
from uss_slam.core.errors import DataFormatError
from uss_slam.core.paths import read_text
from uss_slam.datasets.base import (
    ImageItem,
    OnError,
    SegmentationDataset,
    Transform,
    check_on_error,
    handle_bad_input,
    report_skipped,
)


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
    if not root.exists():
        raise DataFormatError(
            root,
            "not a VOC tree: the folder does not exist (give VOC2012 or the folder holding "
            "VOCdevkit/)",
        )
    raise DataFormatError(
        root, "not a VOC tree: expected ImageSets/Segmentation/ under it or VOCdevkit/VOC2012/"
    )


def read_id_list(list_file: Path) -> list[tuple[int, str]]:
    """``(line number, id)`` of a VOC / SBD id list: one image id per line, blank lines ignored.

    A line with more than one field (e.g. a ``ImageSets/Main`` classification list given by
    mistake) is an error naming the file and line; so is an id listed twice.
    """
    if not list_file.is_file():
        raise DataFormatError(list_file, "id list not found")
    text = read_text(list_file, "expected an id list (one image id per line)")
    ids: list[tuple[int, str]] = []
    seen: dict[str, int] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != 1:
            raise DataFormatError(
                list_file, f"expected one image id per line, got {len(fields)} fields", number
            )
        if fields[0] in seen:
            raise DataFormatError(
                list_file, f"id {fields[0]!r} listed twice (also on line {seen[fields[0]]})", number
            )
        seen[fields[0]] = number
        ids.append((number, fields[0]))
    return ids


def list_pairs(
    list_file: Path,
    image_dir: Path,
    image_suffix: str,
    label_dir: Path,
    label_suffix: str,
    on_error: OnError,
) -> tuple[list[ImageItem], list[DataFormatError]]:
    """Items of an id list whose image and label both exist.

    An image without its label (or a label without its image) is an error naming the list
    file and line, or (``on_error="skip"``) a skipped item.
    """
    items: list[ImageItem] = []
    skipped: list[DataFormatError] = []
    for number, name in read_id_list(list_file):
        image = image_dir / f"{name}{image_suffix}"
        label = label_dir / f"{name}{label_suffix}"
        missing = [path for path in (image, label) if not path.is_file()]
        if missing:
            if len(missing) == 2:
                why = "neither image nor label exists"
            elif missing[0] == label:
                why = f"the image {image.name} has no label"
            else:
                why = f"the label {label.name} has no image"
            error = DataFormatError(
                list_file, f"{missing[0]} (listed as {name!r}) not found: {why}", number
            )
            handle_bad_input(error, on_error, skipped)
            continue
        items.append(ImageItem(image=image, label=label, name=name))
    return items, skipped


class IdListSegmentation(SegmentationDataset):
    """A segmentation split read from an id list (VOC's and SBD's layout), with project classes.

    Subclasses name the layout: :attr:`kind` (in messages), :meth:`find_root`, the list file of
    a split (:meth:`split_list`) and the image / label folders and suffixes; labels hold VOC
    class indices (``classes.voc_lut()``). Every listed id needs both files (see
    :func:`list_pairs` and ``on_error``).
    """

    kind: ClassVar[str]
    image_dir: ClassVar[str]
    image_suffix: ClassVar[str]
    label_dir: ClassVar[str]
    label_suffix: ClassVar[str]

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        transform: Transform | None = None,
        on_error: OnError = "raise",
    ) -> None:
        self.on_error = check_on_error(on_error)
        self.root = self.find_root(root)
        self.split = split
        list_file = self.split_list(split)
        if not list_file.is_file():
            raise DataFormatError(
                list_file, f"split list for split {split!r} not found{self.missing_hint(split)}"
            )
        self.list_file = list_file
        items, skipped = list_pairs(
            list_file,
            self.root / self.image_dir,
            self.image_suffix,
            self.root / self.label_dir,
            self.label_suffix,
            self.on_error,
        )
        if not items and not skipped:
            raise DataFormatError(list_file, "the split list is empty")
        report_skipped(f"{self.kind} {split} ({list_file})", skipped)
        super().__init__(items, lut=voc_checked_lut(), transform=transform, skipped=skipped)

    @staticmethod
    def find_root(root: str | Path) -> Path:
        """The dataset folder for the ``root`` a user gave (an error if it is none)."""
        raise NotImplementedError

    def split_list(self, split: str) -> Path:
        """The id list of ``split`` under :attr:`root`."""
        raise NotImplementedError

    def missing_hint(self, split: str) -> str:
        """Appended to the error of a missing split list (default: nothing)."""
        return ""


class VOCSegmentation(IdListSegmentation):
    """VOC segmentation split with project classes.

    Args:
        root: the ``VOC2012`` folder (or a parent holding ``VOCdevkit/VOC2012``).
        split: name of the id list in ``ImageSets/Segmentation`` (``train``, ``val``, ...).
        transform: joint v2 transform (see :mod:`uss_slam.datasets.transforms`).
        on_error: ``raise`` (default): a listed image without label (or the reverse) is an
            error naming the list file and line; ``skip``: such items are left out and recorded
            in ``skipped``.

    Samples: ``image (3, H, W)`` float32, ``label (H, W)`` int64, ``name`` = image id.
    """

    kind = "VOC"
    image_dir, image_suffix = "JPEGImages", ".jpg"
    label_dir, label_suffix = "SegmentationClass", ".png"
    find_root = staticmethod(find_voc_root)

    def split_list(self, split: str) -> Path:
        return self.root / "ImageSets" / "Segmentation" / f"{split}.txt"
