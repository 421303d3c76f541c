"""The bounded up-front check of a data module's files (``datasets.precheck``): labels with a
value that is no class and truncated images are found before training, within the budget."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from uss_slam.core.errors import DataFormatError
from uss_slam.datasets.base import ImageItem, SegmentationDataset
from uss_slam.datasets.precheck import check_data_files


def _dataset(root: Path, n: int, bad: int | None = None) -> SegmentationDataset:
    """``n`` items of a JPEG and a label PNG; item ``bad``'s label holds the value 7."""
    root.mkdir()
    items = []
    for i in range(n):
        Image.fromarray(np.zeros((8, 10, 3), np.uint8)).save(root / f"{i}.jpg")
        label = np.zeros((8, 10), np.uint8)
        label[0, 0] = 7 if i == bad else 1
        Image.fromarray(label).save(root / f"{i}.png")
        items.append(ImageItem(image=root / f"{i}.jpg", label=root / f"{i}.png", name=str(i)))
    return SegmentationDataset(items)


def test_a_label_value_outside_the_classes_is_found(tmp_path: Path) -> None:
    module = SimpleNamespace(val=_dataset(tmp_path / "v", 2), source=_dataset(tmp_path / "s", 4, 3))
    with pytest.raises(DataFormatError, match=r"3\.png: label values 7 are not class ids"):
        check_data_files(module)


def test_the_budget_bounds_the_files_checked(tmp_path: Path) -> None:
    """Past ``max_files`` nothing is read (the bad label is left to the batch that reads it)."""
    module = SimpleNamespace(source=_dataset(tmp_path / "s", 4, 3), target=None)
    assert check_data_files(module, max_files=3) == 3


def test_a_truncated_image_without_label_is_found(tmp_path: Path) -> None:
    source = _dataset(tmp_path / "s", 2)
    jpg = source.items[1].image
    jpg.write_bytes(jpg.read_bytes()[:-40])
    target = SegmentationDataset([ImageItem(image=jpg, label=None, name="t")])
    with pytest.raises(DataFormatError, match="truncated JPEG"):
        check_data_files(SimpleNamespace(target=target))
